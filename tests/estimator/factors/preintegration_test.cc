#include "estimator/factors/preintegration.h"

#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include "estimator/factors/pose_manifold.h"

namespace raillomer {
namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Jet = ceres::Jet<double, 1>;

constexpr double kGravity = 9.81;
constexpr double kImuDt = 0.005;  // 200 Hz

template <typename T>
using Vec3 = Eigen::Matrix<T, 3, 1>;
template <typename T>
using Mat3 = Eigen::Matrix<T, 3, 3>;

/// a0 + a1 t + sum amp sin(omega t + phase), with its analytic rate.
struct Profile {
  double a0, a1;
  std::vector<std::array<double, 3>> terms;  // amp, omega, phase

  template <typename T>
  T Value(const T& t) const {
    using std::sin;
    T v = T(a0) + T(a1) * t;
    for (const auto& s : terms) v += T(s[0]) * sin(T(s[1]) * t + T(s[2]));
    return v;
  }
  template <typename T>
  T Rate(const T& t) const {
    using std::cos;
    T v = T(a1);
    for (const auto& s : terms) v += T(s[0] * s[1]) * cos(T(s[1]) * t + T(s[2]));
    return v;
  }
};

/// An analytic train-like trajectory. The odometer point moves along its own x axis (the
/// odometer frame's yaw/pitch/roll are smooth sinusoids, its speed is a sinusoid about 30 m/s or
/// -25 m/s), so the odometer model holds exactly; the body (IMU) frame is offset by a rotation and
/// a lever arm. IMU samples come from analytic derivatives (Jets), positions from Gauss-Legendre
/// quadrature of the velocity.
class TrainTrajectory {
 public:
  explicit TrainTrajectory(bool reverse)
      : speed_{reverse ? -25.0 : 30.0, 0.0, {{reverse ? -2.0 : 3.0, 0.7, 0.3}}},
        yaw_{0.4, 0.03, {{0.05, 1.3, 0.4}, {0.004, 9.0, 0.1}}},
        pitch_{0.005, 0.0, {{0.01, 0.8, 0.0}, {0.002, 11.0, 1.0}}},
        roll_{0.0, 0.0, {{0.05, 0.6, 0.2}, {0.003, 7.0, 0.5}}} {
    R_body_odo_ =
        (Eigen::AngleAxisd(0.03, Vector3d::UnitZ()) * Eigen::AngleAxisd(-0.02, Vector3d::UnitY()) *
         Eigen::AngleAxisd(0.01, Vector3d::UnitX()))
            .toRotationMatrix();
    // Level in the odometer frame: a rigid arm's height would move the odometer point along
    // the track as the body pitches, which the along-track row deliberately leaves out (see
    // OdometerPointUnderATallBody).
    p_body_odo_ = R_body_odo_ * Vector3d(1.6, -0.4, 0.0);
    ba_ = Vector3d(0.03, -0.02, 0.05);
    bg_ = Vector3d(0.002, -0.001, 0.0015);
    c_ = 1.03;
  }

  const Matrix3d& R_body_odo() const { return R_body_odo_; }
  const Vector3d& p_body_odo() const { return p_body_odo_; }
  const Vector3d& ba() const { return ba_; }
  const Vector3d& bg() const { return bg_; }
  double c() const { return c_; }

  /// Rotation world <- odometer frame (Z-Y-X Euler angles).
  template <typename T>
  Mat3<T> RotationWorldOdo(const T& t) const {
    using std::cos;
    using std::sin;
    const T y = yaw_.Value(t), p = pitch_.Value(t), r = roll_.Value(t);
    Mat3<T> Rz, Ry, Rx;
    Rz << cos(y), -sin(y), T(0), sin(y), cos(y), T(0), T(0), T(0), T(1);
    Ry << cos(p), T(0), sin(p), T(0), T(1), T(0), -sin(p), T(0), cos(p);
    Rx << T(1), T(0), T(0), T(0), cos(r), -sin(r), T(0), sin(r), cos(r);
    return Rz * Ry * Rx;
  }
  /// Angular velocity of the odometer frame in that frame (Z-Y-X Euler rates).
  template <typename T>
  Vec3<T> OmegaOdo(const T& t) const {
    using std::cos;
    using std::sin;
    const T p = pitch_.Value(t), r = roll_.Value(t);
    const T dy = yaw_.Rate(t), dp = pitch_.Rate(t), dr = roll_.Rate(t);
    return Vec3<T>(
        dr - sin(p) * dy, cos(r) * dp + sin(r) * cos(p) * dy, -sin(r) * dp + cos(r) * cos(p) * dy);
  }
  template <typename T>
  Mat3<T> RotationWorldBody(const T& t) const {
    return RotationWorldOdo(t) * R_body_odo_.transpose().cast<T>();
  }
  template <typename T>
  Vec3<T> OmegaBody(const T& t) const {
    return R_body_odo_.cast<T>() * OmegaOdo(t);
  }
  template <typename T>
  Vec3<T> VelocityOdo(const T& t) const {
    return speed_.Value(t) * RotationWorldOdo(t).col(0);
  }
  template <typename T>
  Vec3<T> VelocityBody(const T& t) const {
    const Vec3<T> w = OmegaBody(t);
    return VelocityOdo(t) - RotationWorldBody(t) * w.cross(p_body_odo_.cast<T>());
  }

