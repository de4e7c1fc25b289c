// The map store on generated submaps of a straight corridor in UTM: runs, ingest that is
// idempotent, tiles and their level-of-detail pyramid, queries, reopening, recovery after a
// crash, schema migration, and bad input that changes nothing.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <set>

#include <gtest/gtest.h>

#include "api/las.h"
#include "mapstore/export.h"
#include "mapstore/map_store.h"
#include "mapstore/schema.h"
#include "mapstore/sqlite.h"
#include "mapstore/tile_codec.h"
#include "tests/support/corridor_submap.h"
#include "tests/support/process.h"

namespace raillomer::mapstore {
namespace {

const Eigen::Vector3d kStart = test::CorridorStart();
using test::CorridorSubmap;

std::unique_ptr<MapStore> OpenStore(const std::string& dir, std::string* error) {
  StoreOptions options;
  return MapStore::Open(dir, options, error);
}

int64_t NewRunId(MapStore& store, const std::string& line = "Test line") {
  RunInfo run;
  const Result r = store.CreateRun({line, "RLM-1", 1'600'000'000'000'000'000}, &run);
  EXPECT_TRUE(r) << r.message;
  return run.id;
}

/// Opens a store in `dir`, stores a run of `submaps` corridor submaps and closes it; the run id.
int64_t StoreRun(const std::string& dir, uint32_t submaps) {
  std::string error;
  auto store = OpenStore(dir, &error);
  EXPECT_TRUE(store) << error;
  if (!store) return 0;
  const int64_t run = NewRunId(*store);
  for (uint32_t i = 0; i < submaps; ++i)
    EXPECT_TRUE(store->IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(i)), nullptr));
  return run;
}

/// Every point of the run's level-0 tiles, as UTM.
std::vector<Eigen::Vector3d> AllPoints(MapStore& store, int64_t run_id, int level = 0) {
  std::vector<TileInfo> tiles;
  const Eigen::AlignedBox2d everywhere(Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(1e6, 1e7));
  EXPECT_TRUE(store.TilesInBox(run_id, level, everywhere, &tiles));
  std::vector<Eigen::Vector3d> points;
  for (const TileInfo& t : tiles) {
    std::string bytes, error;
    EXPECT_TRUE(store.Tile(run_id, t.key, nullptr, &bytes));
    TilePoints decoded;
    EXPECT_TRUE(DecodeTile(bytes, &decoded, &error)) << error;
    EXPECT_EQ(static_cast<int64_t>(decoded.points.size()), t.points);
    for (const Eigen::Vector3f& p : decoded.points)
      points.push_back(decoded.origin + p.cast<double>());
  }
  return points;
}

/// The 0.1 m voxels (UTM) that the points fall in.
std::set<std::tuple<int64_t, int64_t, int64_t>> Voxels(const std::vector<Eigen::Vector3d>& points) {
  std::set<std::tuple<int64_t, int64_t, int64_t>> v;
  for (const Eigen::Vector3d& p : points) {
    v.emplace(std::llround(std::floor(p.x() * 10.0)),
              std::llround(std::floor(p.y() * 10.0)),
              std::llround(std::floor(p.z() * 10.0)));
  }
  return v;
}

TEST(MapStore, StoresSubmapsAsTilesWithALevelOfDetailPyramid) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  const int64_t run = NewRunId(*store);
  std::set<std::tuple<int64_t, int64_t, int64_t>> expected;
  for (uint32_t i = 0; i < 5; ++i) {
    const api::Submap s = CorridorSubmap(i);
    IngestReceipt receipt;
    const Result r = store->IngestSubmap(run, api::EncodeSubmapPcd(s), &receipt);
    ASSERT_EQ(r.outcome, Outcome::kOk) << r.message;
    EXPECT_EQ(receipt.points, s.points.size());
    // Half of each later submap lies on ground the one before covered.
    if (i > 0) {
      EXPECT_NEAR(double(receipt.points_new) / receipt.points, 0.5, 0.01);
    }
    std::vector<Eigen::Vector3d> utm;
    for (const Eigen::Vector3f& p : s.points) utm.push_back(s.origin + p.cast<double>());
    const auto v = Voxels(utm);
    expected.insert(v.begin(), v.end());
  }
  ASSERT_TRUE(store->Flush());
  RunInfo info;
  ASSERT_TRUE(store->GetRun(run, &info));
  EXPECT_EQ(info.submaps, 5);
  EXPECT_EQ(info.utm_zone, "50N");
  EXPECT_EQ(info.status, "live");

  // Level 0 holds one point per voxel the submaps filled, each within the stated error.
  const std::vector<Eigen::Vector3d> level0 = AllPoints(*store, run, 0);
  EXPECT_EQ(level0.size(), expected.size());
  EXPECT_EQ(Voxels(level0), expected);
  // Coarser levels hold fewer points over the same ground.
  size_t previous = level0.size();
  for (int level = 1; level < store->options().grid.levels; ++level) {
    const std::vector<Eigen::Vector3d> coarse = AllPoints(*store, run, level);
    EXPECT_LT(coarse.size(), previous / 3) << "level " << level;
    EXPECT_GT(coarse.size(), 0u);
    previous = coarse.size();
  }
  // The corridor runs 120 m east from x = 432100: tiles 13503-13506 of 32 m at level 0.
  std::vector<TileInfo> tiles;
  const Eigen::AlignedBox2d first(Eigen::Vector2d(432100.0, 3585190.0),
                                  Eigen::Vector2d(432110.0, 3585210.0));
  ASSERT_TRUE(store->TilesInBox(run, 0, first, &tiles));
  ASSERT_EQ(tiles.size(), 1u);
  EXPECT_EQ(tiles[0].key.ix, 13503);
  EXPECT_EQ(tiles[0].key.iy, 112037);
  EXPECT_LE(tiles[0].max_error_m, 0.005);
  EXPECT_EQ(tiles[0].version, 1);
  EXPECT_EQ(tiles[0].etag.front(), '"');
  // Compression: at most 24 bits per point with intensity.
  const double bits = 8.0 * tiles[0].bytes / tiles[0].points;
  EXPECT_LE(bits, 24.0) << bits;
}

