#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

namespace raillomer {

/// Options of the height descriptor (paper IV.C, Fig. 7).
struct HeightDescriptorOptions {
  double x_min_m = 3.0, x_max_m = 33.0;    ///< d_x
  double y_min_m = -20.0, y_max_m = 20.0;  ///< d_y
  double bin_m = 0.5;                      ///< d_r
  double z_floor_m = -4.0;                 ///< heights are z - z_floor_m; points below are ignored
  double z_ceiling_m = 20.0;               ///< points above are ignored (outliers)
  /// A point counts only with min_support_points others within support_radius_m (0: all count).
  double support_radius_m = 0.4;
  int min_support_points = 2;
  double max_shift_search_m = 3.0;  ///< around the predicted shift
  double min_score = 0.2;           ///< mean cosine similarity below this: no measurement
  int min_occupied_cells = 20;      ///< fewer non-empty cells in either descriptor: no measurement
  /// The runner-up local minimum must lie this fraction of the distance range above the best.
  double min_distinctness = 0.2;
  double min_sigma_m = 0.08;  ///< floor of the reported standard deviation (bin quantisation)
  /// The distance valley around the optimum wider than this (m): too flat, no measurement.
  double max_valley_width_m = 1.0;
  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// A Cartesian height grid in the body frame: cell (row, col) holds the greatest height of the
/// points that fall in it (0 when empty, heights taken relative to the lowest bound, z_floor_m;
/// isolated returns do not count). Rows run across the track (y, row 0 at y_min_m), columns
/// along it (x, column 0 at x_min_m), so a longitudinal move shifts every row.
struct HeightDescriptor {
  int rows = 0, cols = 0;
  double x_min_m = 0.0, bin_m = 0.5;
  Eigen::MatrixXf cells;  ///< rows x cols
};

/// The descriptor of one deskewed frame (any LiDAR; meant for the up-looking one), body frame.
HeightDescriptor ComputeHeightDescriptor(const HeightDescriptorOptions& options,
                                         const std::vector<Eigen::Vector3f>& points_body);

/// Eq. (27): mean over rows of (1 - cosine similarity) between `a` and `b` with b's columns
/// shifted by `shift_bins` (b(x) compared with a(x + shift)); rows empty in either are skipped.
/// Over the overlapping columns, a row with returns on one side only counts as 1 and one with
/// returns on neither side is skipped. 1 when nothing is comparable.
double HeightDescriptorDistance(const HeightDescriptor& a,
                                const HeightDescriptor& b,
                                double shift_bins);

/// Longitudinal displacement between two descriptors (frame k then k+1).
struct LongitudinalShift {
  bool ok = false;
  double dx_m = 0.0;      ///< forward motion from k to k+1 (body x of frame k)
  double distance = 1.0;  ///< eq. (27) at the optimum
  double sigma_m = 0.0;   ///< from the width of the distance valley around the optimum
  std::string failure;    ///< why not ok
};

/// Searches the shift minimising eq. (27) within max_shift_search_m of `predicted_dx_m`, with
/// sub-bin refinement. No measurement (ok false, `failure` says why) when a descriptor is too
/// empty, the minimum is at the window's edge, not distinct or too flat, or at zero shift
/// (+-1 bin) while the prediction moves more than 2 bins (structure fixed in the body frame).
LongitudinalShift EstimateLongitudinalShift(const HeightDescriptorOptions& options,
                                            const HeightDescriptor& previous,
                                            const HeightDescriptor& current,
                                            double predicted_dx_m);

}  // namespace raillomer