  /// p_world_odo(t) with p_world_odo(0) = 0: 5-point Gauss-Legendre on 2.5 ms pieces.
  Vector3d PositionOdo(double t) const {
    static const double kX[5] = {
        0.0, -0.5384693101056831, 0.5384693101056831, -0.9061798459386640, 0.9061798459386640};
    static const double kW[5] = {0.5688888888888889,
                                 0.4786286704993665,
                                 0.4786286704993665,
                                 0.2369268850561891,
                                 0.2369268850561891};
    const int n = std::max(1, static_cast<int>(std::ceil(std::abs(t) / 0.0025)));
    const double h = t / n;
    Vector3d p = Vector3d::Zero();
    for (int k = 0; k < n; ++k) {
      const double mid = (k + 0.5) * h;
      for (int m = 0; m < 5; ++m) p += 0.5 * h * kW[m] * VelocityOdo(mid + 0.5 * h * kX[m]);
    }
    return p;
  }

  NavState State(double t) const {
    NavState s;
    const Matrix3d R = RotationWorldBody(t);
    s.q = Quaterniond(R);
    s.p = PositionOdo(t) - R * p_body_odo_;
    s.v = VelocityBody(t);
    s.ba = ba_;
    s.bg = bg_;
    s.c = c_;
    return s;
  }

  Vector3d Gyro(double t) const { return OmegaBody(t) + bg_; }
  Vector3d Accel(double t) const {
    const Vec3<Jet> v = VelocityBody(Jet(t, 0));
    const Vector3d a(v.x().v[0], v.y().v[0], v.z().v[0]);
    return RotationWorldBody(t).transpose() * (a + Vector3d(0.0, 0.0, kGravity)) + ba_;
  }
  /// Raw odometer speed (before the scale factor).
  double Speed(double t) const { return speed_.Value(t) / c_; }

 private:
  Profile speed_, yaw_, pitch_, roll_;
  Matrix3d R_body_odo_;
  Vector3d p_body_odo_;
  Vector3d ba_, bg_;
  double c_;
};

Preintegration MakePreintegration(const TrainTrajectory& traj,
                                  const PreintegrationNoise& noise = PreintegrationNoise()) {
  return Preintegration(
      traj.ba(), traj.bg(), traj.c(), traj.R_body_odo(), traj.p_body_odo(), noise, kGravity);
}

/// Adds the exact samples at t0 + k dt, k = first..last (the first with dt 0 when first == 0).
void AddSamples(const TrainTrajectory& traj, double t0, int first, int last, Preintegration* pre) {
  for (int k = first; k <= last; ++k) {
    const double t = t0 + k * kImuDt;
    pre->Add(k == 0 ? 0.0 : kImuDt, traj.Gyro(t), traj.Accel(t), traj.Speed(t), true);
  }
}

double RotationError(const Quaterniond& a, const Quaterniond& b) {
  return LogQuaternion(a.conjugate() * b).norm();
}

TEST(TrainTrajectoryTest, AngularVelocityMatchesRotationDerivative) {
  const TrainTrajectory traj(false);
  for (double t : {0.3, 1.7, 2.9}) {
    const Mat3<Jet> R = traj.RotationWorldBody(Jet(t, 0));
    Matrix3d R_val, R_dot;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        R_val(r, c) = R(r, c).a;
        R_dot(r, c) = R(r, c).v[0];
      }
    }
    const Matrix3d w_skew = R_val.transpose() * R_dot;
    EXPECT_LT((w_skew - Skew(traj.OmegaBody(t))).norm(), 1e-12);
    // The odometer point moves along the odometer x axis.
    const Vector3d v_odo =
        traj.VelocityBody(t) + R_val * traj.OmegaBody(t).cross(traj.p_body_odo());
    const Vector3d x_odo = R_val * traj.R_body_odo().col(0);
    EXPECT_LT((v_odo - v_odo.dot(x_odo) * x_odo).norm(), 1e-10);
  }
  // The quadrature position differentiates to the velocity.
  const double h = 1e-4;
  const Vector3d dp = (traj.State(1.0 + h).p - traj.State(1.0 - h).p) / (2 * h);
  EXPECT_LT((dp - traj.State(1.0).v).norm(), 1e-6);
}

struct TruthCase {
  bool reverse;
  double duration_s;
  double position_tol_m;
  double velocity_tol_mps;
  double rotation_tol_rad;
};

class PreintegrationTruthTest : public ::testing::TestWithParam<TruthCase> {};