TEST(MapStore, IngestIsIdempotentAndRefusesADifferentPayloadUnderATakenSequence) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  const int64_t run = NewRunId(*store);
  const std::string payload = api::EncodeSubmapPcd(CorridorSubmap(0));
  ASSERT_EQ(store->IngestSubmap(run, payload, nullptr).outcome, Outcome::kOk);
  ASSERT_TRUE(store->Flush());
  const std::vector<Eigen::Vector3d> before = AllPoints(*store, run);
  std::vector<TileInfo> tiles_before;
  const Eigen::AlignedBox2d everywhere(Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(1e6, 1e7));
  ASSERT_TRUE(store->TilesInBox(run, 0, everywhere, &tiles_before));

  EXPECT_EQ(store->IngestSubmap(run, payload, nullptr).outcome, Outcome::kDuplicate);
  api::Submap changed = CorridorSubmap(0);
  changed.points[7].x() += 1.0f;
  const Result conflict = store->IngestSubmap(run, api::EncodeSubmapPcd(changed), nullptr);
  EXPECT_EQ(conflict.outcome, Outcome::kConflict);
  EXPECT_NE(conflict.message.find("sequence 10"), std::string::npos) << conflict.message;
  ASSERT_TRUE(store->Flush());
  std::vector<TileInfo> tiles_after;
  ASSERT_TRUE(store->TilesInBox(run, 0, everywhere, &tiles_after));
  ASSERT_EQ(tiles_after.size(), tiles_before.size());
  for (size_t i = 0; i < tiles_after.size(); ++i)
    EXPECT_EQ(tiles_after[i].etag, tiles_before[i].etag);
  EXPECT_EQ(AllPoints(*store, run).size(), before.size());
  RunInfo info;
  ASSERT_TRUE(store->GetRun(run, &info));
  EXPECT_EQ(info.submaps, 1);

  // Poses: stored once; the same again is a duplicate; a changed one a conflict.
  std::vector<api::StreamPose> poses(3);
  for (size_t i = 0; i < poses.size(); ++i) {
    poses[i].sequence = i;
    poses[i].stamp_ns = 1'600'000'000'000'000'000 + int64_t(i) * 100'000'000;
    poses[i].georeferenced = true;
    poses[i].utm_zone = "50N";
    poses[i].p = kStart + Eigen::Vector3d(double(i), 0.0, 0.0);
  }
  int stored = 0;
  ASSERT_EQ(store->IngestPoses(run, poses, &stored).outcome, Outcome::kOk);
  EXPECT_EQ(stored, 3);
  EXPECT_EQ(store->IngestPoses(run, poses, &stored).outcome, Outcome::kDuplicate);
  EXPECT_EQ(stored, 0);
  poses[1].p.x() += 0.5;
  EXPECT_EQ(store->IngestPoses(run, poses, &stored).outcome, Outcome::kConflict);
  std::vector<api::StreamPose> trajectory;
  ASSERT_TRUE(store->Trajectory(run, &trajectory));
  ASSERT_EQ(trajectory.size(), 3u);
  EXPECT_EQ(trajectory[1].p, kStart + Eigen::Vector3d(1.0, 0.0, 0.0));
}

