#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "estimator/backend/scan_matching.h"
#include "estimator/factors/preintegration.h"
#include "estimator/features/height_descriptor.h"
#include "estimator/features/loam_features.h"
#include "estimator/features/rail_extraction.h"
#include "estimator/features/track_bed.h"
#include "estimator/mapping/gnss_fusion.h"
#include "estimator/mapping/submap_builder.h"
#include "estimator/pipeline/straight_track.h"
#include "estimator/preprocess/filters.h"

namespace raillomer {

/// One LiDAR of the rig.
struct LidarRig {
  std::string name;
  std::string topic;
  std::string type;
  int lidar_id = 0;
  Eigen::Isometry3d T_body_lidar = Eigen::Isometry3d::Identity();
  double rate_hz = 10.0;
  double range_noise_m = 0.02;
  /// Looks down at the track (pitched down): rails are extracted from it.
  bool looks_down() const { return T_body_lidar.linear().col(0).z() < 0.0; }
};

/// The sensor rig, as raillomer-sim writes it to rig.yaml (docs/estimator.md: rig configuration).
struct RigConfig {
  std::string rig;
  std::string utm_zone;
  std::vector<LidarRig> lidars;
  std::string imu_topic = "/imu/data";
  double imu_rate_hz = 200.0;
  double gravity_mps2 = 9.81;
  PreintegrationNoise noise;
  std::string odometer_topic = "/odometer";
  std::string odometer_joint = "wheel";
  double wheel_diameter_m = 0.84;
  int pulses_per_rev = 100;
  double odometer_rate_hz = 50.0;
  Eigen::Vector3d p_body_odometer = Eigen::Vector3d::Zero();  ///< odometer lever arm
  std::string gnss_topic = "/gnss/fix";
  Eigen::Vector3d p_body_antenna = Eigen::Vector3d::Zero();
  double body_above_rail_top_m = 3.8;
  double gauge_m = 1.435;
};

/// Which parts of the estimator run: the paper's ablation study (Fig. 12).
struct AblationSwitches {
  bool use_imu = true;                ///< false: --lidar-only (constant-velocity prediction)
  bool use_odometer = true;           ///< false: --no-odometer (the LiDAR-inertial subset)
  bool use_rail_plane = true;         ///< false: --no-rail-plane
  bool use_height_descriptor = true;  ///< false: --no-height-descriptor
  bool use_favour_factors = true;     ///< false: --no-favour-factors (eq. 23 weights all 1)
  /// false: --no-gnss (odometry only, in the local frame; not part of Name(): the odometry
  /// ablations above are compared without GNSS)
  bool use_gnss = true;
  /// Ablation name for logs and tables, e.g. "full", "lidar-only".
  std::string Name() const;
};

/// Every tunable of the estimator, with defaults; overridable from the `estimator:` section.
struct EstimatorOptions {
  PreprocessOptions preprocess;
  LoamFeatureOptions loam;
  RailExtractionOptions rail;
  HeightDescriptorOptions height;
  TrackBedOptions track_bed;  ///< the sleepers as a distance measure
  /// The heading hold on straight track (needs the IMU; `straight_track.sigma_rad: 0` is off).
  StraightTrackOptions straight_track;
  AblationSwitches switches;