// Midpoint integration is second order: over T the trapezoid error is about T dt^2 / 12 times
// the second derivative of the integrand. The trajectory's carbody vibrations (amplitude A at
// angular frequency w: 4 mrad at 9 rad/s, 2 mrad at 11 rad/s) give omega'' ~ A w^3 ~ 4 rad/s^3
// and, through the 1.65 m lever arm, a'' ~ A w^4 |p_body_odo| ~ 80 m/s^4, so at dt = 5 ms
// |d_theta| ~ 1e-6 rad and |d_beta| ~ 2e-5 m/s over 0.1 s (oscillating, not growing, over 1 s).
// The tolerances allow 3-5 times that, far below any sensor noise and well inside the 1 mm /
// 1e-5 rad asked for 0.1 s. SecondOrderConvergence checks that these are truncation errors.
TEST_P(PreintegrationTruthTest, MatchesIntegratedTruth) {
  const TruthCase tc = GetParam();
  const TrainTrajectory traj(tc.reverse);
  const double t0 = 1.3;
  const int n = static_cast<int>(std::lround(tc.duration_s / kImuDt));
  Preintegration pre = MakePreintegration(traj);
  AddSamples(traj, t0, 0, n, &pre);
  EXPECT_NEAR(pre.sum_dt(), tc.duration_s, 1e-12);
  EXPECT_TRUE(pre.odometer_used());

  const NavState xi = traj.State(t0);
  const NavState xj = traj.State(t0 + n * kImuDt);
  const Eigen::Matrix<double, 19, 1> r = pre.Evaluate(xi, xj);
  EXPECT_LT(r.segment<3>(0).norm(), tc.position_tol_m) << r.transpose();
  EXPECT_LT(r.segment<3>(3).norm(), tc.velocity_tol_mps) << r.transpose();
  EXPECT_LT(r.segment<3>(6).norm(), tc.rotation_tol_rad) << r.transpose();
  EXPECT_LT(r.segment<6>(9).norm(), 1e-15);
  EXPECT_LT(r.segment<3>(15).norm(), tc.position_tol_m) << r.transpose();
  EXPECT_EQ(r(18), 0.0);

  const NavState pred = pre.Predict(xi);
  EXPECT_LT((pred.p - xj.p).norm(), tc.position_tol_m);
  EXPECT_LT((pred.v - xj.v).norm(), tc.velocity_tol_mps);
  EXPECT_LT(RotationError(pred.q, xj.q), tc.rotation_tol_rad);
  EXPECT_EQ(pred.ba, xi.ba);
  EXPECT_EQ(pred.bg, xi.bg);
  EXPECT_EQ(pred.c, xi.c);
  std::printf("%s %.1f s: |r_alpha| %.2e m |r_beta| %.2e m/s |r_theta| %.2e rad |r_phi| %.2e m\n",
              tc.reverse ? "reverse" : "forward",
              tc.duration_s,
              r.segment<3>(0).norm(),
              r.segment<3>(3).norm(),
              r.segment<3>(6).norm(),
              r.segment<3>(15).norm());

  // Relative poses inside the interval (between samples too), for deskewing.
  const Vector3d v_start_body = xi.q.conjugate() * xi.v;
  for (double frac : {0.0, 0.13, 0.5, 0.77, 1.0}) {
    const double t = std::round(frac * n) * kImuDt + (frac > 0.0 && frac < 1.0 ? 0.0021 : 0.0);
    const NavState xt = traj.State(t0 + t);
    const Quaterniond q_rel = xi.q.conjugate() * xt.q;
    const Vector3d p_rel = xi.q.conjugate() * (xt.p - xi.p);
    for (const Eigen::Isometry3d& T :
         {pre.RelativePoseAt(t, v_start_body), pre.RelativePoseAt(t, v_start_body, xi.q)}) {
      EXPECT_LT((T.translation() - p_rel).norm(), tc.position_tol_m) << "t " << t;
      EXPECT_LT(RotationError(Quaterniond(T.linear()), q_rel), tc.rotation_tol_rad) << "t " << t;
    }
  }
}

/// Odometer-row residual of an interval of `n` steps with constant gyro and odometer speed, for
/// body positions p_i = 0 and p_j, rotations Identity and R_j, and the body's own sway roll.
Vector3d OdometerRow(const Vector3d& p_body_odo,
                     const Vector3d& gyro,
                     double speed,
                     int n,
                     const Vector3d& p_j,
                     const Matrix3d& R_j,
                     double sway_roll = 0.0) {
  Preintegration pre(Vector3d::Zero(),
                     Vector3d::Zero(),
                     1.0,
                     Matrix3d::Identity(),
                     p_body_odo,
                     PreintegrationNoise(),
                     kGravity);
  for (int k = 0; k <= n; ++k)
    pre.Add(k == 0 ? 0.0 : kImuDt, gyro, Vector3d(0, 0, kGravity), speed, true);
  pre.set_sway_roll(sway_roll);
  NavState i, j;
  j.p = p_j;
  j.q = Quaterniond(R_j);
  return pre.Evaluate(i, j).segment<3>(15);
}

