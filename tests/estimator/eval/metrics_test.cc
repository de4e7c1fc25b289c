#include "estimator/eval/metrics.h"

#include <cmath>

#include <gtest/gtest.h>

#include "estimator/eval/evaluation.h"
#include "eval_test_util.h"

namespace raillomer::eval {
namespace {

using testing::Pose;
using testing::Scaled;
using testing::StraightTruth;
using testing::Transformed;

constexpr double kDeg = 3.14159265358979323846 / 180.0;

std::vector<PosePair> Pairs(const api::Trajectory& estimate, const api::Trajectory& truth) {
  const Association association = AssociatePoses(estimate, truth, AssociationOptions{});
  EXPECT_TRUE(association.ok) << association.error;
  EXPECT_EQ(association.num_skipped(), 0u);
  return association.pairs;
}

TEST(EvalAte, LateralOffsetOnHalfTheRunGivesKnownFigures) {
  // 1000 poses 1 m apart; the second half is 1 m to the left: errors 500 x 0 m and 500 x 1 m.
  const api::Trajectory truth = StraightTruth(1000, 1.0, Eigen::Vector3d(500000, 4000000, 40), 0.0);
  api::Trajectory estimate = truth;
  for (size_t i = 500; i < estimate.poses.size(); ++i) estimate.poses[i].p_world.y() += 1.0;

  const std::vector<PosePair> pairs = Pairs(estimate, truth);
  const AteStats ate = ComputeAte(pairs, Eigen::Isometry3d::Identity());
  EXPECT_EQ(ate.num_poses, 1000u);
  EXPECT_NEAR(ate.rmse_m, std::sqrt(0.5), 1e-9);
  EXPECT_NEAR(ate.max_m, 1.0, 1e-9);
  EXPECT_NEAR(ate.mean_m, 0.5, 1e-9);
  EXPECT_NEAR(ate.median_m, 0.5, 1e-9);  // Even count: mean of the middle 0 and 1.
  EXPECT_EQ(ate.max_index, 500u);
  EXPECT_EQ(ate.max_stamp_ns, truth.poses[500].stamp_ns);
  EXPECT_NEAR(ate.max_distance_m, 500.0, 1e-6);
  ASSERT_EQ(ate.errors_m.size(), 1000u);
}

TEST(EvalEndDrift, OnePercentScaleErrorGivesOnePercent) {
  // 1000 m straight at heading 30 deg; the estimate runs 1% long.
  const api::Trajectory truth =
      StraightTruth(1001, 1.0, Eigen::Vector3d(500000, 4000000, 40), 30 * kDeg);
  const api::Trajectory long_estimate = Scaled(truth, 1.01);

  // Same frame and same start: no alignment needed.
  DriftStats none = ComputeEndDrift(Pairs(long_estimate, truth), AlignmentMode::kNone);
  ASSERT_TRUE(none.valid);
  EXPECT_NEAR(none.distance_m, 1000.0, 1e-6);
  EXPECT_NEAR(none.end_error_m, 10.0, 1e-6);
  EXPECT_NEAR(none.end_drift_pct, 1.0, 1e-8);

  // In a local frame (yawed and shifted): 4dof and se3 first-pose alignment undo the frame.
  const api::Trajectory local =
      Transformed(long_estimate, Pose(Eigen::Vector3d(-123.0, 456.0, -7.0), -75 * kDeg));
  for (AlignmentMode mode : {AlignmentMode::kFourDof, AlignmentMode::kSe3}) {
    const DriftStats drift = ComputeEndDrift(Pairs(local, truth), mode);
    ASSERT_TRUE(drift.valid);
    EXPECT_NEAR(drift.end_error_m, 10.0, 1e-6) << ToString(mode);
    EXPECT_NEAR(drift.end_drift_pct, 1.0, 1e-8) << ToString(mode);
  }
  // Without alignment the local frame is far off.
  EXPECT_GT(ComputeEndDrift(Pairs(local, truth), AlignmentMode::kNone).end_error_m, 1e6);
}

TEST(EvalRpe, OnePercentScaleErrorGivesOneMetrePerHundred) {
  const api::Trajectory truth = StraightTruth(301, 1.0, Eigen::Vector3d(1000, 2000, 10), 0.4);
  const api::Trajectory estimate = Scaled(truth, 1.01);
  const RpeStats rpe = ComputeRpe(Pairs(estimate, truth), RpeOptions{});
  ASSERT_TRUE(rpe.valid);
  EXPECT_EQ(rpe.num_segments, 201u);  // Starts at 0, 1, ..., 200 m.
  EXPECT_NEAR(rpe.trans_mean_m, 1.0, 1e-8);
  EXPECT_NEAR(rpe.trans_rmse_m, 1.0, 1e-8);
  EXPECT_NEAR(rpe.trans_mean_pct, 1.0, 1e-8);
  EXPECT_NEAR(rpe.trans_rmse_pct, 1.0, 1e-8);
  EXPECT_NEAR(rpe.rot_mean_deg, 0.0, 1e-9);
}

TEST(EvalRpe, ConstantYawDriftGivesKnownDegreesPerSegment) {
  // Positions exact, heading drifting 0.01 deg per metre: 1 deg per 100 m.
  const api::Trajectory truth = StraightTruth(401, 1.0, Eigen::Vector3d(0, 0, 0), 0.0);
  api::Trajectory estimate = truth;
  for (size_t i = 0; i < estimate.poses.size(); ++i) {
    estimate.poses[i].q_world_body =
        Eigen::Quaterniond(Eigen::AngleAxisd(0.01 * kDeg * i, Eigen::Vector3d::UnitZ()));
  }
  const RpeStats rpe = ComputeRpe(Pairs(estimate, truth), RpeOptions{});
  ASSERT_TRUE(rpe.valid);
  EXPECT_NEAR(rpe.rot_mean_deg, 1.0, 1e-9);
  EXPECT_NEAR(rpe.rot_rmse_deg, 1.0, 1e-9);
}

// A receiver's fixes have no orientation (identity quaternions). Relative poses would express
// each displacement in that fixed frame while the truth's turns with the track: on a curve the
// error came out near the segment length itself. Displacements are compared in the world frame.
TEST(EvalRpe, PositionOnlyEstimateComparesWorldDisplacements) {
  const api::Trajectory truth = testing::CurvedTruth();
  api::Trajectory estimate = truth;
  for (api::StampedPose& pose : estimate.poses) {
    pose.q_world_body = Eigen::Quaterniond::Identity();
    pose.p_world.x() += 0.5;  // a constant offset: no relative error at all
  }
  const std::vector<PosePair> pairs = Pairs(estimate, truth);
  ASSERT_TRUE(EstimateIsPositionOnly(pairs));
  ASSERT_FALSE(EstimateIsPositionOnly(Pairs(truth, truth)));
  RpeOptions options;
  const RpeStats wrong = ComputeRpe(pairs, options);
  ASSERT_TRUE(wrong.valid);
  EXPECT_GT(wrong.trans_mean_pct, 5.0);  // what relative poses make of it
  options.position_only = true;
  const RpeStats rpe = ComputeRpe(pairs, options);
  ASSERT_TRUE(rpe.valid);
  EXPECT_FALSE(rpe.has_rotation);
  EXPECT_NEAR(rpe.trans_mean_m, 0.0, 1e-6);

  EvalOptions eval_options;
  eval_options.align = AlignmentMode::kSe3;
  const EvalResult result = Evaluate(estimate, truth, eval_options);
  ASSERT_TRUE(result.ok) << result.error;
  EXPECT_FALSE(result.rpe.has_rotation);
  EXPECT_NEAR(result.rpe.trans_mean_m, 0.0, 1e-6);
  EXPECT_NEAR(result.drift.end_error_m, 0.0, 1e-6);  // aligned by the first position only
  ASSERT_FALSE(result.warnings.empty());
  EXPECT_NE(result.warnings.back().find("positions only"), std::string::npos);
}

TEST(EvalRpe, ShorterThanASegmentIsInvalidNotACrash) {
  const api::Trajectory truth = StraightTruth(50, 1.0, Eigen::Vector3d(0, 0, 0), 0.0);
  const RpeStats rpe = ComputeRpe(Pairs(truth, truth), RpeOptions{});
  EXPECT_FALSE(rpe.valid);
  EXPECT_EQ(rpe.num_segments, 0u);
  EXPECT_FALSE(ComputeRpe({}, RpeOptions{}).valid);
}

TEST(EvalRpe, StandingTrainDoesNotMultiplySegments) {
  // 100 poses standing at the start, then 150 m of running: still starts only every metre.
  api::Trajectory truth = testing::MakeTrajectory(
      250, 0.1, [](int i) { return Pose(Eigen::Vector3d(std::max(0, i - 99), 0, 0), 0.0); });
  const RpeStats rpe = ComputeRpe(Pairs(truth, truth), RpeOptions{});
  ASSERT_TRUE(rpe.valid);
  EXPECT_EQ(rpe.num_segments, 51u);  // Starts at 0 .. 50 m.
  EXPECT_NEAR(rpe.trans_mean_m, 0.0, 1e-12);
}

TEST(EvalRpe, HundredThousandPosesStayLinear) {
  // 100 km at 1 m per pose; only checks that it runs and counts (a quadratic search would not
  // finish in the test timeout).
  const api::Trajectory truth = StraightTruth(100001, 1.0, Eigen::Vector3d(0, 0, 0), 0.0);
  const RpeStats rpe = ComputeRpe(Pairs(Scaled(truth, 0.99), truth), RpeOptions{});
  ASSERT_TRUE(rpe.valid);
  EXPECT_EQ(rpe.num_segments, 99901u);
  EXPECT_NEAR(rpe.trans_mean_pct, 1.0, 1e-6);
}

TEST(EvalDistance, ReverseRunningCountsAsDistance) {
  // Forward 100 m, then back 40 m: 140 m run, 60 m net.
  const api::Trajectory truth = testing::MakeTrajectory(141, 0.1, [](int i) {
    const double x = i <= 100 ? i : 200 - i;
    return Pose(Eigen::Vector3d(700000 + x, 5000000, 0), i <= 100 ? 0.0 : 3.14159265358979323846);
  });
  api::Trajectory estimate = truth;
  estimate.poses.back().p_world.y() += 1.4;  // 1.4 m at the end -> 1% of 140 m.

  const std::vector<PosePair> pairs = Pairs(estimate, truth);
  EXPECT_NEAR(pairs[100].distance_m, 100.0, 1e-6);
  EXPECT_NEAR(pairs.back().distance_m, 140.0, 1e-6);

  EvalOptions options;
  const EvalResult result = Evaluate(estimate, truth, options);
  ASSERT_TRUE(result.ok) << result.error;
  EXPECT_NEAR(result.distance_m, 140.0, 1e-6);
  EXPECT_NEAR(result.drift.distance_m, 140.0, 1e-6);
  EXPECT_NEAR(result.drift.end_error_m, 1.4, 1e-6);
  EXPECT_NEAR(result.drift.end_drift_pct, 1.0, 1e-6);
  EXPECT_NEAR(result.duration_s, 14.0, 1e-9);
  // Segments of 100 m of path start at 0 .. 40 m, across the turn-back.
  ASSERT_TRUE(result.rpe.valid);
  EXPECT_EQ(result.rpe.num_segments, 41u);
}

}  // namespace
}  // namespace raillomer::eval
