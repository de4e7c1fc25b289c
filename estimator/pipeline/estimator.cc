#include "estimator/pipeline/estimator.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <future>
#include <limits>
#include <sstream>
#include <unordered_set>

#include <ceres/loss_function.h>

#include "estimator/backend/local_map.h"
#include "estimator/backend/scan_matching.h"
#include "estimator/backend/sliding_window.h"
#include "estimator/factors/gnss_factors.h"
#include "estimator/factors/heading_factor.h"
#include "estimator/factors/lidar_factors.h"
#include "estimator/factors/preintegration.h"
#include "estimator/features/loam_features.h"
#include "estimator/features/rail_extraction.h"
#include "estimator/features/track_bed.h"
#include "estimator/mapping/voxel_centroids.h"
#include "estimator/pipeline/gravity_fit.h"
#include "estimator/preprocess/filters.h"

namespace raillomer {

namespace {

using Clock = std::chrono::steady_clock;

/// Huber scale of the LiDAR residuals, in units of their sigma.
constexpr double kLidarHuber = 1.0;

double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

Eigen::Isometry3d PoseOf(const NavState& s) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = s.q.normalized().toRotationMatrix();
  T.translation() = s.p;
  return T;
}

/// Pose at fraction s in [0, 1] between a (s = 0) and b (s = 1): slerp and lerp.
Eigen::Isometry3d Interpolate(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b, double s) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  const Eigen::Quaterniond qa(a.linear()), qb(b.linear());
  T.linear() = qa.slerp(s, qb).toRotationMatrix();
  T.translation() = (1.0 - s) * a.translation() + s * b.translation();
  return T;
}

/// The body's motion over a LiDAR frame for deskewing, to the body at the preintegration's end
/// (the frame end): the rotation integrated from the gyro (the preintegration's, which starts
/// `offset_s` before the frame), sampled every `step_s` of the frame's period, and the
/// translation lerped from `translation_end_start` at the frame start to zero at its end.
FrameMotion GyroFrameMotion(const Preintegration& pre,
                            double offset_s,
                            double period_s,
                            double step_s,
                            const Eigen::Vector3d& translation_end_start) {
  const auto rotation_at = [&pre](double t) {
    return Eigen::Matrix3d(
        pre.RelativePoseAt(t, Eigen::Vector3d::Zero(), Eigen::Quaterniond::Identity()).linear());
  };
  const Eigen::Matrix3d R_end_start = rotation_at(pre.sum_dt()).transpose();
  const int n = std::max(1, static_cast<int>(std::ceil(period_s / step_s - 1e-9)));
  FrameMotion motion;
  for (int k = 0; k <= n; ++k) {
    const double u = period_s * k / n;
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = R_end_start * rotation_at(offset_s + u);
    T.translation() = (1.0 - u / period_s) * translation_end_start;
    motion.t_s.push_back(u);
    motion.T_end_t.push_back(T);
  }
  return motion;
}

/// The body's horizontal axis `axis` (0 forward, 1 lateral) at pose T, levelled.
Eigen::Vector3d HorizontalAxis(const Eigen::Isometry3d& T, int axis) {
  Eigen::Vector3d v = T.linear().col(axis);
  v.z() = 0.0;
  return v.normalized();
}

/// A LiDAR's favour factors, eq. (24-26), recorded in `diag` (its degeneracy already set), and
/// the weight they give its terms, 1 / sqrt(xi_failure xi_degeneracy xi_pose). `p_lidar` and
/// `p_inertial`: the frame's translation by the LiDAR alone and by the inertial prediction.
double FavourWeight(const EstimatorOptions& o,
                    const FeatureSet& features,
                    double p_lidar,
                    double p_inertial,
                    LidarDiagnostics* diag) {
  const bool edges_ok = static_cast<int>(features.edges.size()) > o.failure_min_edges;
  const bool planes_ok = static_cast<int>(features.planes.size()) > o.failure_min_planes;
  diag->xi_failure = edges_ok && planes_ok ? 1.0 : (!edges_ok && !planes_ok ? 100.0 : 50.0);
  diag->xi_degeneracy = diag->degeneracy <= o.degeneracy_threshold ? 10.0 : 1.0;
  // Eq. (26) as a symmetric ratio: a LiDAR whose increment disagrees either way loses weight.
  const double ratio = (p_lidar + 0.05) / (p_inertial + 0.05);
  diag->xi_pose = std::clamp(std::max(ratio, 1.0 / ratio), 1.0, 10.0);
  if (!o.switches.use_favour_factors || !o.switches.use_imu) {
    diag->xi_failure = diag->xi_degeneracy = diag->xi_pose = 1.0;
  }
  return 1.0 / std::sqrt(diag->xi_failure * diag->xi_degeneracy * diag->xi_pose);
}

double StampSeconds(int64_t stamp_ns) { return static_cast<double>(stamp_ns) * 1e-9; }

std::string Seconds(double t) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(3);
  s << t << " s";
  return s.str();
}

/// Thins a cloud on a voxel grid (first point per voxel), keeping intensities alongside.
void VoxelThin(double voxel_m,
               std::vector<Eigen::Vector3f>* points,
               std::vector<float>* intensities) {
  std::unordered_set<uint64_t> seen;
  seen.reserve(points->size());
  size_t kept = 0;
  for (size_t i = 0; i < points->size(); ++i) {
    const Eigen::Vector3f& p = (*points)[i];
    if (!seen.insert(VoxelKey(p.cast<double>(), voxel_m)).second) continue;
    (*points)[kept] = p;
    (*intensities)[kept] = (*intensities)[i];
    ++kept;
  }
  points->resize(kept);
  intensities->resize(kept);
}

}  // namespace

/// What the frontend made of one LiDAR's frame.
struct Estimator::FrontendResult {
  bool present = false;
  FeatureSet features;
  std::vector<Eigen::Vector3f> points_body;
  std::vector<float> intensities;
  PreprocessStats stats;
};

/// Per-state data the window does not hold: measurements for the next state's pair factors and
/// what the frame's result will report.
struct Estimator::NodeExtras {
  int64_t stamp_ns = 0;
  FrameResult result;
  bool has_rail = false;
  Eigen::Vector3d rail_normal = Eigen::Vector3d::UnitZ();
  double rail_distance = 0.0;
  bool has_descriptor = false;
  HeightDescriptor descriptor;
  std::vector<Eigen::Vector3f> bed;  ///< track-bed points between the rails (body frame)
  std::vector<Eigen::Vector3f> cloud;
  std::vector<float> intensities;
  /// Until the world is re-levelled: the link from the previous state, and the final state.
  std::shared_ptr<const Preintegration> preintegration;
  NavState final_state;
  /// Both LiDARs' feature points (body frame) waiting to go into the local map.
  FeatureSet map_features;
  /// Rail-head points of the down LiDAR (body frame), for the rail map.
  std::vector<Eigen::Vector3f> rail_points;
  bool in_map = false;
};

/// The prediction of a frame's state from the newest one (paper section IV-B).
struct Estimator::Prediction {
  bool first = false;   ///< the frame initialises the estimator: nothing is predicted
  double t_end = 0.0;   ///< the frame end, the new state's time
  NavState prev, pred;  ///< the newest state before the frame, and the new one predicted
  Eigen::Isometry3d T_prev = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_pred = Eigen::Isometry3d::Identity();
  std::shared_ptr<Preintegration> pre;  ///< IMU/odometer preintegration (null without the IMU)
  bool odometer_ok = false;             ///< the odometer entered `pre`
};

/// One registration round's LiDAR terms, weighted, and the matches behind them.
struct Estimator::RoundTerms {
  std::vector<PlaneTerm> planes;
  std::vector<LineTerm> lines;
  LidarMatches all;       ///< both LiDARs' matches (rail heads apart), for the remapping
  size_t rail_lines = 0;  ///< rail-head lines matched
};