// The body 3.8 m above the rail: the wheels meet the rail at p_body_odo = (0, 0, -3.8).
TEST(PreintegrationTest, OdometerPointUnderATallBody) {
  const double h = 3.8, v = 30.0, T = 0.5;
  const int n = static_cast<int>(std::lround(T / kImuDt));
  const Vector3d rail_contact(0.0, 0.0, -h);

  // Entering a cant, the track rolls 0.06 rad about the rail and takes the body with it: the
  // body swings 0.23 m sideways over a contact point that runs straight along x. With the
  // contact point, the across-track rows hold; taken at the body they would not.
  const double roll = 0.06;
  const Matrix3d R_roll(Eigen::AngleAxisd(roll, Vector3d::UnitX()));
  const Vector3d body_j =
      Vector3d(v * T, 0.0, 0.0) + R_roll * Vector3d(0.0, 0.0, h) - Vector3d(0.0, 0.0, h);
  const Vector3d gyro_roll(roll / T, 0.0, 0.0);
  const Vector3d cant = OdometerRow(rail_contact, gyro_roll, v, n, body_j, R_roll);
  EXPECT_LT(cant.norm(), 1e-9) << cant.transpose();
  const Vector3d cant_at_body = OdometerRow(Vector3d::Zero(), gyro_roll, v, n, body_j, R_roll);
  EXPECT_GT(std::fabs(cant_at_body.y()), 0.2) << cant_at_body.transpose();

  // Pitching 2 mrad on its suspension, the body turns about its own origin, which runs straight
  // along x with the wheels: the wheels do not roll any farther. The along-track row stays at
  // the second-order cosine loss of the pitched odometer axis instead of taking the arm's swing
  // h * pitch = 7.6 mm.
  const double pitch = 0.002;
  const Matrix3d R_pitch(Eigen::AngleAxisd(pitch, Vector3d::UnitY()));
  const Vector3d gyro_pitch(0.0, pitch / T, 0.0);
  const Vector3d bounce =
      OdometerRow(rail_contact, gyro_pitch, v, n, Vector3d(v * T, 0.0, 0.0), R_pitch);
  EXPECT_LT(std::fabs(bounce.x()), 1e-4) << bounce.transpose();

  // Rolling 2 mrad on its suspension, about its own origin, the body does not swing over the
  // rail. Told that this roll is sway, the across-track row holds; taken as the track's roll,
  // the arm would swing h * roll = 7.6 mm sideways.
  const double sway = 0.002;
  const Matrix3d R_sway(Eigen::AngleAxisd(sway, Vector3d::UnitX()));
  const Vector3d gyro_sway(sway / T, 0.0, 0.0);
  const Vector3d swaying =
      OdometerRow(rail_contact, gyro_sway, v, n, Vector3d(v * T, 0.0, 0.0), R_sway, sway);
  EXPECT_LT(swaying.norm(), 1e-4) << swaying.transpose();
  const Vector3d as_cant =
      OdometerRow(rail_contact, gyro_sway, v, n, Vector3d(v * T, 0.0, 0.0), R_sway);
  EXPECT_NEAR(std::fabs(as_cant.y()), h * sway, 1e-4) << as_cant.transpose();
  // Half the roll sway, half cant: the body swings over the rail by the cant's half only.
  const Vector3d body_half =
      Vector3d(v * T, 0.0, 0.0) +
      Matrix3d(Eigen::AngleAxisd(0.5 * sway, Vector3d::UnitX())) * Vector3d(0.0, 0.0, h) -
      Vector3d(0.0, 0.0, h);
  const Vector3d mixed = OdometerRow(rail_contact, gyro_sway, v, n, body_half, R_sway, 0.5 * sway);
  EXPECT_LT(mixed.norm(), 1e-4) << mixed.transpose();
}

// Pitched 2 mrad on its suspension, the body's x axis points below the track, but the wheels
// run along the track. Told the sway, the odometer rows hold; without it they would take the
// wheels' path 2 mrad downwards (3 cm over 15 m).
TEST(PreintegrationTest, TheWheelsFollowTheTrackNotTheSwayingBody) {
  const double sway = 0.002, v = 30.0, T = 0.5;
  const int n = static_cast<int>(std::lround(T / kImuDt));
  auto row = [&](const Vector3d& told) {
    Preintegration pre(Vector3d::Zero(),
                       Vector3d::Zero(),
                       1.0,
                       Matrix3d::Identity(),
                       Vector3d::Zero(),
                       PreintegrationNoise(),
                       kGravity);
    for (int k = 0; k <= n; ++k)
      pre.Add(k == 0 ? 0.0 : kImuDt, Vector3d::Zero(), Vector3d(0, 0, kGravity), v, true, told);
    NavState i, j;
    i.q = j.q = Quaterniond(Eigen::AngleAxisd(sway, Vector3d::UnitY()));
    j.p = Vector3d(v * T, 0.0, 0.0);
    return Vector3d(pre.Evaluate(i, j).segment<3>(15));
  };
  EXPECT_LT(row(Vector3d(0.0, sway, 0.0)).norm(), 1e-4)
      << row(Vector3d(0.0, sway, 0.0)).transpose();
  EXPECT_NEAR(std::fabs(row(Vector3d::Zero()).z()), v * T * sway, 1e-4);
}

