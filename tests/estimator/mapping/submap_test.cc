// Submaps and the global map export: keyframes grouped in tens, their positions rebuilt along
// their headings (no sideways slip of the wheels), points carried into UTM with a double origin
// and float offsets, the submap file codec and the map file round trip.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <vector>

#include <gtest/gtest.h>

#include "api/las.h"
#include "api/stream.h"
#include "estimator/mapping/map_export.h"
#include "estimator/mapping/submap_builder.h"
#include "tests/support/poses.h"
#include "tests/support/process.h"

namespace raillomer {
namespace {

Eigen::Isometry3d Pose(double e, double n, double h, double yaw) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(e, n, h);
  return T;
}

/// A keyframe whose odometry pose is its published pose (the registration stages are tested
/// apart).
SubmapKeyframe Keyframe(int64_t stamp_ns,
                        const Eigen::Isometry3d& T,
                        bool georeferenced,
                        const std::string& zone,
                        std::vector<Eigen::Vector3f> points,
                        std::vector<float> intensities) {
  SubmapKeyframe k;
  k.stamp_ns = stamp_ns;
  k.T_world_body = T;
  k.T_odom_body = T;
  k.georeferenced = georeferenced;
  k.utm_zone = zone;
  k.points_body = std::move(points);
  k.intensities = std::move(intensities);
  return k;
}

SubmapOptions Plain(int keyframes, double voxel_m) {
  SubmapOptions o;
  o.keyframes = keyframes;
  o.voxel_m = voxel_m;
  o.icp = false;
  o.ndt = false;
  o.remove_side_slip = false;  // keyframes placed as given (WithoutSideSlip is tested apart)
  return o;
}

/// A keyframe cloud: a 5 x 5 grid of points 1 m apart in the body frame, 2 m ahead.
std::vector<Eigen::Vector3f> Grid() {
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 5; ++i)
    for (int j = 0; j < 5; ++j)
      points.emplace_back(2.0f, static_cast<float>(i), static_cast<float>(j));
  return points;
}

TEST(SubmapBuilder, TenKeyframesMakeASubmapInUtm) {
  SubmapBuilder builder(Plain(10, 0.0));
  std::vector<api::Submap> done;
  const std::vector<float> intensity(25, 7.f);
  for (int k = 0; k < 25; ++k) {
    // Along a line heading north (yaw 90 deg), 2 m apart, at northing 3.6e6.
    for (api::Submap& s :
         builder.Add(Keyframe(1'600'000'000'000'000'000 + k * 100'000'000LL,
                              Pose(432000.3, 3585000.7 + 2.0 * k, 30.2, M_PI / 2.0),
                              true,
                              "50N",
                              Grid(),
                              intensity))) {
      done.push_back(std::move(s));
    }
  }
  ASSERT_EQ(done.size(), 2u);
  const std::vector<api::Submap> flushed = builder.Flush();
  ASSERT_EQ(flushed.size(), 1u);
  const api::Submap* rest = &flushed[0];
  EXPECT_EQ(rest->keyframes.size(), 5u);
  EXPECT_EQ(rest->index, 2u);
  EXPECT_TRUE(builder.Flush().empty());

  const api::Submap& s = done[1];
  EXPECT_EQ(s.index, 1u);
  EXPECT_EQ(s.keyframes.size(), 10u);
  EXPECT_EQ(s.points.size(), 250u);
  EXPECT_EQ(s.utm_zone, "50N");
  EXPECT_EQ(s.first_stamp_ns, 1'600'000'001'000'000'000);
  // The origin is the first keyframe's position rounded to whole metres.
  EXPECT_EQ(s.origin, Eigen::Vector3d(432000.0, 3585021.0, 30.0));
  // Body (2, 0, 0) at yaw 90 deg is 2 m north of the keyframe: exact to well below a millimetre
  // once the float offset is added to the double origin.
  const Eigen::Vector3d first = s.origin + s.points[0].cast<double>();
  EXPECT_NEAR(first.x(), 432000.3, 1e-4);
  EXPECT_NEAR(first.y(), 3585000.7 + 20.0 + 2.0, 1e-4);
  EXPECT_NEAR(first.z(), 30.2, 1e-4);
  EXPECT_FLOAT_EQ(s.intensities[0], 7.f);
}