Estimator::Estimator(const EstimatorConfig& config, EstimatorSinks sinks)
    : config_(config), sinks_(std::move(sinks)), straight_(config.options.straight_track) {
  if (sinks_.stream) {
    SubmapOptions submap = config.options.submap;
    submap.p_body_odometer = config.rig.p_body_odometer;  // the wheels follow the rails
    // The queue holds what the GNSS fusion releases at once after an outage, and more.
    const double max_queued_s = std::max(30.0, config.options.gnss_max_latency_s + 30.0);
    submaps_ = std::make_unique<SubmapWorker>(
        submap,
        [this](api::Submap s) {
          std::lock_guard<std::mutex> lock(stream_mutex_);
          s.sequence = s.index;
          sinks_.stream->OnSubmap(s);
        },
        max_queued_s);
    provisional_submaps_ = std::make_unique<ProvisionalSubmaps>(config.options.submap.keyframes,
                                                                config.options.submap.voxel_m,
                                                                config.options.submap.max_range_m);
  }
  // The preintegration keeps an interpolated step's noise at one IMU sample period.
  config_.rig.noise.imu_period_s = 1.0 / config_.rig.imu_rate_hz;
  inertial_.sway_time_constant_s = config_.options.odometer_sway_time_constant_s;
  for (size_t i = 0; i < config_.rig.lidars.size(); ++i) {
    lidar_topics_[config_.rig.lidars[i].topic] = static_cast<int>(i);
  }
  const EstimatorOptions& o = config_.options;
  SlidingWindowOptions w;
  w.size = o.window_size;
  w.max_iterations = o.max_solver_iterations;
  w.use_imu = o.switches.use_imu;
  w.estimate_scale = o.switches.use_odometer;
  w.initial_velocity_sigma_mps = o.initial_velocity_sigma_mps;
  w.initial_accel_bias_sigma = o.initial_accel_bias_sigma;
  w.relevelled_accel_bias_sigma = o.relevelled_accel_bias_sigma;
  w.initial_gyro_bias_sigma = o.initial_gyro_bias_sigma;
  w.initial_scale_sigma = o.initial_scale_sigma;
  w.initial_misalignment_sigma_rad =
      Eigen::Vector2d(o.odometer_pitch_sigma_rad, o.odometer_yaw_sigma_rad);
  window_ = std::make_unique<SlidingWindow>(w);
  edge_map_ = std::make_unique<LocalMap>(o.map_voxel_m, o.map_points_per_voxel);
  plane_map_ = std::make_unique<LocalMap>(o.map_voxel_m, o.map_points_per_voxel);
  rail_map_ = std::make_unique<LocalMap>(o.map_voxel_m, o.map_points_per_voxel);
  // Re-levelling needs the trajectory's velocities; without the odometer they carry the very
  // tilt it should remove (0.35 deg the wrong way on the demo run), so it is left out.
  gravity_pending_ = o.switches.use_imu && o.switches.use_odometer &&
                     !config_.rig.odometer_topic.empty() && o.gravity_align_s > 0.0;
  if (o.switches.use_gnss && !config_.rig.gnss_topic.empty()) {
    gnss_ = std::make_unique<GnssFusion>(
        o.gnss, [this](const std::string& m) { Warn(m); }, sinks_.on_info);
  }
}

Estimator::~Estimator() = default;

void Estimator::Warn(const std::string& message) {
  ++stats_.warnings;
  if (sinks_.on_warning) sinks_.on_warning(message);
}

void Estimator::Add(const io::SensorMessage& message) {
  const double receive_s = static_cast<double>(message.receive_ns) * 1e-9;
  if (receive_s < stream_time_s_ - 1e-6) {
    const std::string key = "receive-rewind";
    if (warning_counts_[key]++ < 5) {
      Warn("message on " + message.topic + " received " + Seconds(stream_time_s_ - receive_s) +
           " before the previous one: the stream is out of order; using sensor stamps");
    }
  }
  stream_time_s_ = std::max(stream_time_s_, receive_s);
  if (const auto* frame = std::get_if<io::LidarFrame>(&message.data)) {
    const auto it = lidar_topics_.find(message.topic);
    if (it != lidar_topics_.end()) AddLidar(it->second, *frame);
  } else if (const auto* imu = std::get_if<io::ImuSample>(&message.data)) {
    if (message.topic == config_.rig.imu_topic && config_.options.switches.use_imu) AddImu(*imu);
  } else if (const auto* odo = std::get_if<io::WheelOdometry>(&message.data)) {
    if (message.topic == config_.rig.odometer_topic && config_.options.switches.use_odometer) {
      AddOdometer(*odo);
    }
  } else if (const auto* fix = std::get_if<io::GnssFix>(&message.data)) {
    if (gnss_ && message.topic == config_.rig.gnss_topic) gnss_->AddFix(*fix);
  }
  ProcessReady(false);
}

void Estimator::AddLidar(int index, const io::LidarFrame& frame) {
  const double start_s = static_cast<double>(frame.timebase_ns) * 1e-9;
  const double period = 1.0 / config_.rig.lidars[static_cast<size_t>(index)].rate_hz;
  if (start_s <= last_frame_start_s_ + 0.25 * period) {
    ++stats_.lidar_frames_dropped;
    Warn("LiDAR '" + config_.rig.lidars[static_cast<size_t>(index)].name + "' frame at " +
         Seconds(start_s) + " is not newer than the last processed frame (" +
         Seconds(last_frame_start_s_) + "): dropped");
    return;
  }
  if (frame.points.empty()) {
    ++stats_.lidar_frames_dropped;
    Warn("LiDAR '" + config_.rig.lidars[static_cast<size_t>(index)].name + "' frame at " +
         Seconds(start_s) + " has no points: dropped");
    return;
  }
  // Group with a pending frame of the other LiDAR that starts at about the same time.
  for (auto& [key, pending] : pending_) {
    if (std::abs(pending.start_s - start_s) < 0.25 * period) {
      if (pending.frames.count(index)) {
        ++stats_.lidar_frames_dropped;
        Warn("LiDAR '" + config_.rig.lidars[static_cast<size_t>(index)].name +
             "' sent two frames for " + Seconds(start_s) + ": the second is dropped");
        return;
      }
      pending.frames[index] = frame;
      return;
    }
  }
  PendingFrame pending;
  pending.start_s = start_s;
  pending.frames[index] = frame;
  pending_[static_cast<int64_t>(frame.timebase_ns)] = std::move(pending);
}

void Estimator::AddImu(const io::ImuSample& sample) {
  const double t = static_cast<double>(sample.stamp_ns) * 1e-9;
  if (t <= last_imu_t_) {
    ++stats_.imu_rejected;
    if (warning_counts_["imu-rewind"]++ < 5) {
      Warn("IMU sample at " + Seconds(t) + " is not newer than the previous (" +
           Seconds(last_imu_t_) + "): dropped");
    }
    return;
  }
  if (!sample.angular_velocity_radps.allFinite() || !sample.linear_acceleration_mps2.allFinite()) {
    ++stats_.imu_rejected;
    Warn("IMU sample at " + Seconds(t) + " holds a non-finite value: dropped");
    return;
  }
  if (last_imu_t_ > -1e299 &&
      t - last_imu_t_ > std::max(config_.options.imu_gap_warn_s, 3.0 / config_.rig.imu_rate_hz)) {
    ++stats_.imu_gaps;
    Warn("IMU gap of " + Seconds(t - last_imu_t_) + " before " + Seconds(t) +
         ": bridged by interpolation, the LiDARs and the odometer");
  }
  last_imu_t_ = t;
  ++stats_.imu_samples;
  inertial_.AddImu(t, sample.angular_velocity_radps, sample.linear_acceleration_mps2);
}

