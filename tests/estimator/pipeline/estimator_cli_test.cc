// raillomer-estimator end to end: a short simulated run scored against the truth, the same on a
// recorded bag, and clear errors on bad input that keep what was already written.

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <Eigen/Geometry>

#include "api/stream.h"
#include "api/trajectory.h"
#include "estimator/eval/association.h"
#include "estimator/mapping/map_export.h"
#include "tests/support/process.h"

namespace {

namespace fs = std::filesystem;
using raillomer::test::CommandResult;
using raillomer::test::ReadText;
using raillomer::test::ShellQuote;

class EstimatorCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scratch_ = new raillomer::test::ScratchDir("raillomer_estimator_cli_");
    // One short recording for the bag cases: 5 s of the demo run.
    const fs::path bag_dir = scratch_->path() / "bag";
    const CommandResult r =
        raillomer::test::RunCommand(Bin("raillomer-sim") + " --scenario demo --duration 5 --out " +
                                        ShellQuote(bag_dir.string()),
                                    scratch_->path());
    bag_ok_ = r.exit_code == 0;
    // Level on the first second (the default takes 4 s) so that the short bag yields poses.
    if (bag_ok_)
      std::ofstream(bag_dir / "rig.yaml", std::ios::app) << "estimator:\n  init_gravity_s: 1.0\n";
  }
  static void TearDownTestSuite() {
    delete scratch_;
    scratch_ = nullptr;
  }
  void SetUp() override {
    ASSERT_NE(scratch_, nullptr);
    ASSERT_TRUE(bag_ok_) << "raillomer-sim could not record the test bag";
  }

  static std::string Bin(const std::string& name) {
    return ShellQuote((raillomer::test::BinDir() / name).string());
  }
  static fs::path Dir() { return scratch_->path(); }
  static fs::path Bag() { return Dir() / "bag" / "run.bag"; }
  static fs::path Rig() { return Dir() / "bag" / "rig.yaml"; }
  /// A scenario file `<name>.yaml` in the scratch directory: a built-in `base` with `changes`.
  static fs::path WriteScenario(const std::string& name,
                                const std::string& base,
                                const std::string& changes) {
    const fs::path path = Dir() / (name + ".yaml");
    std::ofstream(path) << "base: " << base << "\nname: " << name << "\n" << changes;
    return path;
  }
  CommandResult Shell(const std::string& command) const {
    return raillomer::test::RunCommand(command, Dir());
  }
  CommandResult Estimate(const std::string& args) const {
    return Shell(Bin("raillomer-estimator") + " --quiet " + args);
  }
  /// Writes the rig of poor_low_embankment_b to embankment_rig/.
  static std::string EmbankmentSim() {
    return Bin("raillomer-sim") + " --scenario poor_low_embankment_b --duration 1 --out " +
           ShellQuote((Dir() / "embankment_rig").string());
  }
  /// `--sim <sim_args>` with GNSS off under the rig `rig_yaml` (saved as <name>.yaml, the run in
  /// <name>/): the error at its end (EndError), or 1e9 after a failed run.
  Eigen::Vector3d SimEndError(const std::string& sim_args,
                              const std::string& rig_yaml,
                              const std::string& name) const;
  /// The first 35 s of poor_low_embankment_b (SimEndError).
  Eigen::Vector3d EmbankmentEndError(const std::string& rig_yaml, const std::string& name) const {
    return SimEndError("poor_low_embankment_b --duration 35", rig_yaml, name);
  }
  /// The rig raillomer-sim writes (to <name>/) for the scenario file `scenario`, or "".
  std::string ScenarioRig(const fs::path& scenario, const std::string& name) const;
  /// Runs the estimator on the test bag with the rig's `from` replaced by `to`.
  CommandResult EstimateWithEditedRig(const std::string& from,
                                      const std::string& to,
                                      const std::string& name,
                                      const std::string& extra_args = "") const {
    std::string rig = ReadText(Rig());
    rig.replace(rig.find(from), from.size(), to);
    const fs::path edited = Dir() / (name + ".yaml");
    std::ofstream(edited) << rig;
    return Estimate("--bag " + ShellQuote(Bag().string()) + " --config " +
                    ShellQuote(edited.string()) + " --out " + ShellQuote((Dir() / name).string()) +
                    " " + extra_args);
  }
  static size_t CountLines(const fs::path& path) {
    std::ifstream in(path);
    size_t n = 0;
    for (std::string line; std::getline(in, line);) n += !line.empty() && line[0] != '#';
    return n;
  }

  static raillomer::test::ScratchDir* scratch_;
  static bool bag_ok_;
};