  int window_size = 6;             ///< states in the sliding window (eq. 2)
  int registration_rounds = 2;     ///< correspondence search + optimisation rounds
  int max_solver_iterations = 20;  ///< Ceres iterations per round (most converge in fewer)
  double map_voxel_m = 1.0;        ///< local map voxel edge
  int map_points_per_voxel = 10;   ///< local map cap per voxel
  /// A frame's features go into the local map once this many newer states have refined its
  /// pose (at the latest when it leaves the window); 0: at once, at its first single-frame
  /// estimate. Not the default: see docs/notebook/estimator-results.md for what it gains
  /// on the feature-poor runs and costs on the 20 km one.
  int map_insert_lag = 0;
  double map_radius_m = 200.0;  ///< voxels farther from the vehicle are dropped
  /// Point-to-plane and point-to-line noise (before the favour factors). Well above the
  /// sensor's 2 cm: a frame's thousands of residuals share their errors (the map is built from
  /// the same trajectory, the deskew from the same prediction), and weighted as independent
  /// 0.1 m measurements they outvote the IMU and odometer so far that a pitch error grows by
  /// feedback through the map at 100 km/h and above (docs/estimator.md: the back end).
  double plane_sigma_m = 0.3;
  double edge_sigma_m = 0.45;
  double max_correspondence_m = 1.0;  ///< neighbour search radius
  /// When > 0, an edge is matched only when its map neighbours lie within this RMS distance of
  /// their line (0: no such check, LOAM's eigenvalue ratio only). Curvature picks edge points
  /// around a soft crease (a ballast shoulder) at places that shift with range; matched to the
  /// scattered far points of the map they turn each frame (0.041 deg of yaw per frame at true
  /// poses on poor_low_embankment_b; 0.023 deg with 0.05 m). Not the default: see
  /// docs/notebook/estimator-results.md.
  double edge_max_spread_m = 0.0;
  /// When > 0, an edge of the LiDAR looking down at the track whose map neighbours lie further
  /// than this RMS from their line (a soft crease of ballast or embankment, not a corner) drops
  /// the part of its residual along the body's lateral axis: it still holds pitch,
  /// height and position along the track, but no longer turns the frame. Not the default: it
  /// helps the embankment and costs other runs about as much (docs/notebook/estimator-results.md:
  /// soft edges); 0.05 m is the value measured there.
  double down_edge_soft_spread_m = 0.0;
  double rail_normal_sigma_rad = 0.003;  ///< rail-plane normal noise (eq. 30)
  double rail_distance_sigma_m = 0.01;   ///< rail-plane distance noise
  /// When > 0, the rail-head points the rail extraction grows (down LiDAR) are matched as lines
  /// to a map of earlier rail heads, with this noise, across the track only (their along-track
  /// and vertical parts left out): they hold the frame sideways and in heading. Not the
  /// default: with the sleepers (track_bed) holding the distance they take every feature-poor
  /// run to 0.10-0.34 %, but long_20km's heading then wanders by a degree (1.10 % at its end;
  /// docs/notebook/estimator-results.md: rail heads as lines). 0.1 m is the value measured there.
  double rail_line_sigma_m = 0.0;
  /// When > 0, only rail-head points nearer than this along body x are matched as lines (0: all
  /// the extraction grows, up to 20 m). Far points turn the frame: on the first 2 km of
  /// long_20km the lines with every point turn the heading 0.07 deg in 500 m, with the points
  /// within 12 m 0.006 deg (docs/notebook/estimator-results.md). Built as the default with
  /// the lines on it turned poor_low_open_a and one embankment seed by a degree, so 0 stays.
  double rail_line_max_forward_m = 0.0;
  /// Failure detection (eq. 24): feature counts below these fail a LiDAR.
  int failure_min_edges = 20;
  int failure_min_planes = 100;
  /// Degeneracy (eq. 25): smallest eigenvalue of the LiDAR's normalised information matrix.
  double degeneracy_threshold = 0.012;
  /// Solution remapping: when both LiDARs' matches together are this degenerate, their
  /// factors stop seeing the translation along the weakest direction. 0 disables.
  double degeneracy_projection = 0.012;
  /// Along-track remapping: where the sleepers measured the frame (track_bed), matches whose
  /// weakest direction lies within 30 deg of the track are remapped below this degeneracy
  /// instead. In a tunnel the LiDARs see the distance through lamps and refuges every 25-50 m
  /// alone (degeneracy 0.012-0.03), and there their registration pulls each frame back: the
  /// odometry ran 0.3-0.5 % short through the 1.3 km tunnel
  /// (docs/notebook/estimator-results.md: the tunnel). 0 disables.
  double degeneracy_projection_along = 0.03;
  /// Heading remapping: when both LiDARs' matches together hold the heading (rotation about
  /// the vertical, the other five directions free) with less than this information per
  /// residual (1/rad^2), their factors stop seeing the heading and the gyro carries it. Weakly
  /// held, the heading follows the registration's small steady pulls (+565 urad a frame on
  /// the embankment at true poses), and the yaw gyro bias with it
  /// (docs/notebook/estimator-results.md: heading remapping). rich_high_mixed_b's frames score
  /// 20-140, the embankment's 2-5 (10th-90th percentile), the curved tunnel's 11-16. A frame
  /// left so is evaluated at the heading its matches would take for the rest of its pose (their
  /// profile), not at its predicted one: held there, the pull went sideways into the points
  /// ahead, and the odometer's sideways term turned it back into heading (the tunnel's curve
  /// 2 mrad; docs/notebook/estimator-results.md: a heading left out). 0 disables.
  double heading_projection = 20.0;
  /// s: the car body's rotation faster than this is its sway on the suspension, about its own
  /// origin (InertialBuffer::SwayAt, the gyro's angles high-passed): that roll does not swing the
  /// odometer's lever arm over the rail, and that pitch does not tilt the wheels' path, which
  /// follows the track. Slower rotation is the track's (cant, grade). 0: the body's whole
  /// rotation is the track's. At 2 s a grade change (6 permille over 2 s) left the pitch's second
  /// high-pass 0.8 mrad below zero for seconds, the path tilted against the body, and rail heads
  /// seen from two submaps 3 cm apart; 0.5 s still keeps 94 % of the body's 1.3 Hz pitch
  /// (docs/notebook/estimator-results.md: the sway's time constant).
  double odometer_sway_time_constant_s = 0.5;
  /// s: each LiDAR point is moved to the frame end by the gyro's rotation up to its own time,
  /// sampled this often (and the translation lerped), so that the car body's pitch and roll on
  /// its suspension within a frame (a rail joint's dip: 1-2 mrad in 0.1 s) does not smear the
  /// points. 0: the paper's deskew (IV.C), the frame's end-to-end increment interpolated
  /// linearly, as without the IMU.
  double deskew_step_s = 0.0025;
  /// Priors of the first state (and of the window after re-levelling, but the accelerometer
  /// bias's: relevelled_accel_bias_sigma).
  double initial_velocity_sigma_mps = 1.0;
  double initial_accel_bias_sigma = 3.0e-2;  ///< m/s^2
  /// m/s^2: the accelerometer bias prior once gravity has re-levelled the world frame, which
  /// took the bias as zero. At 0.03 the bias stood in for gravity along the track, and on
  /// feature-poor runs that start at speed the pitch drifted 2-5 mrad a minute with the LiDAR's
  /// own (docs/notebook/estimator-results.md: the accelerometer bias after re-levelling).
  double relevelled_accel_bias_sigma = 3.0e-3;
  double initial_gyro_bias_sigma = 5.0e-5;  ///< rad/s: an MTi-680G's bias stability
  double initial_scale_sigma = 0.02;        ///< odometer scale
  /// rad: priors of the odometer's misalignment (the pitch and the yaw of the wheels' path against
  /// the odometer's x axis, NavState::m), estimated with the state; 0 holds one at zero, the
  /// paper's model. Held at zero, a body sitting 1.6 mrad nose-up on its suspension drove the
  /// pitch 12 mrad off and the distance 0.9 % long (docs/notebook/estimator-results.md: the
  /// odometer's pitch). The yaw is held by default: a body yawed 1.6 mrad did no harm, and
  /// estimated, the yaw took up the LiDARs' sideways pull (-0.4 to -0.9 mrad where the truth is 0;
  /// tunnel_gnss_outage 0.122 -> 0.188 %).
  double odometer_pitch_sigma_rad = 3.0e-3;
  double odometer_yaw_sigma_rad = 0.0;
  double keyframe_distance_m = 2.0;  ///< keyframes for mapping: distance since the last
  double keyframe_angle_deg = 5.0;   ///< ... or rotation since the last
  double imu_gap_warn_s = 0.05;      ///< IMU gaps longer than this are reported
  double init_gravity_s = 4.0;       ///< IMU and odometer data for the initial roll and pitch
  /// After this long, gravity is re-estimated from the IMU against the estimated trajectory and
  /// the world frame re-levelled once (a start at speed levels the first second poorly); poses
  /// are held back until then. 0 disables.
  double gravity_align_s = 10.0;
  bool write_keyframes = true;
  /// Two-stage submap mapping (paper IV.E): `submap_keyframes` (10) keyframes per submap,
  /// thinned to one point per voxel of `submap_voxel_m` (0.1); `submap_icp` and `submap_ndt`
  /// switch the scan-to-submap ICP and the submap-to-submap NDT; `submap_gnss_pull` (0.05) and
  /// `submap_gnss_pull_vertical` (0) are the share of the way each submap moves from the
  /// odometry chain towards its GNSS pose; `submap_gnss_height_length_m` (2000) and
  /// `submap_gnss_heading_length_m` (1000) are the natural lengths of the loops that tilt and
  /// turn the chain to follow GNSS in height and sideways (0: off; without the heading loop the
  /// pull acts sideways too); `submap_gnss_pull_along_excess` (0.5) and
  /// `submap_gnss_pull_excess` (0) pull on the gap beyond 1/4 and 3/4 of
  /// `submap_chain_reset_m` (2), beyond which across the track (twice it along) GNSS places
  /// the submap.
  SubmapOptions submap;
  /// GNSS fusion (zone and antenna come from the rig). Poses are held back until the alignment
  /// to UTM, at most gnss_max_hold_s (30 s when no usable fix has arrived at all); a run that
  /// is not aligned by then stays in the local frame and says so.
  GnssFusionOptions gnss;
  double gnss_max_hold_s = 180.0;
  /// Once aligned, a pose is held until the GNSS graph has a node after it (about
  /// gnss.factor_period_s plus half gnss.factor_window_s), so that it comes out smoothed
  /// between two nodes; while nodes keep coming at most gnss_prompt_latency_s (0: no limit),
  /// so that the map reaches the server while the train is near; through a GNSS outage at
  /// most gnss_max_latency_s. Released early, it is carried from the newest node.
  double gnss_prompt_latency_s = 3.0;
  double gnss_max_latency_s = 60.0;
  /// A pose (and its keyframe's points) still held this long after it was measured goes to
  /// the stream as provisional output, placed by the fusion as it stands (the newest node
  /// carried by the odometry), so that the server can compare the stretch before the final
  /// output comes: at a run's start before the GNSS graph settles, and through an outage.
  /// 0: none.
  double gnss_provisional_after_s = 3.0;

  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// The whole configuration of raillomer-estimator.
struct EstimatorConfig {
  RigConfig rig;
  EstimatorOptions options;
  /// Every value in effect, one "key: value" per line, for the start-up log.
  std::string Describe() const;
};

/// How the estimator matches a LiDAR's features to its local map: the correspondence radius,
/// the edge spread check, and for the LiDAR looking down at the track its soft edges.
MatchOptions LidarMatchOptions(const EstimatorOptions& options, bool looks_down);

/// Parses rig.yaml (and its optional `estimator:` section); false with "file:line: key" on
/// unknown keys, wrong types or bad values.
bool ParseEstimatorConfig(const std::string& yaml_text,
                          const std::string& source_name,
                          EstimatorConfig* config,
                          std::string* error);
/// Reads and parses a config file.
bool LoadEstimatorConfig(const std::string& path, EstimatorConfig* config, std::string* error);

}  // namespace raillomer
