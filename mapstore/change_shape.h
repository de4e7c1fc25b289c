#pragma once

// The shape of a changed object's voxels (a stretch's frame, z up): what tells a tree and where
// its trunk stands.
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "mapstore/run_comparison.h"

namespace raillomer::mapstore {

/// The lowest and highest voxel's height.
std::pair<double, double> HeightRange(const std::vector<Eigen::Vector3d>& voxels);

/// The horizontal box of the voxels between two heights.
Eigen::AlignedBox2d BoxBetween(const std::vector<Eigen::Vector3d>& voxels, double z0, double z1);

/// A tree's shape: a crown high up, wider than what carries it (a trunk, or nothing seen: a
/// crown with nothing under it). Boxes, wagons and fallen trees stand or lie low. `c` gives the
/// heights above the rail and the size.
bool TreeShaped(const RunChange& c, const std::vector<Eigen::Vector3d>& voxels);

/// A tree's centre is its trunk: a train sees a crown from the side it comes from, its far
/// side seldom, but the trunk under it whole. The trunk is the lowest third of a tree-shaped
/// object when that is at most `trunk_m` wide; false if there is none.
bool TrunkCentre(const RunChange& c,
                 const std::vector<Eigen::Vector3d>& voxels,
                 double trunk_m,
                 Eigen::Vector2d* centre);

}  // namespace raillomer::mapstore
