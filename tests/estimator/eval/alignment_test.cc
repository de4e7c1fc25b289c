#include "estimator/eval/alignment.h"

#include <cmath>

#include <gtest/gtest.h>

#include "estimator/eval/evaluation.h"
#include "eval_test_util.h"

namespace raillomer::eval {
namespace {

using testing::CurvedTruth;
using testing::Pose;
using testing::Transformed;

constexpr double kDeg = 3.14159265358979323846 / 180.0;

std::vector<Eigen::Vector3d> Positions(const api::Trajectory& trajectory) {
  std::vector<Eigen::Vector3d> points;
  for (const api::StampedPose& pose : trajectory.poses) points.push_back(pose.p_world);
  return points;
}

TEST(EvalAlignment, ParsesAndNamesModes) {
  for (AlignmentMode mode : {AlignmentMode::kNone, AlignmentMode::kSe3, AlignmentMode::kFourDof}) {
    AlignmentMode parsed = AlignmentMode::kNone;
    ASSERT_TRUE(ParseAlignmentMode(ToString(mode), &parsed));
    EXPECT_EQ(parsed, mode);
  }
  AlignmentMode parsed = AlignmentMode::kNone;
  EXPECT_FALSE(ParseAlignmentMode("sim3", &parsed));
}

TEST(EvalAlignment, Se3RecoversAKnownRotationAndTranslation) {
  const api::Trajectory truth = CurvedTruth();
  const Eigen::Isometry3d T_truth_est =
      Pose(Eigen::Vector3d(120.0, -45.0, 7.5), 35 * kDeg, -8 * kDeg, 5 * kDeg);
  const api::Trajectory estimate = Transformed(truth, T_truth_est.inverse());

  const Alignment alignment =
      AlignPoints(Positions(estimate), Positions(truth), AlignmentMode::kSe3);
  EXPECT_FALSE(alignment.degenerate);
  EXPECT_EQ(alignment.num_points, truth.poses.size());
  EXPECT_LT((alignment.T_truth_est.linear() - T_truth_est.linear()).norm(), 1e-9);
  EXPECT_LT((alignment.T_truth_est.translation() - T_truth_est.translation()).norm(), 1e-9);
  EXPECT_LT(alignment.rmse_after_m, 1e-9);
  EXPECT_GT(alignment.rmse_before_m, 10.0);
}

TEST(EvalAlignment, AteIsZeroAfterSe3AndTheOffsetWithNone) {
  const api::Trajectory truth = CurvedTruth();
  // A pure 3-4-0 offset: 5 m everywhere without alignment.
  const Eigen::Isometry3d T_offset = Pose(Eigen::Vector3d(3.0, 4.0, 0.0), 0.0);
  const api::Trajectory estimate = Transformed(truth, T_offset);

  EvalOptions options;
  options.align = AlignmentMode::kNone;
  const EvalResult none = Evaluate(estimate, truth, options);
  ASSERT_TRUE(none.ok) << none.error;
  EXPECT_NEAR(none.ate.rmse_m, 5.0, 1e-9);
  EXPECT_NEAR(none.ate.max_m, 5.0, 1e-9);
  EXPECT_NEAR(none.ate.mean_m, 5.0, 1e-9);

  options.align = AlignmentMode::kSe3;
  const EvalResult se3 = Evaluate(estimate, truth, options);
  ASSERT_TRUE(se3.ok) << se3.error;
  EXPECT_LT(se3.ate.rmse_m, 1e-9);
  EXPECT_LT(se3.ate.max_m, 1e-9);

  // A rotation as well: se3 still removes it all.
  const api::Trajectory rotated =
      Transformed(truth, Pose(Eigen::Vector3d(-20, 10, 3), 0.5, 0.05, -0.03));
  const EvalResult se3_rotated = Evaluate(rotated, truth, options);
  ASSERT_TRUE(se3_rotated.ok);
  EXPECT_LT(se3_rotated.ate.max_m, 1e-9);
}

TEST(EvalAlignment, FourDofRecoversYawAndTranslation) {
  const api::Trajectory truth = CurvedTruth();
  const Eigen::Isometry3d T_truth_est = Pose(Eigen::Vector3d(-310.0, 95.0, -12.0), -140 * kDeg);
  const api::Trajectory estimate = Transformed(truth, T_truth_est.inverse());

  const Alignment alignment =
      AlignPoints(Positions(estimate), Positions(truth), AlignmentMode::kFourDof);
  EXPECT_FALSE(alignment.degenerate);
  EXPECT_LT((alignment.T_truth_est.linear() - T_truth_est.linear()).norm(), 1e-9);
  EXPECT_LT((alignment.T_truth_est.translation() - T_truth_est.translation()).norm(), 1e-9);

  EvalOptions options;
  options.align = AlignmentMode::kFourDof;
  const EvalResult result = Evaluate(estimate, truth, options);
  ASSERT_TRUE(result.ok) << result.error;
  EXPECT_LT(result.ate.max_m, 1e-9);
}

TEST(EvalAlignment, FourDofDoesNotAbsorbPitch) {
  const api::Trajectory truth = CurvedTruth();
  // Estimate = truth seen through an extra 2 deg pitch about the centre of the run, plus yaw
  // and translation that 4dof may remove.
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const api::StampedPose& pose : truth.poses) centre += pose.p_world;
  centre /= static_cast<double>(truth.poses.size());
  const Eigen::Isometry3d T_pitch = Eigen::Translation3d(centre) *
                                    Eigen::AngleAxisd(2 * kDeg, Eigen::Vector3d::UnitY()) *
                                    Eigen::Translation3d(-centre);
  const api::Trajectory estimate =
      Transformed(truth, Pose(Eigen::Vector3d(5, -7, 1), 0.4) * T_pitch);

