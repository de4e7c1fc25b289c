#include "estimator/sim/motion.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace raillomer::sim {

SpeedProfile::SpeedProfile(const Scenario& scenario) {
  double t = 0.0, x = 0.0, v = scenario.start_speed_mps;
  for (const MotionPhase& p : scenario.phases) {
    double dt = 0.0, a = 0.0;
    if (p.kind == MotionPhase::Kind::kForSeconds) {
      dt = p.value;
    } else if (p.kind == MotionPhase::Kind::kForMetres) {
      dt = std::fabs(v) > 1e-9 ? p.value / std::fabs(v) : 0.0;
    } else {
      dt = std::fabs(p.value - v) / p.accel_mps2;
      a = p.value > v ? p.accel_mps2 : -p.accel_mps2;
    }
    if (dt <= 0.0) continue;
    pieces_.push_back({t, x, v, a});
    x += v * dt + 0.5 * a * dt * dt;
    v += a * dt;
    t += dt;
  }
  pieces_.push_back({t, x, v, 0.0});
  duration_s_ = t;
}

void SpeedProfile::At(double t, double* distance_m, double* speed_mps, double* accel_mps2) const {
  auto it = std::upper_bound(
      pieces_.begin(), pieces_.end(), t, [](double value, const Piece& p) { return value < p.t0; });
  const Piece& p = it == pieces_.begin() ? pieces_.front() : *(it - 1);
  // Before t = 0 the first piece extends backwards (the IMU differentiates across t = 0); the
  // final piece holds the last speed at zero acceleration.
  const double dt = t - p.t0;
  *distance_m = p.x0 + p.v0 * dt + 0.5 * p.a * dt * dt;
  *speed_mps = p.v0 + p.a * dt;
  *accel_mps2 = p.a;
}

void SpeedProfile::DistanceRange(double* min_m, double* max_m) const {
  *min_m = *max_m = 0.0;
  for (size_t i = 0; i + 1 < pieces_.size(); ++i) {
    const Piece& p = pieces_[i];
    const double dt = pieces_[i + 1].t0 - p.t0;
    double x_end = pieces_[i + 1].x0;
    // A speed reversal inside the piece: the extreme is where the speed passes through zero.
    const double t_turn = p.a != 0.0 ? -p.v0 / p.a : -1.0;
    if (t_turn > 0.0 && t_turn < dt) {
      const double x_turn = p.x0 + p.v0 * t_turn + 0.5 * p.a * t_turn * t_turn;
      *min_m = std::min(*min_m, x_turn);
      *max_m = std::max(*max_m, x_turn);
    }
    *min_m = std::min(*min_m, x_end);
    *max_m = std::max(*max_m, x_end);
  }
}

TruthMotion::TruthMotion(const Scenario& scenario, const Alignment& alignment, uint32_t seed)
    : alignment_(alignment),
      profile_(scenario),
      start_m_(scenario.start_m),
      body_height_m_(scenario.body_height_m),
      vibration_scale_(scenario.vibration_scale),
      body_pitch_rad_(scenario.body_pitch_rad),
      body_yaw_rad_(scenario.body_yaw_rad) {
  std::mt19937 rng(seed * 7919u + 17u);
  std::uniform_real_distribution<double> phase(0.0, 2.0 * M_PI);
  for (int i = 0; i < 8; ++i) phases_.push_back(phase(rng));

  if (scenario.rail_joint_spacing_m > 0.0) {
    // Record every passage over a joint (either direction) by stepping the profile.
    const double spacing = scenario.rail_joint_spacing_m;
    const double step = 0.002;
    double last = std::floor(Chainage(0.0) / spacing);
    for (double t = step; t <= profile_.duration_s(); t += step) {
      const double cell = std::floor(Chainage(t) / spacing);
      if (cell != last) {
        joint_times_.push_back(t);
        joint_gain_.push_back(std::min(1.0, std::fabs(Speed(t)) / 15.0));
        last = cell;
      }
    }
  }
}

double TruthMotion::Chainage(double t) const {
  double x, v, a;
  profile_.At(t, &x, &v, &a);
  return start_m_ + x;
}