void Estimator::AddOdometer(const io::WheelOdometry& reading) {
  const double t = static_cast<double>(reading.stamp_ns) * 1e-9;
  if (t <= last_odo_t_ || !std::isfinite(reading.position_rad)) {
    ++stats_.odometer_rejected;
    if (warning_counts_["odo-rewind"]++ < 5) {
      Warn("odometer reading at " + Seconds(t) +
           " is older than the previous or not finite: dropped");
    }
    return;
  }
  last_odo_t_ = t;
  ++stats_.odometer_samples;
  inertial_.AddOdometer(t, reading.position_rad * 0.5 * config_.rig.wheel_diameter_m);
}

void Estimator::ProcessReady(bool flush) {
  const size_t lidar_count = config_.rig.lidars.size();
  while (!pending_.empty()) {
    const PendingFrame& pending = pending_.begin()->second;
    const double period = 1.0 / config_.rig.lidars[0].rate_hz;
    const double end_s = pending.start_s + period;
    const bool complete = pending.frames.size() == lidar_count;
    const bool imu_ready = !config_.options.switches.use_imu || last_imu_t_ >= end_s;
    const bool odo_ready = !config_.options.switches.use_odometer ||
                           config_.rig.odometer_topic.empty() || last_odo_t_ >= end_s;
    const bool waited = stream_time_s_ >= end_s + 0.05;
    if (!(flush || waited || (complete && imu_ready && odo_ready) || pending_.size() > 20)) break;
    PendingFrame frame = std::move(pending_.begin()->second);
    pending_.erase(pending_.begin());
    ProcessFrame(frame);
  }
}

std::shared_ptr<Preintegration> Estimator::Preintegrate(
    double t0, double t1, const NavState& start, bool use_odometer, bool* odometer_ok) const {
  const RigConfig& rig = config_.rig;
  const bool use_odo =
      use_odometer && config_.options.switches.use_odometer && !rig.odometer_topic.empty();
  return inertial_.Preintegrate(t0,
                                t1,
                                start.ba,
                                start.bg,
                                start.c,
                                rig.p_body_odometer,
                                rig.noise,
                                rig.gravity_mps2,
                                use_odo,
                                odometer_ok);
}

bool Estimator::Initialize(double t_end) {
  NavState s;
  Eigen::Vector3d v_body = Eigen::Vector3d::Zero();
  if (config_.options.switches.use_imu && !Level(t_end, &s.q, &v_body)) return false;
  // Initial velocity: with IMU and odometer, from the levelling fit over its whole span;
  // otherwise from the odometer over up to the last 0.2 s (the train may start at speed).
  if (config_.options.switches.use_imu && inertial_.HasOdometer()) {
    s.v = s.q * v_body;
  } else if (inertial_.HasOdometer()) {
    const double t0 = std::max(inertial_.FirstOdometerTime(), t_end - 0.2);
    bool ok0 = false, ok1 = false;
    const double d1 = inertial_.OdometerDistanceAt(t_end, &ok1);
    const double d0 = inertial_.OdometerDistanceAt(t0, &ok0);
    if (ok0 && ok1 && t_end - t0 > 0.03)
      s.v = s.q * Eigen::Vector3d((d1 - d0) / (t_end - t0), 0.0, 0.0);
  }
  init_time_s_ = t_end;
  next_gravity_try_s_ = t_end + config_.options.gravity_align_s;
  window_->Push(t_end, s, nullptr);
  initialized_ = true;
  last_node_t_ = t_end;
  return true;
}

bool Estimator::Level(double t_end, Eigen::Quaterniond* q, Eigen::Vector3d* v_body) {
  // Roll and pitch from the first init_gravity_s of IMU data, with the velocity change from
  // the odometer's path (InertialBuffer::UpInBody). A roll error at speed reads as a turn
  // (lateral gravity = v * yaw rate): the gyro bias soaks it up and the heading drifts, and
  // no later LiDAR map on a plain line undoes it.
  const double span = config_.options.init_gravity_s;
  const auto& imu = inertial_.imu();
  if (imu.empty() || imu.back().t - imu.front().t < span - 1e-3 ||
      t_end - imu.front().t < span - 1e-3) {
    if (warning_counts_["init-imu"]++ == 0 && sinks_.on_info) {
      sinks_.on_info("initialising: levelling on the first " + Seconds(span) +
                     " of IMU data; no poses before that");
    }
    return false;
  }
  Eigen::Vector3d f;
  if (inertial_.HasOdometer()) {
    if (!inertial_.UpInBody(t_end - span, t_end, config_.rig.gravity_mps2, &f, v_body))
      return false;
  } else {
    // Without the odometer the path is unknown and the train is taken to stand still: level
    // on the first second only (a train that pulls away later would read its acceleration
    // as pitch, 1.6 deg at 0.8 m/s^2), then carry the up direction to t_end on the gyro.
    const double t0 = imu.front().t;
    const double t1 = std::min(t0 + 1.0, t_end);
    Eigen::Vector3d up_t1;
    if (!inertial_.UpInBody(t0, t1, config_.rig.gravity_mps2, &up_t1)) return false;
    bool unused = false;
    const auto pre = Preintegrate(t1, t_end, NavState(), false, &unused);
    f = pre->gamma().conjugate() * up_t1;
  }
  *q = Eigen::Quaterniond::FromTwoVectors(f.normalized(), Eigen::Vector3d::UnitZ());
  // Keep yaw zero: remove the yaw FromTwoVectors may have introduced.
  const Eigen::Vector3d x = *q * Eigen::Vector3d::UnitX();
  const double yaw = std::atan2(x.y(), x.x());
  *q = Eigen::AngleAxisd(-yaw, Eigen::Vector3d::UnitZ()) * *q;
  return true;
}

void Estimator::ProcessFrame(const PendingFrame& pending) {
  const Clock::time_point t_begin = Clock::now();
  const EstimatorOptions& o = config_.options;
  const RigConfig& rig = config_.rig;
  const double period = 1.0 / rig.lidars[0].rate_hz;
  const double t_end = pending.start_s + period;
  const int64_t stamp_ns = static_cast<int64_t>(pending.frames.begin()->second.timebase_ns) +
                           static_cast<int64_t>(std::llround(period * 1e9));
  last_frame_start_s_ = pending.start_s;
  WarnMissingLidars(pending);

  const bool first = !initialized_;
  if (first && !Initialize(t_end)) return;
  const Prediction prediction = Predict(first, t_end);

  // Frontend, one LiDAR per thread, then what the frame measures beyond its features.
  const bool keep_cloud =
      o.write_keyframes || static_cast<bool>(sinks_.on_keyframe) || sinks_.stream != nullptr;
  const std::vector<FrontendResult> fronts = RunFrontends(pending, prediction, keep_cloud);
  auto extras = std::make_unique<NodeExtras>();
  extras->stamp_ns = stamp_ns;
  if (gravity_pending_) extras->preintegration = prediction.pre;
  FrameResult& result = extras->result;
  result.stamp_ns = stamp_ns;
  result.lidars.resize(rig.lidars.size());
  result.odometer_used = prediction.odometer_ok;
  ExtractFrameCues(fronts, extras.get());
  if (keep_cloud) CollectCloud(fronts, extras.get());
  const Clock::time_point t_frontend = Clock::now();
  result.frontend_ms = Ms(t_begin, t_frontend);

  // Backend: the new state, its pair factors, then rounds of matching and optimisation.
  if (!first) AddNewState(prediction, extras.get());
  const bool have_map = !plane_map_->empty();
  if (have_map && !first) {
    for (int round = 0; round < o.registration_rounds; ++round) {
      RegisterRound(fronts, prediction, extras.get());
    }
  }
  if (!have_map && !first && o.switches.use_imu) window_->Optimize();
  for (size_t i = 0; i < fronts.size(); ++i) {
    result.lidars[i].present = fronts[i].present;
    result.lidars[i].points = fronts[i].points_body.size();
    result.lidars[i].edges = fronts[i].features.edges.size();
    result.lidars[i].planes = fronts[i].features.planes.size();
  }
  InsertIntoLocalMap(fronts, std::move(extras));
  FinishFrame(t_end, t_frontend);
}