// A 0.5 s IMU dropout is bridged by one step between the samples around it. Their noise holds
// through the step instead of averaging out over 100 samples, so the step's rotation variance
// is about 100 times that of 100 real samples, not the same.
TEST(PreintegrationTest, ABridgedGapIsNotTrustedLikeRealSamples) {
  PreintegrationNoise noise;
  noise.imu_period_s = kImuDt;
  const Vector3d gyro(0.0, 0.0, 0.01), accel(0.0, 0.0, kGravity);
  // The variances of the yaw and of the velocity along x after 0.5 s in `steps` steps.
  auto variances = [&](const PreintegrationNoise& n, int steps) {
    Preintegration pre(Vector3d::Zero(),
                       Vector3d::Zero(),
                       1.0,
                       Matrix3d::Identity(),
                       Vector3d::Zero(),
                       n,
                       kGravity);
    for (int k = 0; k <= steps; ++k) pre.Add(k == 0 ? 0.0 : 0.5 / steps, gyro, accel, 20.0, true);
    return std::make_pair(pre.covariance()(8, 8), pre.covariance()(3, 3));
  };
  // The samples' own noise: held through the step, not averaged down over it.
  PreintegrationNoise sensor_only = noise;
  sensor_only.gap_rate_sigma_radps = 0.0;
  sensor_only.gap_accel_sigma_mps2 = 0.0;
  const double sampled = variances(sensor_only, 100).first;
  const double held = variances(sensor_only, 1).first;
  const double density = noise.gyro_noise_density;
  EXPECT_NEAR(sampled, density * density * 0.5, 1e-3 * sampled);
  EXPECT_NEAR(held / sampled, 100.0, 1.0);
  // The body's own motion across the gap, which the interpolation does not follow: the turn
  // and the velocity are uncertain by sigma times the gap. Real samples are left as they were.
  const double bridged_theta = variances(noise, 1).first;
  const double rate = noise.gap_rate_sigma_radps * 0.5;
  EXPECT_NEAR(bridged_theta, held + rate * rate, 1e-3 * bridged_theta);
  PreintegrationNoise accel_only = sensor_only;  // (the turn's share of the velocity aside)
  accel_only.gap_accel_sigma_mps2 = noise.gap_accel_sigma_mps2;
  const double bridged_v = variances(accel_only, 1).second;
  const double wander = noise.gap_accel_sigma_mps2 * 0.5;
  EXPECT_NEAR(bridged_v, variances(sensor_only, 1).second + wander * wander, 1e-3 * bridged_v);
  EXPECT_GT(std::sqrt(bridged_theta), 0.009);  // 10 mrad over the 0.5 s gap
  EXPECT_NEAR(variances(noise, 100).first / sampled, 1.0, 1e-9);
  // Without the sample period every step counts as if it had been sampled.
  PreintegrationNoise unknown_period;
  EXPECT_NEAR(variances(unknown_period, 1).first / sampled, 1.0, 1e-4);
}

INSTANTIATE_TEST_SUITE_P(Intervals,
                         PreintegrationTruthTest,
                         ::testing::Values(TruthCase{false, 0.1, 1e-5, 1e-4, 3e-6},
                                           TruthCase{false, 1.0, 1e-4, 2e-4, 1e-5},
                                           TruthCase{true, 0.1, 1e-5, 1e-4, 3e-6},
                                           TruthCase{true, 1.0, 1e-4, 2e-4, 1e-5}));

// The residuals at the truth are truncation errors of a second-order scheme: halving the step
// quarters them.
TEST(PreintegrationTest, SecondOrderConvergence) {
  const TrainTrajectory traj(false);
  const double t0 = 1.3;
  double previous[3] = {0.0, 0.0, 0.0};
  for (int n : {20, 40, 80}) {
    const double dt = 0.1 / n;
    Preintegration pre = MakePreintegration(traj);
    for (int k = 0; k <= n; ++k) {
      const double t = t0 + k * dt;
      pre.Add(k == 0 ? 0.0 : dt, traj.Gyro(t), traj.Accel(t), traj.Speed(t), true);
    }
    const Eigen::Matrix<double, 19, 1> r = pre.Evaluate(traj.State(t0), traj.State(t0 + 0.1));
    const double errors[3] = {
        r.segment<3>(3).norm(), r.segment<3>(6).norm(), r.segment<3>(15).norm()};
    for (int b = 0; b < 3; ++b) {
      if (previous[b] > 0.0) {
        EXPECT_NEAR(previous[b] / errors[b], 4.0, 0.5) << "n " << n << " block " << b;
      }
      previous[b] = errors[b];
    }
  }
}

