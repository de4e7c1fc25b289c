// The true motion: the speed profile at known times, reverse running, the inertial quantities at
// standstill, and a strapdown integration of the truth's own IMU signal that must reproduce the
// truth's poses (the IMU and the ground truth agree).

#include "estimator/sim/motion.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "tests/estimator/sim/scenario_builders.h"

namespace raillomer::sim {
namespace {

using test::Curve;
using test::ForMetres;
using test::ForSeconds;
using test::Straight;
using test::ToSpeed;

constexpr double kGravity = 9.81;
constexpr double kRadToDeg = 180.0 / M_PI;

Eigen::Matrix3d Exp(const Eigen::Vector3d& phi) {
  const double angle = phi.norm();
  if (angle < 1e-15) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, phi / angle).toRotationMatrix();
}

double AngleDeg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a.transpose() * b).angle() * kRadToDeg;
}

/// Result of integrating the truth's noise-free IMU signal.
struct StrapdownError {
  double max_position_m = 0.0;
  double max_rotation_deg = 0.0;
  double final_velocity_mps = 0.0;
};

/// Strapdown integration of TruthMotion::Inertial at `rate_hz` from the true pose and velocity at
/// t0 over `duration_s`, compared with TruthMotion::Pose every 0.1 s. Mid-interval samples make
/// the integration second order.
StrapdownError Strapdown(const TruthMotion& truth, double t0, double duration_s, double rate_hz) {
  const double dt = 1.0 / rate_hz, h = 1e-4;
  const Eigen::Vector3d g_world(0.0, 0.0, -kGravity);
  const Eigen::Isometry3d start = truth.Pose(t0);
  Eigen::Matrix3d R = start.linear();
  Eigen::Vector3d p = start.translation();
  Eigen::Vector3d v =
      (truth.Pose(t0 + h).translation() - truth.Pose(t0 - h).translation()) / (2 * h);
  StrapdownError error;
  const int steps = static_cast<int>(std::lround(duration_s * rate_hz));
  const int compare_every = std::max(1, static_cast<int>(std::lround(0.1 * rate_hz)));
  for (int k = 0; k < steps; ++k) {
    const double t_mid = t0 + (k + 0.5) * dt;
    Eigen::Vector3d omega, force;
    truth.Inertial(t_mid, kGravity, &omega, &force, dt);
    const Eigen::Matrix3d R_mid = R * Exp(0.5 * dt * omega);
    const Eigen::Vector3d a = R_mid * force + g_world;
    p += v * dt + 0.5 * a * dt * dt;
    v += a * dt;
    R = R * Exp(dt * omega);
    if ((k + 1) % compare_every == 0) {
      const Eigen::Isometry3d T = truth.Pose(t0 + (k + 1) * dt);
      error.max_position_m = std::max(error.max_position_m, (T.translation() - p).norm());
      error.max_rotation_deg = std::max(error.max_rotation_deg, AngleDeg(T.linear(), R));
    }
  }
  const double t1 = t0 + steps * dt;
  const Eigen::Vector3d v_true =
      (truth.Pose(t1 + h).translation() - truth.Pose(t1 - h).translation()) / (2 * h);
  error.final_velocity_mps = (v_true - v).norm();
  return error;
}

/// Over 10 s from t0, at two phases of the IMU clock, the 1 kHz strapdown of the truth's own
/// IMU stays within 3 cm, 0.01 deg and 5 mm/s of the truth.
void ExpectStrapdownMatchesTruth(const TruthMotion& truth, double t0) {
  for (double start : {t0, t0 + 0.0002}) {
    const StrapdownError error = Strapdown(truth, start, 10.0, 1000.0);
    EXPECT_LT(error.max_position_m, 0.03) << "t0 " << start;
    EXPECT_LT(error.max_rotation_deg, 0.01) << "t0 " << start;
    EXPECT_LT(error.final_velocity_mps, 0.005) << "t0 " << start;
  }
}

/// A curved, graded, canted line for runs of a few hundred metres.
Scenario CurvedRun() {
  Scenario s;
  s.alignment = {Straight(200.0), Curve(600.0, 500.0, 1, 80.0, 100.0, 8.0), Straight(800.0)};
  s.start_m = 150.0;
  s.start_speed_mps = 20.0;
  s.phases = {ToSpeed(30.0, 0.5), ForSeconds(20.0)};
  s.vibration_scale = 1.0;
  return s;
}

