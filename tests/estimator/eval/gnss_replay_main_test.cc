// End-to-end tests of raillomer-gnss-replay: the demo's GNSS-off odometry replayed with the
// demo's fixes (from the simulated run's gnss.tum or the simulator's bag) is the trajectory the
// estimator publishes with GNSS on; bad input is named.

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "api/trajectory.h"
#include "tests/support/process.h"

namespace raillomer {
namespace {

namespace fs = std::filesystem;

using test::CommandResult;
using test::ShellQuote;

class GnssReplayMain : public ::testing::Test {
 protected:
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }

  CommandResult Replay(const std::string& arguments) const {
    return test::RunCommand(
        ShellQuote((test::BinDir() / "raillomer-gnss-replay").string()) + " " + arguments, dir_);
  }

  /// raillomer-gnss-replay on files of dir_ (no --fixes if `fixes` is empty), with more
  /// arguments, into dir_/out.
  CommandResult ReplayFiles(const std::string& odometry,
                            const std::string& fixes,
                            const std::string& more,
                            const std::string& out) const {
    return Replay("--odometry " + ShellQuote(Path(odometry)) +
                  (fixes.empty() ? "" : " --fixes " + ShellQuote(Path(fixes))) + " " + more +
                  " --out " + ShellQuote(Path(out)));
  }

  /// The demo through the estimator into dir_/name (GNSS on unless no_gnss).
  void RunDemo(const std::string& name, bool no_gnss) const {
    const CommandResult run =
        test::RunCommand(ShellQuote((test::BinDir() / "raillomer-estimator").string()) +
                             " --sim demo --quiet --no-submaps --no-keyframes --out " +
                             ShellQuote(Path(name)) + (no_gnss ? " --no-gnss" : ""),
                         dir_);
    ASSERT_EQ(run.exit_code, 0) << run.err;
  }

  api::Trajectory Read(const std::string& name) const {
    api::Trajectory t;
    std::string error;
    EXPECT_TRUE(api::ReadTum(Path(name), &t, &error)) << error;
    return t;
  }

  void Write(const std::string& name, const api::Trajectory& t) const {
    std::string error;
    ASSERT_TRUE(api::WriteTum(Path(name), t, &error)) << error;
  }

  /// A straight odometry run east at 20 m/s for `seconds`, at 10 Hz (local frame), and the
  /// receiver's fixes along it in zone 50N at 1 Hz, `fixes` of them.
  void WriteStraightRun(double seconds, int fixes) const {
    api::Trajectory odometry, gnss;
    for (int i = 0; i <= static_cast<int>(seconds * 10); ++i) {
      api::StampedPose p;
      p.stamp_ns = 1600000000000000000 + static_cast<int64_t>(i) * 100000000;
      p.p_world = Eigen::Vector3d(2.0 * i, 0.0, 0.0);
      odometry.poses.push_back(p);
      if (i % 10 == 0 && static_cast<int>(gnss.poses.size()) < fixes) {
        p.p_world += Eigen::Vector3d(432000.0, 3585000.0, 30.3);
        gnss.poses.push_back(p);
      }
    }
    gnss.utm_zone = "50N";
    Write("straight_odometry.tum", odometry);
    Write("straight_fixes.tum", gnss);
  }

  /// Every pose of `a` at the stamp of `b`'s, within `tolerance_m` and a microradian.
  static void ExpectSamePoses(const api::Trajectory& a,
                              const api::Trajectory& b,
                              double tolerance_m) {
    ASSERT_EQ(a.poses.size(), b.poses.size());
    double worst = 0.0;
    for (size_t i = 0; i < b.poses.size(); ++i) {
      ASSERT_EQ(a.poses[i].stamp_ns, b.poses[i].stamp_ns) << i;
      worst = std::max(worst, (a.poses[i].p_world - b.poses[i].p_world).norm());
      EXPECT_LT(a.poses[i].q_world_body.angularDistance(b.poses[i].q_world_body), 1e-6) << i;
    }
    EXPECT_LT(worst, tolerance_m);
  }

  /// The same fixes read from the simulator's bag of the demo, the rig from its rig.yaml, give
  /// the published trajectory.
  void ExpectTheBagsFixesGiveTheSame(const api::Trajectory& published) const {
    const CommandResult sim =
        test::RunCommand(ShellQuote((test::BinDir() / "raillomer-sim").string()) +
                             " --scenario demo --out " + ShellQuote(Path("sim")),
                         dir_);
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
    const CommandResult run = ReplayFiles("off/trajectory.tum",
                                          "",
                                          "--bag " + ShellQuote(Path("sim/run.bag")) +
                                              " --config " + ShellQuote(Path("sim/rig.yaml")),
                                          "from_bag.tum");
    ASSERT_EQ(run.exit_code, 0) << run.err;
    ExpectSamePoses(Read("from_bag.tum"), published, 1e-5);
  }

