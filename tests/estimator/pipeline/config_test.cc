#include "estimator/pipeline/config.h"

#include <string>
#include <utility>

#include <gtest/gtest.h>

#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

std::string DemoRigYaml() {
  sim::Scenario scenario;
  std::string error;
  EXPECT_TRUE(sim::LoadScenario("demo", &scenario, &error)) << error;
  sim::SimOptions options;
  options.lidar = false;
  options.duration_s = 1.0;
  auto simulator = sim::Simulator::Create(scenario, options, &error);
  EXPECT_TRUE(simulator) << error;
  return simulator->RigYaml();
}

TEST(EstimatorConfig, ReadsTheSimulatorsRig) {
  EstimatorConfig config;
  std::string error;
  ASSERT_TRUE(ParseEstimatorConfig(DemoRigYaml(), "rig.yaml", &config, &error)) << error;
  ASSERT_EQ(config.rig.lidars.size(), 2u);
  EXPECT_EQ(config.rig.lidars[0].topic, "/livox/lidar_up");
  EXPECT_FALSE(config.rig.lidars[0].looks_down());
  EXPECT_TRUE(config.rig.lidars[1].looks_down());
  // Pitch 12.7 deg down: the x axis of the down LiDAR points below the horizon by that angle.
  const Eigen::Vector3d x = config.rig.lidars[1].T_body_lidar.linear().col(0);
  EXPECT_NEAR(std::asin(-x.z()) * 180.0 / M_PI, 12.7, 1e-9);
  EXPECT_NEAR(config.rig.lidars[1].T_body_lidar.translation().z(), 0.15, 1e-12);
  EXPECT_DOUBLE_EQ(config.rig.wheel_diameter_m, 0.84);
  EXPECT_EQ(config.rig.pulses_per_rev, 100);
  EXPECT_DOUBLE_EQ(config.rig.body_above_rail_top_m, 3.8);
  EXPECT_DOUBLE_EQ(config.options.rail.body_above_rail_top_m, 3.8);
  // The simulated wheel meets the rail at the track's centre line, 3.8 m below the body.
  EXPECT_EQ(config.rig.p_body_odometer, Eigen::Vector3d(0.0, 0.0, -3.8));
  EXPECT_NE(config.Describe().find("window_size"), std::string::npos);
}

TEST(EstimatorConfig, RejectsAnImuRateThatIsNotARate) {
  std::string yaml = DemoRigYaml();
  const size_t at = yaml.find("rate_hz: 200");
  ASSERT_NE(at, std::string::npos);
  yaml.replace(at, 12, "rate_hz: 0");
  EstimatorConfig config;
  std::string error;
  EXPECT_FALSE(ParseEstimatorConfig(yaml, "rig.yaml", &config, &error));
  EXPECT_NE(error.find("imu.rate_hz"), std::string::npos) << error;
}

TEST(EstimatorConfig, ReadsTheImuGapMotionAndRejectsItNegative) {
  const auto with = [](const std::string& lines) {
    std::string yaml = DemoRigYaml();
    const size_t at = yaml.find("rate_hz: 200");
    yaml.insert(yaml.find('\n', at) + 1, lines);
    return yaml;
  };
  EstimatorConfig config;
  std::string error;
  ASSERT_TRUE(
      ParseEstimatorConfig(with("  gap_rate_sigma_radps: 0.05\n  gap_accel_sigma_mps2: 0\n"),
                           "rig.yaml",
                           &config,
                           &error))
      << error;
  EXPECT_DOUBLE_EQ(config.rig.noise.gap_rate_sigma_radps, 0.05);
  EXPECT_DOUBLE_EQ(config.rig.noise.gap_accel_sigma_mps2, 0.0);
  EXPECT_NE(config.Describe().find("across gaps rate 0.05"), std::string::npos);
  EXPECT_FALSE(
      ParseEstimatorConfig(with("  gap_rate_sigma_radps: -0.1\n"), "rig.yaml", &config, &error));
  EXPECT_NE(error.find("imu.gap_rate_sigma_radps must be >= 0"), std::string::npos) << error;
}