void Estimator::WarnMissingLidars(const PendingFrame& pending) {
  const RigConfig& rig = config_.rig;
  for (size_t i = 0; i < rig.lidars.size(); ++i) {
    if (!pending.frames.count(static_cast<int>(i)) &&
        warning_counts_["missing-" + rig.lidars[i].name]++ % 50 == 0) {
      Warn("LiDAR '" + rig.lidars[i].name + "' has no frame for " + Seconds(pending.start_s) +
           ": continuing with the others");
    }
  }
}

Estimator::Prediction Estimator::Predict(bool first, double t_end) {
  Prediction p;
  p.first = first;
  p.t_end = t_end;
  p.prev = window_->Newest();
  p.pred = p.prev;
  if (!first) {
    if (config_.options.switches.use_imu) {
      PredictInertial(&p);
    } else if (window_->size() >= 2) {
      PredictConstantVelocity(&p);
    }
  }
  p.T_prev = PoseOf(p.prev);
  p.T_pred = PoseOf(p.pred);
  return p;
}

void Estimator::PredictInertial(Prediction* p) {
  p->pre = Preintegrate(last_node_t_, p->t_end, p->prev, true, &p->odometer_ok);
  p->pred = p->pre->Predict(p->prev);
  if (!p->odometer_ok || p->t_end - init_time_s_ <= 1.0) return;
  // A slipping or sliding wheel disagrees with the inertial prediction: drop its reading.
  // phi is integrated at the scale prev.c already: it is in metres.
  const double dx_pred = (p->prev.q.conjugate() * (p->pred.p - p->prev.p)).x();
  const double dx_odo = p->pre->phi().x();
  if (std::abs(dx_odo - dx_pred) <= 0.05 * std::abs(dx_pred) + 0.05) return;
  ++stats_.odometer_outliers;
  if (warning_counts_["slip"]++ % 50 == 0) {
    Warn("odometer disagrees with the IMU at " + Seconds(p->t_end) + " (" + std::to_string(dx_odo) +
         " m vs " + std::to_string(dx_pred) + " m): wheel slip or slide, reading not used");
  }
  p->pre = Preintegrate(last_node_t_, p->t_end, p->prev, false, &p->odometer_ok);
  p->pred = p->pre->Predict(p->prev);
}

void Estimator::PredictConstantVelocity(Prediction* p) const {
  const NavState older = window_->State(window_->size() - 2);
  const double dt_prev = last_node_t_ - window_->Time(window_->size() - 2);
  const Eigen::Isometry3d delta = PoseOf(older).inverse() * PoseOf(p->prev);
  const double s = dt_prev > 0.0 ? (p->t_end - last_node_t_) / dt_prev : 1.0;
  const Eigen::Isometry3d step =
      Interpolate(Eigen::Isometry3d::Identity(), delta, std::min(s, 3.0));
  const Eigen::Isometry3d T = PoseOf(p->prev) * step;
  p->pred.p = T.translation();
  p->pred.q = Eigen::Quaterniond(T.linear());
}

std::vector<Estimator::FrontendResult> Estimator::RunFrontends(const PendingFrame& pending,
                                                               const Prediction& prediction,
                                                               bool keep_cloud) const {
  std::vector<FrontendResult> fronts(config_.rig.lidars.size());
  std::vector<std::future<void>> jobs;
  for (const auto& entry : pending.frames) {
    const int index = entry.first;
    const io::LidarFrame* frame = &entry.second;
    jobs.push_back(std::async(std::launch::async, [&, index, frame] {
      fronts[static_cast<size_t>(index)] = RunFrontend(*frame, index, prediction, keep_cloud);
    }));
  }
  for (auto& job : jobs) job.get();
  return fronts;
}

Estimator::FrontendResult Estimator::RunFrontend(const io::LidarFrame& frame,
                                                 int index,
                                                 const Prediction& prediction,
                                                 bool keep_cloud) const {
  const EstimatorOptions& o = config_.options;
  const LidarRig& lidar = config_.rig.lidars[static_cast<size_t>(index)];
  FrontendResult out;
  out.present = true;
  const double lidar_period = 1.0 / lidar.rate_hz;
  Scan scan = ScanFromLidarFrame(frame, index, lidar_period);
  out.stats = Preprocess(o.preprocess, &scan);
  const double start = static_cast<double>(frame.timebase_ns) * 1e-9;
  const Eigen::Isometry3d T_end_start = BodyMotionOverFrame(start, lidar_period, prediction);
  if (prediction.pre && o.deskew_step_s > 0.0) {
    Deskew(lidar.T_body_lidar,
           GyroFrameMotion(*prediction.pre,
                           start - last_node_t_,
                           lidar_period,
                           o.deskew_step_s,
                           T_end_start.translation()),
           &scan);
  } else {
    Deskew(lidar.T_body_lidar, T_end_start, &scan);
  }
  out.features = ExtractLoamFeatures(o.loam, scan);
  out.points_body.reserve(scan.points.size());
  for (const ScanPoint& p : scan.points) out.points_body.push_back(p.p);
  if (keep_cloud) {
    out.intensities.reserve(scan.points.size());
    for (const ScanPoint& p : scan.points) out.intensities.push_back(p.intensity);
  }
  return out;
}

Eigen::Isometry3d Estimator::BodyMotionOverFrame(double start_s,
                                                 double lidar_period,
                                                 const Prediction& p) const {
  Eigen::Isometry3d T_end_start = Eigen::Isometry3d::Identity();
  if (!p.first && p.t_end > last_node_t_) {
    // The pose at the frame start, interpolated between the previous state and the prediction.
    const double s = std::clamp((start_s - last_node_t_) / (p.t_end - last_node_t_), -1.0, 1.0);
    T_end_start = p.T_pred.inverse() * Interpolate(p.T_prev, p.T_pred, s);
  } else if (p.first) {
    T_end_start.translation() = -p.prev.v.norm() * lidar_period * Eigen::Vector3d::UnitX();
  }
  return T_end_start;
}

void Estimator::ExtractFrameCues(const std::vector<FrontendResult>& fronts,
                                 NodeExtras* extras) const {
  const EstimatorOptions& o = config_.options;
  const bool links = o.switches.use_imu;
  for (size_t i = 0; i < fronts.size(); ++i) {
    if (!fronts[i].present) continue;
    const bool down = config_.rig.lidars[i].looks_down();
    if (down && o.switches.use_rail_plane && links && !extras->has_rail) {
      ExtractRailCues(fronts[i].points_body, extras);
    }
    if (!down && o.switches.use_height_descriptor && links && !extras->has_descriptor) {
      extras->descriptor = ComputeHeightDescriptor(o.height, fronts[i].points_body);
      extras->has_descriptor = true;
    }
  }
}

void Estimator::ExtractRailCues(const std::vector<Eigen::Vector3f>& points_body,
                                NodeExtras* extras) const {
  const EstimatorOptions& o = config_.options;
  const RailExtraction rails = ExtractRails(o.rail, points_body);
  if (!rails.ok) return;
  extras->has_rail = true;
  extras->rail_normal = rails.normal;
  extras->rail_distance = rails.distance;
  if (o.track_bed.sigma_m > 0.0) extras->bed = SelectTrackBed(o.track_bed, rails, points_body);
  if (o.rail_line_sigma_m > 0.0) {
    const float reach = o.rail_line_max_forward_m > 0.0
                            ? static_cast<float>(o.rail_line_max_forward_m)
                            : std::numeric_limits<float>::infinity();
    for (const std::vector<Eigen::Vector3f>* side : {&rails.left_points, &rails.right_points})
      for (const Eigen::Vector3f& q : *side)
        if (q.x() < reach) extras->rail_points.push_back(q);
  }
}