  /// --options reach the fusion: trusting the fixes to 5 cm moves the trajectory.
  void ExpectOptionsReachTheFusion(const std::string& inputs,
                                   const api::Trajectory& published) const {
    std::ofstream(Path("tight.yaml")) << "estimator:\n  gnss:\n    sigma_horizontal_m: 0.05\n";
    const CommandResult run = Replay(inputs + " --options " + ShellQuote(Path("tight.yaml")) +
                                     " --out " + ShellQuote(Path("tight.tum")));
    ASSERT_EQ(run.exit_code, 0) << run.err;
    const api::Trajectory tight = Read("tight.tum");
    ASSERT_EQ(tight.poses.size(), published.poses.size());
    double moved = 0.0;
    for (size_t i = 0; i < tight.poses.size(); ++i)
      moved = std::max(moved, (tight.poses[i].p_world - published.poses[i].p_world).norm());
    EXPECT_GT(moved, 0.01);
  }

  test::ScratchDir scratch_{"raillomer-gnss-replay-test-"};
  const fs::path& dir_ = scratch_.path();
};

TEST_F(GnssReplayMain, ReplayingTheOdometryGivesTheEstimatorsTrajectory) {
  RunDemo("on", false);
  RunDemo("off", true);
  const std::string inputs = "--odometry " + ShellQuote(Path("off/trajectory.tum")) + " --fixes " +
                             ShellQuote(Path("off/gnss.tum")) + " --sim demo";
  CommandResult run = Replay(inputs + " --out " + ShellQuote(Path("replayed.tum")) + " --json " +
                             ShellQuote(Path("replayed.json")));
  ASSERT_EQ(run.exit_code, 0) << run.err;
  // The fusion's counts: every fix of the run taken, a factor every 10 s of it.
  const nlohmann::json counts = nlohmann::json::parse(test::ReadText(Path("replayed.json")));
  EXPECT_EQ(counts.at("fixes").get<size_t>(), Read("off/gnss.tum").poses.size());
  EXPECT_GE(counts.at("factors").get<int>(), 2);
  EXPECT_EQ(counts.at("rejected").get<int>(), 0);
  EXPECT_NE(run.err.find("aligned to UTM zone"), std::string::npos) << run.err;
  const api::Trajectory published = Read("on/trajectory.tum"), replayed = Read("replayed.tum");
  ASSERT_FALSE(published.utm_zone.empty());
  EXPECT_EQ(replayed.utm_zone, published.utm_zone);
  ASSERT_GT(published.poses.size(), 200u);
  ASSERT_EQ(replayed.poses.size(), published.poses.size());
  // Both went through a TUM file: micrometres.
  ExpectSamePoses(replayed, published, 1e-5);
  ExpectTheBagsFixesGiveTheSame(published);
  ExpectOptionsReachTheFusion(inputs, published);
}

TEST_F(GnssReplayMain, AStraightRunIsPlacedOnItsFixes) {
  WriteStraightRun(60.0, 1000);
  const CommandResult run =
      ReplayFiles("straight_odometry.tum", "straight_fixes.tum", "--sim demo", "straight.tum");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const api::Trajectory out = Read("straight.tum");
  EXPECT_EQ(out.utm_zone, "50N");
  ASSERT_GT(out.poses.size(), 500u);
  // The fixes are the odometry moved by a known offset (the demo's antenna sits 0.3 m up, as
  // the fixes do): every pose lands there.
  for (const api::StampedPose& p : out.poses) {
    const double t = static_cast<double>(p.stamp_ns - 1600000000000000000) * 1e-9;
    EXPECT_LT((p.p_world - Eigen::Vector3d(432000.0 + 20.0 * t, 3585000.0, 30.0)).norm(), 0.05)
        << t;
  }
}

TEST_F(GnssReplayMain, BadInputIsNamed) {
  WriteStraightRun(60.0, 1000);
  const struct {
    std::string odometry, fixes, more, message;
  } cases[] = {
      // A georeferenced trajectory is not odometry.
      {"straight_fixes.tum", "straight_fixes.tum", "--sim demo", "a --no-gnss run"},
      // Fixes without a zone.
      {"straight_odometry.tum", "straight_odometry.tum", "--sim demo", "utm_zone"},
      {"straight_odometry.tum", "straight_fixes.tum", "", "exactly one of --sim and --config"},
      {"straight_odometry.tum",
       "straight_fixes.tum",
       "--config rig.yaml --options " + ShellQuote(Path("straight_fixes.tum")),
       "--options goes with --sim"},
      {"straight_odometry.tum", "straight_fixes.tum", "--sim no_such_line", "no_such_line"},
      {"straight_odometry.tum", "", "--sim demo", "give the fixes"},
      {"straight_odometry.tum",
       "",
       "--sim demo --bag " + ShellQuote(Path("none.bag")),
       "none.bag does not exist"},
  };
  for (const auto& c : cases) {
    const CommandResult run = ReplayFiles(c.odometry, c.fixes, c.more, "bad.tum");
    EXPECT_EQ(run.exit_code, 2) << c.message << ": " << run.err;
    EXPECT_NE(run.err.find(c.message), std::string::npos) << run.err;
  }
  EXPECT_FALSE(fs::exists(Path("bad.tum")));
}

TEST_F(GnssReplayMain, ARunWithTooFewFixesSaysItIsNotGeoreferenced) {
  // Three fixes over 40 m: no alignment baseline.
  WriteStraightRun(60.0, 3);
  const CommandResult run =
      ReplayFiles("straight_odometry.tum", "straight_fixes.tum", "--sim demo", "few.tum");
  EXPECT_EQ(run.exit_code, 3);
  EXPECT_NE(run.err.find("not georeferenced"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(Path("few.tum")));
}

}  // namespace
}  // namespace raillomer
