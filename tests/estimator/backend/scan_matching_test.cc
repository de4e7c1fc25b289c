#include "estimator/backend/scan_matching.h"

#include <random>

#include <gtest/gtest.h>

#include "estimator/factors/lidar_factors.h"
#include "estimator/factors/pose_manifold.h"
#include "tests/support/poses.h"

namespace raillomer {
namespace {

Eigen::Isometry3d Pose(double x, double y, double z, double roll, double pitch, double yaw) {
  return test::PoseYpr(Eigen::Vector3d(x, y, z), yaw, pitch, roll);
}

/// World: ground z = 0, walls y = +-6, a cross wall x = 40, and vertical poles (edges).
struct World {
  std::vector<Eigen::Vector3d> planes, edges;
};

World MakeWorld(bool with_cross_wall, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  World w;
  for (int i = 0; i < 6000; ++i) {
    const double x = -10.0 + 60.0 * u(rng);
    w.planes.emplace_back(x, -6.0 + 12.0 * u(rng), 0.0);
    w.planes.emplace_back(x, 6.0, 6.0 * u(rng));
    w.planes.emplace_back(x, -6.0, 6.0 * u(rng));
    if (with_cross_wall) w.planes.emplace_back(40.0, -6.0 + 12.0 * u(rng), 6.0 * u(rng));
  }
  for (double x = 0.0; x < 50.0; x += 7.0) {
    for (int i = 0; i < 60; ++i) w.edges.emplace_back(x, 5.0, 6.0 * u(rng));
  }
  return w;
}

FeatureSet ScanFrom(const World& w, const Eigen::Isometry3d& T_world_body, int stride) {
  FeatureSet f;
  const Eigen::Isometry3d T_body_world = T_world_body.inverse();
  for (size_t i = 0; i < w.planes.size(); i += static_cast<size_t>(stride)) {
    f.planes.push_back((T_body_world * w.planes[i]).cast<float>());
  }
  for (size_t i = 0; i < w.edges.size(); i += 3)
    f.edges.push_back((T_body_world * w.edges[i]).cast<float>());
  return f;
}

TEST(ScanMatching, RecoversAKnownPose) {
  const World w = MakeWorld(true, 3);
  LocalMap edges(1.0, 20), planes(1.0, 20);
  edges.Add(w.edges);
  planes.Add(w.planes);
  const Eigen::Isometry3d truth = Pose(12.0, 0.4, 0.2, 0.01, -0.02, 0.05);
  const FeatureSet scan = ScanFrom(w, truth, 7);
  Eigen::Isometry3d guess = truth * Pose(0.3, -0.2, 0.1, 0.005, 0.004, -0.01);
  LidarOnlySolution solution;
  for (int round = 0; round < 4; ++round) {
    const LidarMatches m = MatchFeatures(MatchOptions{}, scan, guess, edges, planes);
    ASSERT_GT(m.planes.size(), 500u);
    ASSERT_GT(m.lines.size(), 20u);
    solution = SolveLidarOnly(m, guess, 10);
    guess = solution.T_world_body;
  }
  const Eigen::Isometry3d error = truth.inverse() * solution.T_world_body;
  EXPECT_LT(error.translation().norm(), 0.01);
  EXPECT_LT(Eigen::AngleAxisd(error.linear()).angle(), 1e-3);
  EXPECT_GT(solution.degeneracy, 0.02);
}

TEST(ScanMatching, FlagsALongCorridorAsDegenerate) {
  // No cross wall: nothing fixes the position along x.
  const World w = MakeWorld(false, 4);
  World planes_only = w;
  planes_only.edges.clear();
  LocalMap edges(1.0, 20), planes(1.0, 20);
  planes.Add(planes_only.planes);
  const Eigen::Isometry3d truth = Pose(12.0, 0.0, 0.0, 0.0, 0.0, 0.0);
  const FeatureSet scan = ScanFrom(planes_only, truth, 7);
  const LidarMatches m = MatchFeatures(MatchOptions{}, scan, truth, edges, planes);
  const LidarOnlySolution solution = SolveLidarOnly(m, truth, 5);
  EXPECT_LT(solution.degeneracy, 0.01);  // vs > 0.02 with the cross wall
  EXPECT_GT(std::abs(solution.weakest_direction.x()), 0.99);
}

TEST(ScanMatching, AnEdgeOnScatteredNeighboursIsNotMatched) {
  // Two edge lines along x: a sharp one (a mast's corner turned on its side) and a soft crease
  // whose points scatter by 10 cm across it. Both pass the eigenvalue-ratio test of a line.
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<Eigen::Vector3d> map_points;
  for (double x = 0.0; x < 10.0; x += 0.3) {
    map_points.emplace_back(x, 2.0 + 0.003 * n(rng), 0.003 * n(rng));
    map_points.emplace_back(x, -2.0 + 0.1 * n(rng), 0.1 * n(rng));
  }
  LocalMap edges(1.0, 10), planes(1.0, 10);
  edges.Add(map_points);
  FeatureSet scan;
  scan.edges.emplace_back(5.05f, 2.0f, 0.0f);
  scan.edges.emplace_back(5.05f, -2.0f, 0.0f);
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  EXPECT_EQ(MatchFeatures(MatchOptions{}, scan, I, edges, planes).lines.size(), 2u);
  MatchOptions tight;
  tight.line_max_spread_m = 0.05;
  const LidarMatches m = MatchFeatures(tight, scan, I, edges, planes);
  ASSERT_EQ(m.lines.size(), 1u);
  EXPECT_NEAR(m.lines[0].p_body.y(), 2.0, 1e-6);
  EXPECT_GT(std::abs(m.lines[0].direction.x()), 0.99);
  // With the soft check instead both are matched, and the crease is marked soft.
  MatchOptions soft;
  soft.line_soft_spread_m = 0.05;
  const LidarMatches both = MatchFeatures(soft, scan, I, edges, planes);
  ASSERT_EQ(both.lines.size(), 2u);
  for (const LineMatch& line : both.lines) EXPECT_EQ(line.soft, line.p_body.y() < 0.0);
}

/// Sum of squared residuals of `cost` at pose T.
double CostAt(const ceres::CostFunction& cost, const Eigen::Isometry3d& T) {
  double pose[7];
  Eigen::Map<Eigen::Vector3d> position(pose);
  Eigen::Map<Eigen::Quaterniond> rotation(pose + 3);
  position = T.translation();
  rotation = Eigen::Quaterniond(T.linear());
  const double* blocks[1] = {pose};
  Eigen::VectorXd r(cost.num_residuals());
  EXPECT_TRUE(cost.Evaluate(blocks, r.data(), nullptr));
  return r.squaredNorm();
}

/// The sideways offset (body y) from T that minimises `cost` with the rotation held at T's:
/// the vertex of the parabola through three offsets.
double SidewaysOptimum(const ceres::CostFunction& cost, const Eigen::Isometry3d& T) {
  const double h = 0.05;
  auto at = [&](double y) {
    Eigen::Isometry3d moved = T;
    moved.translation() += T.linear().col(1) * y;
    return CostAt(cost, moved);
  };
  const double c_minus = at(-h), c0 = at(0.0), c_plus = at(h);
  return 0.5 * h * (c_minus - c_plus) / (c_minus - 2.0 * c0 + c_plus);
}

// A frame whose matches would turn it 3 mrad from its prediction (a registration's pull)
// and whose walls are all seen ahead. Held at the prediction's heading, those walls are
// best met by moving the frame sideways by the turn times their distance ahead; at the
// heading's profile (where the matches would turn it for the rest of the pose) the sideways
// optimum stays where the matches put the frame.
TEST(ScanMatching, AHeadingLeftOutIsProfiledNotHeld) {
  const Eigen::Isometry3d truth = Pose(12.0, 0.0, 0.0, 0.0, 0.0, 0.003);
  const Eigen::Isometry3d prediction = Pose(12.0, 0.0, 0.0, 0.0, 0.0, 0.0);
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  LidarMatches m;
  auto add = [&](const Eigen::Vector3d& world, const Eigen::Vector3d& normal) {
    m.planes.push_back({truth.inverse() * world, normal, -normal.dot(world)});
  };
  for (int i = 0; i < 400; ++i) {
    const double x = 17.0 + 25.0 * u(rng);  // 5-30 m ahead
    add({x, 6.0, 6.0 * u(rng)}, Eigen::Vector3d::UnitY());
    add({x, -6.0, 6.0 * u(rng)}, -Eigen::Vector3d::UnitY());
    add({x, -6.0 + 12.0 * u(rng), 0.0}, Eigen::Vector3d::UnitZ());
    add({60.0, -6.0 + 12.0 * u(rng), 6.0 * u(rng)}, -Eigen::Vector3d::UnitX());
  }
  const LidarOnlySolution frame = SolveLidarOnly(m, prediction, 1);
  EXPECT_NEAR(frame.heading_z0, 0.003, 1e-4);
  std::vector<PlaneTerm> terms;
  for (const PlaneMatch& p : m.planes) terms.push_back({p.p_body, p.normal, p.d, 1.0});
  const auto cost = std::make_shared<LidarFrameCost>(terms, std::vector<LineTerm>{}, 10.0);
  PoseRemapping held;
  held.q0 = Eigen::Quaterniond(prediction.linear());
  PoseRemapping profiled = held;
  profiled.heading_z0 = frame.heading_z0;
  profiled.heading_gain = frame.heading_gain;
  profiled.heading_p_ref = prediction.translation();
  // Walls 17-42 m out from the frame: the held heading moves it about 8 cm sideways.
  EXPECT_GT(std::abs(SidewaysOptimum(RemappedPoseCost(cost, held), prediction)), 0.05);
  EXPECT_LT(std::abs(SidewaysOptimum(RemappedPoseCost(cost, profiled), prediction)), 0.002);
}

TEST(ScanMatching, NoMatchesAgainstAnEmptyMap) {
  LocalMap edges(1.0, 20), planes(1.0, 20);
  FeatureSet scan;
  scan.planes.push_back(Eigen::Vector3f(1, 2, 3));
  const LidarMatches m =
      MatchFeatures(MatchOptions{}, scan, Eigen::Isometry3d::Identity(), edges, planes);
  EXPECT_EQ(m.size(), 0u);
  const LidarOnlySolution s = SolveLidarOnly(m, Eigen::Isometry3d::Identity(), 5);
  EXPECT_FALSE(s.converged);
  EXPECT_EQ(s.degeneracy, 0.0);
}

}  // namespace
}  // namespace raillomer
