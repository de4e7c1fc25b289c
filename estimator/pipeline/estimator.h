#pragma once

#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "api/stream.h"
#include "estimator/features/height_descriptor.h"
#include "estimator/io/sensor_messages.h"
#include "estimator/mapping/gnss_fusion.h"
#include "estimator/mapping/provisional_submaps.h"
#include "estimator/mapping/submap_builder.h"
#include "estimator/pipeline/config.h"
#include "estimator/pipeline/inertial_buffer.h"
#include "estimator/pipeline/straight_track.h"
#include "estimator/pipeline/submap_worker.h"

namespace ceres {
class CostFunction;
}

namespace raillomer {

class GravityFit;
class SlidingWindow;
class LocalMap;
class Preintegration;

/// Diagnostics of one LiDAR in one frame.
struct LidarDiagnostics {
  bool present = false;
  size_t points = 0;  ///< after preprocessing
  size_t edges = 0, planes = 0;
  size_t matches = 0;
  double degeneracy = 0.0;
  double xi_failure = 1.0, xi_degeneracy = 1.0, xi_pose = 1.0;  ///< eq. (24-26)
};

/// The estimate and timing of one processed frame (both LiDARs on one time base).
struct FrameResult {
  int64_t stamp_ns = 0;  ///< frame end (the reference time of the deskewed points)
  /// In the local odometry frame, or, when georeferenced, in the local ENU frame whose origin
  /// is origin_utm (UTM = origin_utm + position; the zone is the rig's utm_zone).
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
  bool georeferenced = false;
  Eigen::Vector3d origin_utm = Eigen::Vector3d::Zero();
  std::string utm_zone;  ///< "50N" when georeferenced
  Eigen::Vector3d v_world = Eigen::Vector3d::Zero();
  double odometer_scale = 1.0;
  Eigen::Vector2d odometer_misalignment = Eigen::Vector2d::Zero();  ///< NavState::m (rad)
  Eigen::Vector3d gyro_bias = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_bias = Eigen::Vector3d::Zero();
  double frontend_ms = 0.0;  ///< preprocessing, deskewing, features, rails, descriptor
  double backend_ms = 0.0;   ///< matching, optimisation, marginalisation, map update
  std::vector<LidarDiagnostics> lidars;
  bool rail_plane = false;    ///< a rail plane was extracted
  bool height_shift = false;  ///< a height-descriptor displacement was used
  /// The sleeper match's correction to the predicted along-track motion (m), when it was used.
  std::optional<double> bed_shift_m;
  double degeneracy = 0.0;  ///< of both LiDARs' matches together (last registration round)
  bool projected = false;   ///< LiDAR factors blind to the weakest direction (remapping)
  /// Per-residual information of both LiDARs' matches on the heading, 1/rad^2 (last round).
  double heading_information = 0.0;
  bool heading_projected = false;  ///< LiDAR factors blind to the heading (heading_projection)
  bool straight_hold = false;      ///< on straight track: the heading held (straight_track)
  bool odometer_used = false;      ///< the odometer entered this interval's factor
  int solver_iterations = 0;
};

/// A keyframe for mapping: its final (marginalised) pose and its deskewed cloud (body frame).
struct Keyframe {
  int64_t stamp_ns = 0;
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();  ///< frame as FrameResult's
  /// Where GNSS puts the keyframe for the submap chain (GnssFusion::MapTarget), in the same
  /// frame: T_world_body fades every re-solve of the GNSS graph, this takes the large ones at
  /// once.
  Eigen::Isometry3d T_world_gnss = Eigen::Isometry3d::Identity();
  /// The odometry's own pose, before any GNSS correction (submaps are built from it).
  Eigen::Isometry3d T_odom_body = Eigen::Isometry3d::Identity();
  /// The odometry's scale error as GNSS sees it (true distance = scale x odometry), or 1.
  double odometry_scale = 1.0;
  bool georeferenced = false;
  Eigen::Vector3d origin_utm = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3f> points_body;
  std::vector<float> intensities;
};

/// Where the estimator's products go; every callback may be empty.
struct EstimatorSinks {
  /// A frame's final pose, once it leaves the sliding window (in time order, every frame).
  std::function<void(const FrameResult&)> on_frame;
  std::function<void(const Keyframe&)> on_keyframe;
  /// A problem with the input (gap, rewind, missing sensor): a human-readable line.
  std::function<void(const std::string&)> on_warning;
  /// Milestones worth a line in the log (e.g. the GNSS alignment).
  std::function<void(const std::string&)> on_info;
  /// The stream for the server (optional, not owned): every final pose and every submap of
  /// `submap_keyframes` keyframes, in UTM once georeferenced, with one monotonic sequence.
  api::StreamSink* stream = nullptr;
};

/// Counters over the whole run.
struct EstimatorStats {
  uint64_t frames = 0;
  /// Frames taken as keyframes (every keyframe_distance_m or keyframe_angle_deg): the submaps'
  /// building blocks, written to keyframes/ only with write_keyframes.
  uint64_t keyframes = 0;
  uint64_t lidar_frames_dropped = 0;  ///< out of order, duplicates, unusable
  uint64_t imu_samples = 0, imu_rejected = 0, imu_gaps = 0;
  uint64_t odometer_samples = 0, odometer_rejected = 0, odometer_outliers = 0;
  uint64_t warnings = 0;
  uint64_t bed_shifts = 0;  ///< frames whose along-track motion the sleepers measured
  double distance_m = 0.0;
  bool georeferenced = false;  ///< the output is in UTM
  GnssFusionStats gnss;
  SubmapStats submaps;  ///< the two-stage submap registration
};

/// raillomer-estimator's core: feeds on a time-ordered stream of sensor messages and estimates
/// the train's state with the sliding-window factor graph of paper section IV. No I/O, no
/// threads of its own beyond running the two LiDARs' frontends side by side and building the
/// submaps on a worker (SubmapWorker), which calls the stream sink's OnSubmap from there.
class Estimator {
 public:
  Estimator(const EstimatorConfig& config, EstimatorSinks sinks);
  ~Estimator();
  Estimator(const Estimator&) = delete;
  Estimator& operator=(const Estimator&) = delete;

