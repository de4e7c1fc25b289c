#include "estimator/pipeline/inertial_buffer.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Geometry>

namespace raillomer {

void InertialBuffer::AddImu(double t, const Eigen::Vector3d& gyro, const Eigen::Vector3d& accel) {
  ImuRecord r{t, gyro, accel};
  const double tau = sway_time_constant_s;
  if (tau > 0.0 && !imu_.empty() && t > imu_.back().t) {
    // First-order high-pass of an angle, h' = w - h / tau, exact for the step's mean rate w;
    // the pitch goes through it twice (its first stage's rate is the input of the second).
    const ImuRecord& last = imu_.back();
    const double dt = t - last.t;
    const double keep = std::exp(-dt / tau), gain = tau * (1.0 - keep);
    const Eigen::Vector3d rate = 0.5 * (last.gyro + gyro);
    r.sway_roll = keep * last.sway_roll + rate.x() * gain;
    r.pitch_once = keep * last.pitch_once + rate.y() * gain;
    r.sway_pitch = keep * last.sway_pitch + (r.pitch_once - last.pitch_once) / dt * gain;
  } else if (!imu_.empty()) {
    r.sway_roll = imu_.back().sway_roll;
    r.pitch_once = imu_.back().pitch_once;
    r.sway_pitch = imu_.back().sway_pitch;
  }
  imu_.push_back(r);
}

InertialBuffer::Sway InertialBuffer::SwayAt(double t) const {
  if (imu_.empty()) return Sway();
  const ImuRecord r = RecordAt(t);
  return {r.sway_roll, r.sway_pitch};
}

void InertialBuffer::AddOdometer(double t, double distance_m) { odo_.push_back({t, distance_m}); }

double InertialBuffer::OdometerDistanceAt(double t, bool* ok) const {
  *ok = false;
  if (odo_.size() < 2 || t < odo_.front().t || t > odo_.back().t) return 0.0;
  auto it = std::lower_bound(
      odo_.begin(), odo_.end(), t, [](const OdoRecord& r, double value) { return r.t < value; });
  if (it == odo_.begin()) {
    *ok = true;
    return it->distance_m;
  }
  const OdoRecord& b = *it;
  const OdoRecord& a = *(it - 1);
  if (b.t - a.t > max_gap_s) return 0.0;  // an odometer gap: no reading
  *ok = true;
  const double s = (t - a.t) / (b.t - a.t);
  return a.distance_m + s * (b.distance_m - a.distance_m);
}

bool InertialBuffer::UpInBody(double t0,
                              double t1,
                              double gravity_mps2,
                              Eigen::Vector3d* up_body,
                              Eigen::Vector3d* velocity_body) const {
  if (imu_.size() < 5 || t1 - t0 < 0.1 || imu_.front().t > t0 + 0.05 || imu_.back().t < t1 - 0.05)
    return false;
  bool odometer_ok = false;
  // Zero biases: an estimated bias may already hold a tilt; the true ones are far smaller.
  const auto pre = Preintegrate(t0,
                                t1,
                                Eigen::Vector3d::Zero(),
                                Eigen::Vector3d::Zero(),
                                1.0,
                                Eigen::Vector3d::Zero(),
                                PreintegrationNoise(),
                                gravity_mps2,
                                true,
                                &odometer_ok);
  const double T = pre->sum_dt();
  const Eigen::Vector3d g_up(0.0, 0.0, gravity_mps2);
  // Per axis: y(t) = path(t) - alpha(t) = v0 t - w t^2 / 2, with w = g * up (frame at t0).
  Eigen::Matrix2d AtA = Eigen::Matrix2d::Zero();
  Eigen::Matrix<double, 2, 3> Aty = Eigen::Matrix<double, 2, 3>::Zero();
  const int steps = std::max(10, static_cast<int>(std::ceil(T / 0.02)));
  for (int k = 1; k <= steps; ++k) {
    const double t = T * k / steps;
    const Eigen::Isometry3d inertial =
        pre->RelativePoseAt(t, Eigen::Vector3d::Zero(), Eigen::Quaterniond::Identity());
    const Eigen::Vector3d alpha = inertial.translation() + 0.5 * g_up * t * t;
    const Eigen::Vector3d path =
        odometer_ok ? Eigen::Vector3d(pre->RelativePoseAt(t, Eigen::Vector3d::Zero()).translation())
                    : Eigen::Vector3d::Zero();
    const Eigen::Vector2d a(t, -0.5 * t * t);
    AtA += a * a.transpose();
    Aty += a * (path - alpha).transpose();
  }
  const Eigen::Matrix<double, 2, 3> x = AtA.ldlt().solve(Aty);
  const Eigen::Vector3d w = x.row(1).transpose();
  if (!(w.norm() > 0.5 * gravity_mps2 && w.norm() < 1.5 * gravity_mps2)) return false;
  const Eigen::Quaterniond gamma(
      pre->RelativePoseAt(T, Eigen::Vector3d::Zero(), Eigen::Quaterniond::Identity()).linear());
  *up_body = (gamma.conjugate() * w).normalized();
  if (velocity_body) {
    // v(t) = v0 + beta(t) - w t in the frame at t0, beta the rotated specific force integrated.
    const Eigen::Vector3d v0 = x.row(0).transpose();
    *velocity_body = gamma.conjugate() * (v0 + pre->beta() - w * T);
  }
  return true;
}

InertialBuffer::ImuRecord InertialBuffer::RecordAt(double t) const {
  auto it = std::lower_bound(
      imu_.begin(), imu_.end(), t, [](const ImuRecord& r, double value) { return r.t < value; });
  if (it == imu_.end()) return imu_.back();
  if (it == imu_.begin()) return *it;
  const ImuRecord& a = *(it - 1);
  const double s = (t - a.t) / (it->t - a.t);
  ImuRecord r;
  r.t = t;
  r.gyro = (1 - s) * a.gyro + s * it->gyro;
  r.accel = (1 - s) * a.accel + s * it->accel;
  r.sway_roll = (1 - s) * a.sway_roll + s * it->sway_roll;
  r.pitch_once = (1 - s) * a.pitch_once + s * it->pitch_once;
  r.sway_pitch = (1 - s) * a.sway_pitch + s * it->sway_pitch;
  return r;
}

std::shared_ptr<Preintegration> InertialBuffer::Preintegrate(double t0,
                                                             double t1,
                                                             const Eigen::Vector3d& ba,
                                                             const Eigen::Vector3d& bg,
                                                             double c,
                                                             const Eigen::Vector3d& p_body_odometer,
                                                             const PreintegrationNoise& noise,
                                                             double gravity_mps2,
                                                             bool use_odometer,
                                                             bool* odometer_ok) const {
  auto pre = std::make_shared<Preintegration>(
      ba, bg, c, Eigen::Matrix3d::Identity(), p_body_odometer, noise, gravity_mps2);
  *odometer_ok = false;
  if (imu_.empty()) return pre;
  pre->set_sway_roll(SwayAt(t1).roll - SwayAt(t0).roll);
  // IMU samples at t0, every record inside (t0, t1), and t1.
  std::vector<double> times{t0};
  for (const ImuRecord& r : imu_) {
    if (r.t > t0 + 1e-6 && r.t < t1 - 1e-6) times.push_back(r.t);
  }
  times.push_back(t1);
  bool d0_ok = false, d1_ok = false;
  const double d0 = use_odometer ? OdometerDistanceAt(t0, &d0_ok) : 0.0;
  const double d1 = use_odometer ? OdometerDistanceAt(t1, &d1_ok) : 0.0;
  *odometer_ok = use_odometer && d0_ok && d1_ok;

  // The odometer's speed over each step, from the interpolated distances: the steps' distances
  // add up to d1 - d0 exactly.
  std::vector<double> speed(times.size(), 0.0);
  std::vector<char> speed_ok(times.size(), 0);
  if (*odometer_ok) {
    double prev_d = d0;
    for (size_t i = 1; i < times.size(); ++i) {
      bool ok = i + 1 == times.size();
      const double d = ok ? d1 : OdometerDistanceAt(times[i], &ok);
      const double dt = times[i] - times[i - 1];
      if (ok && dt > 0.0) {
        speed[i] = (d - prev_d) / dt;
        speed_ok[i] = 1;
        prev_d = d;
      }
    }
    speed[0] = times.size() > 1 ? speed[1] : 0.0;
    speed_ok[0] = times.size() > 1 ? speed_ok[1] : 0;
  }
  // Each Add() is the sample that ends a step (the first one only starts the interval).
  for (size_t i = 0; i < times.size(); ++i) {
    const double dt = i == 0 ? 0.0 : times[i] - times[i - 1];
    if (i > 0 && dt <= 0.0) continue;
    const ImuRecord r = RecordAt(times[i]);
    pre->Add(dt,
             r.gyro,
             r.accel,
             speed[i],
             *odometer_ok && speed_ok[i],
             Eigen::Vector3d(0.0, r.sway_pitch, 0.0));
  }
  return pre;
}

void InertialBuffer::Trim(double t) {
  while (imu_.size() > 2 && imu_[1].t < t) imu_.pop_front();
  while (odo_.size() > 2 && odo_[1].t < t) odo_.pop_front();
}

}  // namespace raillomer