TEST(SpeedProfile, DistancesAndSpeedsAtKnownTimes) {
  Scenario s;
  s.phases = {ForSeconds(2.0), ToSpeed(10.0, 0.5), ForSeconds(5.0), ToSpeed(0.0, 1.0)};
  const SpeedProfile profile(s);
  EXPECT_NEAR(profile.duration_s(), 2.0 + 20.0 + 5.0 + 10.0, 1e-12);
  struct Expected {
    double t, distance, speed, accel;
  };
  for (const Expected& e : {Expected{0.0, 0.0, 0.0, 0.0},
                            Expected{1.0, 0.0, 0.0, 0.0},
                            Expected{12.0, 25.0, 5.0, 0.5},
                            Expected{22.0, 100.0, 10.0, 0.0},
                            Expected{27.0, 150.0, 10.0, -1.0},
                            Expected{32.0, 187.5, 5.0, -1.0},
                            Expected{37.0, 200.0, 0.0, 0.0},
                            Expected{45.0, 200.0, 0.0, 0.0}}) {
    double distance = -1.0, speed = -1.0, accel = -1.0;
    profile.At(e.t, &distance, &speed, &accel);
    EXPECT_NEAR(distance, e.distance, 1e-9) << "t " << e.t;
    EXPECT_NEAR(speed, e.speed, 1e-9) << "t " << e.t;
    EXPECT_NEAR(accel, e.accel, 1e-12) << "t " << e.t;
  }
  // for_m ends after exactly that distance.
  s.start_speed_mps = 8.0;
  s.phases = {ForMetres(100.0), ToSpeed(4.0, 0.8)};
  const SpeedProfile metres(s);
  EXPECT_NEAR(metres.duration_s(), 12.5 + 5.0, 1e-12);
  double distance, speed, accel;
  metres.At(12.5, &distance, &speed, &accel);
  EXPECT_NEAR(distance, 100.0, 1e-9);
  metres.At(17.5, &distance, &speed, &accel);
  EXPECT_NEAR(distance, 100.0 + 0.5 * (8.0 + 4.0) * 5.0, 1e-9);
  EXPECT_NEAR(speed, 4.0, 1e-12);
  EXPECT_NEAR(metres.duration_s(), s.ProfileDurationS(), 1e-12);
}

TEST(TruthMotion, ReverseRunningDecreasesChainage) {
  Scenario s;
  s.alignment = {Straight(1000.0)};
  s.start_m = 300.0;
  s.start_speed_mps = -5.0;
  s.phases = {ForSeconds(20.0)};
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 1);
  EXPECT_NEAR(truth.Chainage(0.0), 300.0, 1e-12);
  EXPECT_NEAR(truth.Chainage(20.0), 200.0, 1e-9);
  EXPECT_NEAR(truth.Speed(10.0), -5.0, 1e-12);
  for (double t = 0.5; t <= 20.0; t += 0.5) {
    EXPECT_LT(truth.Chainage(t), truth.Chainage(t - 0.5));
  }
  // The body keeps facing up the line, so it moves backwards along its own x axis.
  const Eigen::Isometry3d a = truth.Pose(5.0), b = truth.Pose(6.0);
  const Eigen::Vector3d moved = b.translation() - a.translation();
  EXPECT_NEAR(moved.dot(a.linear().col(0)), -5.0, 0.02);

  // A reversal through zero: up the line to a turning point, then back.
  s.start_speed_mps = 5.0;
  s.phases = {ToSpeed(-5.0, 0.5), ForSeconds(10.0)};
  const TruthMotion turn(s, alignment, 1);
  EXPECT_NEAR(turn.duration_s(), 30.0, 1e-12);
  EXPECT_NEAR(turn.Chainage(10.0), 300.0 + 25.0, 1e-9);  // v^2 / 2a
  EXPECT_NEAR(turn.Speed(10.0), 0.0, 1e-12);
  EXPECT_NEAR(turn.Chainage(20.0), 300.0, 1e-9);
  EXPECT_NEAR(turn.Chainage(30.0), 250.0, 1e-9);
  for (double t = 11.0; t <= 30.0; t += 1.0) EXPECT_LT(turn.Chainage(t), turn.Chainage(t - 1.0));
}

