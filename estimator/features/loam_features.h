#pragma once

#include <string>

#include "estimator/preprocess/scan.h"

namespace raillomer {

/// Options of the LOAM edge / plane selection (paper IV.C, after Zhang and Singh).
struct LoamFeatureOptions {
  int curvature_half_window = 5;  ///< neighbours on each side along a laser line
  int sectors_per_line = 20;      ///< each line is cut into this many equal parts
  int max_edges_per_sector = 4;
  int max_planes_per_sector = 30;
  /// Smoothness c = |sum over the window of (p_j - p_i)|^2 / range_i^2 (LOAM's, scaled by range
  /// so that it does not grow with distance). With the Horizon's ~0.2 deg steps and a half
  /// window of 5, a right-angle corner seen at 45 deg on both faces gives about 0.01, range
  /// noise of 2 cm on a plane 10 m away about 0.0004; depth discontinuities give far more.
  double edge_curvature_min = 0.005;   ///< smoothness above this: edge candidate
  double plane_curvature_max = 0.002;  ///< smoothness below this: plane candidate
  double plane_voxel_m = 0.6;          ///< planar points are thinned on this voxel grid
  double edge_voxel_m = 0.3;           ///< edge points are thinned on this voxel grid
  /// Neighbours whose beams lie farther apart than this (returns missing between them, e.g. sky)
  /// break the line: no curvature window spans the gap.
  double gap_angle_deg = 1.0;
  /// Neighbours whose ranges differ by more than this fraction: an occlusion; the points on the
  /// far side are not selected (LOAM).
  double occlusion_depth_ratio = 0.1;
  /// Points whose two neighbours both lie farther away than a surface at this incidence angle
  /// would put them are on a surface seen at grazing incidence (LOAM's parallel beams).
  double max_incidence_deg = 75.0;
  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// Edge and planar feature points of a deskewed scan (body frame), by curvature along each laser
/// line; points next to occlusions or gaps, seen at grazing incidence, or whose window turns back
/// with the scan pattern are not selected. Uses each point's measured range_m (kept by Deskew)
/// to recover the angle between neighbouring beams.
FeatureSet ExtractLoamFeatures(const LoamFeatureOptions& options, const Scan& scan);

}  // namespace raillomer
