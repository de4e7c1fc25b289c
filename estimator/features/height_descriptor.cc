#include "estimator/features/height_descriptor.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace raillomer {

namespace {

int CellCount(double from, double to, double bin) {
  return static_cast<int>(std::lround((to - from) / bin));
}

int Occupied(const HeightDescriptor& d) { return static_cast<int>((d.cells.array() > 0.f).count()); }

/// The descriptor blurred with the kernel [1 2 1] / 4 along and across the track, `passes`
/// times. One frame of a Livox samples each object sparsely and at different spots every time;
/// the blur lets neighbouring cells overlap, and makes the distance a smooth function of the
/// shift (symmetric, so it does not move the optimum).
HeightDescriptor Smoothed(const HeightDescriptor& d, int passes) {
  HeightDescriptor out = d;
  Eigen::MatrixXf tmp(d.rows, d.cols);
  for (int pass = 0; pass < passes; ++pass) {
    for (int i = 0; i < d.rows; ++i) {
      for (int j = 0; j < d.cols; ++j) {
        const float left = j > 0 ? out.cells(i, j - 1) : 0.f;
        const float right = j + 1 < d.cols ? out.cells(i, j + 1) : 0.f;
        tmp(i, j) = 0.25f * left + 0.5f * out.cells(i, j) + 0.25f * right;
      }
    }
    for (int i = 0; i < d.rows; ++i) {
      for (int j = 0; j < d.cols; ++j) {
        const float below = i > 0 ? tmp(i - 1, j) : 0.f;
        const float above = i + 1 < d.rows ? tmp(i + 1, j) : 0.f;
        out.cells(i, j) = 0.25f * below + 0.5f * tmp(i, j) + 0.25f * above;
      }
    }
  }
  return out;
}

/// Cleans a descriptor for matching.
HeightDescriptor Prepared(const HeightDescriptor& d) {
  static const bool kIsolated = !getenv("HD_NO_ISO");
  static const int kGap = getenv("HD_GAP") ? atoi(getenv("HD_GAP")) : 4;
  static const float kGapDh = getenv("HD_GAPDH") ? atof(getenv("HD_GAPDH")) : 0.3f;
  static const int kPasses = getenv("HD_PASSES") ? atoi(getenv("HD_PASSES")) : 1;
  HeightDescriptor out = d;
  if (kIsolated) {
    for (int i = 0; i < d.rows; ++i) {
      for (int j = 0; j < d.cols; ++j) {
        if (d.cells(i, j) <= 0.f) continue;
        bool neighbour = false;
        for (int di = -1; di <= 1 && !neighbour; ++di) {
          for (int dj = -1; dj <= 1 && !neighbour; ++dj) {
            const int ii = i + di, jj = j + dj;
            if ((di || dj) && ii >= 0 && ii < d.rows && jj >= 0 && jj < d.cols &&
                d.cells(ii, jj) > 0.f)
              neighbour = true;
          }
        }
        if (!neighbour) out.cells(i, j) = 0.f;
      }
    }
  }
  if (kGap > 0) {
    const Eigen::MatrixXf src = out.cells;
    for (int i = 0; i < d.rows; ++i) {
      int last = -1;
      for (int j = 0; j < d.cols; ++j) {
        if (src(i, j) <= 0.f) continue;
        if (last >= 0 && j - last - 1 > 0 && j - last - 1 <= kGap &&
            std::fabs(src(i, j) - src(i, last)) <= kGapDh) {
          for (int m = last + 1; m < j; ++m) {
            const float t = static_cast<float>(m - last) / (j - last);
            out.cells(i, m) = (1.f - t) * src(i, last) + t * src(i, j);
          }
        }
        last = j;
      }
    }
  }
  static const int kDx = getenv("HD_DX") ? atoi(getenv("HD_DX")) : 0;
  static const int kDy = getenv("HD_DY") ? atoi(getenv("HD_DY")) : 0;
  if (kDx > 0 || kDy > 0) {
    const Eigen::MatrixXf src = out.cells;
    for (int i = 0; i < d.rows; ++i) {
      for (int j = 0; j < d.cols; ++j) {
        float m = 0.f;
        for (int ii = std::max(0, i - kDy); ii <= std::min(d.rows - 1, i + kDy); ++ii)
          for (int jj = std::max(0, j - kDx); jj <= std::min(d.cols - 1, j + kDx); ++jj)
            m = std::max(m, src(ii, jj));
        out.cells(i, j) = m;
      }
    }
  }
  return Smoothed(out, kPasses);
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
  if (!(max_shift_search_m >= bin_m)) return fail("max_shift_search_m must be at least bin_m");
  if (!(min_score >= 0.0 && min_score < 1.0)) return fail("min_score must be within [0, 1)");
  if (min_occupied_cells < 1) return fail("min_occupied_cells must be at least 1");
  if (!(min_distinctness >= 0.0 && min_distinctness < 1.0))
    return fail("min_distinctness must be within [0, 1)");
  if (!(min_sigma_m > 0.0)) return fail("min_sigma_m must be positive");
  return true;
}

HeightDescriptor ComputeHeightDescriptor(const HeightDescriptorOptions& options,
                                         const std::vector<Eigen::Vector3f>& points_body) {
  HeightDescriptor d;
  d.rows = std::max(1, CellCount(options.y_min_m, options.y_max_m, options.bin_m));
  d.cols = std::max(1, CellCount(options.x_min_m, options.x_max_m, options.bin_m));
  d.x_min_m = options.x_min_m;
  d.bin_m = options.bin_m;
  d.cells = Eigen::MatrixXf::Zero(d.rows, d.cols);
  const float inv_bin = static_cast<float>(1.0 / options.bin_m);
  const float x_min = static_cast<float>(options.x_min_m);
  const float y_min = static_cast<float>(options.y_min_m);
  const float z_floor = static_cast<float>(options.z_floor_m);
  const float z_ceiling = static_cast<float>(options.z_ceiling_m);
  for (const Eigen::Vector3f& p : points_body) {
    if (!(p.z() > z_floor && p.z() <= z_ceiling)) continue;  // also drops NaN
    const float u = (p.x() - x_min) * inv_bin, v = (p.y() - y_min) * inv_bin;
    if (!(u >= 0.f && v >= 0.f)) continue;
    const int col = static_cast<int>(u), row = static_cast<int>(v);
    if (col >= d.cols || row >= d.rows) continue;
    float& cell = d.cells(row, col);
    cell = std::max(cell, p.z() - z_floor);
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
    if (na <= 0.0 || nb <= 0.0) continue;  // empty in either: skipped
    // Eq. (27): 1 - cosine similarity of row i, averaged over the rows.
    sum += 1.0 - dot / std::sqrt(na * nb);
    ++used;
  }
  return used > 0 ? sum / used : 1.0;
}

LongitudinalShift EstimateLongitudinalShift(const HeightDescriptorOptions& options,
                                            const HeightDescriptor& previous,
                                            const HeightDescriptor& current,
                                            double predicted_dx_m) {
  LongitudinalShift result;
  if (!options.IsValid(nullptr) || previous.rows != current.rows ||
      previous.cols != current.cols || previous.bin_m != current.bin_m ||
      !(previous.bin_m > 0.0) || !std::isfinite(predicted_dx_m)) {
    return result;
  }
  if (Occupied(previous) < options.min_occupied_cells ||
      Occupied(current) < options.min_occupied_cells) {
    return result;  // too empty
  }
  const double bin = previous.bin_m;
  const int k_lo = static_cast<int>(std::ceil((predicted_dx_m - options.max_shift_search_m) / bin));
  const int k_hi =
      static_cast<int>(std::floor((predicted_dx_m + options.max_shift_search_m) / bin));
  if (k_hi - k_lo < 2) return result;
  const HeightDescriptor a = Prepared(previous), b = Prepared(current);
  std::vector<double> distance(k_hi - k_lo + 1);
  for (int k = k_lo; k <= k_hi; ++k) {
    distance[k - k_lo] = HeightDescriptorDistance(a, b, k);
  }
  const int n = static_cast<int>(distance.size());
  const int best = static_cast<int>(std::min_element(distance.begin(), distance.end()) -
                                    distance.begin());
  const double d_min = distance[best];
  const double d_max = *std::max_element(distance.begin(), distance.end());
  result.distance = d_min;
  if (best == 0 || best == n - 1) return result;  // the minimum lies outside the window
  if (1.0 - d_min < options.min_score) return result;

  // Distinct: every other local minimum (beyond the best's neighbours) lies clearly higher.
  double runner_up = std::numeric_limits<double>::infinity();
  for (int i = 1; i + 1 < n; ++i) {
    if (std::abs(i - best) <= 1) continue;
    if (distance[i] <= distance[i - 1] && distance[i] <= distance[i + 1])
      runner_up = std::min(runner_up, distance[i]);
  }
  if (runner_up - d_min < options.min_distinctness * (d_max - d_min)) return result;

  // Sub-bin refinement: a parabola through the best shift and its neighbours.
  const double dm = distance[best - 1], dp = distance[best + 1];
  const double curvature = dm - 2.0 * d_min + dp;  // second difference, per bin^2
  if (!(curvature > 1e-9)) return result;
  const double offset = std::clamp(0.5 * (dm - dp) / curvature, -0.5, 0.5);
  result.dx_m = (k_lo + best + offset) * bin;
  result.distance = std::max(0.0, d_min - 0.25 * (dm - dp) * offset);
  // The shift at which the parabola rises by the residual distance at the optimum.
  const double curvature_m = curvature / (bin * bin);
  result.sigma_m = std::max(options.min_sigma_m, std::sqrt(2.0 * result.distance / curvature_m));
  result.ok = true;
  return result;
}

}  // namespace raillomer
