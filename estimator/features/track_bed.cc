#include "estimator/features/track_bed.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>

#include "estimator/features/rail_extraction.h"

namespace raillomer {

bool TrackBedOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* what) {
    if (error) *error = what;
    return false;
  };
  if (!(sigma_m >= 0.0)) return fail("sigma_m must be >= 0 (0 = off)");
  if (!(min_forward_m >= 0.0 && max_forward_m > min_forward_m + 1.0))
    return fail("forward range must satisfy 0 <= min_forward_m < max_forward_m - 1");
  if (!(half_width_m > 0.05)) return fail("half_width_m must be > 0.05");
  if (!(min_depth_m >= 0.0 && max_depth_m > min_depth_m))
    return fail("depth range must satisfy 0 <= min_depth_m < max_depth_m");
  if (!(bin_m > 0.0 && bin_m <= 0.05)) return fail("bin_m must be in (0, 0.05]");
  if (!(depth_bin_m > 0.0)) return fail("depth_bin_m must be > 0");
  if (!(blur_m >= 0.0)) return fail("blur_m must be >= 0");
  if (!(max_search_m >= 2.0 * bin_m && max_search_m < 0.3))
    return fail("max_search_m must be in [2 bin_m, 0.3) (sleepers repeat every 0.6 m)");
  if (history_frames < 1) return fail("history_frames must be >= 1");
  if (min_points < 10) return fail("min_points must be >= 10");
  if (!(min_gain > 0.0)) return fail("min_gain must be > 0");
  return true;
}

std::vector<Eigen::Vector3f> SelectTrackBed(const TrackBedOptions& options,
                                            const RailExtraction& rails,
                                            const std::vector<Eigen::Vector3f>& points_body) {
  std::vector<Eigen::Vector3f> out;
  if (!rails.ok) return out;
  Eigen::Vector3d along = rails.left_direction;
  if (along.dot(rails.right_direction) < 0.0)
    along -= rails.right_direction;
  else
    along += rails.right_direction;
  if (along.x() < 0.0) along = -along;
  along.z() = 0.0;
  if (along.norm() < 1e-6) return out;
  along.normalize();
  const Eigen::Vector3d centre = 0.5 * (rails.left_point + rails.right_point);
  for (const Eigen::Vector3f& q : points_body) {
    const Eigen::Vector3d p = q.cast<double>();
    if (p.x() < options.min_forward_m || p.x() > options.max_forward_m) continue;
    const double depth = -(rails.normal.dot(p) + rails.distance);
    if (depth < options.min_depth_m || depth > options.max_depth_m) continue;
    Eigen::Vector3d off = p - centre;
    off.z() = 0.0;
    if ((off - along.dot(off) * along).norm() > options.half_width_m) continue;
    out.push_back(q);
  }
  return out;
}

namespace {

/// The reference's point density over (along-track bin, depth bin) cells, s_min the along
/// coordinate of bin 0.
struct BedGrid {
  double s_min = 0.0;
  int ns = 0, nd = 0;
  std::vector<double> values;

