#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace raillomer::sim {

/// One piece of the horizontal/vertical alignment, in the order the train meets it.
struct AlignmentSegment {
  enum class Kind { kStraight, kCurve };
  Kind kind = Kind::kStraight;
  double length_m = 100.0;       ///< straight length, or circular-arc length of a curve
  double radius_m = 0.0;         ///< curve radius (curves only)
  int direction = 1;             ///< +1 left, -1 right (curves only)
  double transition_m = 0.0;     ///< clothoid length at each end of a curve
  double cant_mm = 0.0;          ///< superelevation on the circular arc
  double gradient_permille = 0;  ///< grade from the segment's start (rising > 0)
};

/// A kilometre range [from_m, to_m] along the alignment.
struct ChainageRange {
  double from_m = 0.0;
  double to_m = 0.0;
};

/// How densely something is placed beside the line.
struct Density {
  double per_km = 0.0;  ///< objects per km on each side
  double min_offset_m = 0.0;
  double max_offset_m = 0.0;
};

/// A station: platform beside the track, a building, a canopy.
struct Station {
  double at_m = 0.0;
  double length_m = 200.0;
  int side = 1;  ///< +1 left, -1 right
  double platform_height_m = 0.5;
};

/// A turnout onto a parallel track that runs beside the main one and rejoins it.
struct ParallelTrack {
  double from_m = 0.0;
  double to_m = 0.0;
  int side = 1;
  double spacing_m = 4.0;   ///< track centre spacing
  double diverge_m = 60.0;  ///< length over which the turnout reaches full spacing
};

/// A scripted disturbance during the run.
struct Event {
  enum class Kind { kImuDropout, kGnssOutage, kWheelSlip, kLidarBlackout };
  Kind kind = Kind::kImuDropout;
  double at_s = 0.0;
  double duration_s = 0.0;
  double slip = 0.0;  ///< wheel_slip: wheel surface speed error (0.2 = 20 % spin, <0 slide)
  std::string lidar;  ///< lidar_blackout: "up" or "down"
};

/// An edit of the corridor for a changed run, with its ground truth recorded.
struct Change {
  enum class Kind { kObjectAdded, kObjectRemoved, kObjectMoved, kVegetationGrowth, kFallenTree };
  Kind kind = Kind::kObjectAdded;
  double at_m = 0.0;                      ///< chainage (added/growth/fallen) or search point
  double offset_m = 0.0;                  ///< lateral offset, left > 0 (object_added)
  std::array<double, 3> size_m{1, 1, 1};  ///< along, across, height (object_added)
  std::string target;                     ///< removed/moved: mast, signal, building, tree
  std::array<double, 2> move_m{0, 0};     ///< moved: along, lateral
  int side = 1;                           ///< vegetation_growth side
  double intrusion_m = 0.5;               ///< vegetation_growth: depth into the envelope
};

/// Motion: a speed profile built from phases, plus body vibration.
struct MotionPhase {
  enum class Kind { kForSeconds, kForMetres, kToSpeed };
  Kind kind = Kind::kForSeconds;
  double value = 0.0;       ///< seconds, metres, or target speed in m/s
  double accel_mps2 = 0.5;  ///< kToSpeed only
};

/// One Livox Horizon unit.
struct LidarConfig {
  std::string name = "up";
  std::string topic = "/livox/lidar_up";
  std::array<double, 3> translation_m{0.3, 0.0, 0.35};  ///< in the body frame
  std::array<double, 3> rpy_deg{0.0, -12.7, 0.0};       ///< roll, pitch, yaw; pitch < 0 looks up
  uint8_t lidar_id = 0;
};

/// Every setting of a simulated run. Defaults give a plausible feature-rich line.
struct Scenario {
  std::string name = "custom";
  std::string description;
  uint32_t world_seed = 1;  ///< corridor layout; the same for every run of a line
  uint32_t seed = 1;        ///< sensor noise and vibration; --seed overrides

  // Geography and time.
  double origin_latitude_deg = 32.40;  ///< start of the line (Huoqiu area, zone 50N)
  double origin_longitude_deg = 116.28;
  double origin_height_m = 30.0;       ///< ellipsoidal height of the rail top at the start
  double initial_azimuth_deg = 30.0;   ///< clockwise from grid north
  double start_time_s = 1600000000.0;  ///< UNIX time of the first message

  // Alignment.
  std::vector<AlignmentSegment> alignment;
  double vertical_curve_m = 60.0;  ///< length over which a grade change is eased

  // Track.
  double sleeper_spacing_m = 0.6;
  double rail_joint_spacing_m = 0.0;  ///< 0 = continuous welded rail
  std::vector<ParallelTrack> parallel_tracks;

