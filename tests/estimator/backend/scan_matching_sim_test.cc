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

TEST(ScanMatchingSim, TruthMapHoldsTheTruthAtSpeed) {
  sim::Scenario scenario;
  std::string error;
  ASSERT_TRUE(sim::LoadScenario("rich_high_town_a", &scenario, &error)) << error;  // 100 km/h
  sim::SimOptions options;
  options.duration_s = 10.0;
  auto simulator = sim::Simulator::Create(scenario, options, &error);
  ASSERT_TRUE(simulator) << error;
  EstimatorConfig config;
  ASSERT_TRUE(ParseEstimatorConfig(simulator->RigYaml(), "rig.yaml", &config, &error)) << error;
  const EstimatorOptions& o = config.options;
  const sim::TruthMotion& truth = simulator->truth();
  const double t0_abs = static_cast<double>(simulator->StampNs(0.0)) * 1e-9;
  const double period = 1.0 / config.rig.lidars[0].rate_hz;
  std::map<std::string, int> lidar_index;
  for (size_t i = 0; i < config.rig.lidars.size(); ++i)
    lidar_index[config.rig.lidars[i].topic] = static_cast<int>(i);

  LocalMap edges(o.map_voxel_m, o.map_points_per_voxel);
  LocalMap planes(o.map_voxel_m, o.map_points_per_voxel);
  MatchOptions match;
  match.max_distance_m = o.max_correspondence_m;
  // Pose errors of the registration in the true body frame: x, y, z (m), roll, pitch, yaw (rad).
  Eigen::Matrix<double, 6, 1> sum = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> sum_sq = sum;
  int registered = 0;
  auto process = [&](uint64_t timebase_ns, const std::vector<std::pair<int, io::LidarFrame>>& in) {
    const double t_start = static_cast<double>(timebase_ns) * 1e-9 - t0_abs;
    const Eigen::Isometry3d T_end = truth.Pose(t_start + period);
    FeatureSet all;
    for (const auto& [index, frame] : in) {
      Scan scan = ScanFromLidarFrame(frame, index, period);
      Preprocess(o.preprocess, &scan);
      Deskew(config.rig.lidars[static_cast<size_t>(index)].T_body_lidar,
             T_end.inverse() * truth.Pose(t_start),
             &scan);
      const FeatureSet f = ExtractLoamFeatures(o.loam, scan);
      all.edges.insert(all.edges.end(), f.edges.begin(), f.edges.end());
      all.planes.insert(all.planes.end(), f.planes.begin(), f.planes.end());
    }
    if (t_start > 3.0) {  // a map of 3 s first
      const LidarMatches m = MatchFeatures(match, all, T_end, edges, planes);
      const LidarOnlySolution s = SolveLidarOnly(m, T_end, 8);
      const Eigen::Isometry3d d = T_end.inverse() * s.T_world_body;
      const Eigen::Vector3d angle =
          Eigen::AngleAxisd(d.linear()).angle() *
          Eigen::AngleAxisd(d.linear()).axis();  // small: roll, pitch, yaw
      Eigen::Matrix<double, 6, 1> e;
      e << d.translation(), angle;
      sum += e;
      sum_sq += e.cwiseProduct(e);
      ++registered;
    }
    std::vector<Eigen::Vector3d> edges_world, planes_world;
    for (const auto& p : all.edges) edges_world.push_back(T_end * p.cast<double>());
    for (const auto& p : all.planes) planes_world.push_back(T_end * p.cast<double>());
    edges.Add(edges_world);
    planes.Add(planes_world);
  };
  std::map<uint64_t, std::vector<std::pair<int, io::LidarFrame>>> pending;
  io::SensorMessage m;
  while (simulator->Next(&m)) {
    const auto* frame = std::get_if<io::LidarFrame>(&m.data);
    if (!frame) continue;
    auto& frames = pending[frame->timebase_ns];
    frames.push_back({lidar_index.at(m.topic), *frame});
    if (frames.size() == lidar_index.size()) {
      process(pending.begin()->first, pending.begin()->second);
      pending.erase(pending.begin());
    }
  }
  ASSERT_GT(registered, 60);
  const Eigen::Matrix<double, 6, 1> mean = sum / registered;
  const Eigen::Matrix<double, 6, 1> rms = (sum_sq / registered).cwiseSqrt();
  const char* names[6] = {"x", "y", "z", "roll", "pitch", "yaw"};
  for (int k = 0; k < 6; ++k) {
    const double scale = k < 3 ? 1.0 : 180.0 / M_PI;
    std::printf("%-5s mean %+.4f rms %.4f %s over %d frames\n",
                names[k],
                mean(k) * scale,
                rms(k) * scale,
                k < 3 ? "m" : "deg",
                registered);
  }
  // At 28 m/s a frame moves 2.8 m: a 1 ms timing error would show as 2.8 cm along x.
  for (int k = 0; k < 3; ++k) {
    EXPECT_LT(std::abs(mean(k)), 0.01) << names[k];
    EXPECT_LT(rms(k), 0.03) << names[k];
  }
  // Pitch and roll carry a lever arm of tens of metres to the scan's far points.
  for (int k = 3; k < 6; ++k) {
    EXPECT_LT(std::abs(mean(k)) * 180.0 / M_PI, k == 5 ? 0.02 : 0.005) << names[k];
    EXPECT_LT(rms(k) * 180.0 / M_PI, 0.05) << names[k];
  }
}

}  // namespace
}  // namespace raillomer
