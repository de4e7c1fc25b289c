#include "estimator/sim/livox_model.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace raillomer::sim {

namespace {

constexpr double kDeg = M_PI / 180.0;
constexpr double kHorizontalFovDeg = 81.7;
constexpr double kVerticalFovDeg = 25.1;
constexpr int kLines = 6;
constexpr int kSweepsPerFrame = 10;  // 6 lines x 10 sweeps ~ a 64-line spinning LiDAR
constexpr double kMaxRangeM = 260.0;
constexpr double kGolden = 0.6180339887498949;

Eigen::Matrix3d RotationFromRpyDeg(const std::array<double, 3>& rpy) {
  return (Eigen::AngleAxisd(rpy[2] * kDeg, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(rpy[1] * kDeg, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(rpy[0] * kDeg, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

/// Datasheet ranges (90 m @10 %, 130 m @20 %, 260 m @80 %) follow ~ 90 m * sqrt(rho / 10 %).
double DetectionRange(double reflectivity_pct) {
  return std::min(kMaxRangeM, 90.0 * std::sqrt(std::max(reflectivity_pct, 0.5) / 10.0));
}

}  // namespace

LivoxHorizonModel::LivoxHorizonModel(const Scenario& scenario,
                                     const LidarConfig& config,
                                     uint32_t seed)
    : scenario_(scenario), config_(config), seed_(seed) {
  T_body_lidar_ = Eigen::Isometry3d::Identity();
  T_body_lidar_.linear() = RotationFromRpyDeg(config.rpy_deg);
  T_body_lidar_.translation() =
      Eigen::Vector3d(config.translation_m[0], config.translation_m[1], config.translation_m[2]);
  period_ns_ = static_cast<int64_t>(std::llround(1e9 / scenario.lidar_rate_hz));
  // points_per_frame is validated to be a multiple of kLines * kSweepsPerFrame.
  groups_per_sweep_ = scenario.points_per_frame / (kLines * kSweepsPerFrame);
  const double az = scenario.sun_azimuth_deg * kDeg, el = scenario.sun_elevation_deg * kDeg;
  sun_world_ =
      Eigen::Vector3d(std::cos(el) * std::sin(az), std::cos(el) * std::cos(az), std::sin(el));
  sun_cos_ = std::cos(scenario.sun_cone_deg * kDeg);
  // The roof in front of the sensor head: 0.3 m below the lower unit, ending 1 m ahead.
  body_box_ =
      Eigen::AlignedBox3d(Eigen::Vector3d(0.5, -1.4, -0.5), Eigen::Vector3d(1.0, 1.4, -0.15));
}

uint32_t LivoxHorizonModel::OffsetNs(uint32_t index) const {
  return static_cast<uint32_t>(static_cast<int64_t>(index) * period_ns_ /
                               static_cast<int64_t>(scenario_.points_per_frame));
}

Eigen::Vector3d LivoxHorizonModel::Direction(uint64_t frame, uint32_t index, uint8_t* line) const {
  const uint32_t group = index / kLines;
  const int beam = static_cast<int>(index % kLines);
  const uint32_t sweep = group / groups_per_sweep_;
  const double u = ((group - sweep * groups_per_sweep_) + 0.5) / groups_per_sweep_;
  const double across = (sweep % 2 == 0) ? u : 1.0 - u;  // back and forth
  const double azimuth = (across - 0.5) * kHorizontalFovDeg;
  // Each laser owns a band of the vertical field; the sweeps step through it, shifted by a
  // golden-ratio phase every frame so that successive frames fill each other's gaps.
  const double band = kVerticalFovDeg / kLines;
  const double phase = std::fmod(frame * kGolden + config_.lidar_id * 0.25, 1.0);
  const double step = std::fmod((sweep + phase) / kSweepsPerFrame, 1.0);
  const double wobble = 0.2 * std::sin(2.0 * M_PI * 1.5 * across + 1.1 * beam);
  const double elevation = -0.5 * kVerticalFovDeg + band * (beam + step) + wobble;
  if (line) *line = static_cast<uint8_t>(beam);
  const double a = azimuth * kDeg, e = elevation * kDeg;
  return {std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e)};
}

double LivoxHorizonModel::BodyRange(const Eigen::Vector3d& dir_sensor) const {
  if (!scenario_.vehicle_body) return -1.0;
  // Slab test in the body frame.
  const Eigen::Vector3d o = T_body_lidar_.translation();
  const Eigen::Vector3d d = T_body_lidar_.linear() * dir_sensor;
  double t0 = 0.0, t1 = 1e9;
  for (int k = 0; k < 3; ++k) {
    if (std::fabs(d[k]) < 1e-12) {
      if (o[k] < body_box_.min()[k] || o[k] > body_box_.max()[k]) return -1.0;
      continue;
    }
    double a = (body_box_.min()[k] - o[k]) / d[k];
    double b = (body_box_.max()[k] - o[k]) / d[k];
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
    if (t0 > t1) return -1.0;
  }
  return t0 > 0.0 ? t0 : -1.0;
}

/// The sensor's poses on a 1 ms grid over a frame, interpolated per point.
struct LivoxHorizonModel::SensorTrack {
  std::vector<Eigen::Vector3d> p;
  std::vector<Eigen::Quaterniond> q;

  /// The sensor's origin and rotation at t seconds into the frame.
  void At(double t, Eigen::Vector3d* origin, Eigen::Quaterniond* rotation) const {
    const int knots = static_cast<int>(p.size());
    const double f = t / 1e-3;
    const int k = std::min(static_cast<int>(f), knots - 2);
    const double w = f - k;
    *origin = (1.0 - w) * p[k] + w * p[k + 1];
    *rotation = q[k].slerp(w, q[k + 1]);
  }
};

/// The frame's random draws, one stream: a frame scans the same whatever came before.
struct LivoxHorizonModel::FrameNoise {
  std::mt19937_64 rng;
  std::normal_distribution<double> gauss{0.0, 1.0};
  std::uniform_real_distribution<double> uniform{0.0, 1.0};

  double Gauss() { return gauss(rng); }
  double Uniform() { return uniform(rng); }
};

/// What one beam returns.
struct LivoxHorizonModel::Echo {
  PointKind kind = PointKind::kNoReturn;
  double measured = 0.0;      ///< measured range
  double reflectivity = 0.0;  ///< before clamping to 0-255
  double true_range = 0.0;    ///< of a surface hit, 0 otherwise
};

void LivoxHorizonModel::Scan(uint64_t frame,
                             double t0_s,
                             const std::function<Eigen::Isometry3d(double)>& body_pose,
                             const RayCaster& caster,
                             std::vector<io::LivoxPoint>* points,
                             std::vector<PointKind>* kinds) const {
  const uint32_t n = scenario_.points_per_frame;
  points->assign(n, io::LivoxPoint{});
  if (kinds) kinds->assign(n, PointKind::kNoReturn);
  const SensorTrack track = TrackOverFrame(t0_s, body_pose);
  FrameNoise noise{
      std::mt19937_64(seed_ * 0x9E3779B97F4A7C15ULL + frame * 1315423911ULL + config_.lidar_id)};
  const double angular_sigma = scenario_.angular_noise_deg * kDeg;
  std::vector<double> range(n, 0.0);  // true range of surface hits, 0 otherwise
  for (uint32_t i = 0; i < n; ++i) {
    io::LivoxPoint& out = (*points)[i];
    out.offset_time_ns = OffsetNs(i);
    Eigen::Vector3d dir = Direction(frame, i, &out.line);
    if (angular_sigma > 0.0) {
      dir += angular_sigma * Eigen::Vector3d(0.0, noise.Gauss(), noise.Gauss());
      dir.normalize();
    }
    Echo echo = Measure(dir, out.offset_time_ns * 1e-9, track, caster, &noise);
    range[i] = echo.true_range;
    // Boundary bleeding between this point and the previous one of the same laser and sweep.
    if (echo.kind == PointKind::kSurface && i >= kLines && range[i - kLines] > 0.0 &&
        i / kLines % groups_per_sweep_ != 0) {
      Bleed(range[i - kLines], range[i], &noise, &echo);
    }
    if (kinds) (*kinds)[i] = echo.kind;
    if (echo.kind == PointKind::kNoReturn) continue;
    const Eigen::Vector3f p = (echo.measured * dir).cast<float>();
    out.x = p.x();
    out.y = p.y();
    out.z = p.z();
    out.reflectivity = static_cast<uint8_t>(std::clamp(echo.reflectivity, 0.0, 255.0));
    out.tag = 0x10;  // first return
  }
}

LivoxHorizonModel::SensorTrack LivoxHorizonModel::TrackOverFrame(
    double t0_s, const std::function<Eigen::Isometry3d(double)>& body_pose) const {
  const double period_s = period_ns_ * 1e-9;
  const int knots = static_cast<int>(std::ceil(period_s / 1e-3)) + 1;
  SensorTrack track;
  track.p.resize(knots);
  track.q.resize(knots);
  for (int k = 0; k < knots; ++k) {
    const Eigen::Isometry3d T = body_pose(t0_s + k * 1e-3) * T_body_lidar_;
    track.p[k] = T.translation();
    track.q[k] = Eigen::Quaterniond(T.linear());
  }
  return track;
}

LivoxHorizonModel::Echo LivoxHorizonModel::Measure(const Eigen::Vector3d& dir,
                                                   double t_s,
                                                   const SensorTrack& track,
                                                   const RayCaster& caster,
                                                   FrameNoise* noise) const {
  Echo echo;
  const double body = BodyRange(dir);
  if (body > 0.0) {
    echo.kind = PointKind::kBody;
    echo.measured = body + scenario_.range_noise_m * 2.0 * noise->Gauss();
    echo.reflectivity = MaterialReflectivity(Material::kVehicle) * 1.5;
    return echo;
  }
  Eigen::Vector3d origin;
  Eigen::Quaterniond q;
  track.At(t_s, &origin, &q);
  const Eigen::Vector3d dir_world = q * dir;
  const RayHit hit = caster.Cast(origin, dir_world, kMaxRangeM);
  if (hit.hit && hit.range_m >= scenario_.min_range_m) {
    const double cos_incidence = std::fabs(hit.normal.dot(dir_world));
    const double rho = MaterialReflectivity(hit.material);
    const double effective = rho > 100.0 ? rho : rho * std::sqrt(std::max(cos_incidence, 0.02));
    if (hit.range_m <= DetectionRange(effective)) {
      echo.kind = PointKind::kSurface;
      echo.true_range = hit.range_m;
      // Range noise, larger at short range (axial error).
      const double sigma = scenario_.range_noise_m * (hit.range_m < 2.0 ? 3.0 - hit.range_m : 1.0);
      echo.measured = hit.range_m + sigma * noise->Gauss();
      echo.reflectivity = rho > 100.0 ? 200.0 + 20.0 * noise->Uniform()
                                      : std::min(150.0, effective * 1.5) + 2.0 * noise->Gauss();
      return echo;
    }
  }
  if (dir_world.dot(sun_world_) > sun_cos_ &&
      noise->Uniform() < scenario_.sun_flicker_probability) {
    echo.kind = PointKind::kSunFlicker;
    echo.measured = 2.0 + 48.0 * noise->Uniform();
    echo.reflectivity = 8.0 * noise->Uniform();
  }
  return echo;
}

void LivoxHorizonModel::Bleed(double a, double b, FrameNoise* noise, Echo* echo) const {
  const double lo = std::min(a, b), hi = std::max(a, b);
  if (hi - lo > std::max(0.5, 0.1 * lo) && hi < 80.0 &&
      noise->Uniform() < scenario_.bleeding_probability) {
    echo->kind = PointKind::kBleeding;
    echo->measured = lo + (0.15 + 0.7 * noise->Uniform()) * (hi - lo);
  }
}

}  // namespace raillomer::sim