TEST(TruthMotion, StandstillOnAGradeSensesOnlyGravity) {
  Scenario s;
  // Stand on the canted arc of a left curve, on a 20 per mille grade.
  s.alignment = {Straight(100.0), Curve(400.0, 600.0, 1, 50.0, 100.0, 20.0), Straight(300.0)};
  s.start_m = 300.0;
  s.phases = {ForSeconds(30.0)};
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 3);
  const TrackPoint track = alignment.At(300.0);
  ASSERT_NEAR(track.grade, 0.02, 1e-12);
  ASSERT_LT(track.roll_rad, 0.0);
  for (double t : {0.5, 5.0, 17.3, 29.0}) {
    Eigen::Vector3d omega, force;
    truth.Inertial(t, kGravity, &omega, &force);
    const Eigen::Matrix3d R = truth.Pose(t).linear();
    const Eigen::Vector3d expected = R.transpose() * Eigen::Vector3d(0.0, 0.0, kGravity);
    EXPECT_LT((force - expected).norm(), 1e-6) << "t " << t;
    EXPECT_LT(omega.norm(), 1e-9) << "t " << t;
    // Closed form: g (sin pitch, cos pitch sin roll, cos pitch cos roll).
    const double pitch = std::atan(0.02), roll = track.roll_rad;
    EXPECT_NEAR(force.x(), kGravity * std::sin(pitch), 1e-6);  // nose up: +x
    EXPECT_NEAR(force.y(), kGravity * std::cos(pitch) * std::sin(roll), 1e-6);
    EXPECT_NEAR(force.z(), kGravity * std::cos(pitch) * std::cos(roll), 1e-6);
    EXPECT_GT(force.x(), 0.19);
    EXPECT_LT(force.y(), -0.6);
  }
}

TEST(TruthMotion, StrapdownOfTheTruthImuReproducesThePosesOnACurve) {
  // Clothoid and arc without cant or grade: the body's velocity is smooth (see the next test for
  // cant and grade).
  Scenario s = CurvedRun();
  s.alignment[1].cant_mm = 0.0;
  s.alignment[1].gradient_permille = 0.0;
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 5);
  // 2-12 s: accelerating 21 -> 26 m/s from the straight through the entry transition onto the
  // arc, with full vibration.
  ASSERT_LT(truth.Chainage(2.0), 200.0);
  ASSERT_GT(truth.Chainage(12.0), 200.0 + 80.0 + 100.0);
  EXPECT_GT(AngleDeg(truth.Pose(2.0).linear(), truth.Pose(12.0).linear()), 5.0);  // not trivial
  ExpectStrapdownMatchesTruth(truth, 2.0);
}

TEST(TruthMotion, StrapdownOfTheTruthImuReproducesThePosesThroughCantAndGrade) {
  // The same run with 100 mm of cant ramped over the transition and an 8 per mille grade eased
  // in over a 60 m vertical curve. Linear ramps would step the roll and pitch rates at the ramp
  // ends, and a point-sampled IMU would miss the body's velocity step.
  const Scenario s = CurvedRun();
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 5);
  ASSERT_LT(truth.Chainage(3.0), 200.0 + 30.0);  // inside the vertical curve
  ASSERT_GT(truth.Chainage(13.0), 200.0 + 80.0 + 100.0);
  ExpectStrapdownMatchesTruth(truth, 3.0);
}

TEST(TruthMotion, BodyVelocityIsContinuous) {
  // A body on a suspension cannot change velocity in no time. Velocity from central differences
  // 1 ms apart, every millisecond: smooth motion changes by |a| * 1 ms (a few mm/s), a step by
  // its full size. Linear cant and grade ramps would step the roll and pitch rates and give the
  // body, 3.8 m above the rail, a velocity step.
  const Scenario s = CurvedRun();
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 5);
  auto velocity = [&](double t) {
    const double e = 1e-6;
    return Eigen::Vector3d((truth.Pose(t + e).translation() - truth.Pose(t - e).translation()) /
                           (2.0 * e));
  };
  double worst = 0.0, worst_t = 0.0;
  for (double t = 0.01; t < 20.0; t += 1e-3) {
    const double jump = (velocity(t + 5e-4) - velocity(t - 5e-4)).norm();
    if (jump > worst) {
      worst = jump;
      worst_t = t;
    }
  }
  EXPECT_LT(worst, 0.01) << "velocity step at t " << worst_t << " s, chainage "
                         << truth.Chainage(worst_t) << " m";
}

