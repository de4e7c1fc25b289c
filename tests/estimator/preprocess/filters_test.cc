// The per-LiDAR preprocessing (paper IV.C) on constructed artefacts with known answers, and on
// simulated frames whose points carry what produced them.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/preprocess/filters.h"
#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

constexpr double kDeg = M_PI / 180.0;

/// Unit direction at azimuth / elevation (radians), sensor frame (x forward, z up).
Eigen::Vector3d Direction(double azimuth, double elevation) {
  return {std::cos(elevation) * std::cos(azimuth),
          std::cos(elevation) * std::sin(azimuth),
          std::sin(elevation)};
}

ScanPoint MakePoint(const Eigen::Vector3d& p, uint8_t line = 0, double time_s = 0.0) {
  ScanPoint point;
  point.p = p.cast<float>();
  point.range_m = static_cast<float>(p.norm());
  point.line = line;
  point.time_s = static_cast<float>(time_s);
  point.intensity = 30.f;
  return point;
}

/// Whether `scan` still holds a point at exactly `p`.
bool Contains(const Scan& scan, const Eigen::Vector3f& p) {
  return std::any_of(
      scan.points.begin(), scan.points.end(), [&p](const ScanPoint& q) { return q.p == p; });
}

TEST(PreprocessOptions, DefaultsAreValidAndBadFieldsAreNamed) {
  std::string error;
  EXPECT_TRUE(PreprocessOptions().IsValid(&error)) << error;
  PreprocessOptions options;
  options.max_range_m = 1.0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("max_range_m"), std::string::npos) << error;
  options = PreprocessOptions();
  options.hidden_sector_angle_deg = 95.0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("hidden_sector_angle_deg"), std::string::npos) << error;
  options = PreprocessOptions();
  options.flicker_min_points_per_cell = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("flicker_min_points_per_cell"), std::string::npos) << error;
}

TEST(ScanFromLidarFrame, ConvertsFieldsAndDropsZeroPoints) {
  io::LidarFrame frame;
  frame.timebase_ns = 1600000000123456789ULL;
  io::LivoxPoint a;
  a.offset_time_ns = 25000000;
  a.x = 3.f;
  a.y = 4.f;
  a.z = 0.f;
  a.reflectivity = 77;
  a.line = 4;
  io::LivoxPoint zero;  // no echo
  zero.offset_time_ns = 26000000;
  frame.points = {a, zero, a};
  PreprocessStats stats;
  const Scan scan = ScanFromLidarFrame(frame, 1, 0.1, &stats);
  EXPECT_EQ(scan.lidar_index, 1);
  EXPECT_DOUBLE_EQ(scan.duration_s, 0.1);
  EXPECT_NEAR(scan.start_s, 1600000000.123456789, 1e-6);
  ASSERT_EQ(scan.points.size(), 2u);
  EXPECT_EQ(stats.input, 3u);
  EXPECT_EQ(stats.no_return, 1u);
  const ScanPoint& p = scan.points[0];
  EXPECT_FLOAT_EQ(p.time_s, 0.025f);
  EXPECT_FLOAT_EQ(p.range_m, 5.f);
  EXPECT_FLOAT_EQ(p.intensity, 77.f);
  EXPECT_EQ(p.line, 4);
  EXPECT_EQ(p.p, Eigen::Vector3f(3.f, 4.f, 0.f));
  EXPECT_EQ(ScanFromLidarFrame(frame, 0, 0.1).points.size(), 2u);
}

TEST(RemoveNearAndFarPoints, ExactCounts) {
  // min 2 m, max 200 m: 4 too near, 3 too far, 5 kept.
  const std::vector<double> ranges = {
      0.3, 1.0, 1.5, 1.99, 2.01, 3.0, 50.0, 120.0, 199.9, 200.1, 230.0, 400.0};
  Scan scan;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> angle(-0.7, 0.7);
  for (double r : ranges) scan.points.push_back(MakePoint(r * Direction(angle(rng), angle(rng))));
  PreprocessOptions options;
  PreprocessStats stats;
  RemoveNearAndFarPoints(options, &scan, &stats);
  EXPECT_EQ(stats.near_or_far, 7u);
  ASSERT_EQ(scan.points.size(), 5u);
  for (const ScanPoint& p : scan.points) {
    EXPECT_GE(p.range_m, 2.0);
    EXPECT_LE(p.range_m, 200.0);
  }
  // Order is kept.
  EXPECT_NEAR(scan.points.front().range_m, 2.01, 1e-5);
  EXPECT_NEAR(scan.points.back().range_m, 199.9, 1e-4);
}