raillomer::test::ScratchDir* EstimatorCli::scratch_ = nullptr;
bool EstimatorCli::bag_ok_ = false;

TEST_F(EstimatorCli, ShortSimulatedRunTracksTheTruth) {
  const fs::path out = Dir() / "sim";
  const CommandResult r = Estimate("--sim demo --duration 15 --out " + ShellQuote(out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  // One pose per LiDAR frame (10 Hz) after the first 4 s (initial levelling), one timing row
  // each, keyframes and the summary.
  raillomer::api::Trajectory estimate;
  std::string error;
  ASSERT_TRUE(raillomer::api::ReadTum((out / "trajectory.tum").string(), &estimate, &error))
      << error;
  EXPECT_NEAR(static_cast<double>(estimate.poses.size()), 111.0, 2.0);
  EXPECT_EQ(CountLines(out / "timing.csv"), estimate.poses.size() + 1);
  EXPECT_GT(CountLines(out / "keyframes.tum"), 5u);
  size_t pcd = 0;
  for (const auto& entry : fs::directory_iterator(out / "keyframes"))
    pcd += entry.path().extension() == ".pcd";
  EXPECT_EQ(pcd, CountLines(out / "keyframes.tum"));
  const nlohmann::json summary = nlohmann::json::parse(ReadText(out / "summary.json"));
  EXPECT_EQ(summary["frames"].get<int>(), static_cast<int>(estimate.poses.size()));
  EXPECT_EQ(summary["keyframes"].get<size_t>(), pcd);
  EXPECT_EQ(summary["ablation"], "full");

  // Scored by raillomer-eval against the simulator's truth.
  const CommandResult e =
      Shell(Bin("raillomer-eval") + " --estimate " + ShellQuote((out / "trajectory.tum").string()) +
            " --truth " + ShellQuote((out / "truth.tum").string()) + " --align se3 --json " +
            ShellQuote((out / "eval.json").string()));
  ASSERT_EQ(e.exit_code, 0) << e.err;
  const nlohmann::json eval = nlohmann::json::parse(ReadText(out / "eval.json"));
  EXPECT_GT(eval["distance_m"].get<double>(), 50.0);
  EXPECT_LT(eval["ate_rmse_m"].get<double>(), 0.1);
  EXPECT_LT(eval["end_drift_pct"].get<double>(), 0.5);
}

/// The submaps a folder's index.csv lists (submaps/ or provisional/), decoded, each with the
/// sequence its index line gives.
void ReadSubmapFolder(const fs::path& dir,
                      std::vector<std::pair<uint64_t, raillomer::api::Submap>>* submaps) {
  std::ifstream index(dir / "index.csv");
  std::string line, error;
  std::getline(index, line);
  EXPECT_EQ(line.rfind("sequence,index,file,", 0), 0u) << line;
  while (std::getline(index, line)) {
    raillomer::api::Submap s;
    const std::string file = line.substr(line.find(',', line.find(',') + 1) + 1, 10);
    ASSERT_TRUE(raillomer::api::DecodeSubmapPcd(ReadText(dir / file), &s, &error))
        << file << ": " << error;
    submaps->emplace_back(std::stoull(line.substr(0, line.find(','))), std::move(s));
  }
}

/// provisional/ (--provisional-submaps): the run's start, held until the GNSS graph settles,
/// as provisional submaps in UTM, each of one placement, their keyframes within 2 m of where
/// the final trajectory puts them.
void ExpectProvisionalSubmapsNearTheTrajectory(const fs::path& out,
                                               const raillomer::api::Trajectory& trajectory) {
  std::map<int64_t, Eigen::Vector3d> final_at;
  for (const raillomer::api::StampedPose& p : trajectory.poses) final_at[p.stamp_ns] = p.p_world;
  std::vector<std::pair<uint64_t, raillomer::api::Submap>> submaps;
  ReadSubmapFolder(out / "provisional", &submaps);
  EXPECT_GE(submaps.size(), 1u);
  for (const auto& [sequence, s] : submaps) {
    EXPECT_EQ(s.utm_zone, "50N");
    EXPECT_GT(s.placement, 0u) << sequence;
    EXPECT_FALSE(s.points.empty()) << sequence;
    for (const raillomer::api::StampedPose& k : s.keyframes) {
      ASSERT_TRUE(final_at.count(k.stamp_ns)) << sequence;
      EXPECT_LT((k.p_world - final_at[k.stamp_ns]).norm(), 2.0) << sequence;
    }
  }
}

TEST_F(EstimatorCli, GnssPutsTheRunInUtm) {
  // The whole demo (0.3 km): aligned to UTM after 100 m, then a GNSS factor every 10 s; its
  // submaps and the global map in UTM.
  const fs::path out = Dir() / "utm";
  const CommandResult r =
      Estimate("--sim demo --no-keyframes --provisional-submaps --out " + ShellQuote(out.string()) +
               " --map " + ShellQuote((out / "map.ply").string()) + " --map-voxel 0.2");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(ReadText(out / "trajectory.tum").rfind("# utm_zone 50N\n", 0), 0u);
  const nlohmann::json summary = nlohmann::json::parse(ReadText(out / "summary.json"));
  EXPECT_TRUE(summary["georeferenced"].get<bool>());
  EXPECT_GE(summary["gnss"]["factors"].get<int>(), 2);
  // Scored in UTM with no alignment at all. The simulated receiver is single-point (errors of
  // 1-2.5 m that wander over minutes), and the run sits on its fixes: a metre or two, not the
  // hundreds of kilometres between the odometry frame and UTM.
  // The map is scored against the simulated corridor's planes and rail heads as well.
  const CommandResult e =
      Shell(Bin("raillomer-eval") + " --estimate " + ShellQuote((out / "trajectory.tum").string()) +
            " --truth " + ShellQuote((out / "truth.tum").string()) + " --align none --json " +
            ShellQuote((out / "eval.json").string()) + " --scenario demo --submaps " +
            ShellQuote((out / "submaps").string()));
  ASSERT_EQ(e.exit_code, 0) << e.err;
  const nlohmann::json eval = nlohmann::json::parse(ReadText(out / "eval.json"));
  EXPECT_LT(eval["ate_rmse_m"].get<double>(), 2.0);
  EXPECT_LT(eval["ate_max_m"].get<double>(), 3.0);
  // Issue 4's sharpness targets: 3 cm RMS normal to planes, rail heads from different
  // submaps within 3 cm (the demo reaches about 1.2 cm and 0.9 cm).
  const nlohmann::json& map = eval["map"];
  EXPECT_GT(map["plane_patches"].get<int>(), 50);
  EXPECT_LT(map["plane_rms_m"].get<double>(), 0.03);
  EXPECT_GT(map["rail_segments"].get<int>(), 50);
  EXPECT_LT(map["rail_spread_max_m"].get<double>(), 0.03);
  EXPECT_EQ(
      summary["submaps"]["ndt_applied"].get<int>() + summary["submaps"]["ndt_rejected"].get<int>(),
      summary["submaps"]["count"].get<int>() - 1);

  // Submaps of 10 keyframes, in UTM, with sequence numbers that only grow.
  raillomer::api::Trajectory trajectory;
  std::string error;
  ASSERT_TRUE(raillomer::api::ReadTum((out / "trajectory.tum").string(), &trajectory, &error));
  std::vector<std::pair<uint64_t, raillomer::api::Submap>> submaps;
  ReadSubmapFolder(out / "submaps", &submaps);
  for (size_t i = 0; i < submaps.size(); ++i) {
    const raillomer::api::Submap& s = submaps[i].second;
    EXPECT_EQ(s.sequence, submaps[i].first);
    EXPECT_TRUE(i == 0 || s.sequence > submaps[i - 1].second.sequence);
    EXPECT_EQ(s.utm_zone, "50N");
    EXPECT_LT((s.origin - trajectory.poses.front().p_world).head<2>().norm(), 400.0);
  }
  EXPECT_GE(submaps.size(), 3u);
  ExpectProvisionalSubmapsNearTheTrajectory(out, trajectory);
  std::vector<Eigen::Vector3d> points;
  std::vector<float> intensities;
  ASSERT_TRUE(
      raillomer::ReadMapFile((out / "map.ply").string(), &points, &intensities, nullptr, &error))
      << error;
  EXPECT_GT(points.size(), 10000u);
  for (size_t i = 0; i < points.size(); i += 97)
    ASSERT_LT((points[i] - trajectory.poses.front().p_world).head<2>().norm(), 600.0);
}

TEST_F(EstimatorCli, ARunWithoutAFixSaysItIsNotGeoreferenced) {
  // The receiver never gets a fix: the odometry still comes out, in the local frame.
  std::ofstream(Dir() / "no_fix.yaml")
      << Shell(Bin("raillomer-sim") + " --scenario demo --print-scenario").out
      << "events:\n  - {type: gnss_outage, at_s: 0, duration_s: 1000}\n";
  const fs::path out = Dir() / "no_fix";
  const CommandResult r =
      Estimate("--sim " + ShellQuote((Dir() / "no_fix.yaml").string()) +
               " --duration 12 --no-keyframes --out " + ShellQuote(out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.err.find("not georeferenced"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("no usable GNSS fix"), std::string::npos) << r.err;
  EXPECT_EQ(ReadText(out / "trajectory.tum").find("utm_zone"), std::string::npos);
  EXPECT_GT(CountLines(out / "trajectory.tum"), 60u);
  const nlohmann::json summary = nlohmann::json::parse(ReadText(out / "summary.json"));
  EXPECT_FALSE(summary["georeferenced"].get<bool>());
  EXPECT_EQ(summary["gnss"]["fixes"].get<int>(), 0);
}

TEST_F(EstimatorCli, RecordedBagGivesAPoseForEveryFrameAfterLevelling) {
  const fs::path out = Dir() / "from_bag";
  const CommandResult r =
      Estimate("--bag " + ShellQuote(Bag().string()) + " --config " + ShellQuote(Rig().string()) +
               " --out " + ShellQuote(out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NEAR(static_cast<double>(CountLines(out / "trajectory.tum")), 41.0, 2.0);
  const CommandResult e =
      Shell(Bin("raillomer-eval") + " --estimate " + ShellQuote((out / "trajectory.tum").string()) +
            " --truth " + ShellQuote((Dir() / "bag" / "truth.tum").string()) + " --align se3");
  EXPECT_EQ(e.exit_code, 0) << e.err;
}

/// The error at the run's last pose in the true body frame there (x along the track, positive
/// when the estimate runs ahead; y to the left), the estimate put on the truth by its first pose
/// (GNSS off: the drift since the start).
Eigen::Vector3d EndError(const fs::path& run) {
  raillomer::api::Trajectory estimate, truth;
  std::string error;
  EXPECT_TRUE(raillomer::api::ReadTum((run / "trajectory.tum").string(), &estimate, &error))
      << error;
  EXPECT_TRUE(raillomer::api::ReadTum((run / "truth.tum").string(), &truth, &error)) << error;
  const raillomer::eval::Association matched =
      raillomer::eval::AssociatePoses(estimate, truth, raillomer::eval::AssociationOptions{});
  EXPECT_TRUE(matched.ok) << matched.error;
  if (!matched.ok || matched.pairs.size() < 2) return Eigen::Vector3d::Constant(1e9);
  const raillomer::eval::PosePair& first = matched.pairs.front();
  const raillomer::eval::PosePair& last = matched.pairs.back();
  const Eigen::Isometry3d align = first.T_world_truth * first.T_world_est.inverse();
  const Eigen::Vector3d e =
      align * last.T_world_est.translation() - last.T_world_truth.translation();
  return last.T_world_truth.linear().transpose() * e;
}

/// The rig raillomer-sim wrote to `dir` (no `estimator:` section), or "" after a failed
/// assertion.
std::string SimulatedRig(const fs::path& dir, const CommandResult& sim) {
  EXPECT_EQ(sim.exit_code, 0) << sim.err;
  const std::string rig = ReadText(dir / "rig.yaml");
  EXPECT_EQ(rig.find("\nestimator:"), std::string::npos);
  return sim.exit_code == 0 ? rig : "";
}

Eigen::Vector3d EstimatorCli::SimEndError(const std::string& sim_args,
                                          const std::string& rig_yaml,
                                          const std::string& name) const {
  const fs::path config = Dir() / (name + ".yaml");
  std::ofstream(config) << rig_yaml;
  const fs::path out = Dir() / name;
  const CommandResult r =
      Estimate("--sim " + sim_args + " --no-gnss --no-submaps --no-keyframes --config " +
               ShellQuote(config.string()) + " --out " + ShellQuote(out.string()));
  EXPECT_EQ(r.exit_code, 0) << r.err;
  return r.exit_code == 0 ? EndError(out) : Eigen::Vector3d::Constant(1e9);
}

std::string EstimatorCli::ScenarioRig(const fs::path& scenario, const std::string& name) const {
  const fs::path dir = Dir() / name;
  return SimulatedRig(dir,
                      Shell(Bin("raillomer-sim") + " --scenario " + ShellQuote(scenario.string()) +
                            " --duration 1 --out " + ShellQuote(dir.string())));
}

// On an embankment the LiDARs see nothing along the track, and a wheel 2.4 % larger than the
// rig says (0.86 m against 0.84 m) runs the distance long by as much. The sleepers seen by the
// down LiDAR (track_bed, on by default) measure the distance instead: 35 s from standstill end
// 1.0 m ahead without them and 0.03 m with them. (A wheel 1.2 % larger ended 0.28 m ahead
// without them until the heading left out of the LiDAR factors was profiled instead of held;
// held, the registration's yaw pull moved the frames along the track through the masts on one
// side, and with the profile that run ends 0.09 m ahead.)
TEST_F(EstimatorCli, TheSleepersHoldTheDistanceWhenTheWheelSizeIsWrong) {
  std::string rig = SimulatedRig(Dir() / "embankment_rig", Shell(EmbankmentSim()));
  const std::string wheel = "wheel_diameter_m: 0.84";
  ASSERT_NE(rig.find(wheel), std::string::npos);
  rig.replace(rig.find(wheel), wheel.size(), "wheel_diameter_m: 0.86");
  const double without =
      EmbankmentEndError(rig + "estimator:\n  track_bed:\n    sigma_m: 0\n", "big_wheel_no_bed")
          .x();
  const double with = EmbankmentEndError(rig, "big_wheel").x();
  // The summary counts the frames the sleepers measured: nearly all of them, or none when off.
  const nlohmann::json on = nlohmann::json::parse(ReadText(Dir() / "big_wheel" / "summary.json"));
  const nlohmann::json off =
      nlohmann::json::parse(ReadText(Dir() / "big_wheel_no_bed" / "summary.json"));
  EXPECT_GT(on["bed_shifts"].get<double>(), 0.9 * on["frames"].get<double>());
  EXPECT_EQ(off["bed_shifts"].get<int>(), 0);
  EXPECT_GT(without, 0.2) << "without the sleepers";
  EXPECT_LT(std::fabs(with), 0.25 * without) << with << " m with, " << without << " m without";
}

/// The cells of one CSV line (a trailing comma gives a last empty cell).
std::vector<std::string> CsvCells(const std::string& row) {
  std::vector<std::string> cells;
  std::stringstream ss(row);
  for (std::string cell; std::getline(ss, cell, ',');) cells.push_back(cell);
  if (!row.empty() && row.back() == ',') cells.emplace_back();
  return cells;
}

/// The share of a run's timing.csv rows whose column `name` is 1.
double ShareOfFlaggedFrames(const fs::path& timing_csv,
                            const std::string& name,
                            double from_stamp_s = -1e300) {
  std::ifstream in(timing_csv);
  std::string row;
  std::getline(in, row);
  const std::vector<std::string> header = CsvCells(row);
  const auto column = std::find(header.begin(), header.end(), name);
  EXPECT_NE(column, header.end()) << name;
  if (column == header.end()) return -1.0;
  const size_t index = static_cast<size_t>(column - header.begin());
  size_t rows = 0, flagged = 0;
  while (std::getline(in, row)) {
    const std::vector<std::string> cells = CsvCells(row);
    if (cells.empty() || std::stod(cells[0]) < from_stamp_s) continue;
    ++rows;
    flagged += index < cells.size() && cells[index] == "1";
  }
  return rows == 0 ? -1.0 : static_cast<double>(flagged) / static_cast<double>(rows);
}

// On the embankment the LiDARs hold the heading only weakly (rails, ballast and masts all run
// along the track), so nearly every frame leaves it to the gyro (heading_projection); on the
// demo's corridor, with buildings and a station, almost none does. Switched off, none does.
TEST_F(EstimatorCli, WeaklyHeldHeadingsAreLeftToTheGyro) {
  const std::string rig = SimulatedRig(Dir() / "embankment_rig", Shell(EmbankmentSim()));
  ASSERT_FALSE(rig.empty());
  EmbankmentEndError(rig, "heading_projected");
  EmbankmentEndError(rig + "estimator:\n  heading_projection: 0\n", "heading_free");
  EXPECT_GT(ShareOfFlaggedFrames(Dir() / "heading_projected" / "timing.csv", "heading_projected"),
            0.8);
  EXPECT_EQ(ShareOfFlaggedFrames(Dir() / "heading_free" / "timing.csv", "heading_projected"), 0.0);
  const fs::path demo = Dir() / "demo_heading";
  const CommandResult r = Estimate("--sim demo --duration 15 --no-keyframes --no-submaps --out " +
                                   ShellQuote(demo.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_LT(ShareOfFlaggedFrames(demo / "timing.csv", "heading_projected"), 0.1);
}

// On a straight embankment with nothing but masts beside it, the rail heads matched as lines
// (rail_line_sigma_m) hold the train sideways: 35 s from standstill (the sleepers on, the
// straight track's heading hold off, as it would hold the heading itself) drift 0.21 m sideways
// without them and 0.03 m with them.
TEST_F(EstimatorCli, RailHeadLinesHoldTheTrainSideways) {
  const std::string rig = SimulatedRig(Dir() / "embankment_rig", Shell(EmbankmentSim()));
  ASSERT_FALSE(rig.empty());
  const std::string no_hold = rig + "estimator:\n  straight_track:\n    sigma_rad: 0\n";
  const double without = std::fabs(EmbankmentEndError(no_hold, "no_rail_lines").y());
  const double with =
      std::fabs(EmbankmentEndError(no_hold + "  rail_line_sigma_m: 0.1\n", "rail_lines").y());
  EXPECT_GT(without, 0.1);
  EXPECT_LT(with, 0.5 * without) << with << " m with, " << without << " m without";
}

// A train on straight track does not turn. The embankment is straight, and once the gyro has
// shown that for 5 s (after the re-levelling at 10 s) the heading is held there: 35 s from
// standstill end 0.02 m to the side with the hold and 0.21 m without it (heading 0.003 against
// 0.11 deg), the hold on in two frames of three.
TEST_F(EstimatorCli, TheHeadingHoldsOnStraightTrack) {
  const std::string rig = SimulatedRig(Dir() / "embankment_rig", Shell(EmbankmentSim()));
  ASSERT_FALSE(rig.empty());
  const double with = std::fabs(EmbankmentEndError(rig, "straight_hold").y());
  const double without = std::fabs(
      EmbankmentEndError(rig + "estimator:\n  straight_track:\n    sigma_rad: 0\n", "no_hold").y());
  EXPECT_GT(without, 0.1);
  EXPECT_LT(with, 0.25 * without) << with << " m with, " << without << " m without";
  EXPECT_GT(ShareOfFlaggedFrames(Dir() / "straight_hold" / "timing.csv", "straight_hold"), 0.5);
  EXPECT_EQ(ShareOfFlaggedFrames(Dir() / "no_hold" / "timing.csv", "straight_hold"), 0.0);
}

/// Column `name` of the last row of a run's timing.csv (NaN if missing).
double LastValue(const fs::path& timing_csv, const std::string& name) {
  std::ifstream in(timing_csv);
  std::string row, last;
  std::getline(in, row);
  const std::vector<std::string> header = CsvCells(row);
  const auto column = std::find(header.begin(), header.end(), name);
  EXPECT_NE(column, header.end()) << name;
  while (std::getline(in, row))
    if (!row.empty()) last = row;
  const std::vector<std::string> cells = CsvCells(last);
  const size_t index = static_cast<size_t>(column - header.begin());
  if (column == header.end() || index >= cells.size()) return std::nan("");
  return std::stod(cells[index]);
}

// A car body never sits exactly along the track: load and mounting pitch it on its suspension.
// 30 s at 120 km/h with the body 1.6 mrad nose-down: taken to move along its x axis, the wheels'
// path climbs against the LiDARs' ground, the pitch drifts off with the gyro's y bias and the
// run ends 0.47 % of its 1 km off (raillomer-eval, se3); with the pitch estimated (-1.38 mrad,
// where the rail joints' one-sided dips add +0.16), 0.02 %.
TEST_F(EstimatorCli, APitchedCarBodyIsNotTakenToClimb) {
  const fs::path scenario = WriteScenario(
      "pitched_body",
      "long_20km",
      "motion: {start_m: 18100, start_speed_kmh: 120, phases: [{for_s: 30}], body_pitch_mrad: "
      "1.6}\n");
  const std::string rig = ScenarioRig(scenario, "pitched_rig");
  ASSERT_FALSE(rig.empty());
  const std::string sim = ShellQuote(scenario.string());
  const double estimated = SimEndError(sim, rig, "pitched_estimated").norm();
  const double held =
      SimEndError(sim,
                  rig + "estimator:\n  odometer_pitch_sigma_rad: 0\n  odometer_yaw_sigma_rad: 0\n",
                  "pitched_held")
          .norm();
  EXPECT_GT(held, 1.0);
  EXPECT_LT(estimated, 0.15 * held) << estimated << " m estimated, " << held << " m held";
  const double pitch = LastValue(Dir() / "pitched_estimated" / "timing.csv", "odometer_pitch_mrad");
  EXPECT_NEAR(pitch, -1.44, 0.4);
  EXPECT_EQ(LastValue(Dir() / "pitched_held" / "timing.csv", "odometer_pitch_mrad"), 0.0);
}

// In a tunnel the LiDARs see the distance through lamps and refuges every 25-50 m alone, and
// their registration there pulls each frame back (40-50 mm a frame at true poses, LiDARs
// alone). Where the sleepers measured a frame, its weak direction along the track is theirs and
// the wheel's (degeneracy_projection_along): 30 s at 100 km/h inside tunnel_gnss_outage's tunnel
// end 1.02 m short with the LiDARs' pull and 0.02 m long with it left out.
TEST_F(EstimatorCli, InATunnelTheSleepersAndTheWheelMeasureTheDistance) {
  const fs::path scenario =
      WriteScenario("in_tunnel",
                    "tunnel_gnss_outage",
                    "motion: {start_m: 850, start_speed_kmh: 100, phases: [{for_s: 30}]}\n");
  const std::string rig = ScenarioRig(scenario, "tunnel_rig");
  ASSERT_FALSE(rig.empty());
  const std::string sim = ShellQuote(scenario.string());
  const double remapped = SimEndError(sim, rig, "tunnel_remapped").x();
  const double pulled =
      SimEndError(sim, rig + "estimator:\n  degeneracy_projection_along: 0\n", "tunnel_pulled").x();
  EXPECT_LT(pulled, -0.6) << "the LiDARs' pull";
  EXPECT_LT(std::fabs(remapped), 0.15 * std::fabs(pulled))
      << remapped << " m remapped, " << pulled << " m pulled";
  EXPECT_GT(ShareOfFlaggedFrames(Dir() / "tunnel_remapped" / "timing.csv", "projected"), 0.3);
  EXPECT_LT(ShareOfFlaggedFrames(Dir() / "tunnel_pulled" / "timing.csv", "projected"), 0.1);
}

// A worn wheel reads 8 % long (the scale settles at 1 / 1.08), and slips 20 % for 4 s: the
// slip's readings are dropped, and once it is over the odometer is believed again. The reading
// is checked against the inertial prediction in metres; the check once took the scale twice
// (phi is integrated at it), so a worn wheel looked 7 % short and was dropped for good (0 % of
// the frames after the slip used it; winter_wheel_slip seed 3 lost it for 60 s and drifted
// 0.21 %).
TEST_F(EstimatorCli, AWornWheelIsBelievedAgainAfterASlip) {
  const fs::path scenario =
      WriteScenario("worn_wheel",
                    "winter_wheel_slip",
                    "odometer: {scale_error: 0.08, creep_sigma: 0.005}\n"
                    "events: [{type: wheel_slip, at_s: 14, duration_s: 4, slip: 0.2}]\n");
  const fs::path out = Dir() / "worn_wheel";
  const CommandResult r = Estimate("--sim " + ShellQuote(scenario.string()) +
                                   " --duration 30 --no-gnss --no-submaps --no-keyframes --out " +
                                   ShellQuote(out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const double t0 = 1600000000.0;  // the simulator's first stamp
  EXPECT_GT(ShareOfFlaggedFrames(out / "timing.csv", "odometer_used", t0 + 7.0), 0.8);
  EXPECT_GT(ShareOfFlaggedFrames(out / "timing.csv", "odometer_used", t0 + 20.0), 0.95);
  const nlohmann::json summary = nlohmann::json::parse(ReadText(out / "summary.json"));
  // The slip's 4 s are 40 frames.
  EXPECT_GT(summary["odometer_outliers"].get<int>(), 25);
  EXPECT_LT(summary["odometer_outliers"].get<int>(), 60);
  EXPECT_NEAR(LastValue(out / "timing.csv", "odometer_scale"), 1.0 / 1.08, 0.01);
}

// Without the IMU no gyro can carry the heading, so --lidar-only never leaves it out of the
// LiDAR factors: the demo's first, weakly held frames at the station would otherwise let it turn
// freely (the whole demo ended 97 % of its distance off).
TEST_F(EstimatorCli, LidarOnlyKeepsTheHeadingInTheLidarFactors) {
  const fs::path out = Dir() / "lidar_only_heading";
  const CommandResult r =
      Estimate("--sim demo --duration 8 --lidar-only --no-gnss --no-keyframes --no-submaps --out " +
               ShellQuote(out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(ShareOfFlaggedFrames(out / "timing.csv", "heading_projected"), 0.0);
  EXPECT_LT(EndError(out).norm(), 0.5);
}

TEST_F(EstimatorCli, AblationSwitchesRunAndNameThemselves) {
  const fs::path out = Dir() / "lidar_only";
  const CommandResult r =
      Estimate("--bag " + ShellQuote(Bag().string()) + " --config " + ShellQuote(Rig().string()) +
               " --lidar-only --no-keyframes --out " + ShellQuote(out.string()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(ReadText(out / "trajectory.tum").find("lidar-only"), std::string::npos);
  EXPECT_FALSE(fs::exists(out / "keyframes"));
  const nlohmann::json summary = nlohmann::json::parse(ReadText(out / "summary.json"));
  EXPECT_EQ(summary["ablation"], "lidar-only");
  // Taken for the submaps though none is written.
  EXPECT_GT(summary["keyframes"].get<int>(), 0);
}

TEST_F(EstimatorCli, MissingTopicIsNamed) {
  const CommandResult r =
      EstimateWithEditedRig("/livox/lidar_down", "/livox/lidar_middle", "missing");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("/livox/lidar_middle"), std::string::npos) << r.err;
}

TEST_F(EstimatorCli, WrongMessageTypeIsNamed) {
  // The IMU topic pointed at the GNSS receiver's NavSatFix messages (GNSS off: with it on, the
  // topic would be configured twice, which is an error of its own).
  const CommandResult r =
      EstimateWithEditedRig("topic: /imu/data", "topic: /gnss/fix", "type", "--no-gnss");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("sensor_msgs/NavSatFix"), std::string::npos) << r.err;
}

TEST_F(EstimatorCli, TruncatedBagKeepsTheFramesBeforeTheCut) {
  const std::string bytes = ReadText(Bag());
  std::ofstream(Dir() / "cut.bag", std::ios::binary) << bytes.substr(0, bytes.size() * 6 / 10);
  const fs::path out = Dir() / "cut";
  const CommandResult r =
      Estimate("--bag " + ShellQuote((Dir() / "cut.bag").string()) + " --config " +
               ShellQuote(Rig().string()) + " --out " + ShellQuote(out.string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("stopped early"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("truncated"), std::string::npos) << r.err;
  // What was written is a valid trajectory of the frames before the cut.
  raillomer::api::Trajectory estimate;
  std::string error;
  ASSERT_TRUE(raillomer::api::ReadTum((out / "trajectory.tum").string(), &estimate, &error))
      << error;
  EXPECT_GT(estimate.poses.size(), 15u);
  EXPECT_LT(estimate.poses.size(), 40u);
  EXPECT_TRUE(fs::exists(out / "summary.json"));
}

TEST_F(EstimatorCli, UsageErrorsAreClear) {
  CommandResult r = Estimate("--bag " + ShellQuote(Bag().string()) + " --out " +
                             ShellQuote((Dir() / "x").string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--config is required"), std::string::npos) << r.err;
  r = Estimate("--bag /nonexistent/run.bag --config " + ShellQuote(Rig().string()) + " --out " +
               ShellQuote((Dir() / "y").string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("/nonexistent/run.bag"), std::string::npos) << r.err;
  r = Estimate("--sim demo --out " + ShellQuote((Dir() / "m").string()) + " --map map.xyz");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find(".ply, .pcd or .las"), std::string::npos) << r.err;
  r = Estimate("--sim demo --out " + ShellQuote((Dir() / "m").string()) + " --map-voxel 0.5");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("need --map"), std::string::npos) << r.err;
  r = Estimate("--sim no_such_scenario --out " + ShellQuote((Dir() / "z").string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("no_such_scenario"), std::string::npos) << r.err;
  // The test rig ends with its estimator section: a misspelt key in it.
  std::ofstream(Dir() / "bad.yaml") << ReadText(Rig()) << "  window_sise: 4\n";
  r = Estimate("--bag " + ShellQuote(Bag().string()) + " --config " +
               ShellQuote((Dir() / "bad.yaml").string()) + " --out " +
               ShellQuote((Dir() / "w").string()));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("estimator.window_sise"), std::string::npos) << r.err;
  // Values CLI11's own checks let through: an empty source, a duration that is not a number.
  for (const char* args : {"--bag ''", "--sim ''", "--sim demo --duration nan"}) {
    r = Estimate(std::string(args) + " --out " + ShellQuote((Dir() / "e").string()));
    EXPECT_NE(r.exit_code, 0) << args;
    EXPECT_NE(r.err.find(std::string(args).find("nan") != std::string::npos ? "finite number"
                                                                            : "must not be empty"),
              std::string::npos)
        << args << ": " << r.err;
  }
}

}  // namespace
