#include "estimator/features/rail_extraction.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include "tests/estimator/features/sim_frames.h"

#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

constexpr double kRailHeadCentreM = 0.7535;  // half gauge + half head width (the simulator's)

using test::BodyFrame;
using test::MakeSimulator;
using test::ScanFrame;

/// The frame whose end is nearest to the time the body reaches chainage s (forward motion).
uint64_t FrameAtChainage(const sim::Simulator& simulator, double s) {
  double lo = 0.0, hi = simulator.duration_s();
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (simulator.truth().Chainage(mid) < s ? lo : hi) = mid;
  }
  const double period = 1.0 / simulator.scenario().lidar_rate_hz;
  return static_cast<uint64_t>(std::max(0.0, std::round(lo / period) - 1.0));
}

/// Where a body-frame point lies relative to the true track: chainage, lateral offset and
/// height above the rail-top plane (the track frame, with grade and cant).
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

/// Accuracy of one extraction against the simulator's rail geometry.
struct RailErrors {
  double lateral_m = 0.0;     ///< largest offset of a rail point from its rail-head centre line
  double height_m = 0.0;      ///< largest offset of a rail point from the rail top
  double normal_deg = 0.0;    ///< plane normal against the true rail plane
  double distance_m = 0.0;    ///< plane offset against the true one
  double min_length_m = 0.0;  ///< the shorter rail's extent along x
};

RailErrors Compare(const sim::Simulator& simulator,
                   const BodyFrame& frame,
                   const RailExtraction& rails) {
  RailErrors e;
  e.min_length_m = 1e9;
  // The true rail plane: least squares through the true rail-head tops at the chainages of the
  // extracted points (the rail surface twists along a cant transition).
  std::vector<Eigen::Vector3d> truth;
  const Eigen::Isometry3d T_body_world = frame.T_world_body.inverse();
  for (int side : {1, -1}) {
    const std::vector<Eigen::Vector3f>& points = side > 0 ? rails.left_points : rails.right_points;
    float x_min = 1e9f, x_max = -1e9f;
    for (const Eigen::Vector3f& p : points) {
      const TrackCoordinates c = ToTrack(simulator, frame, p.cast<double>());
      e.lateral_m = std::max(e.lateral_m, std::fabs(c.lateral - side * kRailHeadCentreM));
      e.height_m = std::max(e.height_m, std::fabs(c.height));
      const sim::TrackPoint tp = simulator.alignment().At(c.s);
      truth.push_back(
          T_body_world *
          (tp.position + tp.Rotation() * Eigen::Vector3d(0.0, side * kRailHeadCentreM, 0.0)));
      x_min = std::min(x_min, p.x());
      x_max = std::max(x_max, p.x());
    }
    e.min_length_m = std::min(e.min_length_m, static_cast<double>(x_max - x_min));
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : truth) mean += p;
  mean /= static_cast<double>(truth.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& p : truth) cov += (p - mean) * (p - mean).transpose();
  Eigen::Vector3d n = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov).eigenvectors().col(0);
  if (n.z() < 0.0) n = -n;
  e.normal_deg = std::acos(std::clamp(n.dot(rails.normal), -1.0, 1.0)) * 180.0 / M_PI;
  e.distance_m = std::fabs(-n.dot(mean) - rails.distance);
  return e;
}

double CpuMs(const timespec& a, const timespec& b) {
  return (b.tv_sec - a.tv_sec) * 1e3 + (b.tv_nsec - a.tv_nsec) * 1e-6;
}

/// A tight canted curve: 300 m radius, 150 mm cant, left.
const char* kTightCurveYaml = R"(name: tight_curve
world_seed: 3
alignment:
  - {type: straight, length_m: 100}
  - {type: curve, length_m: 300, radius_m: 300, direction: left, transition_m: 40, cant_mm: 150}
  - {type: straight, length_m: 300}
motion:
  start_m: 90
  start_speed_kmh: 50
  phases: [{for_s: 20}]
)";

