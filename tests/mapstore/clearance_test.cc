// The structure gauge against known answers: a straight track's box, the widening on a curve,
// the cant's tilt, the vegetation rule.
#include <cmath>

#include <gtest/gtest.h>

#include "mapstore/clearance.h"

namespace raillomer::mapstore {
namespace {

TEST(Clearance, OnStraightTrackTheMarginIsTheDistanceToTheBox) {
  const StructureGauge gauge{ClearanceOptions()};
  const TrackSection straight{30.0, 0.0, 0.0};
  auto margin = [&](double offset, double z) {
    return gauge.Margin(straight, ToSection(straight, offset, z));
  };
  EXPECT_NEAR(margin(2.0, 31.0), -0.44, 1e-9);  // inside, 0.44 m from the side
  EXPECT_NEAR(margin(-2.0, 31.0), -0.44, 1e-9);
  EXPECT_NEAR(margin(3.0, 31.0), 0.56, 1e-9);  // outside, 0.56 m of room
  EXPECT_NEAR(margin(0.0, 37.0), 0.45, 1e-9);  // above the 6.55 m top
  EXPECT_NEAR(margin(0.0, 33.0), -2.44, 1e-9);
  EXPECT_NEAR(margin(0.5, 29.5), 0.5, 1e-9);                     // below the rail plane
  EXPECT_NEAR(margin(3.44, 38.55), std::hypot(1.0, 2.0), 1e-9);  // off a corner
}

TEST(Clearance, OnACurveTheGaugeWidensMoreOnTheOutside) {
  const StructureGauge gauge{ClearanceOptions()};
  const TrackSection left_curve{0.0, 0.0, 1.0 / 500.0};  // R 500 m, turning left
  // Inside (left): 40500 / 500 = 81 mm; outside (right): 44000 / 500 = 88 mm.
  EXPECT_NEAR(gauge.Margin(left_curve, {2.5, 1.0}), -(2.521 - 2.5), 1e-9);
  EXPECT_NEAR(gauge.Margin(left_curve, {-2.5, 1.0}), -(2.528 - 2.5), 1e-9);
  const TrackSection right_curve{0.0, 0.0, -1.0 / 500.0};
  EXPECT_NEAR(gauge.Margin(right_curve, {2.5, 1.0}), -(2.528 - 2.5), 1e-9);
  // A gentle curve (R 20 km) is treated as straight.
  EXPECT_NEAR(gauge.Margin({0.0, 0.0, 1.0 / 20000.0}, {2.5, 1.0}), 0.06, 1e-9);
  const std::vector<Eigen::Vector2d> outline = gauge.Outline(left_curve);
  EXPECT_NEAR(outline[1].x(), 2.521, 1e-9);
  EXPECT_NEAR(outline[0].x(), -2.528, 1e-9);
}

TEST(Clearance, TheCantTiltsTheSection) {
  // 150 mm of cant, left rail up: the plane turns by asin(0.1) about the track centre.
  const TrackSection canted{10.0, 0.15, 0.0};
  const double s = 0.1, c = std::sqrt(1.0 - 0.01);
  const SectionPoint p = ToSection(canted, 2.0, 14.0);
  EXPECT_NEAR(p.lateral_m, c * 2.0 + s * 4.0, 1e-9);
  EXPECT_NEAR(p.height_m, -s * 2.0 + c * 4.0, 1e-9);
  // A point 4 m up, 2.2 m left is inside on the level but outside once the gauge leans over
  // to the low (right) side: 2.2 c + 4 s = 2.589 > 2.44.
  const StructureGauge gauge{ClearanceOptions()};
  EXPECT_LT(gauge.Margin({10.0, 0.0, 0.0}, ToSection({10.0, 0.0, 0.0}, 2.2, 14.0)), 0.0);
  EXPECT_GT(gauge.Margin(canted, ToSection(canted, 2.2, 14.0)), 0.0);
}

TEST(Clearance, VegetationMayNotBeTallerThanItsDistanceLessThreeMetres) {
  const StructureGauge gauge{ClearanceOptions()};
  EXPECT_NEAR(gauge.VegetationMargin({5.0, 1.5}), 0.5, 1e-9);    // may grow 0.5 m more
  EXPECT_NEAR(gauge.VegetationMargin({-4.0, 2.0}), -1.0, 1e-9);  // 1 m too tall
  EXPECT_TRUE(std::isinf(gauge.VegetationMargin({7.0, 9.0})));   // beyond the 6 m zone
  std::string error;
  EXPECT_TRUE(ClearanceOptions().IsValid(&error));
  ClearanceOptions bad;
  bad.gauge_outline.resize(2);
  EXPECT_FALSE(bad.IsValid(&error));
  EXPECT_NE(error.find("3 corners"), std::string::npos);
}

TEST(Clearance, OneStrayPointDoesNotPutAChangeInsideTheGauge) {
  const StructureGauge gauge{ClearanceOptions()};
  const TrackSection straight{0.0, 0.0, 0.0};
  // A box 2 m left whose top lies 2 mm below the rail plane (outside the gauge, which starts
  // at it), measured on that top but for one return one 8-mm quantisation step higher.
  ClearanceTally box(gauge);
  for (int i = 0; i < 12; ++i) box.Add(straight, {1.8 + 0.04 * i, -0.002});
  box.Add(straight, {1.9, -0.3});
  box.Add(straight, {2.14, 0.006});
  EXPECT_NEAR(box.margin_m(), 0.002, 1e-9);
  EXPECT_NEAR(box.height_max_m(), -0.002, 1e-9);
  EXPECT_NEAR(box.height_min_m(), -0.002, 1e-9);  // the second lowest: the top's
  EXPECT_NEAR(box.vegetation_margin_m(), 1.84 - 3.0 + 0.002, 1e-9);
  // Two returns inside are a change inside: the margin is the second deepest.
  box.Add(straight, {2.0, 0.05});
  EXPECT_NEAR(box.margin_m(), -0.006, 1e-9);
  EXPECT_NEAR(box.height_max_m(), 0.006, 1e-9);
  // A change of one point is measured by that point; of none, nothing is in the way.
  ClearanceTally one(gauge);
  one.Add(straight, {2.0, 0.05});
  EXPECT_NEAR(one.margin_m(), -0.05, 1e-9);
  EXPECT_NEAR(one.height_max_m(), 0.05, 1e-9);
  EXPECT_TRUE(std::isinf(ClearanceTally(gauge).margin_m()));
  // Beyond the vegetation zone, it says nothing of vegetation.
  ClearanceTally far(gauge);
  far.Add(straight, {7.0, 9.0});
  EXPECT_TRUE(std::isinf(far.vegetation_margin_m()));
}

}  // namespace
}  // namespace raillomer::mapstore