void Estimator::CollectCloud(const std::vector<FrontendResult>& fronts, NodeExtras* extras) {
  for (const FrontendResult& f : fronts) {
    extras->cloud.insert(extras->cloud.end(), f.points_body.begin(), f.points_body.end());
    extras->intensities.insert(
        extras->intensities.end(), f.intensities.begin(), f.intensities.end());
  }
}

void Estimator::AddNewState(const Prediction& p, NodeExtras* extras) {
  const EstimatorOptions& o = config_.options;
  window_->Push(p.t_end, p.pred, p.pre);
  if (o.switches.use_imu && o.straight_track.sigma_rad > 0.0)
    HoldStraightHeading(p.prev, p.pred, &extras->result);
  if (!extras_.empty()) AddPairFactors(*extras_.back(), p, extras);
  if (o.track_bed.sigma_m > 0.0 && !extras->bed.empty())
    AddTrackBedFactor(*extras, &extras->result);
}

void Estimator::AddPairFactors(const NodeExtras& before, const Prediction& p, NodeExtras* extras) {
  const EstimatorOptions& o = config_.options;
  if (before.has_rail && extras->has_rail) {
    window_->AddNewestPairFactor(std::make_shared<RailPlaneFactor>(before.rail_normal,
                                                                   before.rail_distance,
                                                                   extras->rail_normal,
                                                                   extras->rail_distance,
                                                                   1.0 / o.rail_normal_sigma_rad,
                                                                   1.0 / o.rail_distance_sigma_m),
                                 std::make_shared<ceres::HuberLoss>(3.0));
    extras->result.rail_plane = true;
  }
  if (before.has_descriptor && extras->has_descriptor) {
    const double dx_pred = (p.T_prev.inverse() * p.T_pred).translation().x();
    const LongitudinalShift shift =
        EstimateLongitudinalShift(o.height, before.descriptor, extras->descriptor, dx_pred);
    if (shift.ok) {
      window_->AddNewestPairFactor(
          std::make_shared<LongitudinalShiftFactor>(shift.dx_m, std::max(shift.sigma_m, 0.05)),
          std::make_shared<ceres::HuberLoss>(2.0));
      extras->result.height_shift = true;
    }
  }
}

void Estimator::RegisterRound(const std::vector<FrontendResult>& fronts,
                              const Prediction& p,
                              NodeExtras* extras) {
  const Eigen::Isometry3d T_current = PoseOf(window_->Newest());
  // The body's horizontal axes: soft edges (down_edge_soft_spread_m) say nothing along the
  // lateral one, rail-head lines nothing along the forward one.
  const Eigen::Vector3d forward = HorizontalAxis(T_current, 0);
  const Eigen::Vector3d lateral = HorizontalAxis(T_current, 1);
  RoundTerms terms;
  for (size_t i = 0; i < fronts.size(); ++i) {
    if (!fronts[i].present) continue;
    AddLidarTerms(fronts[i],
                  config_.rig.lidars[i].looks_down(),
                  T_current,
                  lateral,
                  p,
                  &extras->result.lidars[i],
                  &terms);
  }
  AddRailLineTerms(*extras, T_current, forward, &terms);
  window_->SetNewestLidarFactor(FrameCost(T_current, forward, std::move(terms), &extras->result));
  const WindowSummary summary = window_->Optimize();
  extras->result.solver_iterations += summary.iterations;
}

void Estimator::AddLidarTerms(const FrontendResult& front,
                              bool looks_down,
                              const Eigen::Isometry3d& T_current,
                              const Eigen::Vector3d& lateral,
                              const Prediction& p,
                              LidarDiagnostics* diag,
                              RoundTerms* terms) const {
  const EstimatorOptions& o = config_.options;
  // The down LiDAR's soft edges (creases, not corners): see down_edge_soft_spread_m.
  const LidarMatches matches = MatchFeatures(
      LidarMatchOptions(o, looks_down), front.features, T_current, *edge_map_, *plane_map_);
  const LidarOnlySolution lidar_only = SolveLidarOnly(matches, T_current, 4);
  diag->matches = matches.size();
  diag->degeneracy = lidar_only.degeneracy;
  const double p_lidar = (p.T_prev.inverse() * lidar_only.T_world_body).translation().norm();
  const double p_inertial = (p.T_prev.inverse() * p.T_pred).translation().norm();
  const double favour = FavourWeight(o, front.features, p_lidar, p_inertial, diag);
  const double w_plane = favour / o.plane_sigma_m;
  const double w_edge = favour / o.edge_sigma_m;
  terms->all.planes.insert(terms->all.planes.end(), matches.planes.begin(), matches.planes.end());
  terms->all.lines.insert(terms->all.lines.end(), matches.lines.begin(), matches.lines.end());
  for (const PlaneMatch& m : matches.planes) {
    terms->planes.push_back({m.p_body, m.normal, m.d, w_plane});
  }
  for (const LineMatch& m : matches.lines) {
    terms->lines.emplace_back(m.p_body, m.point, m.direction, w_edge);
    if (m.soft) terms->lines.back().Ignore(lateral);
  }
}

void Estimator::AddRailLineTerms(const NodeExtras& extras,
                                 const Eigen::Isometry3d& T_current,
                                 const Eigen::Vector3d& forward,
                                 RoundTerms* terms) const {
  // Rail heads against the rail map: lines along the track that hold the frame sideways and
  // in heading where the LiDARs' other features are soft or few.
  if (extras.rail_points.empty() || rail_map_->empty()) return;
  const EstimatorOptions& o = config_.options;
  FeatureSet rail;
  rail.edges = extras.rail_points;
  // Edges only: with no plane features the plane map is never searched.
  const LidarMatches matches =
      MatchFeatures(LidarMatchOptions(o, true), rail, T_current, *rail_map_, *rail_map_);
  for (const LineMatch& m : matches.lines) {
    terms->lines.emplace_back(m.p_body, m.point, m.direction, 1.0 / o.rail_line_sigma_m);
    terms->lines.back().Ignore(forward);
    terms->lines.back().Ignore(Eigen::Vector3d::UnitZ());
  }
  terms->rail_lines = matches.lines.size();
}

std::shared_ptr<ceres::CostFunction> Estimator::FrameCost(const Eigen::Isometry3d& T_current,
                                                          const Eigen::Vector3d& forward,
                                                          RoundTerms terms,
                                                          FrameResult* result) const {
  const EstimatorOptions& o = config_.options;
  // Solution remapping: what neither LiDAR observes is left to the other factors.
  const LidarOnlySolution frame = SolveLidarOnly(terms.all, T_current, 1);
  result->degeneracy = frame.degeneracy;
  // Where the sleepers measured the frame, a weak direction along the track (within 30 deg)
  // is theirs below a higher bar: the LiDARs' few cues there (a tunnel's lamps and refuges)
  // pull each frame back.
  const bool along_track = result->bed_shift_m.has_value() &&
                           std::fabs(frame.weakest_direction.dot(forward)) > std::cos(M_PI / 6.0);
  const double projection = along_track
                                ? std::max(o.degeneracy_projection, o.degeneracy_projection_along)
                                : o.degeneracy_projection;
  const size_t matched = terms.all.size();
  result->projected = projection > 0.0 && matched >= 6 && frame.degeneracy < projection;
  result->heading_information = frame.heading_information;
  // The rail-head lines, when matched, hold the heading themselves; without the IMU there is
  // no gyro to carry it.
  result->heading_projected = o.heading_projection > 0.0 && o.switches.use_imu && matched >= 6 &&
                              terms.rail_lines == 0 &&
                              frame.heading_information < o.heading_projection;
  // Both LiDARs' terms, each under a Huber loss, as one residual block on the pose.
  std::shared_ptr<ceres::CostFunction> cost = std::make_shared<LidarFrameCost>(
      std::move(terms.planes), std::move(terms.lines), kLidarHuber);
  if (!result->projected && !result->heading_projected) return cost;
  PoseRemapping remapping;
  if (result->projected) {
    remapping.direction = frame.weakest_direction;
    remapping.p0 = T_current.translation();
  }
  if (result->heading_projected) {
    // The profile is about the pose it was linearised at (T_current, one iteration).
    remapping.q0 = Eigen::Quaterniond(frame.T_linearized.linear());
    remapping.heading_z0 = frame.heading_z0;
    remapping.heading_gain = frame.heading_gain;
    remapping.heading_p_ref = frame.T_linearized.translation();
  }
  return std::make_shared<RemappedPoseCost>(std::move(cost), remapping);
}