/// A Livox-like frame: 6 lines sweeping +-40 deg in 0.2 deg steps, 10 sweeps per line stepping
/// through each line's band. `range(dir)` gives the range along a sensor-frame ray (<= 0: none).
template <typename RangeFn>
Scan SweepScan(RangeFn range, int sweeps = 10) {
  Scan scan;
  const int per_sweep = 400;
  for (int sweep = 0; sweep < sweeps; ++sweep) {
    for (int i = 0; i < per_sweep; ++i) {
      const double u = (i + 0.5) / per_sweep;
      const double across = sweep % 2 == 0 ? u : 1.0 - u;
      for (int line = 0; line < 6; ++line) {
        const double azimuth = (across - 0.5) * 80.0 * kDeg;
        const double elevation = (-12.5 + 4.2 * (line + (sweep + 0.5) / sweeps)) * kDeg;
        const Eigen::Vector3d dir = Direction(azimuth, elevation);
        const double r = range(dir);
        if (r <= 0.0) continue;
        const double t = 0.1 * (sweep * per_sweep + i) / (sweeps * per_sweep);
        scan.points.push_back(MakePoint(r * dir, static_cast<uint8_t>(line), t));
      }
    }
  }
  return scan;
}

TEST(RemoveSunFlicker, RemovesIsolatedSkyPointsAndKeepsSurfaces) {
  // A building face 25 m ahead below 2 deg of elevation; above it empty sky.
  auto wall = [](const Eigen::Vector3d& dir) {
    if (dir.z() / dir.norm() > std::sin(2.0 * kDeg)) return 0.0;
    return 25.0 / dir.x();
  };
  Scan scan = SweepScan(wall);
  const size_t surface = scan.points.size();
  ASSERT_GT(surface, 10000u);
  // Flicker: isolated returns at random ranges (3..50 m) towards the sky, each far from the
  // others (at least 5 cell edges at its range, as the default cells grow with range).
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> azimuth(-35.0, 35.0), elevation(4.0, 12.0),
      range(3.0, 50.0);
  std::vector<Eigen::Vector3d> flicker;
  const PreprocessOptions options;
  while (flicker.size() < 150) {
    const Eigen::Vector3d p = range(rng) * Direction(azimuth(rng) * kDeg, elevation(rng) * kDeg);
    const double cell = options.flicker_cell_size_m * p.norm() / options.flicker_reference_range_m;
    const bool isolated = std::all_of(
        flicker.begin(), flicker.end(), [&](const auto& q) { return (q - p).norm() > 5.0 * cell; });
    if (isolated) flicker.push_back(p);
  }
  for (size_t i = 0; i < flicker.size(); ++i) {
    ScanPoint point = MakePoint(flicker[i], static_cast<uint8_t>(i % 6));
    point.intensity = 3.f;
    scan.points.insert(scan.points.begin() + (i * 97) % scan.points.size(), point);
  }
  PreprocessStats stats;
  RemoveSunFlicker(options, &scan, &stats);
  size_t flicker_left = 0;
  for (const Eigen::Vector3d& p : flicker) flicker_left += Contains(scan, p.cast<float>());
  EXPECT_EQ(flicker_left, 0u);
  EXPECT_EQ(stats.flicker + scan.points.size(), surface + flicker.size());
  EXPECT_GE(scan.points.size(), static_cast<size_t>(0.99 * surface));
}

