// Scan-to-map registration on the simulator's own LiDAR frames, through the estimator's
// frontend (preprocessing, deskewing with the true motion, LOAM features), against a local map
// built from the earlier frames at their true poses. At 100 km/h the registration must stay at
// the truth: a bias here (a timing, deskew or range-dependent error of the LiDAR chain) is what
// the estimator would follow, frame after frame, into drift.

#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/backend/local_map.h"
#include "estimator/backend/scan_matching.h"
#include "estimator/features/loam_features.h"
#include "estimator/pipeline/config.h"
#include "estimator/preprocess/filters.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

/// Mean and RMS of the registration's pose error in the true body frame: x, y, z (m), roll,
/// pitch, yaw (rad).
struct RegistrationErrors {
  Eigen::Matrix<double, 6, 1> mean = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> rms = Eigen::Matrix<double, 6, 1>::Zero();
  int frames = 0;
};

constexpr const char* kAxisNames[6] = {"x", "y", "z", "roll", "pitch", "yaw"};

/// Frames in, registered against a map of the frames before them, all at their true poses.
class TruthMapRegistration {
 public:
  TruthMapRegistration(const EstimatorConfig& config,
                       const sim::TruthMotion& truth,
                       double t0_abs,
                       double edge_max_spread_m)
      : config_(config),
        o_(config.options),
        truth_(truth),
        t0_abs_(t0_abs),
        period_(1.0 / config.rig.lidars[0].rate_hz),
        edges_(o_.map_voxel_m, o_.map_points_per_voxel),
        planes_(o_.map_voxel_m, o_.map_points_per_voxel) {
    match_.max_distance_m = o_.max_correspondence_m;
    match_.line_max_spread_m = edge_max_spread_m;
  }

  /// One sweep of every LiDAR: registered once the map holds 3 s, then added to the map.
  void Process(uint64_t timebase_ns, const std::vector<std::pair<int, io::LidarFrame>>& in) {
    const double t_start = static_cast<double>(timebase_ns) * 1e-9 - t0_abs_;
    const Eigen::Isometry3d T_end = truth_.Pose(t_start + period_);
    const FeatureSet all = FeaturesAtTruth(t_start, T_end, in);
    if (t_start > 3.0) Register(all, T_end);
    AddToMap(all, T_end);
  }

  /// Mean and RMS over the registered frames.
  RegistrationErrors Errors() const {
    RegistrationErrors out;
    out.frames = frames_;
    if (frames_ == 0) return out;
    out.mean = sum_ / frames_;
    out.rms = (sum_sq_ / frames_).cwiseSqrt();
    return out;
  }

 private:
  /// Preprocessed, deskewed with the true motion, LOAM features of every LiDAR in the body frame.
  FeatureSet FeaturesAtTruth(double t_start,
                             const Eigen::Isometry3d& T_end,
                             const std::vector<std::pair<int, io::LidarFrame>>& in) const {
    FeatureSet all;
    for (const auto& [index, frame] : in) {
      Scan scan = ScanFromLidarFrame(frame, index, period_);
      Preprocess(o_.preprocess, &scan);
      Deskew(config_.rig.lidars[static_cast<size_t>(index)].T_body_lidar,
             T_end.inverse() * truth_.Pose(t_start),
             &scan);
      const FeatureSet f = ExtractLoamFeatures(o_.loam, scan);
      all.edges.insert(all.edges.end(), f.edges.begin(), f.edges.end());
      all.planes.insert(all.planes.end(), f.planes.begin(), f.planes.end());
    }
    return all;
  }

  /// Registers from the true pose and adds the pose error to the sums.
  void Register(const FeatureSet& all, const Eigen::Isometry3d& T_end) {
    const LidarMatches m = MatchFeatures(match_, all, T_end, edges_, planes_);
    const LidarOnlySolution s = SolveLidarOnly(m, T_end, 8);
    const Eigen::Isometry3d d = T_end.inverse() * s.T_world_body;
    const Eigen::Vector3d angle = Eigen::AngleAxisd(d.linear()).angle() *
                                  Eigen::AngleAxisd(d.linear()).axis();  // small: roll, pitch, yaw
    Eigen::Matrix<double, 6, 1> e;
    e << d.translation(), angle;
    sum_ += e;
    sum_sq_ += e.cwiseProduct(e);
    ++frames_;
  }

  void AddToMap(const FeatureSet& all, const Eigen::Isometry3d& T_end) {
    std::vector<Eigen::Vector3d> edges_world, planes_world;
    for (const auto& p : all.edges) edges_world.push_back(T_end * p.cast<double>());
    for (const auto& p : all.planes) planes_world.push_back(T_end * p.cast<double>());
    edges_.Add(edges_world);
    planes_.Add(planes_world);
  }

  const EstimatorConfig& config_;
  const EstimatorOptions& o_;
  const sim::TruthMotion& truth_;
  const double t0_abs_;
  const double period_;
  LocalMap edges_, planes_;
  MatchOptions match_;
  Eigen::Matrix<double, 6, 1> sum_ = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> sum_sq_ = Eigen::Matrix<double, 6, 1>::Zero();
  int frames_ = 0;
};

