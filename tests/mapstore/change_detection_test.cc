// Change detection of a stretch on scenes with known answers, each run made by casting the
// LiDARs' rays into a scene of boxes on a ground plane from poses along the track: an added
// box, a removed pole, a pole hidden behind a wagon (not observed, never removed), an
// unchanged scene seen from other poses (nothing), a lost wire (removed), and low boxes whose
// place the reference saw only down to the ground or slab just under them (added), and what a
// hanging bracket's other sampling left that only rising rays passed (not observed).
#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "mapstore/change_detection.h"

namespace raillomer::mapstore {
namespace {

using Box = Eigen::AlignedBox3d;

Box Make(double x0, double y0, double z0, double x1, double y1, double z1) {
  return Box(Eigen::Vector3d(x0, y0, z0), Eigen::Vector3d(x1, y1, z1));
}

/// The distance along a unit ray to a box (infinity if it misses), by slabs.
double Hit(const Box& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  double near = 0.0, far = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12) {
      if (o[a] < b.min()[a] || o[a] > b.max()[a]) return std::numeric_limits<double>::infinity();
      continue;
    }
    double t0 = (b.min()[a] - o[a]) / d[a], t1 = (b.max()[a] - o[a]) / d[a];
    if (t0 > t1) std::swap(t0, t1);
    near = std::max(near, t0);
    far = std::min(far, t1);
    if (near > far) return std::numeric_limits<double>::infinity();
  }
  return near;
}

/// A run through the scene: LiDAR poses every 2 m from `first_x` along x, `height_m` above
/// the ground, looking ahead, tilted up by `pitch_deg`; rays every 0.5 deg over the field of
/// view, returns within 100 m.
RunStretch Scan(const std::vector<Box>& scene,
                double first_x,
                double height_m = 2.0,
                double pitch_deg = 0.0) {
  RunStretch run;
  const Eigen::Matrix3d tilt =
      Eigen::AngleAxisd(-pitch_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  for (double x = first_x; x <= 60.0; x += 2.0) {
    Eigen::Isometry3d sensor = Eigen::Isometry3d::Identity();
    sensor.translation() = Eigen::Vector3d(x, 0.0, height_m);
    sensor.linear() = tilt;
    run.sensors.push_back(sensor);
    for (double az = -40.0; az <= 40.0; az += 0.5)
      for (double el = -25.0; el <= 10.0; el += 0.5) {
        const double a = az * M_PI / 180.0, e = el * M_PI / 180.0;
        const Eigen::Vector3d d =
            tilt *
            Eigen::Vector3d(std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e));
        const Eigen::Vector3d o = sensor.translation();
        double t = d.z() < 0.0 ? -o.z() / d.z() : std::numeric_limits<double>::infinity();
        for (const Box& b : scene) t = std::min(t, Hit(b, o, d));
        if (t > 100.0) continue;
        const Eigen::Vector3d p = o + t * d;
        if (std::abs(p.y()) > 20.0) continue;  // the corridor's width
        run.points.push_back(p);
      }
  }
  return run;
}

const Box kBuilding = Make(40.0, 10.0, 0.0, 50.0, 14.0, 5.0);
const Box kPole = Make(30.0, 4.0, 0.0, 30.3, 4.3, 6.0);

TEST(ChangeDetection, ABoxAddedBesideTheTrackIsFoundWhereItIs) {
  const Box box = Make(35.0, -3.6, 0.0, 36.2, -2.8, 1.6);
  StretchSummary summary;
  const std::vector<StretchChange> changes = CompareStretch(
      Scan({kBuilding, kPole}, 0.0), Scan({kBuilding, kPole, box}, 1.0), ChangeOptions(), &summary);
  ASSERT_EQ(changes.size(), 1u) << summary.objects << " objects";
  EXPECT_EQ(changes[0].kind, StretchChange::Kind::kAdded);
  // What the run saw of it: its faces towards the track, within a voxel of the box.
  EXPECT_LT((changes[0].centre.head<2>() - box.center().head<2>()).norm(), 0.6);
  EXPECT_GT(changes[0].box.sizes().z(), 1.2);
  EXPECT_GE(changes[0].seen_empty_share, 0.5);
  // The box's shadow on the ground behind it was not seen by the later run: not observed.
  EXPECT_GE(summary.not_observed, 1u);
}

TEST(ChangeDetection, ARemovedPoleIsFound) {
  const std::vector<StretchChange> changes =
      CompareStretch(Scan({kBuilding, kPole}, 0.0), Scan({kBuilding}, 1.0), ChangeOptions());
  ASSERT_EQ(changes.size(), 1u);
  EXPECT_EQ(changes[0].kind, StretchChange::Kind::kRemoved);
  EXPECT_LT((changes[0].centre.head<2>() - kPole.center().head<2>()).norm(), 0.3);
}

TEST(ChangeDetection, APoleHiddenBehindAWagonIsNotObservedNotRemoved) {
  // A wagon along the whole stretch stands between the track and a 3 m pole in the later run:
  // the pole is not in its map, but no ray of it passed where the pole stands.
  const Box low_pole = Make(30.0, 6.0, 0.0, 30.3, 6.3, 3.0);
  const Box wagon = Make(-5.0, 2.5, 0.0, 80.0, 3.5, 3.5);
  StretchSummary summary;
  const std::vector<StretchChange> changes = CompareStretch(Scan({kBuilding, low_pole}, 0.0),
                                                            Scan({kBuilding, low_pole, wagon}, 1.0),
                                                            ChangeOptions(),
                                                            &summary);
  // Only the wagon (in pieces where its far end is sparsely seen), within half a metre.
  Box near_wagon = wagon;
  near_wagon.min().array() -= 0.5;
  near_wagon.max().array() += 0.5;
  for (const StretchChange& c : changes) {
    EXPECT_EQ(c.kind, StretchChange::Kind::kAdded) << c.centre.transpose();
    EXPECT_TRUE(near_wagon.contains(c.centre)) << c.centre.transpose();
  }
  EXPECT_FALSE(changes.empty()) << "the wagon was not found";
  EXPECT_GE(summary.not_observed, 1u);
}

