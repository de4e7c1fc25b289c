// The map sharpness check on constructed maps with known answers: the spread normal to a plane,
// the height difference of a rail head between two submaps, and which corridor surfaces count.
#include <algorithm>
#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "estimator/eval/map_sharpness.h"
#include "estimator/sim/world.h"

namespace raillomer::eval {
namespace {

using Vec3 = Eigen::Vector3d;

const Vec3 kOrigin(432000.0, 3585000.0, 30.0);

/// A 20 m x 20 m horizontal plane at height 1 m above kOrigin, as two triangles.
std::vector<ReferenceTriangle> Floor() {
  const Vec3 a = kOrigin + Vec3(0, 0, 1), b = kOrigin + Vec3(20, 0, 1),
             c = kOrigin + Vec3(20, 20, 1), d = kOrigin + Vec3(0, 20, 1);
  return {{ReferenceTriangle::Kind::kPlane, a, b, c}, {ReferenceTriangle::Kind::kPlane, a, c, d}};
}

/// A rail head's top, 72 mm wide and `length` long along x from kOrigin, as two triangles.
std::vector<ReferenceTriangle> RailHeadTop(double length) {
  const Vec3 a = kOrigin + Vec3(0, -0.036, 0), b = kOrigin + Vec3(length, -0.036, 0),
             c = kOrigin + Vec3(length, 0.036, 0), d = kOrigin + Vec3(0, 0.036, 0);
  return {{ReferenceTriangle::Kind::kRailHead, a, b, c},
          {ReferenceTriangle::Kind::kRailHead, a, c, d}};
}

/// A submap of points on the floor with Gaussian noise of `sigma` along z, raised by `lift`.
api::Submap FloorSubmap(double sigma, double lift, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, sigma);
  api::Submap s;
  s.origin = kOrigin;
  for (double x = 0.5; x < 19.5; x += 0.2) {
    for (double y = 0.5; y < 19.5; y += 0.2) {
      s.points.emplace_back(Eigen::Vector3f(static_cast<float>(x),
                                            static_cast<float>(y),
                                            static_cast<float>(1.0 + lift + noise(rng))));
    }
  }
  return s;
}

TEST(MapSharpness, PlaneSpreadIsTheNoiseNormalToThePlane) {
  MapSharpness sharpness(Floor());
  // The truth alignment only assigns points to surfaces: a small error in it changes nothing.
  Eigen::Isometry3d T_truth_est = Eigen::Isometry3d::Identity();
  T_truth_est.translation() = Vec3(0.05, -0.05, 0.03);
  sharpness.AddSubmap(FloorSubmap(0.02, 0.0, 1), T_truth_est);
  const SharpnessResult r = sharpness.Result();
  EXPECT_EQ(r.submaps, 1u);
  EXPECT_EQ(r.plane_patches, 4u);  // 10 m patches
  EXPECT_GT(r.plane_points, 8000u);
  EXPECT_NEAR(r.plane_rms_m, 0.02, 0.001);
}

TEST(MapSharpness, TwoSubmapsOffsetFromEachOtherBlurThePlane) {
  MapSharpness sharpness(Floor());
  sharpness.AddSubmap(FloorSubmap(0.0, 0.0, 1), Eigen::Isometry3d::Identity());
  // The second submap sits 6 cm higher; its alignment to the truth takes that out again.
  Eigen::Isometry3d T_truth_est = Eigen::Isometry3d::Identity();
  T_truth_est.translation() = Vec3(0.0, 0.0, -0.06);
  sharpness.AddSubmap(FloorSubmap(0.0, 0.06, 2), T_truth_est);
  EXPECT_NEAR(sharpness.Result().plane_rms_m, 0.03, 0.001);  // +-3 cm about the fitted plane
  // Each patch tells the two submaps apart: 3 cm below and above the fitted plane (its normal
  // may point either way), each as sharp as its points.
  const std::vector<PlanePatchReport> patches = sharpness.PlanePatches();
  ASSERT_EQ(patches.size(), 4u);
  for (const PlanePatchReport& patch : patches) {
    EXPECT_NEAR(patch.rms_m, 0.03, 0.001);
    ASSERT_EQ(patch.samples.size(), 2u);
    EXPECT_NEAR(std::fabs(patch.samples[0].offset_m), 0.03, 0.001);
    EXPECT_NEAR(patch.samples[0].offset_m, -patch.samples[1].offset_m, 0.001);
    EXPECT_LT(patch.samples[0].rms_m, 0.001);
  }
  const std::string csv = PlanePatchesCsv(patches);
  EXPECT_EQ(csv.rfind("x,y,z,patch_rms_m,patch_points,submap,points,offset_m,rms_m\n", 0), 0u);
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 9);  // a header and 2 rows per patch
}

