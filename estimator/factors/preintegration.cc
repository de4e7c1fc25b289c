#include "estimator/factors/preintegration.h"

#include <algorithm>
#include <cmath>
#include <cstddef>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "estimator/factors/pose_manifold.h"

namespace raillomer {
namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Matrix19d = Eigen::Matrix<double, 19, 19>;

using namespace preintegration_index;  // NOLINT: the residual's block offsets

// White noise offsets of one step: accelerometer, gyroscope, odometer speed. The random walks
// (biases, odometer scale) add to their own diagonal entries.
constexpr int kNa = 0;
constexpr int kNg = 3;
constexpr int kNs = 6;
constexpr int kNl = 7;  // two components: across the odometer axis (y, z)
constexpr int kNoise = 9;

double Square(double x) { return x * x; }

/// The variances of one step's white noise: continuous densities averaged over dt have variance
/// density^2 / dt.
Eigen::Matrix<double, kNoise, 1> StepNoiseVariances(const PreintegrationNoise& noise, double dt) {
  Eigen::Matrix<double, kNoise, 1> q_white;
  const double imu_dt = noise.imu_period_s > 0.0 ? std::min(dt, noise.imu_period_s) : dt;
  q_white.segment<3>(kNa).setConstant(Square(noise.accel_noise_density) / imu_dt);
  q_white.segment<3>(kNg).setConstant(Square(noise.gyro_noise_density) / imu_dt);
  if (noise.imu_period_s > 0.0 && dt > 1.5 * noise.imu_period_s) {
    // White noise of variance q over a step of dt moves the integral by (sqrt(q) dt)^2.
    q_white.segment<3>(kNa).array() += Square(noise.gap_accel_sigma_mps2);
    q_white.segment<3>(kNg).array() += Square(noise.gap_rate_sigma_radps);
  }
  q_white(kNs) = Square(noise.odometer_speed_density) / dt;
  q_white(kNl) = Square(noise.odometer_lateral_density) / dt;
  q_white(kNl + 1) = Square(noise.odometer_vertical_density) / dt;
  return q_white;
}

}  // namespace

/// The error-state transition F and noise input G of one step (eq. 15-17). Only the alpha,
/// beta, theta and phi rows of F differ from the identity: Fr holds them, in that order (rows
/// 0-8 are alpha, beta, theta; rows 9-11 phi). The noise enters those rows through Gr
/// (accelerometer, gyroscope, odometer speed) and the random walks add directly.
struct Preintegration::StepTransition {
  static constexpr int kRowPhi = 9;
  Eigen::Matrix<double, 12, 19> Fr = Eigen::Matrix<double, 12, 19>::Zero();
  Eigen::Matrix<double, 12, kNoise> Gr = Eigen::Matrix<double, 12, kNoise>::Zero();
  Matrix3d R0, R1;  ///< gamma at the step's start and end
  Matrix3d dR;      ///< the step's rotation
  Matrix3d jr_dt;   ///< Jr(w dt) dt
};

Preintegration::Preintegration(const Vector3d& ba,
                               const Vector3d& bg,
                               double c,
                               const Matrix3d& R_body_odo,
                               const Vector3d& p_body_odo,
                               const PreintegrationNoise& noise,
                               double gravity_mps2)
    : ba_(ba),
      bg_(bg),
      c_(c),
      R_body_odo_(R_body_odo),
      p_body_odo_(p_body_odo),
      noise_(noise),
      gravity_mps2_(gravity_mps2) {
  const Vector3d axis = R_body_odo_.col(0), up = R_body_odo_.col(2);
  p_body_odo_level_ = p_body_odo_ - up * up.dot(p_body_odo_);
  along_odo_ = axis * axis.transpose();
  set_sway_roll(0.0);
}

void Preintegration::set_sway_roll(double rad) {
  sway_roll_ = rad;
  const Eigen::AngleAxisd undo(-rad, R_body_odo_.col(0));
  sway_p_body_odo_ = undo * p_body_odo_;
  sway_p_body_odo_level_ = undo * p_body_odo_level_;
}

Vector3d Preintegration::LeverTerm(const Matrix3d& R_ij) const {
  return LeverTerm(R_ij, sway_p_body_odo_, sway_p_body_odo_level_);
}