TEST(MapStore, BadInputIsRefusedWithAMessageAndChangesNothing) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  const int64_t run = NewRunId(*store);
  ASSERT_TRUE(store->IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(0)), nullptr));
  ASSERT_TRUE(store->Flush());
  const size_t points = AllPoints(*store, run).size();

  auto expect = [&](const std::string& payload, Outcome outcome, const std::string& words) {
    const Result r = store->IngestSubmap(run, payload, nullptr);
    EXPECT_EQ(r.outcome, outcome) << r.message;
    EXPECT_NE(r.message.find(words), std::string::npos) << r.message;
  };
  const std::string good = api::EncodeSubmapPcd(CorridorSubmap(1));
  expect(good.substr(0, good.size() - 5), Outcome::kInvalid, "truncated");
  expect("hello", Outcome::kInvalid, "submap PCD");
  api::Submap nan = CorridorSubmap(1);
  nan.points[12].y() = NAN;
  expect(api::EncodeSubmapPcd(nan), Outcome::kInvalid, "point 12");
  api::Submap local = CorridorSubmap(1);
  local.georeferenced = false;
  expect(api::EncodeSubmapPcd(local), Outcome::kInvalid, "not georeferenced");
  api::Submap far = CorridorSubmap(1);
  far.origin.x() = -5.0;
  expect(api::EncodeSubmapPcd(far), Outcome::kInvalid, "not a UTM position");
  api::Submap zone = CorridorSubmap(1);
  zone.utm_zone = "51N";
  expect(api::EncodeSubmapPcd(zone), Outcome::kInvalid, "zone 51N");
  EXPECT_EQ(store->IngestSubmap(run + 7, good, nullptr).outcome, Outcome::kNotFound);
  std::vector<api::StreamPose> bad(1);
  bad[0].p.x() = NAN;
  EXPECT_EQ(store->IngestPoses(run, bad, nullptr).outcome, Outcome::kInvalid);
  RunInfo ignored;
  EXPECT_EQ(store->CreateRun({"", "RLM-1", 0}, &ignored).outcome, Outcome::kInvalid);

  // A finished run takes no more submaps; a finished run's submap re-sent is a duplicate.
  RunInfo info;
  ASSERT_TRUE(store->FinishRun(run, 1'600'000'100'000'000'000, &info));
  EXPECT_EQ(info.status, "finished");
  EXPECT_EQ(store->IngestSubmap(run, good, nullptr).outcome, Outcome::kConflict);
  EXPECT_EQ(store->IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(0)), nullptr).outcome,
            Outcome::kDuplicate);

  ASSERT_TRUE(store->Flush());
  EXPECT_EQ(AllPoints(*store, run).size(), points);
  ASSERT_TRUE(store->GetRun(run, &info));
  EXPECT_EQ(info.submaps, 1);
  EXPECT_EQ(store->stats().submaps_rejected, 8u);
}

TEST(MapStore, ASubmapOverThePointLimitIsRefused) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  StoreOptions options;
  options.max_points_per_submap = 40'000;  // a corridor submap has 44 000
  auto store = MapStore::Open(dir.path().string(), options, &error);
  ASSERT_TRUE(store) << error;
  const int64_t run = NewRunId(*store);
  const Result r = store->IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(0)), nullptr);
  EXPECT_EQ(r.outcome, Outcome::kInvalid);
  EXPECT_NE(r.message.find("44000 points, more than the 40000 allowed"), std::string::npos)
      << r.message;
  RunInfo info;
  ASSERT_TRUE(store->GetRun(run, &info));
  EXPECT_EQ(info.submaps, 0);
  // Options that make no sense are refused when the store opens.
  options.grid.tile_m = 1.0;
  EXPECT_FALSE(MapStore::Open((dir.path() / "other").string(), options, &error));
  EXPECT_NE(error.find("tile_m"), std::string::npos) << error;
}

TEST(MapStore, ReopensWithEverythingAndMergesIncrementally) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  const int64_t run = StoreRun(dir.path().string(), 2);  // closing the store writes the tiles
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  const size_t two = AllPoints(*store, run).size();
  EXPECT_EQ(two, Voxels(AllPoints(*store, run)).size());
  // A third submap merges into the written tiles: half of it is new ground.
  IngestReceipt receipt;
  ASSERT_TRUE(store->IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(2)), &receipt));
  ASSERT_TRUE(store->Flush());
  EXPECT_EQ(AllPoints(*store, run).size(), two + receipt.points_new);
  EXPECT_NEAR(double(receipt.points_new) / receipt.points, 0.5, 0.01);
  std::vector<RunInfo> runs = store->ListRuns();
  ASSERT_EQ(runs.size(), 1u);
  EXPECT_EQ(runs[0].submaps, 3);
}

TEST(MapStore, AStoreInUseIsRefusedToASecondOpenerNamingTheHolder) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  auto first = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(first) << error;
  EXPECT_FALSE(OpenStore(dir.path().string(), &error));
  EXPECT_NE(error.find("in use by another process (pid " + std::to_string(getpid()) + ")"),
            std::string::npos)
      << error;
  first.reset();  // closing lets the folder go (a killed holder does too: the next test)
  EXPECT_TRUE(OpenStore(dir.path().string(), &error)) << error;
}