TEST(EstimatorConfig, AnOdometerPointGivenIsKeptAndDefaultsToTheBodyOrigin) {
  const std::string sim_line = "  translation_m: [0, 0, -3.8]\n";
  const std::string demo = DemoRigYaml();
  const size_t at = demo.find(sim_line);
  ASSERT_NE(at, std::string::npos);
  EstimatorConfig config;
  std::string error;
  std::string yaml = demo;
  yaml.replace(at, sim_line.size(), "  translation_m: [1.5, 0, -3.4]\n");
  ASSERT_TRUE(ParseEstimatorConfig(yaml, "rig.yaml", &config, &error)) << error;
  EXPECT_EQ(config.rig.p_body_odometer, Eigen::Vector3d(1.5, 0.0, -3.4));
  yaml = demo;
  yaml.erase(at, sim_line.size());
  ASSERT_TRUE(ParseEstimatorConfig(yaml, "rig.yaml", &config, &error)) << error;
  EXPECT_EQ(config.rig.p_body_odometer, Eigen::Vector3d::Zero());
}

TEST(EstimatorConfig, RejectsUnknownKeysWithTheirLine) {
  EstimatorConfig config;
  std::string error;
  const std::string yaml = DemoRigYaml() + "estimator:\n  window_size: 8\n  windw_size: 3\n";
  EXPECT_FALSE(ParseEstimatorConfig(yaml, "rig.yaml", &config, &error));
  EXPECT_NE(error.find("unknown key 'estimator.windw_size'"), std::string::npos) << error;
  EXPECT_NE(error.find("rig.yaml:"), std::string::npos) << error;
}

TEST(EstimatorConfig, RejectsBadValuesAndTypes) {
  // Each bad `estimator:` line and what its message must name.
  const std::pair<const char*, const char*> cases[] = {
      {"window_size: 1", "window_size"},
      {"map_voxel_m: big", "wrong type"},
      // A zero across-axis odometer noise would pin the attitude to the car body's sway again.
      {"odometer_lateral_density: 0", "estimator.odometer_lateral_density must be > 0"},
      {"odometer_vertical_density: -0.03", "estimator.odometer_vertical_density must be > 0"},
      {"degeneracy_projection: -1", "degeneracy_projection must be in [0, 1)"},
      {"degeneracy_projection_along: 1", "degeneracy_projection_along must be in [0, 1)"},
      {"heading_projection: -5", "heading_projection must be in [0, 1e6)"},
      {"odometer_sway_time_constant_s: -1", "odometer_sway_time_constant_s must be in [0, 60]"},
      {"odometer_yaw_sigma_rad: -0.001", "odometer_yaw_sigma_rad must be in [0, 0.1] rad"},
      {"odometer_misalignment_walk: -1e-5", "estimator.odometer_misalignment_walk must be >= 0"},
      {"deskew_step_s: 0.5", "deskew_step_s must be in [0, 0.1] s"},
      {"edge_max_spread_m: -0.1", "edge_max_spread_m must be >= 0"},
      {"down_edge_soft_spread_m: -1", "down_edge_soft_spread_m must be >= 0"},
      {"map_insert_lag: -1", "map_insert_lag must be >= 0"},
      {"submap_gnss_height_length_m: -1",
       "submap_gnss_height_length_m must be 0 (off) or a length"},
      {"submap_gnss_heading_length_m: -1",
       "submap_gnss_heading_length_m must be 0 (off) or a length"},
      {"submap_gnss_turn_rate_rad_per_m: 0", "submap_gnss_turn_rate_rad_per_m must be > 0"},
      {"submap_gnss_pull_excess: 2", "submap_gnss_pull_excess must be in [0, 1]"},
      {"submap_gnss_pull_along_excess: -0.5", "submap_gnss_pull_along_excess must be in [0, 1]"},
      {"submap_chain_reset_m: 0", "submap_chain_reset_m must be > 0 m"},
      {"submap_max_range_m: -1", "submap_max_range_m must be >= 0 m (0: every point)"},
      {"submap_ndt_min_along_information_revisit: 2",
       "submap_ndt_min_along_information_revisit must be in [0, 1]"},
      {"submap_side_slip_max_jump_m: 0", "submap_side_slip_max_jump_m must be > 0 m"},
      {"rail_line_sigma_m: -0.1", "rail_line_sigma_m must be >= 0"},
      {"rail_line_max_forward_m: -1", "rail_line_max_forward_m must be >= 0"},
      // Half the sleeper spacing or more: the match could land on the next sleeper.
      {"track_bed:\n    max_search_m: 0.3", "track_bed: max_search_m must be in"},
      {"track_bed:\n    sigma_m: -1", "track_bed: sigma_m must be >= 0"},
      {"track_bed:\n    sigma: 0.01", "unknown key 'estimator.track_bed.sigma'"},
      {"straight_track:\n    sigma_rad: -0.001", "straight_track: sigma_rad must be in [0, 0.1]"},
      {"straight_track:\n    detect_s: 0", "straight_track: detect_s must be in [0.5, 600]"},
      {"straight_track:\n    tolerance: 0.001", "unknown key 'estimator.straight_track.tolerance'"},
      {"gnss:\n    vertical_drift_fraction: 0.5",
       "gnss.vertical_drift_fraction must be in [0, 0.5)"},
  };
  EstimatorConfig config;
  std::string error;
  for (const auto& [line, message] : cases) {
    EXPECT_FALSE(ParseEstimatorConfig(
        DemoRigYaml() + "estimator:\n  " + line + "\n", "rig.yaml", &config, &error))
        << line;
    EXPECT_NE(error.find(message), std::string::npos) << line << ": " << error;
  }
  // The track gauge is the vehicle's key, and the message names it there, with its line.
  std::string rig = DemoRigYaml();
  const size_t gauge = rig.find("gauge_m: 1.435");
  ASSERT_NE(gauge, std::string::npos) << rig;
  rig.replace(gauge, 14, "gauge_m: 0");
  EXPECT_FALSE(ParseEstimatorConfig(rig, "rig.yaml", &config, &error));
  EXPECT_NE(error.find("key 'vehicle.gauge_m' must be within (0.5, 3) m"), std::string::npos)
      << error;
  EXPECT_NE(error.find("rig.yaml:"), std::string::npos) << error;
  EXPECT_FALSE(ParseEstimatorConfig("rig: x\n", "rig.yaml", &config, &error));
  EXPECT_NE(error.find("lidars"), std::string::npos) << error;
  EXPECT_FALSE(ParseEstimatorConfig("rig: [", "rig.yaml", &config, &error));
  EXPECT_NE(error.find("YAML syntax"), std::string::npos) << error;
}

