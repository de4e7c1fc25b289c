#include "estimator/pipeline/inertial_buffer.h"

#include <cmath>
#include <cstdio>
#include <variant>

#include <gtest/gtest.h>

#include "estimator/factors/pose_manifold.h"
#include "estimator/pipeline/config.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

struct SimInertial {
  std::unique_ptr<sim::Simulator> simulator;
  EstimatorConfig config;
  InertialBuffer buffer;
  double t0_abs = 0.0;  ///< absolute time of run time 0
};

/// IMU and odometer of a scenario (no LiDAR), with the IMU biases and the wheel creep switched
/// off so that the true states are known exactly.
SimInertial Simulate(const std::string& name, double duration_s, bool ideal) {
  SimInertial out;
  sim::Scenario scenario;
  std::string error;
  EXPECT_TRUE(sim::LoadScenario(name, &scenario, &error)) << error;
  if (ideal) {
    scenario.gyro_bias_sigma = scenario.gyro_bias_walk = 0.0;
    scenario.accel_bias_sigma = scenario.accel_bias_walk = 0.0;
    scenario.creep_sigma = 0.0;
  }
  sim::SimOptions options;
  options.lidar = false;
  options.duration_s = duration_s;
  out.simulator = sim::Simulator::Create(scenario, options, &error);
  EXPECT_TRUE(out.simulator) << error;
  EXPECT_TRUE(ParseEstimatorConfig(out.simulator->RigYaml(), "rig.yaml", &out.config, &error))
      << error;
  out.t0_abs = static_cast<double>(out.simulator->StampNs(0.0)) * 1e-9;
  io::SensorMessage m;
  while (out.simulator->Next(&m)) {
    if (const auto* imu = std::get_if<io::ImuSample>(&m.data)) {
      out.buffer.AddImu(static_cast<double>(imu->stamp_ns) * 1e-9 - out.t0_abs,
                        imu->angular_velocity_radps,
                        imu->linear_acceleration_mps2);
    } else if (const auto* odo = std::get_if<io::WheelOdometry>(&m.data)) {
      out.buffer.AddOdometer(static_cast<double>(odo->stamp_ns) * 1e-9 - out.t0_abs,
                             odo->position_rad * 0.5 * out.config.rig.wheel_diameter_m);
    }
  }
  return out;
}

NavState TruthState(const sim::TruthMotion& truth, double t, double c) {
  const Eigen::Isometry3d T = truth.Pose(t);
  const double h = 1e-4;
  NavState s;
  s.p = T.translation();
  s.q = Eigen::Quaterniond(T.linear());
  s.v = (truth.Pose(t + h).translation() - truth.Pose(t - h).translation()) / (2.0 * h);
  s.c = c;
  return s;
}

// On the simulator's own IMU and odometer, the preintegration over each 0.1 s frame, evaluated
// at the true states, leaves whitened residuals that are noise: no bias in any row, and no
// component far beyond its modelled spread. A bias here is a modelling error the estimator would
// absorb into its velocity, attitude or odometer scale.
class InertialBufferResiduals : public ::testing::TestWithParam<const char*> {};

TEST_P(InertialBufferResiduals, TruthResidualsAreUnbiasedNoise) {
  SimInertial s = Simulate(GetParam(), 40.0, true);
  const sim::Scenario& sc = s.simulator->scenario();
  const double c_true = 1.0 / (1.0 + sc.odometer_scale_error);
  const sim::TruthMotion& truth = s.simulator->truth();
  Eigen::Matrix<double, 19, 1> sum = Eigen::Matrix<double, 19, 1>::Zero();
  Eigen::Matrix<double, 19, 1> sum_sq = Eigen::Matrix<double, 19, 1>::Zero();
  Eigen::Matrix<double, 19, 1> raw_sum = Eigen::Matrix<double, 19, 1>::Zero();
  Eigen::Matrix<double, 19, 1> raw_sq = Eigen::Matrix<double, 19, 1>::Zero();
  Eigen::Matrix<double, 19, 1> var_sum = Eigen::Matrix<double, 19, 1>::Zero();
  int n = 0;
  for (double t = 3.0; t + 0.1 < 39.0; t += 0.1) {
    const NavState a = TruthState(truth, t, c_true);
    const NavState b = TruthState(truth, t + 0.1, c_true);
    bool odo_ok = false;
    auto pre = s.buffer.Preintegrate(t,
                                     t + 0.1,
                                     a.ba,
                                     a.bg,
                                     a.c,
                                     s.config.rig.p_body_odometer,
                                     s.config.rig.noise,
                                     s.config.rig.gravity_mps2,
                                     true,
                                     &odo_ok);
    ASSERT_TRUE(odo_ok) << "t " << t;
    const Eigen::Matrix<double, 19, 1> r = pre->Evaluate(a, b);
    const Eigen::Matrix<double, 19, 1> w = pre->SqrtInformation() * r;
    sum += w;
    sum_sq += w.cwiseProduct(w);
    raw_sum += r;
    raw_sq += r.cwiseProduct(r);
    var_sum += pre->covariance().diagonal();
    ++n;
  }
  const Eigen::Matrix<double, 19, 1> mean = sum / n;
  const Eigen::Matrix<double, 19, 1> rms = (sum_sq / n).cwiseSqrt();
  for (int k = 0; k < 19; ++k) {
    std::printf("%s row %2d: whitened mean %+.3f rms %.3f, raw mean %+.3e rms %.3e sigma %.3e\n",
                GetParam(),
                k,
                mean(k),
                rms(k),
                raw_sum(k) / n,
                std::sqrt(raw_sq(k) / n),
                std::sqrt(var_sum(k) / n));
    // Rows 9-14 and 18 (bias and scale walks) are exactly zero at the truth here.
    EXPECT_LT(std::abs(mean(k)), 0.25) << "row " << k;
    EXPECT_LT(rms(k), 1.5) << "row " << k;
  }
}

