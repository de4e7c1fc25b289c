// The IMU, odometer and GNSS models against their specifications: noise levels, whole pulses,
// wheel-wear scale error, slip, time-correlated GNSS error with outliers, and outages.

#include "estimator/sim/sensor_models.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/geo/utm.h"
#include "estimator/sim/simulator.h"
#include "tests/estimator/sim/scenario_builders.h"

namespace raillomer::sim {
namespace {

using test::ForMetres;
using test::ForSeconds;
using test::Straight;
using test::ToSpeed;

/// A train standing on a 1 km straight for `seconds`, in an empty corridor (cheap to build).
Scenario Standstill(double seconds) {
  Scenario s;
  s.alignment = {Straight(1000.0)};
  s.start_m = 100.0;
  s.phases = {ForSeconds(seconds)};
  s.catenary = false;
  s.trees.per_km = 0.0;
  s.bushes.per_km = 0.0;
  s.buildings.per_km = 0.0;
  s.signal_spacing_m = 0.0;
  s.km_posts = false;
  return s;
}

/// A train cruising at 20 m/s for 40 s on a 1.1 km straight.
Scenario Cruising() {
  Scenario s = Standstill(0.0);
  s.start_speed_mps = 20.0;
  s.phases = {ForSeconds(40.0)};
  s.alignment = {Straight(1100.0)};
  return s;
}

struct Stats {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  Eigen::Vector3d std = Eigen::Vector3d::Zero();
};

Stats Statistics(const std::vector<Eigen::Vector3d>& samples) {
  Stats stats;
  for (const Eigen::Vector3d& x : samples) stats.mean += x;
  stats.mean /= samples.size();
  for (const Eigen::Vector3d& x : samples) {
    stats.std += (x - stats.mean).cwiseAbs2();
  }
  stats.std = (stats.std / (samples.size() - 1)).cwiseSqrt();
  return stats;
}

TEST(EventActive, HalfOpenIntervalsPerKindAndUnit) {
  Scenario s;
  Event outage;
  outage.kind = Event::Kind::kGnssOutage;
  outage.at_s = 10.0;
  outage.duration_s = 5.0;
  Event blackout;
  blackout.kind = Event::Kind::kLidarBlackout;
  blackout.at_s = 0.0;
  blackout.duration_s = 1.0;
  blackout.lidar = "down";
  s.events = {outage, blackout};
  EXPECT_FALSE(EventActive(s, Event::Kind::kGnssOutage, 9.999));
  EXPECT_TRUE(EventActive(s, Event::Kind::kGnssOutage, 10.0));
  EXPECT_TRUE(EventActive(s, Event::Kind::kGnssOutage, 14.999));
  EXPECT_FALSE(EventActive(s, Event::Kind::kGnssOutage, 15.0));
  EXPECT_FALSE(EventActive(s, Event::Kind::kImuDropout, 12.0));
  EXPECT_TRUE(EventActive(s, Event::Kind::kLidarBlackout, 0.5, "down"));
  EXPECT_FALSE(EventActive(s, Event::Kind::kLidarBlackout, 0.5, "up"));
}

TEST(ImuModel, NoiseDensityAndBiasAtStandstill) {
  for (double rate : {100.0, 400.0}) {
    SCOPED_TRACE(rate);
    Scenario s = Standstill(100.0);
    s.imu_rate_hz = rate;
    s.gyro_bias_sigma = 0.01;  // large turn-on biases, so the mean test can see them
    s.accel_bias_sigma = 0.05;
    const Alignment alignment(s);
    const TruthMotion truth(s, alignment, 1);
    ImuModel imu(s, truth, 1);
    const Eigen::Vector3d gyro_bias0 = imu.gyro_bias(), accel_bias0 = imu.accel_bias();
    EXPECT_GT(gyro_bias0.norm(), 1e-3);
    EXPECT_GT(accel_bias0.norm(), 5e-3);
    std::vector<Eigen::Vector3d> gyro, accel;
    Eigen::Vector3d gyro_bias_sum = Eigen::Vector3d::Zero(), accel_bias_sum = gyro_bias_sum;
    const int n = static_cast<int>(100.0 * rate);
    const double gyro_sigma = s.gyro_noise_density * std::sqrt(rate);
    const double accel_sigma = s.accel_noise_density * std::sqrt(rate);
    for (int k = 0; k < n; ++k) {
      gyro_bias_sum += imu.gyro_bias();
      accel_bias_sum += imu.accel_bias();
      const io::ImuSample sample = imu.Sample(k / rate, 1000 + k);
      ASSERT_EQ(sample.stamp_ns, 1000 + k);
      ASSERT_DOUBLE_EQ(sample.gyro_noise_var, gyro_sigma * gyro_sigma);
      ASSERT_DOUBLE_EQ(sample.accel_noise_var, accel_sigma * accel_sigma);
      gyro.push_back(sample.angular_velocity_radps);
      accel.push_back(sample.linear_acceleration_mps2);
    }
    const Stats g = Statistics(gyro), a = Statistics(accel);
    for (int i = 0; i < 3; ++i) {
      EXPECT_NEAR(g.std[i], gyro_sigma, 0.1 * gyro_sigma) << "gyro axis " << i;
      EXPECT_NEAR(a.std[i], accel_sigma, 0.1 * accel_sigma) << "accel axis " << i;
    }
    // Mean = truth + bias (averaged over its slow walk), within 4 standard errors.
    const Eigen::Vector3d accel_expected =
        Eigen::Vector3d(0, 0, s.gravity_mps2) + accel_bias_sum / n;
    const Eigen::Vector3d gyro_expected = gyro_bias_sum / n;
    for (int i = 0; i < 3; ++i) {
      EXPECT_NEAR(a.mean[i], accel_expected[i], 4.0 * accel_sigma / std::sqrt(n)) << i;
      EXPECT_NEAR(g.mean[i], gyro_expected[i], 4.0 * gyro_sigma / std::sqrt(n)) << i;
    }
    // The bias walks only slowly: 100 s of walk is far below the turn-on bias.
    EXPECT_LT((imu.accel_bias() - accel_bias0).norm(), 10.0 * s.accel_bias_walk * 10.0);
    EXPECT_LT((imu.gyro_bias() - gyro_bias0).norm(), 10.0 * s.gyro_bias_walk * 10.0);
  }
}

TEST(ImuModel, TheSimulatorRecordsTheBiasesItAppliesAtTenHertz) {
  // Large turn-on biases and a fast walk, so the track's values and their drift are plain.
  Scenario s = Standstill(3.0);
  s.gyro_bias_sigma = 0.01;
  s.accel_bias_sigma = 0.05;
  s.gyro_bias_walk = 1e-3;
  s.accel_bias_walk = 1e-2;
  SimOptions options;
  options.lidar = false;
  std::string error;
  std::unique_ptr<Simulator> sim = Simulator::Create(s, options, &error);
  ASSERT_TRUE(sim) << error;
  std::vector<io::ImuSample> samples;
  io::SensorMessage message;
  while (sim->Next(&message)) {
    if (const auto* imu = std::get_if<io::ImuSample>(&message.data)) samples.push_back(*imu);
  }
  const std::vector<ImuBiasSample>& track = sim->imu_bias_track();
  ASSERT_EQ(track.size(), 31u);  // 0, 0.1, ..., 3.0 s
  for (size_t k = 0; k < track.size(); ++k) {
    EXPECT_EQ(track[k].stamp_ns, sim->StampNs(0.1 * static_cast<double>(k))) << k;
  }
  // The first entry is the model's turn-on bias (the same seed gives the same model).
  const ImuModel fresh(sim->scenario(), sim->truth(), sim->scenario().seed);
  EXPECT_EQ(track.front().gyro, fresh.gyro_bias());
  EXPECT_EQ(track.front().accel, fresh.accel_bias());
  // The track walks, and it is what the samples carry: at standstill each tenth of a second's
  // 20 gyro samples average to the recorded bias, within 4 standard errors of the white noise.
  EXPECT_GT((track.back().gyro - track.front().gyro).norm(), 1e-4);
  const double gyro_sigma = s.gyro_noise_density * std::sqrt(s.imu_rate_hz);
  const int per_tenth = static_cast<int>(s.imu_rate_hz / 10.0);
  for (size_t k = 0; k + 1 < track.size(); ++k) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (int i = 0; i < per_tenth; ++i) mean += samples[k * per_tenth + i].angular_velocity_radps;
    mean /= per_tenth;
    EXPECT_LT((mean - track[k].gyro).cwiseAbs().maxCoeff(), 4.0 * gyro_sigma / std::sqrt(per_tenth))
        << "tenth " << k;
  }
  // The CSV: the estimator's timing.csv names, one row per entry, the values as recorded.
  const std::string csv = sim->ImuBiasCsv();
  EXPECT_EQ(csv.rfind("stamp_s,gyro_bias_x,gyro_bias_y,gyro_bias_z,accel_bias_x,accel_bias_y,"
                      "accel_bias_z\n",
                      0),
            0u);
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 32);
  const size_t second_line = csv.find('\n') + 1;
  double stamp = 0.0, gx = 0.0;
  ASSERT_EQ(std::sscanf(csv.c_str() + second_line, "%lf,%lf", &stamp, &gx), 2);
  EXPECT_NEAR(stamp, track.front().stamp_ns * 1e-9, 1e-6);
  EXPECT_NEAR(gx, track.front().gyro.x(), 1e-6 * std::abs(gx));
}