  double& at(int s, int d) { return values[static_cast<size_t>(s) * nd + d]; }
  double at(int s, int d) const { return values[static_cast<size_t>(s) * nd + d]; }
};

/// A current point over the reference's span: fractional along bin and depth bin.
struct BedCell {
  double s;
  int d;
};

/// The depth below the plane n . x + d = 0.
struct PlaneDepth {
  Eigen::Vector3d normal;
  double distance;
  double operator()(const Eigen::Vector3d& p) const { return -(normal.dot(p) + distance); }
};

/// The depth bin of `depth`, or nullopt outside the depth band.
std::optional<int> DepthBin(const TrackBedOptions& options, double depth) {
  if (depth < options.min_depth_m || depth > options.max_depth_m) return std::nullopt;
  return static_cast<int>(std::lround((depth - options.min_depth_m) / options.depth_bin_m));
}

/// Point counts of the reference per cell, over its span widened by `margin` each way.
BedGrid CountReference(const TrackBedOptions& options,
                       const std::vector<Eigen::Vector3d>& reference,
                       const PlaneDepth& depth_of,
                       double s_min,
                       int ns) {
  BedGrid grid;
  grid.s_min = s_min;
  grid.ns = ns;
  grid.nd = static_cast<int>(
                std::ceil((options.max_depth_m - options.min_depth_m) / options.depth_bin_m)) +
            1;
  grid.values.assign(static_cast<size_t>(grid.ns) * grid.nd, 0.0);
  for (const Eigen::Vector3d& p : reference) {
    const std::optional<int> d = DepthBin(options, depth_of(p));
    if (!d) continue;
    const int s = static_cast<int>(std::lround((p.x() - s_min) / options.bin_m));
    if (s >= 0 && s < grid.ns && *d >= 0 && *d < grid.nd) grid.at(s, *d) += 1.0;
  }
  return grid;
}

/// Smooths the counts along the track with a Gaussian of blur_m and across depth with
/// [1 2 1] / 4; returns the densest cell's value.
double SmoothGrid(const TrackBedOptions& options, BedGrid* grid) {
  const int ns = grid->ns, nd = grid->nd;
  const int radius = static_cast<int>(std::ceil(3.0 * options.blur_m / options.bin_m));
  std::vector<double> kernel(static_cast<size_t>(2 * radius + 1), 0.0);
  for (int k = -radius; k <= radius; ++k) {
    const double x = k * options.bin_m / std::max(options.blur_m, 1e-9);
    kernel[static_cast<size_t>(k + radius)] =
        options.blur_m > 0.0 ? std::exp(-0.5 * x * x) : (k == 0 ? 1.0 : 0.0);
  }
  std::vector<double> smooth(grid->values.size(), 0.0);
  for (int s = 0; s < ns; ++s) {
    for (int d = 0; d < nd; ++d) {
      double sum = 0.0;
      for (int k = -radius; k <= radius; ++k) {
        const int t = s + k;
        if (t >= 0 && t < ns) sum += kernel[static_cast<size_t>(k + radius)] * grid->at(t, d);
      }
      smooth[static_cast<size_t>(s) * nd + d] = sum;
    }
  }
  double peak = 0.0;
  for (int s = 0; s < ns; ++s) {
    for (int d = 0; d < nd; ++d) {
      const double up = d > 0 ? smooth[static_cast<size_t>(s) * nd + d - 1] : 0.0;
      const double down = d + 1 < nd ? smooth[static_cast<size_t>(s) * nd + d + 1] : 0.0;
      grid->at(s, d) = 0.25 * up + 0.5 * smooth[static_cast<size_t>(s) * nd + d] + 0.25 * down;
      peak = std::max(peak, grid->at(s, d));
    }
  }
  return peak;
}

/// The current points within [lo, hi] along the track and in the depth band, as cells.
std::vector<BedCell> CurrentCells(const TrackBedOptions& options,
                                  const std::vector<Eigen::Vector3d>& current,
                                  const PlaneDepth& depth_of,
                                  double s_min,
                                  double lo,
                                  double hi) {
  std::vector<BedCell> cells;
  for (const Eigen::Vector3d& p : current) {
    if (p.x() < lo || p.x() > hi) continue;
    const std::optional<int> d = DepthBin(options, depth_of(p));
    if (d) cells.push_back({(p.x() - s_min) / options.bin_m, *d});
  }
  return cells;
}

/// Turns the density into log-density relative to `peak`, only over the columns a search of
/// +-steps bins reads, with bins to spare for rounding (the grid spans every reference frame,
/// most of them behind what this frame sees).
void ToLogDensity(const std::vector<BedCell>& cells, int steps, double peak, BedGrid* grid) {
  double c_min = 1e300, c_max = -1e300;
  for (const BedCell& c : cells) {
    c_min = std::min(c_min, c.s);
    c_max = std::max(c_max, c.s);
  }
  const int read_lo = std::clamp(static_cast<int>(std::floor(c_min)) - steps - 2, 0, grid->ns - 1);
  const int read_hi = std::clamp(static_cast<int>(std::floor(c_max)) + steps + 2, 0, grid->ns - 1);
  for (int t = read_lo; t <= read_hi; ++t) {
    for (int d = 0; d < grid->nd; ++d) grid->at(t, d) = std::log(0.02 + grid->at(t, d) / peak);
  }
}

/// The cells' mean log-density with every cell moved by `shift_bins`, interpolated along.
double ShiftScore(const BedGrid& grid, const std::vector<BedCell>& cells, double shift_bins) {
  double sum = 0.0;
  for (const BedCell& c : cells) {
    const double s = c.s + shift_bins;
    const int s0 = static_cast<int>(std::floor(s));
    const double f = s - s0;
    const int s1 = std::clamp(s0 + 1, 0, grid.ns - 1);
    const int sc = std::clamp(s0, 0, grid.ns - 1);
    const int d = std::clamp(c.d, 0, grid.nd - 1);
    sum += (1.0 - f) * grid.at(sc, d) + f * grid.at(s1, d);
  }
  return sum / static_cast<double>(cells.size());
}

/// Places the maximum of the scores of shifts -steps..steps bins (a parabola through the best
/// and its neighbours) and its sigma into `out`; false, with the failure, when there is none.
bool PlaceMaximum(const TrackBedOptions& options,
                  const std::vector<double>& scores,
                  int steps,
                  size_t cells,
                  TrackBedShift* out) {
  int best = 0;
  double mean = 0.0;
  for (size_t k = 0; k < scores.size(); ++k) {
    mean += scores[k];
    if (scores[k] > scores[static_cast<size_t>(best)]) best = static_cast<int>(k);
  }
  mean /= static_cast<double>(scores.size());
  out->gain = scores[static_cast<size_t>(best)] - mean;
  if (best == 0 || best == 2 * steps) {
    out->failure = "best shift at the edge of the search";
    return false;
  }
  if (out->gain < options.min_gain) {
    out->failure = "score too flat (gain " + std::to_string(out->gain) + "): no sleepers in view";
    return false;
  }
  const double a = scores[static_cast<size_t>(best - 1)], b = scores[static_cast<size_t>(best)],
               c = scores[static_cast<size_t>(best + 1)];
  const double curvature = a - 2.0 * b + c;  // per bin^2, negative at a maximum
  if (!(curvature < 0.0)) {
    out->failure = "no maximum";
    return false;
  }
  const double offset = std::clamp(0.5 * (a - c) / curvature, -0.5, 0.5);
  out->shift_m = (best - steps + offset) * options.bin_m;
  // Each point's mean log-density as its log-likelihood: the information is N |L''|.
  const double info = static_cast<double>(cells) * -curvature / (options.bin_m * options.bin_m);
  out->sigma_m = 1.0 / std::sqrt(info);
  return true;
}

}  // namespace

