#include "estimator/features/rail_extraction.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

constexpr double kRailHeadCentreM = 0.7535;  // half gauge + half head width

std::unique_ptr<sim::Simulator> MakeSimulator(const std::string& name_or_yaml) {
  sim::Scenario scenario;
  std::string error;
  const bool parsed = name_or_yaml.find('\n') == std::string::npos
                          ? sim::LoadScenario(name_or_yaml, &scenario, &error)
                          : sim::ParseScenario(name_or_yaml, "test", &scenario, &error);
  EXPECT_TRUE(parsed) << error;
  if (!parsed) return nullptr;
  auto simulator = sim::Simulator::Create(scenario, sim::SimOptions{}, &error);
  EXPECT_NE(simulator, nullptr) << error;
  return simulator;
}

/// One LiDAR frame in the body frame at its end time, deskewed with the truth.
struct BodyFrame {
  double t_end = 0.0;
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();  ///< at t_end
  std::vector<Eigen::Vector3f> points;
};

BodyFrame ScanFrame(const sim::Simulator& simulator, const std::string& unit, uint64_t frame) {
  BodyFrame out;
  const sim::LivoxHorizonModel* lidar = nullptr;
  for (const sim::LivoxHorizonModel& l : simulator.lidars()) {
    if (l.config().name == unit) lidar = &l;
  }
  if (lidar == nullptr) return out;
  const double period = 1.0 / simulator.scenario().lidar_rate_hz;
  const double t0 = frame * period;
  const sim::TruthMotion& truth = simulator.truth();
  std::vector<io::LivoxPoint> points;
  lidar->Scan(
      frame, t0, [&truth](double t) { return truth.Pose(t); }, simulator.caster(), &points, nullptr);
  out.t_end = t0 + period;
  out.T_world_body = truth.Pose(out.t_end);
  const Eigen::Isometry3d T_end_world = out.T_world_body.inverse();
  out.points.reserve(points.size());
  for (const io::LivoxPoint& p : points) {
    if (p.x == 0.f && p.y == 0.f && p.z == 0.f) continue;  // no return
    const double t = t0 + p.offset_time_ns * 1e-9;
    const Eigen::Vector3d p_body = lidar->T_body_lidar() * Eigen::Vector3d(p.x, p.y, p.z);
    out.points.push_back((T_end_world * truth.Pose(t) * p_body).cast<float>());
  }
  return out;
}

/// Where a body-frame point lies relative to the true track: chainage, lateral, height above
/// the rail-top plane (track frame with grade and cant).
struct TrackCoordinates {
  double s = 0.0, lateral = 0.0, height = 0.0;
};

TrackCoordinates ToTrack(const sim::Simulator& simulator,
                         const BodyFrame& frame,
                         const Eigen::Vector3d& p_body) {
  const Eigen::Vector3d p_world = frame.T_world_body * p_body;
  TrackCoordinates c;
  c.s = simulator.truth().Chainage(frame.t_end) + p_body.x();
  for (int i = 0; i < 5; ++i) {
    const sim::TrackPoint tp = simulator.alignment().At(c.s);
    const Eigen::Vector3d local = tp.Rotation().transpose() * (p_world - tp.position);
    c.s += local.x();
    c.lateral = local.y();
    c.height = local.z();
  }
  return c;
}

/// The true rail-head centre (top) at chainage s on one side, in the body frame.
Eigen::Vector3d TrueRailHead(const sim::Simulator& simulator,
                             const BodyFrame& frame,
                             double s,
                             int side) {
  const sim::TrackPoint tp = simulator.alignment().At(s);
  const Eigen::Vector3d world =
      tp.position + tp.Rotation() * Eigen::Vector3d(0.0, side * kRailHeadCentreM, 0.0);
  return frame.T_world_body.inverse() * world;
}

/// Accuracy of one extraction against the simulator's rail geometry.
struct RailErrors {
  double max_lateral_m = 0.0;  ///< of any rail point from its true rail-head centre line
  double max_height_m = 0.0;   ///< of any rail point from the true rail top
  double normal_deg = 0.0;     ///< plane normal vs the true rail plane
  double distance_m = 0.0;     ///< plane offset vs truth, along the normal
  double length_m = 0.0;       ///< extent of the extracted rails along x
  double roll_deg = 0.0, pitch_deg = 0.0, signed_distance_m = 0.0, mean_height_m = 0.0;
  double low_fraction = 0.0;
};