struct OdometerReading {
  double t;
  io::WheelOdometry odo;
};

std::vector<OdometerReading> RunOdometer(const Scenario& s, double duration_s) {
  const Alignment alignment(s);
  const TruthMotion truth(s, alignment, s.seed);
  OdometerModel odometer(s, truth, s.seed);
  std::vector<OdometerReading> out;
  const int n = static_cast<int>(std::lround(duration_s * s.odometer_rate_hz));
  for (int k = 0; k <= n; ++k) {
    const double t = k / s.odometer_rate_hz;
    out.push_back({t, odometer.Sample(t, k)});
  }
  return out;
}

/// Wheel surface speed implied by the readings between t0 and t1 with the nominal diameter.
double ApparentSpeed(const Scenario& s,
                     const std::vector<OdometerReading>& readings,
                     double t0,
                     double t1) {
  const size_t i0 = static_cast<size_t>(std::lround(t0 * s.odometer_rate_hz));
  const size_t i1 = static_cast<size_t>(std::lround(t1 * s.odometer_rate_hz));
  const double radians = readings[i1].odo.position_rad - readings[i0].odo.position_rad;
  return radians * 0.5 * s.wheel_diameter_m / (readings[i1].t - readings[i0].t);
}

TEST(OdometerModel, WholePulsesAndScaleError) {
  Scenario s = Standstill(0.0);
  // 0 -> 20 m/s at 1 m/s^2 (200 m), then 300 m: 500 m in 35 s.
  s.phases = {ToSpeed(20.0, 1.0), ForMetres(300.0)};
  s.creep_sigma = 0.0;
  s.odometer_scale_error = 0.03;
  s.pulses_per_rev = 100;
  const double pulse = 2.0 * M_PI / s.pulses_per_rev;
  const std::vector<OdometerReading> readings = RunOdometer(s, 35.0);
  double previous = 0.0;
  for (const OdometerReading& r : readings) {
    const double pulses = r.odo.position_rad / pulse;
    ASSERT_NEAR(pulses, std::round(pulses), 1e-9) << "t " << r.t;
    ASSERT_GE(r.odo.position_rad, previous) << "t " << r.t;
    previous = r.odo.position_rad;
  }
  const double nominal_radius = 0.5 * s.wheel_diameter_m;
  const double implied_m = readings.back().odo.position_rad * nominal_radius;
  const double expected_m = 500.0 * (1.0 + s.odometer_scale_error);
  EXPECT_NEAR(implied_m, expected_m, 0.002 * expected_m);
  // In fact to within one pulse (2.6 cm of rim).
  EXPECT_NEAR(implied_m, expected_m, pulse * nominal_radius + 1e-6);

  // The reported rate is the pulse count over the sample interval.
  const OdometerReading& a = readings[readings.size() - 11];
  const OdometerReading& b = readings[readings.size() - 10];
  EXPECT_NEAR(b.odo.velocity_radps, (b.odo.position_rad - a.odo.position_rad) / (b.t - a.t), 1e-9);
  EXPECT_NEAR(ApparentSpeed(s, readings, 25.0, 35.0), 20.0 * 1.03, 0.01);

  // A coarse encoder: still whole pulses.
  s.pulses_per_rev = 7;
  for (const OdometerReading& r : RunOdometer(s, 5.0)) {
    const double pulses = r.odo.position_rad / (2.0 * M_PI / 7.0);
    ASSERT_NEAR(pulses, std::round(pulses), 1e-9);
  }
}