TEST(MapStore, ASubmapAcknowledgedBeforeACrashIsInTheTilesAfterRestart) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  const int64_t run = StoreRun(dir.path().string(), 1);
  // A child process stores three more submaps, acknowledged but not yet in written tiles, and
  // dies without cleaning up.
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    std::string e;
    auto store = OpenStore(dir.path().string(), &e);
    bool ok = store != nullptr;
    for (uint32_t i = 1; ok && i < 4; ++i)
      ok = store->IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(i)), nullptr).ok();
    kill(getpid(), SIGKILL);
    _exit(ok ? 0 : 1);
  }
  int status = 0;
  waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status));

  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  EXPECT_EQ(store->stats().submaps_recovered, 3u);
  std::set<std::tuple<int64_t, int64_t, int64_t>> expected;
  for (uint32_t i = 0; i < 4; ++i) {
    const api::Submap s = CorridorSubmap(i);
    std::vector<Eigen::Vector3d> utm;
    for (const Eigen::Vector3f& p : s.points) utm.push_back(s.origin + p.cast<double>());
    const auto v = Voxels(utm);
    expected.insert(v.begin(), v.end());
  }
  EXPECT_EQ(Voxels(AllPoints(*store, run)), expected);
  RunInfo info;
  ASSERT_TRUE(store->GetRun(run, &info));
  EXPECT_EQ(info.submaps, 4);
  store.reset();
  // SQLite's own tool (not our code) finds the index sound, every submap in written tiles; the
  // payloads are let go.
  const test::CommandResult check = test::RunCommand(
      "sqlite3 " + test::ShellQuote((dir.path() / "index.sqlite").string()) +
          " 'PRAGMA integrity_check; SELECT count(*) FROM submaps WHERE tiled = 1;'",
      dir.path());
  ASSERT_EQ(check.exit_code, 0) << check.err;
  EXPECT_EQ(check.out, "ok\n4\n");
  EXPECT_TRUE(std::filesystem::is_empty(dir.path() / "incoming"));
}

/// Poses along a line from the corridor's start: 200 m east on a 5 per mille rise, then 200 m
/// of a 500 m radius curve to the left with 0.1 m of cant; then 50 m of reversing and forward
/// again over the same ground, which the centreline must ignore.
std::vector<api::StreamPose> LinePoses() {
  std::vector<api::StreamPose> poses;
  auto add = [&](const Eigen::Vector3d& p, double heading, double roll) {
    api::StreamPose pose;
    pose.sequence = poses.size();
    pose.stamp_ns = 1'600'000'000'000'000'000 + int64_t(poses.size()) * 100'000'000;
    pose.georeferenced = true;
    pose.utm_zone = "50N";
    pose.p = p;
    pose.q = Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ()) *
             Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX());
    poses.push_back(pose);
  };
  const double radius = 500.0, roll = std::asin(0.1 / kRailHeadSpacingM);
  auto at = [&](double s) -> Eigen::Vector3d {  // position, s metres along the line
    if (s <= 200.0) return kStart + Eigen::Vector3d(s, 0.0, 0.005 * s);
    const double a = (s - 200.0) / radius;
    return kStart +
           Eigen::Vector3d(200.0 + radius * std::sin(a), radius * (1.0 - std::cos(a)), 0.005 * s);
  };
  for (double s = 0.0; s <= 400.0; s += 1.5)
    add(at(s), s <= 200.0 ? 0.0 : (s - 200.0) / radius, s <= 200.0 ? 0.0 : roll);
  for (double s = 400.0; s >= 350.0; s -= 1.5) add(at(s), (s - 200.0) / radius, roll);
  for (double s = 350.0; s <= 420.0; s += 1.5) add(at(s), (s - 200.0) / radius, roll);
  return poses;
}

/// A finished run of "Line A" along LinePoses with four corridor submaps: it defines the line.
int64_t StoreLineRun(MapStore& store) {
  const int64_t run = NewRunId(store, "Line A");
  EXPECT_TRUE(store.IngestPoses(run, LinePoses(), nullptr));
  for (uint32_t i = 0; i < 4; ++i)
    EXPECT_TRUE(store.IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(i)), nullptr));
  EXPECT_TRUE(store.FinishRun(run, 1'600'000'100'000'000'000, nullptr));
  return run;
}

/// The straight: no curvature, a 5 per mille rise, no cant, and the corridor's tiles cover it;
/// the curve: 1 / 500 m to the left, 0.1 m of cant. Ranges off the line are refused.
void ExpectLineATrackGeometry(MapStore& store) {
  TrackSegment segment;
  ASSERT_TRUE(store.Segment("Line A", 20.0, 120.0, &segment));
  ASSERT_GE(segment.samples.size(), 99u);
  EXPECT_NEAR(segment.samples.front().point.chainage_m, 20.0, 0.5);
  for (const TrackSample& s : segment.samples) {
    EXPECT_NEAR(s.curvature_per_m, 0.0, 1e-4);
    EXPECT_NEAR(s.gradient, 0.005, 1e-4);
    EXPECT_NEAR(s.point.cant_m, 0.0, 1e-6);
  }
  EXPECT_FALSE(segment.tiles.empty());
  // The curve: 1 / 500 m to the left, 0.1 m of cant.
  ASSERT_TRUE(store.Segment("Line A", 250.0, 350.0, &segment));
  for (const TrackSample& s : segment.samples) {
    EXPECT_NEAR(s.curvature_per_m, 1.0 / 500.0, 0.05 / 500.0) << s.point.chainage_m;
    EXPECT_NEAR(s.point.cant_m, 0.1, 0.002);
  }
  EXPECT_EQ(store.Segment("Line A", 5000.0, 6000.0, &segment).outcome, Outcome::kNotFound);
  EXPECT_EQ(store.Segment("Line A", 10.0, 5.0, &segment).outcome, Outcome::kInvalid);
  EXPECT_EQ(store.Segment("Line B", 0.0, 5.0, &segment).outcome, Outcome::kNotFound);
}