TEST(SubmapBuilder, OverlappingKeyframesAreThinnedToOnePointPerVoxel) {
  SubmapBuilder builder(Plain(2, 0.1));
  const std::vector<float> intensity(25, 1.f);
  builder.Add(Keyframe(1, Pose(100.0, 200.0, 10.0, 0.0), false, "", Grid(), intensity));
  const std::vector<api::Submap> done =
      builder.Add(Keyframe(2, Pose(100.0, 200.0, 10.0, 0.0), false, "", Grid(), intensity));
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(done[0].points.size(), 25u);  // the same 25 points twice
  EXPECT_FALSE(done[0].georeferenced);
}

TEST(SubmapBuilder, PointsBeyondTheRangeLimitStayOut) {
  // One keyframe seeing a point 10 m ahead, one 49.9 m ahead and one 50.1 m ahead.
  const std::vector<Eigen::Vector3f> points = {
      {10.f, 0.f, 0.f}, {0.f, 49.9f, 0.f}, {30.f, 40.f, 0.5f}};
  auto kept = [&](double max_range_m) {
    SubmapOptions options = Plain(1, 0.0);
    options.max_range_m = max_range_m;
    SubmapBuilder builder(options);
    const std::vector<api::Submap> done = builder.Add(
        Keyframe(1, Pose(100.0, 200.0, 10.0, 0.3), false, "", points, std::vector<float>(3, 1.f)));
    EXPECT_EQ(done.size(), 1u);
    return done.empty() ? size_t{0} : done[0].points.size();
  };
  EXPECT_EQ(kept(50.0), 2u);
  EXPECT_EQ(kept(0.0), 3u);  // no limit
  EXPECT_EQ(kept(5.0), 0u);
}

TEST(SubmapBuilder, TheFrameChangingClosesTheOpenSubmap) {
  SubmapBuilder builder(Plain(10, 0.0));
  builder.Add(Keyframe(1, Pose(1.0, 2.0, 3.0, 0.0), false, "", Grid(), {}));
  const std::vector<api::Submap> done =
      builder.Add(Keyframe(2, Pose(432000.0, 3585000.0, 30.0, 0.0), true, "50N", Grid(), {}));
  ASSERT_EQ(done.size(), 1u);
  EXPECT_FALSE(done[0].georeferenced);
  EXPECT_EQ(builder.Flush().at(0).utm_zone, "50N");
}

/// A body pose from its position and roll, pitch and yaw (rad).
Eigen::Isometry3d BodyPose(const Eigen::Vector3d& p, double roll, double pitch, double yaw) {
  return test::PoseYpr(p, yaw, pitch, roll);
}

double LargestMove(const std::vector<Eigen::Isometry3d>& a,
                   const std::vector<Eigen::Isometry3d>& b) {
  double worst = 0.0;
  for (size_t k = 0; k < a.size(); ++k)
    worst = std::max(worst, (a[k].translation() - b[k].translation()).norm());
  return worst;
}

TEST(WithoutSideSlip, KeepsAPathAlongItsHeadingOnACurvedGrade) {
  // Keyframes 3 m apart on a 500 m curve climbing at 10 permille, each heading along it, the
  // wheels 3.8 m below the body on the rail.
  const Eigen::Vector3d wheel(0.0, 0.0, -3.8);
  std::vector<Eigen::Isometry3d> poses;
  const double radius = 500.0, grade = 0.01;
  for (int k = 0; k < 10; ++k) {
    const double angle = 3.0 * k / radius;
    Eigen::Isometry3d T = BodyPose(Eigen::Vector3d::Zero(), 0.0, -std::atan(grade), angle);
    const Eigen::Vector3d rail(
        radius * std::sin(angle), radius * (1.0 - std::cos(angle)), 3.0 * k * grade);
    T.translation() = rail - T.linear() * wheel;
    poses.push_back(T);
  }
  EXPECT_LT(LargestMove(poses, WithoutSideSlip(poses, 5, wheel, 0.02)), 1e-9);
  EXPECT_TRUE(WithoutSideSlip({}, 0, Eigen::Vector3d::Zero(), 0.02).empty());
}

