#include "estimator/features/height_descriptor.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace raillomer {

namespace {

constexpr double kSigmaPerValleyWidth = 0.12;

int CellCount(double from, double to, double bin) {
  return static_cast<int>(std::lround((to - from) / bin));
}

int Occupied(const HeightDescriptor& d) {
  return static_cast<int>((d.cells.array() > 0.f).count());
}

/// The descriptor's points sorted by cell (a counting sort): cell c holds
/// sorted[begin[c], begin[c + 1]).
struct CellPoints {
  std::vector<int> begin;
  std::vector<Eigen::Vector3f> sorted;
};

/// Sorts the points between z_floor_m and z_ceiling_m that fall in the grid into its cells.
CellPoints SortIntoCells(const HeightDescriptorOptions& options,
                         const HeightDescriptor& d,
                         const std::vector<Eigen::Vector3f>& points_body) {
  const float inv_bin = static_cast<float>(1.0 / options.bin_m);
  const float x_min = static_cast<float>(options.x_min_m);
  const float y_min = static_cast<float>(options.y_min_m);
  const float z_floor = static_cast<float>(options.z_floor_m);
  const float z_ceiling = static_cast<float>(options.z_ceiling_m);
  const int n_cells = d.rows * d.cols;
  CellPoints cells;
  std::vector<int> cell_of(points_body.size(), -1);
  cells.begin.assign(n_cells + 1, 0);
  for (size_t i = 0; i < points_body.size(); ++i) {
    const Eigen::Vector3f& p = points_body[i];
    if (!(p.z() > z_floor && p.z() <= z_ceiling)) continue;  // also drops NaN
    const float u = (p.x() - x_min) * inv_bin, v = (p.y() - y_min) * inv_bin;
    if (!(u >= 0.f && v >= 0.f && u < d.cols && v < d.rows)) continue;
    const int col = std::min(d.cols - 1, static_cast<int>(u));
    const int row = std::min(d.rows - 1, static_cast<int>(v));
    cell_of[i] = row * d.cols + col;
    ++cells.begin[cell_of[i] + 1];
  }
  for (int c = 0; c < n_cells; ++c) cells.begin[c + 1] += cells.begin[c];
  cells.sorted.resize(cells.begin[n_cells]);
  std::vector<int> fill(cells.begin.begin(), cells.begin.end() - 1);
  for (size_t i = 0; i < points_body.size(); ++i) {
    if (cell_of[i] >= 0) cells.sorted[fill[cell_of[i]]++] = points_body[i];
  }
  return cells;
}

/// The support test of a point (see Supported), from the options once per descriptor.
struct Support {
  explicit Support(const HeightDescriptorOptions& options)
      : radius2(static_cast<float>(options.support_radius_m * options.support_radius_m)),
        reach(std::max(1, static_cast<int>(std::ceil(options.support_radius_m / options.bin_m)))),
        min_points(options.min_support_points) {}