/// The demo rig with every tunable the tests below check set away from its default.
void OverriddenConfig(EstimatorConfig* config) {
  std::string error;
  const std::string yaml =
      DemoRigYaml() +
      "estimator:\n  window_size: 8\n  plane_sigma_m: 0.05\n  map_insert_lag: 0\n"
      "  edge_max_spread_m: 0.2\n  down_edge_soft_spread_m: 0.05\n  submap_gnss_height_length_m: "
      "0\n"
      "  submap_gnss_heading_length_m: 250\n  submap_gnss_pull_excess: 0.5\n"
      "  submap_gnss_pull_along_excess: 0.25\n  "
      "submap_chain_reset_m: 5\n  submap_remove_side_slip: false\n  submap_max_range_m: 0\n"
      "  submap_ndt_min_along_information_revisit: 0\n  degeneracy_projection_along: 0.02\n"
      "  rail_line_sigma_m: 0.2\n  rail_line_max_forward_m: 12\n"
      "  odometer_pitch_sigma_rad: 0.001\n  odometer_yaw_sigma_rad: 0.002\n"
      "  odometer_misalignment_walk: 2e-5\n  deskew_step_s: 0\n"
      "  preprocess:\n"
      "    min_range_m: 3.5\n"
      "  track_bed:\n"
      "    sigma_m: 0.02\n"
      "    history_frames: 4\n"
      "  straight_track:\n"
      "    sigma_rad: 0.002\n"
      "    detect_s: 8\n"
      "    tolerance_rad: 0.0015\n"
      "    max_rate_rps: 0.0002\n";
  ASSERT_TRUE(ParseEstimatorConfig(yaml, "rig.yaml", config, &error)) << error;
}