void Estimator::InsertIntoLocalMap(const std::vector<FrontendResult>& fronts,
                                   std::unique_ptr<NodeExtras> extras) {
  // The local map takes each frame once it is `map_insert_lag` states old in the window (its
  // pose refined by that many later frames; by default at once), and every frame while the map
  // is empty.
  FeatureSet& pending_map = extras->map_features;
  for (const FrontendResult& f : fronts) {
    pending_map.edges.insert(
        pending_map.edges.end(), f.features.edges.begin(), f.features.edges.end());
    pending_map.planes.insert(
        pending_map.planes.end(), f.features.planes.begin(), f.features.planes.end());
  }
  extras_.push_back(std::move(extras));
  // extras_[i] belongs to the window's state i (both gain the frame and lose the oldest together).
  const int lag = plane_map_->empty() ? 0 : config_.options.map_insert_lag;
  for (int i = 0; i + lag < static_cast<int>(extras_.size()); ++i) {
    AddToMap(extras_[static_cast<size_t>(i)].get(), PoseOf(window_->State(i)));
  }
  if (stats_.frames % 10 == 0) {
    const Eigen::Vector3d centre = window_->Newest().p;
    const double radius = config_.options.map_radius_m;
    edge_map_->RemoveFar(centre, radius);
    plane_map_->RemoveFar(centre, radius);
    rail_map_->RemoveFar(centre, radius);
  }
}

void Estimator::FinishFrame(double t_end, Clock::time_point t_frontend) {
  last_node_t_ = t_end;
  ++stats_.frames;
  const NavState newest = window_->Newest();
  FrameResult& result = extras_.back()->result;
  result.backend_ms = Ms(t_frontend, Clock::now());
  result.T_world_body = PoseOf(newest);
  result.v_world = newest.v;
  result.odometer_scale = newest.c;
  result.odometer_misalignment = newest.m;
  latest_ = result;
  if (gravity_pending_ && t_end >= next_gravity_try_s_) AlignGravity(false);
  while (window_->Full()) {
    const Clock::time_point t_pop = Clock::now();
    EmitOldest();
    // Marginalisation is part of this frame's backend time.
    extras_.back()->result.backend_ms += Ms(t_pop, Clock::now());
  }
  inertial_.Trim(last_node_t_ - 1.0);
}

void Estimator::HoldStraightHeading(const NavState& prev,
                                    const NavState& pred,
                                    FrameResult* result) {
  const StraightTrackOptions& st = config_.options.straight_track;
  // The gyro's turn about the vertical, its bias estimate put back (StraightTrackDetector).
  const double t_new = window_->Time(window_->size() - 1);
  const double bias_up = (prev.q * prev.bg).z();
  straight_.Add(t_new,
                WrapAngle(HeadingOf(pred.q) - HeadingOf(prev.q)) + bias_up * (t_new - last_node_t_),
                bias_up);
  if (straight_.ended()) {
    // The train has begun to turn: the states still in the window may be in the curve's
    // transition already, so none of them keeps the hold.
    window_->ClearUnaryFactors();
    straight_heading_.reset();
  }
  if (straight_.started()) {
    // The straight's heading: the mean over its recognition span of the final headings and of
    // the window's current ones, each less the gyro's deviation from its line there (the car
    // body's sway, or the last of a transition).
    std::vector<double> headings;
    for (const auto& [t, h] : recent_headings_) headings.push_back(h - straight_.DeviationAt(t));
    for (int i = 0; i < window_->size(); ++i) {
      headings.push_back(HeadingOf(window_->State(i).q) - straight_.DeviationAt(window_->Time(i)));
    }
    const double h0 = headings.front();
    double sum = 0.0;
    for (double h : headings) sum += WrapAngle(h - h0);
    straight_heading_ = h0 + sum / static_cast<double>(headings.size());
  }
  if (straight_heading_) {
    window_->AddNewestUnaryFactor(
        std::make_shared<HeadingHoldFactor>(*straight_heading_, st.sigma_rad));
    result->straight_hold = true;
  }
}

void Estimator::AddTrackBedFactor(const NodeExtras& newest, FrameResult* result) {
  const TrackBedOptions& b = config_.options.track_bed;
  const int n = window_->size();
  if (n < 2) return;
  // The reference: the bed points of the window's earlier frames and of those that left it,
  // in the body frame of the previous state.
  const Eigen::Isometry3d T_prev_world = PoseOf(window_->State(n - 2)).inverse();
  std::vector<Eigen::Vector3d> reference;
  for (const std::vector<Eigen::Vector3d>& frame : bed_history_) {
    for (const Eigen::Vector3d& p : frame) reference.push_back(T_prev_world * p);
  }
  for (int i = 0; i + 1 < n; ++i) {
    const Eigen::Isometry3d T = T_prev_world * PoseOf(window_->State(i));
    for (const Eigen::Vector3f& p : extras_[static_cast<size_t>(i)]->bed)
      reference.push_back(T * p.cast<double>());
  }
  const Eigen::Isometry3d T_rel = T_prev_world * PoseOf(window_->Newest());
  std::vector<Eigen::Vector3d> current;
  current.reserve(newest.bed.size());
  for (const Eigen::Vector3f& p : newest.bed) current.push_back(T_rel * p.cast<double>());
  const Eigen::Vector3d normal = T_rel.linear() * newest.rail_normal;
  const double distance = newest.rail_distance - normal.dot(T_rel.translation());
  const TrackBedShift shift = EstimateTrackBedShift(b, reference, current, normal, distance);
  if (!shift.ok) return;
  window_->AddNewestPairFactor(
      std::make_shared<LongitudinalShiftFactor>(T_rel.translation().x() + shift.shift_m,
                                                std::max(shift.sigma_m, b.sigma_m)),
      std::make_shared<ceres::HuberLoss>(2.0));
  result->bed_shift_m = shift.shift_m;
  ++stats_.bed_shifts;
}

void Estimator::AddToMap(NodeExtras* node, const Eigen::Isometry3d& T_world_body) {
  if (node->in_map) return;
  auto to_world = [&](const std::vector<Eigen::Vector3f>& body) {
    std::vector<Eigen::Vector3d> world;
    world.reserve(body.size());
    for (const Eigen::Vector3f& p : body) world.push_back(T_world_body * p.cast<double>());
    return world;
  };
  edge_map_->Add(to_world(node->map_features.edges));
  plane_map_->Add(to_world(node->map_features.planes));
  if (!node->rail_points.empty()) rail_map_->Add(to_world(node->rail_points));
  node->rail_points = {};
  node->in_map = true;
  node->map_features = FeatureSet();
}