double TruthMotion::Speed(double t) const {
  double x, v, a;
  profile_.At(t, &x, &v, &a);
  return v;
}

void TruthMotion::Vibration(double t,
                            double speed,
                            Eigen::Vector3d* offset,
                            Eigen::Vector3d* rpy) const {
  // Car-body modes: amplitudes grow with speed up to 20 m/s.
  const double g = vibration_scale_ * std::min(1.0, std::fabs(speed) / 20.0);
  const double w = 2.0 * M_PI;
  offset->x() = 0.0;
  offset->y() = g * 0.003 * std::sin(w * 0.9 * t + phases_[0]);
  offset->z() = g * (0.004 * std::sin(w * 1.1 * t + phases_[1]) +
                     0.0015 * std::sin(w * 2.7 * t + phases_[2]) +
                     0.0001 * std::sin(w * 11.0 * t + phases_[3]));
  rpy->x() = g * (0.0015 * std::sin(w * 0.8 * t + phases_[4]) +
                  0.0005 * std::sin(w * 1.9 * t + phases_[5]));
  rpy->y() = body_pitch_rad_ + g * 0.0010 * std::sin(w * 1.3 * t + phases_[6]);
  rpy->z() = body_yaw_rad_ + g * 0.0003 * std::sin(w * 0.7 * t + phases_[7]);

  // Rail-joint impulses: a damped 6 Hz oscillation after each passage.
  if (joint_times_.empty()) return;
  const double omega = w * 6.0, zeta = 0.25;
  const double omega_d = omega * std::sqrt(1.0 - zeta * zeta);
  auto end = std::upper_bound(joint_times_.begin(), joint_times_.end(), t);
  for (auto it = end; it != joint_times_.begin();) {
    --it;
    const double tau = t - *it;
    if (tau > 1.5) break;
    const double k = joint_gain_[static_cast<size_t>(it - joint_times_.begin())] * vibration_scale_;
    // A dip that starts with zero velocity (the suspension filters the wheel's impact) and
    // rings out at 6 Hz: vertical acceleration up to ~2.6 m/s^2 at 15 m/s and above.
    const double response = -std::exp(-zeta * omega * tau) * (1.0 - std::cos(omega_d * tau));
    offset->z() += k * 0.0018 * response;
    rpy->y() += k * 0.0012 * response;
    rpy->x() += k * 0.0006 * response;
  }
}

Eigen::Isometry3d TruthMotion::Pose(double t) const {
  double x, v, a;
  profile_.At(t, &x, &v, &a);
  const TrackPoint track = alignment_.At(start_m_ + x);
  Eigen::Vector3d offset, rpy;
  Vibration(t, v, &offset, &rpy);
  const Eigen::Matrix3d R_track = track.Rotation();
  const Eigen::Matrix3d R_vib = (Eigen::AngleAxisd(rpy.z(), Eigen::Vector3d::UnitZ()) *
                                 Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(rpy.x(), Eigen::Vector3d::UnitX()))
                                    .toRotationMatrix();
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = R_track * R_vib;
  pose.translation() =
      track.position + R_track * (offset + Eigen::Vector3d(0.0, 0.0, body_height_m_));
  return pose;
}

void TruthMotion::Inertial(double t,
                           double gravity_mps2,
                           Eigen::Vector3d* omega_body,
                           Eigen::Vector3d* specific_force_body,
                           double window_s) const {
  const double half = 0.5 * window_s, h = 1e-5;
  const Eigen::Isometry3d before = Pose(t - half), now = Pose(t), after = Pose(t + half);
  auto velocity = [this, h](double at) {
    return Eigen::Vector3d((Pose(at + h).translation() - Pose(at - h).translation()) / (2.0 * h));
  };
  const Eigen::Vector3d accel_world = (velocity(t + half) - velocity(t - half)) / window_s;
  const Eigen::AngleAxisd delta(before.linear().transpose() * after.linear());
  *omega_body = delta.axis() * delta.angle() / window_s;
  const Eigen::Vector3d g_world(0.0, 0.0, -gravity_mps2);
  *specific_force_body = now.linear().transpose() * (accel_world - g_world);
}
}  // namespace raillomer::sim
