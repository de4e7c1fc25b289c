#include "estimator/factors/imu_odometer_factor.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace raillomer {
namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

using namespace preintegration_index;  // NOLINT: the residual's block offsets

// Lower-right 3x3 block of Qleft(a) * Qright(b) (Hamilton, [w, x, y, z]), where a (x) q equals
// Qleft(a) q and q (x) b equals Qright(b) q.
Matrix3d QleftQrightVec(const Quaterniond& a, const Quaterniond& b) {
  const Matrix3d left = a.w() * Matrix3d::Identity() + Skew(a.vec());
  const Matrix3d right = b.w() * Matrix3d::Identity() - Skew(b.vec());
  return -a.vec() * b.vec().transpose() + left * right;
}

NavState ReadState(const double* pose, const double* speed_bias, const double* odometer) {
  NavState s;
  s.p = Eigen::Map<const Vector3d>(pose);
  s.q = Eigen::Map<const Quaterniond>(pose + 3);
  s.v = Eigen::Map<const Vector3d>(speed_bias);
  s.ba = Eigen::Map<const Vector3d>(speed_bias + 3);
  s.bg = Eigen::Map<const Vector3d>(speed_bias + 6);
  s.c = odometer[0];
  s.m = Eigen::Map<const Eigen::Vector2d>(odometer + 1);
  return s;
}

/// The odometer counts pulses: its noise (quantisation, speed noise, creep) lives in its own
/// units, not in metres. The component of phi along the odometer axis is therefore taken in
/// odometer units, scaled by c_lin / c_i, so that its whitened size does not depend on the
/// scale estimate. In metres the cost of pure odometer noise would fall as c^2, and the solver
/// would shrink a scale the data leave unobserved (constant speed, LiDAR degenerate along the
/// track) a little at every step.
Matrix3d PhiScaling(const Preintegration& pre, double c_i) {
  const Vector3d axis = pre.R_body_odo().col(0);
  return Matrix3d::Identity() + (pre.linearized_c() / c_i - 1.0) * axis * axis.transpose();
}

/// Whitening of the misalignment's walk over the interval; without a walk the misalignment is
/// one constant, held equal to 1 urad.
double MisalignmentWeight(const Preintegration& pre) {
  const double walk = pre.noise().odometer_misalignment_walk;
  return walk > 0.0 ? 1.0 / (walk * std::sqrt(std::max(pre.sum_dt(), 1e-6))) : 1e6;
}

/// What every Jacobian block of the factor shares: the states, the whitened error and the
/// rotations of eq. (18-19) at them.
struct Linearization {
  Linearization(const Preintegration& pre_in,
                const Eigen::Matrix<double, 19, 19>& sqrt_info_in,
                const NavState& i_in,
                const NavState& j_in,
                const Eigen::Matrix<double, 21, 1>& error_in)
      : pre(pre_in), sqrt_info(sqrt_info_in), i(i_in), j(j_in), error(error_in) {}

  // The inputs, held by reference: they outlive the linearisation (Evaluate's locals).
  const Preintegration& pre;
  const Eigen::Matrix<double, 19, 19>& sqrt_info;
  const NavState& i;
  const NavState& j;
  const Eigen::Matrix<double, 21, 1>& error;
  /// sqrt_info with the metre residual's odometer-unit scaling folded in.
  Eigen::Matrix<double, 19, 19> whitening;
  double dt;
  Vector3d g_w;
  Matrix3d Ri_t, R_ij;
  Vector3d dtheta_bg;
  /// The corrected gamma of eq. (18) and the rotation error quaternion e = gamma^-1 qi^-1 qj.
  Quaterniond gamma, qij, e;
};

Linearization Linearize(const Preintegration& pre,
                        const Eigen::Matrix<double, 19, 19>& sqrt_info,
                        const NavState& i,
                        const NavState& j,
                        const Eigen::Matrix<double, 21, 1>& error) {
  Linearization l(pre, sqrt_info, i, j, error);
  // The Jacobians of the metre residual go through the same odometer-unit scaling.
  l.whitening = sqrt_info;
  l.whitening.middleCols<3>(kPhi) = sqrt_info.middleCols<3>(kPhi) * PhiScaling(pre, i.c);
  l.dt = pre.sum_dt();
  l.g_w = Vector3d(0.0, 0.0, pre.gravity_mps2());
  l.Ri_t = i.q.toRotationMatrix().transpose();
  const Matrix3d Rj = j.q.toRotationMatrix();
  l.R_ij = l.Ri_t * Rj;
  const Eigen::Matrix<double, 19, 19>& J = pre.jacobian();
  l.dtheta_bg = J.block<3, 3>(kTheta, kBg) * (i.bg - pre.linearized_bg());
  l.gamma = (pre.gamma() * ExpQuaternion(l.dtheta_bg)).normalized();
  l.qij = i.q.conjugate() * j.q;
  l.e = l.gamma.conjugate() * l.qij;
  return l;
}