TEST(WithoutSideSlip, TakesOutASidewaysSlideAndKeepsTheRest) {
  // Heading east on straight track, the positions sliding north by 2 mrad of the travel.
  std::vector<Eigen::Isometry3d> poses;
  for (int k = 0; k < 10; ++k)
    poses.push_back(BodyPose(Eigen::Vector3d(3.0 * k, 0.002 * 3.0 * k, 0.0), 0.0, 0.0, 0.0));
  const std::vector<Eigen::Isometry3d> out =
      WithoutSideSlip(poses, 4, Eigen::Vector3d(0, 0, -3.8), 0.02);
  for (size_t k = 0; k < poses.size(); ++k) {
    EXPECT_NEAR(out[k].translation().x(), poses[k].translation().x(), 1e-9) << k;
    EXPECT_NEAR(out[k].translation().y(), poses[4].translation().y(), 1e-9) << k;  // the anchor's
    EXPECT_TRUE(out[k].linear().isApprox(poses[k].linear())) << k;
  }
  EXPECT_EQ(out[4].translation(), poses[4].translation());
}

TEST(WithoutSideSlip, KeepsWhatTheStepsDoNotShare) {
  // Heading east, the positions zigzagging 5 mm either side over ten steps: no common slip,
  // nothing moves.
  const Eigen::Vector3d wheel(0.0, 0.0, -3.8);
  std::vector<Eigen::Isometry3d> poses;
  for (int k = 0; k < 11; ++k)
    poses.push_back(BodyPose(Eigen::Vector3d(3.0 * k, k % 2 ? 0.005 : -0.005, 0.0), 0.0, 0.0, 0.0));
  EXPECT_LT(LargestMove(poses, WithoutSideSlip(poses, 5, wheel, 0.02)), 1e-9);
  // The same zigzag on a 2 mrad slide: the slide goes, the zigzag stays.
  std::vector<Eigen::Isometry3d> sliding = poses;
  for (int k = 0; k < 11; ++k) sliding[k].translation().y() += 0.006 * k;
  const std::vector<Eigen::Isometry3d> out = WithoutSideSlip(sliding, 5, wheel, 0.02);
  for (int k = 0; k < 11; ++k)
    EXPECT_NEAR(out[k].translation().y(), poses[k].translation().y() + 0.03, 1e-9) << k;
}

TEST(WithoutSideSlip, TakesOutAStepAcrossTheTrack) {
  // Heading east on straight track; between the third and the fourth keyframe the positions
  // jump 9 cm north (the window taking a correction). Fitted with the jump, the slip would
  // have turned every other step by 3.7 mrad.
  const Eigen::Vector3d wheel(0.0, 0.0, -3.8);
  std::vector<Eigen::Isometry3d> poses;
  for (int k = 0; k < 10; ++k)
    poses.push_back(BodyPose(Eigen::Vector3d(3.0 * k, k >= 3 ? 0.09 : 0.0, 0.0), 0.0, 0.0, 0.0));
  const std::vector<Eigen::Isometry3d> out = WithoutSideSlip(poses, 5, wheel, 0.02);
  for (int k = 0; k < 10; ++k) {
    EXPECT_NEAR(out[k].translation().y(), 0.09, 1e-9) << k;  // the anchor's side
    EXPECT_NEAR(out[k].translation().x(), 3.0 * k, 1e-9) << k;
  }
  // Taken for slip (a threshold above the jump), it would bend the rest by centimetres.
  EXPECT_GT(LargestMove(poses, WithoutSideSlip(poses, 5, wheel, 0.1)), 0.03);
}