/// A km post pinned at 100 m along the line makes that point km 12.400; one far off is refused.
void ExpectKmPostPinned(MapStore& store) {
  LineInfo line;
  TrackSegment segment;
  const Eigen::Vector2d post = (kStart + Eigen::Vector3d(100.0, 0.3, 0.0)).head<2>();
  ASSERT_TRUE(store.PinKmPost("Line A", "km 12.4", 12400.0, post, &line));
  EXPECT_NEAR(line.chainage_offset_m, 12300.0, 0.01);
  ASSERT_TRUE(store.Segment("Line A", 12390.0, 12410.0, &segment));
  const auto km =
      std::min_element(segment.samples.begin(), segment.samples.end(), [](auto& a, auto& b) {
        return std::abs(a.point.chainage_m - 12400.0) < std::abs(b.point.chainage_m - 12400.0);
      });
  EXPECT_NEAR(km->point.p.x(), kStart.x() + 100.0, 0.6);  // the centreline every metre
  EXPECT_EQ(
      store.PinKmPost("Line A", "far", 0.0, post + Eigen::Vector2d(0.0, 80.0), nullptr).outcome,
      Outcome::kInvalid);
  // A position beyond UTM's, or a label with a control character, is refused.
  const Result huge = store.PinKmPost("Line A", "", 0.0, Eigen::Vector2d(1e308, 1e308), nullptr);
  EXPECT_NE(huge.message.find("must be a UTM position"), std::string::npos) << huge.message;
  EXPECT_EQ(store.PinKmPost("Line A", "a\x01b", 12400.0, post, nullptr).outcome, Outcome::kInvalid);
  // A range shorter than the centreline's sampling (a metre) gets the nearer sample.
  ASSERT_TRUE(store.Segment("Line A", 12400.2, 12400.25, &segment));
  ASSERT_EQ(segment.samples.size(), 1u);
  EXPECT_NEAR(segment.samples[0].point.chainage_m, 12400.0, 0.6);
}

/// A second run of the line leaves its centreline as it was, and is referenced to it: its
/// poses, 0.4 m to the side, get the chainage of the first run's (offset included); one 30 m
/// off the line gets none.
void ExpectSecondRunReferenced(MapStore& store, int64_t reference) {
  const int64_t second = NewRunId(store, "Line A");
  std::vector<api::StreamPose> later = LinePoses();
  later.resize(100);
  for (api::StreamPose& p : later) p.p.y() += 0.4;
  later[50].p.y() += 30.0;
  ASSERT_TRUE(store.IngestPoses(second, later, nullptr));
  std::vector<double> chainage;
  ASSERT_TRUE(store.ChainageOfPoses(second, later, &chainage));
  for (size_t i = 0; i < later.size(); ++i) {
    if (i == 50) {
      EXPECT_TRUE(std::isnan(chainage[i]));
      continue;
    }
    EXPECT_NEAR(chainage[i], 12300.0 + 1.5 * static_cast<double>(i), 0.01) << i;
  }
  ASSERT_TRUE(store.FinishRun(second, 1'600'000'100'000'000'000, nullptr));
  LineInfo line;
  ASSERT_TRUE(store.GetLine("Line A", &line));
  EXPECT_EQ(line.reference_run, reference);
}

TEST(MapStore, TheFirstRunOfALineDefinesItsChainageAndTrackGeometry) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  const int64_t run = NewRunId(*store, "Line A");
  ASSERT_TRUE(store->IngestPoses(run, LinePoses(), nullptr));
  for (uint32_t i = 0; i < 4; ++i)
    ASSERT_TRUE(store->IngestSubmap(run, api::EncodeSubmapPcd(CorridorSubmap(i)), nullptr));
  LineInfo line;
  ASSERT_TRUE(store->GetLine("Line A", &line));
  EXPECT_EQ(line.reference_run, 0);
  TrackSegment segment;
  EXPECT_EQ(store->Segment("Line A", 0.0, 100.0, &segment).outcome, Outcome::kNotFound);
  ASSERT_TRUE(store->FinishRun(run, 1'600'000'100'000'000'000, nullptr));
  ASSERT_TRUE(store->GetLine("Line A", &line));
  EXPECT_EQ(line.reference_run, run);
  EXPECT_EQ(line.utm_zone, "50N");
  // 420 m of line (the reversing adds nothing); chainage is the distance along it.
  EXPECT_NEAR(line.length_m, 420.0, 2.0);

  ASSERT_NO_FATAL_FAILURE(ExpectLineATrackGeometry(*store));
  ASSERT_NO_FATAL_FAILURE(ExpectKmPostPinned(*store));
  ASSERT_NO_FATAL_FAILURE(ExpectSecondRunReferenced(*store, run));
  std::vector<LineInfo> lines;
  ASSERT_TRUE(store->ListLines(&lines));
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_EQ(lines[0].runs, 2);
}