TEST(OdometerModel, WheelSlipRaisesTheApparentSpeed) {
  Scenario s = Cruising();
  s.creep_sigma = 0.0;
  s.odometer_scale_error = 0.004;
  Event spin;
  spin.kind = Event::Kind::kWheelSlip;
  spin.at_s = 10.0;
  spin.duration_s = 10.0;
  spin.slip = 0.25;
  Event slide = spin;
  slide.at_s = 25.0;
  slide.duration_s = 8.0;
  slide.slip = -0.3;
  s.events = {spin, slide};
  const std::vector<OdometerReading> readings = RunOdometer(s, 40.0);
  const double base = 20.0 * (1.0 + s.odometer_scale_error);
  EXPECT_NEAR(ApparentSpeed(s, readings, 2.0, 9.5), base, 0.005 * base);
  EXPECT_NEAR(ApparentSpeed(s, readings, 10.6, 19.4), base * 1.25, 0.01 * base);
  EXPECT_NEAR(ApparentSpeed(s, readings, 20.5, 24.5), base, 0.01 * base);
  EXPECT_NEAR(ApparentSpeed(s, readings, 25.6, 32.4), base * 0.7, 0.01 * base);
  EXPECT_NEAR(ApparentSpeed(s, readings, 33.5, 40.0), base, 0.01 * base);
  // The slip ramps in over 0.5 s: half of it 0.25 s in.
  EXPECT_GT(ApparentSpeed(s, readings, 10.0, 10.5), base * 1.05);
  EXPECT_LT(ApparentSpeed(s, readings, 10.0, 10.5), base * 1.2);
}

