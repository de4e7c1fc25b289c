#include "estimator/eval/association.h"

#include <cmath>

#include <gtest/gtest.h>

#include "estimator/eval/alignment.h"
#include "eval_test_util.h"

namespace raillomer::eval {
namespace {

using testing::kStartStampNs;
using testing::MakeTrajectory;
using testing::Pose;

const Eigen::Vector3d kVelocity(2.0, -1.0, 0.5);  // m/s
constexpr double kYawRate = 0.1;                  // rad/s

Eigen::Isometry3d LinearMotion(double t_s) {
  return Pose(Eigen::Vector3d(500000.0, 4000000.0, 30.0) + t_s * kVelocity, 0.3 + kYawRate * t_s);
}

TEST(EvalAssociation, InterpolationIsExactOnLinearMotion) {
  // Truth at 10 Hz; constant velocity and constant yaw rate, so linear + slerp are exact.
  const api::Trajectory truth =
      MakeTrajectory(101, 0.1, [](int i) { return LinearMotion(0.1 * i); });
  api::Trajectory estimate;
  for (int i = 0; i < 300; ++i) {
    api::StampedPose pose;
    pose.stamp_ns = kStartStampNs + 1234567 + i * 33000000LL;  // 30 Hz, off the truth's grid
    estimate.poses.push_back(pose);
  }
  const Association association = AssociatePoses(estimate, truth, AssociationOptions{});
  ASSERT_TRUE(association.ok) << association.error;
  EXPECT_EQ(association.num_skipped_gap, 0u);
  ASSERT_EQ(association.pairs.size() + association.num_skipped_outside, estimate.poses.size());
  ASSERT_GT(association.pairs.size(), 250u);
  const double t0_s = (association.pairs.front().stamp_ns - kStartStampNs) * 1e-9;
  for (const PosePair& pair : association.pairs) {
    const double t_s = (pair.stamp_ns - kStartStampNs) * 1e-9;
    const Eigen::Isometry3d expected = LinearMotion(t_s);
    EXPECT_LT((pair.T_world_truth.translation() - expected.translation()).norm(), 1e-8);
    EXPECT_LT(RotationAngle(pair.T_world_truth.linear().transpose() * expected.linear()), 1e-9);
    EXPECT_NEAR(pair.distance_m, (t_s - t0_s) * kVelocity.norm(), 1e-8);
  }
}

TEST(EvalAssociation, InterpolatePoseHitsEndpointsExactly) {
  api::StampedPose a, b;
  a.stamp_ns = 100;
  b.stamp_ns = 300;
  a.p_world = Eigen::Vector3d(1, 2, 3);
  b.p_world = Eigen::Vector3d(3, 6, 9);
  b.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitX()));
  EXPECT_EQ(InterpolatePose(a, b, 100).p_world, a.p_world);
  EXPECT_EQ(InterpolatePose(a, b, 300).p_world, b.p_world);
  const api::StampedPose mid = InterpolatePose(a, b, 200);
  EXPECT_LT((mid.p_world - Eigen::Vector3d(2, 4, 6)).norm(), 1e-12);
  EXPECT_NEAR(mid.q_world_body.angularDistance(Eigen::Quaterniond::Identity()), 0.2, 1e-12);
}

TEST(EvalAssociation, SkipsPosesOutsideTheTruthAndAcrossGaps) {
  // Truth 0..10 s at 0.1 s, except no poses strictly between 5 s and 6 s (a 1 s gap).
  api::Trajectory truth;
  for (int i = 0; i <= 100; ++i) {
    if (i > 50 && i < 60) continue;
    api::StampedPose pose;
    pose.stamp_ns = kStartStampNs + i * 100000000LL;
    pose.p_world = Eigen::Vector3d(i, 0, 0);
    truth.poses.push_back(pose);
  }
  // Estimate -1..12 s at 0.05 s: 261 poses.
  api::Trajectory estimate;
  for (int i = -20; i <= 240; ++i) {
    api::StampedPose pose;
    pose.stamp_ns = kStartStampNs + i * 50000000LL;
    estimate.poses.push_back(pose);
  }
  const Association association = AssociatePoses(estimate, truth, AssociationOptions{});
  ASSERT_TRUE(association.ok) << association.error;
  EXPECT_EQ(association.num_estimate_poses, 261u);
  EXPECT_EQ(association.num_truth_poses, 92u);
  // Before 0 s: 20 poses; after 10 s: 40 poses.
  EXPECT_EQ(association.num_skipped_outside, 60u);
  // Strictly between 5 s and 6 s: 5.05 .. 5.95 = 19 poses; 5.0 and 6.0 hit truth stamps.
  EXPECT_EQ(association.num_skipped_gap, 19u);
  EXPECT_EQ(association.num_skipped(), 79u);
  EXPECT_EQ(association.pairs.size(), 182u);

  AssociationOptions wide;
  wide.max_gap_s = 1.5;
  const Association across = AssociatePoses(estimate, truth, wide);
  EXPECT_EQ(across.num_skipped_gap, 0u);
  EXPECT_EQ(across.pairs.size(), 201u);
}

TEST(EvalAssociation, RejectsUnorderedStampsAndBadOptions) {
  const api::Trajectory truth =
      MakeTrajectory(10, 0.1, [](int i) { return LinearMotion(0.1 * i); });
  api::Trajectory estimate = truth;
  std::swap(estimate.poses[3], estimate.poses[4]);
  Association association = AssociatePoses(estimate, truth, AssociationOptions{});
  EXPECT_FALSE(association.ok);
  EXPECT_NE(association.error.find("estimate"), std::string::npos);

  AssociationOptions bad;
  bad.max_gap_s = 0.0;
  std::string error;
  EXPECT_FALSE(bad.IsValid(&error));
  EXPECT_FALSE(AssociatePoses(truth, truth, bad).ok);
}

}  // namespace
}  // namespace raillomer::eval