/// d r / d pose_i (7 columns, the last, the quaternion's fourth, zero).
void PoseIJacobian(const Linearization& l, double* jacobian) {
  const NavState& i = l.i;
  const NavState& j = l.j;
  const double dt = l.dt;
  Eigen::Matrix<double, 19, 6> d = Eigen::Matrix<double, 19, 6>::Zero();
  d.block<3, 3>(kAlpha, 0) = -l.Ri_t;
  d.block<3, 3>(kAlpha, 3) = Skew(l.Ri_t * (j.p - i.p + 0.5 * l.g_w * dt * dt - i.v * dt));
  d.block<3, 3>(kBeta, 3) = Skew(l.Ri_t * (j.v + l.g_w * dt - i.v));
  d.block<3, 3>(kTheta, 3) = -QleftQrightVec(l.gamma.conjugate(), l.qij);
  d.block<3, 3>(kPhi, 0) = -l.Ri_t;
  d.block<3, 3>(kPhi, 3) = Skew(l.Ri_t * (j.p - i.p)) + l.pre.LeverTermJacobianI(l.R_ij);
  Eigen::Map<Eigen::Matrix<double, 21, 7, Eigen::RowMajor>> out(jacobian);
  out.setZero();
  out.topLeftCorner<19, 6>() = l.whitening * d;
}

/// d r / d [v, ba, bg]_i.
void SpeedBiasIJacobian(const Linearization& l, double* jacobian) {
  const Eigen::Matrix<double, 19, 19>& J = l.pre.jacobian();
  Eigen::Matrix<double, 19, 9> d = Eigen::Matrix<double, 19, 9>::Zero();
  d.block<3, 3>(kAlpha, 0) = -l.Ri_t * l.dt;
  d.block<3, 6>(kAlpha, 3) = -J.block<3, 6>(kAlpha, kBa);
  d.block<3, 3>(kBeta, 0) = -l.Ri_t;
  d.block<3, 6>(kBeta, 3) = -J.block<3, 6>(kBeta, kBa);
  // e = Exp(-Jr J dbg) (x) e to first order: the left perturbation through Qright(e).
  const Matrix3d e_right = l.e.w() * Matrix3d::Identity() - Skew(l.e.vec());
  d.block<3, 3>(kTheta, 6) = -e_right * RightJacobian(l.dtheta_bg) * J.block<3, 3>(kTheta, kBg);
  d.block<3, 3>(kBa, 3) = -Matrix3d::Identity();
  d.block<3, 3>(kBg, 6) = -Matrix3d::Identity();
  d.block<3, 6>(kPhi, 3) = -J.block<3, 6>(kPhi, kBa);
  Eigen::Map<Eigen::Matrix<double, 21, 9, Eigen::RowMajor>> out(jacobian);
  out.setZero();
  out.topRows<19>() = l.whitening * d;
}

/// d r / d [c, m]_i: the odometer scale and misalignment.
void OdometerIJacobian(const Linearization& l, double misalignment_weight, double* jacobian) {
  Eigen::Matrix<double, 19, 1> d = -l.pre.jacobian().col(kC);
  d(kC) = -1.0;
  Eigen::Map<Eigen::Matrix<double, 21, 3, Eigen::RowMajor>> out(jacobian);
  out.setZero();
  // The scaled row also depends on c_i through c_lin / c_i: d/dc_i of (c_lin / c_i) e is
  // -(scaled row) / c_i.
  const Vector3d axis = l.pre.R_body_odo().col(0);
  const Vector3d along = axis * axis.dot(l.error.segment<3>(kPhi));
  out.block<19, 1>(0, 0) = l.whitening * d - l.sqrt_info.middleCols<3>(kPhi) * along / l.i.c;
  // d_phi = ... - phi_misalignment m_i.
  out.block<19, 2>(0, 1) = -l.whitening.middleCols<3>(kPhi) * l.pre.phi_misalignment();
  out.block<2, 2>(ImuOdometerFactor::kMisalignment, 1) =
      -misalignment_weight * Eigen::Matrix2d::Identity();
}

