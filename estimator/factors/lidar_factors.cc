#include "estimator/factors/lidar_factors.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

namespace raillomer {
namespace {

using RowJacobian1x6 = Eigen::Matrix<double, 1, 6, Eigen::RowMajor>;
using RowJacobian3x6 = Eigen::Matrix<double, 3, 6, Eigen::RowMajor>;
using RowJacobian1x7 = Eigen::Matrix<double, 1, 7, Eigen::RowMajor>;
using RowJacobian3x7 = Eigen::Matrix<double, 3, 7, Eigen::RowMajor>;
using RowJacobian4x7 = Eigen::Matrix<double, 4, 7, Eigen::RowMajor>;
using RowJacobian7x7 = Eigen::Matrix<double, 7, 7, Eigen::RowMajor>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;

/// A pose block [p, q] as the rotation and translation the residuals use.
struct PoseBlock {
  explicit PoseBlock(const double* pose)
      : t(pose),
        rotation(Eigen::Quaterniond(pose[6], pose[3], pose[4], pose[5]).toRotationMatrix()) {}
  Eigen::Vector3d t;
  Eigen::Matrix3d rotation;
};

bool JacobianWanted(double** jacobians) { return jacobians != nullptr && jacobians[0] != nullptr; }

/// Eq. (21) at rotation R and translation t, with its Jacobian on the tangent (dp, dtheta).
double PlaneResidual(const PlaneTerm& m,
                     const Eigen::Matrix3d& rotation,
                     const Eigen::Vector3d& t,
                     RowJacobian1x6* jacobian) {
  if (jacobian) {
    jacobian->leftCols<3>() = m.weight * m.normal.transpose();
    // d(R Exp(dtheta) p)/d(dtheta) = -R [p]x.
    jacobian->rightCols<3>() = -m.weight * m.normal.transpose() * rotation * Skew(m.p_body);
  }
  // The signed distance of the world point to the plane.
  return m.weight * (m.normal.dot(rotation * m.p_body + t) + m.d);
}

/// Eq. (20): the component of (p_world - a) perpendicular to the line (its norm is d_epsilon).
Eigen::Vector3d LineResidual(const LineTerm& m,
                             const Eigen::Matrix3d& rotation,
                             const Eigen::Vector3d& t,
                             RowJacobian3x6* jacobian) {
  if (jacobian) {
    jacobian->leftCols<3>() = m.weight * m.projector;
    jacobian->rightCols<3>() = -m.weight * m.projector * rotation * Skew(m.p_body);
  }
  return m.weight * m.projector * (rotation * m.p_body + t - m.point);
}

}  // namespace

LineTerm::LineTerm(const Eigen::Vector3d& p_body_in,
                   const Eigen::Vector3d& point_world,
                   const Eigen::Vector3d& direction_world,
                   double weight_in)
    : p_body(p_body_in), point(point_world), weight(weight_in) {
  const Eigen::Vector3d u = direction_world.normalized();
  projector = Eigen::Matrix3d::Identity() - u * u.transpose();
}

void LineTerm::Ignore(const Eigen::Vector3d& axis) {
  projector = (Eigen::Matrix3d::Identity() - axis * axis.transpose()) * projector;
}

PointToPlaneFactor::PointToPlaneFactor(const Eigen::Vector3d& p_body,
                                       const Eigen::Vector3d& normal_world,
                                       double d,
                                       double weight)
    : term_{p_body, normal_world, d, weight} {}

bool PointToPlaneFactor::Evaluate(double const* const* parameters,
                                  double* residuals,
                                  double** jacobians) const {
  const PoseBlock pose(parameters[0]);
  const bool jacobian_wanted = JacobianWanted(jacobians);
  RowJacobian1x6 tangent;
  residuals[0] = PlaneResidual(term_, pose.rotation, pose.t, jacobian_wanted ? &tangent : nullptr);
  if (jacobian_wanted) {
    Eigen::Map<RowJacobian1x7> jacobian(jacobians[0]);
    jacobian << tangent, 0.0;
  }
  return true;
}

PointToLineFactor::PointToLineFactor(const Eigen::Vector3d& p_body,
                                     const Eigen::Vector3d& point_world,
                                     const Eigen::Vector3d& direction_world,
                                     double weight)
    : term_(p_body, point_world, direction_world, weight) {}

bool PointToLineFactor::Evaluate(double const* const* parameters,
                                 double* residuals,
                                 double** jacobians) const {
  const PoseBlock pose(parameters[0]);
  const bool jacobian_wanted = JacobianWanted(jacobians);
  RowJacobian3x6 tangent;
  Eigen::Map<Eigen::Vector3d> r(residuals);
  r = LineResidual(term_, pose.rotation, pose.t, jacobian_wanted ? &tangent : nullptr);
  if (jacobian_wanted) {
    Eigen::Map<RowJacobian3x7> jacobian(jacobians[0]);
    jacobian.leftCols<6>() = tangent;
    jacobian.col(6).setZero();
  }
  return true;
}

LidarFrameCost::LidarFrameCost(std::vector<PlaneTerm> planes,
                               std::vector<LineTerm> lines,
                               double huber)
    : planes_(std::move(planes)), lines_(std::move(lines)), huber_(huber) {}

bool LidarFrameCost::Evaluate(double const* const* parameters,
                              double* residuals,
                              double** jacobians) const {
  const bool jacobian_wanted = JacobianWanted(jacobians);
  Matrix6d H = Matrix6d::Zero();
  Vector6d g = Vector6d::Zero();
  const double cost = Accumulate(parameters[0], jacobian_wanted ? &H : nullptr, &g);
  Eigen::Map<Eigen::Matrix<double, 7, 1>> out(residuals);
  out.setZero();
  if (!jacobian_wanted) {
    out(6) = std::sqrt(cost);
    return true;
  }
  // H = V S V^T; rows for the directions the terms observe, none for the rest (g has no part
  // there: it lies in the range of H).
  H.triangularView<Eigen::StrictlyLower>() = H.transpose();
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eigen(H);
  const double floor = 1e-12 * std::max(eigen.eigenvalues().maxCoeff(), 1e-300);
  Eigen::Map<RowJacobian7x7> jacobian(jacobians[0]);
  jacobian.setZero();
  for (int k = 0; k < 6; ++k) {
    const double s = eigen.eigenvalues()(k);
    if (s <= floor) continue;
    const double root = std::sqrt(s);
    jacobian.block<1, 6>(k, 0) = root * eigen.eigenvectors().col(k).transpose();
    out(k) = eigen.eigenvectors().col(k).dot(g) / root;
  }
  out(6) = std::sqrt(std::max(cost - out.head<6>().squaredNorm(), 0.0));
  return true;
}

double LidarFrameCost::Accumulate(const double* pose_parameters,
                                  Eigen::Matrix<double, 6, 6>* H,
                                  Eigen::Matrix<double, 6, 1>* g) const {
  const PoseBlock pose(pose_parameters);
  const bool jacobian_wanted = H != nullptr;
  const double b = huber_ * huber_;
  // ceres::HuberLoss on s = |r|^2: rho = s below b, 2 sqrt(b s) - b above; rho' = min(1,
  // sqrt(b/s)).
  auto robust = [&](double s, double* rho1) {
    if (s <= b) {
      *rho1 = 1.0;
      return s;
    }
    const double root = std::sqrt(s);
    *rho1 = huber_ / root;
    return 2.0 * huber_ * root - b;
  };
  double cost = 0.0;  // sum of rho, twice Ceres' cost
  RowJacobian1x6 j_plane;
  for (const PlaneTerm& m : planes_) {
    const double r = PlaneResidual(m, pose.rotation, pose.t, jacobian_wanted ? &j_plane : nullptr);
    double rho1 = 1.0;
    cost += robust(r * r, &rho1);
    if (!jacobian_wanted) continue;
    H->selfadjointView<Eigen::Upper>().rankUpdate(j_plane.transpose(), rho1);
    *g += (rho1 * r) * j_plane.transpose();
  }
  RowJacobian3x6 j_line;
  for (const LineTerm& m : lines_) {
    const Eigen::Vector3d r =
        LineResidual(m, pose.rotation, pose.t, jacobian_wanted ? &j_line : nullptr);
    double rho1 = 1.0;
    cost += robust(r.squaredNorm(), &rho1);
    if (!jacobian_wanted) continue;
    H->selfadjointView<Eigen::Upper>().rankUpdate(j_line.transpose(), rho1);
    *g += rho1 * j_line.transpose() * r;
  }
  return cost;
}

RailPlaneFactor::RailPlaneFactor(const Eigen::Vector3d& normal_i,
                                 double distance_i,
                                 const Eigen::Vector3d& normal_j,
                                 double distance_j,
                                 double sqrt_weight_normal,
                                 double sqrt_weight_distance)
    : n_i_(normal_i),
      n_j_(normal_j),
      d_i_(distance_i),
      d_j_(distance_j),
      w_n_(sqrt_weight_normal),
      w_d_(sqrt_weight_distance) {}

bool RailPlaneFactor::Evaluate(double const* const* parameters,
                               double* residuals,
                               double** jacobians) const {
  const Eigen::Map<const Eigen::Vector3d> t_i(parameters[0]);
  const Eigen::Map<const Eigen::Quaterniond> q_i(parameters[0] + 3);
  const Eigen::Map<const Eigen::Vector3d> t_j(parameters[1]);
  const Eigen::Map<const Eigen::Quaterniond> q_j(parameters[1] + 3);
  const Eigen::Matrix3d r_i = q_i.toRotationMatrix();
  const Eigen::Matrix3d r_j = q_j.toRotationMatrix();
  // Eq. (29): T_ij = T_i^-1 T_j (the LiDAR-body extrinsic is folded into the plane measurements).
  const Eigen::Matrix3d r_ij = r_i.transpose() * r_j;
  const Eigen::Vector3d t_ij = r_i.transpose() * (t_j - t_i);
  // Eq. (28): n_i . x_i + d_i = 0 with x_i = R_ij x_j + t_ij gives the plane in frame j.
  const Eigen::Vector3d n_pred = r_ij.transpose() * n_i_;
  const double d_pred = d_i_ + n_i_.dot(t_ij);
  // Eq. (30): r = m_j - T m_i (sign flipped; the squared norm is the same).
  Eigen::Map<Eigen::Vector4d> r(residuals);
  r.head<3>() = w_n_ * (n_pred - n_j_);
  r(3) = w_d_ * (d_pred - d_j_);
  if (jacobians == nullptr) return true;
  if (jacobians[0] != nullptr) {
    Eigen::Map<RowJacobian4x7> jacobian(jacobians[0]);
    jacobian.setZero();
    // n' = R_j^T R_i n_i; R_i -> R_i Exp(dtheta_i): dn' = -R_ij^T [n_i]x dtheta_i.
    jacobian.block<3, 3>(0, 3) = -w_n_ * r_ij.transpose() * Skew(n_i_);
    // d' = d_i + n_i^T R_i^T (t_j - t_i).
    jacobian.block<1, 3>(3, 0) = -w_d_ * (r_i * n_i_).transpose();
    jacobian.block<1, 3>(3, 3) = w_d_ * n_i_.transpose() * Skew(t_ij);
  }
  if (jacobians[1] != nullptr) {
    Eigen::Map<RowJacobian4x7> jacobian(jacobians[1]);
    jacobian.setZero();
    // R_j -> R_j Exp(dtheta_j): dn' = [n']x dtheta_j.
    jacobian.block<3, 3>(0, 3) = w_n_ * Skew(n_pred);
    jacobian.block<1, 3>(3, 0) = w_d_ * (r_i * n_i_).transpose();
  }
  return true;
}

LongitudinalShiftFactor::LongitudinalShiftFactor(double dx_m, double sigma_m)
    : dx_(dx_m), sigma_(sigma_m) {}

bool LongitudinalShiftFactor::Evaluate(double const* const* parameters,
                                       double* residuals,
                                       double** jacobians) const {
  const Eigen::Map<const Eigen::Vector3d> t_i(parameters[0]);
  const Eigen::Map<const Eigen::Quaterniond> q_i(parameters[0] + 3);
  const Eigen::Map<const Eigen::Vector3d> t_j(parameters[1]);
  const Eigen::Matrix3d r_i = q_i.toRotationMatrix();
  const Eigen::Vector3d t_ij = r_i.transpose() * (t_j - t_i);
  const double inv_sigma = 1.0 / sigma_;
  // Eq. (27) as a displacement: the forward (x) component of the motion in body frame i.
  residuals[0] = (t_ij.x() - dx_) * inv_sigma;
  if (jacobians == nullptr) return true;
  const Eigen::RowVector3d forward_world = inv_sigma * r_i.col(0).transpose();
  if (jacobians[0] != nullptr) {
    Eigen::Map<RowJacobian1x7> jacobian(jacobians[0]);
    jacobian.leftCols<3>() = -forward_world;
    // e_x^T (I - [dtheta]x) t_ij = e_x^T t_ij + e_x^T [t_ij]x dtheta.
    jacobian.block<1, 3>(0, 3) = inv_sigma * Eigen::RowVector3d::UnitX() * Skew(t_ij);
    jacobian(0, 6) = 0.0;
  }
  if (jacobians[1] != nullptr) {
    Eigen::Map<RowJacobian1x7> jacobian(jacobians[1]);
    jacobian.setZero();
    jacobian.leftCols<3>() = forward_world;
  }
  return true;
}

RemappedPoseCost::RemappedPoseCost(std::shared_ptr<ceres::CostFunction> inner,
                                   const PoseRemapping& remapping)
    : inner_(std::move(inner)), remapping_(remapping) {
  if (remapping_.direction) {
    const Eigen::Vector3d u = remapping_.direction->normalized();
    projector_ -= u * u.transpose();
  }
  if (remapping_.q0) remapping_.q0->normalize();
  set_num_residuals(inner_->num_residuals());
  mutable_parameter_block_sizes()->push_back(7);
}

bool RemappedPoseCost::Evaluate(double const* const* parameters,
                                double* residuals,
                                double** jacobians) const {
  double pose[7];
  std::copy(parameters[0], parameters[0] + 7, pose);
  Eigen::Map<Eigen::Vector3d> p(pose);
  if (remapping_.direction) p = remapping_.p0 + projector_ * (p - remapping_.p0);
  Eigen::Matrix3d rotation_map = Eigen::Matrix3d::Identity();
  // d(remapped body-frame turn) / d(position), through the heading's profile.
  Eigen::Matrix3d position_to_rotation = Eigen::Matrix3d::Zero();
  if (remapping_.q0) {
    const Eigen::Quaterniond q(pose[6], pose[3], pose[4], pose[5]);
    // The rotation since q0 in the world frame, its part about z replaced by the profile's.
    const Eigen::Vector3d delta_in = LogQuaternion(q * remapping_.q0->conjugate());
    Eigen::Vector3d delta = delta_in;
    const Eigen::Vector3d k_p = remapping_.heading_gain.head<3>();
    const Eigen::Vector3d k_r(remapping_.heading_gain(3), remapping_.heading_gain(4), 0.0);
    delta.z() = remapping_.heading_z0 + k_p.dot(p - remapping_.heading_p_ref) +
                k_r.x() * delta.x() + k_r.y() * delta.y();
    const Eigen::Quaterniond q_remapped = (ExpQuaternion(delta) * *remapping_.q0).normalized();
    Eigen::Map<Eigen::Quaterniond>(pose + 3) = q_remapped;
    // A body-frame turn dtheta of q moves delta by Jl^-1(delta) R dtheta; its z part replaced
    // (M = P + e_z k_r^T, P: no z part), delta' turns the remapped pose by R'^T Jl(delta')
    // d delta' in its body frame (Jl: the left Jacobian of SO(3), to first order).
    Eigen::Matrix3d M = Eigen::Matrix3d::Identity();
    M(2, 2) = 0.0;
    M.row(2) = k_r.transpose();
    const Eigen::Matrix3d out = q_remapped.toRotationMatrix().transpose() *
                                (Eigen::Matrix3d::Identity() + 0.5 * Skew(delta));
    rotation_map =
        out * M * (Eigen::Matrix3d::Identity() - 0.5 * Skew(delta_in)) * q.toRotationMatrix();
    position_to_rotation = out.col(2) * k_p.transpose();
  }
  const double* remapped[1] = {pose};
  if (!inner_->Evaluate(remapped, residuals, jacobians)) return false;
  if (jacobians != nullptr && jacobians[0] != nullptr) {
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, 7, Eigen::RowMajor>> J(
        jacobians[0], num_residuals(), 7);
    if (remapping_.q0) {
      J.leftCols<3>() += J.middleCols<3>(3) * position_to_rotation;
      J.middleCols<3>(3) = (J.middleCols<3>(3) * rotation_map).eval();
    }
    if (remapping_.direction) J.leftCols<3>() = (J.leftCols<3>() * projector_).eval();
  }
  return true;
}

}  // namespace raillomer