// Eq. (18): the first-order corrections against a full repropagation. Their difference must be
// second order in the bias/scale change: halving the change quarters it.
TEST(PreintegrationTest, BiasAndScaleJacobiansAreFirstOrderExact) {
  const TrainTrajectory traj(false);
  const double t0 = 0.7;
  Preintegration pre = MakePreintegration(traj);
  AddSamples(traj, t0, 0, 200, &pre);
  const NavState xi = traj.State(t0);
  const NavState xj = traj.State(t0 + 1.0);

  const Vector3d dba(0.05, -0.03, 0.04);
  const Vector3d dbg(0.004, -0.003, 0.005);
  const double dc = 0.02;
  double previous_error[4] = {0, 0, 0, 0};
  for (double scale : {1.0, 0.5}) {
    NavState xi_moved = xi;
    xi_moved.ba += scale * dba;
    xi_moved.bg += scale * dbg;
    xi_moved.c += scale * dc;
    Preintegration moved = pre;
    moved.Repropagate(xi_moved.ba, xi_moved.bg, xi_moved.c);
    const Eigen::Matrix<double, 19, 1> r_first_order = pre.Evaluate(xi_moved, xj);
    const Eigen::Matrix<double, 19, 1> r_exact = moved.Evaluate(xi_moved, xj);
    const Eigen::Matrix<double, 19, 1> r_uncorrected = pre.Evaluate(xi, xj);
    const int blocks[4] = {0, 3, 6, 15};  // alpha, beta, theta, phi
    for (int b = 0; b < 4; ++b) {
      const double change = (r_exact - r_uncorrected).segment<3>(blocks[b]).norm();
      const double error = (r_first_order - r_exact).segment<3>(blocks[b]).norm();
      std::printf("block %d scale %.1f: change %.3e, first-order error %.3e\n",
                  blocks[b],
                  scale,
                  change,
                  error);
      EXPECT_GT(change, 1e-3 * scale);
      EXPECT_LT(error, 0.01 * change);
      if (scale < 1.0) {
        // Second order: the ratio is 4 up to third-order terms.
        EXPECT_NEAR(previous_error[b] / error, 4.0, 0.6) << "block " << blocks[b];
      }
      previous_error[b] = error;
    }
  }
}

// The misalignment m is first-order exact: phi integrated along the axis turned by m (the
// odometer frame R_body_odo Exp((0, m0, m1))) against phi + phi_misalignment() m.
TEST(PreintegrationTest, MisalignmentJacobianIsFirstOrderExact) {
  const TrainTrajectory traj(false);
  const double t0 = 0.7;
  Preintegration pre = MakePreintegration(traj);
  AddSamples(traj, t0, 0, 200, &pre);
  double previous_error = 0.0;
  for (double scale : {1.0, 0.5}) {
    const Eigen::Vector2d m = scale * Eigen::Vector2d(3e-3, -2e-3);
    const Matrix3d R_turned =
        traj.R_body_odo() * ExpQuaternion(Vector3d(0.0, m.x(), m.y())).toRotationMatrix();
    Preintegration turned(traj.ba(),
                          traj.bg(),
                          traj.c(),
                          R_turned,
                          traj.p_body_odo(),
                          PreintegrationNoise(),
                          kGravity);
    AddSamples(traj, t0, 0, 200, &turned);
    const Vector3d change = turned.phi() - pre.phi();
    const double error = (change - pre.phi_misalignment() * m).norm();
    std::printf("scale %.1f: change %.3e, first-order error %.3e\n", scale, change.norm(), error);
    EXPECT_GT(change.norm(), 0.05 * scale);  // about 20 m at 3.6 mrad
    EXPECT_LT(error, 0.01 * change.norm());
    if (scale < 1.0) {
      EXPECT_NEAR(previous_error / error, 4.0, 0.6);
    }
    previous_error = error;
  }
}

/// The true IMU and odometer readings of `traj` over n + 1 samples from t0.
struct ImuSamples {
  std::vector<Vector3d> gyro, accel;
  std::vector<double> speed;  ///< the true odometer speed
};

ImuSamples SampleTrajectory(const TrainTrajectory& traj, double t0, int n) {
  ImuSamples out;
  for (int k = 0; k <= n; ++k) {
    const double t = t0 + k * kImuDt;
    out.gyro.push_back(traj.Gyro(t));
    out.accel.push_back(traj.Accel(t));
    out.speed.push_back(traj.Speed(t) * traj.c());
  }
  return out;
}

/// Draws of the standard normal distribution, in the order the Monte Carlo runs take them.
struct NormalDraws {
  std::mt19937 rng{42};
  std::normal_distribution<double> normal{0.0, 1.0};
  double operator()() { return normal(rng); }
  Vector3d Three() { return Vector3d(normal(rng), normal(rng), normal(rng)); }
};