Vector3d Preintegration::LeverTerm(const Matrix3d& R_ij,
                                   const Vector3d& swayed_p,
                                   const Vector3d& swayed_p_level) const {
  return along_odo_ * (R_ij * swayed_p_level - p_body_odo_level_) +
         (Matrix3d::Identity() - along_odo_) * (R_ij * swayed_p - p_body_odo_);
}

Matrix3d Preintegration::LeverTermJacobianJ(const Matrix3d& R_ij) const {
  return -along_odo_ * R_ij * Skew(sway_p_body_odo_level_) -
         (Matrix3d::Identity() - along_odo_) * R_ij * Skew(sway_p_body_odo_);
}

Matrix3d Preintegration::LeverTermJacobianI(const Matrix3d& R_ij) const {
  return along_odo_ * Skew(R_ij * sway_p_body_odo_level_) +
         (Matrix3d::Identity() - along_odo_) * Skew(R_ij * sway_p_body_odo_);
}

void Preintegration::Add(double dt,
                         const Vector3d& gyro_radps,
                         const Vector3d& accel_mps2,
                         double speed_mps,
                         bool odometer_valid,
                         const Vector3d& sway_rad) {
  ++revision_;
  if (!has_last_) {
    // The very first measurement: the start of the first step.
    has_last_ = true;
    last_gyro_ = gyro_radps;
    last_accel_ = accel_mps2;
    last_speed_ = speed_mps;
    last_odometer_valid_ = odometer_valid;
    last_sway_ = sway_rad;
    if (!odometer_valid) odometer_used_ = false;
    if (dt <= 0.0) return;
  } else if (dt <= 0.0) {
    last_gyro_ = gyro_radps;
    last_accel_ = accel_mps2;
    last_speed_ = speed_mps;
    last_odometer_valid_ = odometer_valid;
    last_sway_ = sway_rad;
    return;
  }
  Step step;
  step.dt = dt;
  step.gyro0 = last_gyro_;
  step.accel0 = last_accel_;
  step.speed0 = last_speed_;
  step.gyro1 = gyro_radps;
  step.accel1 = accel_mps2;
  step.speed1 = speed_mps;
  step.odometer_valid = last_odometer_valid_ && odometer_valid;
  step.sway0 = last_sway_;
  step.sway1 = sway_rad;
  steps_.push_back(step);
  Integrate(step);
  last_gyro_ = gyro_radps;
  last_accel_ = accel_mps2;
  last_speed_ = speed_mps;
  last_odometer_valid_ = odometer_valid;
  last_sway_ = sway_rad;
}

Preintegration::Delta Preintegration::Propagate(const Delta& in, const Step& s, double f) const {
  // Eq. (14) with midpoint values, as in VINS-Mono's integration_base.h; the step ends at the
  // share f of s, its end measurements interpolated.
  const double h = f * s.dt;
  const Vector3d gyro1 = s.gyro0 + f * (s.gyro1 - s.gyro0);
  const Vector3d accel1 = s.accel0 + f * (s.accel1 - s.accel0);
  const Vector3d w = 0.5 * (s.gyro0 + gyro1) - bg_;
  Delta out;
  out.gamma = (in.gamma * ExpQuaternion(w * h)).normalized();
  const Vector3d acc = 0.5 * (in.gamma * (s.accel0 - ba_) + out.gamma * (accel1 - ba_));
  out.alpha = in.alpha + in.beta * h + 0.5 * acc * h * h;
  out.beta = in.beta + acc * h;
  out.phi = in.phi;
  if (s.odometer_valid) {
    // Eq. (13): the odometer velocity c * s along its x axis, rotated into the start body frame;
    // the axis turned back by the body's own sway, so that it runs along the track.
    const double speed1 = s.speed0 + f * (s.speed1 - s.speed0);
    const Vector3d sway1 = s.sway0 + f * (s.sway1 - s.sway0);
    out.phi +=
        0.5 * c_ *
        (in.gamma * (TrackAxis(s.sway0) * s.speed0) + out.gamma * (TrackAxis(sway1) * speed1)) * h;
  }
  return out;
}

