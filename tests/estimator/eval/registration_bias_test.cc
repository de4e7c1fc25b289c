#include "estimator/eval/registration_bias.h"

#include <cmath>
#include <filesystem>
#include <functional>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "estimator/pipeline/config.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"
#include "tests/support/process.h"

namespace raillomer::eval {
namespace {

namespace fs = std::filesystem;

std::unique_ptr<sim::Simulator> Demo() {
  sim::Scenario scenario;
  std::string error;
  EXPECT_TRUE(sim::LoadScenario("demo", &scenario, &error)) << error;
  auto simulator = sim::Simulator::Create(scenario, sim::SimOptions{}, &error);
  EXPECT_NE(simulator, nullptr) << error;
  return simulator;
}

/// Runs MeasureRegistrationBias on the demo with the estimator's configuration for its rig,
/// changed first by `edit` if given.
bool MeasureDemo(const RegistrationBiasOptions& options,
                 RegistrationBiasReport* report,
                 std::string* error,
                 const std::function<void(EstimatorConfig*)>& edit = {}) {
  auto simulator = Demo();
  EstimatorConfig config;
  if (simulator == nullptr ||
      !ParseEstimatorConfig(simulator->RigYaml(), "rig.yaml", &config, error)) {
    return false;
  }
  if (edit) edit(&config);
  return MeasureRegistrationBias(simulator.get(), config, options, report, error);
}

// Three families of planes (walls along and across the track, the ground, a sloped bank); a
// frame whose body points are moved by a small body-frame motion D comes back by D^-1.
TEST(RegistrationBias, ThePullOfAMovedFrameIsTheMotionBack) {
  const Eigen::Isometry3d T_true =
      Eigen::Translation3d(100.0, -20.0, 3.8) * Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ());
  LidarMatches exact;
  auto add_plane = [&](const Eigen::Vector3d& normal_world, double d, const Eigen::Vector3d& p0) {
    const Eigen::Vector3d n = normal_world.normalized();
    const Eigen::Vector3d u = n.unitOrthogonal(), v = n.cross(u);
    for (int a = -3; a <= 3; ++a) {
      for (int b = -3; b <= 3; ++b) {
        Eigen::Vector3d w = p0 + 1.5 * a * u + 1.5 * b * v;
        w -= (n.dot(w) + d) * n;  // onto the plane
        exact.planes.push_back({T_true.inverse() * w, n, d});
      }
    }
  };
  const Eigen::Vector3d centre = T_true.translation();
  add_plane(Eigen::Vector3d::UnitZ(), 0.0, centre + Eigen::Vector3d(10, 0, -4));
  const Eigen::Vector3d along = T_true.linear().col(0), left = T_true.linear().col(1);
  add_plane(left, -left.dot(centre + 6.0 * left), centre + 6.0 * left + 10.0 * along);
  add_plane(along, -along.dot(centre + 30.0 * along), centre + 30.0 * along);
  const Eigen::Vector3d bank = (-left + Eigen::Vector3d::UnitZ()).normalized();
  add_plane(bank, -bank.dot(centre - 5.0 * left), centre - 5.0 * left + 12.0 * along);

  const PosePull none = RegistrationPull(exact, T_true, T_true, 4);
  EXPECT_LT(none.translation_m.norm(), 1e-6);
  EXPECT_LT(none.rotation_rad.norm(), 1e-7);

