#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace raillomer::eval {

/// The series the plot draws; positions are relative to `origin` so UTM numbers stay small.
struct PlotData {
  std::string title;
  /// Shown in the caption of the top-down panel, e.g. "first truth pose, UTM 50N".
  std::string origin_label;
  std::vector<Eigen::Vector2d> xy_truth_m;
  std::vector<Eigen::Vector2d> xy_est_m;
  /// Translational error (m) along the truth distance (m), same length.
  std::vector<double> distance_m;
  std::vector<double> error_m;
};

/// Size and decimation of the plot.
struct SvgPlotOptions {
  int width_px = 900;
  /// Upper bound on the points of any one polyline.
  size_t max_points_per_line = 4000;
};

/// True if `path` names a format RenderSvgPlot writes (.svg); otherwise false with a message
/// naming the supported extension.
bool IsSupportedPlotPath(const std::string& path, std::string* error);

/// Renders a standalone SVG: panel 1 top-down xy of truth vs aligned estimate at equal axis
/// scale, panel 2 translational error along distance. No file I/O.
std::string RenderSvgPlot(const PlotData& data, const SvgPlotOptions& options);

/// Indices of at most max_points evenly spread over num_points, first and last included.
std::vector<size_t> DecimateEvenly(size_t num_points, size_t max_points);

/// Keeps at most max_points of a series by emitting the min and max of each bucket in order,
/// so single spikes survive.
std::vector<size_t> DecimateMinMax(const std::vector<double>& values, size_t max_points);

/// Ticks at 1, 2 or 5 times a power of ten covering [lo, hi] with about `target` intervals.
std::vector<double> NiceTicks(double lo, double hi, int target);

}  // namespace raillomer::eval