TEST(OdometerModel, CreepIsSlowAndSmall) {
  Scenario s = Cruising();
  s.creep_sigma = 0.02;
  s.odometer_scale_error = 0.0;
  const std::vector<OdometerReading> readings = RunOdometer(s, 40.0);
  double max_deviation = 0.0;
  for (double t = 0.0; t + 2.0 <= 40.0; t += 2.0) {
    max_deviation =
        std::max(max_deviation, std::fabs(ApparentSpeed(s, readings, t, t + 2.0) - 20.0));
  }
  EXPECT_GT(max_deviation, 0.02);  // creep is there
  EXPECT_LT(max_deviation, 20.0 * 5.0 * s.creep_sigma);
}

/// A GNSS receiver on a standing train, sampled at 1 Hz, with its errors.
struct GnssRun {
  std::vector<Eigen::Vector3d> errors;
  std::vector<io::GnssFix> fixes;
  std::vector<double> times;
  double max_roundtrip_m = 0.0;  ///< lat/lon back to UTM vs truth antenna + error
  double max_altitude_m = 0.0;
};

GnssRun RunGnss(const Scenario& s, double seconds) {
  const Alignment alignment(s);
  const World world(s, alignment);
  const TruthMotion truth(s, alignment, s.seed);
  const geo::UtmZone zone = geo::StandardZone(s.origin_latitude_deg, s.origin_longitude_deg);
  const Eigen::Vector2d en =
      geo::GeographicToUtm(zone, s.origin_latitude_deg, s.origin_longitude_deg);
  const Eigen::Vector3d origin(en.x(), en.y(), s.origin_height_m);
  GnssModel gnss(s, world, truth, zone, origin, s.seed);
  const Eigen::Vector3d antenna(s.gnss_antenna_m[0], s.gnss_antenna_m[1], s.gnss_antenna_m[2]);
  GnssRun run;
  for (int k = 0; k < static_cast<int>(seconds); ++k) {
    const double t = k;
    io::GnssFix fix;
    if (!gnss.Sample(t, k, &fix)) continue;
    run.errors.push_back(gnss.last_error());
    run.fixes.push_back(fix);
    run.times.push_back(t);
    const Eigen::Vector3d truth_utm = origin + truth.Pose(t) * antenna + gnss.last_error();
    const Eigen::Vector2d utm = geo::GeographicToUtm(zone, fix.latitude_deg, fix.longitude_deg);
    run.max_roundtrip_m = std::max(run.max_roundtrip_m, (utm - truth_utm.head<2>()).norm());
    run.max_altitude_m = std::max(run.max_altitude_m, std::fabs(fix.altitude_m - truth_utm.z()));
  }
  return run;
}

