// End-to-end tests of the raillomer-eval executable ($RAILLOMER_BIN/raillomer-eval).

#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "api/trajectory.h"
#include "estimator/eval/evaluation.h"
#include "eval_test_util.h"
#include "tests/support/process.h"

namespace raillomer::eval {
namespace {

namespace fs = std::filesystem;

using test::CommandResult;
using test::ReadText;

using test::ShellQuote;

class EvalMain : public ::testing::Test {
 protected:
  void SetUp() override {
    program_ = test::BinDir() / "raillomer-eval";
    ASSERT_TRUE(fs::exists(program_)) << program_;
    ASSERT_FALSE(dir_.empty());

    // A curved run in UTM zone 50N; the estimate is 0.3 m east and 0.4 m south of it: 0.5 m.
    truth_ = testing::Transformed(testing::CurvedTruth(),
                                  testing::Pose(Eigen::Vector3d(500000, 4000000, 50), 0.0));
    truth_.utm_zone = "50N";
    estimate_ = testing::Transformed(truth_, testing::Pose(Eigen::Vector3d(0.3, -0.4, 0), 0.0));
    std::string error;
    ASSERT_TRUE(api::WriteTum(Path("truth.tum"), truth_, &error)) << error;
    ASSERT_TRUE(api::WriteTum(Path("estimate.tum"), estimate_, &error)) << error;
  }

  std::string Path(const std::string& name) const { return (dir_ / name).string(); }

  CommandResult Execute(const std::string& arguments) const {
    return test::RunCommand(ShellQuote(program_.string()) + " " + arguments, dir_);
  }

  std::string Inputs() const {
    return "--estimate " + ShellQuote(Path("estimate.tum")) + " --truth " +
           ShellQuote(Path("truth.tum"));
  }

  fs::path program_;
  test::ScratchDir scratch_{"raillomer-eval-test-"};
  const fs::path& dir_ = scratch_.path();
  api::Trajectory truth_;
  api::Trajectory estimate_;
};

TEST_F(EvalMain, WritesJsonAndPlotWithKnownFigures) {
  const CommandResult run = Execute(Inputs() + " --json " + ShellQuote(Path("summary.json")) +
                                    " --plot " + ShellQuote(Path("plot.svg")));
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.err.find("align=none"), std::string::npos) << run.err;
  EXPECT_NE(run.err.find("max_gap_s=0.5"), std::string::npos) << run.err;
  EXPECT_NE(run.out.find("ATE RMSE"), std::string::npos) << run.out;

  const nlohmann::json json = nlohmann::json::parse(ReadText(Path("summary.json")));
  EXPECT_EQ(json.at("align"), "none");
  EXPECT_EQ(json.at("utm_zone"), "50N");
  EXPECT_EQ(json.at("matched_poses"), 600);
  EXPECT_EQ(json.at("skipped_poses"), 0);
  // TUM files carry micrometres, hence 1e-5.
  EXPECT_NEAR(json.at("ate_rmse_m").get<double>(), 0.5, 1e-5);
  EXPECT_NEAR(json.at("ate_max_m").get<double>(), 0.5, 1e-5);
  EXPECT_NEAR(json.at("ate_median_m").get<double>(), 0.5, 1e-5);
  EXPECT_NEAR(json.at("end_error_m").get<double>(), 0.5, 1e-5);
  EXPECT_NEAR(json.at("duration_s").get<double>(), 59.9, 1e-9);
  EXPECT_NEAR(json.at("rpe_trans_mean_m").get<double>(), 0.0, 1e-5);

  // Every figure equals the library's on the same files.
  api::Trajectory estimate, truth;
  std::string error;
  ASSERT_TRUE(api::ReadTum(Path("estimate.tum"), &estimate, &error)) << error;
  ASSERT_TRUE(api::ReadTum(Path("truth.tum"), &truth, &error)) << error;
  const EvalResult reference = Evaluate(estimate, truth, EvalOptions{});
  ASSERT_TRUE(reference.ok);
  EXPECT_DOUBLE_EQ(json.at("distance_m").get<double>(), reference.distance_m);
  EXPECT_DOUBLE_EQ(json.at("ate_rmse_m").get<double>(), reference.ate.rmse_m);
  EXPECT_DOUBLE_EQ(json.at("end_drift_pct").get<double>(), reference.drift.end_drift_pct);
  EXPECT_GT(reference.distance_m, 599.0);