TEST(MapStore, ExportsABoxOrAKmRangeAsPlyPcdAndLas) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  const int64_t run = StoreLineRun(*store);

  // A box 10-30 m along the corridor: its ground (8 m wide) and wall, one point per voxel.
  ExportRequest box;
  box.run_id = run;
  box.has_box = true;
  box.box = Eigen::AlignedBox2d((kStart + Eigen::Vector3d(10.0, -10.0, 0.0)).head<2>(),
                                (kStart + Eigen::Vector3d(30.0, 10.0, 0.0)).head<2>());
  std::vector<ExportPoint> points;
  std::string zone;
  ASSERT_TRUE(store->Export(box, &points, &zone));
  EXPECT_EQ(zone, "50N");
  EXPECT_EQ(points.size(), 200u * 110u);
  for (ExportFormat format : {ExportFormat::kPly, ExportFormat::kPcd, ExportFormat::kLas}) {
    std::vector<ExportPoint> back;
    ASSERT_TRUE(DecodeExport(EncodeExport(points, format, zone), format, &back, &error)) << error;
    ASSERT_EQ(back.size(), points.size()) << ExtensionOf(format);
    double worst = 0.0;
    for (size_t i = 0; i < back.size(); ++i) {
      worst = std::max(worst, (back[i].p - points[i].p).cwiseAbs().maxCoeff());
      EXPECT_EQ(back[i].intensity, points[i].intensity);
    }
    EXPECT_LE(worst, 0.001) << ExtensionOf(format);  // LAS keeps millimetres
  }
  // A LAS export names its zone for GIS tools: WGS 84 / UTM zone 50N.
  api::las::Contents las;
  ASSERT_TRUE(api::las::Decode(EncodeExport(points, ExportFormat::kLas, zone), &las, &error))
      << error;
  EXPECT_EQ(las.epsg, 32650);
  EXPECT_EQ(las.system_identifier, "RailLoMer UTM zone 50N");
  // Along the line from 20 m to 40 m, within 3 m of the centreline: ground only (the wall
  // stands 4 m off), 20 m by 6 m with a half disc at either end, 100 points per square metre.
  ExportRequest along;
  along.run_id = run;
  along.line = "Line A";
  along.from_m = 20.0;
  along.to_m = 40.0;
  along.half_width_m = 3.0;
  ASSERT_TRUE(store->Export(along, &points, &zone));
  EXPECT_NEAR(static_cast<double>(points.size()), 100.0 * (20.0 * 6.0 + M_PI * 9.0), 100.0);
  for (const ExportPoint& p : points) EXPECT_LE(std::abs(p.p.y() - kStart.y()), 3.05);
  along.max_points = 100;
  EXPECT_EQ(store->Export(along, &points, &zone).outcome, Outcome::kInvalid);
  ExportRequest nothing;
  nothing.run_id = run;
  EXPECT_EQ(store->Export(nothing, &points, &zone).outcome, Outcome::kInvalid);
}

/// The two points of interest of the test below, listed by line and by area: the mast on line A
/// and the level crossing 500 m on, on no line.
void ExpectPoisListedByLineAndArea(MapStore& store) {
  std::vector<Poi> list;
  ASSERT_TRUE(store.ListPois("", nullptr, &list));
  EXPECT_EQ(list.size(), 2u);
  ASSERT_TRUE(store.ListPois("Line A", nullptr, &list));
  ASSERT_EQ(list.size(), 1u);
  const Eigen::AlignedBox2d near((kStart + Eigen::Vector3d(400.0, -10.0, 0.0)).head<2>(),
                                 (kStart + Eigen::Vector3d(600.0, 10.0, 0.0)).head<2>());
  ASSERT_TRUE(store.ListPois("", &near, &list));
  ASSERT_EQ(list.size(), 1u);
  EXPECT_EQ(list[0].kind, "level crossing");
}