INSTANTIATE_TEST_SUITE_P(Scenarios,
                         InertialBufferResiduals,
                         ::testing::Values("poor_low_open_a", "rich_high_town_a"));

// The initial levelling: roll and pitch from the first seconds of IMU and odometer data match
// the truth, also when the run starts at 140 km/h with the car body swaying; so does the
// initial velocity fitted with them.
TEST(InertialBufferSim, UpInBodyLevelsAtSpeed) {
  for (const char* name : {"poor_low_open_a", "poor_high_open_a", "rich_high_town_a"}) {
    SimInertial s = Simulate(name, 12.0, false);
    const sim::TruthMotion& truth = s.simulator->truth();
    const double span = EstimatorOptions().init_gravity_s;  // the default levelling span
    double worst_roll = 0.0, worst_pitch = 0.0, worst_speed = 0.0, worst_across = 0.0;
    for (double t1 = span + 0.2; t1 < 11.5; t1 += 0.7) {
      Eigen::Vector3d up, v;
      ASSERT_TRUE(s.buffer.UpInBody(t1 - span, t1, s.config.rig.gravity_mps2, &up, &v));
      const Eigen::Isometry3d T1 = truth.Pose(t1);
      const Eigen::Vector3d up_true = T1.linear().transpose() * Eigen::Vector3d::UnitZ();
      // Roll error about x, pitch error about y (small angles).
      worst_roll = std::max(worst_roll, std::abs(up.y() - up_true.y()));
      worst_pitch = std::max(worst_pitch, std::abs(up.x() - up_true.x()));
      const Eigen::Vector3d v_true =
          T1.linear().transpose() *
          (truth.Pose(t1 + 1e-4).translation() - truth.Pose(t1 - 1e-4).translation()) / 2e-4;
      worst_speed = std::max(worst_speed, std::abs(v.x() - v_true.x()) / (v_true.norm() + 1.0));
      worst_across = std::max(worst_across, v.tail<2>().norm());
    }
    std::printf(
        "%-18s span %.0f s: worst roll error %.3f deg, pitch %.3f deg, speed %.2f %%, "
        "across %.3f m/s\n",
        name,
        span,
        worst_roll * 180 / M_PI,
        worst_pitch * 180 / M_PI,
        100.0 * worst_speed,
        worst_across);
    // The wheel reads 0.4 % long (the simulated wear) and creeps by 0.5 % of the speed.
    EXPECT_LT(worst_speed, 0.015) << name;
    EXPECT_LT(worst_across, 0.1) << name;
    // Roll decides the heading at speed (lateral gravity reads as a turn): hundredths of a
    // degree. Pitch is limited by the wheel's creep (0.5 % of speed, varying over seconds).
    EXPECT_LT(worst_roll * 180 / M_PI, 0.05) << name;
    EXPECT_LT(worst_pitch * 180 / M_PI, 0.6) << name;
  }
}

