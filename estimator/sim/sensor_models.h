#pragma once

#include <cstdint>
#include <random>

#include <Eigen/Core>

#include "estimator/geo/utm.h"
#include "estimator/io/sensor_messages.h"
#include "estimator/sim/motion.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/world.h"

namespace raillomer::sim {

/// Whether an event of `kind` (and, for LiDARs, of unit `lidar`) is active at run time t.
bool EventActive(const Scenario& scenario,
                 Event::Kind kind,
                 double t,
                 const std::string& lidar = {});

/// MTi-680G-class IMU: white noise plus turn-on bias and bias random walk.
class ImuModel {
 public:
  ImuModel(const Scenario& scenario, const TruthMotion& truth, uint32_t seed);
  /// The sample at run time t (call with increasing t, once per IMU period).
  io::ImuSample Sample(double t, int64_t stamp_ns);
  const Eigen::Vector3d& gyro_bias() const { return gyro_bias_; }
  const Eigen::Vector3d& accel_bias() const { return accel_bias_; }

 private:
  Eigen::Vector3d Gauss3();
  const Scenario& scenario_;
  const TruthMotion& truth_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> gauss_{0.0, 1.0};
  Eigen::Vector3d gyro_bias_, accel_bias_;
};

/// Phonic-wheel odometer: whole pulses, wheel-wear scale error, creep and slip events.
class OdometerModel {
 public:
  OdometerModel(const Scenario& scenario, const TruthMotion& truth, uint32_t seed);
  /// The reading at run time t (call with increasing t).
  io::WheelOdometry Sample(double t, int64_t stamp_ns);

 private:
  const Scenario& scenario_;
  const TruthMotion& truth_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> gauss_{0.0, 1.0};
  double true_radius_m_;  ///< the wheel truly rolls on nominal / (1 + scale error)
  double t_ = 0.0;
  double angle_rad_ = 0.0;  ///< true cumulative wheel angle
  double creep_ = 0.0;
  double last_position_rad_ = 0.0;
  double last_t_ = -1.0;
};

/// Single point positioning receiver: time-correlated error, outliers, outages, and a reported
/// covariance that is too optimistic.
class GnssModel {
 public:
  GnssModel(const Scenario& scenario,
            const World& world,
            const TruthMotion& truth,
            const geo::UtmZone& zone,
            const Eigen::Vector3d& origin_utm,
            uint32_t seed);
  /// The fix at run time t, or false when there is none (outage, tunnel). Call once per epoch.
  bool Sample(double t, int64_t stamp_ns, io::GnssFix* fix);
  /// Error of the last fix (UTM east, north, up), for tests.
  const Eigen::Vector3d& last_error() const { return last_error_; }

 private:
  const Scenario& scenario_;
  const World& world_;
  const TruthMotion& truth_;
  geo::UtmZone zone_;
  Eigen::Vector3d origin_utm_;
  std::mt19937_64 rng_;
  std::normal_distribution<double> gauss_{0.0, 1.0};
  std::uniform_real_distribution<double> uniform_{0.0, 1.0};
  Eigen::Vector3d correlated_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d last_error_ = Eigen::Vector3d::Zero();
  double last_t_ = -1.0;
};

}  // namespace raillomer::sim