void PrintErrors(const RegistrationErrors& out) {
  for (int k = 0; k < 6; ++k) {
    const double scale = k < 3 ? 1.0 : 180.0 / M_PI;
    std::printf("%-5s mean %+.4f rms %.4f %s over %d frames\n",
                kAxisNames[k],
                out.mean(k) * scale,
                out.rms(k) * scale,
                k < 3 ? "m" : "deg",
                out.frames);
  }
}

/// Runs `scenario_name` for duration_s (< 0: the whole run; noise as the scenario has it, or none
/// in the LiDAR ranges with `noise_free_lidar`) and registers every frame after the first 3 s
/// against the map of the frames before it, from the true pose.
RegistrationErrors RegisterAtTruth(const std::string& scenario_name,
                                   double duration_s,
                                   bool noise_free_lidar,
                                   double edge_max_spread_m = 0.0) {
  sim::Scenario scenario;
  std::string error;
  EXPECT_TRUE(sim::LoadScenario(scenario_name, &scenario, &error)) << error;
  if (noise_free_lidar) {
    scenario.range_noise_m = 0.0;
    scenario.angular_noise_deg = 0.0;
  }
  sim::SimOptions options;
  options.duration_s = duration_s;
  auto simulator = sim::Simulator::Create(scenario, options, &error);
  EXPECT_TRUE(simulator) << error;
  if (!simulator) return {};
  EstimatorConfig config;
  EXPECT_TRUE(ParseEstimatorConfig(simulator->RigYaml(), "rig.yaml", &config, &error)) << error;
  std::map<std::string, int> lidar_index;
  for (size_t i = 0; i < config.rig.lidars.size(); ++i)
    lidar_index[config.rig.lidars[i].topic] = static_cast<int>(i);
  TruthMapRegistration registration(config,
                                    simulator->truth(),
                                    static_cast<double>(simulator->StampNs(0.0)) * 1e-9,
                                    edge_max_spread_m);
  // Frames of one sweep share a timebase; a sweep is processed once every LiDAR's frame is in.
  std::map<uint64_t, std::vector<std::pair<int, io::LidarFrame>>> pending;
  io::SensorMessage m;
  while (simulator->Next(&m)) {
    const auto* frame = std::get_if<io::LidarFrame>(&m.data);
    if (!frame) continue;
    auto& frames = pending[frame->timebase_ns];
    frames.push_back({lidar_index.at(m.topic), *frame});
    if (frames.size() == lidar_index.size()) {
      registration.Process(pending.begin()->first, pending.begin()->second);
      pending.erase(pending.begin());
    }
  }
  const RegistrationErrors out = registration.Errors();
  if (out.frames > 0) PrintErrors(out);
  return out;
}

TEST(ScanMatchingSim, TruthMapHoldsTheTruthAtSpeed) {
  const RegistrationErrors e = RegisterAtTruth("rich_high_town_a", 10.0, false);  // 100 km/h
  ASSERT_GT(e.frames, 60);
  // At 28 m/s a frame moves 2.8 m: a 1 ms timing error would show as 2.8 cm along x.
  for (int k = 0; k < 3; ++k) {
    EXPECT_LT(std::abs(e.mean(k)), 0.01) << kAxisNames[k];
    EXPECT_LT(e.rms(k), 0.03) << kAxisNames[k];
  }
  // Pitch and roll carry a lever arm of tens of metres to the scan's far points.
  for (int k = 3; k < 6; ++k) {
    EXPECT_LT(std::abs(e.mean(k)) * 180.0 / M_PI, k == 5 ? 0.02 : 0.005) << kAxisNames[k];
    EXPECT_LT(e.rms(k) * 180.0 / M_PI, 0.05) << kAxisNames[k];
  }
}

// A straight embankment: ballast, formation and slopes under the down LiDAR, masts every 60 m
// for the up one. Its soft creases are where curvature picks edge points at places that move
// with range; matched to scattered map neighbours they turn every frame to the left, which the
// estimator follows into a heading drift of 8e-5 rad/s with a perfect IMU. The spread check on
// edge neighbours (edge_max_spread_m; off by default: docs/notebook/estimator-results.md) takes
// most of it away.
TEST(ScanMatchingSim, EdgeSpreadCheckKeepsSoftCreasesFromTurningTheRegistration) {
  const RegistrationErrors e = RegisterAtTruth("poor_low_embankment_b", -1.0, true, 0.05);
  ASSERT_GT(e.frames, 1000);
  // Without the check on the edge neighbours' spread: yaw +0.041 deg, y -6.4 mm; with it +0.023
  // deg and -0.6 mm. Frame to frame the yaw scatters by 0.2 deg and y by 5 cm here.
  EXPECT_LT(std::abs(e.mean(5)) * 180.0 / M_PI, 0.03) << "yaw";
  EXPECT_LT(std::abs(e.mean(1)), 0.003) << "y";
}

}  // namespace
}  // namespace raillomer