TEST(TruthMotion, InertialAtTheStartOfARunningStart) {
  // A run that starts at speed: the first IMU sample (t = 0) must not see a step from standing.
  // (Were SpeedProfile::At to clamp t < 0 to the start, the second difference at t = 0 would
  // read v0 / h, 40,000 m/s^2 at 20 m/s.)
  Scenario s;
  s.alignment = {Straight(1000.0)};
  s.start_m = 12.0;
  s.start_speed_mps = 20.0;
  s.phases = {ForSeconds(20.0)};
  s.vibration_scale = 0.0;
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 1);
  for (double t : {0.0, 0.0002, 0.005, 1.0}) {
    Eigen::Vector3d omega, force;
    truth.Inertial(t, kGravity, &omega, &force);
    EXPECT_LT((force - Eigen::Vector3d(0.0, 0.0, kGravity)).norm(), 1e-3)
        << "t " << t << ": " << force.transpose();
    EXPECT_LT(omega.norm(), 1e-9) << "t " << t;
  }
}

TEST(TruthMotion, BodyRidesAtBodyHeightAboveTheRailTop) {
  Scenario s = CurvedRun();
  s.body_height_m = 3.8;
  s.phases.insert(s.phases.begin(), ForSeconds(5.0));
  s.start_speed_mps = 0.0;
  s.phases[1] = ToSpeed(25.0, 0.8);
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 2);
  for (double t = 0.0; t <= truth.duration_s(); t += 0.37) {
    const TrackPoint track = alignment.At(truth.Chainage(t));
    const Eigen::Matrix3d R_track = track.Rotation();
    const Eigen::Vector3d local =
        R_track.transpose() * (truth.Pose(t).translation() - track.position);
    if (t < 5.0) {  // standing: no vibration
      EXPECT_NEAR(local.z(), 3.8, 1e-9) << "t " << t;
      EXPECT_NEAR(local.head<2>().norm(), 0.0, 1e-9) << "t " << t;
    } else {  // car-body modes of a few millimetres
      EXPECT_NEAR(local.z(), 3.8, 0.007) << "t " << t;
      EXPECT_NEAR(local.y(), 0.0, 0.004) << "t " << t;
      EXPECT_NEAR(local.x(), 0.0, 1e-9) << "t " << t;
    }
  }
}

// The body's standing pitch and yaw against the track (motion.body_pitch_mrad, body_yaw_mrad)
// hold at rest and at speed: the body's x axis leaves the track's by them.
TEST(TruthMotion, AStandingPitchAndYawTurnTheBodyOffTheTrack) {
  Scenario s = CurvedRun();
  s.vibration_scale = 0.0;
  s.body_pitch_rad = 1.6e-3;
  s.body_yaw_rad = -0.8e-3;
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 2);
  for (double t = 0.0; t <= truth.duration_s(); t += 0.37) {
    const Eigen::Matrix3d R_track = alignment.At(truth.Chainage(t)).Rotation();
    const Eigen::Vector3d x = R_track.transpose() * truth.Pose(t).linear().col(0);
    EXPECT_NEAR(x.z(), -1.6e-3, 1e-8) << "t " << t;  // nose down
    EXPECT_NEAR(x.y(), -0.8e-3, 1e-8) << "t " << t;  // to the right
  }
}