TEST(MapSharpness, RailHeadHeightsAreComparedBetweenSubmaps) {
  MapSharpness sharpness(RailHeadTop(4.0));
  for (int k = 0; k < 3; ++k) {
    api::Submap s;
    s.index = static_cast<uint32_t>(10 + k);
    s.origin = kOrigin;
    const double lift = k == 2 ? 0.025 : 0.0;  // the third submap sees the rail 25 mm higher
    for (double x = 0.05; x < 4.0; x += 0.1) {
      s.points.emplace_back(Eigen::Vector3f(static_cast<float>(x), 0.0f, static_cast<float>(lift)));
    }
    s.points.emplace_back(Eigen::Vector3f(1.0f, 0.3f, 0.0f));  // beside the rail: not counted
    // The truth alignment of the third takes its lift out: its own error is zero there.
    Eigen::Isometry3d T_truth_est = Eigen::Isometry3d::Identity();
    T_truth_est.translation().z() = -lift;
    sharpness.AddSubmap(s, T_truth_est);
  }
  const SharpnessResult r = sharpness.Result();
  EXPECT_EQ(r.rail_points, 120u);
  EXPECT_EQ(r.rail_segments, 2u);  // 2 m segments
  EXPECT_NEAR(r.rail_spread_max_m, 0.025, 1e-4);
  EXPECT_NEAR(r.rail_spread_median_m, 0.025, 1e-4);

  // Segment by segment: which submaps saw it, how many points, at what height.
  const std::vector<RailSegmentReport> segments = sharpness.RailSegments();
  ASSERT_EQ(segments.size(), 2u);
  for (const RailSegmentReport& segment : segments) {
    EXPECT_NEAR(segment.spread_m, 0.025, 1e-4);
    ASSERT_EQ(segment.samples.size(), 3u);
    for (size_t k = 0; k < 3; ++k) {
      const RailSegmentReport::Sample& sample = segment.samples[k];
      EXPECT_EQ(sample.submap, 10 + k);
      EXPECT_EQ(sample.points, 20u);
      EXPECT_NEAR(sample.height_m, k == 2 ? 0.025 : 0.0, 1e-5);
      EXPECT_NEAR(sample.rms_m, 0.0, 1e-5);
      EXPECT_NEAR(sample.truth_offset_m, 0.0, 1e-5);
    }
  }
  const std::string csv = RailSegmentsCsv(segments);
  EXPECT_EQ(csv.substr(0, csv.find('\n')),
            "x,y,z,spread_m,submap,points,height_m,rms_m,truth_offset_m");
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 1 + 6);
  EXPECT_NE(csv.find(",0.0250,12,20,0.0250,0.0000,0.0000\n"), std::string::npos) << csv;
}