RailErrors Compare(const sim::Simulator& simulator,
                   const BodyFrame& frame,
                   const RailExtraction& rails) {
  RailErrors e;
  std::vector<Eigen::Vector3d> truth;  // true rail heads at the chainages of the points
  double x_min = 1e9, x_max = -1e9;
  for (int side : {1, -1}) {
    for (const Eigen::Vector3f& p : side > 0 ? rails.left_points : rails.right_points) {
      const TrackCoordinates c = ToTrack(simulator, frame, p.cast<double>());
      e.max_lateral_m = std::max(e.max_lateral_m, std::fabs(c.lateral - side * kRailHeadCentreM));
      e.max_height_m = std::max(e.max_height_m, std::fabs(c.height));
      e.mean_height_m += c.height;
      e.low_fraction += c.height < -0.02;
      truth.push_back(TrueRailHead(simulator, frame, c.s, side));
      x_min = std::min(x_min, static_cast<double>(p.x()));
      x_max = std::max(x_max, static_cast<double>(p.x()));
    }
  }
  e.length_m = x_max - x_min;
  // The true rail plane: least squares through the true rail heads.
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : truth) mean += p;
  mean /= static_cast<double>(truth.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& p : truth) cov += (p - mean) * (p - mean).transpose();
  Eigen::Vector3d n = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvectors().col(0);
  if (n.z() < 0.0) n = -n;
  const double d = -n.dot(mean);
  e.normal_deg = std::acos(std::clamp(n.dot(rails.normal), -1.0, 1.0)) * 180.0 / M_PI;
  e.distance_m = std::fabs(d - rails.distance);
  e.signed_distance_m = rails.distance - d;
  e.roll_deg = (std::atan2(rails.normal.y(), rails.normal.z()) - std::atan2(n.y(), n.z())) * 180 / M_PI;
  e.pitch_deg = (std::atan2(rails.normal.x(), rails.normal.z()) - std::atan2(n.x(), n.z())) * 180 / M_PI;
  e.mean_height_m /= truth.size();
  e.low_fraction /= truth.size();
  return e;
}

/// The run time at which the body reaches chainage s (the motion runs forward).
double TimeAtChainage(const sim::Simulator& simulator, double s) {
  double lo = 0.0, hi = simulator.duration_s();
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (simulator.truth().Chainage(mid) < s ? lo : hi) = mid;
  }
  return lo;
}

TEST(RailExtractionTest, Explore) {
  auto simulator = MakeSimulator("demo");
  ASSERT_NE(simulator, nullptr);
  for (uint64_t f : {30u, 100u, 200u}) {
    const BodyFrame frame = ScanFrame(*simulator, "down", f);
    int rail = 0, bed = 0;
    for (const Eigen::Vector3f& p : frame.points) {
      const TrackCoordinates c = ToTrack(*simulator, frame, p.cast<double>());
      if (p.x() < 40 && std::fabs(std::fabs(c.lateral) - kRailHeadCentreM) < 0.04 &&
          c.height > -0.06 && c.height < 0.03)
        ++rail;
      if (std::fabs(p.z() + 3.8) < 0.6) ++bed;
    }
    const auto start = std::chrono::steady_clock::now();
    RailExtraction rails = ExtractRails(RailExtractionOptions{}, frame.points);
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
            .count();
    std::printf("frame %lu: %zu points, %d bed, %d true rail head, ok=%d (%s) %.2f ms\n",
                static_cast<unsigned long>(f),
                frame.points.size(),
                bed,
                rail,
                rails.ok,
                rails.failure.c_str(),
                ms);
    if (rails.ok) {
      const RailErrors e = Compare(*simulator, frame, rails);
      std::printf(
          "  left %zu right %zu; lateral %.3f height %.3f normal %.3f deg dist %.4f len %.1f "
          "rms %.4f\n",
          rails.left_points.size(),
          rails.right_points.size(),
          e.max_lateral_m,
          e.max_height_m,
          e.normal_deg,
          e.distance_m,
          e.length_m,
          rails.plane_rms_m);
    }
  }
}

TEST(RailExtractionTest, Debug) {
  auto simulator = MakeSimulator("long_20km");
  const BodyFrame frame = ScanFrame(*simulator, "down", 1320);
  RailExtraction rails = ExtractRails(RailExtractionOptions{}, frame.points);
  std::printf("%s\n", rails.failure.c_str());
  FILE* f = std::fopen("/tmp/rail_dbg.txt", "w");
  for (const Eigen::Vector3f& p : frame.points) {
    if (p.x() < 3 || p.x() > 40 || std::fabs(p.y()) > 3 || std::fabs(p.z() + 3.8) > 1) continue;
    const TrackCoordinates c = ToTrack(*simulator, frame, p.cast<double>());
    std::fprintf(f, "%f %f %f %f %f\n", p.x(), p.y(), p.z(), c.lateral, c.height);
  }
  std::fclose(f);
}

