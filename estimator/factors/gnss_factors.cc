#include "estimator/factors/gnss_factors.h"

#include <cmath>

namespace raillomer {

double WrapAngle(double a) {
  a = std::fmod(a + M_PI, 2.0 * M_PI);
  if (a <= 0.0) a += 2.0 * M_PI;
  return a - M_PI;
}

GnssPositionFactor::GnssPositionFactor(const Eigen::Vector3d& fix_enu,
                                       const Eigen::Vector3d& antenna_levelled,
                                       double sigma_horizontal_m,
                                       double sigma_vertical_m)
    : z_(fix_enu),
      a_(antenna_levelled),
      w_(1.0 / sigma_horizontal_m, 1.0 / sigma_horizontal_m, 1.0 / sigma_vertical_m) {}

bool GnssPositionFactor::Evaluate(double const* const* parameters,
                                  double* residuals,
                                  double** jacobians) const {
  const double* x = parameters[0];
  const double c = std::cos(x[3]), s = std::sin(x[3]);
  const Eigen::Vector3d Ra(c * a_.x() - s * a_.y(), s * a_.x() + c * a_.y(), a_.z());
  const Eigen::Vector3d r = Eigen::Vector3d(x[0], x[1], x[2]) + Ra - z_;
  Eigen::Map<Eigen::Vector3d> out(residuals);
  out = w_.cwiseProduct(r);
  if (jacobians && jacobians[0]) {
    Eigen::Map<Eigen::Matrix<double, 3, 4, Eigen::RowMajor>> J(jacobians[0]);
    J.setZero();
    J.block<3, 3>(0, 0) = w_.asDiagonal();
    J(0, 3) = w_.x() * (-s * a_.x() - c * a_.y());
    J(1, 3) = w_.y() * (c * a_.x() - s * a_.y());
  }
  return true;
}

FourDofBetweenFactor::FourDofBetweenFactor(const Eigen::Vector3d& dp,
                                           double dyaw,
                                           double path_length_m,
                                           double sigma_horizontal_m,
                                           double sigma_vertical_m,
                                           double sigma_yaw)
    : dp_(dp),
      wp_(1.0 / sigma_horizontal_m, 1.0 / sigma_horizontal_m, 1.0 / sigma_vertical_m),
      dyaw_(dyaw),
      length_(path_length_m),
      wyaw_(1.0 / sigma_yaw) {}

bool FourDofBetweenFactor::Evaluate(double const* const* parameters,
                                    double* residuals,
                                    double** jacobians) const {
  const double* xi = parameters[0];
  const double* xj = parameters[1];
  const double* drift = parameters[2];
  const double c = std::cos(xi[3]), s = std::sin(xi[3]);
  const Eigen::Vector3d d(xj[0] - xi[0], xj[1] - xi[1], xj[2] - xi[2]);
  // R_z(yaw_i)^T d
  const Eigen::Vector3d local(c * d.x() + s * d.y(), -s * d.x() + c * d.y(), d.z());
  // The odometry's displacement with its drift removed: scale * R_z(half_turn) * dp.
  const double scale = std::exp(drift[0]);
  const double half_turn = 0.5 * drift[1] * length_;
  const double ch = std::cos(half_turn), sh = std::sin(half_turn);
  const Eigen::Vector3d turned(ch * dp_.x() - sh * dp_.y(), sh * dp_.x() + ch * dp_.y(), dp_.z());
  const Eigen::Vector3d predicted = scale * turned;
  Eigen::Map<Eigen::Vector4d> r(residuals);
  r.head<3>() = wp_.cwiseProduct(local - predicted);
  r(3) = wyaw_ * WrapAngle(xj[3] - xi[3] - dyaw_ - drift[1] * length_);
  if (jacobians) {
    Eigen::Matrix3d Rt;
    Rt << c, s, 0, -s, c, 0, 0, 0, 1;
    const Eigen::Matrix3d W = wp_.asDiagonal();
    // d(local)/d(yaw_i): derivative of R_z(yaw)^T d.
    const Eigen::Vector3d dlocal_dyaw(-s * d.x() + c * d.y(), -c * d.x() - s * d.y(), 0.0);
    if (jacobians[0]) {
      Eigen::Map<Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> J(jacobians[0]);
      J.setZero();
      J.block<3, 3>(0, 0) = -W * Rt;
      J.block<3, 1>(0, 3) = W * dlocal_dyaw;
      J(3, 3) = -wyaw_;
    }
    if (jacobians[1]) {
      Eigen::Map<Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> J(jacobians[1]);
      J.setZero();
      J.block<3, 3>(0, 0) = W * Rt;
      J(3, 3) = wyaw_;
    }
    if (jacobians[2]) {
      Eigen::Map<Eigen::Matrix<double, 4, 2, Eigen::RowMajor>> J(jacobians[2]);
      J.setZero();
      J.block<3, 1>(0, 0) = -W * predicted;
      // d(turned)/d(half_turn) * d(half_turn)/dk
      const Eigen::Vector3d dturned(-sh * dp_.x() - ch * dp_.y(), ch * dp_.x() - sh * dp_.y(), 0.0);
      J.block<3, 1>(0, 1) = -W * (scale * 0.5 * length_ * dturned);
      J(3, 1) = -wyaw_ * length_;
    }
  }
  return true;
}

}  // namespace raillomer