  float radius2;   ///< support_radius_m squared
  int reach;       ///< cells searched either way
  int min_points;  ///< min_support_points
};

/// Whether point `self` (in cell row, col) has min_support_points others within
/// support_radius_m: a real surface. Isolated returns (sun flicker, mixed returns, dust) would
/// add random heights.
bool Supported(const Support& support,
               const HeightDescriptor& d,
               const CellPoints& cells,
               int row,
               int col,
               int self) {
  if (support.min_points <= 0) return true;
  const int reach = support.reach;
  const Eigen::Vector3f& p = cells.sorted[self];
  int found = 0;
  for (int r = std::max(0, row - reach); r <= std::min(d.rows - 1, row + reach); ++r) {
    for (int c = std::max(0, col - reach); c <= std::min(d.cols - 1, col + reach); ++c) {
      const int cell = r * d.cols + c;
      for (int k = cells.begin[cell]; k < cells.begin[cell + 1]; ++k) {
        if (k != self && (cells.sorted[k] - p).squaredNorm() <= support.radius2 &&
            ++found >= support.min_points) {
          return true;
        }
      }
    }
  }
  return false;
}

/// Why two descriptors cannot be compared (layout, prediction, too few occupied cells), or an
/// empty string.
std::string CannotCompare(const HeightDescriptorOptions& options,
                          const HeightDescriptor& previous,
                          const HeightDescriptor& current,
                          double predicted_dx_m) {
  std::string error;
  if (!options.IsValid(&error)) return "invalid options: " + error;
  if (previous.rows != current.rows || previous.cols != current.cols ||
      previous.bin_m != current.bin_m || !(previous.bin_m > 0.0) ||
      previous.cells.rows() != previous.rows || previous.cells.cols() != previous.cols ||
      current.cells.rows() != current.rows || current.cells.cols() != current.cols) {
    return "the descriptors differ in layout";
  }
  if (!std::isfinite(predicted_dx_m)) return "the predicted shift is not finite";
  const int occupied = std::min(Occupied(previous), Occupied(current));
  if (occupied < options.min_occupied_cells) {
    return "too empty: " + std::to_string(occupied) + " occupied cells (need " +
           std::to_string(options.min_occupied_cells) + ")";
  }
  return "";
}

/// The lowest local minimum of `distance` beyond `best` and its neighbours (infinity if none).
double RunnerUp(const std::vector<double>& distance, int best) {
  const int n = static_cast<int>(distance.size());
  double runner_up = std::numeric_limits<double>::infinity();
  for (int i = 1; i + 1 < n; ++i) {
    if (std::abs(i - best) <= 1) continue;
    if (distance[i] <= distance[i - 1] && distance[i] <= distance[i + 1]) {
      runner_up = std::min(runner_up, distance[i]);
    }
  }
  return runner_up;
}

/// Refines the best whole-bin shift with a parabola through it and its neighbours; fills the
/// result's shift, distance and sigma, or returns why it cannot.
std::string RefineShift(const HeightDescriptorOptions& options,
                        const std::vector<double>& distance,
                        int best,
                        int best_shift,
                        double bin,
                        LongitudinalShift* result) {
  const double d_min = distance[best];
  const double dm = distance[best - 1], dp = distance[best + 1];
  const double curvature = dm - 2.0 * d_min + dp;  // second difference, per bin^2
  if (!(curvature > 1e-9)) return "the minimum is flat";
  const double offset = std::clamp(0.5 * (dm - dp) / curvature, -0.5, 0.5);
  const double d_opt = std::max(0.0, d_min - 0.25 * (dm - dp) * offset);
  // Valley width: where the parabola has risen by the residual distance at its vertex. The
  // error grows with it (calibrated on simulated Livox frames), above a floor from the bins.
  const double width_m = std::sqrt(2.0 * d_opt / (curvature / (bin * bin)));
  if (width_m > options.max_valley_width_m) return "the distance valley is too wide";
  result->dx_m = (best_shift + offset) * bin;
  result->distance = d_opt;
  result->sigma_m = std::hypot(options.min_sigma_m, kSigmaPerValleyWidth * width_m);
  return "";
}

}  // namespace

bool HeightDescriptorOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (!(bin_m > 0.0)) return fail("bin_m must be positive");
  if (!(x_max_m > x_min_m + 2.0 * bin_m)) return fail("x_max_m must exceed x_min_m by two bins");
  if (!(y_max_m > y_min_m + bin_m)) return fail("y_max_m must exceed y_min_m by a bin");
  if (!(z_ceiling_m > z_floor_m)) return fail("z_ceiling_m must exceed z_floor_m");
  if (!(support_radius_m >= 0.0 && support_radius_m <= 4.0 * bin_m))
    return fail("support_radius_m must be within [0, 4 bin_m]");
  if (min_support_points < 0) return fail("min_support_points must not be negative");
  if (!(max_shift_search_m >= bin_m)) return fail("max_shift_search_m must be at least bin_m");
  if (!(min_score >= 0.0 && min_score < 1.0)) return fail("min_score must be within [0, 1)");
  if (min_occupied_cells < 1) return fail("min_occupied_cells must be at least 1");
  if (!(min_distinctness >= 0.0 && min_distinctness < 1.0))
    return fail("min_distinctness must be within [0, 1)");
  if (!(min_sigma_m > 0.0)) return fail("min_sigma_m must be positive");
  if (!(max_valley_width_m > 0.0)) return fail("max_valley_width_m must be positive");
  return true;
}

HeightDescriptor ComputeHeightDescriptor(const HeightDescriptorOptions& options,
                                         const std::vector<Eigen::Vector3f>& points_body) {
  HeightDescriptor d;
  if (!options.IsValid(nullptr)) return d;  // no cells: nothing to compare
  d.rows = std::max(1, CellCount(options.y_min_m, options.y_max_m, options.bin_m));
  d.cols = std::max(1, CellCount(options.x_min_m, options.x_max_m, options.bin_m));
  d.x_min_m = options.x_min_m;
  d.bin_m = options.bin_m;
  d.cells = Eigen::MatrixXf::Zero(d.rows, d.cols);
  const float z_floor = static_cast<float>(options.z_floor_m);
  const CellPoints cells = SortIntoCells(options, d, points_body);
  const Support support(options);
  // Each cell: the height of its highest supported point.
  for (int row = 0; row < d.rows; ++row) {
    for (int col = 0; col < d.cols; ++col) {
      const int cell = row * d.cols + col;
      float best = 0.f;
      for (int k = cells.begin[cell]; k < cells.begin[cell + 1]; ++k) {
        const float h = cells.sorted[k].z() - z_floor;
        if (h > best && Supported(support, d, cells, row, col, k)) best = h;
      }
      d.cells(row, col) = best;
    }
  }
  return d;
}