  // Catenary.
  bool catenary = true;
  double mast_spacing_min_m = 50.0;
  double mast_spacing_max_m = 65.0;
  double mast_offset_min_m = 2.5;
  double mast_offset_max_m = 3.0;
  int mast_side = -1;
  double mast_height_m = 9.0;
  double contact_wire_height_m = 6.0;
  double system_height_m = 1.4;
  double stagger_m = 0.2;

  // Corridor.
  Density trees{30.0, 6.0, 30.0};
  Density bushes{40.0, 4.0, 20.0};
  Density buildings{2.0, 15.0, 60.0};
  double signal_spacing_m = 1500.0;  ///< 0 = none
  bool km_posts = true;
  std::vector<Station> stations;
  std::vector<double> level_crossings_m;
  std::vector<ChainageRange> tunnels;
  std::vector<ChainageRange> feature_poor;  ///< no trees, bushes or buildings here
  double terrain_half_width_m = 80.0;
  double terrain_relief_m = 1.5;

  // Motion.
  double start_m = 10.0;         ///< chainage of the body frame at t = 0
  double start_speed_mps = 0.0;  ///< speed at t = 0 (negative: reversing)
  std::vector<MotionPhase> phases;
  double vibration_scale = 1.0;
  double body_height_m = 3.8;  ///< body (IMU) frame above the rail-top plane
  /// rad: the car body's (IMU's) standing pitch (positive nose down) and yaw (positive to the
  /// left) against the track, from load or mounting: the wheels' path is not its x axis.
  double body_pitch_rad = 0.0;
  double body_yaw_rad = 0.0;

  // Sensors.
  std::vector<LidarConfig> lidars;
  uint32_t points_per_frame = 24000;
  double lidar_rate_hz = 10.0;
  double range_noise_m = 0.02;
  double angular_noise_deg = 0.02;
  double min_range_m = 0.1;
  double sun_azimuth_deg = 60.0;
  double sun_elevation_deg = 10.0;
  double sun_flicker_probability = 0.15;
  double sun_cone_deg = 7.0;
  double bleeding_probability = 0.35;
  bool vehicle_body = true;  ///< the roof edge in front of the LiDARs gives near points

  double imu_rate_hz = 200.0;
  std::string imu_topic = "/imu/data";
  double gyro_noise_density = 1.22e-4;  ///< rad/s/sqrt(Hz)
  double gyro_bias_sigma = 3.9e-5;      ///< rad/s, turn-on bias
  double gyro_bias_walk = 1.0e-6;       ///< rad/s^2/sqrt(Hz)
  double accel_noise_density = 5.9e-4;  ///< m/s^2/sqrt(Hz)
  double accel_bias_sigma = 1.5e-4;     ///< m/s^2
  double accel_bias_walk = 1.0e-5;      ///< m/s^3/sqrt(Hz)
  double gravity_mps2 = 9.81;

  double odometer_rate_hz = 50.0;
  std::string odometer_topic = "/odometer";
  double wheel_diameter_m = 0.84;  ///< nominal, as configured
  int pulses_per_rev = 100;
  double odometer_scale_error = 0.004;  ///< true wheel rolls this much shorter than nominal
  double creep_sigma = 0.005;           ///< slowly varying creep, fraction of speed

  double gnss_rate_hz = 1.0;
  std::string gnss_topic = "/gnss/fix";
  std::array<double, 3> gnss_antenna_m{0.0, 0.0, 0.3};
  double gnss_horizontal_sigma_m = 0.8;  ///< per-axis Gauss-Markov
  double gnss_vertical_sigma_m = 2.4;
  double gnss_white_sigma_m = 0.3;
  double gnss_tau_s = 120.0;
  double gnss_outlier_probability = 0.01;
  double gnss_reported_sigma_m = 0.5;  ///< what the receiver claims (too optimistic)

  std::vector<Event> events;
  std::vector<Change> changes;

  /// Duration of the motion profile in seconds.
  double ProfileDurationS() const;
};

/// Loads a scenario from YAML text. Unknown keys, wrong types and impossible values give false
/// and a message naming the key and line. `resolve_base` looks up `base:` scenarios by name.
bool ParseScenario(const std::string& yaml_text,
                   const std::string& source_name,
                   Scenario* scenario,
                   std::string* error);

/// Loads a named built-in scenario or a YAML file path.
bool LoadScenario(const std::string& name_or_path, Scenario* scenario, std::string* error);

/// The built-in scenarios: name and one-line description, in listing order.
struct ScenarioInfo {
  std::string name;
  std::string description;
};
std::vector<ScenarioInfo> ListScenarios();

/// The YAML text of a built-in scenario, or empty if there is none of that name.
std::string BuiltinScenarioText(const std::string& name);

}  // namespace raillomer::sim
