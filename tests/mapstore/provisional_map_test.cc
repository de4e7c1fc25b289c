// The server's provisional output: held for live, georeferenced runs in one zone, pruned as the
// final output covers it, refused with a reason otherwise.
#include <gtest/gtest.h>

#include "mapstore/provisional_map.h"

namespace raillomer::mapstore {
namespace {

RunInfo LiveRun() {
  RunInfo info;
  info.id = 7;
  info.status = "live";
  return info;
}

api::StreamPose Pose(int64_t stamp_ns, const std::string& zone = "50N") {
  api::StreamPose p;
  p.stamp_ns = stamp_ns;
  p.georeferenced = true;
  p.utm_zone = zone;
  p.p = Eigen::Vector3d(500000.0 + stamp_ns, 4000000.0, 10.0);
  return p;
}

api::Submap Submap(int64_t first_ns, int64_t last_ns, size_t points, uint32_t placement = 0) {
  api::Submap s;
  s.placement = placement;
  s.georeferenced = true;
  s.utm_zone = "50N";
  s.first_stamp_ns = first_ns;
  s.last_stamp_ns = last_ns;
  s.origin = Eigen::Vector3d(500000.0, 4000000.0, 10.0);
  for (size_t i = 0; i < points; ++i) s.points.emplace_back(static_cast<float>(i), 0.0f, 0.0f);
  return s;
}

TEST(ProvisionalMap, GivesThePointsOfAPlacementTogether) {
  ProvisionalMap map;
  ASSERT_TRUE(map.AddSubmap(LiveRun(), Submap(1, 2, 10, 3)));
  ASSERT_TRUE(map.AddSubmap(LiveRun(), Submap(3, 4, 20, 5)));
  ASSERT_TRUE(map.AddSubmap(LiveRun(), Submap(5, 6, 30, 3)));
  ASSERT_TRUE(map.AddSubmap(LiveRun(), Submap(7, 8, 2, 9)));
  ProvisionalRun run;
  ASSERT_TRUE(map.Get(7, &run));
  // Placement 3's two pieces together, then 5's; 9's two points lie outside the box.
  const std::vector<std::vector<Eigen::Vector3d>> points =
      ProvisionalPointsIn(run,
                          Eigen::AlignedBox2d(Eigen::Vector2d(500002.5, 3999999.0),
                                              Eigen::Vector2d(500100.0, 4000001.0)));
  ASSERT_EQ(points.size(), 2u);
  EXPECT_EQ(points[0].size(), 7u + 27u);
  EXPECT_EQ(points[1].size(), 17u);
}

TEST(ProvisionalMap, HoldsALiveRunsOutputUntilTheFinalCoversIt) {
  ProvisionalMap map;
  int added = 0;
  ASSERT_TRUE(map.AddPoses(LiveRun(), {Pose(3), Pose(1), Pose(2)}, &added));
  EXPECT_EQ(added, 3);
  ASSERT_TRUE(map.AddPoses(LiveRun(), {Pose(2), Pose(4)}, &added));  // 2 again: skipped
  EXPECT_EQ(added, 1);
  ASSERT_TRUE(map.AddSubmap(LiveRun(), Submap(1, 2, 10)));
  ASSERT_TRUE(map.AddSubmap(LiveRun(), Submap(3, 4, 10)));
  EXPECT_EQ(map.AddSubmap(LiveRun(), Submap(3, 4, 10)).outcome, Outcome::kDuplicate);
  ProvisionalRun run;
  ASSERT_TRUE(map.Get(7, &run));
  ASSERT_EQ(run.poses.size(), 4u);
  EXPECT_EQ(run.poses.front().stamp_ns, 1);
  EXPECT_EQ(run.pieces.size(), 2u);
  EXPECT_EQ(run.MappedUntil(), 4);
  const std::vector<std::vector<Eigen::Vector3d>> points =
      ProvisionalPointsIn(run,
                          Eigen::AlignedBox2d(Eigen::Vector2d(500000.0, 3999999.0),
                                              Eigen::Vector2d(500004.5, 4000001.0)));
  ASSERT_EQ(points.size(), 1u);      // one placement
  EXPECT_EQ(points[0].size(), 10u);  // x 0..4 of each piece

  map.PrunePoses(7, 2);  // the final output holds poses up to 2 and submaps up to 2
  map.PruneMap(7, 2);
  ASSERT_TRUE(map.Get(7, &run));
  ASSERT_EQ(run.poses.size(), 2u);
  EXPECT_EQ(run.poses.front().stamp_ns, 3);
  ASSERT_EQ(run.pieces.size(), 1u);
  EXPECT_EQ(run.pieces[0]->first_stamp_ns, 3);
  map.PrunePoses(7, 4);
  map.PruneMap(7, 4);
  EXPECT_FALSE(map.Get(7, &run));  // all covered: nothing held
  ASSERT_TRUE(map.AddPoses(LiveRun(), {Pose(5)}, &added));
  map.Drop(7);
  EXPECT_FALSE(map.Get(7, &run));
}

TEST(ProvisionalMap, RefusesWhatCannotBeProvisionalOutputOfTheRun) {
  ProvisionalMap map(ProvisionalOptions{15, 3});
  int added = 0;
  RunInfo finished = LiveRun();
  finished.status = "finished";
  EXPECT_EQ(map.AddPoses(finished, {Pose(1)}, &added).outcome, Outcome::kConflict);
  api::StreamPose local = Pose(1);
  local.georeferenced = false;
  EXPECT_EQ(map.AddPoses(LiveRun(), {local}, &added).outcome, Outcome::kInvalid);
  RunInfo zoned = LiveRun();
  zoned.utm_zone = "51N";
  const Result other_zone = map.AddPoses(zoned, {Pose(1)}, &added);
  EXPECT_EQ(other_zone.outcome, Outcome::kInvalid);
  EXPECT_NE(other_zone.message.find("51N"), std::string::npos) << other_zone.message;
  ASSERT_TRUE(map.AddPoses(LiveRun(), {Pose(1)}, &added));
  EXPECT_EQ(map.AddPoses(LiveRun(), {Pose(2, "51N")}, &added).outcome, Outcome::kInvalid);
  // Limits: 3 poses, 15 points a run; nothing of a refused batch is kept.
  EXPECT_EQ(map.AddPoses(LiveRun(), {Pose(2), Pose(3), Pose(4)}, &added).outcome,
            Outcome::kInvalid);
  ASSERT_TRUE(map.AddSubmap(LiveRun(), Submap(1, 2, 10)));
  EXPECT_EQ(map.AddSubmap(LiveRun(), Submap(3, 4, 10)).outcome, Outcome::kInvalid);
  ProvisionalRun run;
  ASSERT_TRUE(map.Get(7, &run));
  EXPECT_EQ(run.poses.size(), 1u);
  EXPECT_EQ(run.pieces.size(), 1u);
}

}  // namespace
}  // namespace raillomer::mapstore
