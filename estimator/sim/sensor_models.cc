#include "estimator/sim/sensor_models.h"

#include <cmath>

namespace raillomer::sim {

bool EventActive(const Scenario& scenario, Event::Kind kind, double t, const std::string& lidar) {
  for (const Event& e : scenario.events) {
    if (e.kind != kind || t < e.at_s || t >= e.at_s + e.duration_s) continue;
    if (kind == Event::Kind::kLidarBlackout && e.lidar != lidar) continue;
    return true;
  }
  return false;
}

ImuModel::ImuModel(const Scenario& scenario, const TruthMotion& truth, uint32_t seed)
    : scenario_(scenario), truth_(truth), rng_(seed * 6364136223846793005ULL + 11ULL) {
  gyro_bias_ = scenario.gyro_bias_sigma * Gauss3();
  accel_bias_ = scenario.accel_bias_sigma * Gauss3();
}

Eigen::Vector3d ImuModel::Gauss3() { return {gauss_(rng_), gauss_(rng_), gauss_(rng_)}; }

io::ImuSample ImuModel::Sample(double t, int64_t stamp_ns) {
  const double rate = scenario_.imu_rate_hz;
  const double dt = 1.0 / rate;
  Eigen::Vector3d omega, force;
  truth_.Inertial(t, scenario_.gravity_mps2, &omega, &force, dt);
  // Discrete white noise: density * sqrt(rate); bias walk: density * sqrt(dt).
  const double gyro_sigma = scenario_.gyro_noise_density * std::sqrt(rate);
  const double accel_sigma = scenario_.accel_noise_density * std::sqrt(rate);
  io::ImuSample sample;
  sample.stamp_ns = stamp_ns;
  sample.angular_velocity_radps = omega + gyro_bias_ + gyro_sigma * Gauss3();
  sample.linear_acceleration_mps2 = force + accel_bias_ + accel_sigma * Gauss3();
  sample.gyro_noise_var = gyro_sigma * gyro_sigma;
  sample.accel_noise_var = accel_sigma * accel_sigma;
  gyro_bias_ += scenario_.gyro_bias_walk * std::sqrt(dt) * Gauss3();
  accel_bias_ += scenario_.accel_bias_walk * std::sqrt(dt) * Gauss3();
  return sample;
}

OdometerModel::OdometerModel(const Scenario& scenario, const TruthMotion& truth, uint32_t seed)
    : scenario_(scenario),
      truth_(truth),
      rng_(seed * 1442695040888963407ULL + 29ULL),
      true_radius_m_(0.5 * scenario.wheel_diameter_m / (1.0 + scenario.odometer_scale_error)) {}

io::WheelOdometry OdometerModel::Sample(double t, int64_t stamp_ns) {
  // Integrate the wheel's rolling speed in 1 ms steps up to t.
  const double step = 1e-3;
  const double tau = 5.0;
  while (t_ < t) {
    const double h = std::min(step, t - t_);
    const double mid = t_ + 0.5 * h;
    double slip = 0.0;
    for (const Event& e : scenario_.events) {
      if (e.kind != Event::Kind::kWheelSlip) continue;
      // Ramp in and out over 0.5 s.
      const double in = std::clamp((mid - e.at_s) / 0.5, 0.0, 1.0);
      const double out = std::clamp((e.at_s + e.duration_s - mid) / 0.5, 0.0, 1.0);
      slip += e.slip * std::min(in, out);
    }
    const double a = std::exp(-h / tau);
    creep_ = a * creep_ + scenario_.creep_sigma * std::sqrt(1.0 - a * a) * gauss_(rng_);
    const double surface_speed = truth_.Speed(mid) * (1.0 + creep_ + slip);
    angle_rad_ += surface_speed / true_radius_m_ * h;
    t_ += h;
  }
  const double pulse = 2.0 * M_PI / scenario_.pulses_per_rev;
  io::WheelOdometry reading;
  reading.stamp_ns = stamp_ns;
  reading.position_rad = std::floor(angle_rad_ / pulse) * pulse;
  reading.velocity_radps = last_t_ >= 0.0 && t > last_t_
                               ? (reading.position_rad - last_position_rad_) / (t - last_t_)
                               : 0.0;
  last_position_rad_ = reading.position_rad;
  last_t_ = t;
  return reading;
}

GnssModel::GnssModel(const Scenario& scenario,
                     const World& world,
                     const TruthMotion& truth,
                     const geo::UtmZone& zone,
                     const Eigen::Vector3d& origin_utm,
                     uint32_t seed)
    : scenario_(scenario),
      world_(world),
      truth_(truth),
      zone_(zone),
      origin_utm_(origin_utm),
      rng_(seed * 3935559000370003845ULL + 37ULL) {
  const Eigen::Vector3d sigma(scenario.gnss_horizontal_sigma_m,
                              scenario.gnss_horizontal_sigma_m,
                              scenario.gnss_vertical_sigma_m);
  for (int k = 0; k < 3; ++k) correlated_[k] = sigma[k] * gauss_(rng_);
}

bool GnssModel::Sample(double t, int64_t stamp_ns, io::GnssFix* fix) {
  // The Gauss-Markov error runs on through outages. It starts from its stationary spread: a
  // receiver that has been on for a while is already off by that much at the first epoch (a
  // start at zero would hand an estimator an almost exact first fix).
  const double a = last_t_ >= 0.0 ? std::exp(-(t - last_t_) / scenario_.gnss_tau_s) : 0.0;
  last_t_ = t;
  const Eigen::Vector3d sigma(scenario_.gnss_horizontal_sigma_m,
                              scenario_.gnss_horizontal_sigma_m,
                              scenario_.gnss_vertical_sigma_m);
  for (int k = 0; k < 3; ++k) {
    correlated_[k] = a * correlated_[k] + sigma[k] * std::sqrt(1.0 - a * a) * gauss_(rng_);
  }
  if (EventActive(scenario_, Event::Kind::kGnssOutage, t)) return false;
  if (world_.InTunnel(truth_.Chainage(t), 30.0)) return false;

  Eigen::Vector3d error = correlated_;
  const double white = scenario_.gnss_white_sigma_m;
  error += Eigen::Vector3d(white * gauss_(rng_), white * gauss_(rng_), 2.0 * white * gauss_(rng_));
  if (uniform_(rng_) < scenario_.gnss_outlier_probability) {
    // Multipath: a jump of 5-30 m in a random horizontal direction.
    const double magnitude = 5.0 + 25.0 * uniform_(rng_);
    const double heading = 2.0 * M_PI * uniform_(rng_);
    error += Eigen::Vector3d(magnitude * std::cos(heading),
                             magnitude * std::sin(heading),
                             0.5 * magnitude * (uniform_(rng_) - 0.5));
  }
  last_error_ = error;
  const Eigen::Vector3d antenna(
      scenario_.gnss_antenna_m[0], scenario_.gnss_antenna_m[1], scenario_.gnss_antenna_m[2]);
  const Eigen::Vector3d utm = origin_utm_ + truth_.Pose(t) * antenna + error;
  const Eigen::Vector2d latlon = geo::UtmToGeographic(zone_, utm.x(), utm.y());
  fix->stamp_ns = stamp_ns;
  fix->status = 0;
  fix->service = 1 | 2 | 4;  // GPS, GLONASS, BDS
  fix->latitude_deg = latlon.x();
  fix->longitude_deg = latlon.y();
  fix->altitude_m = utm.z();
  const double h = scenario_.gnss_reported_sigma_m;
  fix->position_covariance = {h * h, 0, 0, 0, h * h, 0, 0, 0, 4 * h * h};
  fix->position_covariance_type = 2;
  return true;
}

}  // namespace raillomer::sim