Vector3d Preintegration::TrackAxis(const Vector3d& sway) const {
  const Vector3d u = R_body_odo_.col(0);
  return u - sway.cross(u);
}

void Preintegration::Integrate(const Step& s) {
  Delta start;
  start.alpha = alpha_;
  start.beta = beta_;
  start.gamma = gamma_;
  start.phi = phi_;
  step_start_deltas_.push_back(start);
  step_start_times_.push_back(sum_dt_);
  const Delta end = Propagate(start, s, 1.0);
  StepTransition t = InertialTransition(s, start, end);
  if (s.odometer_valid) AddOdometerStep(s, &t);
  PropagateCovariance(t, s.dt);
  alpha_ = end.alpha;
  beta_ = end.beta;
  gamma_ = end.gamma;
  phi_ = end.phi;
  sum_dt_ += s.dt;
  if (!s.odometer_valid) odometer_used_ = false;
}

Preintegration::StepTransition Preintegration::InertialTransition(const Step& s,
                                                                  const Delta& start,
                                                                  const Delta& end) const {
  StepTransition t;
  const double dt = s.dt;
  const Vector3d w = 0.5 * (s.gyro0 + s.gyro1) - bg_;
  t.dR = ExpQuaternion(w * dt).toRotationMatrix();
  t.jr_dt = RightJacobian(w * dt) * dt;
  t.R0 = start.gamma.toRotationMatrix();
  t.R1 = end.gamma.toRotationMatrix();
  const Vector3d a0 = s.accel0 - ba_;
  const Vector3d a1 = s.accel1 - ba_;
  // d_theta1 = dR^T d_theta0 - Jr dt (d_bg + n_g); midpoint acceleration derivatives:
  const Matrix3d R1_a1x = t.R1 * Skew(a1);
  const Matrix3d acc_theta = -0.5 * (t.R0 * Skew(a0) + R1_a1x * t.dR.transpose());
  const Matrix3d acc_bg = 0.5 * R1_a1x * t.jr_dt;
  const Matrix3d acc_ba = -0.5 * (t.R0 + t.R1);
  const double half_dt2 = 0.5 * dt * dt;
  t.Fr.block<9, 9>(0, 0).setIdentity();
  t.Fr.block<3, 3>(StepTransition::kRowPhi, kPhi).setIdentity();
  t.Fr.block<3, 3>(kAlpha, kBeta) = Matrix3d::Identity() * dt;
  t.Fr.block<3, 3>(kAlpha, kTheta) = half_dt2 * acc_theta;
  t.Fr.block<3, 3>(kAlpha, kBa) = half_dt2 * acc_ba;
  t.Fr.block<3, 3>(kAlpha, kBg) = half_dt2 * acc_bg;
  t.Fr.block<3, 3>(kBeta, kTheta) = dt * acc_theta;
  t.Fr.block<3, 3>(kBeta, kBa) = dt * acc_ba;
  t.Fr.block<3, 3>(kBeta, kBg) = dt * acc_bg;
  t.Fr.block<3, 3>(kTheta, kTheta) = t.dR.transpose();
  t.Fr.block<3, 3>(kTheta, kBg) = -t.jr_dt;
  t.Gr.block<3, 3>(kAlpha, kNa) = half_dt2 * acc_ba;
  t.Gr.block<3, 3>(kBeta, kNa) = dt * acc_ba;
  t.Gr.block<3, 3>(kAlpha, kNg) = half_dt2 * acc_bg;
  t.Gr.block<3, 3>(kBeta, kNg) = dt * acc_bg;
  t.Gr.block<3, 3>(kTheta, kNg) = -t.jr_dt;
  return t;
}

