// The map pipeline's own floor: a simulated run's frames, preprocessed and grouped into submaps
// at their true poses, scored by the map sharpness check. Whatever the estimator's maps lose
// beyond this is the trajectory's doing.
#include <cstdio>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/eval/map_sharpness.h"
#include "estimator/mapping/submap_builder.h"
#include "estimator/preprocess/filters.h"
#include "estimator/sim/simulator.h"

namespace raillomer::eval {
namespace {

/// Frame `frame` of both LiDARs as a keyframe at its true pose: preprocessed, each point moved to
/// the frame's end by the true motion.
SubmapKeyframe KeyframeAtTruth(sim::Simulator& simulator, uint64_t frame) {
  const sim::TruthMotion& truth = simulator.truth();
  const double t0 = 0.1 * static_cast<double>(frame);
  const Eigen::Isometry3d T_end = truth.Pose(t0 + 0.1);
  SubmapKeyframe keyframe;
  keyframe.stamp_ns = static_cast<int64_t>(frame) * 100'000'000;
  keyframe.T_world_body = keyframe.T_odom_body = T_end;
  for (size_t unit = 0; unit < simulator.lidars().size(); ++unit) {
    const sim::LivoxHorizonModel& lidar = simulator.lidars()[unit];
    io::LidarFrame message;
    lidar.Scan(
        frame,
        t0,
        [&truth](double t) { return truth.Pose(t); },
        simulator.caster(),
        &message.points,
        nullptr);
    Scan scan = ScanFromLidarFrame(message, static_cast<int>(unit), 0.1);
    Preprocess(PreprocessOptions(), &scan);
    for (const ScanPoint& p : scan.points) {
      const Eigen::Isometry3d T_end_t = T_end.inverse() * truth.Pose(t0 + p.time_s);
      keyframe.points_body.push_back(
          (T_end_t * lidar.T_body_lidar() * p.p.cast<double>()).cast<float>());
      keyframe.intensities.push_back(p.intensity);
    }
  }
  return keyframe;
}

TEST(MapSharpness, SubmapsBuiltAtTruePosesAgreeOnTheRailHeadsWellWithinTheTarget) {
  // 25 s of the canted curve at 140 km/h: each frame is a keyframe 3.9 m on (as the estimator
  // takes one every 2 m), both LiDARs' points moved to the frame's end by the true motion. The
  // submaps take their sideways slip out as the estimator's do (the car body's sway is no
  // slip: without it, 1.30 cm, the same).
  sim::Scenario scenario;
  std::string error;
  ASSERT_TRUE(sim::LoadScenario("poor_high_open_a", &scenario, &error)) << error;
  sim::SimOptions sim_options;
  sim_options.duration_s = 51.0;
  auto simulator = sim::Simulator::Create(scenario, sim_options, &error);
  ASSERT_TRUE(simulator) << error;
  SubmapOptions options;
  options.icp = false;
  options.ndt = false;
  // The wheels on the rail below the body, as the simulator's rig has them.
  options.p_body_odometer = Eigen::Vector3d(0.0, 0.0, -scenario.body_height_m);
  SubmapBuilder builder(options);
  MapSharpness sharpness(
      SelectReferenceTriangles(simulator->world().mesh(), Eigen::Vector3d::Zero()));
  auto score = [&sharpness](const std::vector<api::Submap>& submaps) {
    for (const api::Submap& s : submaps) sharpness.AddSubmap(s, Eigen::Isometry3d::Identity());
  };
  for (uint64_t frame = 250; frame < 500; ++frame)
    score(builder.Add(KeyframeAtTruth(*simulator, frame)));
  score(builder.Flush());
  const SharpnessResult r = sharpness.Result();
  std::printf("%zu submaps, %zu rail segments: spread median %.4f p95 %.4f max %.4f m\n",
              r.submaps,
              r.rail_segments,
              r.rail_spread_median_m,
              r.rail_spread_p95_m,
              r.rail_spread_max_m);
  EXPECT_EQ(r.submaps, 25u);
  EXPECT_GT(r.rail_segments, 150u);
  EXPECT_LT(r.rail_spread_p95_m, 0.01);
  EXPECT_LT(r.rail_spread_max_m, 0.015);  // the target is 3 cm
}

}  // namespace
}  // namespace raillomer::eval