// The sway is the gyro's angles high-passed. A cant transition's steady roll (0.03 rad/s for
// 8 s) leaves the roll's change over a frame within a few time constants, and a vertical curve's
// steady pitch rate leaves the pitch itself; the body's 1 Hz rotation on its suspension passes,
// the roll's change nearly whole. Without a time constant there is none.
TEST(InertialBufferSway, SplitsTheBodysSwayFromTheTracksTurns) {
  const double tau = 1.0, dt = 0.005, frame = 0.1, amplitude = 0.002;
  auto rate = [&](double t, bool track) {
    if (track) return t > 1.0 && t < 9.0 ? 0.03 : 0.0;
    return amplitude * 2.0 * M_PI * std::cos(2.0 * M_PI * t);
  };
  for (const bool track : {true, false}) {
    InertialBuffer buffer, off;
    buffer.sway_time_constant_s = tau;
    for (int k = 0; k <= static_cast<int>(10.0 / dt); ++k) {
      const double t = k * dt;
      const Eigen::Vector3d gyro(rate(t, track), rate(t, track), 0.0), accel(0.0, 0.0, 9.81);
      buffer.AddImu(t, gyro, accel);
      off.AddImu(t, gyro, accel);
    }
    double roll_error = 0.0, roll_peak = 0.0, pitch_error = 0.0;
    for (double t0 = 6.5; t0 + frame <= 8.9; t0 += frame) {
      const InertialBuffer::Sway a = buffer.SwayAt(t0), b = buffer.SwayAt(t0 + frame);
      EXPECT_EQ(off.SwayAt(t0).roll, 0.0);
      EXPECT_EQ(off.SwayAt(t0).pitch, 0.0);
      // The rotation over the frame, by the trapezoid rule on a fine grid.
      double turn = 0.0;
      for (int k = 0; k < 100; ++k) {
        const double u = t0 + frame * k / 100.0, v = t0 + frame * (k + 1) / 100.0;
        turn += 0.5 * (rate(u, track) + rate(v, track)) * (v - u);
      }
      // What is sway: nothing of the track's turn; all of the suspension's.
      const double roll_sway = track ? 0.0 : turn;
      const double pitch_sway = track ? 0.0 : amplitude * std::sin(2.0 * M_PI * t0);
      roll_error = std::max(roll_error, std::fabs(b.roll - a.roll - roll_sway));
      roll_peak = std::max(roll_peak, std::fabs(turn));
      pitch_error = std::max(pitch_error, std::fabs(a.pitch - pitch_sway));
    }
    if (track) {
      EXPECT_LT(roll_error, 0.01 * roll_peak) << "cant taken as sway";
      // Once high-passed, the pitch would hold 0.03 rad/s * tau = 0.03 rad.
      EXPECT_LT(pitch_error, 1e-3) << "vertical curve taken as sway";
    } else {
      // A first-order high-pass misses 1 / |1 + i w tau| = 16 % of a 1 Hz rotation; twice
      // high-passed, 31 %, mostly its phase.
      EXPECT_LT(roll_error, 0.2 * roll_peak) << "sway roll missed";
      EXPECT_LT(pitch_error, 0.35 * amplitude) << "sway pitch missed";
    }
  }
}

// A grade change (6 mrad over 2 s, 0 to -6 permille at 110 km/h) is the track's, not the body's
// sway. Twice high-passed, it swings the pitch past zero for a few time constants; at the
// default time constant that swing must have died out 2 s after the grade is reached. At the
// former 2 s it had not: the wheels' path stayed tilted against the body, and two submaps saw
// the same rail heads 3 cm apart (rich_high_mixed_b).
TEST(InertialBufferSway, AGradeChangeLeavesThePitchSwaySoon) {
  // The largest |sway pitch| from 2 s after the grade change on.
  const auto late_sway = [](double tau) {
    InertialBuffer buffer;
    buffer.sway_time_constant_s = tau;
    const double dt = 0.005;
    double late = 0.0;
    for (int k = 0; k <= static_cast<int>(20.0 / dt); ++k) {
      const double t = k * dt;
      const double pitch_rate = t > 1.0 && t < 3.0 ? -0.003 : 0.0;
      buffer.AddImu(t, Eigen::Vector3d(0.0, pitch_rate, 0.0), Eigen::Vector3d(0.0, 0.0, 9.81));
      if (t >= 5.0) late = std::max(late, std::fabs(buffer.SwayAt(t).pitch));
    }
    return late;
  };
  EXPECT_LT(late_sway(EstimatorOptions().odometer_sway_time_constant_s), 2e-4)
      << "the grade change still taken as sway 2 s after it";
  EXPECT_GT(late_sway(2.0), 5e-4) << "the former time constant should fail the bound";
}

}  // namespace
}  // namespace raillomer