TEST(RemoveSunFlicker, FixedGridCountsPointsPerCell) {
  // The paper's plain grid (reference range 0): 1 m cells, a cell needs 3 points.
  PreprocessOptions options;
  options.flicker_reference_range_m = 0.0;
  Scan scan;
  auto add = [&scan](double x, double y, double z) {
    scan.points.push_back(MakePoint(Eigen::Vector3d(x, y, z)));
  };
  add(10.1, 0.1, 0.1);  // cell (10, 0, 0): 3 points, kept
  add(10.5, 0.5, 0.5);
  add(10.9, 0.9, 0.9);
  add(20.2, 5.2, 1.2);  // cell (20, 5, 1): 2 points, removed...
  add(20.8, 5.8, 1.8);
  add(21.2, 5.2, 1.2);  // ...as is this one, alone in (21, 5, 1), though 0.4 m from them
  // The second grid, shifted by half a cell, rescues points a boundary cut off: here (14.9,
  // 3.9), (15.1, 4.1), (15.2, 3.9) share the shifted cell (15, 4) though not an unshifted one.
  add(14.9, 3.9, 0.55);
  add(15.1, 4.1, 0.6);
  add(15.2, 3.9, 0.7);
  PreprocessStats stats;
  RemoveSunFlicker(options, &scan, &stats);
  EXPECT_EQ(stats.flicker, 3u);
  ASSERT_EQ(scan.points.size(), 6u);
  EXPECT_FLOAT_EQ(scan.points[0].p.x(), 10.1f);
  EXPECT_FLOAT_EQ(scan.points[3].p.x(), 14.9f);
  // Bright points in sparse cells stay when exempted.
  options.flicker_exempt_intensity = 100.0;
  Scan bright;
  bright.points.push_back(MakePoint(Eigen::Vector3d(30.0, 0.0, 0.0)));
  bright.points.push_back(MakePoint(Eigen::Vector3d(40.0, 0.0, 0.0)));
  bright.points[0].intensity = 150.f;
  RemoveSunFlicker(options, &bright, nullptr);
  ASSERT_EQ(bright.points.size(), 1u);
  EXPECT_FLOAT_EQ(bright.points[0].p.x(), 30.f);
}

/// One line sweeping in azimuth (0.2 deg steps) with its points given as ranges.
struct LineProfile {
  Scan scan;
  std::vector<int> kind;  ///< 0 real surface, 1 stretched (bleeding)
};

void AddRun(LineProfile* profile,
            const std::vector<double>& ranges,
            int kind,
            double elevation_deg,
            uint8_t line,
            double* azimuth_deg) {
  for (double r : ranges) {
    profile->scan.points.push_back(
        MakePoint(r * Direction(*azimuth_deg * kDeg, elevation_deg * kDeg), line));
    profile->kind.push_back(kind);
    *azimuth_deg += 0.2;
  }
}

std::vector<double> Flat(double range, int n) { return std::vector<double>(n, range); }

TEST(RemoveBoundaryBleeding, RemovesStretchedPointsAndKeepsRealSurfaces) {
  // On each line: a foreground edge (a mast face 10..20 m away), then 1-3 mixed returns
  // stretched between it and the background wall behind, then the wall; and the other way
  // round. Between the cases lie clean depth jumps (no mixed return) and a thin object hit by a
  // single beam, which must all stay.
  LineProfile profile;
  std::mt19937 rng(5);
  // Each stretched point sits on its own beam, 0.2 deg from the last, at a fraction of the way
  // from the foreground to the background, evenly spread with jitter; the background lies 30 % to
  // 150 % farther, so that each step runs within phi of the beam.
  std::uniform_real_distribution<double> fore(8.0, 15.0), ratio(1.3, 2.5), jitter(-0.1, 0.1);
  for (uint8_t line = 0; line < 6; ++line) {
    const double elevation = -10.0 + 4.0 * line;
    double azimuth = -40.0;
    for (int c = 0; c < 12; ++c) {
      const double a = fore(rng), b = a * ratio(rng);
      const int stretched = 1 + c % 3;
      std::vector<double> mixed;
      for (int s = 1; s <= stretched; ++s) {
        mixed.push_back(a + (s + jitter(rng)) / (stretched + 1) * (b - a));
      }
      const bool rising = c % 2 == 0;
      if (!rising) std::reverse(mixed.begin(), mixed.end());
      AddRun(&profile, Flat(rising ? a : b, 12), 0, elevation, line, &azimuth);
      AddRun(&profile, mixed, 1, elevation, line, &azimuth);
      AddRun(&profile, Flat(rising ? b : a, 12), 0, elevation, line, &azimuth);
      // A clean jump back and a one-beam thin pole in front of the wall.
      AddRun(&profile, Flat(30.0, 4), 0, elevation, line, &azimuth);
      AddRun(&profile, {12.0}, 0, elevation, line, &azimuth);
      AddRun(&profile, Flat(30.0, 4), 0, elevation, line, &azimuth);
    }
  }
  std::vector<std::pair<Eigen::Vector3f, int>> truth;
  for (size_t i = 0; i < profile.kind.size(); ++i) {
    truth.push_back({profile.scan.points[i].p, profile.kind[i]});
  }
  PreprocessStats stats;
  RemoveBoundaryBleeding(PreprocessOptions(), &profile.scan, &stats);
  size_t real = 0, real_kept = 0, mixed = 0, mixed_kept = 0;
  for (const auto& [p, kind] : truth) {
    const bool kept = Contains(profile.scan, p);
    (kind == 1 ? mixed : real) += 1;
    (kind == 1 ? mixed_kept : real_kept) += kept;
  }
  EXPECT_GT(mixed, 100u);
  EXPECT_EQ(mixed_kept, 0u) << "of " << mixed << " stretched points";
  EXPECT_GE(real_kept, 0.95 * real) << real_kept << " of " << real;
  EXPECT_EQ(real_kept, real);  // in fact every real point stays
  EXPECT_EQ(stats.bleeding, mixed);
}