void Preintegration::AddOdometerStep(const Step& s, StepTransition* t) {
  constexpr int kRowPhi = StepTransition::kRowPhi;
  const double dt = s.dt;
  const Matrix3d& R0 = t->R0;
  const Matrix3d& R1 = t->R1;
  const Vector3d u = R_body_odo_.col(0);
  const Vector3d u0 = TrackAxis(s.sway0), u1 = TrackAxis(s.sway1);
  const Matrix3d R1_o1x = R1 * Skew(c_ * s.speed1 * u1);
  t->Fr.block<3, 3>(kRowPhi, kTheta) =
      -0.5 * dt * (R0 * Skew(c_ * s.speed0 * u0) + R1_o1x * t->dR.transpose());
  t->Fr.block<3, 3>(kRowPhi, kBg) = 0.5 * dt * R1_o1x * t->jr_dt;
  t->Fr.block<3, 1>(kRowPhi, kC) = 0.5 * dt * (R0 * u0 * s.speed0 + R1 * u1 * s.speed1);
  t->Gr.block<3, 3>(kRowPhi, kNg) = t->Fr.block<3, 3>(kRowPhi, kBg);
  // Eq. (9): c * s_hat = v + eta_s, so the speed noise enters unscaled.
  t->Gr.block<3, 1>(kRowPhi, kNs) = -0.5 * dt * (R0 + R1) * u;
  t->Gr.block<3, 2>(kRowPhi, kNl) = -0.5 * dt * (R0 + R1) * R_body_odo_.rightCols<2>();
  // The axis turned by the misalignment m: d u / d m = [-z_odo, y_odo].
  Eigen::Matrix<double, 3, 2> du_dm;
  du_dm << -R_body_odo_.col(2), R_body_odo_.col(1);
  phi_m_ += 0.5 * dt * c_ * (R0 * s.speed0 + R1 * s.speed1) * du_dm;
}

void Preintegration::PropagateCovariance(const StepTransition& t, double dt) {
  const Eigen::Matrix<double, 12, 19>& Fr = t.Fr;
  const Eigen::Matrix<double, 12, kNoise>& Gr = t.Gr;
  const Eigen::Matrix<double, kNoise, 1> q_white = StepNoiseVariances(noise_, dt);
  // Eq. (17): J = F J, P = F P F^T + G Q G^T, touching only the rows and columns F changes.
  const Eigen::Matrix<double, 12, 19> new_rows = Fr * jacobian_;
  jacobian_.topRows<9>() = new_rows.topRows<9>();
  jacobian_.middleRows<3>(kPhi) = new_rows.bottomRows<3>();
  Matrix19d fp = covariance_;
  const Eigen::Matrix<double, 12, 19> fr_p = Fr * covariance_;
  fp.topRows<9>() = fr_p.topRows<9>();
  fp.middleRows<3>(kPhi) = fr_p.bottomRows<3>();
  const Eigen::Matrix<double, 19, 12> fp_frt = fp * Fr.transpose();
  covariance_ = fp;
  covariance_.leftCols<9>() = fp_frt.leftCols<9>();
  covariance_.middleCols<3>(kPhi) = fp_frt.rightCols<3>();
  const Eigen::Matrix<double, 12, 12> gqg = Gr * q_white.asDiagonal() * Gr.transpose();
  covariance_.topLeftCorner<9, 9>() += gqg.topLeftCorner<9, 9>();
  covariance_.block<9, 3>(0, kPhi) += gqg.topRightCorner<9, 3>();
  covariance_.block<3, 9>(kPhi, 0) += gqg.bottomLeftCorner<3, 9>();
  covariance_.block<3, 3>(kPhi, kPhi) += gqg.bottomRightCorner<3, 3>();
  // A random walk grows by density^2 * dt.
  covariance_.diagonal().segment<3>(kBa).array() += Square(noise_.accel_bias_walk) * dt;
  covariance_.diagonal().segment<3>(kBg).array() += Square(noise_.gyro_bias_walk) * dt;
  covariance_(kC, kC) += Square(noise_.odometer_scale_walk) * dt;
}

void Preintegration::Repropagate(const Vector3d& ba, const Vector3d& bg, double c) {
  ++revision_;
  ba_ = ba;
  bg_ = bg;
  c_ = c;
  sum_dt_ = 0.0;
  alpha_.setZero();
  beta_.setZero();
  gamma_.setIdentity();
  phi_.setZero();
  phi_m_.setZero();
  jacobian_.setIdentity();
  covariance_.setZero();
  step_start_deltas_.clear();
  step_start_times_.clear();
  if (!steps_.empty()) odometer_used_ = true;
  for (const Step& step : steps_) Integrate(step);
}