TEST(EstimatorConfig, OverridesTunables) {
  EstimatorConfig config;
  ASSERT_NO_FATAL_FAILURE(OverriddenConfig(&config));
  EXPECT_EQ(config.options.window_size, 8);
  EXPECT_DOUBLE_EQ(config.options.plane_sigma_m, 0.05);
  EXPECT_EQ(config.options.map_insert_lag, 0);
  EXPECT_DOUBLE_EQ(config.options.edge_max_spread_m, 0.2);
  EXPECT_DOUBLE_EQ(config.options.down_edge_soft_spread_m, 0.05);
  EXPECT_DOUBLE_EQ(config.options.submap.gnss_height_length_m, 0.0);
  EXPECT_DOUBLE_EQ(config.options.submap.gnss_heading_length_m, 250.0);
  EXPECT_DOUBLE_EQ(config.options.submap.gnss_pull_excess, 0.5);
  EXPECT_DOUBLE_EQ(config.options.submap.gnss_pull_along_excess, 0.25);
  EXPECT_FALSE(config.options.submap.remove_side_slip);
  EXPECT_EQ(config.options.submap.max_range_m, 0.0);
  EXPECT_EQ(config.options.submap.ndt_min_along_information_revisit, 0.0);
  EXPECT_EQ(config.options.degeneracy_projection_along, 0.02);
  EXPECT_DOUBLE_EQ(config.options.submap.chain_reset_m, 5.0);
  EXPECT_DOUBLE_EQ(config.options.preprocess.min_range_m, 3.5);
  EXPECT_DOUBLE_EQ(config.options.rail_line_sigma_m, 0.2);
  EXPECT_DOUBLE_EQ(config.options.rail_line_max_forward_m, 12.0);
  EXPECT_DOUBLE_EQ(config.options.odometer_pitch_sigma_rad, 0.001);
  EXPECT_DOUBLE_EQ(config.options.odometer_yaw_sigma_rad, 0.002);
  EXPECT_DOUBLE_EQ(config.rig.noise.odometer_misalignment_walk, 2e-5);
  EXPECT_DOUBLE_EQ(config.options.deskew_step_s, 0.0);
  EXPECT_DOUBLE_EQ(config.options.track_bed.sigma_m, 0.02);
  EXPECT_EQ(config.options.track_bed.history_frames, 4);
  EXPECT_DOUBLE_EQ(config.options.straight_track.sigma_rad, 0.002);
  EXPECT_DOUBLE_EQ(config.options.straight_track.detect_s, 8.0);
  EXPECT_DOUBLE_EQ(config.options.straight_track.tolerance_rad, 0.0015);
  EXPECT_DOUBLE_EQ(config.options.straight_track.max_rate_rps, 0.0002);
}

TEST(EstimatorConfig, DescribesTheOverriddenSettings) {
  EstimatorConfig config;
  ASSERT_NO_FATAL_FAILURE(OverriddenConfig(&config));
  EXPECT_NE(config.Describe().find("chain reset beyond 5 m across / 10 m along"), std::string::npos)
      << config.Describe();
  EXPECT_NE(config.Describe().find("with the sleepers measured, below 0.02"), std::string::npos)
      << config.Describe();
  EXPECT_NE(config.Describe().find("points within any range"), std::string::npos);
  EXPECT_NE(config.Describe().find("side slip kept"), std::string::npos) << config.Describe();
  EXPECT_NE(config.Describe().find("odometer misalignment pitch 0.001 yaw 0.002 rad"),
            std::string::npos)
      << config.Describe();
  EXPECT_NE(config.Describe().find("deskew: linear from the frame's start to its end"),
            std::string::npos)
      << config.Describe();
  EXPECT_NE(config.Describe().find("track bed (sleepers): sigma 0.02 m"), std::string::npos)
      << config.Describe();
  EXPECT_NE(config.Describe().find("straight track (heading hold): sigma 0.002 rad"),
            std::string::npos)
      << config.Describe();
  EXPECT_NE(
      config.Describe().find("rail-head lines matched sideways, sigma 0.2 m, within 12 m ahead"),
      std::string::npos)
      << config.Describe();
}

TEST(AblationSwitches, NamesTheVariant) {
  AblationSwitches s;
  EXPECT_EQ(s.Name(), "full");
  s.use_odometer = false;
  EXPECT_EQ(s.Name(), "no-odometer");
  s.use_rail_plane = false;
  EXPECT_EQ(s.Name(), "no-odometer,no-rail-plane");
  s.use_imu = false;
  EXPECT_EQ(s.Name(), "lidar-only");
}

}  // namespace
}  // namespace raillomer