TEST(ChangeDetection, AnUnchangedSceneSeenFromOtherPosesHasNoChange) {
  StretchSummary summary;
  const std::vector<StretchChange> changes = CompareStretch(
      Scan({kBuilding, kPole}, 0.0), Scan({kBuilding, kPole}, 1.0), ChangeOptions(), &summary);
  EXPECT_TRUE(changes.empty()) << changes.size() << " changes, the first at "
                               << changes[0].centre.transpose();
  std::string error;
  EXPECT_TRUE(ChangeOptions().IsValid(&error)) << error;
  ChangeOptions bad;
  bad.seen_empty_share = 0.0;
  EXPECT_FALSE(bad.IsValid(&error));
}

/// A wire along the track 3 m up, 3 m to the left, sampled every 5 cm from `from` to `to` (x).
void AddWire(RunStretch* run, double from, double to) {
  for (double x = from; x <= to; x += 0.05) run->points.emplace_back(x, 3.0, 3.0);
}

/// A noise barrier behind the wire: rays through the wire's place hit it, so a run that has
/// no wire there saw the place empty.
const Box kBarrier = Make(20.0, 8.0, 0.0, 60.0, 8.5, 8.0);

TEST(ChangeDetection, AWireTheLaterRunLostIsRemoved) {
  RunStretch reference = Scan({kBuilding, kBarrier}, 0.0), later = Scan({kBuilding, kBarrier}, 1.0);
  AddWire(&reference, 26.0, 34.0);
  StretchSummary summary;
  const std::vector<StretchChange> changes =
      CompareStretch(reference, later, ChangeOptions(), &summary);
  ASSERT_EQ(changes.size(), 1u) << summary.objects << " objects";
  EXPECT_EQ(changes[0].kind, StretchChange::Kind::kRemoved);
  EXPECT_GT(changes[0].box.sizes().x(), 7.5);
}

/// A low object seen from a roof-high LiDAR: the reference's rays through where it stands end
/// on the ground (or the slab) just behind or under it, nearer than ChangeOptions::beyond_m,
/// and nothing of the reference is level with it there.
void ExpectLowBoxFound(const std::vector<Box>& both, const Box& box) {
  std::vector<Box> later = both;
  later.push_back(box);
  StretchSummary summary;
  const std::vector<StretchChange> changes =
      CompareStretch(Scan(both, 0.0, 4.0), Scan(later, 1.0, 4.0), ChangeOptions(), &summary);
  ASSERT_EQ(changes.size(), 1u) << summary.objects << " objects";
  EXPECT_EQ(changes[0].kind, StretchChange::Kind::kAdded);
  EXPECT_LT((changes[0].centre.head<2>() - box.center().head<2>()).norm(), 0.3);
  EXPECT_GE(changes[0].seen_empty_share, 0.5);
}

TEST(ChangeDetection, LowObjectsInBothRunsAreNoChange) {
  const std::vector<Box> scene = {kBuilding,
                                  kPole,
                                  Make(30.0, 3.5, 0.0, 40.0, 7.0, 0.7),
                                  Make(33.0, 4.0, 0.0, 35.0, 5.0, 1.05),
                                  Make(35.0, 1.8, 0.0, 35.4, 2.2, 0.5)};
  StretchSummary summary;
  const std::vector<StretchChange> changes =
      CompareStretch(Scan(scene, 0.0, 4.0), Scan(scene, 1.0, 4.0), ChangeOptions(), &summary);
  EXPECT_TRUE(changes.empty()) << changes.size() << " changes, the first at "
                               << changes[0].centre.transpose();
}

TEST(ChangeDetection, ALowBoxOnTheGroundIsFound) {
  ExpectLowBoxFound({kBuilding, kPole}, Make(35.0, 1.8, 0.0, 35.4, 2.2, 0.5));
}

TEST(ChangeDetection, ABoxStandingInASlabIsFoundOverIt) {
  // A 0.7 m slab in both runs; the box stands 0.35 m above it.
  ExpectLowBoxFound({kBuilding, kPole, Make(30.0, 3.5, 0.0, 40.0, 7.0, 0.7)},
                    Make(33.0, 4.0, 0.0, 35.0, 5.0, 1.05));
}

TEST(ChangeDetection, WhatOnlyRisingRaysPassedAboveAHangingBracketIsNotRemoved) {
  // A bracket hanging 6.0-6.6 m up beside the track, nothing behind it, seen by a LiDAR
  // tilted 30 deg up; the later run has its lower third only (sampled otherwise). The later
  // run's rays rising to where the rest was pass just over that lower third and end in the
  // cells grown around it, and nothing behind returns: they tell nothing of the place, which
  // is not observed, not removed.
  const Box bracket = Make(30.0, 1.0, 6.0, 30.6, 1.6, 6.6);
  Box lower = bracket;
  lower.max().z() = 6.2;
  StretchSummary summary;
  const std::vector<StretchChange> changes =
      CompareStretch(Scan({kBuilding, bracket}, 0.0, 2.0, 30.0),
                     Scan({kBuilding, lower}, 1.0, 2.0, 30.0),
                     ChangeOptions(),
                     &summary);
  EXPECT_TRUE(changes.empty()) << changes.size() << " changes, the first at "
                               << changes[0].centre.transpose();
  EXPECT_GE(summary.not_observed, 1u);
}

}  // namespace
}  // namespace raillomer::mapstore