TEST(RemoveBoundaryBleeding, KeepsGrazingSurfacesAndRespectsTheSector) {
  // A wall seen at grazing incidence: every step runs along the beam, but the chain is long.
  LineProfile profile;
  double azimuth = -20.0;
  std::vector<double> grazing;
  for (int i = 0; i < 30; ++i) grazing.push_back(8.0 + 0.6 * i);
  AddRun(&profile, Flat(6.0, 5), 0, 0.0, 0, &azimuth);
  AddRun(&profile, grazing, 0, 0.0, 0, &azimuth);
  AddRun(&profile, Flat(40.0, 5), 0, 0.0, 0, &azimuth);
  const size_t n = profile.scan.points.size();
  RemoveBoundaryBleeding(PreprocessOptions(), &profile.scan, nullptr);
  EXPECT_EQ(profile.scan.points.size(), n);

  // A point between two surfaces but off the beam axis by more than phi stays; within phi it
  // goes; within phi but farther than d from both neighbours it stays.
  auto run = [](double lateral_deg, double fore, double mid, double back, double radius) {
    Scan scan;
    scan.points.push_back(MakePoint(fore * Direction(-0.4 * kDeg, 0.0)));
    scan.points.push_back(MakePoint(fore * Direction(-0.2 * kDeg, 0.0)));
    scan.points.push_back(MakePoint(mid * Direction(lateral_deg * kDeg, 0.0)));
    scan.points.push_back(MakePoint(back * Direction(0.2 * kDeg, 0.0)));
    scan.points.push_back(MakePoint(back * Direction(0.4 * kDeg, 0.0)));
    PreprocessOptions options;
    options.hidden_sector_radius_m = radius;
    RemoveBoundaryBleeding(options, &scan, nullptr);
    return scan.points.size();
  };
  EXPECT_EQ(run(0.0, 10.0, 11.0, 12.0, 20.0), 4u);  // on the axis: mixed
  // 2 deg off the neighbour's axis at 11 m is 0.38 m sideways over a 1 m step: 21 deg.
  EXPECT_EQ(run(2.0, 10.0, 11.0, 12.0, 20.0), 5u);
  EXPECT_EQ(run(0.0, 10.0, 28.0, 50.0, 20.0), 4u);
  EXPECT_EQ(run(0.0, 10.0, 28.0, 50.0, 5.0), 5u);  // 18 m and 22 m from its neighbours, d = 5 m
}

/// The rig's up LiDAR: [0.3, 0, 0.35], pitched 12.7 deg up (R = Rz Ry Rx, pitch -12.7 deg).
Eigen::Isometry3d UpLidarExtrinsic() {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(-12.7 * kDeg, Eigen::Vector3d::UnitY()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.3, 0.0, 0.35);
  return T;
}

/// Planes n . x = d of a world: the ground, a wall to each side, a wall ahead.
struct World {
  std::vector<Eigen::Vector4d> planes = {
      {0, 0, 1, -4.0}, {0, 1, 0, 9.0}, {0, 1, 0, -7.0}, {1, 0, 0, 60.0}};

  double Cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) const {
    double best = -1.0;
    for (const Eigen::Vector4d& plane : planes) {
      const double denominator = plane.head<3>().dot(dir);
      if (std::fabs(denominator) < 1e-9) continue;
      const double t = (plane[3] - plane.head<3>().dot(origin)) / denominator;
      if (t > 0.5 && (best < 0.0 || t < best)) best = t;
    }
    return best;
  }

  double Distance(const Eigen::Vector3d& p) const {
    double best = 1e9;
    for (const Eigen::Vector4d& plane : planes) {
      best = std::min(best, std::fabs(plane.head<3>().dot(p) - plane[3]));
    }
    return best;
  }
};

