// The sliding window over long runs of noise-free IMU data and encoder-like odometer data on a
// straight, level track: what the data leave unobserved must stay where the priors put it, and
// what they observe must settle at the truth and stay there.

#include <cmath>
#include <memory>

#include <ceres/ceres.h>
#include <gtest/gtest.h>

#include "estimator/backend/sliding_window.h"
#include "estimator/factors/preintegration.h"
#include "estimator/pipeline/inertial_buffer.h"

namespace raillomer {
namespace {

constexpr double kGravity = 9.81;
constexpr double kImuDt = 0.005;
constexpr double kOdometerDt = 0.02;
constexpr double kFrameDt = 0.1;
constexpr double kTrueScale = 0.996;  // the wheel rolls 0.4 % short of its nominal size
/// 100 pulses on a 0.84 m wheel.
const double kPulse = M_PI * 0.84 / 100.0;

/// Speed profile: `speed0` m/s, accelerating at `accel` m/s^2 for the first `accel_s` seconds.
struct Profile {
  double speed0 = 44.44;
  double accel = 0.0;
  double accel_s = 0.0;
  double Speed(double t) const { return speed0 + accel * std::min(t, accel_s); }
  double Distance(double t) const {
    const double ta = std::min(t, accel_s);
    return speed0 * t + 0.5 * accel * ta * ta + accel * accel_s * std::max(0.0, t - accel_s);
  }
  double Accel(double t) const { return t < accel_s ? accel : 0.0; }
};

struct RunResult {
  double first_c = 0.0, last_c = 0.0;  ///< newest state once the window is full / at the end
  double first_speed = 0.0, last_speed = 0.0;
  double last_true_speed = 0.0;
  double last_slope = 0.0;       ///< z of the newest body's x axis at the end
  double last_accel_bias = 0.0;  ///< its accelerometer bias along x
};

/// A LiDAR that pulls the body's nose towards slope `slope` (the z of its x axis), as a
/// registration against a map that bends with the trajectory does, a little at every frame.
struct PitchPull {
  PitchPull(double slope, double sigma) : slope_(slope), sigma_(sigma) {}
  template <typename T>
  bool operator()(const T* pose, T* residual) const {
    // pose: x y z, then the quaternion's x y z w; the z of R e_x is 2 (xz - wy).
    const T& qx = pose[3];
    const T& qy = pose[4];
    const T& qz = pose[5];
    const T& qw = pose[6];
    residual[0] = (T(2.0) * (qx * qz - qw * qy) - T(slope_)) / T(sigma_);
    return true;
  }
  double slope_, sigma_;
};

/// What a run does beyond feeding the sensors.
struct Extras {
  SlidingWindowOptions options;
  bool relevel = false;     ///< re-level the world (by nothing) after the first state
  double pull_slope = 0.0;  ///< with pull_sigma > 0: a PitchPull on every new state
  double pull_sigma = 0.0;
};

/// Runs `frames` frames through a window of `size` states. The first state starts at scale
/// `c0` with the speed the odometer gives at that scale. The odometer is an encoder read at
/// 50 Hz, its distance floored to whole pulses when `quantise`.
RunResult RunWindow(const Profile& profile,
                    int frames,
                    int size,
                    double c0,
                    bool quantise,
                    const Extras& extras = {}) {
  PreintegrationNoise noise;
  noise.odometer_resolution_m = quantise ? kPulse : 0.0;
  SlidingWindowOptions options = extras.options;
  options.size = size;
  SlidingWindow window(options);
  InertialBuffer buffer;
  int imu_index = 0, odometer_index = 0;
  auto feed_until = [&](double t_end) {
    for (; imu_index * kImuDt <= t_end + 1e-9; ++imu_index) {
      const double t = imu_index * kImuDt;
      buffer.AddImu(t, Eigen::Vector3d::Zero(), Eigen::Vector3d(profile.Accel(t), 0.0, kGravity));
    }
    for (; odometer_index * kOdometerDt <= t_end + kOdometerDt + 1e-9; ++odometer_index) {
      const double t = odometer_index * kOdometerDt;
      const double d = profile.Distance(t) / kTrueScale;
      buffer.AddOdometer(t, quantise ? std::floor(d / kPulse) * kPulse : d);
    }
  };

  NavState state;
  state.c = c0;
  state.v = Eigen::Vector3d(c0 * profile.Speed(0.0) / kTrueScale, 0.0, 0.0);
  window.Push(0.0, state, nullptr);
  window.Optimize();
  if (extras.relevel) window.RotateWorld(Eigen::Matrix3d::Identity());
  RunResult result;
  for (int f = 1; f <= frames; ++f) {
    const NavState newest = window.Newest();
    feed_until(f * kFrameDt);
    bool odometer_ok = false;
    auto pre = buffer.Preintegrate((f - 1) * kFrameDt,
                                   f * kFrameDt,
                                   newest.ba,
                                   newest.bg,
                                   newest.c,
                                   Eigen::Vector3d::Zero(),
                                   noise,
                                   kGravity,
                                   true,
                                   &odometer_ok);
    EXPECT_TRUE(odometer_ok);
    window.Push(f * kFrameDt, pre->Predict(newest), pre);
    if (extras.pull_sigma > 0.0) {
      window.AddNewestUnaryFactor(std::make_shared<ceres::AutoDiffCostFunction<PitchPull, 1, 7>>(
          new PitchPull(extras.pull_slope, extras.pull_sigma)));
    }
    window.Optimize();
    if (window.Full()) window.PopOldest(nullptr);
    if (f == size + 1) {
      result.first_c = window.Newest().c;
      result.first_speed = window.Newest().v.norm();
    }
  }
  result.last_c = window.Newest().c;
  result.last_speed = window.Newest().v.norm();
  result.last_true_speed = profile.Speed(frames * kFrameDt);
  result.last_slope = (window.Newest().q * Eigen::Vector3d::UnitX()).z();
  result.last_accel_bias = window.Newest().ba.x();
  return result;
}

// At constant speed the IMU cannot tell the odometer's scale: (c, v) may move together along
// v = c * odometer speed without changing any residual. The window must keep the scale where
// the prior put it (1.0 here, the truth being 0.996) over 40 s.
TEST(SlidingWindow, UnobservedScaleStaysPut) {
  const RunResult r = RunWindow(Profile{}, 400, 6, 1.0, false);
  EXPECT_NEAR(r.last_c, r.first_c, 1e-4);
  EXPECT_NEAR(r.last_speed, r.first_speed, 5e-3);
}

// The same with the encoder's 2.6 cm pulses: a bounded error on the distance. Were the
// odometer's noise taken in metres, its cost would fall as c^2 and the solver would shrink the
// scale a little at every step (by 1.4 % over these 40 s before the odometer row was taken in
// odometer units).
TEST(SlidingWindow, UnobservedScaleStaysPutWithPulseQuantisation) {
  const RunResult r = RunWindow(Profile{}, 400, 6, 1.0, true);
  EXPECT_NEAR(r.last_c, r.first_c, 1e-3);
  EXPECT_NEAR(r.last_speed, r.first_speed, 5e-2);
}

// Accelerating, the IMU measures the speed change the odometer counts in pulses: the scale is
// observed, settles at the truth and stays there through 30 s of constant speed.
TEST(SlidingWindow, ObservedScaleSettlesAtTheTruth) {
  Profile profile;
  profile.speed0 = 10.0;
  profile.accel = 0.8;
  profile.accel_s = 10.0;
  const RunResult r = RunWindow(profile, 400, 6, 1.0, true);
  EXPECT_NEAR(r.last_c, kTrueScale, 1e-3);
  EXPECT_NEAR(r.last_speed, r.last_true_speed, 0.05);
}

// After gravity has re-levelled the world frame the accelerometer bias is known to be small
// (the levelling took it as zero), so gravity, not the bias, must answer a LiDAR that tilts
// the pitch: 60 s at 30 m/s on level track, every frame pulled towards a 5 mrad nose-up slope,
// the slope stays at 1.0 mrad. With the bias as loose as before the levelling (0.03 m/s^2) it
// takes up 0.038 m/s^2 of gravity and the slope goes to 3.9 mrad.
TEST(SlidingWindow, AfterRelevellingGravityHoldsThePitchAgainstAPull) {
  Profile profile;
  profile.speed0 = 30.0;
  Extras extras;
  extras.relevel = true;
  extras.pull_slope = 0.005;
  extras.pull_sigma = 0.02;
  const RunResult held = RunWindow(profile, 600, 6, kTrueScale, false, extras);
  EXPECT_LT(std::abs(held.last_slope), 1.5e-3) << "bias " << held.last_accel_bias;
  extras.options.relevelled_accel_bias_sigma = 3.0e-2;
  const RunResult loose = RunWindow(profile, 600, 6, kTrueScale, false, extras);
  EXPECT_GT(std::abs(loose.last_slope), 2.5e-3) << "bias " << loose.last_accel_bias;
}

// A frame levelled far off (a start at speed) bends the gyro's roll and pitch biases towards
// the tilt the odometer asks for (on poor_high_open_a -2.9e-5 rad/s in pitch against a true
// +2.2e-5). Re-levelling with forget_tilt_gyro_bias zeroes those two and keeps the heading's,
// and the fresh prior holds them at zero: the next solve, with nothing else to say, leaves them
// there. Without it every bias is kept.
TEST(SlidingWindow, RelevellingCanForgetTheTiltGyroBiases) {
  for (const bool forget : {true, false}) {
    SlidingWindow window(SlidingWindowOptions{});
    NavState state;
    state.v = Eigen::Vector3d(30.0, 0.0, 0.0);
    state.bg = Eigen::Vector3d(4e-5, -3e-5, 2e-5);
    window.Push(0.0, state, nullptr);
    window.Optimize();
    window.RotateWorld(Eigen::Matrix3d::Identity(), forget);
    window.Optimize();
    const Eigen::Vector3d bg = window.Newest().bg;
    const Eigen::Vector3d expected = forget ? Eigen::Vector3d(0.0, 0.0, 2e-5) : state.bg;
    EXPECT_LT((bg - expected).norm(), 1e-9) << "forget " << forget << ": " << bg.transpose();
  }
}

}  // namespace
}  // namespace raillomer
