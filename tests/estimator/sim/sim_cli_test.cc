// raillomer-sim end to end: the outputs of a short run, the independent bag check (python
// rosbag, not our reader), and clear errors on bad input with nothing half-written left behind.

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "api/trajectory.h"
#include "tests/support/process.h"

namespace {

namespace fs = std::filesystem;
using raillomer::test::CommandResult;
using raillomer::test::ReadText;

class SimCli : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(fs::exists(sim_)) << sim_;
    ASSERT_FALSE(dir_.empty());
  }

  /// Runs a shell command with its output captured.
  CommandResult Shell(const std::string& command) const {
    return raillomer::test::RunCommand(command, dir_);
  }

  const std::string sim_ = (raillomer::test::BinDir() / "raillomer-sim").string();
  const std::string checker_ = (raillomer::test::SourceDir() / "tests/tools/check_bag.py").string();
  raillomer::test::ScratchDir scratch_{"raillomer_sim_cli_"};
  const fs::path& dir_ = scratch_.path();
};

TEST_F(SimCli, ListsTheScenarioSuite) {
  const CommandResult run = Shell(sim_ + " --list");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  for (const char* name : {"rich_low_station_a",
                           "rich_low_yard_b",
                           "rich_high_town_a",
                           "rich_high_mixed_b",
                           "poor_low_open_a",
                           "poor_low_embankment_b",
                           "poor_high_open_a",
                           "poor_high_catenary_b",
                           "imu_loss",
                           "reverse_running",
                           "winter_wheel_slip",
                           "tunnel_gnss_outage",
                           "long_20km",
                           "rich_low_station_a_changed"}) {
    EXPECT_NE(run.out.find(name), std::string::npos) << name;
  }
  EXPECT_EQ(run.out.find("invalid"), std::string::npos) << run.out;
}

TEST_F(SimCli, ShortRunWritesAValidBagTruthAndRig) {
  const fs::path out = dir_ / "run";
  const CommandResult run =
      Shell(sim_ + " --scenario demo --out " + out.string() + " --duration 3 --seed 5");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  for (const char* file : {"run.bag", "truth.tum", "gnss.tum", "imu_bias.csv", "rig.yaml"}) {
    EXPECT_TRUE(fs::exists(out / file)) << file;
  }
  EXPECT_FALSE(fs::exists(out / "changes.json"));
  const std::string biases = ReadText(out / "imu_bias.csv");
  EXPECT_EQ(biases.rfind("stamp_s,gyro_bias_x,", 0), 0u) << biases.substr(0, 80);
  EXPECT_EQ(std::count(biases.begin(), biases.end(), '\n'), 32);  // header + 10 Hz over 3 s
  for (const auto& entry : fs::directory_iterator(out)) {
    EXPECT_EQ(entry.path().filename().string().find(".tmp-"), std::string::npos)
        << "leftover temporary " << entry.path();
  }

  raillomer::api::Trajectory truth;
  std::string error;
  ASSERT_TRUE(raillomer::api::ReadTum((out / "truth.tum").string(), &truth, &error)) << error;
  EXPECT_EQ(truth.utm_zone, "50N");
  ASSERT_EQ(truth.poses.size(), 301u);  // 100 Hz over 3 s, both ends
  EXPECT_EQ(truth.poses[1].stamp_ns - truth.poses[0].stamp_ns, 10000000);
  EXPECT_GT(truth.poses.front().p_world.x(), 166000.0);  // a UTM easting, not a local frame
  EXPECT_GT(truth.poses.front().p_world.y(), 3.0e6);
  EXPECT_EQ(ReadText(out / "truth.tum").rfind("# utm_zone 50N\n", 0), 0u);

  raillomer::api::Trajectory gnss;
  ASSERT_TRUE(raillomer::api::ReadTum((out / "gnss.tum").string(), &gnss, &error)) << error;
  EXPECT_GE(gnss.poses.size(), 3u);
  EXPECT_LT((gnss.poses.front().p_world - truth.poses.front().p_world).norm(), 40.0);

  const std::string rig = ReadText(out / "rig.yaml");
  for (const char* key : {"/livox/lidar_up",
                          "/livox/lidar_down",
                          "/imu/data",
                          "/odometer",
                          "/gnss/fix",
                          "wheel_diameter_m",
                          "pulses_per_rev",
                          "rpy_deg"}) {
    EXPECT_NE(rig.find(key), std::string::npos) << key;
  }

  // The independent check: topics, types, md5 sums, definitions, rates, points per frame.
  const CommandResult check =
      Shell("/usr/bin/python3 " + checker_ + " " + (out / "run.bag").string() +
            " --duration-s 3 --points-per-frame 24000");
  EXPECT_EQ(check.exit_code, 0) << check.out << check.err;
  EXPECT_NE(check.out.find("0 failed"), std::string::npos) << check.out;
}

