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

void LivoxHorizonModel::Scan(uint64_t frame,
                             double t0_s,
                             const std::function<Eigen::Isometry3d(double)>& body_pose,
                             const RayCaster& caster,
                             std::vector<io::LivoxPoint>* points,
                             std::vector<PointKind>* kinds) const {
  const uint32_t n = scenario_.points_per_frame;
  points->assign(n, io::LivoxPoint{});
  if (kinds) kinds->assign(n, PointKind::kNoReturn);

  // Sensor poses on a 1 ms grid over the frame, interpolated per point below.
  const double period_s = period_ns_ * 1e-9;
  const int knots = static_cast<int>(std::ceil(period_s / 1e-3)) + 1;
  std::vector<Eigen::Vector3d> knot_p(knots);
  std::vector<Eigen::Quaterniond> knot_q(knots);
  for (int k = 0; k < knots; ++k) {
    const Eigen::Isometry3d T = body_pose(t0_s + k * 1e-3) * T_body_lidar_;
    knot_p[k] = T.translation();
    knot_q[k] = Eigen::Quaterniond(T.linear());
  }

  std::mt19937_64 rng(seed_ * 0x9E3779B97F4A7C15ULL + frame * 1315423911ULL + config_.lidar_id);
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const double angular_sigma = scenario_.angular_noise_deg * kDeg;
  const double sun_cos = std::cos(scenario_.sun_cone_deg * kDeg);

  std::vector<double> range(n, 0.0);  // true range of surface hits, 0 otherwise
  for (uint32_t i = 0; i < n; ++i) {
    io::LivoxPoint& out = (*points)[i];
    out.offset_time_ns = OffsetNs(i);
    Eigen::Vector3d dir = Direction(frame, i, &out.line);
    if (angular_sigma > 0.0) {
      dir += angular_sigma * Eigen::Vector3d(0.0, gauss(rng), gauss(rng));
      dir.normalize();
    }
    const double body = BodyRange(dir);
    double measured = 0.0;
    double reflectivity = 0.0;
    PointKind kind = PointKind::kNoReturn;
    if (body > 0.0) {
      kind = PointKind::kBody;
      measured = body + scenario_.range_noise_m * 2.0 * gauss(rng);
      reflectivity = MaterialReflectivity(Material::kVehicle) * 1.5;
    } else {
      const double t = out.offset_time_ns * 1e-9;
      const double f = t / 1e-3;
      const int k = std::min(static_cast<int>(f), knots - 2);
      const double w = f - k;
      const Eigen::Vector3d origin = (1.0 - w) * knot_p[k] + w * knot_p[k + 1];
      const Eigen::Quaterniond q = knot_q[k].slerp(w, knot_q[k + 1]);
      const Eigen::Vector3d dir_world = q * dir;
      const RayHit hit = caster.Cast(origin, dir_world, kMaxRangeM);
      bool returned = false;
      if (hit.hit && hit.range_m >= scenario_.min_range_m) {
        const double cos_incidence = std::fabs(hit.normal.dot(dir_world));
        const double rho = MaterialReflectivity(hit.material);
        const double effective = rho > 100.0 ? rho : rho * std::sqrt(std::max(cos_incidence, 0.02));
        if (hit.range_m <= DetectionRange(effective)) {
          returned = true;
          kind = PointKind::kSurface;
          range[i] = hit.range_m;
          // Range noise, larger at short range (axial error).
          const double sigma =
              scenario_.range_noise_m * (hit.range_m < 2.0 ? 3.0 - hit.range_m : 1.0);
          measured = hit.range_m + sigma * gauss(rng);
          reflectivity = rho > 100.0 ? 200.0 + 20.0 * uniform(rng)
                                     : std::min(150.0, effective * 1.5) + 2.0 * gauss(rng);
        }
      }
      if (!returned && dir_world.dot(sun_world_) > sun_cos &&
          uniform(rng) < scenario_.sun_flicker_probability) {
        kind = PointKind::kSunFlicker;
        measured = 2.0 + 48.0 * uniform(rng);
        reflectivity = 8.0 * uniform(rng);
      }
    }
    // Boundary bleeding between this point and the previous one of the same laser and sweep.
    if (kind == PointKind::kSurface && i >= kLines && range[i - kLines] > 0.0 &&
        i / kLines % groups_per_sweep_ != 0) {
      const double a = range[i - kLines], b = range[i];
      const double lo = std::min(a, b), hi = std::max(a, b);
      if (hi - lo > std::max(0.5, 0.1 * lo) && hi < 80.0 &&
          uniform(rng) < scenario_.bleeding_probability) {
        kind = PointKind::kBleeding;
        measured = lo + (0.15 + 0.7 * uniform(rng)) * (hi - lo);
      }
    }
    if (kinds) (*kinds)[i] = kind;
    if (kind == PointKind::kNoReturn) continue;
    const Eigen::Vector3f p = (measured * dir).cast<float>();
    out.x = p.x();
    out.y = p.y();
    out.z = p.z();
    out.reflectivity = static_cast<uint8_t>(std::clamp(reflectivity, 0.0, 255.0));
    out.tag = 0x10;  // first return
  }
}

}  // namespace raillomer::sim
