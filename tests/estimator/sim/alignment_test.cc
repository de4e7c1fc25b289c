// The track alignment against closed-form geometry: straights along the azimuth, circular arcs,
// clothoid transitions, cant on the outer rail, eased grades, and continuity between knots.

#include "estimator/sim/alignment.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "tests/estimator/sim/scenario_builders.h"

namespace raillomer::sim {
namespace {

using test::Curve;
using test::Straight;

constexpr double kDeg = M_PI / 180.0;

Scenario WithAlignment(std::vector<AlignmentSegment> segments, double azimuth_deg = 90.0) {
  Scenario s;
  s.alignment = std::move(segments);
  s.initial_azimuth_deg = azimuth_deg;
  return s;
}

/// Signed curvature of the horizontal track from positions only (second differences).
double NumericCurvature(const Alignment& a, double s, double h = 1.0) {
  const Eigen::Vector2d p0 = a.At(s - h).position.head<2>();
  const Eigen::Vector2d p1 = a.At(s).position.head<2>();
  const Eigen::Vector2d p2 = a.At(s + h).position.head<2>();
  const Eigen::Vector2d d1 = (p2 - p0) / (2.0 * h);
  const Eigen::Vector2d d2 = (p2 - 2.0 * p1 + p0) / (h * h);
  return (d1.x() * d2.y() - d1.y() * d2.x()) / std::pow(d1.norm(), 3);
}

double WrapAngle(double a) { return std::atan2(std::sin(a), std::cos(a)); }

TEST(PiecewiseLinear, ValueIntegralAndSlope) {
  PiecewiseLinear f;
  f.Add(0.0, 1.0);
  f.Add(10.0, 3.0);
  f.Add(20.0, 3.0);
  EXPECT_DOUBLE_EQ(f.Value(-5.0), 1.0);
  EXPECT_DOUBLE_EQ(f.Value(5.0), 2.0);
  EXPECT_DOUBLE_EQ(f.Value(15.0), 3.0);
  EXPECT_DOUBLE_EQ(f.Value(25.0), 3.0);
  EXPECT_DOUBLE_EQ(f.Slope(5.0), 0.2);
  EXPECT_DOUBLE_EQ(f.Slope(15.0), 0.0);
  EXPECT_NEAR(f.Integral(5.0), 5.0 * 1.0 + 0.5 * 0.2 * 25.0, 1e-12);
  EXPECT_NEAR(f.Integral(10.0), 20.0, 1e-12);
  EXPECT_NEAR(f.Integral(20.0), 50.0, 1e-12);
  EXPECT_NEAR(f.Integral(24.0), 62.0, 1e-12);  // continues with the last value
}

TEST(Alignment, StraightFollowsTheInitialAzimuth) {
  {
    const Alignment a(WithAlignment({Straight(500.0)}, 90.0));  // due east
    EXPECT_DOUBLE_EQ(a.length_m(), 500.0);
    const TrackPoint p = a.At(100.0);
    EXPECT_NEAR(p.position.x(), 100.0, 1e-9);
    EXPECT_NEAR(p.position.y(), 0.0, 1e-9);
    EXPECT_NEAR(p.position.z(), 0.0, 1e-12);
    EXPECT_NEAR(p.heading_rad, 0.0, 1e-12);
    EXPECT_NEAR(p.curvature, 0.0, 1e-15);
    EXPECT_NEAR((p.Left() - Eigen::Vector3d::UnitY()).norm(), 0.0, 1e-12);  // north
  }
  {
    const Alignment a(WithAlignment({Straight(500.0)}, 0.0));  // due north
    const TrackPoint p = a.At(100.0);
    EXPECT_NEAR(p.position.x(), 0.0, 1e-9);
    EXPECT_NEAR(p.position.y(), 100.0, 1e-9);
    EXPECT_NEAR(p.heading_rad, M_PI / 2.0, 1e-12);
    EXPECT_NEAR((p.Left() + Eigen::Vector3d::UnitX()).norm(), 0.0, 1e-12);  // west
  }
  {
    const Alignment a(WithAlignment({Straight(500.0)}, 30.0));  // clockwise from north
    const TrackPoint p = a.At(200.0);
    EXPECT_NEAR(p.position.x(), 200.0 * std::sin(30.0 * kDeg), 1e-9);
    EXPECT_NEAR(p.position.y(), 200.0 * std::cos(30.0 * kDeg), 1e-9);
    // The track frame's x axis is the direction of travel.
    const Eigen::Vector3d forward = p.Rotation().col(0);
    EXPECT_NEAR(forward.x(), std::sin(30.0 * kDeg), 1e-12);
    EXPECT_NEAR(forward.y(), std::cos(30.0 * kDeg), 1e-12);
    // Beyond the end the line continues straight.
    const TrackPoint beyond = a.At(550.0);
    EXPECT_NEAR(beyond.position.x(), 550.0 * std::sin(30.0 * kDeg), 1e-9);
    EXPECT_NEAR(beyond.position.y(), 550.0 * std::cos(30.0 * kDeg), 1e-9);
    // Beside: lateral in the horizontal plane, height above the rail top.
    const Eigen::Vector3d beside = a.Beside(200.0, 3.0, 1.5);
    EXPECT_NEAR(
        (beside - p.position - 3.0 * p.Left() - Eigen::Vector3d(0, 0, 1.5)).norm(), 0.0, 1e-12);
    EXPECT_NEAR(beside.x(), 200.0 * std::sin(30.0 * kDeg) - 3.0 * std::cos(30.0 * kDeg), 1e-9);
  }
}

TEST(Alignment, CircularCurveMatchesTheCircle) {
  const double R = 500.0, L = 300.0;
  for (int direction : {1, -1}) {
    SCOPED_TRACE(direction > 0 ? "left" : "right");
    const Alignment a(WithAlignment({Straight(100.0), Curve(L, R, direction), Straight(200.0)}));
    EXPECT_NEAR(a.length_m(), 600.0, 1e-9);
    const double k = direction / R;
    // Start of the arc at (100, 0) heading east; centre R to the left (or right).
    const Eigen::Vector2d centre(100.0, direction * R);
    for (double arc = 0.0; arc <= L; arc += 25.0) {
      const double phi = arc / R;
      const TrackPoint p = a.At(100.0 + arc);
      const Eigen::Vector2d expected(100.0 + R * std::sin(phi),
                                     direction * R * (1.0 - std::cos(phi)));
      EXPECT_LT((p.position.head<2>() - expected).norm(), 1e-3) << "arc " << arc;
      EXPECT_NEAR((p.position.head<2>() - centre).norm(), R, 1e-3);
      EXPECT_NEAR(p.heading_rad, k * arc, 1e-8);
    }
    // Heading changes by L / R over the arc.
    EXPECT_NEAR(a.At(100.0 + L).heading_rad - a.At(100.0).heading_rad, direction * L / R, 1e-8);
    EXPECT_NEAR(a.At(550.0).heading_rad, direction * L / R, 1e-8);
    // Curvature: reported and measured from positions alone.
    for (double s = 110.0; s <= 390.0; s += 20.0) {
      EXPECT_NEAR(a.At(s).curvature, k, 1e-12);
      EXPECT_NEAR(NumericCurvature(a, s), k, 1e-6) << "s " << s;
    }
    for (double s : {50.0, 450.0}) EXPECT_NEAR(NumericCurvature(a, s), 0.0, 1e-6);
  }
}

TEST(Alignment, ClothoidRampsCurvatureLinearly) {
  const double R = 600.0, L = 200.0, T = 80.0;
  const Alignment a(WithAlignment({Straight(100.0), Curve(L, R, 1, T), Straight(300.0)}));
  EXPECT_NEAR(a.length_m(), 100.0 + T + L + T + 300.0, 1e-9);
  const double k = 1.0 / R;
  for (double x = 0.0; x <= T; x += 10.0) {
    const double s = 100.0 + x;
    EXPECT_NEAR(a.At(s).curvature, k * x / T, 1e-9) << "x " << x;
    if (x >= 2.0 && x <= T - 2.0) {
      EXPECT_NEAR(NumericCurvature(a, s), k * x / T, 1e-6) << x;
    }
    EXPECT_NEAR(a.At(s).heading_rad, 0.5 * k * x * x / T, 1e-9);
  }
  // Exit transition ramps back down.
  const double exit = 100.0 + T + L;
  EXPECT_NEAR(a.At(exit + 0.25 * T).curvature, 0.75 * k, 1e-9);
  EXPECT_NEAR(NumericCurvature(a, exit + 0.5 * T), 0.5 * k, 1e-6);
  // Total heading change: arc plus half of each transition.
  EXPECT_NEAR(a.At(exit + T + 10.0).heading_rad, k * (L + T), 1e-9);
  // End of the entry clothoid against its series expansion (A^2 = R T).
  const Eigen::Vector2d end = a.At(100.0 + T).position.head<2>();
  const double x_series =
      T - std::pow(T, 3) / (40.0 * R * R) + std::pow(T, 5) / (3456.0 * std::pow(R, 4));
  const double y_series = T * T / (6.0 * R) - std::pow(T, 4) / (336.0 * std::pow(R, 3));
  EXPECT_NEAR(end.x() - 100.0, x_series, 1e-4);
  EXPECT_NEAR(end.y(), y_series, 1e-4);
}

TEST(Alignment, CantRaisesTheOuterRail) {
  const double cant_m = 0.12, T = 60.0;
  {
    const Alignment a(WithAlignment({Straight(100.0), Curve(200.0, 800.0, 1, T, 120.0)}));
    const TrackPoint arc = a.At(100.0 + T + 100.0);  // left curve: right rail is the outer one
    EXPECT_NEAR(arc.cant_m, -cant_m, 1e-12);
    EXPECT_LT(arc.roll_rad, 0.0);
    EXPECT_NEAR(arc.roll_rad, std::asin(-cant_m / 1.5), 1e-12);
    const Eigen::Matrix3d R = arc.Rotation();
    EXPECT_NEAR((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-12);
    EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
    EXPECT_LT(R.col(1).z(), 0.0);  // the left (inner) side is lower
    EXPECT_NEAR(R.col(1).z(), -cant_m / 1.5, 1e-12);
    // The inner rail head (0.75 m to the left) sits lower than the outer one.
    const Eigen::Vector3d left_rail = arc.position + R * Eigen::Vector3d(0, 0.75, 0);
    const Eigen::Vector3d right_rail = arc.position + R * Eigen::Vector3d(0, -0.75, 0);
    EXPECT_NEAR(right_rail.z() - left_rail.z(), cant_m, 1e-9);
    // Ramps in over the transition, zero on straights.
    EXPECT_NEAR(a.At(100.0 + 0.5 * T).cant_m, -0.5 * cant_m, 1e-9);
    EXPECT_NEAR(a.At(50.0).cant_m, 0.0, 1e-15);
    EXPECT_NEAR(a.At(50.0).roll_rad, 0.0, 1e-15);
  }
  {
    const Alignment a(WithAlignment({Straight(100.0), Curve(200.0, 800.0, -1, T, 120.0)}));
    const TrackPoint arc = a.At(100.0 + T + 100.0);  // right curve: left rail raised
    EXPECT_NEAR(arc.cant_m, cant_m, 1e-12);
    EXPECT_GT(arc.roll_rad, 0.0);
    EXPECT_GT(arc.Rotation().col(1).z(), 0.0);
  }
}

TEST(Alignment, GradesRiseAndEaseOverVerticalCurves) {
  Scenario s = WithAlignment({Straight(500.0), Straight(1000.0, 10.0), Straight(500.0, -5.0)});
  s.vertical_curve_m = 60.0;
  const Alignment a(s);
  // Far from the vertical curves: z rises by gradient * length.
  EXPECT_NEAR(a.At(900.0).position.z() - a.At(600.0).position.z(), 0.01 * 300.0, 1e-9);
  EXPECT_NEAR(a.At(300.0).position.z(), 0.0, 1e-12);
  EXPECT_NEAR(a.At(700.0).grade, 0.01, 1e-12);
  EXPECT_NEAR(a.At(1800.0).grade, -0.005, 1e-12);
  EXPECT_NEAR(a.At(1900.0).position.z() - a.At(1600.0).position.z(), -0.005 * 300.0, 1e-9);
  // The grade eases over 60 m centred on the change, as a smoothstep (so the pitch rate has no
  // steps): 3u^2 - 2u^3 of the change at u = 0.25 and 0.75.
  EXPECT_NEAR(a.At(470.0).grade, 0.0, 1e-9);
  EXPECT_NEAR(a.At(485.0).grade, 0.01 * 0.15625, 1e-9);
  EXPECT_NEAR(a.At(500.0).grade, 0.005, 1e-9);
  EXPECT_NEAR(a.At(515.0).grade, 0.01 * 0.84375, 1e-9);
  EXPECT_NEAR(a.At(530.0).grade, 0.01, 1e-9);
  EXPECT_NEAR(a.At(1500.0).grade, 0.0025, 1e-9);
  EXPECT_NEAR(a.At(530.0).position.z() - a.At(470.0).position.z(), 0.3, 1e-9);
  // The reported grade is the slope of the positions; the track frame pitches up with it.
  for (double at : {300.0, 480.0, 500.0, 520.0, 700.0, 1490.0, 1800.0}) {
    const double h = 0.05;
    const double slope = (a.At(at + h).position.z() - a.At(at - h).position.z()) / (2.0 * h);
    EXPECT_NEAR(slope, a.At(at).grade, 1e-7) << at;
  }
  const Eigen::Vector3d forward = a.At(700.0).Rotation().col(0);
  EXPECT_NEAR(forward.z(), std::sin(std::atan(0.01)), 1e-12);
  EXPECT_NEAR(forward.norm(), 1.0, 1e-12);
}

TEST(Alignment, ContinuousAcrossKnotsAndSegmentBoundaries) {
  // Transitions of 37 m put segment boundaries between the 5 m knots.
  Scenario s = WithAlignment({Straight(123.0),
                              Curve(211.0, 450.0, 1, 37.0, 110.0, 8.0),
                              Straight(96.0, -6.0),
                              Curve(180.0, 300.0, -1, 41.0, 150.0, 12.0),
                              Curve(0.5, 2000.0, 1),
                              Straight(150.0)},
                             47.0);
  s.vertical_curve_m = 40.0;
  const Alignment a(s);
  std::vector<double> checks;
  for (double at = 0.0; at <= a.length_m() + 1e-9; at += 5.0) checks.push_back(at);
  double boundary = 0.0;
  for (const AlignmentSegment& seg : s.alignment) {
    if (seg.kind == AlignmentSegment::Kind::kStraight) {
      boundary += seg.length_m;
      checks.push_back(boundary);
    } else {
      for (double part : {seg.transition_m, seg.length_m, seg.transition_m}) {
        boundary += part;
        checks.push_back(boundary);
      }
    }
  }
  EXPECT_NEAR(boundary, a.length_m(), 1e-9);
  const double eps = 1e-7;
  for (double at : checks) {
    const TrackPoint before = a.At(at - eps), after = a.At(at + eps);
    EXPECT_LT((after.position - before.position).norm(), 1e-6) << "s " << at;
    EXPECT_LT(std::fabs(WrapAngle(after.heading_rad - before.heading_rad)), 1e-8) << "s " << at;
  }
  // Dense walk: each 1 cm step moves the centreline by 1 cm (chainage is arc length).
  for (double at = 0.0; at < a.length_m(); at += 0.01) {
    const double step = (a.At(at + 0.01).position - a.At(at).position).norm();
    ASSERT_NEAR(step, 0.01, 2e-6) << "s " << at;
  }
}

}  // namespace
}  // namespace raillomer::sim
