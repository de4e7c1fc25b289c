#include "estimator/pipeline/gravity_fit.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <vector>

namespace raillomer {
namespace {

constexpr double kDt = 0.1;  // one state a LiDAR frame

/// A train moving off from rest at 0.5 m/s^2 for 10 s (as long_20km does) in a frame levelled
/// 0.5 mrad off about its y axis: the IMU's world increments R beta_k = v_k - v_{k-1} + g dt,
/// with g the accelerometer's reading at rest in that frame.
struct MovingOff {
  Eigen::Vector3d g =
      Eigen::AngleAxisd(5e-4, Eigen::Vector3d::UnitY()) * Eigen::Vector3d(0, 0, 9.81);
  int states = 101;
  Eigen::Vector3d Velocity(int k) const { return Eigen::Vector3d(0.5 * k * kDt, 0.0, 0.0); }
  Eigen::Vector3d Increment(int k) const { return Velocity(k) - Velocity(k - 1) + g * kDt; }
  /// Feeds states first..last - 1 exactly, as one line.
  void Feed(int first, int last, GravityFit* fit) const {
    fit->Start(Velocity(first));
    for (int k = first + 1; k < last; ++k) fit->Add(kDt, Increment(k), Velocity(k));
  }
};

/// Angle between two gravity vectors (rad).
double Tilt(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

TEST(GravityFit, RecoversGravityExactlyFromExactStates) {
  const MovingOff run;
  GravityFit fit;
  run.Feed(0, run.states, &fit);
  Eigen::Vector3d g;
  ASSERT_TRUE(fit.Gravity(&g));
  EXPECT_LT((g - run.g).norm(), 1e-9);
  EXPECT_NEAR(fit.duration_s(), 10.0, 1e-9);
}

// The first state's velocity straight after the initial levelling was 0.044 m/s off moving
// off on long_20km. Taken between the two ends, that error tilts gravity by 0.044 / (g T) =
// 0.45 mrad; through the fitted line it counts as one state of 101.
TEST(GravityFit, OneStatesVelocityErrorBarelyTiltsIt) {
  const MovingOff run;
  const Eigen::Vector3d error(0.044, 0.0, 0.0);
  GravityFit fit;
  fit.Start(run.Velocity(0) + error);
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (int k = 1; k < run.states; ++k) {
    fit.Add(kDt, run.Increment(k), run.Velocity(k));
    c += run.Increment(k);
  }
  Eigen::Vector3d g;
  ASSERT_TRUE(fit.Gravity(&g));
  const Eigen::Vector3d between_ends =
      (c - (run.Velocity(run.states - 1) - (run.Velocity(0) + error))) / 10.0;
  EXPECT_GT(Tilt(between_ends, run.g), 4e-4);
  EXPECT_LT(Tilt(g, run.g), 0.05e-3);
}

// Every state's velocity off by white noise of 2 cm/s: the fit's tilt stays under 0.1 mrad
// (between the ends the same noise tilts it by 0.3 mrad RMS).
TEST(GravityFit, AveragesTheStatesVelocityNoise) {
  const MovingOff run;
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.02);
  auto noisy = [&](const Eigen::Vector3d& v) {
    return Eigen::Vector3d(v.x() + noise(rng), v.y() + noise(rng), v.z() + noise(rng));
  };
  GravityFit fit;
  fit.Start(noisy(run.Velocity(0)));
  for (int k = 1; k < run.states; ++k) fit.Add(kDt, run.Increment(k), noisy(run.Velocity(k)));
  Eigen::Vector3d g;
  ASSERT_TRUE(fit.Gravity(&g));
  EXPECT_LT(Tilt(g, run.g), 0.1e-3);
}

// A gap in the IMU data breaks the sum of increments: the states after it start a new line
// (its own offset, the same slope), and gravity still comes out exactly. Chained across the
// gap as one line, the 1 m/s the train gained unseen would have tilted it by 20 mrad.
TEST(GravityFit, AGapStartsANewLineWithTheSameSlope) {
  const MovingOff run;
  GravityFit fit;
  run.Feed(0, 40, &fit);
  run.Feed(60, run.states, &fit);  // after 2 s without IMU data
  Eigen::Vector3d g;
  ASSERT_TRUE(fit.Gravity(&g));
  EXPECT_LT((g - run.g).norm(), 1e-9);
  EXPECT_NEAR(fit.duration_s(), 7.9, 1e-9);
}

TEST(GravityFit, NoIntervalNoGravity) {
  GravityFit fit;
  Eigen::Vector3d g;
  EXPECT_FALSE(fit.Gravity(&g));
  fit.Start(Eigen::Vector3d::Zero());
  EXPECT_FALSE(fit.Gravity(&g));
  fit.Start(Eigen::Vector3d::UnitX());
  EXPECT_FALSE(fit.Gravity(&g));
  EXPECT_EQ(fit.duration_s(), 0.0);
}

}  // namespace
}  // namespace raillomer
