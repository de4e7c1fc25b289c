#include "estimator/pipeline/config.h"

#include <array>
#include <cmath>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>

#include "api/yaml_map_reader.h"
#include "estimator/geo/utm.h"

namespace raillomer {

namespace {

using api::MapReader;

Eigen::Isometry3d PoseFromYaml(const std::array<double, 3>& t,
                               const std::array<double, 3>& rpy_deg) {
  const double k = M_PI / 180.0;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(rpy_deg[2] * k, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(rpy_deg[1] * k, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rpy_deg[0] * k, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = Eigen::Vector3d(t[0], t[1], t[2]);
  return T;
}

Eigen::Vector3d Vec(const std::array<double, 3>& a) { return {a[0], a[1], a[2]}; }

void ParseLidars(MapReader& root, RigConfig* rig) {
  api::ForEachMap(root, "lidars", [&](MapReader& r, const YAML::Node& node) {
    LidarRig lidar;
    std::array<double, 3> t{0, 0, 0}, rpy{0, 0, 0};
    std::string model;
    int points = 0;
    r.Read("name", &lidar.name);
    r.Read("topic", &lidar.topic);
    r.Read("type", &lidar.type);
    r.Read("model", &model);
    r.Read("lidar_id", &lidar.lidar_id);
    r.ReadArray("translation_m", &t);
    r.ReadArray("rpy_deg", &rpy);
    r.Read("points_per_frame", &points);
    r.Read("rate_hz", &lidar.rate_hz);
    r.Read("range_noise_m", &lidar.range_noise_m);
    if (lidar.topic.empty()) r.Fail(node, "key '" + r.Path("topic") + "' is required");
    if (!(lidar.rate_hz > 0.0)) r.Fail(node, "key '" + r.Path("rate_hz") + "' must be > 0");
    if (lidar.name.empty()) lidar.name = lidar.topic;
    lidar.T_body_lidar = PoseFromYaml(t, rpy);
    rig->lidars.push_back(lidar);
  });
  if (rig->lidars.empty())
    root.Fail(root.Node("lidars"), "key 'lidars' must list at least one LiDAR");
}

/// The sliding window, the solver, the local map and feature matching.
void ReadWindowAndMatching(MapReader& r, EstimatorOptions* o) {
  r.Read("window_size", &o->window_size);
  r.Read("registration_rounds", &o->registration_rounds);
  r.Read("max_solver_iterations", &o->max_solver_iterations);
  r.Read("map_voxel_m", &o->map_voxel_m);
  r.Read("map_points_per_voxel", &o->map_points_per_voxel);
  r.Read("map_radius_m", &o->map_radius_m);
  r.Read("plane_sigma_m", &o->plane_sigma_m);
  r.Read("edge_sigma_m", &o->edge_sigma_m);
  r.Read("max_correspondence_m", &o->max_correspondence_m);
  r.Read("edge_max_spread_m", &o->edge_max_spread_m);
  r.Read("down_edge_soft_spread_m", &o->down_edge_soft_spread_m);
  r.Read("map_insert_lag", &o->map_insert_lag);
}

/// The rail and height-descriptor factors, the favour factors and the projections.
void ReadRailAndFavour(MapReader& r, EstimatorOptions* o) {
  r.Read("rail_normal_sigma_rad", &o->rail_normal_sigma_rad);
  r.Read("rail_distance_sigma_m", &o->rail_distance_sigma_m);
  r.Read("rail_line_sigma_m", &o->rail_line_sigma_m);
  r.Read("rail_line_max_forward_m", &o->rail_line_max_forward_m);
  r.Read("failure_min_edges", &o->failure_min_edges);
  r.Read("failure_min_planes", &o->failure_min_planes);
  r.Read("degeneracy_threshold", &o->degeneracy_threshold);
  r.Read("degeneracy_projection", &o->degeneracy_projection);
  r.Read("degeneracy_projection_along", &o->degeneracy_projection_along);
  r.Read("heading_projection", &o->heading_projection);
}

/// Odometer sway, deskewing, the initial sigmas and keyframes.
void ReadPriorsAndKeyframes(MapReader& r, EstimatorOptions* o) {
  r.Read("odometer_sway_time_constant_s", &o->odometer_sway_time_constant_s);
  r.Read("deskew_step_s", &o->deskew_step_s);
  r.Read("initial_velocity_sigma_mps", &o->initial_velocity_sigma_mps);
  r.Read("initial_accel_bias_sigma", &o->initial_accel_bias_sigma);
  r.Read("relevelled_accel_bias_sigma", &o->relevelled_accel_bias_sigma);
  r.Read("initial_gyro_bias_sigma", &o->initial_gyro_bias_sigma);
  r.Read("initial_scale_sigma", &o->initial_scale_sigma);
  r.Read("odometer_pitch_sigma_rad", &o->odometer_pitch_sigma_rad);
  r.Read("odometer_yaw_sigma_rad", &o->odometer_yaw_sigma_rad);
  r.Read("keyframe_distance_m", &o->keyframe_distance_m);
  r.Read("keyframe_angle_deg", &o->keyframe_angle_deg);
  r.Read("write_keyframes", &o->write_keyframes);
}

/// The submaps: size, ICP, NDT, the GNSS pull and the chain.
void ReadSubmapOptions(MapReader& r, EstimatorOptions* o) {
  r.Read("submap_keyframes", &o->submap.keyframes);
  r.Read("submap_voxel_m", &o->submap.voxel_m);
  r.Read("submap_max_range_m", &o->submap.max_range_m);
  r.Read("submap_icp", &o->submap.icp);
  r.Read("submap_remove_side_slip", &o->submap.remove_side_slip);
  r.Read("submap_side_slip_max_jump_m", &o->submap.side_slip_max_jump_m);
  r.Read("submap_ndt", &o->submap.ndt);
  r.Read("submap_gnss_pull", &o->submap.gnss_pull);
  r.Read("submap_gnss_pull_vertical", &o->submap.gnss_pull_vertical);
  r.Read("submap_gnss_height_length_m", &o->submap.gnss_height_length_m);
  r.Read("submap_gnss_heading_length_m", &o->submap.gnss_heading_length_m);
  r.Read("submap_gnss_turn_rate_rad_per_m", &o->submap.gnss_max_turn_rate_rad_per_m);
  r.Read("submap_gnss_pull_excess", &o->submap.gnss_pull_excess);
  r.Read("submap_gnss_pull_along_excess", &o->submap.gnss_pull_along_excess);
  r.Read("submap_chain_reset_m", &o->submap.chain_reset_m);
  r.Read("submap_ndt_min_turn_arm_m", &o->submap.ndt_min_turn_arm_m);
  r.Read("submap_ndt_min_along_information_revisit", &o->submap.ndt_min_along_information_revisit);
}

/// The estimator.gnss section: the fusion's factors, gates and latencies.
void ReadGnssOptions(MapReader& r, EstimatorOptions* o) {
  if (r.Has("gnss")) {
    MapReader g(r.Node("gnss"), r.Path("gnss"), r.source());
    g.Read("factor_period_s", &o->gnss.factor_period_s);
    g.Read("sigma_horizontal_m", &o->gnss.sigma_horizontal_m);
    g.Read("sigma_vertical_m", &o->gnss.sigma_vertical_m);
    g.Read("gate_m", &o->gnss.gate_m);
    g.Read("drift_fraction", &o->gnss.drift_fraction);
    g.Read("vertical_drift_fraction", &o->gnss.vertical_drift_fraction);
    g.Read("align_distance_m", &o->gnss.alignment.min_extent_m);
    g.Read("max_hold_s", &o->gnss_max_hold_s);
    g.Read("prompt_latency_s", &o->gnss_prompt_latency_s);
    g.Read("max_latency_s", &o->gnss_max_latency_s);
    g.Read("provisional_after_s", &o->gnss_provisional_after_s);
    g.Read("factor_window_s", &o->gnss.factor_window_s);
    g.Read("continuity_length_m", &o->gnss.continuity_length_m);
    g.Read("continuity_max_step_m", &o->gnss.continuity_max_step_m);
    g.Finish();
  }
}

/// The estimator's preprocess, height_descriptor, track_bed and straight_track sections.
void ReadSubsections(MapReader& r, EstimatorOptions* o) {
  if (r.Has("preprocess")) {
    MapReader p(r.Node("preprocess"), r.Path("preprocess"), r.source());
    p.Read("min_range_m", &o->preprocess.min_range_m);
    p.Read("max_range_m", &o->preprocess.max_range_m);
    p.Read("flicker_cell_size_m", &o->preprocess.flicker_cell_size_m);
    p.Read("flicker_min_points_per_cell", &o->preprocess.flicker_min_points_per_cell);
    p.Read("hidden_sector_angle_deg", &o->preprocess.hidden_sector_angle_deg);
    p.Read("hidden_sector_radius_m", &o->preprocess.hidden_sector_radius_m);
    p.Finish();
  }
  if (r.Has("height_descriptor")) {
    MapReader h(r.Node("height_descriptor"), r.Path("height_descriptor"), r.source());
    h.Read("max_shift_search_m", &o->height.max_shift_search_m);
    h.Read("min_score", &o->height.min_score);
    h.Finish();
  }
  if (r.Has("track_bed")) {
    MapReader b(r.Node("track_bed"), r.Path("track_bed"), r.source());
    b.Read("sigma_m", &o->track_bed.sigma_m);
    b.Read("min_forward_m", &o->track_bed.min_forward_m);
    b.Read("max_forward_m", &o->track_bed.max_forward_m);
    b.Read("half_width_m", &o->track_bed.half_width_m);
    b.Read("min_depth_m", &o->track_bed.min_depth_m);
    b.Read("max_depth_m", &o->track_bed.max_depth_m);
    b.Read("bin_m", &o->track_bed.bin_m);
    b.Read("depth_bin_m", &o->track_bed.depth_bin_m);
    b.Read("blur_m", &o->track_bed.blur_m);
    b.Read("max_search_m", &o->track_bed.max_search_m);
    b.Read("history_frames", &o->track_bed.history_frames);
    b.Read("min_points", &o->track_bed.min_points);
    b.Read("min_gain", &o->track_bed.min_gain);
    b.Finish();
  }
  if (r.Has("straight_track")) {
    MapReader st(r.Node("straight_track"), r.Path("straight_track"), r.source());
    st.Read("sigma_rad", &o->straight_track.sigma_rad);
    st.Read("detect_s", &o->straight_track.detect_s);
    st.Read("tolerance_rad", &o->straight_track.tolerance_rad);
    st.Read("max_rate_rps", &o->straight_track.max_rate_rps);
    st.Finish();
  }
}

void ParseEstimatorSection(MapReader& root, EstimatorOptions* o, PreintegrationNoise* noise) {
  if (!root.Has("estimator")) return;
  MapReader r(root.Node("estimator"), "estimator", root.source());
  ReadWindowAndMatching(r, o);
  ReadRailAndFavour(r, o);
  ReadPriorsAndKeyframes(r, o);
  ReadSubmapOptions(r, o);
  r.Read("init_gravity_s", &o->init_gravity_s);
  r.Read("gravity_align_s", &o->gravity_align_s);
  ReadGnssOptions(r, o);
  r.Read("odometer_speed_density", &noise->odometer_speed_density);
  r.Read("odometer_scale_walk", &noise->odometer_scale_walk);
  r.Read("odometer_misalignment_walk", &noise->odometer_misalignment_walk);
  r.Read("odometer_lateral_density", &noise->odometer_lateral_density);
  r.Read("odometer_vertical_density", &noise->odometer_vertical_density);
  ReadSubsections(r, o);
  r.Finish();
}

/// The imu section (required): topic, rate, noise densities and gravity.
void ParseImu(MapReader& root, const YAML::Node& root_node, RigConfig* rig) {
  if (!root.Has("imu")) {
    root.Fail(root_node, "key 'imu' is required");
    return;
  }
  MapReader r(root.Node("imu"), "imu", root.source());
  r.Read("topic", &rig->imu_topic);
  r.Read("rate_hz", &rig->imu_rate_hz);
  r.Read("gyro_noise_density", &rig->noise.gyro_noise_density);
  r.Read("gyro_bias_walk", &rig->noise.gyro_bias_walk);
  r.Read("accel_noise_density", &rig->noise.accel_noise_density);
  r.Read("accel_bias_walk", &rig->noise.accel_bias_walk);
  r.Read("gap_rate_sigma_radps", &rig->noise.gap_rate_sigma_radps);
  r.Read("gap_accel_sigma_mps2", &rig->noise.gap_accel_sigma_mps2);
  r.Read("gravity_mps2", &rig->gravity_mps2);
  if (!(rig->imu_rate_hz >= 1.0 && rig->imu_rate_hz <= 10000.0)) {
    r.Fail(r.Node("rate_hz"), "key 'imu.rate_hz' must be in [1, 10000] Hz");
  }
  r.Finish();
}

/// The odometer section; without one the run has no odometer.
void ParseOdometer(MapReader& root, RigConfig* rig) {
  if (!root.Has("odometer")) {
    rig->odometer_topic.clear();
    return;
  }
  MapReader r(root.Node("odometer"), "odometer", root.source());
  std::array<double, 3> t{0, 0, 0};
  r.Read("topic", &rig->odometer_topic);
  r.Read("joint_name", &rig->odometer_joint);
  r.Read("wheel_diameter_m", &rig->wheel_diameter_m);
  r.Read("pulses_per_rev", &rig->pulses_per_rev);
  r.Read("rate_hz", &rig->odometer_rate_hz);
  r.ReadArray("translation_m", &t);
  rig->p_body_odometer = Vec(t);
  if (!(rig->wheel_diameter_m > 0.1 && rig->wheel_diameter_m < 3.0)) {
    r.Fail(r.Node("wheel_diameter_m"), "key 'odometer.wheel_diameter_m' must be in (0.1, 3) m");
  }
  if (rig->pulses_per_rev < 1) {
    r.Fail(r.Node("pulses_per_rev"), "key 'odometer.pulses_per_rev' must be >= 1");
  }
  rig->noise.odometer_resolution_m = M_PI * rig->wheel_diameter_m / rig->pulses_per_rev;
  r.Finish();
}

/// The optional gnss (topic, antenna) and vehicle (body height, gauge) sections.
void ParseGnssAndVehicle(MapReader& root, RigConfig* rig) {
  if (root.Has("gnss")) {
    MapReader r(root.Node("gnss"), "gnss", root.source());
    std::array<double, 3> antenna{0, 0, 0};
    double rate = 1.0;
    r.Read("topic", &rig->gnss_topic);
    r.ReadArray("antenna_m", &antenna);
    r.Read("rate_hz", &rate);
    rig->p_body_antenna = Vec(antenna);
    r.Finish();
  }
  if (root.Has("vehicle")) {
    MapReader r(root.Node("vehicle"), "vehicle", root.source());
    r.Read("body_above_rail_top_m", &rig->body_above_rail_top_m);
    r.Read("gauge_m", &rig->gauge_m);
    if (root.Node("vehicle")["gauge_m"] && !(rig->gauge_m > 0.5 && rig->gauge_m < 3.0))
      r.Fail(root.Node("vehicle")["gauge_m"], "key 'vehicle.gauge_m' must be within (0.5, 3) m");
    r.Finish();
  }
}

/// Why the noise figures are unusable, or an empty string. White-noise densities must be
/// positive (zero would make a measurement exact); random walks may be zero (a constant bias or
/// scale).
std::string BadNoise(const PreintegrationNoise& n) {
  const std::pair<const char*, double> densities[] = {
      {"imu.gyro_noise_density", n.gyro_noise_density},
      {"imu.accel_noise_density", n.accel_noise_density},
      {"estimator.odometer_speed_density", n.odometer_speed_density},
      {"estimator.odometer_lateral_density", n.odometer_lateral_density},
      {"estimator.odometer_vertical_density", n.odometer_vertical_density}};
  const std::pair<const char*, double> walks[] = {
      {"imu.gyro_bias_walk", n.gyro_bias_walk},
      {"imu.accel_bias_walk", n.accel_bias_walk},
      {"imu.gap_rate_sigma_radps", n.gap_rate_sigma_radps},
      {"imu.gap_accel_sigma_mps2", n.gap_accel_sigma_mps2},
      {"estimator.odometer_scale_walk", n.odometer_scale_walk},
      {"estimator.odometer_misalignment_walk", n.odometer_misalignment_walk}};
  for (const auto& [key, value] : densities) {
    if (!(value > 0.0 && std::isfinite(value))) return std::string(key) + " must be > 0";
  }
  for (const auto& [key, value] : walks) {
    if (!(value >= 0.0 && std::isfinite(value))) return std::string(key) + " must be >= 0";
  }
  return "";
}

}  // namespace

std::string AblationSwitches::Name() const {
  if (!use_imu) return "lidar-only";
  std::string name;
  auto add = [&](bool on, const char* what) {
    if (!on) name += std::string(name.empty() ? "" : ",") + what;
  };
  add(use_odometer, "no-odometer");
  add(use_rail_plane, "no-rail-plane");
  add(use_height_descriptor, "no-height-descriptor");
  add(use_favour_factors, "no-favour-factors");
  return name.empty() ? "full" : name;
}

MatchOptions LidarMatchOptions(const EstimatorOptions& options, bool looks_down) {
  MatchOptions match;
  match.max_distance_m = options.max_correspondence_m;
  match.line_max_spread_m = options.edge_max_spread_m;
  match.line_soft_spread_m = looks_down ? options.down_edge_soft_spread_m : 0.0;
  return match;
}

namespace {

/// What is wrong with the GNSS fusion options, or an empty string.
std::string GnssProblem(const EstimatorOptions& o) {
  if (!(o.gnss.factor_period_s >= 0.5 && o.gnss.factor_period_s <= 600.0))
    return "gnss.factor_period_s must be in [0.5, 600] s";
  if (!(o.gnss.sigma_horizontal_m > 0.0 && o.gnss.sigma_vertical_m > 0.0))
    return "gnss.sigma_horizontal_m and gnss.sigma_vertical_m must be > 0";
  if (!(o.gnss.gate_m > 0.0)) return "gnss.gate_m must be > 0";
  if (!(o.gnss.drift_fraction >= 0.0 && o.gnss.drift_fraction < 0.5))
    return "gnss.drift_fraction must be in [0, 0.5)";
  if (!(o.gnss.vertical_drift_fraction >= 0.0 && o.gnss.vertical_drift_fraction < 0.5))
    return "gnss.vertical_drift_fraction must be in [0, 0.5)";
  if (!(o.gnss.alignment.min_extent_m >= 10.0)) return "gnss.align_distance_m must be >= 10 m";
  if (!(o.gnss_max_hold_s >= 10.0)) return "gnss.max_hold_s must be >= 10 s";
  if (!(o.gnss_max_latency_s >= 0.0 && o.gnss_max_latency_s <= 600.0))
    return "gnss.max_latency_s must be in [0, 600] s";
  if (!(o.gnss_prompt_latency_s >= 0.0 && o.gnss_prompt_latency_s <= 600.0))
    return "gnss.prompt_latency_s must be in [0, 600] s";
  if (!(o.gnss_provisional_after_s >= 0.0 && o.gnss_provisional_after_s <= 600.0))
    return "gnss.provisional_after_s must be in [0, 600] s";
  if (!(o.gnss.factor_window_s >= 0.0 && o.gnss.factor_window_s <= 2.0 * o.gnss.factor_period_s))
    return "gnss.factor_window_s must be in [0, 2 * factor_period_s]";
  if (!(o.gnss.continuity_length_m >= 0.0) || !(o.gnss.continuity_max_step_m >= 0.0))
    return "gnss.continuity_length_m and gnss.continuity_max_step_m must be >= 0";
  return "";
}

/// What is wrong with the solver and submap options, or an empty string.
std::string SubmapProblem(const EstimatorOptions& o) {
  if (o.max_solver_iterations < 1) return "max_solver_iterations must be >= 1";
  if (!(o.submap.gnss_pull >= 0.0 && o.submap.gnss_pull <= 1.0) ||
      !(o.submap.gnss_pull_vertical >= 0.0 && o.submap.gnss_pull_vertical <= 1.0))
    return "submap_gnss_pull and submap_gnss_pull_vertical must be in [0, 1]";
  if (!(o.submap.side_slip_max_jump_m > 0.0)) return "submap_side_slip_max_jump_m must be > 0 m";
  if (!(o.submap.gnss_pull_excess >= 0.0 && o.submap.gnss_pull_excess <= 1.0))
    return "submap_gnss_pull_excess must be in [0, 1]";
  if (!(o.submap.gnss_pull_along_excess >= 0.0 && o.submap.gnss_pull_along_excess <= 1.0))
    return "submap_gnss_pull_along_excess must be in [0, 1]";
  if (!(o.submap.chain_reset_m > 0.0)) return "submap_chain_reset_m must be > 0 m";
  if (!(o.submap.ndt_min_along_information_revisit >= 0.0 &&
        o.submap.ndt_min_along_information_revisit <= 1.0))
    return "submap_ndt_min_along_information_revisit must be in [0, 1] (0: always NDT's "
           "along-track correction onto an earlier pass)";
  if (!(o.submap.ndt_min_turn_arm_m >= 0.0 && o.submap.ndt_min_turn_arm_m <= 100.0))
    return "submap_ndt_min_turn_arm_m must be in [0, 100] m (0: always NDT's turn)";
  if (!(o.submap.gnss_height_length_m >= 0.0))
    return "submap_gnss_height_length_m must be 0 (off) or a length in metres";
  if (!(o.submap.gnss_heading_length_m >= 0.0))
    return "submap_gnss_heading_length_m must be 0 (off) or a length in metres";
  if (!(o.submap.gnss_max_turn_rate_rad_per_m > 0.0))
    return "submap_gnss_turn_rate_rad_per_m must be > 0";
  if (o.submap.keyframes < 1 || o.submap.keyframes > 1000)
    return "submap_keyframes must be in [1, 1000]";
  if (!(o.submap.voxel_m >= 0.0 && o.submap.voxel_m <= 5.0))
    return "submap_voxel_m must be in [0, 5] m (0: every point)";
  if (!(o.submap.max_range_m >= 0.0)) return "submap_max_range_m must be >= 0 m (0: every point)";
  return "";
}

/// What is wrong with the local map, matching and rail options, or an empty string.
std::string MatchingProblem(const EstimatorOptions& o) {
  if (!(o.map_voxel_m > 0.05)) return "map_voxel_m must be > 0.05";
  if (o.map_points_per_voxel < 5) return "map_points_per_voxel must be >= 5";
  if (!(o.map_radius_m > 10.0)) return "map_radius_m must be > 10";
  if (!(o.plane_sigma_m > 0.0) || !(o.edge_sigma_m > 0.0)) return "LiDAR sigmas must be > 0";
  if (!(o.max_correspondence_m > 0.0)) return "max_correspondence_m must be > 0";
  if (!(o.edge_max_spread_m >= 0.0)) return "edge_max_spread_m must be >= 0 (0 = no check)";
  if (!(o.down_edge_soft_spread_m >= 0.0)) return "down_edge_soft_spread_m must be >= 0 (0 = off)";
  if (o.map_insert_lag < 0) return "map_insert_lag must be >= 0";
  if (!(o.rail_line_sigma_m >= 0.0)) return "rail_line_sigma_m must be >= 0 (0 = off)";
  if (!(o.rail_line_max_forward_m >= 0.0))
    return "rail_line_max_forward_m must be >= 0 (0 = no limit)";
  if (!(o.rail_normal_sigma_rad > 0.0) || !(o.rail_distance_sigma_m > 0.0)) {
    return "rail-plane sigmas must be > 0";
  }
  return "";
}

/// What is wrong with the priors, keyframes, remapping and deskewing options, or an empty
/// string.
std::string PriorProblem(const EstimatorOptions& o) {
  if (!(o.initial_velocity_sigma_mps > 0.0) || !(o.initial_accel_bias_sigma > 0.0) ||
      !(o.relevelled_accel_bias_sigma > 0.0) || !(o.initial_gyro_bias_sigma > 0.0) ||
      !(o.initial_scale_sigma > 0.0)) {
    return "initial_*_sigma and relevelled_accel_bias_sigma must be > 0";
  }
  if (!(o.odometer_pitch_sigma_rad >= 0.0 && o.odometer_pitch_sigma_rad <= 0.1) ||
      !(o.odometer_yaw_sigma_rad >= 0.0 && o.odometer_yaw_sigma_rad <= 0.1))
    return "odometer_pitch_sigma_rad and odometer_yaw_sigma_rad must be in [0, 0.1] rad (0 = "
           "held at zero)";
  if (!(o.keyframe_distance_m > 0.0) || !(o.keyframe_angle_deg > 0.0)) {
    return "keyframe thresholds must be > 0";
  }
  if (!(o.degeneracy_threshold >= 0.0 && o.degeneracy_threshold < 1.0))
    return "degeneracy_threshold must be in [0, 1)";
  if (!(o.degeneracy_projection >= 0.0 && o.degeneracy_projection < 1.0))
    return "degeneracy_projection must be in [0, 1) (0 = no remapping)";
  if (!(o.degeneracy_projection_along >= 0.0 && o.degeneracy_projection_along < 1.0))
    return "degeneracy_projection_along must be in [0, 1) (0 = no along-track remapping)";
  if (!(o.heading_projection >= 0.0 && o.heading_projection < 1e6))
    return "heading_projection must be in [0, 1e6) 1/rad^2 (0 = never)";
  if (!(o.odometer_sway_time_constant_s >= 0.0 && o.odometer_sway_time_constant_s <= 60.0))
    return "odometer_sway_time_constant_s must be in [0, 60] s (0 = off)";
  if (!(o.deskew_step_s >= 0.0 && o.deskew_step_s <= 0.1))
    return "deskew_step_s must be in [0, 0.1] s (0 = linear from end to end)";
  return "";
}

}  // namespace

bool EstimatorOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& m) {
    if (error) *error = m;
    return false;
  };
  if (window_size < 2 || window_size > 30) return fail("window_size must be in [2, 30]");
  if (registration_rounds < 1) return fail("registration_rounds must be >= 1");
  if (!(init_gravity_s >= 0.1 && init_gravity_s <= 10.0))
    return fail("init_gravity_s must be in [0.1, 10] s");
  if (!(gravity_align_s == 0.0 || (gravity_align_s >= 3.0 && gravity_align_s <= 120.0)))
    return fail("gravity_align_s must be 0 (off) or in [3, 120] s");
  for (const std::string& why :
       {GnssProblem(*this), SubmapProblem(*this), MatchingProblem(*this), PriorProblem(*this)}) {
    if (!why.empty()) return fail(why);
  }
  std::string stage;
  if (!preprocess.IsValid(&stage)) return fail("preprocess: " + stage);
  if (!loam.IsValid(&stage)) return fail("loam: " + stage);
  if (!rail.IsValid(&stage)) return fail("rail: " + stage);
  if (!height.IsValid(&stage)) return fail("height_descriptor: " + stage);
  if (!track_bed.IsValid(&stage)) return fail("track_bed: " + stage);
  if (!straight_track.IsValid(&stage)) return fail("straight_track: " + stage);
  return true;
}

namespace {

/// The rig: LiDARs, IMU, odometer and vehicle.
void DescribeRig(const RigConfig& rig, std::ostream& s) {
  s << "rig: " << rig.rig << "\n";
  for (const LidarRig& l : rig.lidars) {
    const Eigen::Vector3d t = l.T_body_lidar.translation();
    s << "lidar " << l.name << ": topic " << l.topic << ", at [" << t.transpose() << "] m, "
      << (l.looks_down() ? "looks down" : "looks up") << ", " << l.rate_hz << " Hz\n";
  }
  s << "imu: " << rig.imu_topic << ", " << rig.imu_rate_hz << " Hz, gyro noise "
    << rig.noise.gyro_noise_density << ", accel noise " << rig.noise.accel_noise_density
    << ", gyro walk " << rig.noise.gyro_bias_walk << ", accel walk " << rig.noise.accel_bias_walk
    << ", across gaps rate " << rig.noise.gap_rate_sigma_radps << " accel "
    << rig.noise.gap_accel_sigma_mps2 << ", g " << rig.gravity_mps2 << "\n";
  s << "odometer: " << rig.odometer_topic << " joint '" << rig.odometer_joint << "', wheel "
    << rig.wheel_diameter_m << " m, " << rig.pulses_per_rev << " pulses/rev, at ["
    << rig.p_body_odometer.transpose() << "] m, speed noise " << rig.noise.odometer_speed_density
    << ", across-axis noise " << rig.noise.odometer_lateral_density << " sideways, "
    << rig.noise.odometer_vertical_density << " vertically, scale walk "
    << rig.noise.odometer_scale_walk << ", misalignment walk "
    << rig.noise.odometer_misalignment_walk << ", pulse " << rig.noise.odometer_resolution_m
    << " m\n";
  s << "vehicle: body " << rig.body_above_rail_top_m << " m above rail top, gauge " << rig.gauge_m
    << " m\n";
}

/// The ablation, the window, the local map and the LiDAR and rail matching.
void DescribeMatching(const EstimatorOptions& o, std::ostream& s) {
  s << "ablation: " << o.switches.Name() << "\n";
  s << "window_size: " << o.window_size << ", registration_rounds: " << o.registration_rounds
    << ", max_solver_iterations: " << o.max_solver_iterations << "\n";
  s << "map: voxel " << o.map_voxel_m << " m, " << o.map_points_per_voxel
    << " points/voxel, radius " << o.map_radius_m << " m, frames go in " << o.map_insert_lag
    << " states old\n";
  s << "lidar sigmas: plane " << o.plane_sigma_m << " m, edge " << o.edge_sigma_m
    << " m, correspondences within " << o.max_correspondence_m << " m, edge neighbours' spread ";
  if (o.edge_max_spread_m > 0.0) {
    s << "within " << o.edge_max_spread_m << " m RMS";
  } else {
    s << "not checked";
  }
  if (o.down_edge_soft_spread_m > 0.0) {
    s << "; the down LiDAR's edges beyond " << o.down_edge_soft_spread_m
      << " m RMS hold nothing sideways";
  }
  s << "\n";
  s << "rail plane sigmas: normal " << o.rail_normal_sigma_rad << " rad, distance "
    << o.rail_distance_sigma_m << " m; rail-head lines ";
  if (o.rail_line_sigma_m > 0.0) {
    s << "matched sideways, sigma " << o.rail_line_sigma_m << " m";
    if (o.rail_line_max_forward_m > 0.0)
      s << ", within " << o.rail_line_max_forward_m << " m ahead";
    s << "\n";
  } else {
    s << "not matched\n";
  }
}

/// The priors, the favour factors and remapping, odometer sway and deskewing.
void DescribePriors(const EstimatorOptions& o, std::ostream& s) {
  s << "initial sigmas: velocity " << o.initial_velocity_sigma_mps << " m/s, accel bias "
    << o.initial_accel_bias_sigma << " m/s^2 (after re-levelling " << o.relevelled_accel_bias_sigma
    << "), gyro bias " << o.initial_gyro_bias_sigma << " rad/s, odometer scale "
    << o.initial_scale_sigma << ", odometer misalignment pitch " << o.odometer_pitch_sigma_rad
    << " yaw " << o.odometer_yaw_sigma_rad << " rad\n";
  s << "favour factors: failure below " << o.failure_min_edges << " edges / "
    << o.failure_min_planes << " planes, degeneracy below " << o.degeneracy_threshold
    << "; solution remapping below " << o.degeneracy_projection
    << " (along the track, with the sleepers measured, below " << o.degeneracy_projection_along
    << "); heading remapping below " << o.heading_projection << " /rad^2\n";
  s << "odometer sway: ";
  if (o.odometer_sway_time_constant_s > 0.0) {
    s << "the body's rotation faster than " << o.odometer_sway_time_constant_s
      << " s is its own, not the track's\n";
  } else {
    s << "off (the body's whole rotation is the track's)\n";
  }
  s << "deskew: ";
  if (o.deskew_step_s > 0.0) {
    s << "the gyro's rotation every " << o.deskew_step_s << " s within a frame\n";
  } else {
    s << "linear from the frame's start to its end\n";
  }
}

/// Preprocessing, the height descriptor, the sleepers and the straight-track hold.
void DescribeCues(const EstimatorOptions& o, std::ostream& s) {
  s << "preprocess: range [" << o.preprocess.min_range_m << ", " << o.preprocess.max_range_m
    << "] m, flicker cell " << o.preprocess.flicker_cell_size_m << " m min "
    << o.preprocess.flicker_min_points_per_cell << ", hidden sector "
    << o.preprocess.hidden_sector_angle_deg << " deg / " << o.preprocess.hidden_sector_radius_m
    << " m\n";
  s << "height descriptor: x [" << o.height.x_min_m << ", " << o.height.x_max_m << "] y ["
    << o.height.y_min_m << ", " << o.height.y_max_m << "] bin " << o.height.bin_m << " m\n";
  s << "track bed (sleepers): ";
  if (o.track_bed.sigma_m > 0.0) {
    s << "sigma " << o.track_bed.sigma_m << " m, x [" << o.track_bed.min_forward_m << ", "
      << o.track_bed.max_forward_m << "] m, within " << o.track_bed.half_width_m
      << " m of the centre, " << o.track_bed.min_depth_m << "-" << o.track_bed.max_depth_m
      << " m below the rails, against " << o.track_bed.history_frames << " frames\n";
  } else {
    s << "off\n";
  }
  s << "straight track (heading hold): ";
  if (o.straight_track.sigma_rad > 0.0 && o.switches.use_imu) {
    s << "sigma " << o.straight_track.sigma_rad << " rad, once the gyro's heading has kept within "
      << o.straight_track.tolerance_rad << " rad of a line turning at most "
      << o.straight_track.max_rate_rps << " rad/s for " << o.straight_track.detect_s << " s\n";
  } else {
    s << "off\n";
  }
}

/// Keyframes, levelling and the GNSS fusion.
void DescribeGnss(const EstimatorOptions& o, std::ostream& s) {
  s << "keyframes: every " << o.keyframe_distance_m << " m or " << o.keyframe_angle_deg
    << " deg, written: " << (o.write_keyframes ? "yes" : "no") << "\n";
  s << "initial levelling: " << o.init_gravity_s << " s of IMU data, re-levelled after "
    << o.gravity_align_s << " s\n";
  s << "gnss: " << (o.switches.use_gnss ? "on" : "off") << ", a factor every "
    << o.gnss.factor_period_s << " s, sigma " << o.gnss.sigma_horizontal_m << " / "
    << o.gnss.sigma_vertical_m << " m, gate " << o.gnss.gate_m << " m, odometry drift "
    << o.gnss.drift_fraction << " (height " << o.gnss.vertical_drift_fraction
    << ") of the path, aligned after " << o.gnss.alignment.min_extent_m << " m, poses held "
    << o.gnss_prompt_latency_s << " s while fixes keep coming, else for smoothing up to "
    << o.gnss_max_latency_s << " s, provisional output after "
    << (o.gnss_provisional_after_s > 0.0 ? std::to_string(o.gnss_provisional_after_s) + " s"
                                         : std::string("(off)"))
    << "\n";
}

/// The submaps.
void DescribeSubmaps(const EstimatorOptions& o, std::ostream& s) {
  const SubmapOptions& m = o.submap;
  s << "submaps: " << m.keyframes << " keyframes, voxel " << m.voxel_m << " m, points within ";
  if (m.max_range_m > 0.0) {
    s << m.max_range_m << " m";
  } else {
    s << "any range";
  }
  s << ", side slip ";
  if (m.remove_side_slip) {
    s << "removed (steps across of over " << m.side_slip_max_jump_m << " m taken as jumps)";
  } else {
    s << "kept";
  }
  s << ", icp " << (m.icp ? "on" : "off") << ", ndt " << (m.ndt ? "on" : "off") << "; gnss pull "
    << m.gnss_pull << " (vertical " << m.gnss_pull_vertical << ", along beyond "
    << 0.25 * m.chain_reset_m << " m " << m.gnss_pull_along_excess << ", sideways beyond "
    << 0.75 * m.chain_reset_m << " m " << m.gnss_pull_excess << "), height loop "
    << m.gnss_height_length_m << " m, heading loop " << m.gnss_heading_length_m << " m at up to "
    << m.gnss_max_turn_rate_rad_per_m << " rad/m, chain reset beyond " << m.chain_reset_m
    << " m across / " << 2.0 * m.chain_reset_m << " m along; ndt's turn kept from a lever arm of "
    << m.ndt_min_turn_arm_m << " m; ndt along the track onto an earlier pass from an information "
    << "share of " << m.ndt_min_along_information_revisit << "\n";
}

}  // namespace

std::string EstimatorConfig::Describe() const {
  std::ostringstream s;
  DescribeRig(rig, s);
  DescribeMatching(options, s);
  DescribePriors(options, s);
  DescribeCues(options, s);
  DescribeGnss(options, s);
  DescribeSubmaps(options, s);
  return s.str();
}

bool ParseEstimatorConfig(const std::string& yaml_text,
                          const std::string& source_name,
                          EstimatorConfig* config,
                          std::string* error) {
  EstimatorConfig c;
  RigConfig& rig = c.rig;
  try {
    const YAML::Node root_node = YAML::Load(yaml_text);
    if (!root_node || root_node.IsNull())
      throw api::YamlError(source_name + ": the config is empty");
    MapReader root(root_node, "", source_name);
    root.Read("rig", &rig.rig);
    root.Read("utm_zone", &rig.utm_zone);
    ParseLidars(root, &rig);
    ParseImu(root, root_node, &rig);
    ParseOdometer(root, &rig);
    ParseGnssAndVehicle(root, &rig);
    ParseEstimatorSection(root, &c.options, &rig.noise);
    root.Finish();
  } catch (const api::YamlError& e) {
    if (error) *error = e.what();
    return false;
  } catch (const YAML::Exception& e) {
    if (error) {
      *error = source_name + ":" + std::to_string(e.mark.line + 1) + ": YAML syntax: " + e.msg;
    }
    return false;
  }
  c.options.rail.body_above_rail_top_m = rig.body_above_rail_top_m;
  c.options.rail.gauge_m = rig.gauge_m;
  c.options.gnss.p_body_antenna = rig.p_body_antenna;
  if (!rig.utm_zone.empty() && !geo::ParseZone(rig.utm_zone, &c.options.gnss.zone)) {
    if (error) *error = source_name + ": utm_zone '" + rig.utm_zone + "' is not a zone like 50N";
    return false;
  }
  std::string why;
  if (!c.options.IsValid(&why)) {
    if (error) *error = source_name + ": estimator." + why;
    return false;
  }
  why = BadNoise(c.rig.noise);
  if (!why.empty()) {
    if (error) *error = source_name + ": " + why;
    return false;
  }
  *config = std::move(c);
  return true;
}

bool LoadEstimatorConfig(const std::string& path, EstimatorConfig* config, std::string* error) {
  std::ifstream in(path);
  if (!in) {
    if (error) *error = path + ": cannot open the config file";
    return false;
  }
  std::stringstream text;
  text << in.rdbuf();
  return ParseEstimatorConfig(text.str(), path, config, error);
}

}  // namespace raillomer