const char* kTightCurve = R"(name: tight_curve
world_seed: 3
alignment:
  - {type: straight, length_m: 100}
  - {type: curve, length_m: 300, radius_m: RADIUS, direction: left, transition_m: 40, cant_mm: 150}
  - {type: straight, length_m: 300}
motion:
  start_m: 90
  start_speed_kmh: 50
  phases: [{for_s: 20}]
)";

TEST(RailExtractionTest, Detail) {
  for (const char* name : {"R300", "R150"}) {
    std::string yaml = kTightCurve;
    yaml.replace(yaml.find("RADIUS"), 6, name + 1);
    auto simulator = MakeSimulator(yaml);
    for (int f = 10; f < 300; f += 10) {
      const BodyFrame frame = ScanFrame(*simulator, "down", f);
      RailExtraction rails = ExtractRails(RailExtractionOptions{}, frame.points);
      if (!rails.ok) { std::printf("%s\n", rails.failure.c_str()); continue; }
      const RailErrors e = Compare(*simulator, frame, rails);
      std::printf("%s f%d n=%zu/%zu roll %+.3f pitch %+.3f dd %+.4f meanh %+.4f low %.2f len %.1f\n", name, f,
                  rails.left_points.size(), rails.right_points.size(), e.roll_deg, e.pitch_deg,
                  e.signed_distance_m, e.mean_height_m, e.low_fraction, e.length_m);
    }
  }
}

TEST(RailExtractionTest, Survey) {
  std::vector<sim::ScenarioInfo> list = sim::ListScenarios();
  list.insert(list.begin(), {{"R150", ""}, {"R300", ""}});
  for (const sim::ScenarioInfo& info : list) {
    std::string name = info.name;
    if (name[0] == 'R') {
      name = kTightCurve;
      name.replace(name.find("RADIUS"), 6, info.name.substr(1));
    }
    auto simulator = MakeSimulator(name);
    ASSERT_NE(simulator, nullptr);
    const int frames = static_cast<int>(simulator->duration_s() * 10.0);
    const int samples = 40;
    int ok = 0;
    double nrm_sq = 0, dst_sq = 0;
    double lat = 0, hgt = 0, nrm = 0, dst = 0, tmax = 0, tsum = 0, len_min = 1e9;
    std::map<std::string, int> failures;
    for (int i = 0; i < samples; ++i) {
      const uint64_t f = static_cast<uint64_t>((i + 0.5) * frames / samples);
      const BodyFrame frame = ScanFrame(*simulator, "down", f);
      if (frame.points.empty()) continue;
      timespec t0, t1;
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t0);
      RailExtraction rails = ExtractRails(RailExtractionOptions{}, frame.points);
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t1);
      const double ms = (t1.tv_sec - t0.tv_sec) * 1e3 + (t1.tv_nsec - t0.tv_nsec) * 1e-6;
      tmax = std::max(tmax, ms);
      tsum += ms;
      if (!rails.ok) {
        const double s = simulator->truth().Chainage(frame.t_end);
        std::printf("  %s f%lu s=%.0f: %s\n", info.name.c_str(), (unsigned long)f, s,
                    rails.failure.c_str());
        failures[rails.failure.substr(0, 30)]++;
        continue;
      }
      ++ok;
      const RailErrors e = Compare(*simulator, frame, rails);
      if (e.normal_deg > 0.2 || e.distance_m > 0.015 || e.max_lateral_m > 0.05 || e.max_height_m > 0.05)
        std::printf("  %s f%lu: lat %.3f h %.3f n %.3f d %.4f len %.1f\n", info.name.c_str(),
                    (unsigned long)f, e.max_lateral_m, e.max_height_m, e.normal_deg, e.distance_m,
                    e.length_m);
      lat = std::max(lat, e.max_lateral_m);
      hgt = std::max(hgt, e.max_height_m);
      nrm = std::max(nrm, e.normal_deg);
      nrm_sq += e.normal_deg * e.normal_deg;
      dst_sq += e.distance_m * e.distance_m;
      dst = std::max(dst, e.distance_m);
      len_min = std::min(len_min, e.length_m);
    }
    std::printf("%-28s ok %2d/%d lat %.3f h %.3f n %.3f (rms %.3f) d %.4f (rms %.4f) minlen %.1f t %.2f/%.2f ms\n",
                info.name.c_str(), ok, samples, lat, hgt, nrm, std::sqrt(nrm_sq / ok), dst, std::sqrt(dst_sq / ok), len_min, tsum / samples, tmax);
  }
}

}  // namespace
}  // namespace raillomer
