#pragma once

#include <string>

#include "estimator/preprocess/scan.h"

namespace raillomer {

/// Options of the LOAM edge / plane selection (paper IV.C, after Zhang and Singh).
struct LoamFeatureOptions {
  int curvature_half_window = 5;  ///< neighbours on each side along a laser line
  int sectors_per_line = 8;       ///< each line is cut into this many equal parts
  int max_edges_per_sector = 4;
  int max_planes_per_sector = 40;
  double edge_curvature_min = 0.1;   ///< smoothness above this: edge candidate
  double plane_curvature_max = 0.02;  ///< smoothness below this: plane candidate
  double plane_voxel_m = 0.6;        ///< planar points are thinned on this voxel grid
  double edge_voxel_m = 0.3;
  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// Edge and planar feature points of a deskewed scan (body frame), by curvature along each laser
/// line; points next to occlusions or seen at grazing incidence are not selected.
FeatureSet ExtractLoamFeatures(const LoamFeatureOptions& options, const Scan& scan);

}  // namespace raillomer