TrackBedShift EstimateTrackBedShift(const TrackBedOptions& options,
                                    const std::vector<Eigen::Vector3d>& reference,
                                    const std::vector<Eigen::Vector3d>& current,
                                    const Eigen::Vector3d& plane_normal,
                                    double plane_distance) {
  TrackBedShift out;
  if (static_cast<int>(reference.size()) < options.min_points) {
    out.failure = "reference has " + std::to_string(reference.size()) + " bed points";
    return out;
  }
  const PlaneDepth depth_of{plane_normal, plane_distance};
  double s_min = 1e9, s_max = -1e9;
  for (const Eigen::Vector3d& p : reference) {
    s_min = std::min(s_min, p.x());
    s_max = std::max(s_max, p.x());
  }
  const double margin = options.max_search_m + 3.0 * options.blur_m + options.bin_m;
  s_min -= margin;
  s_max += margin;
  const int ns = static_cast<int>(std::ceil((s_max - s_min) / options.bin_m)) + 1;
  if (ns > 100000) {
    out.failure = "reference spans too far along the track";
    return out;
  }
  // The reference's density, relative to its densest cell.
  BedGrid grid = CountReference(options, reference, depth_of, s_min, ns);
  const double peak = SmoothGrid(options, &grid);
  if (!(peak > 0.0)) {
    out.failure = "reference has no points in the depth band";
    return out;
  }
  const std::vector<BedCell> cells =
      CurrentCells(options, current, depth_of, s_min, s_min + margin, s_max - margin);
  out.points = static_cast<int>(cells.size());
  if (out.points < options.min_points) {
    out.failure = "frame has " + std::to_string(out.points) + " bed points over the reference";
    return out;
  }
  const int steps = static_cast<int>(std::lround(options.max_search_m / options.bin_m));
  ToLogDensity(cells, steps, peak, &grid);
  std::vector<double> scores(static_cast<size_t>(2 * steps + 1));
  for (int k = -steps; k <= steps; ++k) {
    scores[static_cast<size_t>(k + steps)] = ShiftScore(grid, cells, k);
  }
  out.ok = PlaceMaximum(options, scores, steps, cells.size(), &out);
  return out;
}

}  // namespace raillomer