double Square(double x) { return x * x; }

double Autocorrelation(const std::vector<Eigen::Vector3d>& e, int axis, size_t lag) {
  double mean = 0.0;
  for (const Eigen::Vector3d& x : e) mean += x[axis];
  mean /= e.size();
  double c0 = 0.0, c = 0.0;
  for (size_t i = 0; i < e.size(); ++i) {
    c0 += (e[i][axis] - mean) * (e[i][axis] - mean);
    if (i + lag < e.size()) c += (e[i][axis] - mean) * (e[i + lag][axis] - mean);
  }
  return c / c0;
}

TEST(GnssModel, ErrorLevelsCorrelationAndConversion) {
  Scenario s = Standstill(20000.0);
  s.gnss_outlier_probability = 0.0;
  const GnssRun run = RunGnss(s, 20000.0);
  ASSERT_EQ(run.errors.size(), 20000u);
  double horizontal = 0.0, vertical = 0.0;
  for (const Eigen::Vector3d& e : run.errors) {
    horizontal += e.head<2>().squaredNorm();
    vertical += e.z() * e.z();
  }
  horizontal = std::sqrt(horizontal / run.errors.size());
  vertical = std::sqrt(vertical / run.errors.size());
  const double h = s.gnss_horizontal_sigma_m, w = s.gnss_white_sigma_m;
  const double expected_horizontal = std::sqrt(2.0) * std::hypot(h, w);  // 1.21 m
  EXPECT_NEAR(horizontal, expected_horizontal, 0.3 * expected_horizontal);
  EXPECT_NEAR(horizontal, 1.2, 0.36);  // the paper's receiver
  EXPECT_NEAR(vertical, 2.5, 0.4 * 2.5);
  // Gauss-Markov with tau = 120 s at 1 Hz plus white noise: lag-1 autocorrelation
  // exp(-1/tau) * (var - white^2) / var, about 0.87 horizontally and 0.93 vertically with the
  // defaults; it decays by 1/e over tau. The realised variance of a 20,000 s run varies by ~10 %
  // from seed to seed, so the expectation uses it.
  const double a = std::exp(-1.0 / s.gnss_tau_s);
  for (int axis = 0; axis < 3; ++axis) {
    const double white = axis < 2 ? w : 2.0 * w;
    double var = 0.0;
    for (const Eigen::Vector3d& e : run.errors) var += e[axis] * e[axis];
    var /= run.errors.size();
    const double rho1 = Autocorrelation(run.errors, axis, 1);
    EXPECT_NEAR(rho1, a * (var - white * white) / var, 0.01) << "axis " << axis;
    EXPECT_GT(rho1, axis < 2 ? 0.8 : 0.9) << "axis " << axis;
    const double at_tau = Autocorrelation(run.errors, axis, 120);
    EXPECT_GT(at_tau, 0.1) << "axis " << axis;
    EXPECT_LT(at_tau, 0.55) << "axis " << axis;
    EXPECT_LT(Autocorrelation(run.errors, axis, 1000), 0.2) << "axis " << axis;
  }

  // lat/lon converted back to UTM is the true antenna position plus the error.
  EXPECT_LT(run.max_roundtrip_m, 1e-6);
  EXPECT_LT(run.max_altitude_m, 1e-9);
  const io::GnssFix& fix = run.fixes.front();
  EXPECT_EQ(fix.position_covariance_type, 2);
  EXPECT_NEAR(fix.position_covariance[0], 0.25, 1e-12);
  EXPECT_NEAR(fix.position_covariance[4], 0.25, 1e-12);
  EXPECT_NEAR(fix.position_covariance[8], 1.0, 1e-12);
  EXPECT_NEAR(fix.latitude_deg, s.origin_latitude_deg, 0.01);
  EXPECT_NEAR(fix.longitude_deg, s.origin_longitude_deg, 0.01);
}