TEST(RailExtractionOptionsTest, DefaultsAreValidAndBadFieldsAreNamed) {
  RailExtractionOptions options;
  std::string error;
  EXPECT_TRUE(options.IsValid(&error)) << error;
  options.rail_head_width_m = -0.1;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("rail_head_width_m"), std::string::npos) << error;
  options = RailExtractionOptions();
  options.min_rail_points = 1;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("min_rail_points"), std::string::npos) << error;
  // Invalid options make a failed extraction, not a crash.
  const RailExtraction rails = ExtractRails(options, {});
  EXPECT_FALSE(rails.ok);
  EXPECT_NE(rails.failure.find("min_rail_points"), std::string::npos) << rails.failure;
}

/// The shape of an extraction: both rails well supported, the plane level-ish and flat, the
/// rails a gauge apart and running forward.
void ExpectPlausibleRails(const RailExtractionOptions& options,
                          const RailExtraction& rails,
                          const std::string& where) {
  EXPECT_GE(static_cast<int>(rails.left_points.size()), options.min_rail_points) << where;
  EXPECT_GE(static_cast<int>(rails.right_points.size()), options.min_rail_points) << where;
  EXPECT_GT(rails.normal.z(), 0.99) << where;
  EXPECT_NEAR(rails.normal.norm(), 1.0, 1e-9) << where;
  EXPECT_GT(rails.left_direction.x(), 0.95) << where;
  EXPECT_NEAR(rails.left_point.y() - rails.right_point.y(), 2.0 * kRailHeadCentreM, 0.1) << where;
  EXPECT_LT(rails.plane_rms_m, 0.015) << where;
}

/// Worst and RMS errors over the frames of MatchesTheSimulatorsRails, and its CPU time.
struct RailSummary {
  RailErrors worst;
  double normal_sq = 0.0, distance_sq = 0.0, cpu_ms = 0.0;
  int frames = 0;

  void Add(const RailErrors& e, bool away_from_turnout) {
    if (away_from_turnout) worst.lateral_m = std::max(worst.lateral_m, e.lateral_m);
    worst.height_m = std::max(worst.height_m, e.height_m);
    worst.normal_deg = std::max(worst.normal_deg, e.normal_deg);
    worst.distance_m = std::max(worst.distance_m, e.distance_m);
    normal_sq += e.normal_deg * e.normal_deg;
    distance_sq += e.distance_m * e.distance_m;
  }

  void Print() const {
    std::printf(
        "[ rails    ] %d frames: points within %.3f m laterally (away from the turnout), %.3f m "
        "vertically of the true rail heads; normal error max %.3f deg (rms %.3f), distance error "
        "max %.4f m (rms %.4f); %.2f ms CPU per frame\n",
        frames,
        worst.lateral_m,
        worst.height_m,
        worst.normal_deg,
        std::sqrt(normal_sq / frames),
        worst.distance_m,
        std::sqrt(distance_sq / frames),
        cpu_ms / frames);
  }
};