double HeightDescriptorDistance(const HeightDescriptor& a,
                                const HeightDescriptor& b,
                                double shift_bins) {
  if (a.rows != b.rows || a.cols != b.cols || a.cells.rows() != a.rows ||
      a.cells.cols() != a.cols || b.cells.rows() != b.rows || b.cells.cols() != b.cols ||
      !std::isfinite(shift_bins)) {
    return 1.0;
  }
  // b's column j is compared with a at column j + shift, linearly interpolated between columns.
  const double floor_shift = std::floor(shift_bins);
  if (std::fabs(floor_shift) >= a.cols) return 1.0;
  const int s0 = static_cast<int>(floor_shift);
  const float f = static_cast<float>(shift_bins - floor_shift);
  const int j_begin = std::max(0, -s0);
  const int j_end = std::min(b.cols, a.cols - s0 - (f > 0.f ? 1 : 0));
  double sum = 0.0;
  int used = 0;
  for (int i = 0; i < a.rows; ++i) {
    if (!(a.cells.row(i).maxCoeff() > 0.f && b.cells.row(i).maxCoeff() > 0.f)) continue;
    double dot = 0.0, na = 0.0, nb = 0.0;
    for (int j = j_begin; j < j_end; ++j) {
      const int ja = j + s0;
      const float av =
          f > 0.f ? (1.f - f) * a.cells(i, ja) + f * a.cells(i, ja + 1) : a.cells(i, ja);
      const float bv = b.cells(i, j);
      dot += av * bv;
      na += av * av;
      nb += bv * bv;
    }
    // Rows empty in either descriptor are skipped (above). Within the overlap, returns on one
    // side only are a full mismatch (else shifting a feature out of the overlap would hide it),
    // and on neither side no evidence.
    if (na <= 0.0 && nb <= 0.0) continue;
    // Eq. (27): 1 - cosine similarity of row i, averaged over the rows.
    sum += na > 0.0 && nb > 0.0 ? 1.0 - dot / std::sqrt(na * nb) : 1.0;
    ++used;
  }
  return used > 0 ? sum / used : 1.0;
}

LongitudinalShift EstimateLongitudinalShift(const HeightDescriptorOptions& options,
                                            const HeightDescriptor& previous,
                                            const HeightDescriptor& current,
                                            double predicted_dx_m) {
  LongitudinalShift result;
  auto fail = [&result](const std::string& why) {
    result.failure = why;
    return result;
  };
  const std::string why = CannotCompare(options, previous, current, predicted_dx_m);
  if (!why.empty()) return fail(why);

  // Eq. (27) at every whole-bin shift within the search window around the prediction.
  const double bin = previous.bin_m;
  const int k_lo = static_cast<int>(std::ceil((predicted_dx_m - options.max_shift_search_m) / bin));
  const int k_hi =
      static_cast<int>(std::floor((predicted_dx_m + options.max_shift_search_m) / bin));
  if (k_hi - k_lo < 2) return fail("the search window spans fewer than three shifts");
  std::vector<double> distance(k_hi - k_lo + 1);
  for (int k = k_lo; k <= k_hi; ++k) {
    distance[k - k_lo] = HeightDescriptorDistance(previous, current, k);
  }
  const int n = static_cast<int>(distance.size());
  const int best =
      static_cast<int>(std::min_element(distance.begin(), distance.end()) - distance.begin());
  const double d_min = distance[best];
  const double d_max = *std::max_element(distance.begin(), distance.end());
  result.distance = d_min;
  if (best == 0 || best == n - 1) return fail("the minimum lies at the edge of the window");
  if (1.0 - d_min < options.min_score) return fail("the similarity is below min_score");
  // Distinct: every other local minimum (beyond the best's neighbours) lies clearly higher.
  if (RunnerUp(distance, best) - d_min < options.min_distinctness * (d_max - d_min)) {
    return fail("the minimum is not distinct");
  }
  // Structures cut off by the field of view, and long surfaces sampled by the scan pattern,
  // stay put in the body frame and pull towards zero shift: zero while moving is no answer.
  const int best_shift = k_lo + best;
  if (std::abs(best_shift) <= 1 && std::fabs(predicted_dx_m) > 2.0 * bin) {
    return fail("locked to zero shift while the prediction moves");
  }
  const std::string flat = RefineShift(options, distance, best, best_shift, bin, &result);
  if (!flat.empty()) return fail(flat);
  result.ok = true;
  return result;
}

}  // namespace raillomer
