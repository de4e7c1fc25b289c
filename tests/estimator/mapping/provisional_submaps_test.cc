// Provisional submaps: keyframes' points placed at their provisional UTM poses, a voxel apart
// and within range, a submap every N keyframes, and a new one after a gap, in another zone or
// of another placement.
#include <gtest/gtest.h>

#include "estimator/mapping/provisional_submaps.h"

namespace raillomer {
namespace {

constexpr int64_t kSecond = 1'000'000'000;

Eigen::Isometry3d At(double easting) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(500000.0 + easting, 4000000.0, 10.0);
  return T;
}

TEST(ProvisionalSubmaps, GathersKeyframesAtTheirPosesAVoxelApartWithinRange) {
  ProvisionalSubmaps submaps(3, 0.1, 50.0);
  // Two points in one voxel, one 60 m off (beyond range).
  const std::vector<Eigen::Vector3f> points = {
      {1.01f, 0.0f, 0.0f}, {1.02f, 0.01f, 0.0f}, {60.0f, 0.0f, 0.0f}};
  const std::vector<float> intensities = {10.0f, 20.0f, 30.0f};
  EXPECT_TRUE(submaps.Add(0, At(0.0), "50N", 1, points, intensities).empty());
  EXPECT_TRUE(submaps.Add(kSecond / 10, At(2.0), "50N", 1, points, intensities).empty());
  const std::vector<api::Submap> done =
      submaps.Add(2 * kSecond / 10, At(4.0), "50N", 1, points, intensities);
  ASSERT_EQ(done.size(), 1u);
  const api::Submap& s = done[0];
  EXPECT_TRUE(s.georeferenced);
  EXPECT_EQ(s.utm_zone, "50N");
  EXPECT_EQ(s.keyframes.size(), 3u);
  EXPECT_EQ(s.first_stamp_ns, 0);
  EXPECT_EQ(s.last_stamp_ns, 2 * kSecond / 10);
  ASSERT_EQ(s.points.size(), 3u);  // one a keyframe: the first of each voxel, none beyond 50 m
  EXPECT_FLOAT_EQ(s.intensities[0], 10.0f);
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector3d utm = s.origin + s.points[i].cast<double>();
    EXPECT_NEAR(utm.x(), 500001.01 + 2.0 * i, 1e-3);
    EXPECT_NEAR(utm.y(), 4000000.0, 1e-3);
  }
  EXPECT_EQ(submaps.made(), 1u);
}

TEST(ProvisionalSubmaps, StartsAnotherAfterAGapOrInAnotherZone) {
  ProvisionalSubmaps submaps(10, 0.1, 0.0);
  const std::vector<Eigen::Vector3f> points = {{1.0f, 0.0f, 0.0f}};
  EXPECT_TRUE(submaps.Add(0, At(0.0), "50N", 1, points, {1.0f}).empty());
  // 3 s later: the first goes out alone.
  std::vector<api::Submap> done = submaps.Add(3 * kSecond, At(80.0), "50N", 1, points, {1.0f});
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(done[0].keyframes.size(), 1u);
  done = submaps.Add(3 * kSecond + kSecond / 10, At(82.0), "51N", 1, points, {1.0f});
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(done[0].utm_zone, "50N");
  EXPECT_EQ(done[0].first_stamp_ns, 3 * kSecond);
  const std::optional<api::Submap> rest = submaps.Flush();
  ASSERT_TRUE(rest);
  EXPECT_EQ(rest->utm_zone, "51N");
  EXPECT_EQ(rest->sequence, 2u);
  EXPECT_FALSE(submaps.Flush());
}

TEST(ProvisionalSubmaps, StartsAnotherWhereThePlacementChanges) {
  ProvisionalSubmaps submaps(10, 0.1, 0.0);
  const std::vector<Eigen::Vector3f> points = {{1.0f, 0.0f, 0.0f}};
  EXPECT_TRUE(submaps.Add(0, At(0.0), "50N", 3, points, {1.0f}).empty());
  EXPECT_TRUE(submaps.Add(kSecond / 10, At(2.0), "50N", 3, points, {1.0f}).empty());
  const std::vector<api::Submap> done =
      submaps.Add(2 * kSecond / 10, At(4.5), "50N", 4, points, {1.0f});
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(done[0].placement, 3u);
  EXPECT_EQ(done[0].keyframes.size(), 2u);
  const std::optional<api::Submap> rest = submaps.Flush();
  ASSERT_TRUE(rest);
  EXPECT_EQ(rest->placement, 4u);
  EXPECT_EQ(rest->first_stamp_ns, 2 * kSecond / 10);
}

}  // namespace
}  // namespace raillomer