// Down-LiDAR frames on straight track, a station, cant transitions, canted arcs (800 m / 60 mm,
// 2500 m / 80 mm, 300 m / 150 mm), a turnout and a tunnel: the rails found lie on the true
// rail heads, and the plane matches the true rail plane (with its cant).
TEST(RailExtractionTest, MatchesTheSimulatorsRails) {
  struct Case {
    std::string scenario;
    std::vector<double> chainages_m;  ///< body positions
    double lateral_tolerance_m = 0.05;
  };
  const std::vector<Case> cases = {
      {"demo", {10.0, 60.0, 150.0, 240.0, 285.0}},      // station, straight, transition
      {"rich_low_station_a", {600.0, 700.0, 760.0}},    // 800 m arc, 60 mm cant
      {"poor_high_open_a", {1300.0, 1600.0}},           // 2500 m arc, 80 mm cant, 140 km/h
      {kTightCurveYaml, {180.0, 250.0, 320.0, 390.0}},  // 300 m arc, 150 mm cant
      // Past the turnout at 80 m: by the switch, the diverging rails run within a head width of
      // the main ones and some of their returns are taken.
      {"rich_low_yard_b", {70.0, 95.0, 120.0}, 0.1},
      {"tunnel_gnss_outage", {1200.0, 1700.0}},  // inside the tunnel (rails are there)
  };
  const RailExtractionOptions options;
  RailSummary summary;
  for (const Case& c : cases) {
    auto simulator = MakeSimulator(c.scenario);
    ASSERT_NE(simulator, nullptr);
    for (double s : c.chainages_m) {
      const BodyFrame frame = ScanFrame(*simulator, "down", FrameAtChainage(*simulator, s));
      const std::string where = simulator->scenario().name + " at " + std::to_string(s) + " m";
      timespec t0, t1;
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t0);
      const RailExtraction rails = ExtractRails(options, frame.points);
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t1);
      summary.cpu_ms += CpuMs(t0, t1);
      ++summary.frames;
      ASSERT_TRUE(rails.ok) << where << ": " << rails.failure;
      ExpectPlausibleRails(options, rails, where);
      const RailErrors e = Compare(*simulator, frame, rails);
      // Rail-head points: within half the head width (36 mm) plus noise of the centre line,
      // and on the head (its sides reach 50 mm down).
      EXPECT_LT(e.lateral_m, c.lateral_tolerance_m) << where;
      EXPECT_LT(e.height_m, 0.06) << where;
      EXPECT_LT(e.normal_deg, 0.3) << where;
      EXPECT_LT(e.distance_m, 0.02) << where;
      EXPECT_GT(e.min_length_m, 10.0) << where;
      summary.Add(e, c.lateral_tolerance_m <= 0.05);
    }
  }
  summary.Print();
}

// Ordinary running: consecutive stretches of frames, extraction succeeds on nearly all.
TEST(RailExtractionTest, SucceedsOnOrdinaryFrames) {
  int tried = 0, ok = 0;
  for (const char* name : {"rich_high_town_a", "poor_low_embankment_b"}) {
    auto simulator = MakeSimulator(name);
    ASSERT_NE(simulator, nullptr);
    const int frames = static_cast<int>(simulator->duration_s() * 10.0);
    for (int i = 0; i < 15; ++i) {
      const BodyFrame frame =
          ScanFrame(*simulator, "down", static_cast<uint64_t>((i + 0.5) * frames / 15));
      const RailExtraction rails = ExtractRails(RailExtractionOptions{}, frame.points);
      ++tried;
      ok += rails.ok;
      EXPECT_TRUE(rails.ok) << name << " frame " << i << ": " << rails.failure;
    }
  }
  EXPECT_GE(ok, tried - 1);
}