TEST(TruthMotion, VibrationGrowsWithSpeed) {
  Scenario s = CurvedRun();
  s.start_speed_mps = 0.0;
  s.phases = {ForSeconds(10.0), ToSpeed(20.0, 1.0), ForSeconds(20.0)};
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 2);
  auto rms_vertical_accel = [&](double from, double to) {
    double sum = 0.0;
    int n = 0;
    for (double t = from; t < to; t += 0.005, ++n) {
      Eigen::Vector3d omega, force;
      truth.Inertial(t, kGravity, &omega, &force);
      sum += (force.z() - kGravity) * (force.z() - kGravity);
    }
    return std::sqrt(sum / n);
  };
  const double standing = rms_vertical_accel(1.0, 9.0);
  const double running = rms_vertical_accel(32.0, 50.0);
  EXPECT_LT(standing, 0.01);
  EXPECT_GT(running, 0.3);
  EXPECT_LT(running, 2.0);
}

/// Vertical specific force (minus its mean) sampled at 1 kHz over a constant-speed run.
std::vector<double> VerticalAccel(const TruthMotion& truth, double from, double to) {
  std::vector<double> out;
  for (double t = from; t < to; t += 1e-3) {
    Eigen::Vector3d omega, force;
    truth.Inertial(t, kGravity, &omega, &force);
    out.push_back(force.z());
  }
  return out;
}

double Variance(const std::vector<double>& x) {
  double mean = 0.0, sq = 0.0;
  for (double v : x) mean += v;
  mean /= x.size();
  for (double v : x) sq += (v - mean) * (v - mean);
  return sq / x.size();
}

TEST(TruthMotion, RailJointsAddVerticalImpulses) {
  Scenario s;
  s.alignment = {Straight(1000.0)};
  s.start_m = 12.0;
  s.start_speed_mps = 15.0;
  s.phases = {ForSeconds(20.0)};
  const Alignment alignment(s);
  const TruthMotion welded(s, alignment, 4);
  s.rail_joint_spacing_m = 25.0;
  const TruthMotion jointed(s, alignment, 4);

  // Same seed: the difference is the joint response alone. The first joint is at 25 m, passed
  // after 13 m / 15 m/s = 0.87 s; every 25 m / 15 m/s = 1.67 s after that.
  double max_before = 0.0, max_after = 0.0;
  for (double t = 0.0; t < 20.0; t += 0.002) {
    const double dz =
        std::fabs(jointed.Pose(t).translation().z() - welded.Pose(t).translation().z());
    double& max = t < 0.86 ? max_before : max_after;
    max = std::max(max, dz);
  }
  EXPECT_EQ(max_before, 0.0);
  EXPECT_GT(max_after, 0.001);
  EXPECT_LT(max_after, 0.003);

  // Right after each passage the vertical acceleration is much stronger than the car-body
  // modes alone give in the same windows.
  double sq_jointed = 0.0, sq_welded = 0.0;
  for (double t_joint = 0.87 + 5 * 25.0 / 15.0; t_joint < 19.0; t_joint += 25.0 / 15.0) {
    sq_jointed += Variance(VerticalAccel(jointed, t_joint, t_joint + 0.3));
    sq_welded += Variance(VerticalAccel(welded, t_joint, t_joint + 0.3));
  }
  EXPECT_GT(sq_jointed, 4.0 * sq_welded) << sq_jointed << " vs " << sq_welded;
}

TEST(TruthMotion, StrapdownOfTheTruthImuReproducesThePosesOverRailJoints) {
  // The joint response starts without a vertical velocity step: a step (7 cm/s at 15 m/s) is
  // what a point-sampled IMU misses or reads as a spike of up to 145 m/s^2.
  Scenario s;
  s.alignment = {Straight(1000.0)};
  s.start_m = 12.0;
  s.start_speed_mps = 15.0;
  s.phases = {ForSeconds(20.0)};
  s.rail_joint_spacing_m = 25.0;
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, 5);
  ExpectStrapdownMatchesTruth(truth, 3.0);
  // The vertical specific force stays within what the 6 Hz joint mode can produce
  // (k * 2 mm * w^2 = 2.8 m/s^2) plus the car-body modes (about 2 m/s^2).
  double peak = 0.0;
  for (double t = 1.0; t < 20.0; t += 1.0 / 200.0) {
    Eigen::Vector3d omega, force;
    truth.Inertial(t, kGravity, &omega, &force);
    peak = std::max(peak, std::fabs(force.z() - kGravity));
  }
  EXPECT_LT(peak, 6.0);
}

}  // namespace
}  // namespace raillomer::sim