TEST(GnssModel, TheFirstFixIsAlreadyOffByTheStationarySpread) {
  // A receiver switched on long before the run: its time-correlated error does not start at
  // zero (which would give an estimator an almost exact first fix to anchor on).
  Scenario s = Standstill(10.0);
  s.gnss_outlier_probability = 0.0;
  const Alignment alignment(s);
  const World world(s, alignment);
  const TruthMotion truth(s, alignment, s.seed);
  const geo::UtmZone zone = geo::StandardZone(s.origin_latitude_deg, s.origin_longitude_deg);
  const Eigen::Vector3d origin(500000.0, 4000000.0, 0.0);
  const int runs = 2000;
  double east = 0.0, up = 0.0;
  for (int seed = 1; seed <= runs; ++seed) {
    GnssModel gnss(s, world, truth, zone, origin, static_cast<uint32_t>(seed));
    io::GnssFix fix;
    ASSERT_TRUE(gnss.Sample(0.0, 0, &fix));
    east += Square(gnss.last_error().x());
    up += Square(gnss.last_error().z());
  }
  const double w = s.gnss_white_sigma_m;
  const double east_expected = std::sqrt(Square(s.gnss_horizontal_sigma_m) + Square(w));
  const double up_expected = std::sqrt(Square(s.gnss_vertical_sigma_m) + Square(2.0 * w));
  EXPECT_NEAR(std::sqrt(east / runs), east_expected, 0.1 * east_expected);
  EXPECT_NEAR(std::sqrt(up / runs), up_expected, 0.1 * up_expected);
}

