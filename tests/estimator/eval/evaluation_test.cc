#include "estimator/eval/evaluation.h"

#include <gtest/gtest.h>

#include "estimator/eval/report.h"
#include "eval_test_util.h"

namespace raillomer::eval {
namespace {

using testing::CurvedTruth;
using testing::StraightTruth;

TEST(EvalEvaluate, DifferentUtmZonesAreAnError) {
  api::Trajectory truth = CurvedTruth(50);
  api::Trajectory estimate = truth;
  truth.utm_zone = "50N";
  estimate.utm_zone = "51N";
  const EvalResult result = Evaluate(estimate, truth, EvalOptions{});
  EXPECT_FALSE(result.ok);
  EXPECT_NE(result.error.find("50N"), std::string::npos);
  EXPECT_NE(result.error.find("51N"), std::string::npos);
}

TEST(EvalEvaluate, OneSidedUtmZoneWarnsOnlyWithoutAlignment) {
  api::Trajectory truth = CurvedTruth(50);
  const api::Trajectory estimate = truth;
  truth.utm_zone = "32N";
  EvalOptions options;
  const EvalResult none = Evaluate(estimate, truth, options);
  ASSERT_TRUE(none.ok) << none.error;
  ASSERT_EQ(none.warnings.size(), 1u);
  EXPECT_NE(none.warnings[0].find("utm_zone"), std::string::npos);
  EXPECT_EQ(none.utm_zone, "32N");

  options.align = AlignmentMode::kSe3;
  EXPECT_TRUE(Evaluate(estimate, truth, options).warnings.empty());
}

TEST(EvalEvaluate, FewerThanTwoMatchedPosesIsAnError) {
  const api::Trajectory truth = CurvedTruth(50);
  api::Trajectory estimate = truth;
  for (api::StampedPose& pose : estimate.poses) pose.stamp_ns += 3600LL * 1000000000LL;
  const EvalResult result = Evaluate(estimate, truth, EvalOptions{});
  EXPECT_FALSE(result.ok);
  EXPECT_NE(result.error.find("only 0 of 50"), std::string::npos) << result.error;
}

TEST(EvalEvaluate, InvalidOptionsAreAnError) {
  const api::Trajectory truth = CurvedTruth(50);
  EvalOptions options;
  options.segment_length_m = -1.0;
  const EvalResult result = Evaluate(truth, truth, options);
  EXPECT_FALSE(result.ok);
  EXPECT_NE(result.error.find("segment_length_m"), std::string::npos);
}

TEST(EvalReport, JsonCarriesUnitsAndNullsForMissingFigures) {
  const api::Trajectory truth = StraightTruth(51, 1.0, Eigen::Vector3d(0, 0, 0), 0.0);
  api::Trajectory estimate = truth;
  for (api::StampedPose& pose : estimate.poses) pose.p_world.z() += 0.25;
  EvalOptions options;
  const EvalResult result = Evaluate(estimate, truth, options);
  ASSERT_TRUE(result.ok) << result.error;

  const nlohmann::json json = ToJson(result);
  EXPECT_EQ(json.at("align"), "none");
  EXPECT_EQ(json.at("matched_poses"), 51);
  EXPECT_EQ(json.at("skipped_poses"), 0);
  EXPECT_NEAR(json.at("ate_rmse_m").get<double>(), 0.25, 1e-12);
  EXPECT_NEAR(json.at("ate_max_m").get<double>(), 0.25, 1e-12);
  EXPECT_NEAR(json.at("distance_m").get<double>(), 50.0, 1e-9);
  EXPECT_NEAR(json.at("duration_s").get<double>(), 5.0, 1e-9);
  // No alignment: the 0.25 m offset is all end error, over 50 m.
  EXPECT_NEAR(json.at("end_error_m").get<double>(), 0.25, 1e-12);
  EXPECT_NEAR(json.at("end_drift_pct").get<double>(), 0.5, 1e-9);
  EXPECT_TRUE(json.at("rpe_trans_mean_pct").is_null());  // 50 m < one 100 m segment.
  EXPECT_TRUE(json.at("rpe_rot_mean_deg").is_null());
  EXPECT_EQ(json.at("alignment").at("rotation").size(), 3u);
  EXPECT_EQ(json.at("alignment").at("translation_m").size(), 3u);

  const std::string table = FormatTable(result);
  EXPECT_NE(table.find("ATE RMSE"), std::string::npos);
  EXPECT_NE(table.find("n/a"), std::string::npos);
}

}  // namespace
}  // namespace raillomer::eval