  /// Takes one message (receive-time order); processes every frame whose data is complete.
  void Add(const io::SensorMessage& message);
  /// Processes what is pending and flushes the window (every frame reaches on_frame).
  void Finish();

  const EstimatorStats& stats() const { return stats_; }
  /// The newest estimate (after the last processed frame), if any.
  std::optional<FrameResult> Latest() const { return latest_; }

 private:
  struct PendingFrame {
    double start_s = 0.0;
    std::map<int, io::LidarFrame> frames;  ///< by LiDAR index
  };
  struct FrontendResult;
  struct NodeExtras;

  void Warn(const std::string& message);
  void AddLidar(int index, const io::LidarFrame& frame);
  void AddImu(const io::ImuSample& sample);
  void AddOdometer(const io::WheelOdometry& reading);
  void ProcessReady(bool flush);
  struct Prediction;
  struct RoundTerms;
  /// One synchronised frame of every LiDAR: predict, run the frontends, add the new state and
  /// its factors, register against the local map, then update the map and emit what is final.
  void ProcessFrame(const PendingFrame& pending);
  void WarnMissingLidars(const PendingFrame& pending);
  /// The new state at t_end from the newest: preintegrated (IMU, and the odometer unless it
  /// disagrees), or at constant velocity without the IMU.
  Prediction Predict(bool first, double t_end);
  void PredictInertial(Prediction* p);
  void PredictConstantVelocity(Prediction* p) const;
  /// Preprocesses, deskews and extracts features of each LiDAR's frame, one thread each.
  std::vector<FrontendResult> RunFrontends(const PendingFrame& pending,
                                           const Prediction& prediction,
                                           bool keep_cloud) const;
  FrontendResult RunFrontend(const io::LidarFrame& frame,
                             int index,
                             const Prediction& prediction,
                             bool keep_cloud) const;
  /// The body's motion from a frame's end back to its start (`start_s`), for deskewing.
  Eigen::Isometry3d BodyMotionOverFrame(double start_s,
                                        double lidar_period,
                                        const Prediction& p) const;
  /// The rail plane and rail heads of the down LiDAR, the height descriptor of the up one.
  void ExtractFrameCues(const std::vector<FrontendResult>& fronts, NodeExtras* extras) const;
  void ExtractRailCues(const std::vector<Eigen::Vector3f>& points_body, NodeExtras* extras) const;
  static void CollectCloud(const std::vector<FrontendResult>& fronts, NodeExtras* extras);
  /// Pushes the predicted state with its links to the previous one: preintegration, heading
  /// hold, rail plane, height-descriptor shift and sleeper match.
  void AddNewState(const Prediction& p, NodeExtras* extras);
  void AddPairFactors(const NodeExtras& before, const Prediction& p, NodeExtras* extras);
  /// One round of matching both LiDARs (and the rail heads) against the local map, then an
  /// optimisation of the window.
  void RegisterRound(const std::vector<FrontendResult>& fronts,
                     const Prediction& p,
                     NodeExtras* extras);
  void AddLidarTerms(const FrontendResult& front,
                     bool looks_down,
                     const Eigen::Isometry3d& T_current,
                     const Eigen::Vector3d& lateral,
                     const Prediction& p,
                     LidarDiagnostics* diag,
                     RoundTerms* terms) const;
  void AddRailLineTerms(const NodeExtras& extras,
                        const Eigen::Isometry3d& T_current,
                        const Eigen::Vector3d& forward,
                        RoundTerms* terms) const;
  /// The round's terms as one cost on the newest pose, remapped where the LiDARs are blind.
  std::shared_ptr<ceres::CostFunction> FrameCost(const Eigen::Isometry3d& T_current,
                                                 const Eigen::Vector3d& forward,
                                                 RoundTerms terms,
                                                 FrameResult* result) const;
  void InsertIntoLocalMap(const std::vector<FrontendResult>& fronts,
                          std::unique_ptr<NodeExtras> extras);
  /// Records the newest state in the frame's result, then emits the states leaving the window.
  void FinishFrame(double t_end, std::chrono::steady_clock::time_point t_frontend);
  bool Initialize(double t_end);
  /// The first state's orientation, level with yaw zero, from the IMU (and the odometer's
  /// velocity in the body, `v_body`); false until there is enough IMU data.
  bool Level(double t_end, Eigen::Quaterniond* q, Eigen::Vector3d* v_body);
  /// IMU (and, when use_odometer, odometer) preintegration over [t0, t1] from `start`'s biases.
  std::shared_ptr<Preintegration> Preintegrate(
      double t0, double t1, const NavState& start, bool use_odometer, bool* odometer_ok) const;
  void EmitOldest();
  /// The sleeper match of the newest frame against the earlier ones (TrackBedOptions): a
  /// factor on the along-track motion from the previous state.
  void AddTrackBedFactor(const NodeExtras& newest, FrameResult* result);
  /// Feeds the gyro's heading change from `prev` to `pred` to the straight-track detector and
  /// holds the newest state's heading while the track is straight (StraightTrackOptions).
  void HoldStraightHeading(const NavState& prev, const NavState& pred, FrameResult* result);
  /// Puts a frame's features into the local map at the given pose, once.
  void AddToMap(NodeExtras* node, const Eigen::Isometry3d& T_world_body);
  /// Hands a final state to the sinks (and picks keyframes).
  void Emit(std::unique_ptr<NodeExtras> extras);
  /// Georeferences a final frame (and its keyframe) once GNSS is aligned; holds them until
  /// then, and gives up after gnss_max_hold_s (the run then stays in the local frame).
  void Deliver(FrameResult frame, std::optional<Keyframe> keyframe);
  /// Hands the held frames the GNSS fusion has settled (all of them with flush) to the sinks,
  /// georeferenced or (after giving up) local, then sends what still waits provisionally.
  void ReleaseHeld(bool flush);
  /// Hands a final frame (and its keyframe, whose cloud moves on into the submaps) to the sinks;
  /// `sent_provisionally`: the keyframe went out as provisional output while it was held.
  void Output(const FrameResult& frame,
              std::optional<Keyframe> keyframe,
              bool sent_provisionally = false);
  /// Re-levels the world frame on gravity estimated from the IMU against the trajectory so
  /// far (see EstimatorOptions::gravity_align_s), then releases the held-back states. With
  /// `last_chance` it settles for whatever data there is.
  void AlignGravity(bool last_chance);
  /// Gravity fitted to the IMU's velocity increments between the states so far; `states`: how
  /// many of them it used.
  GravityFit FitGravity(size_t* states) const;
  /// Rotates the world frame by R: the window, the local maps, the held states and the sleeper
  /// history; the straight-track hold starts anew.
  void RotateWorld(const Eigen::Matrix3d& R, bool forget_tilt_gyro_bias);