void Preintegration::Append(const Preintegration& next) {
  steps_.insert(steps_.end(), next.steps_.begin(), next.steps_.end());
  if (next.has_last_) {
    has_last_ = true;
    last_gyro_ = next.last_gyro_;
    last_accel_ = next.last_accel_;
    last_speed_ = next.last_speed_;
    last_odometer_valid_ = next.last_odometer_valid_;
    last_sway_ = next.last_sway_;
  }
  const bool used = odometer_used_ && next.odometer_used_;
  set_sway_roll(sway_roll_ + next.sway_roll_);
  Repropagate(ba_, bg_, c_);
  odometer_used_ = odometer_used_ && used;
}

Preintegration::Delta Preintegration::Corrected(const Vector3d& ba,
                                                const Vector3d& bg,
                                                double c) const {
  // Eq. (18).
  const Vector3d dba = ba - ba_;
  const Vector3d dbg = bg - bg_;
  const double dc = c - c_;
  Delta d;
  d.alpha =
      alpha_ + jacobian_.block<3, 3>(kAlpha, kBa) * dba + jacobian_.block<3, 3>(kAlpha, kBg) * dbg;
  d.beta =
      beta_ + jacobian_.block<3, 3>(kBeta, kBa) * dba + jacobian_.block<3, 3>(kBeta, kBg) * dbg;
  d.gamma = (gamma_ * ExpQuaternion(jacobian_.block<3, 3>(kTheta, kBg) * dbg)).normalized();
  d.phi = phi_ + jacobian_.block<3, 3>(kPhi, kBg) * dbg + jacobian_.block<3, 1>(kPhi, kC) * dc;
  return d;
}

Eigen::Matrix<double, 19, 1> Preintegration::Evaluate(const NavState& i, const NavState& j) const {
  const Delta d = Corrected(i.ba, i.bg, i.c);
  const double dt = sum_dt_;
  const Vector3d g_w(0.0, 0.0, gravity_mps2_);
  const Quaterniond qi_inv = i.q.conjugate();
  Eigen::Matrix<double, 19, 1> r;
  // Eq. (19).
  r.segment<3>(kAlpha) = qi_inv * (j.p - i.p + 0.5 * g_w * dt * dt - i.v * dt) - d.alpha;
  r.segment<3>(kBeta) = qi_inv * (j.v + g_w * dt - i.v) - d.beta;
  r.segment<3>(kTheta) = 2.0 * (d.gamma.conjugate() * (qi_inv * j.q)).vec();
  r.segment<3>(kBa) = j.ba - i.ba;
  r.segment<3>(kBg) = j.bg - i.bg;
  r.segment<3>(kPhi) =
      qi_inv * (j.p - i.p) + LeverTerm((qi_inv * j.q).toRotationMatrix()) - d.phi - phi_m_ * i.m;
  r(kC) = j.c - i.c;
  return r;
}

NavState Preintegration::Predict(const NavState& i) const {
  const Delta d = Corrected(i.ba, i.bg, i.c);
  const double dt = sum_dt_;
  const Vector3d g_w(0.0, 0.0, gravity_mps2_);
  NavState j = i;
  j.p = i.p + i.v * dt - 0.5 * g_w * dt * dt + i.q * d.alpha;
  j.v = i.v - g_w * dt + i.q * d.beta;
  j.q = (i.q * d.gamma).normalized();
  return j;
}

Preintegration::Delta Preintegration::DeltaAt(double t_s) const {
  if (steps_.empty() || t_s <= 0.0) return Delta();
  if (t_s >= sum_dt_) {
    Delta d;
    d.alpha = alpha_;
    d.beta = beta_;
    d.gamma = gamma_;
    d.phi = phi_;
    return d;
  }
  const auto it = std::upper_bound(step_start_times_.begin(), step_start_times_.end(), t_s);
  const size_t k =
      static_cast<size_t>(std::max<std::ptrdiff_t>(it - step_start_times_.begin() - 1, 0));
  const Step& s = steps_[k];
  const double h = t_s - step_start_times_[k];
  if (h <= 0.0) return step_start_deltas_[k];
  return Propagate(step_start_deltas_[k], s, std::min(h / s.dt, 1.0));
}