TEST(WithoutSideSlip, KeepsTheBodysSwingAboutTheWheels) {
  // A cant transition: the body rolls by up to 50 mrad about the rail 3.8 m below it, so its
  // origin moves sideways by up to 19 cm while the wheels run straight.
  const Eigen::Vector3d wheel(0.0, 0.0, -3.8);
  std::vector<Eigen::Isometry3d> poses;
  for (int k = 0; k < 10; ++k) {
    const double roll = 0.005 * k;
    Eigen::Isometry3d T = BodyPose(Eigen::Vector3d::Zero(), roll, 0.0, 0.0);
    T.translation() = Eigen::Vector3d(3.0 * k, 0.0, 0.0) - T.linear() * wheel;
    poses.push_back(T);
  }
  EXPECT_LT(LargestMove(poses, WithoutSideSlip(poses, 5, wheel, 0.02)), 1e-9);
  // Taken at the body origin instead, the step would lose that sideways swing.
  EXPECT_GT(LargestMove(poses, WithoutSideSlip(poses, 5, Eigen::Vector3d::Zero(), 0.02)), 0.05);
}

TEST(SubmapBuilder, KeyframesSlidingSidewaysStillMapAPostToOnePlace) {
  // A post (points 1 m apart up a vertical line) 1.5 m left of the track at 40 m, seen from
  // ten keyframes 3 m apart heading east whose odometry slides north by 2 mrad of the travel.
  std::vector<Eigen::Vector3d> post;
  for (int i = 0; i < 5; ++i) post.emplace_back(40.0, 1.5, static_cast<double>(i));
  auto spread = [&](bool remove_side_slip) {
    SubmapOptions options = Plain(10, 0.0);
    options.remove_side_slip = remove_side_slip;
    options.p_body_odometer = Eigen::Vector3d(0.0, 0.0, -3.8);
    SubmapBuilder builder(options);
    std::vector<api::Submap> done;
    for (int k = 0; k < 10; ++k) {
      const Eigen::Isometry3d truth = Pose(3.0 * k, 0.0, 0.0, 0.0);
      std::vector<Eigen::Vector3f> points;
      for (const Eigen::Vector3d& p : post) points.push_back((truth.inverse() * p).cast<float>());
      SubmapKeyframe keyframe = Keyframe(k + 1,
                                         Pose(3.0 * k, 0.006 * k, 0.0, 0.0),
                                         false,
                                         "",
                                         points,
                                         std::vector<float>(points.size(), 1.f));
      for (api::Submap& s : builder.Add(std::move(keyframe))) done.push_back(std::move(s));
    }
    EXPECT_EQ(done.size(), 1u);
    double lo = 1e9, hi = -1e9;
    for (const Eigen::Vector3f& q : done.at(0).points) {
      lo = std::min(lo, static_cast<double>(q.y()));
      hi = std::max(hi, static_cast<double>(q.y()));
    }
    return hi - lo;
  };
  EXPECT_LT(spread(true), 1e-4);
  EXPECT_GT(spread(false), 0.05);  // 2 mrad over the 27 m between the first and last keyframe
}

api::Submap SampleSubmap() {
  SubmapBuilder builder(Plain(3, 0.0));
  const std::vector<float> intensity(25, 3.5f);
  for (int k = 0; k < 2; ++k) {
    builder.Add(Keyframe(1'600'000'000'100'000'000 + k * 100'000'000LL,
                         Pose(432000.3 + 2.0 * k, 3585000.7 + 1.0 * k, 30.2, 0.3),
                         true,
                         "50N",
                         Grid(),
                         intensity));
  }
  api::Submap s = builder.Flush().at(0);
  s.sequence = 41;
  return s;
}