/// A point of interest with no position or kind, on an unknown line or with an unknown id is
/// refused.
void ExpectBadPoisRefused(MapStore& store, const Poi& good) {
  Poi bad = good;
  bad.p.x() = NAN;
  EXPECT_EQ(store.UpdatePoi(&bad).outcome, Outcome::kInvalid);
  bad = good;
  bad.kind.clear();
  EXPECT_EQ(store.CreatePoi(&bad).outcome, Outcome::kInvalid);
  bad = good;
  bad.line = "No such line";
  EXPECT_EQ(store.CreatePoi(&bad).outcome, Outcome::kNotFound);
  bad = good;
  bad.id = 999;
  EXPECT_EQ(store.UpdatePoi(&bad).outcome, Outcome::kNotFound);
}

TEST(MapStore, PointsOfInterestAreCreatedReadListedUpdatedAndDeleted) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  NewRunId(*store, "Line A");
  Poi mast;
  mast.line = "Line A";
  mast.kind = "mast";
  mast.name = "M 12";
  mast.utm_zone = "50N";
  mast.p = kStart + Eigen::Vector3d(10.0, 3.2, 0.0);
  mast.properties_json = R"({"height_m": 8.5})";
  ASSERT_TRUE(store->CreatePoi(&mast));
  EXPECT_GT(mast.id, 0);
  Poi crossing = mast;
  crossing.line.clear();
  crossing.kind = "level crossing";
  crossing.p = kStart + Eigen::Vector3d(500.0, 0.0, 0.0);
  ASSERT_TRUE(store->CreatePoi(&crossing));

  Poi back;
  ASSERT_TRUE(store->GetPoi(mast.id, &back));
  EXPECT_EQ(back.name, "M 12");
  EXPECT_EQ(back.properties_json, R"({"height_m": 8.5})");
  ExpectPoisListedByLineAndArea(*store);

  mast.name = "M 12a";
  ASSERT_TRUE(store->UpdatePoi(&mast));
  ASSERT_TRUE(store->GetPoi(mast.id, &back));
  EXPECT_EQ(back.name, "M 12a");
  EXPECT_GE(back.updated_ns, back.created_ns);
  // Bad input changes nothing.
  ExpectBadPoisRefused(*store, mast);
  ASSERT_TRUE(store->GetPoi(mast.id, &back));
  EXPECT_EQ(back.name, "M 12a");

  ASSERT_TRUE(store->DeletePoi(mast.id));
  EXPECT_EQ(store->GetPoi(mast.id, &back).outcome, Outcome::kNotFound);
  EXPECT_EQ(store->DeletePoi(mast.id).outcome, Outcome::kNotFound);
}

TEST(MapStore, ASubmapWhosePayloadWasLostIsRestoredBySendingItAgain) {
  test::ScratchDir dir("raillomer_store_");
  std::string error;
  const int64_t run = StoreRun(dir.path().string(), 1);
  const std::string payload = api::EncodeSubmapPcd(CorridorSubmap(1));
  // A child acknowledges submap 1 and dies before its tiles are written; then its payload is
  // lost too (as a power cut could).
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    std::string e;
    auto store = OpenStore(dir.path().string(), &e);
    const bool ok = store && store->IngestSubmap(run, payload, nullptr).ok();
    kill(getpid(), SIGKILL);
    _exit(ok ? 0 : 1);
  }
  int status = 0;
  waitpid(child, &status, 0);
  std::filesystem::remove_all(dir.path() / "incoming");
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  EXPECT_EQ(store->stats().submaps_lost, 1u);
  EXPECT_EQ(store->recovery().lost,
            (std::vector<std::pair<int64_t, uint64_t>>{{run, CorridorSubmap(1).sequence}}));
  // The run counts what its tiles hold: the lost submap apart.
  RunInfo info;
  ASSERT_TRUE(store->GetRun(run, &info));
  const int64_t points = static_cast<int64_t>(CorridorSubmap(1).points.size());
  EXPECT_EQ(info.submaps_lost, 1);
  const RunInfo lost = info;
  const size_t before = AllPoints(*store, run).size();
  IngestReceipt receipt;
  const Result r = store->IngestSubmap(run, payload, &receipt);
  EXPECT_EQ(r.outcome, Outcome::kOk) << r.message;
  ASSERT_TRUE(store->GetRun(run, &info));
  EXPECT_EQ(info.submaps_lost, 0);
  EXPECT_EQ(info.submaps, lost.submaps + 1);
  EXPECT_EQ(info.points, lost.points + points);
  ASSERT_TRUE(store->Flush());
  EXPECT_EQ(AllPoints(*store, run).size(), before + receipt.points_new);
  EXPECT_GT(receipt.points_new, 0u);
  // Sent once more, it is an ordinary duplicate.
  EXPECT_EQ(store->IngestSubmap(run, payload, nullptr).outcome, Outcome::kDuplicate);
}

/// An index as schema version `version` wrote it, with `rows` inserted (SQL statements).
void WriteOldIndex(const std::string& path, int version, const std::string& rows) {
  std::string error;
  Database db;
  ASSERT_TRUE(db.Open(path, true, &error)) << error;
  ASSERT_TRUE(MigrateSchemaTo(db, version, &error)) << error;
  ASSERT_TRUE(db.Exec(rows, &error)) << error;
}

