#include "estimator/backend/local_map.h"

#include <algorithm>
#include <random>

#include <gtest/gtest.h>

namespace raillomer {
namespace {

std::vector<Eigen::Vector3d> RandomPoints(int n, double extent, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-extent, extent);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < n; ++i) points.emplace_back(u(rng), u(rng), u(rng));
  return points;
}

TEST(LocalMap, KNearestMatchesBruteForce) {
  // A coarse cloud (spacing well above a quarter voxel) so that every point is kept.
  LocalMap map(1.0, 50);
  const std::vector<Eigen::Vector3d> points = RandomPoints(3000, 10.0, 1);
  map.Add(points);
  std::vector<Eigen::Vector3d> kept;
  // Recover what the map kept by querying each point with radius ~0.
  Eigen::Vector3d out[16];
  for (const Eigen::Vector3d& p : points) {
    if (map.KNearest(p, 1, 1e-9, out) == 1) kept.push_back(p);
  }
  EXPECT_EQ(kept.size(), map.num_points());
  EXPECT_GT(kept.size(), 2500u);
  for (const Eigen::Vector3d& q : RandomPoints(200, 9.0, 2)) {
    std::vector<double> d;
    for (const Eigen::Vector3d& p : kept) d.push_back((p - q).norm());
    std::sort(d.begin(), d.end());
    const int found = map.KNearest(q, 5, 1.0, out);
    const int expected =
        static_cast<int>(std::count_if(d.begin(), d.end(), [](double x) { return x <= 1.0; }));
    ASSERT_EQ(found, std::min(5, expected));
    for (int i = 0; i < found; ++i)
      EXPECT_NEAR((out[i] - q).norm(), d[static_cast<size_t>(i)], 1e-12);
  }
}

TEST(LocalMap, CapsPointsPerVoxelAndSpacing) {
  LocalMap map(1.0, 5);
  std::vector<Eigen::Vector3d> dense;
  for (int i = 0; i < 1000; ++i) dense.emplace_back(0.001 * i, 0.5, 0.5);  // inside one voxel row
  map.Add(dense);
  EXPECT_LE(map.num_points(), 5u);
  EXPECT_EQ(map.num_voxels(), 1u);
  // Points closer than a quarter voxel to a kept one are skipped.
  LocalMap spaced(1.0, 100);
  spaced.Add({Eigen::Vector3d(0.1, 0.1, 0.1),
              Eigen::Vector3d(0.2, 0.1, 0.1),
              Eigen::Vector3d(0.6, 0.6, 0.6)});
  EXPECT_EQ(spaced.num_points(), 2u);
}

TEST(LocalMap, RemoveFarBoundsTheMap) {
  LocalMap map(1.0, 10);
  std::vector<Eigen::Vector3d> line;
  for (int i = 0; i < 2000; ++i) line.emplace_back(static_cast<double>(i), 0.0, 0.0);
  map.Add(line);
  EXPECT_EQ(map.num_points(), 2000u);
  map.RemoveFar(Eigen::Vector3d(1000.0, 0.0, 0.0), 100.0);
  EXPECT_LE(map.num_points(), 202u);
  EXPECT_GE(map.num_points(), 198u);
  Eigen::Vector3d out[4];
  EXPECT_EQ(map.KNearest(Eigen::Vector3d(10.0, 0.0, 0.0), 1, 1.0, out), 0);
  EXPECT_EQ(map.KNearest(Eigen::Vector3d(1000.2, 0.0, 0.0), 1, 1.0, out), 1);
}

TEST(LocalMap, NegativeCoordinatesHashApart) {
  LocalMap map(1.0, 10);
  map.Add({Eigen::Vector3d(-0.5, -0.5, -0.5), Eigen::Vector3d(0.5, 0.5, 0.5)});
  EXPECT_EQ(map.num_voxels(), 2u);
  Eigen::Vector3d out[2];
  ASSERT_EQ(map.KNearest(Eigen::Vector3d(-0.4, -0.5, -0.5), 1, 0.5, out), 1);
  EXPECT_NEAR(out[0].x(), -0.5, 1e-12);
}

}  // namespace
}  // namespace raillomer
