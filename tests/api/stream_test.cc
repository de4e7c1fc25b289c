// The submap codec against inputs the fuzzer (tests/tools/fuzz_submap_decoder.sh) found or
// aims at: each is refused with a message, never a crash or a huge allocation.
#include <gtest/gtest.h>

#include "api/stream.h"

namespace raillomer::api {
namespace {

Submap Small() {
  Submap s;
  s.sequence = 7;
  s.index = 3;
  s.georeferenced = true;
  s.utm_zone = "33S";
  s.origin = Eigen::Vector3d(432100.0, 3585200.0, 30.0);
  for (int i = 0; i < 5; ++i) {
    s.points.emplace_back(0.1f * i, 0.2f, 0.3f);
    s.intensities.push_back(10.0f * i);
  }
  return s;
}

void ExpectRefused(const std::string& bytes, const std::string& words) {
  Submap s;
  std::string error;
  EXPECT_FALSE(DecodeSubmapPcd(bytes, &s, &error));
  EXPECT_NE(error.find(words), std::string::npos) << error;
}

TEST(SubmapPcd, RoundTrips) {
  const Submap s = Small();
  Submap back;
  std::string error;
  ASSERT_TRUE(DecodeSubmapPcd(EncodeSubmapPcd(s), &back, &error)) << error;
  EXPECT_EQ(back.utm_zone, "33S");
  EXPECT_EQ(back.points.size(), 5u);
  EXPECT_EQ(back.intensities[4], 40.0f);
}

TEST(SubmapPcd, RefusesWhatTheFuzzerFound) {
  const std::string good = EncodeSubmapPcd(Small());
  // Found by the fuzzer: a second zone line ("local" after "33S") left a zone on a submap that
  // said it was not georeferenced.
  std::string twice = good;
  twice.insert(twice.find("# raillomer origin"), "# raillomer zone local\n");
  ExpectRefused(twice, "second 'zone' line");
  // A POINTS count whose byte size wraps around, and a short body.
  std::string huge = good;
  huge.replace(huge.find("POINTS 5"), 8, "POINTS 1152921504606846976");
  ExpectRefused(huge, "bytes of points");
  ExpectRefused(good.substr(0, good.size() - 1), "truncated");
  ExpectRefused("", "lacks FIELDS");
}

}  // namespace
}  // namespace raillomer::api
