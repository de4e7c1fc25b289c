// Two stored runs of one line compared end to end through the store: the corridor's submaps
// and poses ingested twice, the later run 0.4 m off in UTM (another GNSS error) with a box
// added beside the track; the comparison finds the box, on the left side, at its kilometre,
// outside the structure gauge, and nothing else; and which pieces of the catenary's wires
// are no change.
#include <algorithm>

#include <gtest/gtest.h>

#include "mapstore/run_comparison.h"
#include "tests/mapstore/store_fixture.h"
#include "tests/support/corridor_submap.h"
#include "tests/support/process.h"

namespace raillomer::mapstore {
namespace {

/// Poses every metre from `first` to `last` m along the corridor, 2 m above the ground,
/// shifted by `shift` (UTM).
std::vector<api::StreamPose> CorridorPoses(const Eigen::Vector3d& shift, int first, int last) {
  std::vector<api::StreamPose> poses;
  for (int k = first; k <= last; ++k) {
    api::StreamPose p;
    p.sequence = static_cast<uint64_t>(k);
    p.stamp_ns = 1'600'000'000'000'000'000 + int64_t{k} * 100'000'000;
    p.georeferenced = true;
    p.utm_zone = "50N";
    p.p = test::CorridorStart() + shift + Eigen::Vector3d(k, 0.0, 2.0);
    poses.push_back(p);
  }
  return poses;
}

/// A run of the corridor: 6 submaps (140 m) and a pose every metre 2 m above the ground,
/// everything shifted by `shift` (UTM), with `extra` points added to submap 3.
int64_t IngestRun(MapStore& store,
                  const Eigen::Vector3d& shift,
                  const std::vector<Eigen::Vector3f>& extra) {
  RunInfo run;
  EXPECT_TRUE(store.CreateRun({"Corridor", "RLM-1", 1'600'000'000'000'000'000}, &run));
  for (uint32_t i = 0; i < 6; ++i) {
    api::Submap s = test::CorridorSubmap(i);
    s.origin += shift;
    if (i == 3)
      for (const Eigen::Vector3f& p : extra) {
        s.points.push_back(p);
        s.intensities.push_back(100.0f);
      }
    EXPECT_TRUE(store.IngestSubmap(run.id, api::EncodeSubmapPcd(s), nullptr));
  }
  int stored = 0;
  EXPECT_TRUE(store.IngestPoses(run.id, CorridorPoses(shift, 0, 140), &stored));
  EXPECT_TRUE(store.FinishRun(run.id, 1'700'000'000'000'000'000, nullptr));
  return run.id;
}

/// A live run of the corridor whose final output (submaps and poses) ends 60 m along; the rest,
/// with `extra` points in submap 3, only provisional.
int64_t IngestHalfRun(MapStore& store,
                      const Eigen::Vector3d& shift,
                      const std::vector<Eigen::Vector3f>& extra,
                      ProvisionalRun* provisional) {
  RunInfo run;
  EXPECT_TRUE(store.CreateRun({"Corridor", "RLM-1", 1'600'000'000'000'000'000}, &run));
  provisional->utm_zone = "50N";
  for (uint32_t i = 0; i < 6; ++i) {
    api::Submap s = test::CorridorSubmap(i);
    s.origin += shift;
    if (i < 3) {
      EXPECT_TRUE(store.IngestSubmap(run.id, api::EncodeSubmapPcd(s), nullptr));
      continue;
    }
    auto piece = std::make_shared<ProvisionalPiece>();
    piece->origin = s.origin;
    piece->points = s.points;
    if (i == 3) piece->points.insert(piece->points.end(), extra.begin(), extra.end());
    piece->first_stamp_ns = s.first_stamp_ns;
    piece->last_stamp_ns = s.last_stamp_ns;
    provisional->pieces.push_back(piece);
  }
  provisional->poses = CorridorPoses(shift, 61, 140);
  int stored = 0;
  EXPECT_TRUE(store.IngestPoses(run.id, CorridorPoses(shift, 0, 60), &stored));
  EXPECT_TRUE(store.Flush());  // the tiles as received so far, as the worker reads them
  return run.id;
}

/// The points a LiDAR leaves of a 1.2 x 0.8 x 1.6 m box on the ground, its corner at
/// (x0, y0) (submap frame, decimetres), on the 0.1 m grid: its shell.
std::vector<Eigen::Vector3f> Box(int x0, int y0) {
  std::vector<Eigen::Vector3f> box;
  for (int x = x0; x < x0 + 12; ++x)
    for (int y = y0; y < y0 + 8; ++y)
      for (int z = 1; z < 16; ++z)
        if (x == x0 || x == x0 + 11 || y == y0 || y == y0 + 7 || z == 15)
          box.emplace_back(0.1f * x + 0.05f, 0.1f * y + 0.05f, 0.1f * z + 0.05f);
  return box;
}

using RunComparisonTest = StoreTest;

TEST_F(RunComparisonTest, FindsABoxAddedBesideTheTrackOfAShiftedRun) {
  MapStore* store = store_.get();
  const int64_t reference = IngestRun(*store, Eigen::Vector3d::Zero(), {});
  // A 1.2 x 0.8 x 1.6 m box on the ground 3 m left of the track, 75 m along (submap 3 starts
  // at 60 m), in front of the wall, which the reference run's rays through its place hit.
  const std::vector<Eigen::Vector3f> box = Box(150, 26);
  // Another GNSS error: 0.4 m aside and 0.1 m up (along this bare corridor a shift along the
  // track could not be told, nor can it on real plain track without masts).
  const int64_t later = IngestRun(*store, Eigen::Vector3d(0.0, -0.4, 0.1), box);
  std::vector<RunChange> changes;
  RunComparisonSummary summary;
  ASSERT_TRUE(CompareRuns(*store, reference, later, RunComparisonOptions(), &changes, &summary));
  EXPECT_GE(summary.stretches_compared, 1u);
  EXPECT_LT(summary.registration_rms_m, 0.03);
  ASSERT_EQ(changes.size(), 1u) << summary.objects << " objects, " << summary.not_observed
                                << " not observed";
  const RunChange& c = changes[0];
  EXPECT_EQ(c.kind, ChangeKind::kAdded);
  EXPECT_NEAR(c.chainage_m, 75.6, 0.6);
  EXPECT_NEAR(c.offset_m, 3.0, 0.3);  // left of the track
  EXPECT_GT(c.margin_m, 0.0);         // 2.6 m from the centre: outside the 2.44 m gauge
  EXPECT_FALSE(c.intrudes_envelope);
  // In the reference run's map: where the box stands once the later run is registered.
  const Eigen::Vector3d truth = test::CorridorStart() + Eigen::Vector3d(75.6, 3.0, 0.8);
  EXPECT_LT((c.centre_utm - truth).head<2>().norm(), 0.3) << (c.centre_utm - truth).transpose();
  // Runs of other lines are not compared.
  RunInfo other;
  ASSERT_TRUE(store->CreateRun({"Elsewhere", "RLM-2", 1}, &other));
  EXPECT_EQ(
      CompareRuns(*store, reference, other.id, RunComparisonOptions(), &changes, &summary).outcome,
      Outcome::kInvalid);
}

TEST_F(RunComparisonTest, AgainstAnotherRunOffsetsAreFromTheTrackInThatRunsMap) {
  MapStore* store = store_.get();
  IngestRun(*store, Eigen::Vector3d::Zero(), {});  // the line's reference: its centreline
  // The run compared with lies 1.5 m right and 0.2 m up in UTM (its own GNSS error); the later
  // run has the box 3 m left of the track.
  const Eigen::Vector3d chosen_shift(0.0, -1.5, 0.2);
  const int64_t chosen = IngestRun(*store, chosen_shift, {});
  const int64_t later = IngestRun(*store, Eigen::Vector3d(0.0, 0.4, 0.0), Box(150, 26));
  std::vector<RunChange> changes;
  RunComparisonSummary summary;
  ASSERT_TRUE(CompareRuns(*store, chosen, later, RunComparisonOptions(), &changes, &summary));
  ASSERT_EQ(changes.size(), 1u) << summary.objects << " objects";
  const RunChange& c = changes[0];
  EXPECT_NEAR(c.offset_m, 3.0, 0.3);  // from the track, not from the line's centreline (1.5 m)
  EXPECT_GT(c.margin_m, 0.0);         // clear of the gauge, as it is
  EXPECT_NEAR(c.chainage_m, 75.6, 0.6);
  const Eigen::Vector3d truth =
      test::CorridorStart() + chosen_shift + Eigen::Vector3d(75.6, 3.0, 0.8);
  EXPECT_LT((c.centre_utm - truth).head<2>().norm(), 0.3) << (c.centre_utm - truth).transpose();
}

TEST_F(RunComparisonTest, AnObjectStandingElsewhereHasMoved) {
  MapStore* store = store_.get();
  // A cabinet 65 m along, 3 m left; a week later 5 m further on.
  const int64_t reference = IngestRun(*store, Eigen::Vector3d::Zero(), Box(50, 26));
  const int64_t later = IngestRun(*store, Eigen::Vector3d(0.0, -0.4, 0.1), Box(100, 26));
  std::vector<RunChange> changes;
  RunComparisonSummary summary;
  ASSERT_TRUE(CompareRuns(*store, reference, later, RunComparisonOptions(), &changes, &summary));
  ASSERT_EQ(changes.size(), 1u) << summary.objects << " objects";
  const RunChange& c = changes[0];
  EXPECT_EQ(c.kind, ChangeKind::kMoved);
  EXPECT_NEAR(c.moved_m, 5.0, 0.3);
  EXPECT_NEAR(c.chainage_m, 70.6, 0.6);  // where it stands now
  const Eigen::Vector3d before = test::CorridorStart() + Eigen::Vector3d(65.6, 3.0, 0.8);
  EXPECT_LT((c.moved_from_utm - before).head<2>().norm(), 0.3);
}

TEST_F(RunComparisonTest, AStretchIsComparedOnProvisionalOutputAheadOfTheFinal) {
  MapStore* store = store_.get();
  const int64_t reference = IngestRun(*store, Eigen::Vector3d::Zero(), {});
  ProvisionalRun provisional;
  const int64_t later =
      IngestHalfRun(*store, Eigen::Vector3d(0.0, -0.4, 0.1), Box(150, 26), &provisional);
  std::unique_ptr<RunComparison> comparison;
  ASSERT_TRUE(RunComparison::Prepare(
      *store, reference, later, RunComparisonOptions(), &comparison, &provisional));
  EXPECT_NEAR(comparison->later_reach_m(false), 60.0, 1.0);
  EXPECT_NEAR(comparison->later_reach_m(true), 140.0, 1.0);
  EXPECT_EQ(comparison->provisional_mapped_until(), provisional.pieces.back()->last_stamp_ns);
  const StretchRange first = comparison->stretches().at(0);  // 0-80 m: the box at 75 m
  StretchOutcome on_final, on_provisional;
  ASSERT_TRUE(comparison->Compare(first, &on_final, false));
  ASSERT_TRUE(comparison->Compare(first, &on_provisional, true));
  EXPECT_FALSE(on_final.provisional);
  ASSERT_TRUE(on_final.compared) << on_final.skipped;
  EXPECT_TRUE(on_final.changes.empty());  // the final map ends before the box
  EXPECT_TRUE(on_provisional.provisional);
  ASSERT_TRUE(on_provisional.compared) << on_provisional.skipped;
  ASSERT_EQ(on_provisional.changes.size(), 1u);
  EXPECT_EQ(on_provisional.changes[0].kind, ChangeKind::kAdded);
  EXPECT_NEAR(on_provisional.changes[0].chainage_m, 75.6, 0.6);
  // Provisional output in another zone than the reference's is not used.
  provisional.utm_zone = "51N";
  ASSERT_TRUE(RunComparison::Prepare(
      *store, reference, later, RunComparisonOptions(), &comparison, &provisional));
  EXPECT_NEAR(comparison->later_reach_m(true), 60.0, 1.0);
}

TEST_F(RunComparisonTest, AProvisionalPlacementThatDoesNotFitIsLeftOut) {
  MapStore* store = store_.get();
  const int64_t reference = IngestRun(*store, Eigen::Vector3d::Zero(), {});
  ProvisionalRun provisional;
  const int64_t later =
      IngestHalfRun(*store, Eigen::Vector3d(0.0, -0.4, 0.1), Box(150, 26), &provisional);
  for (auto& piece : provisional.pieces) {
    auto placed = std::make_shared<ProvisionalPiece>(*piece);
    placed->placement = 1;
    piece = placed;
  }
  // The fusion's graph moved: the same place (submap 3, with the box) sent again, placed
  // 0.3 m aside and 0.5 m higher, as a second placement.
  auto moved = std::make_shared<ProvisionalPiece>(*provisional.pieces.front());
  moved->origin += Eigen::Vector3d(0.0, 0.3, 0.5);
  moved->placement = 2;
  moved->first_stamp_ns = provisional.pieces.back()->last_stamp_ns + 1;
  moved->last_stamp_ns = moved->first_stamp_ns + 1;
  provisional.pieces.push_back(moved);
  // A third placement that fits the first, with a second box 10 m before the first.
  auto fitting = std::make_shared<ProvisionalPiece>(*provisional.pieces.front());
  const std::vector<Eigen::Vector3f> second_box = Box(50, 26);
  fitting->points.insert(fitting->points.end(), second_box.begin(), second_box.end());
  fitting->placement = 3;
  fitting->first_stamp_ns = moved->last_stamp_ns + 1;
  fitting->last_stamp_ns = fitting->first_stamp_ns + 1;
  provisional.pieces.push_back(fitting);
  const auto compare = [&](StretchOutcome* out) {
    std::unique_ptr<RunComparison> comparison;
    ASSERT_TRUE(RunComparison::Prepare(
        *store, reference, later, RunComparisonOptions(), &comparison, &provisional));
    ASSERT_TRUE(comparison->Compare(comparison->stretches().at(0), out, true));
  };
  StretchOutcome apart;
  compare(&apart);
  ASSERT_TRUE(apart.compared) << apart.skipped;
  EXPECT_LT(apart.registration_rms_m, 0.03);
  // The two boxes, not the ground seen twice: the moved placement is left out, the fitting
  // one kept.
  ASSERT_EQ(apart.changes.size(), 2u);
  std::vector<double> at;
  for (const RunChange& c : apart.changes) {
    EXPECT_EQ(c.kind, ChangeKind::kAdded);
    at.push_back(c.chainage_m);
  }
  std::sort(at.begin(), at.end());
  EXPECT_NEAR(at[0], 65.6, 0.6);
  EXPECT_NEAR(at[1], 75.6, 0.6);
  // Taken as one placement, the first two do not fit: the ground shows twice, or nothing
  // registers.
  auto same = std::make_shared<ProvisionalPiece>(*moved);
  same->placement = 1;
  provisional.pieces[provisional.pieces.size() - 2] = same;
  StretchOutcome together;
  compare(&together);
  EXPECT_TRUE(!together.compared || together.changes.size() > 1u)
      << together.changes.size() << " changes";
}

/// A piece of contact wire one run sampled: 0.8 m along the track, 0.2 m across and high,
/// 6 m above the rails, 0.13 m right of the centre (the stagger).
RunChange WirePiece() {
  RunChange c;
  c.kind = ChangeKind::kRemoved;
  c.offset_m = -0.13;
  c.size_m = Eigen::Vector3d(0.8, 0.2, 0.2);
  c.height_above_rail_min_m = 5.93;
  c.height_above_rail_max_m = 6.03;
  return c;
}

TEST(CatenaryWirePiece, OnlyAShortThinMemberAtWireHeightOverTheTrack) {
  const RunComparisonOptions o;
  EXPECT_TRUE(CatenaryWirePiece(WirePiece(), o));
  RunChange added = WirePiece();
  added.kind = ChangeKind::kAdded;
  EXPECT_TRUE(CatenaryWirePiece(added, o));
  // A piece of a tunnel's bracket from the crown: 0.1 x 0.1 m, 0.9 m upright, 6.6 m up.
  RunChange bracket = added;
  bracket.offset_m = 0.1;
  bracket.size_m = Eigen::Vector3d(0.1, 0.1, 0.9);
  bracket.height_above_rail_min_m = 6.6;
  bracket.height_above_rail_max_m = 7.5;
  EXPECT_TRUE(CatenaryWirePiece(bracket, o));
  // A cantilever's tube beside the mast, a thin bar on the track, a whole span of wire gone,
  // a branch grown to the wire, something wide hung over the track: all reported.
  RunChange beside = WirePiece(), low = WirePiece(), span = WirePiece(), branch = WirePiece(),
            wide = WirePiece();
  beside.offset_m = -2.0;
  low.height_above_rail_min_m = 0.2;
  span.size_m.x() = 40.0;
  branch.kind = ChangeKind::kVegetation;
  wide.size_m = Eigen::Vector3d(0.8, 0.5, 0.6);
  for (const RunChange& c : {beside, low, span, branch, wide})
    EXPECT_FALSE(CatenaryWirePiece(c, o)) << c.offset_m << " m off, " << c.size_m.transpose();
}

}  // namespace
}  // namespace raillomer::mapstore
