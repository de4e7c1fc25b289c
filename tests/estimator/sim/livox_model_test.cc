// The Livox Horizon model against the world: every true return, moved by the true pose at its
// own time, lies on the world geometry within the range noise; the pattern and the artefacts
// look like the real sensor's.

#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/sim/livox_model.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace raillomer::sim {
namespace {

constexpr double kDeg = M_PI / 180.0;

/// A short, fast run through a feature-rich corridor.
Scenario FastScenario() {
  Scenario s;
  std::string error;
  EXPECT_TRUE(LoadScenario("rich_high_town_a", &s, &error)) << error;
  return s;
}

struct ScannedFrame {
  std::vector<io::LivoxPoint> points;
  std::vector<PointKind> kinds;
  double t0 = 0.0;
};

ScannedFrame Scan(const Simulator& sim, size_t unit, uint64_t frame) {
  ScannedFrame out;
  out.t0 = frame / sim.scenario().lidar_rate_hz;
  const TruthMotion& truth = sim.truth();
  sim.lidars()[unit].Scan(
      frame,
      out.t0,
      [&truth](double t) { return truth.Pose(t); },
      sim.caster(),
      &out.points,
      &out.kinds);
  return out;
}

/// Range along the measured ray from the true sensor pose at `pose_t` to the world, minus the
/// measured range.
double RangeResidual(const Simulator& sim, size_t unit, const io::LivoxPoint& p, double pose_t) {
  const Eigen::Isometry3d T = sim.truth().Pose(pose_t) * sim.lidars()[unit].T_body_lidar();
  const Eigen::Vector3d q(p.x, p.y, p.z);
  const double measured = q.norm();
  const RayHit hit = sim.caster().Cast(T.translation(), T.linear() * (q / measured), 300.0);
  if (!hit.hit) return 1e9;
  return measured - hit.range_m;
}

TEST(LivoxModel, TrueReturnsLandOnTheWorldAtTheirOwnTime) {
  Scenario s = FastScenario();
  s.angular_noise_deg = 0.0;  // the residual is then pure range noise
  SimOptions options;
  options.duration_s = 5.0;
  std::string error;
  auto sim = Simulator::Create(s, options, &error);
  ASSERT_TRUE(sim) << error;
  // 100 km/h: 2.8 m of travel within one frame, so skew matters.
  for (size_t unit = 0; unit < sim->lidars().size(); ++unit) {
    const ScannedFrame frame = Scan(*sim, unit, 20);
    double sum2 = 0.0, worst = 0.0, skewed_bad = 0.0;
    int surface = 0;
    for (size_t i = 0; i < frame.points.size(); ++i) {
      if (frame.kinds[i] != PointKind::kSurface) continue;
      const io::LivoxPoint& p = frame.points[i];
      const double r = std::sqrt(p.x * p.x + p.y * p.y + p.z * p.z);
      if (r < 2.0) continue;  // short range has extra axial noise by design
      const double t = frame.t0 + p.offset_time_ns * 1e-9;
      const double residual = RangeResidual(*sim, unit, p, t);
      sum2 += residual * residual;
      worst = std::max(worst, std::fabs(residual));
      ++surface;
      // The same point cast from the pose at the frame's start: a scan that ignores skew.
      if (i % 7 == 0 && std::fabs(RangeResidual(*sim, unit, p, frame.t0)) > 0.1) ++skewed_bad;
    }
    ASSERT_GT(surface, 2000) << "unit " << unit;  // the upper unit sees mostly sky
    const double rms = std::sqrt(sum2 / surface);
    EXPECT_NEAR(rms, s.range_noise_m, 0.25 * s.range_noise_m) << "unit " << unit;
    EXPECT_LT(worst, 6.0 * s.range_noise_m) << "unit " << unit;
    // Ignoring the skew puts a large share of the points off the geometry.
    EXPECT_GT(skewed_bad / (surface / 7.0), 0.3) << "unit " << unit;
  }
}

TEST(LivoxModel, PatternCoversTheFieldOfViewWithSixLines) {
  Scenario s = FastScenario();
  LidarConfig config = s.lidars.front();
  LivoxHorizonModel model(s, config, 1);
  double min_az = 1e9, max_az = -1e9, min_el = 1e9, max_el = -1e9;
  std::vector<int> per_line(6, 0);
  uint32_t last_offset = 0;
  for (uint32_t i = 0; i < s.points_per_frame; ++i) {
    uint8_t line = 0;
    const Eigen::Vector3d d = model.Direction(3, i, &line);
    ASSERT_NEAR(d.norm(), 1.0, 1e-12);
    ASSERT_LT(line, 6);
    ++per_line[line];
    min_az = std::min(min_az, std::atan2(d.y(), d.x()) / kDeg);
    max_az = std::max(max_az, std::atan2(d.y(), d.x()) / kDeg);
    min_el = std::min(min_el, std::asin(d.z()) / kDeg);
    max_el = std::max(max_el, std::asin(d.z()) / kDeg);
    ASSERT_GE(model.OffsetNs(i), last_offset);
    last_offset = model.OffsetNs(i);
  }
  EXPECT_NEAR(max_az - min_az, 81.7, 0.5);
  EXPECT_NEAR(max_el - min_el, 25.1, 1.0);
  for (int n : per_line) EXPECT_EQ(n, static_cast<int>(s.points_per_frame / 6));
  // Points ~4167 ns apart; the frame lasts 100 ms.
  EXPECT_NEAR(model.OffsetNs(1), 4167, 1);
  EXPECT_LT(last_offset, 100000000u);
  EXPECT_GT(last_offset, 99990000u);
  // Non-repetitive: the next frame's rays differ.
  uint8_t line = 0;
  EXPECT_GT((model.Direction(3, 100, &line) - model.Direction(4, 100, &line)).norm(), 1e-4);
}

TEST(LivoxModel, ArtefactsAppearWhereTheyShould) {
  Scenario s = FastScenario();
  SimOptions options;
  options.duration_s = 5.0;
  std::string error;
  // The sun straight ahead, low: the up-looking unit sees flicker.
  const double heading_deg = s.initial_azimuth_deg;
  s.sun_azimuth_deg = heading_deg;
  s.sun_elevation_deg = 12.0;
  s.sun_flicker_probability = 0.5;
  auto sim = Simulator::Create(s, options, &error);
  ASSERT_TRUE(sim) << error;
  auto count = [](const ScannedFrame& f, PointKind kind) {
    return std::count(f.kinds.begin(), f.kinds.end(), kind);
  };
  const ScannedFrame up = Scan(*sim, 0, 5);
  const ScannedFrame down = Scan(*sim, 1, 5);
  EXPECT_GT(count(up, PointKind::kSunFlicker), 50);
  EXPECT_EQ(count(down, PointKind::kSunFlicker), 0);  // the sun is above its field of view
  EXPECT_GT(count(up, PointKind::kBleeding) + count(down, PointKind::kBleeding), 5);
  // The roof edge in front of the lower unit: near points, under 1.5 m.
  EXPECT_GT(count(down, PointKind::kBody), 100);
  EXPECT_EQ(count(up, PointKind::kBody), 0);
  for (size_t i = 0; i < down.points.size(); ++i) {
    if (down.kinds[i] != PointKind::kBody) continue;
    const io::LivoxPoint& p = down.points[i];
    EXPECT_LT(std::sqrt(p.x * p.x + p.y * p.y + p.z * p.z), 1.5);
  }
  // No-return points are zeros, as the driver sends them; returns carry tag 0x10.
  for (size_t i = 0; i < up.points.size(); ++i) {
    const io::LivoxPoint& p = up.points[i];
    if (up.kinds[i] == PointKind::kNoReturn) {
      EXPECT_EQ(p.x, 0.f);
      EXPECT_EQ(p.tag, 0);
    } else {
      EXPECT_EQ(p.tag, 0x10);
    }
  }
  // Sun flicker switched off: none.
  s.sun_flicker_probability = 0.0;
  auto quiet = Simulator::Create(s, options, &error);
  ASSERT_TRUE(quiet) << error;
  EXPECT_EQ(count(Scan(*quiet, 0, 5), PointKind::kSunFlicker), 0);
}

TEST(LivoxModel, DownUnitSeesTheRailsAhead) {
  Scenario s = FastScenario();
  s.angular_noise_deg = 0.0;
  SimOptions options;
  options.duration_s = 2.0;
  std::string error;
  auto sim = Simulator::Create(s, options, &error);
  ASSERT_TRUE(sim) << error;
  const ScannedFrame down = Scan(*sim, 1, 3);
  // Points on the rail heads: body-frame height about rail top, |y| near 0.75 m.
  const Eigen::Isometry3d T_body_lidar = sim->lidars()[1].T_body_lidar();
  int rail = 0;
  for (size_t i = 0; i < down.points.size(); ++i) {
    if (down.kinds[i] != PointKind::kSurface) continue;
    const io::LivoxPoint& p = down.points[i];
    const Eigen::Vector3d b = T_body_lidar * Eigen::Vector3d(p.x, p.y, p.z);
    if (b.x() > 5.0 && b.x() < 30.0 && std::fabs(std::fabs(b.y()) - 0.7535) < 0.05 &&
        std::fabs(b.z() + s.body_height_m) < 0.06) {
      ++rail;
    }
  }
  EXPECT_GT(rail, 50);
}

}  // namespace
}  // namespace raillomer::sim