TEST(MapSharpness, PointsAtARailHeadsEdgeAreNotTakenForItsTop) {
  // A rail head's sides drop from its edges: a map point there, below the top, is no measure
  // of the top's height.
  MapSharpness sharpness(RailHeadTop(2.0));
  for (int k = 0; k < 2; ++k) {
    api::Submap s;
    s.index = static_cast<uint32_t>(k);
    s.origin = kOrigin;
    for (double x = 0.05; x < 2.0; x += 0.2) {
      s.points.emplace_back(static_cast<float>(x), 0.0f, 0.0f);                  // the top's middle
      s.points.emplace_back(static_cast<float>(x), 0.024f, 0.003f);              // 12 mm inside
      if (k == 1) s.points.emplace_back(static_cast<float>(x), 0.033f, -0.03f);  // 3 mm: a side
      if (k == 1) s.points.emplace_back(static_cast<float>(x), 0.04f, -0.02f);   // beyond it
    }
    sharpness.AddSubmap(s, Eigen::Isometry3d::Identity());
  }
  const SharpnessResult r = sharpness.Result();
  EXPECT_EQ(r.rail_points, 40u);
  EXPECT_EQ(r.rail_segments, 1u);
  EXPECT_NEAR(r.rail_spread_max_m, 0.0, 1e-6);

  // A point 12 mm inside the edge counts wherever it is: a submap 25 mm low there is seen.
  api::Submap low;
  low.index = 2;
  low.origin = kOrigin;
  for (double x = 0.05; x < 2.0; x += 0.2) {
    low.points.emplace_back(static_cast<float>(x), 0.024f, -0.025f);
  }
  sharpness.AddSubmap(low, Eigen::Isometry3d::Identity());
  EXPECT_NEAR(sharpness.Result().rail_spread_max_m, 0.0265, 1e-4);
}

TEST(MapSharpness, ReferenceSurfacesArePlatformTopsWallsAndRailHeads) {
  sim::Mesh mesh;
  const Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  mesh.AddBox(Vec3(0, 0, 0.5), R, Vec3(10, 2, 0.5), sim::Material::kPlatform);  // top, bottom
  mesh.AddBox(Vec3(0, 20, 3), R, Vec3(5, 5, 3), sim::Material::kBuilding);      // 4 walls
  mesh.AddBox(Vec3(0, -5, 3), R, Vec3(1, 1, 1), sim::Material::kVegetation);    // not at all
  // A rail on a 3.5 % grade, with the simulator's profile: head top at z 0 (72 mm wide), the
  // head's underside at z -0.05 either side of the web, the foot's top at z -0.16 and its bottom
  // at z -0.172 (150 mm wide). Only the head top counts; faces wound either way, as in the
  // corridor mesh.
  constexpr double kGrade = 0.035;
  const auto strip = [&](double from_y, double to_y, double z, bool up) {
    const Vec3 a(0, from_y, z), b(2, from_y, z + 2 * kGrade), c(2, to_y, z + 2 * kGrade),
        d(0, to_y, z);
    if (up) {
      mesh.AddQuad(a, b, c, d, sim::Material::kRail);
    } else {
      mesh.AddQuad(d, c, b, a, sim::Material::kRail);
    }
  };
  strip(-0.036, 0.036, 0.0, false);
  strip(0.0083, 0.036, -0.05, true);
  strip(-0.036, -0.0083, -0.05, false);
  strip(0.0083, 0.075, -0.16, true);
  strip(-0.075, -0.0083, -0.16, true);
  strip(-0.075, 0.075, -0.172, false);
  const std::vector<ReferenceTriangle> t = SelectReferenceTriangles(mesh, kOrigin);
  int planes = 0, rails = 0;
  for (const ReferenceTriangle& r : t) {
    if (r.kind == ReferenceTriangle::Kind::kPlane) ++planes;
    if (r.kind == ReferenceTriangle::Kind::kRailHead) {
      ++rails;
      for (const Vec3& corner : {r.a, r.b, r.c}) {
        EXPECT_NEAR(corner.z(), kOrigin.z() + kGrade * (corner.x() - kOrigin.x()), 1e-6);
      }
    }
  }
  EXPECT_EQ(planes, 4 + 8);  // the platform's top and bottom, the building's four walls
  EXPECT_EQ(rails, 2);
}

}  // namespace
}  // namespace raillomer::eval