TEST(MapStore, MigratesAnOlderIndexAndRefusesANewerOne) {
  test::ScratchDir dir("raillomer_store_");
  const std::string path = (dir.path() / "index.sqlite").string();
  std::string error;
  // An index as the first schema version wrote it, with a run on it.
  ASSERT_NO_FATAL_FAILURE(
      WriteOldIndex(path,
                    1,
                    "INSERT INTO runs (line, vehicle, status, start_ns, created_ns) VALUES "
                    "('Old line', 'RLM-0', 'finished', 5, 6)"));
  {
    auto store = OpenStore(dir.path().string(), &error);
    ASSERT_TRUE(store) << error;
    const std::vector<RunInfo> runs = store->ListRuns();
    ASSERT_EQ(runs.size(), 1u);
    EXPECT_EQ(runs[0].line, "Old line");
  }
  Database db;
  ASSERT_TRUE(db.Open(path, false, &error)) << error;
  Statement version(db, "PRAGMA user_version");
  ASSERT_TRUE(version.Step());
  EXPECT_EQ(version.Int(0), LatestSchemaVersion());
  Statement line(db, "SELECT name FROM lines");
  ASSERT_TRUE(line.Step());
  EXPECT_EQ(line.Text(0), "Old line");
  ASSERT_TRUE(db.Exec("PRAGMA user_version = 99", &error));
  auto newer = OpenStore(dir.path().string(), &error);
  EXPECT_FALSE(newer);
  EXPECT_NE(error.find("schema version 99"), std::string::npos) << error;
}

TEST(MapStore, MigrationEightKeepsTheChangesAndNeverGivesAnIdAgain) {
  test::ScratchDir dir("raillomer_store_");
  const std::string path = (dir.path() / "index.sqlite").string();
  std::string error;
  const std::string change =
      "INSERT INTO changes (run_id, reference_run, stretch, line, kind, chainage_m, offset_m, "
      "utm_zone, x, y, z, properties, intrudes, size_max_m, created_ns, updated_ns, "
      "first_seen_run) VALUES (7, 1, 0, 'L', 'added', 12.0, -2.0, '50N', 1, 2, 3, '{}', 0, 1.5, "
      "5, 6, 7)";
  // Version 7 held change 5, the latest, with a note.
  ASSERT_NO_FATAL_FAILURE(WriteOldIndex(path,
                                        7,
                                        "INSERT INTO runs (id, line, vehicle, status, start_ns, "
                                        "created_ns) VALUES (7, 'L', 'V', 'finished', 5, 6); " +
                                            change +
                                            "; UPDATE changes SET id = 5, note = 'cut it'"));
  ASSERT_TRUE(OpenStore(dir.path().string(), &error)) << error;  // migrates, then closes
  Database db;
  ASSERT_TRUE(db.Open(path, false, &error)) << error;
  Statement kept(db, "SELECT id, note, rechecking, first_seen_run FROM changes");
  ASSERT_TRUE(kept.Step());
  EXPECT_EQ(kept.Int(0), 5);
  EXPECT_EQ(kept.Text(1), "cut it");
  EXPECT_EQ(kept.Int(2), 0);
  EXPECT_EQ(kept.Int(3), 7);
  // Change 5 withdrawn, the next is 6, not 5 again.
  ASSERT_TRUE(db.Exec("DELETE FROM changes WHERE id = 5; " + change, &error)) << error;
  EXPECT_EQ(db.LastInsertId(), 6);
}

TEST(MapStore, MigrationFourTakesLostSubmapsOutOfTheirRunsCounts) {
  test::ScratchDir dir("raillomer_store_");
  const std::string path = (dir.path() / "index.sqlite").string();
  std::string error;
  // Version 3 counted a submap whose payload was lost (tiled = -1) in its run.
  ASSERT_NO_FATAL_FAILURE(WriteOldIndex(
      path,
      3,
      "INSERT INTO runs (id, line, vehicle, status, start_ns, created_ns, utm_zone, submaps, "
      "points) VALUES (7, 'L', 'V', 'finished', 5, 6, '50N', 2, 300);"
      "INSERT INTO submaps VALUES (7, 0, 0, 1, 2, '50N', 0, 0, 0, 0, 0, 1, 1, 100, 1, 'a', 1, 9);"
      "INSERT INTO submaps VALUES (7, 1, 1, 3, 4, '50N', 0, 0, 0, 0, 0, 1, 1, 200, 1, 'b', -1, "
      "9);"));
  auto store = OpenStore(dir.path().string(), &error);
  ASSERT_TRUE(store) << error;
  RunInfo run;
  ASSERT_TRUE(store->GetRun(7, &run));
  EXPECT_EQ(run.submaps, 1);
  EXPECT_EQ(run.submaps_lost, 1);
  EXPECT_EQ(run.points, 100);
  EXPECT_EQ(store->stats().submaps_lost_stored, 1u);
}

}  // namespace
}  // namespace raillomer::mapstore