TEST_F(SimCli, RunStartingAtSpeedPassesTheIndependentCheck) {
  // A run that starts at 100 km/h: no start-up transient in the IMU or odometer.
  const fs::path out = dir_ / "fast";
  const CommandResult run =
      Shell(sim_ + " --scenario rich_high_town_a --out " + out.string() + " --duration 1.5");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const CommandResult check = Shell("/usr/bin/python3 " + checker_ + " " +
                                    (out / "run.bag").string() + " --duration-s 1.5");
  EXPECT_EQ(check.exit_code, 0) << check.out << check.err;
}

TEST_F(SimCli, ChangedRunWritesTheGroundTruthOfItsEdits) {
  const fs::path out = dir_ / "changed";
  const CommandResult run = Shell(sim_ + " --scenario rich_low_station_a_changed --out " +
                                  out.string() + " --duration 1");
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const std::string changes = ReadText(out / "changes.json");
  for (const char* kind : {"fallen_tree",
                           "vegetation_growth",
                           "object_removed",
                           "object_moved",
                           "object_added",
                           "centre_utm",
                           "intrudes_clearance",
                           "50N"}) {
    EXPECT_NE(changes.find(kind), std::string::npos) << kind;
  }
}

TEST_F(SimCli, MalformedScenarioNamesTheKeyAndLineAndWritesNothing) {
  const fs::path scenario = dir_ / "bad.yaml";
  std::ofstream(scenario) << "name: bad\n"
                             "alignment:\n"
                             "  - {type: straight, length_m: 900}\n"
                             "corridor:\n"
                             "  treez: {per_km: 3}\n"
                             "motion:\n"
                             "  phases: [{to_kmh: 30}, {for_s: 10}]\n";
  const fs::path out = dir_ / "out";
  const CommandResult run =
      Shell(sim_ + " --scenario " + scenario.string() + " --out " + out.string());
  EXPECT_EQ(run.exit_code, 2);
  EXPECT_NE(run.err.find("bad.yaml:5:"), std::string::npos) << run.err;
  EXPECT_NE(run.err.find("corridor.treez"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(out / "run.bag"));

  std::ofstream(scenario) << "name: bad\n"
                             "alignment:\n"
                             "  - {type: curve, length_m: 900, radius_m: 800, direction: up}\n";
  const CommandResult direction =
      Shell(sim_ + " --scenario " + scenario.string() + " --out " + out.string());
  EXPECT_EQ(direction.exit_code, 2);
  EXPECT_NE(direction.err.find("bad.yaml:3:"), std::string::npos) << direction.err;
  EXPECT_NE(direction.err.find("left or right"), std::string::npos) << direction.err;
}

TEST_F(SimCli, UnknownScenarioAndTooLongDurationAreClearErrors) {
  const CommandResult unknown = Shell(sim_ + " --scenario no_such_line --out " + dir_.string());
  EXPECT_EQ(unknown.exit_code, 2);
  EXPECT_NE(unknown.err.find("no_such_line"), std::string::npos);
  EXPECT_NE(unknown.err.find("rich_low_station_a"), std::string::npos);  // lists the built-ins

  const CommandResult too_long =
      Shell(sim_ + " --scenario demo --out " + (dir_ / "x").string() + " --duration 500");
  EXPECT_EQ(too_long.exit_code, 2);
  // Both durations as a user would write them (the demo runs 29.8 s).
  EXPECT_NE(too_long.err.find("--duration 500 s exceeds the scenario's motion profile of 29.8 s"),
            std::string::npos)
      << too_long.err;
  EXPECT_FALSE(fs::exists(dir_ / "x" / "run.bag"));

  const CommandResult missing = Shell(sim_ + " --scenario demo");
  EXPECT_NE(missing.exit_code, 0);
  EXPECT_NE(missing.err.find("--out"), std::string::npos);
}

}  // namespace
