#pragma once

#include <deque>
#include <memory>

#include <Eigen/Core>

#include "estimator/factors/preintegration.h"

namespace raillomer {

/// The recent IMU samples and wheel-odometer distances, and their preintegration between two
/// times: the link between consecutive states of the sliding window.
class InertialBuffer {
 public:
  struct ImuRecord {
    double t;
    Eigen::Vector3d gyro, accel;
    /// rad, see SwayAt; pitch_once is the pitch's first high-pass stage.
    double sway_roll = 0.0, pitch_once = 0.0, sway_pitch = 0.0;
  };
  struct OdoRecord {
    double t;
    double distance_m;
  };

  /// Samples must come in increasing time; the caller filters rewinds.
  void AddImu(double t, const Eigen::Vector3d& gyro, const Eigen::Vector3d& accel);
  void AddOdometer(double t, double distance_m);

  const std::deque<ImuRecord>& imu() const { return imu_; }
  bool HasOdometer() const { return !odo_.empty(); }
  double FirstOdometerTime() const { return odo_.front().t; }

  /// Distance rolled by the wheel at time t, interpolated; ok false outside the buffer or
  /// inside a gap of more than `max_gap_s` between readings.
  double OdometerDistanceAt(double t, bool* ok) const;

  /// The up direction (unit, opposite to gravity) in the body frame at t1, from the IMU and
  /// odometer over [t0, t1]. In the body frame at t0, the wheel's path (odometer distances
  /// along the gyro-rotated body x axis) equals v0 t + (double integral of the rotated specific
  /// force) - g t^2 / 2 at every t; a least-squares fit of v0 and g per axis gives the tilt.
  /// Fitting positions, not end velocities, keeps the car body's sway (a few mm, but +-2 cm/s)
  /// and the pulse quantisation out of the tilt. Without odometer data the train is taken to
  /// stand still. False without enough IMU data. velocity_body (if given) gets the fitted
  /// velocity at t1 in the body frame at t1: a fit over the whole span, far less disturbed by
  /// the pulse quantisation and the creep than the odometer's speed over a fraction of a second.
  bool UpInBody(double t0,
                double t1,
                double gravity_mps2,
                Eigen::Vector3d* up_body,
                Eigen::Vector3d* velocity_body = nullptr) const;

  /// Preintegration over [t0, t1] linearised at the given biases and odometer scale. IMU
  /// samples are interpolated at t0 and t1 and held across the ends of the buffer. With
  /// use_odometer the odometer enters when it covers the whole interval (*odometer_ok says so).
  std::shared_ptr<Preintegration> Preintegrate(double t0,
                                               double t1,
                                               const Eigen::Vector3d& ba,
                                               const Eigen::Vector3d& bg,
                                               double c,
                                               const Eigen::Vector3d& p_body_odometer,
                                               const PreintegrationNoise& noise,
                                               double gravity_mps2,
                                               bool use_odometer,
                                               bool* odometer_ok) const;

  /// The car body's rotation on its suspension, about its own origin (rad): the gyro's angles
  /// high-passed with sway_time_constant_s, so that the track's slow turns (a cant transition's
  /// roll, a change of grade) and a steady gyro bias stay out of it.
  struct Sway {
    /// High-passed once: only its change over an interval is used, and a steady roll rate (a
    /// cant transition, a bias) leaves that change at zero.
    double roll = 0.0;
    /// High-passed twice: it is used as an angle, and a steady pitch rate (a vertical curve, a
    /// bias) would hold a once-high-passed angle at rate * tau.
    double pitch = 0.0;
  };
  /// Interpolated at t; held across the ends of the buffer; zero without a time constant.
  Sway SwayAt(double t) const;

  /// Drops what lies entirely before t (keeping one record before it for interpolation).
  void Trim(double t);

  double max_gap_s = 0.25;  ///< odometer readings farther apart than this are a gap
  /// s: time constant of the sway's high-passes (0: no sway; the odometer's lever arm then swings
  /// with the body's whole roll, and the wheels run along the body's x axis). Set before the
  /// first sample.
  double sway_time_constant_s = 0.0;

 private:
  /// The record at t, every field interpolated linearly; held across the ends of the buffer,
  /// which must not be empty.
  ImuRecord RecordAt(double t) const;

  std::deque<ImuRecord> imu_;
  std::deque<OdoRecord> odo_;
};

}  // namespace raillomer
