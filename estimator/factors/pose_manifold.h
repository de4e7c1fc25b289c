#pragma once

#include <cmath>

#include <ceres/manifold.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer {

/// Parameter block layouts shared by every factor (all doubles):
///   pose        [7]: p_world_body (x, y, z), q_world_body (x, y, z, w; Eigen's coeffs order)
///   speed_bias  [9]: v_world (3), accelerometer bias (3), gyroscope bias (3)
///   odometer    [3]: odometer scale factor c^O (eq. 9), then the misalignment of the wheels'
///                    path against the odometer's x axis: pitch and yaw (rad, about the
///                    odometer's y and z axes; NavState::m)
inline constexpr int kPoseSize = 7;
inline constexpr int kPoseTangentSize = 6;
inline constexpr int kSpeedBiasSize = 9;
inline constexpr int kOdometerBlockSize = 3;

/// Skew-symmetric matrix [v]x.
inline Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

/// Exp map of SO(3) as a unit quaternion (exact, safe near zero).
inline Eigen::Quaterniond ExpQuaternion(const Eigen::Vector3d& theta) {
  const double angle = theta.norm();
  if (angle < 1e-10) {
    return Eigen::Quaterniond(1.0, 0.5 * theta.x(), 0.5 * theta.y(), 0.5 * theta.z()).normalized();
  }
  const Eigen::Vector3d axis = theta / angle;
  return Eigen::Quaterniond(Eigen::AngleAxisd(angle, axis));
}

/// Log map of a unit quaternion (rotation vector), with the shortest-arc sign.
inline Eigen::Vector3d LogQuaternion(const Eigen::Quaterniond& q_in) {
  Eigen::Quaterniond q = q_in.w() < 0.0 ? Eigen::Quaterniond(-q_in.coeffs()) : q_in;
  const double s = q.vec().norm();
  if (s < 1e-10) return 2.0 * q.vec();
  return 2.0 * std::atan2(s, q.w()) / s * q.vec();
}

/// The pose manifold: p' = p + dp, q' = q * Exp(dtheta) (rotation perturbed in the body frame).
///
/// Jacobian convention (as in VINS-Mono): every cost function taking a pose block returns its
/// Jacobian with respect to the tangent (dp, dtheta) in the first 6 of the 7 ambient columns and
/// zeros in the 7th; PlusJacobian() is therefore [I6; 0]. All our pose factors are analytic.
class PoseManifold : public ceres::Manifold {
 public:
  int AmbientSize() const override { return kPoseSize; }
  int TangentSize() const override { return kPoseTangentSize; }

  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override {
    Eigen::Map<const Eigen::Vector3d> p(x);
    Eigen::Map<const Eigen::Quaterniond> q(x + 3);
    Eigen::Map<const Eigen::Vector3d> dp(delta);
    Eigen::Map<const Eigen::Vector3d> dtheta(delta + 3);
    Eigen::Map<Eigen::Vector3d> p_out(x_plus_delta);
    Eigen::Map<Eigen::Quaterniond> q_out(x_plus_delta + 3);
    p_out = p + dp;
    q_out = (q * ExpQuaternion(dtheta)).normalized();
    return true;
  }

  bool PlusJacobian(const double* /*x*/, double* jacobian) const override {
    Eigen::Map<Eigen::Matrix<double, 7, 6, Eigen::RowMajor>> j(jacobian);
    j.setZero();
    j.topRows<6>().setIdentity();
    return true;
  }

  bool Minus(const double* y, const double* x, double* y_minus_x) const override {
    Eigen::Map<const Eigen::Vector3d> py(y), px(x);
    Eigen::Map<const Eigen::Quaterniond> qy(y + 3), qx(x + 3);
    Eigen::Map<Eigen::Vector3d> dp(y_minus_x), dtheta(y_minus_x + 3);
    dp = py - px;
    dtheta = LogQuaternion(qx.conjugate() * qy);
    return true;
  }

  bool MinusJacobian(const double* /*x*/, double* jacobian) const override {
    Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>> j(jacobian);
    j.setZero();
    j.leftCols<6>().setIdentity();
    return true;
  }
};

/// Right Jacobian of SO(3): Exp(x + d) ~= Exp(x) Exp(Jr(x) d).
inline Eigen::Matrix3d RightJacobian(const Eigen::Vector3d& x) {
  const double angle = x.norm();
  const Eigen::Matrix3d k = Skew(x);
  if (angle < 1e-4) return Eigen::Matrix3d::Identity() - 0.5 * k + k * k / 6.0;
  const double a2 = angle * angle;
  return Eigen::Matrix3d::Identity() - (1.0 - std::cos(angle)) / a2 * k +
         (angle - std::sin(angle)) / (a2 * angle) * k * k;
}

}  // namespace raillomer
