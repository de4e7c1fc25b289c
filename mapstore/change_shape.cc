#include "mapstore/change_shape.h"

#include <algorithm>
#include <limits>

namespace raillomer::mapstore {

Eigen::AlignedBox2d BoxBetween(const std::vector<Eigen::Vector3d>& voxels, double z0, double z1) {
  Eigen::AlignedBox2d box;
  for (const Eigen::Vector3d& v : voxels)
    if (v.z() >= z0 && v.z() <= z1) box.extend(v.head<2>());
  return box;
}

namespace {

/// The widest horizontal side of the voxels between two heights.
double WidthBetween(const std::vector<Eigen::Vector3d>& voxels, double z0, double z1) {
  const Eigen::AlignedBox2d box = BoxBetween(voxels, z0, z1);
  return box.isEmpty() ? 0.0 : box.sizes().maxCoeff();
}

}  // namespace

std::pair<double, double> HeightRange(const std::vector<Eigen::Vector3d>& voxels) {
  double z0 = std::numeric_limits<double>::infinity(), z1 = -z0;
  for (const Eigen::Vector3d& v : voxels) {
    z0 = std::min(z0, v.z());
    z1 = std::max(z1, v.z());
  }
  return {z0, z1};
}

bool TreeShaped(const RunChange& c, const std::vector<Eigen::Vector3d>& voxels) {
  if (c.height_above_rail_max_m < 2.5 || c.size_m.z() < 1.0) return false;
  const auto [z0, z1] = HeightRange(voxels);
  const double third = (z1 - z0) / 3.0;
  const double top = WidthBetween(voxels, z1 - third, z1);
  const double bottom = WidthBetween(voxels, z0, z0 + third);
  const bool floating = c.height_above_rail_min_m >= 1.5 && top >= 1.0;
  return floating || (top >= 1.5 && top >= 2.0 * bottom);
}

bool TrunkCentre(const RunChange& c,
                 const std::vector<Eigen::Vector3d>& voxels,
                 double trunk_m,
                 Eigen::Vector2d* centre) {
  if (!TreeShaped(c, voxels)) return false;
  const auto [z0, z1] = HeightRange(voxels);
  const Eigen::AlignedBox2d trunk = BoxBetween(voxels, z0, z0 + (z1 - z0) / 3.0);
  if (trunk.isEmpty() || trunk.sizes().maxCoeff() > trunk_m) return false;
  *centre = trunk.center();
  return true;
}

}  // namespace raillomer::mapstore
