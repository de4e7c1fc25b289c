// The shape of a changed object's voxels: a tree seen from the side a train comes from (its
// crown's near half and its trunk) is centred on the trunk, not on what was seen of the crown;
// a box and a fallen tree are not trees; a crown with no trunk seen keeps its own centre.
#include <gtest/gtest.h>

#include "mapstore/change_shape.h"

namespace raillomer::mapstore {
namespace {

constexpr double kVoxel = 0.1;

/// A trunk 0.3 m thick at (x, y) from the ground to `top`.
void AddTrunk(double x, double y, double top, std::vector<Eigen::Vector3d>* voxels) {
  for (double z = 0.05; z < top; z += kVoxel)
    for (double dx = -0.1; dx <= 0.1; dx += kVoxel) voxels->emplace_back(x + dx, y, z);
}

/// The half of a round crown (radius r, centred at c) that faces -x, where the train comes
/// from: its far half hidden.
void AddNearHalfCrown(const Eigen::Vector3d& c, double r, std::vector<Eigen::Vector3d>* voxels) {
  for (double x = -r; x <= 0.0; x += kVoxel)
    for (double y = -r; y <= r; y += kVoxel)
      for (double z = -r; z <= r; z += kVoxel) {
        const double d = std::sqrt(x * x + y * y + z * z);
        if (d <= r && d > r - kVoxel) voxels->push_back(c + Eigen::Vector3d(x, y, z));
      }
}

/// What Place() gives: heights above the rail (the rail plane at z = 0) and the size.
RunChange Placed(const std::vector<Eigen::Vector3d>& voxels) {
  RunChange c;
  const auto [z0, z1] = HeightRange(voxels);
  c.height_above_rail_min_m = z0;
  c.height_above_rail_max_m = z1;
  Eigen::AlignedBox3d box;
  for (const Eigen::Vector3d& v : voxels) box.extend(v);
  c.size_m = box.sizes().array() + kVoxel;
  return c;
}

TEST(ChangeShape, ATreeSeenFromOneSideIsCentredOnItsTrunk) {
  std::vector<Eigen::Vector3d> tree;
  AddTrunk(10.0, 4.0, 4.0, &tree);
  AddNearHalfCrown({10.0, 4.0, 5.5}, 2.0, &tree);
  const RunChange c = Placed(tree);
  ASSERT_TRUE(TreeShaped(c, tree));
  Eigen::Vector2d centre;
  ASSERT_TRUE(TrunkCentre(c, tree, 1.0, &centre));
  EXPECT_LT((centre - Eigen::Vector2d(10.0, 4.0)).norm(), 0.1) << centre.transpose();
  // What was seen of it is centred a metre short of the trunk.
  Eigen::AlignedBox3d seen;
  for (const Eigen::Vector3d& v : tree) seen.extend(v);
  EXPECT_GT(std::abs(seen.center().x() - 10.0), 0.8);
}

TEST(ChangeShape, ACrownWithNoTrunkSeenKeepsItsOwnCentre) {
  std::vector<Eigen::Vector3d> crown;
  AddNearHalfCrown({10.0, 4.0, 5.5}, 2.0, &crown);
  const RunChange c = Placed(crown);
  EXPECT_TRUE(TreeShaped(c, crown));  // floating: a crown with nothing under it
  Eigen::Vector2d centre;
  // Its lowest third is the crown's own underside, wider than a trunk.
  EXPECT_FALSE(TrunkCentre(c, crown, 1.0, &centre));
}

TEST(ChangeShape, BoxesAndFallenTreesAreNotTrees) {
  std::vector<Eigen::Vector3d> box;
  for (double x = 0.05; x < 1.4; x += kVoxel)
    for (double y = 0.05; y < 1.4; y += kVoxel)
      for (double z = 0.05; z < 1.6; z += kVoxel) box.emplace_back(x, y, z);
  EXPECT_FALSE(TreeShaped(Placed(box), box));
  // A trunk lying across the track with its crown at one end, low.
  std::vector<Eigen::Vector3d> fallen;
  for (double y = -6.0; y <= 6.0; y += kVoxel) fallen.emplace_back(0.0, y, 0.25);
  AddNearHalfCrown({0.0, 8.0, 1.0}, 1.4, &fallen);
  Eigen::Vector2d centre;
  EXPECT_FALSE(TrunkCentre(Placed(fallen), fallen, 1.0, &centre));
}

}  // namespace
}  // namespace raillomer::mapstore