/// One noisy run over `samples` (white noise and random walks of `noise`): its error against
/// the clean preintegration, ordered as the covariance of Eq. (17).
Eigen::Matrix<double, 19, 1> NoisyRunError(const TrainTrajectory& traj,
                                           const PreintegrationNoise& noise,
                                           const ImuSamples& samples,
                                           const Preintegration& clean,
                                           NormalDraws* randn) {
  const double sqrt_dt = std::sqrt(kImuDt);
  Preintegration noisy = MakePreintegration(traj, noise);
  Vector3d dba = Vector3d::Zero(), dbg = Vector3d::Zero();
  double c = traj.c();
  for (size_t k = 0; k < samples.gyro.size(); ++k) {
    if (k > 0) {
      dba += noise.accel_bias_walk * sqrt_dt * randn->Three();
      dbg += noise.gyro_bias_walk * sqrt_dt * randn->Three();
      c += noise.odometer_scale_walk * sqrt_dt * (*randn)();
    }
    const Vector3d g = samples.gyro[k] + dbg + noise.gyro_noise_density / sqrt_dt * randn->Three();
    const Vector3d a =
        samples.accel[k] + dba + noise.accel_noise_density / sqrt_dt * randn->Three();
    // Eq. (9): c * s_hat = v + eta.
    const double s = (samples.speed[k] + noise.odometer_speed_density / sqrt_dt * (*randn)()) / c;
    noisy.Add(k == 0 ? 0.0 : kImuDt, g, a, s, true);
  }
  Eigen::Matrix<double, 19, 1> e;
  e.segment<3>(0) = noisy.alpha() - clean.alpha();
  e.segment<3>(3) = noisy.beta() - clean.beta();
  e.segment<3>(6) = LogQuaternion(clean.gamma().conjugate() * noisy.gamma());
  e.segment<3>(9) = dba;
  e.segment<3>(12) = dbg;
  e.segment<3>(15) = noisy.phi() - clean.phi();
  e(18) = c - traj.c();
  return e;
}

Eigen::Matrix<double, 19, 19> SampleCovariance(
    const std::vector<Eigen::Matrix<double, 19, 1>>& errors) {
  const double runs = static_cast<double>(errors.size());
  Eigen::Matrix<double, 19, 1> mean = Eigen::Matrix<double, 19, 1>::Zero();
  for (const auto& e : errors) mean += e / runs;
  Eigen::Matrix<double, 19, 19> sample = Eigen::Matrix<double, 19, 19>::Zero();
  for (const auto& e : errors) sample += (e - mean) * (e - mean).transpose() / (runs - 1);
  return sample;
}

// Eq. (17): the propagated covariance against the sample covariance of noisy runs. The noise
// densities are raised so that every term (white noise and random walks) is visible. With 400
// runs a sample variance has a relative standard error of 7 %, so 25 % is a 3.5 sigma bound.
TEST(PreintegrationTest, CovarianceMatchesMonteCarlo) {
  const TrainTrajectory traj(false);
  PreintegrationNoise noise;
  noise.gyro_noise_density = 2e-3;
  noise.accel_noise_density = 2e-2;
  noise.gyro_bias_walk = 2e-3;
  noise.accel_bias_walk = 2e-2;
  noise.odometer_speed_density = 0.05;
  noise.odometer_scale_walk = 5e-3;
  const ImuSamples samples = SampleTrajectory(traj, 2.1, 200);
  Preintegration clean = MakePreintegration(traj, noise);
  for (size_t k = 0; k < samples.gyro.size(); ++k) {
    clean.Add(k == 0 ? 0.0 : kImuDt,
              samples.gyro[k],
              samples.accel[k],
              samples.speed[k] / traj.c(),
              true);
  }
  NormalDraws randn;
  std::vector<Eigen::Matrix<double, 19, 1>> errors;
  for (int run = 0; run < 400; ++run)
    errors.push_back(NoisyRunError(traj, noise, samples, clean, &randn));
  const Eigen::Matrix<double, 19, 19> sample = SampleCovariance(errors);

  const Eigen::Matrix<double, 19, 19>& cov = clean.covariance();
  for (int k = 0; k < 19; ++k) {
    const double ratio = sample(k, k) / cov(k, k);
    std::printf(
        "row %2d: propagated %.3e sample %.3e ratio %.3f\n", k, cov(k, k), sample(k, k), ratio);
    EXPECT_NEAR(ratio, 1.0, 0.25) << "row " << k;
  }
  // The strongest correlations (alpha-beta along each axis, theta-phi) carry over as well.
  for (int k = 0; k < 3; ++k) {
    const double rho_cov = cov(k, 3 + k) / std::sqrt(cov(k, k) * cov(3 + k, 3 + k));
    const double rho_sample = sample(k, 3 + k) / std::sqrt(sample(k, k) * sample(3 + k, 3 + k));
    EXPECT_NEAR(rho_sample, rho_cov, 0.1) << "axis " << k;
  }
}

