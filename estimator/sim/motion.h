#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/sim/alignment.h"
#include "estimator/sim/scenario.h"

namespace raillomer::sim {

/// Speed profile from the scenario's phases: piecewise constant acceleration.
class SpeedProfile {
 public:
  explicit SpeedProfile(const Scenario& scenario);
  double duration_s() const { return duration_s_; }
  /// Distance travelled since t = 0 (signed), speed and acceleration along the track.
  void At(double t, double* distance_m, double* speed_mps, double* accel_mps2) const;
  /// The least and greatest distance reached (from the start, signed) over the profile.
  void DistanceRange(double* min_m, double* max_m) const;

 private:
  struct Piece {
    double t0, x0, v0, a;
  };
  std::vector<Piece> pieces_;
  double duration_s_ = 0.0;
};

/// The true motion of the body (IMU) frame in the world frame, with vibration and rail-joint
/// impulses, and the inertial quantities an IMU senses.
class TruthMotion {
 public:
  TruthMotion(const Scenario& scenario, const Alignment& alignment, uint32_t seed);

  double duration_s() const { return profile_.duration_s(); }
  /// Chainage of the body at time t (seconds since the run start).
  double Chainage(double t) const;
  /// Speed along the track at time t (negative when running in reverse).
  double Speed(double t) const;
  /// T_world_body at time t.
  Eigen::Isometry3d Pose(double t) const;
  /// Angular velocity and specific force (a - g) in the body frame, averaged over the IMU's
  /// sample window centred on t (what an IMU's increments measure): the rotation and velocity
  /// change over the window, so kinks of the track (cant and grade ramps) are not lost.
  void Inertial(double t,
                double gravity_mps2,
                Eigen::Vector3d* omega_body,
                Eigen::Vector3d* specific_force_body,
                double window_s = 0.005) const;

 private:
  /// Vibration offset (track frame) and small rotation (roll, pitch, yaw) at time t, the
  /// rotation with the body's standing pitch and yaw.
  void Vibration(double t, double speed, Eigen::Vector3d* offset, Eigen::Vector3d* rpy) const;

  const Alignment& alignment_;
  SpeedProfile profile_;
  double start_m_;
  double body_height_m_;
  double vibration_scale_;
  double body_pitch_rad_, body_yaw_rad_;
  std::vector<double> phases_;       ///< random phases of the vibration modes
  std::vector<double> joint_times_;  ///< when the body passes a rail joint
  std::vector<double> joint_gain_;   ///< impulse amplitude per passage (speed dependent)
};

}  // namespace raillomer::sim