  const Eigen::Isometry3d D =
      Eigen::Translation3d(0.03, -0.02, 0.01) *
      Eigen::AngleAxisd(0.002, Eigen::Vector3d(0.2, -0.3, 1.0).normalized());
  LidarMatches moved = exact;
  for (PlaneMatch& m : moved.planes) m.p_body = D * m.p_body;
  const PosePull back = RegistrationPull(moved, T_true, T_true, 4);
  const Eigen::Isometry3d D_inverse = D.inverse();
  const Eigen::AngleAxisd expected_rotation(D_inverse.linear());
  EXPECT_LT((back.translation_m - D_inverse.translation()).norm(), 1e-5);
  EXPECT_LT((back.rotation_rad - expected_rotation.angle() * expected_rotation.axis()).norm(),
            1e-6);
}

// On the demo's first 8 s the frames, deskewed with the true motion and matched at their true
// poses, pull by millimetres and fractions of a milliradian (6 mm and 0.1 mrad today); started
// 8 cm and 2.2 mrad off, the registration takes all but about 6 mm and 0.2 mrad of it back.
TEST(RegistrationBias, AtTruePosesTheDemoPullsByMillimetresAndTakesBackAnOffset) {
  RegistrationBiasOptions options;
  options.duration_s = 8.0;
  options.window_s = 4.0;
  RegistrationBiasReport report;
  std::string error;
  ASSERT_TRUE(MeasureDemo(options, &report, &error)) << error;
  EXPECT_GE(report.frames, 75);
  EXPECT_GE(report.both.frames, 70);
  ASSERT_EQ(report.windows.size(), 2u);
  ASSERT_EQ(report.per_lidar.size(), 2u);
  EXPECT_EQ(report.lidar_names, (std::vector<std::string>{"up", "down"}));
  EXPECT_GE(report.per_lidar[1].frames, 70);  // the down LiDAR sees the track in every frame
  EXPECT_LT(report.both.mean.translation_m.norm(), 0.02);
  EXPECT_LT(report.both.mean.rotation_rad.norm(), 5e-4);
  for (const RegistrationBiasWindow& w : report.windows) {
    EXPECT_LT(w.both.mean.translation_m.norm(), 0.03) << w.t_from_s;
  }

  options.start_offset = Eigen::Translation3d(0.06, -0.04, 0.03) *
                         Eigen::AngleAxisd(0.002, Eigen::Vector3d::UnitZ()) *
                         Eigen::AngleAxisd(0.001, Eigen::Vector3d::UnitY());
  RegistrationBiasReport offset;
  ASSERT_TRUE(MeasureDemo(options, &offset, &error)) << error;
  EXPECT_EQ(offset.both.frames, report.both.frames);
  EXPECT_LT((offset.both.mean.translation_m - report.both.mean.translation_m).norm(), 0.01);
  EXPECT_LT((offset.both.mean.rotation_rad - report.both.mean.rotation_rad).norm(), 3e-4);
}

// Each class of match alone: the demo's frames are solved from their planes alone and from
// their edges alone, and each class pulls differently from both together (the edges alone are
// the weaker: fewer frames reach min_matches).
TEST(RegistrationBias, EachClassOfMatchAloneHasItsOwnPull) {
  RegistrationBiasOptions options;
  options.duration_s = 4.0;
  options.window_s = 4.0;
  RegistrationBiasReport all, planes, edges;
  std::string error;
  ASSERT_TRUE(MeasureDemo(options, &all, &error)) << error;
  options.matches = RegistrationBiasOptions::Matches::kPlanes;
  ASSERT_TRUE(MeasureDemo(options, &planes, &error)) << error;
  options.matches = RegistrationBiasOptions::Matches::kEdges;
  ASSERT_TRUE(MeasureDemo(options, &edges, &error)) << error;
  EXPECT_EQ(planes.frames, all.frames);
  EXPECT_GE(planes.both.frames, all.both.frames - 2);
  EXPECT_GT(edges.both.frames, 0);
  EXPECT_LE(edges.both.frames, all.both.frames);
  EXPECT_GT((planes.both.mean.translation_m - all.both.mean.translation_m).norm(), 5e-4);
  EXPECT_GT((edges.both.mean.translation_m - all.both.mean.translation_m).norm(), 5e-4);
  EXPECT_GT((edges.both.mean.translation_m - planes.both.mean.translation_m).norm(), 5e-4);
}

TEST(RegistrationBias, ARigWithoutTheSimulatorsLidarIsRefused) {
  RegistrationBiasOptions options;
  options.duration_s = 1.0;
  RegistrationBiasReport report;
  std::string error;
  EXPECT_FALSE(MeasureDemo(options, &report, &error, [](EstimatorConfig* config) {
    config->rig.lidars.at(0).topic = "/livox/elsewhere";
  }));
  EXPECT_NE(error.find("/livox/lidar_up"), std::string::npos) << error;
}

TEST(RegistrationBiasMain, WritesTheFiguresAndRefusesAnUnknownScenario) {
  const fs::path program = test::BinDir() / "raillomer-registration-bias";
  ASSERT_TRUE(fs::exists(program)) << program;
  test::ScratchDir scratch("raillomer-registration-bias-test-");
  const std::string json = (scratch.path() / "bias.json").string();
  const test::CommandResult run = test::RunCommand(
      test::ShellQuote(program.string()) + " --scenario demo --duration 3 --window 1 --json " +
          test::ShellQuote(json),
      scratch.path());
  ASSERT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.out.find("whole run"), std::string::npos) << run.out;
  EXPECT_NE(run.out.find("down alone"), std::string::npos) << run.out;
  const nlohmann::json j = nlohmann::json::parse(test::ReadText(json));
  EXPECT_EQ(j["scenario"], "demo");
  EXPECT_GE(j["frames"].get<int>(), 25);
  EXPECT_GE(j["windows"].size(), 2u);
  EXPECT_EQ(j["both"]["translation_mm"].size(), 3u);
  EXPECT_EQ(j["matches"], "all");

  const test::CommandResult edges = test::RunCommand(
      test::ShellQuote(program.string()) + " --scenario demo --duration 2 --matches edges",
      scratch.path());
  ASSERT_EQ(edges.exit_code, 0) << edges.err;
  EXPECT_NE(edges.out.find("matches edges"), std::string::npos) << edges.out;
  const test::CommandResult wrong = test::RunCommand(
      test::ShellQuote(program.string()) + " --scenario demo --matches corners", scratch.path());
  EXPECT_NE(wrong.exit_code, 0);
  EXPECT_NE(wrong.err.find("corners"), std::string::npos) << wrong.err;

  const test::CommandResult unknown = test::RunCommand(
      test::ShellQuote(program.string()) + " --scenario no_such_line", scratch.path());
  EXPECT_EQ(unknown.exit_code, 2);
  EXPECT_NE(unknown.err.find("no_such_line"), std::string::npos) << unknown.err;
}

}  // namespace
}  // namespace raillomer::eval