  EvalOptions options;
  options.align = AlignmentMode::kFourDof;
  const EvalResult four_dof = Evaluate(estimate, truth, options);
  ASSERT_TRUE(four_dof.ok) << four_dof.error;
  // Points up to ~170 m from the centre along x move by up to ~170 * sin(2 deg) ~ 6 m in z.
  EXPECT_GT(four_dof.ate.rmse_m, 1.0);
  EXPECT_GT(four_dof.ate.max_m, 3.0);

  options.align = AlignmentMode::kSe3;
  const EvalResult se3 = Evaluate(estimate, truth, options);
  ASSERT_TRUE(se3.ok);
  EXPECT_LT(se3.ate.max_m, 1e-9);
}

TEST(EvalAlignment, AlignByPoseMatchesTheFirstPoseInTheChosenDof) {
  const Eigen::Isometry3d T_world_truth = Pose(Eigen::Vector3d(10, 20, 3), 50 * kDeg, 4 * kDeg);
  const Eigen::Isometry3d T_world_est = Pose(Eigen::Vector3d(-1, 2, 0), 20 * kDeg, 4 * kDeg);

  EXPECT_TRUE(AlignByPose(T_world_est, T_world_truth, AlignmentMode::kNone)
                  .isApprox(Eigen::Isometry3d::Identity()));

  const Eigen::Isometry3d se3 = AlignByPose(T_world_est, T_world_truth, AlignmentMode::kSe3);
  EXPECT_LT(((se3 * T_world_est).matrix() - T_world_truth.matrix()).norm(), 1e-12);

  const Eigen::Isometry3d four = AlignByPose(T_world_est, T_world_truth, AlignmentMode::kFourDof);
  EXPECT_NEAR(BestYaw(four.linear()), 30 * kDeg, 1e-12);
  EXPECT_LT(((four * T_world_est).translation() - T_world_truth.translation()).norm(), 1e-12);
  // Only a rotation about z.
  EXPECT_NEAR(four.linear()(2, 2), 1.0, 1e-15);
}

TEST(EvalAlignment, BestYawAndRotationAngle) {
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_NEAR(BestYaw(R), 0.7, 1e-15);
  EXPECT_NEAR(RotationAngle(R), 0.7, 1e-15);
  const Eigen::Matrix3d flip =
      Eigen::AngleAxisd(3.14159265358979323846, Eigen::Vector3d(1, 1, 0).normalized())
          .toRotationMatrix();
  EXPECT_NEAR(RotationAngle(flip), 3.14159265358979323846, 1e-7);
  EXPECT_NEAR(RotationAngle(Eigen::Matrix3d::Identity()), 0.0, 1e-15);
}

TEST(EvalAlignment, StraightLineIsFlaggedDegenerateButStillFits) {
  const api::Trajectory truth = testing::StraightTruth(200, 1.0, Eigen::Vector3d(100, 200, 5), 0.3);
  const api::Trajectory estimate = Transformed(truth, Pose(Eigen::Vector3d(4, 5, 6), 0.2));
  const Alignment alignment =
      AlignPoints(Positions(estimate), Positions(truth), AlignmentMode::kSe3);
  EXPECT_TRUE(alignment.degenerate);
  EXPECT_LT(alignment.rmse_after_m, 1e-9);

  EvalOptions options;
  options.align = AlignmentMode::kSe3;
  const EvalResult result = Evaluate(estimate, truth, options);
  ASSERT_TRUE(result.ok);
  ASSERT_EQ(result.warnings.size(), 1u);
  EXPECT_NE(result.warnings[0].find("not unique"), std::string::npos);
}

}  // namespace
}  // namespace raillomer::eval