TEST(SubmapCodec, RoundTripKeepsEverything) {
  const api::Submap s = SampleSubmap();
  api::Submap back;
  std::string error;
  ASSERT_TRUE(api::DecodeSubmapPcd(api::EncodeSubmapPcd(s), &back, &error)) << error;
  EXPECT_EQ(back.sequence, 41u);
  EXPECT_EQ(back.index, s.index);
  EXPECT_EQ(back.first_stamp_ns, s.first_stamp_ns);
  EXPECT_EQ(back.last_stamp_ns, s.last_stamp_ns);
  EXPECT_TRUE(back.georeferenced);
  EXPECT_EQ(back.utm_zone, "50N");
  EXPECT_EQ(back.origin, s.origin);
  ASSERT_EQ(back.keyframes.size(), 2u);
  EXPECT_NEAR((back.keyframes[1].p_world - s.keyframes[1].p_world).norm(), 0.0, 1e-6);
  ASSERT_EQ(back.points.size(), s.points.size());
  for (size_t i = 0; i < s.points.size(); ++i) {
    EXPECT_EQ(back.points[i], s.points[i]);
    EXPECT_EQ(back.intensities[i], s.intensities[i]);
  }
  EXPECT_EQ(back.placement, 0u);
  // A cut file is named as such.
  const std::string bytes = api::EncodeSubmapPcd(s);
  EXPECT_FALSE(api::DecodeSubmapPcd(bytes.substr(0, bytes.size() - 5), &back, &error));
  EXPECT_NE(error.find("truncated"), std::string::npos) << error;
}

TEST(SubmapCodec, KeepsAProvisionalSubmapsPlacement) {
  api::Submap s = SampleSubmap();
  s.placement = 7;
  const std::string bytes = api::EncodeSubmapPcd(s);
  api::Submap back;
  std::string error;
  ASSERT_TRUE(api::DecodeSubmapPcd(bytes, &back, &error)) << error;
  EXPECT_EQ(back.placement, 7u);
  // A placement that is no whole number is named.
  std::string bad = bytes;
  bad.replace(bad.find("placement 7"), 11, "placement x");
  EXPECT_FALSE(api::DecodeSubmapPcd(bad, &back, &error));
  EXPECT_NE(error.find("placement"), std::string::npos) << error;
}

class MapExport : public ::testing::TestWithParam<const char*> {};

TEST_P(MapExport, RoundTripKeepsUtmCoordinatesWithinAMillimetre) {
  const test::ScratchDir dir("raillomer_map_export_");
  const std::string path = (dir.path() / (std::string("map.") + GetParam())).string();
  const api::Submap s = SampleSubmap();
  MapExportOptions options;
  options.voxel_m = 0.0;
  std::string error;
  std::unique_ptr<MapExporter> map = MapExporter::Open(path, options, &error);
  ASSERT_TRUE(map) << error;
  map->Add(s);
  ASSERT_TRUE(map->Close(&error)) << error;
  EXPECT_FALSE(std::filesystem::exists(path + ".points.tmp"));
  std::vector<Eigen::Vector3d> points;
  std::vector<float> intensities;
  std::string comment;
  ASSERT_TRUE(ReadMapFile(path, &points, &intensities, &comment, &error)) << error;
  EXPECT_NE(comment.find("UTM zone 50N"), std::string::npos) << comment;
  ASSERT_EQ(points.size(), s.points.size());
  // LAS holds whole intensities: 3.5 is rounded.
  const float intensity = std::string(GetParam()) == "las" ? 4.f : 3.5f;
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d expected = s.origin + s.points[i].cast<double>();
    EXPECT_LT((points[i] - expected).norm(), 1e-3);
    EXPECT_EQ(intensities[i], intensity);
  }
  // Truth independent of the codec: the first point is body (2, 0, 0) of the first keyframe.
  const Eigen::Vector3d first =
      Pose(432000.3, 3585000.7, 30.2, 0.3) * Eigen::Vector3d(2.0, 0.0, 0.0);
  EXPECT_LT((points[0] - first).norm(), 1e-3);
}

