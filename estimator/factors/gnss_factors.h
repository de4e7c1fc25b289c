#pragma once

#include <ceres/sized_cost_function.h>

#include <Eigen/Core>

namespace raillomer {

/// The GNSS factor (paper eq. 31) on a 4-DoF node [x, y, z, yaw] of the georeferenced pose
/// graph. The node sits at the fix's epoch, so the preintegrated motion between the state and
/// the fix of eq. 31 is zero: r = W (p + R_z(yaw) a - z), with a the antenna lever arm rotated
/// by the body's roll and pitch (from the odometry, which observes them through gravity) and W
/// = diag(1/sigma_h, 1/sigma_h, 1/sigma_v).
class GnssPositionFactor : public ceres::SizedCostFunction<3, 4> {
 public:
  GnssPositionFactor(const Eigen::Vector3d& fix_enu,
                     const Eigen::Vector3d& antenna_levelled,
                     double sigma_horizontal_m,
                     double sigma_vertical_m);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector3d z_, a_, w_;
};

/// Relative motion between two 4-DoF nodes from the odometry, corrected for the odometry's
/// systematic drift over the window: a scale error (wheel wear, calibration) and a heading
/// drift per metre travelled (gyro bias). With the drift block d = [ln s, k] and the path
/// length L between the nodes, the odometry's displacement dp (in i's yaw-only frame) becomes
/// s R_z(k L / 2) dp (a heading error growing along the path turns the chord by half its end
/// value) and its yaw change dyaw + k L:
/// r = [(R_z(yaw_i)^T (p_j - p_i) - s R_z(k L / 2) dp) / [sigma_h, sigma_h, sigma_v];
///      wrap(yaw_j - yaw_i - dyaw - k L) / sigma_yaw].
class FourDofBetweenFactor : public ceres::SizedCostFunction<4, 4, 4, 2> {
 public:
  FourDofBetweenFactor(const Eigen::Vector3d& dp,
                       double dyaw,
                       double path_length_m,
                       double sigma_horizontal_m,
                       double sigma_vertical_m,
                       double sigma_yaw);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector3d dp_, wp_;
  double dyaw_, length_, wyaw_;
};

/// Wraps an angle to (-pi, pi].
double WrapAngle(double a);

}  // namespace raillomer
