// Run-to-run registration on a constructed stretch with a known offset: ground, ballast
// slopes, masts and a building, sampled twice on different grids; the second run has a box
// added and a mast gone, which must not pull the result.
#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "mapstore/run_registration.h"

namespace raillomer::mapstore {
namespace {

/// The stretch's surfaces sampled every `step` m from `phase` m in, with `noise` m of range
/// noise; `box` adds a 1.2 x 0.8 x 1.6 m box beside the track, `mast_gone` drops one mast.
std::vector<Eigen::Vector3d> Stretch(
    double step, double phase, double noise, bool box, bool mast_gone, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, noise);
  std::vector<Eigen::Vector3d> out;
  auto add = [&](const Eigen::Vector3d& p) {
    out.push_back(p + Eigen::Vector3d(n(rng), n(rng), n(rng)));
  };
  for (double x = phase; x < 80.0; x += step)
    for (double y = -15.0 + phase; y < 15.0; y += step) {
      // Ballast bed 0.35 m high within 1.75 m of the centre, 1:1.75 slopes to the formation.
      const double l = std::abs(y);
      const double z = l <= 1.75 ? 0.35 : std::max(0.0, 0.35 - (l - 1.75) / 1.75);
      add({x, y, z});
    }
  for (double mx : {10.0, 35.0, 60.0}) {
    if (mast_gone && mx == 35.0) continue;
    for (double z = phase; z < 8.0; z += step)
      for (double a = 0.0; a < 2.0 * M_PI; a += step / 0.15)
        add({mx + 0.15 * std::cos(a), 3.0 + 0.15 * std::sin(a), z});
  }
  // A building: its long wall faces the track, its end walls face along it.
  for (double z = phase; z < 6.0; z += step) {
    for (double x = 30.0 + phase; x < 45.0; x += step) add({x, 12.0, z});
    for (double y = 12.0 + phase; y < 15.0; y += step) {
      add({30.0, y, z});
      add({45.0, y, z});
    }
  }
  if (box)
    for (double x = 50.0; x < 51.2; x += step)
      for (double z = 0.0; z < 1.6; z += step) {
        add({x, -3.2, z});
        add({x, -4.0, z});
      }
  return out;
}

TEST(RunRegistration, RecoversAKnownOffsetAndChangesDoNotPullIt) {
  const std::vector<Eigen::Vector3d> reference = Stretch(0.1, 0.0, 0.01, false, false, 1);
  std::vector<Eigen::Vector3d> later = Stretch(0.1, 0.05, 0.01, true, true, 2);
  // The later run lies 1.6 m along, 0.7 m aside and 0.4 m up, turned 0.4 deg: what two SPP
  // receivers make of one place.
  Eigen::Isometry3d T_true = Eigen::Isometry3d::Identity();
  T_true.linear() =
      Eigen::AngleAxisd(0.4 * M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T_true.translation() = Eigen::Vector3d(1.6, -0.7, -0.4);  // moves the later run onto the first
  for (Eigen::Vector3d& p : later) p = T_true.inverse() * p;
  const RegistrationResult r =
      RegisterClouds(reference, later, Eigen::Isometry3d::Identity(), RegistrationOptions());
  EXPECT_TRUE(r.converged);
  // Within 2 cm: well inside the 3 cm the rails may be apart after registration.
  const Eigen::Isometry3d error = T_true.inverse() * r.T_fixed_moving;
  EXPECT_LT(error.translation().norm(), 0.02) << error.translation().transpose();
  EXPECT_LT(Eigen::AngleAxisd(error.linear()).angle(), 1e-4);
  EXPECT_LT(r.rms_m, 0.03);
  EXPECT_GT(r.translation_conditioning, 0.01);
}

TEST(RunRegistration, OneTargetRegistersAndChecksSeveralClouds) {
  const std::vector<Eigen::Vector3d> reference = Stretch(0.1, 0.0, 0.01, false, false, 1);
  const std::vector<Eigen::Vector3d> later = Stretch(0.1, 0.05, 0.01, true, true, 2);
  // Two placements of the later run, 0.8 m apart: each is registered onto the one target.
  const Eigen::Vector3d shifts[2] = {{1.2, -0.5, -0.3}, {0.4, 0.1, 0.2}};
  RegistrationTarget target(reference, RegistrationOptions());
  for (const Eigen::Vector3d& shift : shifts) {
    std::vector<Eigen::Vector3d> moved = later;
    for (Eigen::Vector3d& p : moved) p -= shift;
    const RegistrationResult alone =
        RegisterClouds(reference, moved, Eigen::Isometry3d::Identity(), RegistrationOptions());
    const RegistrationResult shared = target.Register(moved, Eigen::Isometry3d::Identity());
    EXPECT_TRUE(shared.T_fixed_moving.isApprox(alone.T_fixed_moving, 1e-12));
    EXPECT_EQ(shared.iterations, alone.iterations);
    EXPECT_LT((shared.T_fixed_moving.translation() - shift).norm(), 0.02);
  }
  std::vector<Eigen::Vector3d> second = later;
  for (Eigen::Vector3d& p : second) p -= shifts[1];
  Eigen::Isometry3d first = Eigen::Isometry3d::Identity();
  first.translation() = shifts[0];
  // Checked where it lies, the second fits closely; where the first lies, it does not.
  Eigen::Isometry3d there = Eigen::Isometry3d::Identity();
  there.translation() = shifts[1];
  const RegistrationResult fits = target.Check(second, there);
  const RegistrationResult off = target.Check(second, first);
  EXPECT_TRUE(fits.T_fixed_moving.isApprox(there));
  EXPECT_GT(fits.inliers, fits.pairs * 8 / 10);
  EXPECT_LT(fits.rms_m, 0.03);
  EXPECT_GT(off.rms_m, 0.1);
}

TEST(RunRegistration, ABareStraightCannotTellAShiftAlongTheTrack) {
  std::vector<Eigen::Vector3d> bare;
  for (double x = 0.0; x < 80.0; x += 0.1)
    for (double y = -15.0; y < 15.0; y += 0.1)
      bare.push_back(
          {x, y, std::abs(y) <= 1.75 ? 0.35 : std::max(0.0, 0.35 - (std::abs(y) - 1.75) / 1.75)});
  const RegistrationResult r =
      RegisterClouds(bare, bare, Eigen::Isometry3d::Identity(), RegistrationOptions());
  EXPECT_LT(r.translation_conditioning, 1e-3);
  std::string error;
  RegistrationOptions bad;
  bad.planarity = 0.5;
  EXPECT_FALSE(bad.IsValid(&error));
}

TEST(RunRegistration, VoxelCentroidsAverageEachVoxel) {
  const std::vector<Eigen::Vector3d> points = {
      {0.01, 0.01, 0.01}, {0.09, 0.09, 0.09}, {0.25, 0, 0}};
  const std::vector<Eigen::Vector3d> c = VoxelCentroids(points, 0.1);
  ASSERT_EQ(c.size(), 2u);
  const bool first = (c[0] - Eigen::Vector3d(0.05, 0.05, 0.05)).norm() < 1e-12;
  EXPECT_TRUE(first || (c[1] - Eigen::Vector3d(0.05, 0.05, 0.05)).norm() < 1e-12);
}

}  // namespace
}  // namespace raillomer::mapstore