/// Pose (slerp and lerp) between `T` (weight 1) and identity (weight 0).
Eigen::Isometry3d Interpolate(const Eigen::Isometry3d& T, double weight) {
  Eigen::Isometry3d out = Eigen::Isometry3d::Identity();
  out.linear() = Eigen::Quaterniond::Identity()
                     .slerp(weight, Eigen::Quaterniond(T.linear()))
                     .toRotationMatrix();
  out.translation() = weight * T.translation();
  return out;
}

/// Scans `world` from the LiDAR while the body moves along T_world_body(t), t in [0, 0.1 s]:
/// each point from the pose at its own time, as a Livox does.
template <typename PoseFn>
Scan SkewedScan(const World& world, const Eigen::Isometry3d& T_body_lidar, PoseFn T_world_body) {
  Scan scan;
  scan.duration_s = 0.1;
  const int n = 12000;
  for (int i = 0; i < n; ++i) {
    const double t = 0.1 * i / n;
    const double azimuth = (std::fmod(i * 0.6180339887, 1.0) - 0.5) * 80.0 * kDeg;
    const double elevation = (std::fmod(i * 0.7548776662, 1.0) - 0.5) * 25.0 * kDeg;
    const Eigen::Vector3d dir = Direction(azimuth, elevation);
    const Eigen::Isometry3d T_world_lidar = T_world_body(t) * T_body_lidar;
    const double r = world.Cast(T_world_lidar.translation(), T_world_lidar.linear() * dir);
    if (r <= 0.0 || r > 150.0) continue;
    scan.points.push_back(MakePoint(r * dir, static_cast<uint8_t>(i % 6), t));
  }
  return scan;
}

/// Largest distance of a deskewed scan's points (body at the frame end) from the world.
double WorstDistance(const World& world, const Scan& scan, const Eigen::Isometry3d& T_world_end) {
  double worst = 0.0;
  for (const ScanPoint& p : scan.points) {
    worst = std::max(worst, world.Distance(T_world_end * p.p.cast<double>()));
  }
  return worst;
}