TEST(GnssModel, OutliersOfFiveToThirtyMetres) {
  Scenario s = Standstill(20000.0);
  s.gnss_outlier_probability = 0.02;
  const GnssRun run = RunGnss(s, 20000.0);
  ASSERT_EQ(run.errors.size(), 20000u);
  // An outlier stands out from the median of its four neighbours (the correlated error moves by
  // centimetres per second, the white noise is 0.3 m per axis).
  std::vector<double> jumps;
  for (size_t i = 2; i + 2 < run.errors.size(); ++i) {
    Eigen::Vector2d median;
    for (int axis = 0; axis < 2; ++axis) {
      std::vector<double> n = {run.errors[i - 2][axis],
                               run.errors[i - 1][axis],
                               run.errors[i + 1][axis],
                               run.errors[i + 2][axis]};
      std::sort(n.begin(), n.end());
      median[axis] = 0.5 * (n[1] + n[2]);
    }
    const double jump = (run.errors[i].head<2>() - median).norm();
    if (jump > 2.5) jumps.push_back(jump);
  }
  const double expected = s.gnss_outlier_probability * run.errors.size();  // 400
  EXPECT_NEAR(static_cast<double>(jumps.size()), expected, 0.2 * expected);
  // Their sizes spread over 5-30 m (a neighbouring outlier or the white noise blurs a few).
  std::sort(jumps.begin(), jumps.end());
  ASSERT_GT(jumps.size(), 100u);
  const double p05 = jumps[jumps.size() / 20], p50 = jumps[jumps.size() / 2];
  const double p95 = jumps[jumps.size() * 19 / 20];
  EXPECT_GT(p05, 4.0);
  EXPECT_LT(p05, 8.0);
  EXPECT_NEAR(p50, 17.5, 3.0);
  EXPECT_GT(p95, 25.0);
  EXPECT_LT(jumps.back(), 32.0);
}

TEST(GnssModel, NoFixesInTunnelsOrOutages) {
  Scenario s;
  std::string error;
  ASSERT_TRUE(LoadScenario("tunnel_gnss_outage", &s, &error)) << error;
  ASSERT_EQ(s.tunnels.size(), 1u);
  Event outage;
  outage.kind = Event::Kind::kGnssOutage;
  outage.at_s = 5.0;
  outage.duration_s = 10.0;
  s.events.push_back(outage);
  SimOptions options;
  options.lidar = false;
  std::unique_ptr<Simulator> sim = Simulator::Create(s, options, &error);
  ASSERT_TRUE(sim) << error;
  const ChainageRange tunnel = s.tunnels[0];
  std::vector<double> fix_times;
  int imu = 0, odometer = 0;
  io::SensorMessage message;
  while (sim->Next(&message)) {
    if (std::holds_alternative<io::ImuSample>(message.data)) ++imu;
    if (std::holds_alternative<io::WheelOdometry>(message.data)) ++odometer;
    if (!std::holds_alternative<io::GnssFix>(message.data)) continue;
    EXPECT_EQ(message.topic, s.gnss_topic);
    fix_times.push_back(sim->last_time_s());
  }
  const double duration = sim->duration_s();
  EXPECT_EQ(imu, static_cast<int>(std::floor((duration + 1e-9) * s.imu_rate_hz)) + 1);
  EXPECT_EQ(odometer, static_cast<int>(std::floor((duration + 1e-9) * s.odometer_rate_hz)) + 1);
  int expected = 0;
  for (int k = 0; k <= static_cast<int>(std::floor(duration + 1e-9)); ++k) {
    const double chainage = sim->truth().Chainage(k);
    const bool dark =
        (k >= 5 && k < 15) || (chainage >= tunnel.from_m - 30.0 && chainage <= tunnel.to_m + 30.0);
    if (!dark) ++expected;
  }
  EXPECT_EQ(static_cast<int>(fix_times.size()), expected);
  int in_tunnel_span = 0;
  for (double t : fix_times) {
    EXPECT_FALSE(t >= 5.0 && t < 15.0) << "fix during the outage at " << t;
    const double chainage = sim->truth().Chainage(t);
    EXPECT_FALSE(chainage >= tunnel.from_m - 30.0 && chainage <= tunnel.to_m + 30.0)
        << "fix in the tunnel at chainage " << chainage;
    if (chainage > tunnel.from_m - 60.0 && chainage < tunnel.to_m + 60.0) ++in_tunnel_span;
  }
  // Fixes resume right outside the 30 m margins (27.8 m/s: at least one fix in each 30 m band).
  EXPECT_GE(in_tunnel_span, 2);
  EXPECT_GT(expected, 30);
}

}  // namespace
}  // namespace raillomer::sim