TEST(PreintegrationTest, SqrtInformationWhitensTheCovariance) {
  const TrainTrajectory traj(false);
  Preintegration pre = MakePreintegration(traj);
  AddSamples(traj, 0.2, 0, 40, &pre);
  const Eigen::Matrix<double, 19, 19> L = pre.SqrtInformation();
  EXPECT_TRUE(L.isUpperTriangular());
  // L cov L^T = I up to the conditioning of the covariance.
  const Eigen::Matrix<double, 19, 19> whitened = L * pre.covariance() * L.transpose();
  EXPECT_LT((whitened - Eigen::Matrix<double, 19, 19>::Identity()).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(PreintegrationTest, IntervalWithoutOdometerCarriesNoPhiInformation) {
  const TrainTrajectory traj(false);
  Preintegration pre = MakePreintegration(traj);
  for (int k = 0; k <= 40; ++k) {
    const double t = 0.5 + k * kImuDt;
    pre.Add(k == 0 ? 0.0 : kImuDt, traj.Gyro(t), traj.Accel(t), traj.Speed(t), k != 17);
  }
  EXPECT_FALSE(pre.odometer_used());
  const Eigen::Matrix<double, 19, 19> L = pre.SqrtInformation();
  EXPECT_TRUE(L.allFinite());
  EXPECT_EQ(L.middleRows<3>(15).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ(L.middleCols<3>(15).cwiseAbs().maxCoeff(), 0.0);
  // The other rows whiten the rest of the covariance.
  std::vector<int> rest;
  for (int k = 0; k < 19; ++k) {
    if (k < 15 || k > 17) rest.push_back(k);
  }
  Eigen::MatrixXd L_rest(16, 16), cov_rest(16, 16);
  for (int a = 0; a < 16; ++a) {
    for (int b = 0; b < 16; ++b) {
      L_rest(a, b) = L(rest[a], rest[b]);
      cov_rest(a, b) = pre.covariance()(rest[a], rest[b]);
    }
  }
  EXPECT_LT((L_rest * cov_rest * L_rest.transpose() - Eigen::MatrixXd::Identity(16, 16))
                .cwiseAbs()
                .maxCoeff(),
            1e-6);
  // The IMU part is unaffected: residuals at the truth still vanish apart from phi.
  const Eigen::Matrix<double, 19, 1> r = pre.Evaluate(traj.State(0.5), traj.State(0.7));
  EXPECT_LT(r.head<9>().norm(), 1e-4);
  // Without odometer data RelativePoseAt falls back to the IMU with a level start.
  EXPECT_TRUE(pre.RelativePoseAt(0.1, Vector3d::Zero()).matrix().allFinite());

  // A valid interval is not affected by an invalid sample of another one.
  Preintegration ok = MakePreintegration(traj);
  AddSamples(traj, 0.5, 0, 40, &ok);
  EXPECT_TRUE(ok.odometer_used());
  EXPECT_GT(ok.SqrtInformation().middleRows<3>(15).cwiseAbs().maxCoeff(), 0.0);
}

TEST(PreintegrationTest, AppendEqualsOnePreintegration) {
  const TrainTrajectory traj(true);
  const double t0 = 0.9;
  Preintegration whole = MakePreintegration(traj);
  AddSamples(traj, t0, 0, 60, &whole);
  Preintegration first = MakePreintegration(traj);
  AddSamples(traj, t0, 0, 25, &first);
  Preintegration second = MakePreintegration(traj);
  const double t_second = t0 + 25 * kImuDt;
  AddSamples(traj, t_second, 0, 35, &second);
  // Linearised elsewhere: Append repropagates about the first one's point.
  second.Repropagate(Vector3d(0.1, 0.0, 0.0), Vector3d::Zero(), 1.0);
  first.Append(second);

  EXPECT_EQ(first.num_steps(), whole.num_steps());
  EXPECT_NEAR(first.sum_dt(), whole.sum_dt(), 1e-12);
  EXPECT_LT((first.alpha() - whole.alpha()).norm(), 1e-12);
  EXPECT_LT((first.beta() - whole.beta()).norm(), 1e-12);
  EXPECT_LT(RotationError(first.gamma(), whole.gamma()), 1e-12);
  EXPECT_LT((first.phi() - whole.phi()).norm(), 1e-12);
  EXPECT_LT((first.jacobian() - whole.jacobian()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((first.covariance() - whole.covariance()).cwiseAbs().maxCoeff(), 1e-16);
  EXPECT_TRUE(first.odometer_used());

  // Adding to the joined preintegration continues from the last measurement.
  AddSamples(traj, t0, 61, 70, &first);
  AddSamples(traj, t0, 61, 70, &whole);
  EXPECT_LT((first.alpha() - whole.alpha()).norm(), 1e-12);
}

}  // namespace
}  // namespace raillomer