TEST_P(MapExport, VoxelAndBoxThinTheMap) {
  const test::ScratchDir dir("raillomer_map_export_");
  const std::string path = (dir.path() / (std::string("map.") + GetParam())).string();
  MapExportOptions options;
  options.voxel_m = 0.5;
  options.has_box = true;
  options.box_min = Eigen::Vector2d(431990.0, 3584990.0);
  options.box_max = Eigen::Vector2d(432003.0, 3585010.0);
  std::string error;
  std::unique_ptr<MapExporter> map = MapExporter::Open(path, options, &error);
  ASSERT_TRUE(map) << error;
  const api::Submap s = SampleSubmap();
  map->Add(s);
  map->Add(s);  // the same submap again: its voxels are already in the map
  ASSERT_TRUE(map->Close(&error)) << error;
  std::vector<Eigen::Vector3d> points;
  std::vector<float> intensities;
  ASSERT_TRUE(ReadMapFile(path, &points, &intensities, nullptr, &error)) << error;
  EXPECT_GT(points.size(), 10u);
  EXPECT_LT(points.size(), s.points.size());
  for (const Eigen::Vector3d& p : points) {
    EXPECT_GE(p.x(), 431990.0);
    EXPECT_LE(p.x(), 432003.0);
  }
}

INSTANTIATE_TEST_SUITE_P(Formats, MapExport, ::testing::Values("ply", "pcd", "las"));

TEST(MapExportLas, NamesItsUtmZoneForGisToolsOrAUserDefinedSystemWhenLocal) {
  const test::ScratchDir dir("raillomer_map_export_");
  for (const bool georeferenced : {true, false}) {
    const std::string path = (dir.path() / "map.las").string();
    api::Submap s = SampleSubmap();
    s.georeferenced = georeferenced;
    if (!georeferenced) s.utm_zone.clear();
    std::string error;
    std::unique_ptr<MapExporter> map = MapExporter::Open(path, MapExportOptions(), &error);
    ASSERT_TRUE(map) << error;
    map->Add(s);
    ASSERT_TRUE(map->Close(&error)) << error;
    std::ifstream in(path, std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    api::las::Contents las;
    ASSERT_TRUE(api::las::Decode(bytes, &las, &error)) << error;
    EXPECT_EQ(las.points.size(), map->points());
    EXPECT_EQ(las.epsg, georeferenced ? 32650 : 32767);  // 32767: user-defined
    EXPECT_GE(las.creation_year, 2026);
    EXPECT_EQ(las.system_identifier,
              georeferenced ? "RailLoMer UTM zone 50N" : "RailLoMer local odometry frame");
    EXPECT_EQ(bytes.substr(58, 19), "raillomer-estimator");
  }
}

TEST(MapExportErrors, NameWhatIsWrong) {
  std::string error;
  EXPECT_FALSE(MapExporter::Open("/tmp/map.xyz", MapExportOptions(), &error));
  EXPECT_NE(error.find(".ply, .pcd or .las"), std::string::npos) << error;
  EXPECT_FALSE(MapExporter::Open("/nonexistent/dir/map.ply", MapExportOptions(), &error));
  EXPECT_NE(error.find("/nonexistent/dir/map.ply"), std::string::npos) << error;
  const test::ScratchDir dir("raillomer_map_export_");
  const std::string path = (dir.path() / "cut.ply").string();
  std::ofstream(path)
      << "ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty double x\n"
         "property double y\nproperty double z\nproperty float intensity\nend_header\nxx";
  std::vector<Eigen::Vector3d> points;
  std::vector<float> intensities;
  EXPECT_FALSE(ReadMapFile(path, &points, &intensities, nullptr, &error));
  EXPECT_NE(error.find("expected 10 points"), std::string::npos) << error;
}

}  // namespace
}  // namespace raillomer
