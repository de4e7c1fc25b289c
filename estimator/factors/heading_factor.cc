#include "estimator/factors/heading_factor.h"

#include <cmath>

#include <Eigen/Core>

#include "estimator/factors/gnss_factors.h"

namespace raillomer {

double HeadingOf(const Eigen::Matrix3d& R_world_body) {
  return std::atan2(R_world_body(1, 0), R_world_body(0, 0));
}

double HeadingOf(const Eigen::Quaterniond& q_world_body) {
  return HeadingOf(q_world_body.normalized().toRotationMatrix());
}

HeadingHoldFactor::HeadingHoldFactor(double heading_ref_rad, double sigma_rad)
    : heading_ref_(heading_ref_rad), weight_(1.0 / sigma_rad) {}

bool HeadingHoldFactor::Evaluate(double const* const* parameters,
                                 double* residuals,
                                 double** jacobians) const {
  Eigen::Map<const Eigen::Quaterniond> q(parameters[0] + 3);
  const Eigen::Matrix3d R = q.normalized().toRotationMatrix();
  residuals[0] = weight_ * WrapAngle(HeadingOf(R) - heading_ref_);
  if (jacobians && jacobians[0]) {
    // The body x axis a = R e1 moves by R (dtheta x e1) = R(:,1) dtheta_z - R(:,2) dtheta_y
    // under q' = q Exp(dtheta); the heading atan2(a_y, a_x) by (a_x da_y - a_y da_x) / |a_xy|^2.
    Eigen::Map<Eigen::Matrix<double, 1, 7, Eigen::RowMajor>> j(jacobians[0]);
    j.setZero();
    const double ax = R(0, 0), ay = R(1, 0);
    const double h = ax * ax + ay * ay;
    if (h > 1e-12) {
      j(0, 4) = -weight_ * (ax * R(1, 2) - ay * R(0, 2)) / h;
      j(0, 5) = weight_ * (ax * R(1, 1) - ay * R(0, 1)) / h;
    }
  }
  return true;
}

}  // namespace raillomer