TEST(Deskew, LinearMotionPutsPointsBackOnTheWorld) {
  // 100 km/h forward with a 0.3 rad/s yaw rate and a little climb, constant over the frame in
  // the sense Deskew assumes: T_end_t interpolates linearly from T_end_start to identity.
  const World world;
  const Eigen::Isometry3d T_body_lidar = UpLidarExtrinsic();
  Eigen::Isometry3d T_end_start = Eigen::Isometry3d::Identity();
  T_end_start.linear() = Eigen::AngleAxisd(-0.03, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T_end_start.translation() = Eigen::Vector3d(-2.78, 0.04, -0.02);
  Eigen::Isometry3d T_world_end = Eigen::Isometry3d::Identity();
  T_world_end.translation() = Eigen::Vector3d(3.0, 0.5, 0.0);
  auto pose = [&](double t) { return T_world_end * Interpolate(T_end_start, 1.0 - t / 0.1); };
  Scan scan = SkewedScan(world, T_body_lidar, pose);
  ASSERT_GT(scan.points.size(), 10000u);
  const Scan raw = scan;

  Deskew(T_body_lidar, T_end_start, &scan);
  EXPECT_LT(WorstDistance(world, scan, T_world_end), 1e-4);
  for (size_t i = 0; i < scan.points.size(); ++i) {  // what Deskew must not touch
    EXPECT_EQ(scan.points[i].range_m, raw.points[i].range_m);
    EXPECT_EQ(scan.points[i].time_s, raw.points[i].time_s);
    EXPECT_EQ(scan.points[i].line, raw.points[i].line);
  }

  // Without motion compensation (only the extrinsic) the early points are metres off.
  Scan skewed = raw;
  Deskew(T_body_lidar, Eigen::Isometry3d::Identity(), &skewed);
  EXPECT_GT(WorstDistance(world, skewed, T_world_end), 1.0);
}

TEST(Deskew, ConstantVelocityAndYawRateOnAnArc) {
  // A true arc: 30 m/s forward, 0.2 rad/s yaw. Linear interpolation of the translation cuts the
  // chord: the sagitta v T (w T) / 8 = 7.5 mm bounds the residual.
  const World world;
  const Eigen::Isometry3d T_body_lidar = UpLidarExtrinsic();
  const double v = 30.0, w = 0.2;
  auto pose = [&](double t) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = Eigen::AngleAxisd(w * t, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(v / w * std::sin(w * t), v / w * (1.0 - std::cos(w * t)), 0);
    return T;
  };
  Scan scan = SkewedScan(world, T_body_lidar, pose);
  const Eigen::Isometry3d T_end_start = pose(0.1).inverse() * pose(0.0);
  Scan raw = scan;
  Deskew(T_body_lidar, T_end_start, &scan);
  EXPECT_LT(WorstDistance(world, scan, pose(0.1)), 0.01);
  Deskew(T_body_lidar, Eigen::Isometry3d::Identity(), &raw);
  EXPECT_GT(WorstDistance(world, raw, pose(0.1)), 1.0);
}

TEST(Deskew, SampledMotionFollowsAPitchDipWithinTheFrame) {
  // 30 m/s forward while the body dips 1.3 mrad nose-up and back within the frame (a rail
  // joint's ring, 6 Hz): the frame's ends agree, so interpolating between them sees no rotation
  // at all, and the ground 30-60 m ahead lands centimetres off. Sampled every 2.5 ms (what the
  // estimator does with the gyro) it lands within a millimetre.
  const World world;
  const Eigen::Isometry3d T_body_lidar = UpLidarExtrinsic();
  auto pose = [](double t) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    const double dip = -1.3e-3 * std::sin(M_PI * t / 0.1) * std::sin(M_PI * t / 0.1);
    T.linear() = Eigen::AngleAxisd(dip, Eigen::Vector3d::UnitY()).toRotationMatrix();
    T.translation() = Eigen::Vector3d(30.0 * t, 0.0, 0.0);
    return T;
  };
  const Scan raw = SkewedScan(world, T_body_lidar, pose);
  const Eigen::Isometry3d T_end = pose(0.1);
  FrameMotion motion;
  for (int k = 0; k <= 40; ++k) {
    motion.t_s.push_back(0.0025 * k);
    motion.T_end_t.push_back(T_end.inverse() * pose(0.0025 * k));
  }
  Scan sampled = raw;
  Deskew(T_body_lidar, motion, &sampled);
  EXPECT_LT(WorstDistance(world, sampled, T_end), 1e-3);
  Scan linear = raw;
  Deskew(T_body_lidar, T_end.inverse() * pose(0.0), &linear);
  EXPECT_GT(WorstDistance(world, linear, T_end), 0.02);
  // A linear motion sampled finely is the linear deskew: each point finds its segment, and the
  // points stamped after the last sample extrapolate it.
  const Eigen::Isometry3d T_end_start = T_end.inverse() * pose(0.0);
  FrameMotion linear_sampled;
  for (int k = 0; k <= 40; ++k) {
    linear_sampled.t_s.push_back(0.0025 * k);
    linear_sampled.T_end_t.push_back(Interpolate(T_end_start, 1.0 - 0.0025 * k / 0.1));
  }
  Scan late = raw;
  for (ScanPoint& p : late.points) p.time_s *= 1.2f;  // the last sixth beyond the frame end
  Scan by_samples = late;
  Deskew(T_body_lidar, linear_sampled, &by_samples);
  Deskew(T_body_lidar, T_end_start, &late);
  for (size_t i = 0; i < late.points.size(); ++i)
    ASSERT_LT((by_samples.points[i].p - late.points[i].p).norm(), 1e-4) << i;
}

/// Figures of the filters on simulated frames, per point kind.
struct KindCounts {
  std::map<sim::PointKind, size_t> in, out;
  size_t surface_beyond_min = 0;

  double Removed(sim::PointKind kind) const {
    const size_t n = in.count(kind) ? in.at(kind) : 0;
    const size_t kept = out.count(kind) ? out.at(kind) : 0;
    return n ? 1.0 - static_cast<double>(kept) / n : 0.0;
  }
};