  const std::string svg = ReadText(Path("plot.svg"));
  EXPECT_TRUE(svg.rfind("<?xml", 0) == 0 || svg.rfind("<svg", 0) == 0);
  EXPECT_NE(svg.find("xmlns=\"http://www.w3.org/2000/svg\""), std::string::npos);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);

  // No temporaries left behind by the atomic writes.
  size_t files = 0;
  for (const auto& entry : fs::directory_iterator(dir_)) {
    EXPECT_EQ(entry.path().string().find(".tmp-"), std::string::npos) << entry.path();
    ++files;
  }
  EXPECT_EQ(files, 6u);  // Two inputs, two outputs, stdout, stderr.
}

TEST_F(EvalMain, Se3AlignmentRemovesTheOffset) {
  const CommandResult run =
      Execute(Inputs() + " --align se3 --json " + ShellQuote(Path("summary.json")));
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const nlohmann::json json = nlohmann::json::parse(ReadText(Path("summary.json")));
  EXPECT_EQ(json.at("align"), "se3");
  EXPECT_LT(json.at("ate_rmse_m").get<double>(), 1e-5);
  EXPECT_NEAR(json.at("alignment").at("translation_m").at(0).get<double>(), -0.3, 1e-3);
  EXPECT_NEAR(json.at("alignment").at("translation_m").at(1).get<double>(), 0.4, 1e-3);
}

TEST_F(EvalMain, MalformedLineGivesExitCodeTwoWithFileAndLine) {
  std::string text = api::FormatTum(truth_);
  // Line 1 is the utm_zone comment, so the fourth pose is line 5.
  size_t at = 0;
  for (int line = 1; line < 5; ++line) at = text.find('\n', at) + 1;
  text.insert(at, "1600000000.35 1.0 2.0 oops 0 0 0 1\n");
  std::ofstream(Path("truth.tum"), std::ios::binary) << text;

  const CommandResult run = Execute(Inputs() + " --json " + ShellQuote(Path("summary.json")));
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_NE(run.err.find("line 5"), std::string::npos) << run.err;
  EXPECT_NE(run.err.find("truth.tum"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(Path("summary.json")));
}

TEST_F(EvalMain, MissingFileGivesExitCodeTwo) {
  const CommandResult run = Execute("--estimate " + ShellQuote(Path("nothing.tum")) + " --truth " +
                                    ShellQuote(Path("truth.tum")));
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_NE(run.err.find("nothing.tum"), std::string::npos) << run.err;
}

TEST_F(EvalMain, NoOverlapGivesExitCodeTwo) {
  api::Trajectory late = estimate_;
  for (api::StampedPose& pose : late.poses) pose.stamp_ns += 3600LL * 1000000000LL;
  std::string error;
  ASSERT_TRUE(api::WriteTum(Path("estimate.tum"), late, &error));
  const CommandResult run = Execute(Inputs());
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_NE(run.err.find("match"), std::string::npos) << run.err;
}

TEST_F(EvalMain, DifferentUtmZonesGiveExitCodeTwo) {
  api::Trajectory other = estimate_;
  other.utm_zone = "51N";
  std::string error;
  ASSERT_TRUE(api::WriteTum(Path("estimate.tum"), other, &error));
  const CommandResult run = Execute(Inputs());
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_NE(run.err.find("51N"), std::string::npos) << run.err;
}

TEST_F(EvalMain, UnknownAlignAndPlotFormatAreUsageErrors) {
  CommandResult run =
      Execute(Inputs() + " --align sim3 --json " + ShellQuote(Path("summary.json")));
  EXPECT_NE(run.exit_code, 0);
  EXPECT_NE(run.err.find("--align"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(Path("summary.json")));

  run = Execute(Inputs() + " --plot " + ShellQuote(Path("plot.png")));
  EXPECT_NE(run.exit_code, 0);
  EXPECT_NE(run.err.find(".svg"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(Path("plot.png")));
}

}  // namespace
}  // namespace raillomer::eval