/// d r / d pose_j.
void PoseJJacobian(const Linearization& l, double* jacobian) {
  Eigen::Matrix<double, 19, 6> d = Eigen::Matrix<double, 19, 6>::Zero();
  d.block<3, 3>(kAlpha, 0) = l.Ri_t;
  d.block<3, 3>(kTheta, 3) = l.e.w() * Matrix3d::Identity() + Skew(l.e.vec());
  d.block<3, 3>(kPhi, 0) = l.Ri_t;
  d.block<3, 3>(kPhi, 3) = l.pre.LeverTermJacobianJ(l.R_ij);
  Eigen::Map<Eigen::Matrix<double, 21, 7, Eigen::RowMajor>> out(jacobian);
  out.setZero();
  out.topLeftCorner<19, 6>() = l.whitening * d;
}

/// d r / d [v, ba, bg]_j.
void SpeedBiasJJacobian(const Linearization& l, double* jacobian) {
  Eigen::Matrix<double, 19, 9> d = Eigen::Matrix<double, 19, 9>::Zero();
  d.block<3, 3>(kBeta, 0) = l.Ri_t;
  d.block<3, 3>(kBa, 3).setIdentity();
  d.block<3, 3>(kBg, 6).setIdentity();
  Eigen::Map<Eigen::Matrix<double, 21, 9, Eigen::RowMajor>> out(jacobian);
  out.setZero();
  out.topRows<19>() = l.whitening * d;
}

/// d r / d [c, m]_j.
void OdometerJJacobian(const Linearization& l, double misalignment_weight, double* jacobian) {
  Eigen::Map<Eigen::Matrix<double, 21, 3, Eigen::RowMajor>> out(jacobian);
  out.setZero();
  out.block<19, 1>(0, 0) = l.whitening.col(kC);
  out.block<2, 2>(ImuOdometerFactor::kMisalignment, 1) =
      misalignment_weight * Eigen::Matrix2d::Identity();
}

}  // namespace

ImuOdometerFactor::ImuOdometerFactor(std::shared_ptr<const Preintegration> preintegration)
    : preintegration_(std::move(preintegration)),
      sqrt_information_(preintegration_->SqrtInformation()),
      misalignment_weight_(MisalignmentWeight(*preintegration_)),
      revision_(preintegration_->revision()) {}

Eigen::Matrix<double, 21, 1> ImuOdometerFactor::Residual(const NavState& i,
                                                         const NavState& j) const {
  Eigen::Matrix<double, 21, 1> r;
  r.head<19>() = preintegration_->Evaluate(i, j);
  r.segment<3>(kPhi) = PhiScaling(*preintegration_, i.c) * r.segment<3>(kPhi);
  r.segment<2>(kMisalignment) = j.m - i.m;
  return r;
}

bool ImuOdometerFactor::Evaluate(double const* const* parameters,
                                 double* residuals,
                                 double** jacobians) const {
  const Preintegration& pre = *preintegration_;
  const NavState i = ReadState(parameters[0], parameters[1], parameters[2]);
  const NavState j = ReadState(parameters[3], parameters[4], parameters[5]);
  // The cached whitening, unless the preintegration changed since construction.
  Eigen::Matrix<double, 19, 19> recomputed;
  const Eigen::Matrix<double, 19, 19>* sqrt_info_ptr = &sqrt_information_;
  if (pre.revision() != revision_) {
    recomputed = pre.SqrtInformation();
    sqrt_info_ptr = &recomputed;
  }
  const Eigen::Matrix<double, 19, 19>& sqrt_info = *sqrt_info_ptr;

  // Eq. (19) with the odometer row in odometer units, whitened, and the misalignment's walk.
  const Eigen::Matrix<double, 21, 1> error = Residual(i, j);
  Eigen::Map<Eigen::Matrix<double, 21, 1>> r(residuals);
  r.head<19>() = sqrt_info * error.head<19>();
  r.tail<2>() = misalignment_weight_ * error.tail<2>();
  if (jacobians == nullptr) return true;
  const Linearization l = Linearize(pre, sqrt_info, i, j, error);
  if (jacobians[0] != nullptr) PoseIJacobian(l, jacobians[0]);
  if (jacobians[1] != nullptr) SpeedBiasIJacobian(l, jacobians[1]);
  if (jacobians[2] != nullptr) OdometerIJacobian(l, misalignment_weight_, jacobians[2]);
  if (jacobians[3] != nullptr) PoseJJacobian(l, jacobians[3]);
  if (jacobians[4] != nullptr) SpeedBiasJJacobian(l, jacobians[4]);
  if (jacobians[5] != nullptr) OdometerJJacobian(l, misalignment_weight_, jacobians[5]);
  return true;
}

}  // namespace raillomer