/// Scans `frame` of LiDAR `unit` and counts its points by kind before and after Preprocess()
/// into `all`, and before and after the bleeding filter on its own into `bleeding_stage`.
void CountFrame(const sim::Simulator& simulator,
                uint64_t frame,
                size_t unit,
                const PreprocessOptions& options,
                KindCounts* all,
                KindCounts* bleeding_stage) {
  const sim::TruthMotion& truth = simulator.truth();
  io::LidarFrame message;
  std::vector<sim::PointKind> kinds;
  simulator.lidars()[unit].Scan(
      frame,
      frame * 0.1,
      [&truth](double t) { return truth.Pose(t); },
      simulator.caster(),
      &message.points,
      &kinds);
  std::map<std::tuple<float, float, float>, sim::PointKind> kind_of;
  for (size_t i = 0; i < kinds.size(); ++i) {
    const io::LivoxPoint& p = message.points[i];
    if (kinds[i] == sim::PointKind::kNoReturn) continue;
    kind_of[{p.x, p.y, p.z}] = kinds[i];
    const bool beyond_min = Eigen::Vector3f(p.x, p.y, p.z).norm() >= options.min_range_m;
    if (kinds[i] != sim::PointKind::kSurface || beyond_min) ++all->in[kinds[i]];
  }
  auto count_out = [&kind_of](const Scan& scan, KindCounts* counts) {
    for (const ScanPoint& p : scan.points) ++counts->out[kind_of.at({p.p.x(), p.p.y(), p.p.z()})];
  };
  Scan scan = ScanFromLidarFrame(message, static_cast<int>(unit), 0.1);
  // The bleeding filter on its own (the occupancy grid also takes many mixed returns).
  Scan alone = scan;
  RemoveNearAndFarPoints(options, &alone, nullptr);
  for (const ScanPoint& p : alone.points)
    ++bleeding_stage->in[kind_of.at({p.p.x(), p.p.y(), p.p.z()})];
  RemoveBoundaryBleeding(options, &alone, nullptr);
  count_out(alone, bleeding_stage);

  const PreprocessStats stats = Preprocess(options, &scan);
  EXPECT_EQ(stats.input - stats.near_or_far - stats.flicker - stats.bleeding, stats.output);
  count_out(scan, all);
}

TEST(Preprocess, SimulatedFramesLoseTheirArtefactsAndKeepTheirSurfaces) {
  sim::Scenario scenario;
  std::string error;
  ASSERT_TRUE(sim::LoadScenario("rich_low_station_a", &scenario, &error)) << error;
  // The low sun straight ahead of the up LiDAR, as in the simulator's own artefact test.
  scenario.sun_azimuth_deg = scenario.initial_azimuth_deg;
  scenario.sun_elevation_deg = 12.0;
  sim::SimOptions sim_options;
  sim_options.duration_s = 30.0;
  auto simulator = sim::Simulator::Create(scenario, sim_options, &error);
  ASSERT_TRUE(simulator) << error;
  const PreprocessOptions options;
  KindCounts all, bleeding_stage;
  for (uint64_t frame : {60, 120, 180, 240}) {  // moving off and through the station
    for (size_t unit = 0; unit < simulator->lidars().size(); ++unit)
      CountFrame(*simulator, frame, unit, options, &all, &bleeding_stage);
  }
  using sim::PointKind;
  ASSERT_GT(all.in[PointKind::kSunFlicker], 200u);
  ASSERT_GT(all.in[PointKind::kBleeding], 100u);
  const double flicker = all.Removed(PointKind::kSunFlicker);
  const double bleeding = all.Removed(PointKind::kBleeding);
  const double surface_kept = 1.0 - all.Removed(PointKind::kSurface);
  const double bleeding_alone = bleeding_stage.Removed(PointKind::kBleeding);
  std::printf(
      "flicker %zu removed %.1f%%, bleeding %zu removed %.1f%% (bleeding filter alone %.1f%%), "
      "body %zu removed %.1f%%, surface beyond min range %zu kept %.2f%%\n",
      all.in[PointKind::kSunFlicker],
      100.0 * flicker,
      all.in[PointKind::kBleeding],
      100.0 * bleeding,
      100.0 * bleeding_alone,
      all.in[PointKind::kBody],
      100.0 * all.Removed(PointKind::kBody),
      all.in[PointKind::kSurface],
      100.0 * surface_kept);
  EXPECT_GE(flicker, 0.90);
  EXPECT_GE(bleeding, 0.60);
  EXPECT_GE(bleeding_alone, 0.50);
  EXPECT_GE(surface_kept, 0.95);
  EXPECT_EQ(all.Removed(PointKind::kBody), 1.0);  // the roof edge is under min_range_m
}

}  // namespace
}  // namespace raillomer