void Estimator::EmitOldest() {
  double t = 0.0;
  const NavState s = window_->PopOldest(&t);
  std::unique_ptr<NodeExtras> extras = std::move(extras_.front());
  extras_.pop_front();
  FrameResult& result = extras->result;
  AddToMap(extras.get(), PoseOf(s));
  if (config_.options.track_bed.sigma_m > 0.0) {
    std::vector<Eigen::Vector3d> bed;
    bed.reserve(extras->bed.size());
    const Eigen::Isometry3d T = PoseOf(s);
    for (const Eigen::Vector3f& p : extras->bed) bed.push_back(T * p.cast<double>());
    bed_history_.push_back(std::move(bed));
    while (static_cast<int>(bed_history_.size()) > config_.options.track_bed.history_frames)
      bed_history_.pop_front();
  }
  extras->bed.clear();
  extras->bed.shrink_to_fit();
  recent_headings_.emplace_back(t, HeadingOf(s.q));
  while (!recent_headings_.empty() &&
         recent_headings_.front().first < t - config_.options.straight_track.detect_s)
    recent_headings_.pop_front();
  result.T_world_body = PoseOf(s);
  result.v_world = s.v;
  result.odometer_scale = s.c;
  result.odometer_misalignment = s.m;
  result.gyro_bias = s.bg;
  result.accel_bias = s.ba;
  if (gravity_pending_) {
    // Held back until the world is re-levelled; the cloud is thinned now to bound the memory.
    extras->final_state = s;
    if (!extras->cloud.empty()) VoxelThin(0.1, &extras->cloud, &extras->intensities);
    held_.push_back(std::move(extras));
    return;
  }
  Emit(std::move(extras));
}

void Estimator::Emit(std::unique_ptr<NodeExtras> extras) {
  FrameResult& result = extras->result;
  const Eigen::Vector3d position = result.T_world_body.translation();
  if (have_output_) stats_.distance_m += (position - last_output_position_).norm();
  last_output_position_ = position;
  have_output_ = true;

  std::optional<Keyframe> keyframe;
  const Eigen::Isometry3d delta = last_keyframe_pose_.inverse() * result.T_world_body;
  const double angle_deg = Eigen::AngleAxisd(delta.linear()).angle() * 180.0 / M_PI;
  if (!have_keyframe_ || delta.translation().norm() >= config_.options.keyframe_distance_m ||
      angle_deg >= config_.options.keyframe_angle_deg) {
    have_keyframe_ = true;
    last_keyframe_pose_ = result.T_world_body;
    ++stats_.keyframes;
    if ((sinks_.on_keyframe || sinks_.stream) && !extras->cloud.empty()) {
      Keyframe k;
      k.stamp_ns = result.stamp_ns;
      k.T_world_body = result.T_world_body;
      k.T_world_gnss = result.T_world_body;
      k.T_odom_body = result.T_world_body;
      k.points_body = std::move(extras->cloud);
      k.intensities = std::move(extras->intensities);
      VoxelThin(0.1, &k.points_body, &k.intensities);
      keyframe = std::move(k);
    }
  }
  Deliver(std::move(result), std::move(keyframe));
}

void Estimator::Deliver(FrameResult frame, std::optional<Keyframe> keyframe) {
  if (!gnss_ || gnss_gave_up_) {
    Output(frame, std::move(keyframe));
    return;
  }
  gnss_->AddOdometry(frame.stamp_ns, frame.T_world_body);
  stats_.gnss = gnss_->stats();
  gnss_held_.push_back({std::move(frame), std::move(keyframe)});
  ReleaseHeld(false);
}

void Estimator::ReleaseHeld(bool flush) {
  if (gnss_held_.empty()) return;
  const double newest_s = StampSeconds(gnss_held_.back().frame.stamp_ns);
  const double held_s = newest_s - StampSeconds(gnss_held_.front().frame.stamp_ns);
  if (!gnss_->aligned()) {
    // Waiting for the alignment, at most gnss_max_hold_s (30 s when no fix has come at all).
    if (!flush && !gnss_->AlignmentOverdue(held_s, config_.options.gnss_max_hold_s)) return;
    gnss_gave_up_ = true;
    Warn("not georeferenced: " +
         (flush ? std::string("the run ended before the GNSS alignment")
                : "no GNSS alignment after " + Seconds(held_s)) +
         " (" + gnss_->pending_reason() + "); the output stays in the local odometry frame");
    while (!gnss_held_.empty()) {
      Output(gnss_held_.front().frame, std::move(gnss_held_.front().keyframe));
      gnss_held_.pop_front();
    }
    return;
  }
  // Aligned: a pose goes out once the GNSS graph has a node after it (it is then smoothed
  // between two nodes), or when it has waited gnss_max_latency_s (a GNSS outage), or at the
  // end of the run; those are extrapolated from the newest node.
  stats_.georeferenced = true;
  while (!gnss_held_.empty()) {
    HeldOutput& h = gnss_held_.front();
    const double t = StampSeconds(h.frame.stamp_ns);
    if (!flush &&
        !gnss_->Releases(
            t, newest_s, config_.options.gnss_prompt_latency_s, config_.options.gnss_max_latency_s))
      break;
    const Eigen::Isometry3d T_odom_body = h.frame.T_world_body;
    const Eigen::Isometry3d T_map_target = gnss_->MapTarget(T_odom_body, t);
    h.frame.T_world_body = gnss_->Publish(T_odom_body, t);
    h.frame.georeferenced = true;
    h.frame.origin_utm = gnss_->origin_utm();
    h.frame.utm_zone = gnss_->zone().Name();
    if (h.keyframe) {
      h.keyframe->T_world_body = h.frame.T_world_body;  // the keyframe is this frame
      h.keyframe->T_world_gnss = T_map_target;
      h.keyframe->odometry_scale = gnss_->odometry_scale();
      h.keyframe->georeferenced = true;
      h.keyframe->origin_utm = h.frame.origin_utm;
    }
    Output(h.frame, std::move(h.keyframe), h.provisional);
    gnss_held_.pop_front();
  }
  if (!flush) SendProvisional(newest_s);
}

void Estimator::SendProvisional(double newest_s) {
  const double after_s = config_.options.gnss_provisional_after_s;
  if (!sinks_.stream || after_s <= 0.0) return;
  const bool held_behind = !gnss_held_.empty() && gnss_held_.front().provisional;
  if (!held_behind && !submaps_->BehindProvisional()) {
    // The final output caught up: what was gathered goes out now, not with a later outage.
    if (std::optional<api::Submap> rest = provisional_submaps_->Flush()) {
      std::lock_guard<std::mutex> lock(stream_mutex_);
      sinks_.stream->OnProvisionalSubmap(*rest);
    }
  }
  // Queued keyframes are final (their poses went out) but their submaps are not built yet; they
  // are older than anything held.
  const auto before_ns = static_cast<int64_t>((newest_s - after_s) * 1e9);
  for (const SubmapKeyframe& k : submaps_->TakeProvisional(before_ns)) {
    if (!k.georeferenced) continue;
    std::lock_guard<std::mutex> lock(stream_mutex_);
    AddProvisionalKeyframe(
        k.stamp_ns, k.T_world_body, k.utm_zone, true, k.points_body, k.intensities);
  }
  const Eigen::Vector3d origin = gnss_->origin_utm();
  const std::string zone = gnss_->zone().Name();
  for (HeldOutput& h : gnss_held_) {
    const double t = StampSeconds(h.frame.stamp_ns);
    if (newest_s - t < after_s) break;
    if (h.provisional) continue;
    h.provisional = true;
    Eigen::Isometry3d T_utm_body = gnss_->ToEnu(h.frame.T_world_body, t);
    T_utm_body.translation() += origin;
    api::StreamPose pose;
    pose.stamp_ns = h.frame.stamp_ns;
    pose.georeferenced = true;
    pose.utm_zone = zone;
    pose.p = T_utm_body.translation();
    pose.q = Eigen::Quaterniond(T_utm_body.linear()).normalized();
    std::lock_guard<std::mutex> lock(stream_mutex_);
    sinks_.stream->OnProvisionalPose(pose);
    if (h.keyframe)
      AddProvisionalKeyframe(h.keyframe->stamp_ns,
                             T_utm_body,
                             zone,
                             false,
                             h.keyframe->points_body,
                             h.keyframe->intensities);
  }
}