Eigen::Isometry3d Preintegration::RelativePoseAt(double t_s, const Vector3d& v_start_body) const {
  if (!odometer_used_ || steps_.empty()) {
    return RelativePoseAt(t_s, v_start_body, Quaterniond::Identity());
  }
  const Delta d = DeltaAt(t_s);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = d.gamma.toRotationMatrix();
  // The odometer point moved by phi in the start body frame; the body's sway roll so far is
  // taken as the share of the interval's.
  const double share = sum_dt_ > 0.0 ? std::clamp(t_s / sum_dt_, 0.0, 1.0) : 0.0;
  const Eigen::AngleAxisd undo(-share * sway_roll_, R_body_odo_.col(0));
  T.translation() =
      d.phi - LeverTerm(d.gamma.toRotationMatrix(), undo * p_body_odo_, undo * p_body_odo_level_);
  return T;
}

Eigen::Isometry3d Preintegration::RelativePoseAt(double t_s,
                                                 const Vector3d& v_start_body,
                                                 const Quaterniond& q_world_start) const {
  const double t = std::clamp(t_s, 0.0, sum_dt_);
  const Delta d = DeltaAt(t);
  const Vector3d g_start = q_world_start.conjugate() * Vector3d(0.0, 0.0, gravity_mps2_);
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = d.gamma.toRotationMatrix();
  T.translation() = v_start_body * t + d.alpha - 0.5 * g_start * t * t;
  return T;
}

Eigen::Matrix<double, 19, 19> Preintegration::FactorCovariance() const {
  Matrix19d cov = covariance_;
  if (odometer_used_ && noise_.odometer_resolution_m > 0.0) {
    // Each end of the interval reads the distance to within one pulse: along the odometer axis
    // at the start (u) and at the end (gamma u), in the start body frame.
    const Vector3d u0 = R_body_odo_.col(0);
    const Vector3d u1 = gamma_ * u0;
    const double var = Square(noise_.odometer_resolution_m) / 12.0;
    cov.block<3, 3>(kPhi, kPhi) += var * (u0 * u0.transpose() + u1 * u1.transpose());
  }
  return cov;
}

Eigen::Matrix<double, 19, 19> Preintegration::SqrtInformation() const {
  // Information of the rows that carry any: without odometer data phi is left out entirely.
  const int n = odometer_used_ ? 19 : 16;
  Eigen::VectorXi index(n);
  for (int k = 0, m = 0; k < 19; ++k) {
    if (odometer_used_ || k < kPhi || k >= kPhi + 3) index(m++) = k;
  }
  const Matrix19d full = FactorCovariance();
  Eigen::MatrixXd cov(n, n);
  for (int a = 0; a < n; ++a) {
    for (int b = 0; b < n; ++b)
      cov(a, b) = 0.5 * (full(index(a), index(b)) + full(index(b), index(a)));
  }
  // Invert through the correlation matrix so that the very different scales (alpha over a few
  // milliseconds against phi over a second) do not cost precision; variances below a floor of
  // (1e-8)^2 and near-singular directions are clamped rather than producing infinities.
  constexpr double kVarianceFloor = 1e-16;
  constexpr double kMinEigenvalue = 1e-12;
  Eigen::VectorXd scale(n);
  for (int a = 0; a < n; ++a) scale(a) = std::sqrt(std::max(cov(a, a), kVarianceFloor));
  const Eigen::MatrixXd corr =
      scale.cwiseInverse().asDiagonal() * cov * scale.cwiseInverse().asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(corr);
  const Eigen::VectorXd inv_values = eig.eigenvalues().cwiseMax(kMinEigenvalue).cwiseInverse();
  Eigen::MatrixXd info = scale.cwiseInverse().asDiagonal() * eig.eigenvectors() *
                         inv_values.asDiagonal() * eig.eigenvectors().transpose() *
                         scale.cwiseInverse().asDiagonal();
  info = 0.5 * (info + info.transpose()).eval();
  const Eigen::MatrixXd upper = Eigen::LLT<Eigen::MatrixXd>(info).matrixU();

  Eigen::Matrix<double, 19, 19> L = Eigen::Matrix<double, 19, 19>::Zero();
  for (int a = 0; a < n; ++a) {
    for (int b = 0; b < n; ++b) L(index(a), index(b)) = upper(a, b);
  }
  return L;
}

}  // namespace raillomer
