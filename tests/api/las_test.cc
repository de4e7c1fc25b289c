#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include <gtest/gtest.h>

#include "api/las.h"

namespace raillomer::api {
namespace {

TEST(Las, EpsgCodesOfUtmZones) {
  EXPECT_EQ(las::EpsgOfUtmZone("50N"), 32650);
  EXPECT_EQ(las::EpsgOfUtmZone("33S"), 32733);
  EXPECT_EQ(las::EpsgOfUtmZone("1N"), 32601);
  EXPECT_EQ(las::EpsgOfUtmZone("60S"), 32760);
  for (const char* bad : {"", "61N", "0N", "50", "50X", "50NN", "N50"})
    EXPECT_EQ(las::EpsgOfUtmZone(bad), 0) << bad;
}

TEST(Las, PointsRoundTripToTheMillimetreWithTheirZone) {
  // b's x and a's z round up to the next millimetre, b's z down: the header's bounds must still
  // enclose every point as stored.
  const Eigen::Vector3d a(432000.1234, 3585000.9876, 30.2006), b(432950.0006, 3586200.5, -12.2496);
  las::Header header;
  header.points = 2;
  header.bounds.extend(a);
  header.bounds.extend(b);
  header.utm_zone = "50N";
  header.software = "a test";
  header.created = 1767225600 + 40 * 86400;  // 10 February 2026, 00:00 UTC
  std::string bytes, error;
  ASSERT_TRUE(las::EncodeHeader(header, &bytes, &error)) << error;
  const Eigen::Vector3d offset = las::OffsetOf(header);
  EXPECT_EQ(offset, Eigen::Vector3d(432000.0, 3585000.0, -13.0));
  las::AppendRecord(&bytes, a, offset, 17);
  las::AppendRecord(&bytes, b, offset, 65535);
  las::Contents back;
  ASSERT_TRUE(las::Decode(bytes, &back, &error)) << error;
  ASSERT_EQ(back.points.size(), 2u);
  EXPECT_LE((back.points[0] - a).cwiseAbs().maxCoeff(), 0.0005);
  EXPECT_LE((back.points[1] - b).cwiseAbs().maxCoeff(), 0.0005);
  EXPECT_EQ(back.intensities[0], 17);
  EXPECT_EQ(back.intensities[1], 65535);
  EXPECT_EQ(back.epsg, 32650);
  EXPECT_EQ(back.system_identifier, "RailLoMer UTM zone 50N");
  EXPECT_EQ(back.creation_year, 2026);
  EXPECT_EQ(back.creation_day, 41);
  for (const Eigen::Vector3d& p : back.points) {
    EXPECT_TRUE((p.array() >= back.min.array()).all()) << p.transpose();
    EXPECT_TRUE((p.array() <= back.max.array()).all()) << p.transpose();
  }
  EXPECT_NEAR(back.max.x(), 432950.001, 1e-9);
  EXPECT_NEAR(back.max.z(), 30.201, 1e-9);
  EXPECT_NEAR(back.min.z(), -12.250, 1e-9);
  // The fixed layout: signature, version 1.2, the points right after the key record.
  EXPECT_EQ(bytes.substr(0, 4), "LASF");
  EXPECT_EQ(bytes[24], 1);
  EXPECT_EQ(bytes[25], 2);
  uint32_t point_offset = 0;
  std::memcpy(&point_offset, bytes.data() + 96, sizeof(point_offset));
  EXPECT_EQ(point_offset, 227u + 54u + 48u);
  EXPECT_EQ(bytes.size(), point_offset + 2 * las::kRecordBytes);
}

TEST(Las, ALocalFrameIsAUserDefinedSystem) {
  las::Header header;
  std::string bytes, error;
  ASSERT_TRUE(las::EncodeHeader(header, &bytes, &error)) << error;
  EXPECT_EQ(bytes.size(), 227u + 54u + 48u);  // the key record is there: LAS 1.2 requires it
  las::Contents back;
  ASSERT_TRUE(las::Decode(bytes, &back, &error)) << error;
  EXPECT_TRUE(back.points.empty());
  EXPECT_EQ(back.epsg, 32767);
  EXPECT_EQ(back.system_identifier, "RailLoMer local odometry frame");
  EXPECT_EQ(back.creation_year, 0);  // not set
}

TEST(Las, WhatLas12CannotHoldIsRefusedByName) {
  las::Header header;
  header.points = uint64_t{1} << 32;
  std::string bytes, error;
  EXPECT_FALSE(las::EncodeHeader(header, &bytes, &error));
  EXPECT_NE(error.find("at most 4294967295 points"), std::string::npos) << error;
  header.points = 2;
  header.bounds = Eigen::AlignedBox3d(Eigen::Vector3d::Zero(), Eigen::Vector3d(3.0e6, 0.0, 0.0));
  EXPECT_FALSE(las::EncodeHeader(header, &bytes, &error));
  EXPECT_NE(error.find("3000000 m"), std::string::npos) << error;
  header.bounds.max() = Eigen::Vector3d(std::nan(""), 0.0, 0.0);
  EXPECT_FALSE(las::EncodeHeader(header, &bytes, &error));
  EXPECT_NE(error.find("not finite"), std::string::npos) << error;
  header.bounds.max() =
      Eigen::Vector3d(1.0, std::nan(""), 0.0);  // not only in the first coordinate
  EXPECT_FALSE(las::EncodeHeader(header, &bytes, &error));
  EXPECT_NE(error.find("not finite"), std::string::npos) << error;
}

TEST(Las, ACutFileIsNamed) {
  las::Header header;
  header.points = 3;
  header.utm_zone = "33S";
  std::string bytes, error;
  ASSERT_TRUE(las::EncodeHeader(header, &bytes, &error)) << error;
  for (int i = 0; i < 2; ++i) las::AppendRecord(&bytes, Eigen::Vector3d::Zero(), {0, 0, 0}, 0);
  las::Contents back;
  EXPECT_FALSE(las::Decode(bytes, &back, &error));
  EXPECT_NE(error.find("truncated"), std::string::npos) << error;
  EXPECT_FALSE(las::Decode("PLY", &back, &error));
  EXPECT_NE(error.find("not a LAS file"), std::string::npos) << error;
}

}  // namespace
}  // namespace raillomer::api