void Estimator::AddProvisionalKeyframe(int64_t stamp_ns,
                                       const Eigen::Isometry3d& T_utm_body,
                                       const std::string& zone,
                                       bool queued,
                                       const std::vector<Eigen::Vector3f>& points_body,
                                       const std::vector<float>& intensities) {
  const auto placement = static_cast<uint32_t>(2 * gnss_->revision() + (queued ? 2 : 1));
  for (const api::Submap& submap :
       provisional_submaps_->Add(stamp_ns, T_utm_body, zone, placement, points_body, intensities))
    sinks_.stream->OnProvisionalSubmap(submap);
}

void Estimator::Output(const FrameResult& frame,
                       std::optional<Keyframe> keyframe,
                       bool sent_provisionally) {
  if (sinks_.on_frame) sinks_.on_frame(frame);
  if (keyframe && sinks_.on_keyframe) sinks_.on_keyframe(*keyframe);
  if (!sinks_.stream) return;
  api::StreamPose pose;
  pose.stamp_ns = frame.stamp_ns;
  pose.georeferenced = frame.georeferenced;
  pose.utm_zone = frame.utm_zone;
  pose.p = frame.T_world_body.translation() +
           (frame.georeferenced ? frame.origin_utm : Eigen::Vector3d::Zero());
  pose.q = Eigen::Quaterniond(frame.T_world_body.linear()).normalized();
  {
    std::lock_guard<std::mutex> lock(stream_mutex_);
    pose.sequence = pose_sequence_++;
    sinks_.stream->OnPose(pose);
  }
  if (!keyframe) return;
  SubmapKeyframe k;
  k.stamp_ns = keyframe->stamp_ns;
  k.T_world_body = keyframe->T_world_gnss;
  if (keyframe->georeferenced) k.T_world_body.translation() += keyframe->origin_utm;
  k.T_odom_body = keyframe->T_odom_body;
  k.odometry_scale = keyframe->odometry_scale;
  k.georeferenced = keyframe->georeferenced;
  if (keyframe->georeferenced) k.utm_zone = frame.utm_zone;
  // The paper's trigger: the scan-to-map solve ran into its iteration limit. (Degenerate,
  // remapped frames are routine on plain track, and the odometer holds them.)
  k.odometry_suspect = frame.solver_iterations >= config_.options.max_solver_iterations;
  k.points_body = std::move(keyframe->points_body);  // the sinks above are done with it
  k.intensities = std::move(keyframe->intensities);
  submaps_->Add(std::move(k), sent_provisionally);
  stats_.submaps = submaps_->stats();
}

void Estimator::AlignGravity(bool last_chance) {
  size_t states = 0;
  const GravityFit fit = FitGravity(&states);
  const double min_duration = 0.5 * config_.options.gravity_align_s;
  const double g = config_.rig.gravity_mps2;
  bool aligned = false;
  Eigen::Vector3d g_est;
  if (states >= 2 &&
      fit.duration_s() >= (last_chance ? std::min(3.0, min_duration) : min_duration) &&
      fit.Gravity(&g_est)) {
    const Eigen::Quaterniond q_fix =
        Eigen::Quaterniond::FromTwoVectors(g_est.normalized(), Eigen::Vector3d::UnitZ());
    const double angle_rad = Eigen::AngleAxisd(q_fix).angle();
    const double angle_deg = angle_rad * 180.0 / M_PI;
    if (std::abs(g_est.norm() - g) < 0.03 * g && angle_deg < 3.0) {
      // A frame levelled this far off (started at speed, the simulated runs re-level by 1.3-4.5
      // mrad; from rest by 0.3-0.7) had the gyro's roll and pitch biases bent to it: on
      // poor_high_open_a -2.9e-5 rad/s in pitch against a true +2.2e-5, which pitched the body
      // 0.6 mrad within 16 s of the re-levelling. From rest they were learnt standing still,
      // and are kept.
      constexpr double kForgetTiltGyroBiasRad = 1.0e-3;
      RotateWorld(q_fix.toRotationMatrix(), angle_rad > kForgetTiltGyroBiasRad);
      if (sinks_.on_info) {
        std::ostringstream m;
        m.precision(3);
        m << "re-levelled the world frame by " << angle_deg << " deg on gravity from "
          << fit.duration_s() << " s of IMU data (|g| " << g_est.norm() << " m/s^2)";
        sinks_.on_info(m.str());
      }
    } else {
      Warn("gravity from the IMU does not fit the trajectory (|g| " + std::to_string(g_est.norm()) +
           " m/s^2, tilt " + std::to_string(angle_deg) + " deg): frame kept as levelled");
      // Not retried: the data disagree, the initial levelling stands.
    }
    aligned = true;
  }
  if (!aligned && !last_chance) {
    next_gravity_try_s_ += 1.0;
    return;
  }
  gravity_pending_ = false;
  for (auto& e : extras_) e->preintegration.reset();
  while (!held_.empty()) {
    std::unique_ptr<NodeExtras> h = std::move(held_.front());
    held_.pop_front();
    Emit(std::move(h));
  }
}

GravityFit Estimator::FitGravity(size_t* states) const {
  // The states so far in time order: the held-back final ones, then the window's (the two
  // newest are left out: their velocities are the least settled). Over the intervals between
  // them the IMU's velocity increments, rotated into the world and taken with zero
  // accelerometer bias (a bias would have absorbed the tilt), add up to the velocity change
  // plus gravity times the time: c_k = sum_{i <= k} R_i beta_i = v_k - v_0 + g t_k. Gravity
  // is the slope of the line fitted through c_k - v_k against t_k, every state counting, not
  // the difference between the first and the last (GravityFit). Between the two ends, the first
  // state's velocity error straight after the initial levelling (0.04 m/s moving off from rest
  // on long_20km) tilted the frame by 0.35 mrad.
  struct Item {
    NavState state;
    const Preintegration* pre;
  };
  std::vector<Item> items;
  for (const auto& h : held_) items.push_back({h->final_state, h->preintegration.get()});
  for (int i = 0; i < window_->size(); ++i) {
    items.push_back({window_->State(i), extras_[static_cast<size_t>(i)]->preintegration.get()});
  }
  const size_t n = items.size() >= 3 ? items.size() - 2 : 0;
  *states = n;
  const Eigen::Vector3d g_w(0.0, 0.0, config_.rig.gravity_mps2);
  GravityFit fit;
  for (size_t k = 0; k < n; ++k) {
    if (k == 0 || !items[k].pre) {
      fit.Start(items[k].state.v);
      continue;
    }
    NavState start = items[k - 1].state;
    start.ba.setZero();
    const double dt = items[k].pre->sum_dt();
    fit.Add(dt, items[k].pre->Predict(start).v - start.v + g_w * dt, items[k].state.v);
  }
  return fit;
}

void Estimator::RotateWorld(const Eigen::Matrix3d& R, bool forget_tilt_gyro_bias) {
  window_->RotateWorld(R, forget_tilt_gyro_bias);
  // The heading hold was in the old frame: the straight is recognised anew.
  straight_.Reset();
  straight_heading_.reset();
  recent_headings_.clear();
  edge_map_->Rotate(R);
  plane_map_->Rotate(R);
  rail_map_->Rotate(R);
  for (std::vector<Eigen::Vector3d>& frame : bed_history_)
    for (Eigen::Vector3d& p : frame) p = R * p;
  for (auto& h : held_) {
    h->result.T_world_body.linear() = R * h->result.T_world_body.linear();
    h->result.T_world_body.translation() = R * h->result.T_world_body.translation();
    h->result.v_world = R * h->result.v_world;
  }
}

void Estimator::Finish() {
  ProcessReady(true);
  if (gravity_pending_) AlignGravity(true);
  // Flush the window: every remaining state is final now.
  while (window_->size() > 0 && !extras_.empty()) EmitOldest();
  if (gnss_) stats_.gnss = gnss_->stats();
  if (gnss_ && !gnss_gave_up_) {
    gnss_->Finish();
    ReleaseHeld(true);
  }
  if (submaps_) {
    submaps_->Finish();
    stats_.submaps = submaps_->stats();
  }
}

}  // namespace raillomer