  EstimatorConfig config_;
  EstimatorSinks sinks_;
  EstimatorStats stats_;
  std::map<std::string, int> lidar_topics_;

  InertialBuffer inertial_;
  std::map<int64_t, PendingFrame> pending_;  ///< by frame start (ns)
  double stream_time_s_ = -1e300;
  double last_frame_start_s_ = -1e300;
  double last_imu_t_ = -1e300, last_odo_t_ = -1e300;

  std::unique_ptr<SlidingWindow> window_;
  std::unique_ptr<LocalMap> edge_map_, plane_map_;
  std::unique_ptr<LocalMap> rail_map_;              ///< rail-head points (rail_line_sigma_m)
  std::deque<std::unique_ptr<NodeExtras>> extras_;  ///< parallel to the window's states
  /// Track-bed points (world frame, final poses) of the frames that have left the window,
  /// newest last: with the window's own, the reference of the sleeper match.
  std::deque<std::vector<Eigen::Vector3d>> bed_history_;
  StraightTrackDetector straight_;
  /// The final headings (t, rad) of the states that left the window over the last
  /// straight_track.detect_s: with the window's, a straight's heading is their mean, each less
  /// the gyro's deviation from its line, when it is recognised.
  std::deque<std::pair<double, double>> recent_headings_;
  std::optional<double> straight_heading_;  ///< the heading held, while on a straight
  bool gravity_pending_ = false;            ///< re-levelling still to come
  double next_gravity_try_s_ = 0.0;
  std::deque<std::unique_ptr<NodeExtras>> held_;  ///< final states held until re-levelling
  bool initialized_ = false;
  double last_node_t_ = 0.0;
  double init_time_s_ = 0.0;
  Eigen::Isometry3d last_keyframe_pose_ = Eigen::Isometry3d::Identity();
  bool have_keyframe_ = false;
  Eigen::Vector3d last_output_position_ = Eigen::Vector3d::Zero();
  bool have_output_ = false;
  std::optional<FrameResult> latest_;
  struct HeldOutput {
    FrameResult frame;
    std::optional<Keyframe> keyframe;
    bool provisional = false;  ///< sent as provisional output
  };
  /// Sends as provisional output what has waited gnss_provisional_after_s behind the newest
  /// frame (`newest_s`): the keyframes queued for the submap worker (after an outage it has
  /// the outage's submaps to build first), then the held poses and keyframes.
  void SendProvisional(double newest_s);
  /// Adds a keyframe's points at `T_utm_body` to the provisional submaps; sends one when it is
  /// complete. `queued`: a keyframe of the submap worker's queue, placed at its final pose (the
  /// fusion's published, continuous placement); otherwise held, placed by the fusion's graph as
  /// it stands (GnssFusion::ToEnu), which a new revision of the graph moves. Each of the two,
  /// under each revision, is a placement of its own (api::Submap::placement). Called under
  /// stream_mutex_.
  void AddProvisionalKeyframe(int64_t stamp_ns,
                              const Eigen::Isometry3d& T_utm_body,
                              const std::string& zone,
                              bool queued,
                              const std::vector<Eigen::Vector3f>& points_body,
                              const std::vector<float>& intensities);
  std::unique_ptr<GnssFusion> gnss_;  ///< null with --no-gnss
  /// Serialises the stream sink's calls: poses from here, submaps from the submap worker.
  std::mutex stream_mutex_;
  /// Poses are numbered in the order they become final and submaps by their index: both
  /// orders follow from the data alone, so a rerun on the same input numbers every message as
  /// the first run did, and the ingest client can resume without a duplicate.
  uint64_t pose_sequence_ = 0;
  std::unique_ptr<SubmapWorker> submaps_;                    ///< with a stream sink only
  std::unique_ptr<ProvisionalSubmaps> provisional_submaps_;  ///< with a stream sink only
  std::deque<HeldOutput> gnss_held_;
  bool gnss_gave_up_ = false;
  std::map<std::string, uint64_t> warning_counts_;
};

}  // namespace raillomer