TEST(RailExtractionTest, FailsCleanlyWithoutRails) {
  const RailExtractionOptions options;
  // Nothing at all.
  RailExtraction rails = ExtractRails(options, {});
  EXPECT_FALSE(rails.ok);
  EXPECT_FALSE(rails.failure.empty());

  // Ballast only: a rough flat bed 0.36 m below the rail top, dense as a down-LiDAR frame.
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> x(5.f, 40.f), y(-2.5f, 2.5f);
  std::normal_distribution<float> rough(0.f, 0.02f);
  std::vector<Eigen::Vector3f> ballast;
  for (int i = 0; i < 20000; ++i) ballast.emplace_back(x(rng), y(rng), -4.16f + rough(rng));
  rails = ExtractRails(options, ballast);
  EXPECT_FALSE(rails.ok);
  EXPECT_FALSE(rails.failure.empty());
  std::printf("[ rails    ] ballast only: %s\n", rails.failure.c_str());

  // Sleepers on ballast, no rails: the sleeper tops are local maxima, but not a rail head.
  std::vector<Eigen::Vector3f> sleepers = ballast;
  for (int i = 0; i < 8000; ++i) {
    const float px = x(rng), py = y(rng);
    if (std::fmod(px, 0.6f) < 0.25f && std::fabs(py) < 1.3f) {
      sleepers.emplace_back(px, py, -3.972f + rough(rng) * 0.2f);
    }
  }
  rails = ExtractRails(options, sleepers);
  EXPECT_FALSE(rails.ok);
  std::printf("[ rails    ] sleepers, no rails: %s\n", rails.failure.c_str());

  // Garbage: NaNs, infinities and a few far points.
  std::vector<Eigen::Vector3f> garbage = {
      Eigen::Vector3f::Constant(std::nanf("")),
      Eigen::Vector3f::Constant(INFINITY),
      Eigen::Vector3f(10.f, 0.7f, -3.8f),
      Eigen::Vector3f(12.f, -0.7f, -3.8f),
  };
  rails = ExtractRails(options, garbage);
  EXPECT_FALSE(rails.ok);

  // The up LiDAR sees no track: a clean failure.
  auto simulator = MakeSimulator("demo");
  ASSERT_NE(simulator, nullptr);
  rails = ExtractRails(options, ScanFrame(*simulator, "up", 100).points);
  EXPECT_FALSE(rails.ok);
  std::printf("[ rails    ] up-LiDAR frame: %s\n", rails.failure.c_str());

  // A vehicle rolled by 10 degrees is outside the track-bed band and candidate areas.
  const BodyFrame frame = ScanFrame(*simulator, "down", 150);
  std::vector<Eigen::Vector3f> rolled;
  const Eigen::Matrix3f R = Eigen::AngleAxisf(0.17f, Eigen::Vector3f::UnitX()).toRotationMatrix();
  for (const Eigen::Vector3f& p : frame.points) rolled.push_back(R * p);
  rails = ExtractRails(options, rolled);
  EXPECT_FALSE(rails.ok);
  std::printf("[ rails    ] rolled 10 deg: %s\n", rails.failure.c_str());
}

// The survey behind the figures in the report: every built-in scenario, 40 frames each.
// Run with --gtest_also_run_disabled_tests (about 20 s).
TEST(RailExtractionTest, DISABLED_SurveyBuiltinScenarios) {
  for (const sim::ScenarioInfo& info : sim::ListScenarios()) {
    auto simulator = MakeSimulator(info.name);
    ASSERT_NE(simulator, nullptr);
    const int frames = static_cast<int>(simulator->duration_s() * 10.0);
    const int samples = 40;
    int ok = 0;
    RailErrors worst;
    double normal_sq = 0.0, cpu_ms = 0.0, cpu_max = 0.0;
    for (int i = 0; i < samples; ++i) {
      const BodyFrame frame =
          ScanFrame(*simulator, "down", static_cast<uint64_t>((i + 0.5) * frames / samples));
      if (frame.points.empty()) continue;
      timespec t0, t1;
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t0);
      const RailExtraction rails = ExtractRails(RailExtractionOptions{}, frame.points);
      clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t1);
      cpu_ms += CpuMs(t0, t1);
      cpu_max = std::max(cpu_max, CpuMs(t0, t1));
      if (!rails.ok) {
        std::printf("  %s frame %d: %s\n", info.name.c_str(), i, rails.failure.c_str());
        continue;
      }
      ++ok;
      const RailErrors e = Compare(*simulator, frame, rails);
      worst.lateral_m = std::max(worst.lateral_m, e.lateral_m);
      worst.height_m = std::max(worst.height_m, e.height_m);
      worst.normal_deg = std::max(worst.normal_deg, e.normal_deg);
      worst.distance_m = std::max(worst.distance_m, e.distance_m);
      normal_sq += e.normal_deg * e.normal_deg;
    }
    std::printf(
        "%-28s ok %2d/%d lateral %.3f height %.3f normal %.3f (rms %.3f) deg distance %.4f m, "
        "CPU %.2f ms (max %.2f)\n",
        info.name.c_str(),
        ok,
        samples,
        worst.lateral_m,
        worst.height_m,
        worst.normal_deg,
        std::sqrt(normal_sq / std::max(ok, 1)),
        worst.distance_m,
        cpu_ms / samples,
        cpu_max);
  }
}

}  // namespace
}  // namespace raillomer
