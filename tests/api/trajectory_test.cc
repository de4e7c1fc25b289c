#include "api/trajectory.h"

#include <cstdio>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "api/atomic_file.h"

namespace raillomer::api {
namespace {

TEST(Stamp, ParsesAndFormatsExactNanoseconds) {
  int64_t ns = 0;
  ASSERT_TRUE(ParseStampSeconds("1600000000.123456789", &ns));
  EXPECT_EQ(ns, 1600000000123456789LL);
  ASSERT_TRUE(ParseStampSeconds("1600000000.1", &ns));
  EXPECT_EQ(ns, 1600000000100000000LL);
  ASSERT_TRUE(ParseStampSeconds("42", &ns));
  EXPECT_EQ(ns, 42000000000LL);
  ASSERT_TRUE(ParseStampSeconds("1.6e9", &ns));
  EXPECT_EQ(ns, 1600000000000000000LL);
  EXPECT_FALSE(ParseStampSeconds("12a", &ns));
  EXPECT_FALSE(ParseStampSeconds("", &ns));
  EXPECT_EQ(FormatStampSeconds(1600000000000000001LL), "1600000000.000000001");
  EXPECT_EQ(FormatStampSeconds(-1500000000LL), "-1.500000000");
}

TEST(Tum, RoundTripsWithZone) {
  Trajectory t;
  t.utm_zone = "50N";
  for (int i = 0; i < 3; ++i) {
    StampedPose p;
    p.stamp_ns = 1600000000000000000LL + i * 10000000LL;
    p.p_world = Eigen::Vector3d(432000.123456 + i, 3585000.5, 33.8);
    p.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitZ()));
    t.poses.push_back(p);
  }
  Trajectory back;
  std::string error;
  ASSERT_TRUE(ParseTum(FormatTum(t), &back, &error)) << error;
  EXPECT_EQ(back.utm_zone, "50N");
  ASSERT_EQ(back.poses.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(back.poses[i].stamp_ns, t.poses[i].stamp_ns);
    EXPECT_NEAR((back.poses[i].p_world - t.poses[i].p_world).norm(), 0.0, 1e-6);
    EXPECT_NEAR(back.poses[i].q_world_body.angularDistance(t.poses[i].q_world_body), 0.0, 1e-8);
  }
}

TEST(Tum, RejectsBadLinesByNumber) {
  Trajectory t;
  std::string error;
  EXPECT_FALSE(ParseTum("# c\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n", &t, &error));
  EXPECT_NE(error.find("line 3"), std::string::npos) << error;
  EXPECT_FALSE(ParseTum("1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", &t, &error));
  EXPECT_NE(error.find("does not increase"), std::string::npos) << error;
  EXPECT_FALSE(ParseTum("1 0 0 0 0 0 0 2\n", &t, &error));
  EXPECT_NE(error.find("unit length"), std::string::npos) << error;
  EXPECT_FALSE(ParseTum("# utm_zone 99X\n", &t, &error));
  EXPECT_NE(error.find("utm_zone"), std::string::npos) << error;
  EXPECT_FALSE(ReadTum("/nonexistent/x.tum", &t, &error));
  EXPECT_NE(error.find("/nonexistent/x.tum"), std::string::npos) << error;
}

TEST(AtomicFile, LeavesNothingWithoutCommit) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / "raillomer_atomic";
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "out.txt").string();
  std::filesystem::remove(path);
  {
    AtomicFile file(path);
    std::ofstream(file.temp_path()) << "half";
  }
  EXPECT_FALSE(std::filesystem::exists(path));
  EXPECT_TRUE(std::filesystem::is_empty(dir));
  std::string error;
  ASSERT_TRUE(WriteFileAtomically(path, "whole", &error)) << error;
  std::ifstream in(path);
  std::string text;
  in >> text;
  EXPECT_EQ(text, "whole");
  EXPECT_FALSE(WriteFileAtomically("/nonexistent/dir/x", "x", &error));
  EXPECT_NE(error.find("/nonexistent/dir/x"), std::string::npos);
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace raillomer::api
