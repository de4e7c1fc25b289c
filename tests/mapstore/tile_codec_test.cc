// The Draco tile codec on generated points: positions come back within the grid's stated error,
// intensities exactly; a decoded tile encoded again is bit-for-bit the same points (the fixed
// grid); bytes that are not a tile are refused with a message; Debian's draco_decoder (not our
// code) decodes a tile to the same points.
#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <random>

#include <gtest/gtest.h>

#include "mapstore/tile_codec.h"
#include "mapstore/tile_grid.h"
#include "tests/support/process.h"

namespace raillomer::mapstore {
namespace {

/// A grid of 64 m tiles (a 128 m quantisation cube), whatever the default.
TileGrid Grid64() {
  TileGrid grid;
  grid.tile_m = 64.0;
  return grid;
}

TilePoints RandomTile(size_t n, const TileQuantization& q, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  TilePoints t;
  t.origin = Eigen::Vector3d(432128.0, 3585216.0, 31.0);
  t.utm_zone = "50N";
  for (size_t i = 0; i < n; ++i) {
    // Inside the tile's square, heights from 2 m below to 30 m above the reference.
    t.points.emplace_back(64.0f * u(rng), 64.0f * u(rng), -2.0f + 32.0f * u(rng));
    t.intensities.push_back(static_cast<uint8_t>(rng() % 256));
  }
  EXPECT_TRUE(std::all_of(
      t.points.begin(), t.points.end(), [&](const Eigen::Vector3f& p) { return q.Covers(p); }));
  return t;
}

/// Points sorted with their intensities, to compare clouds the coder reordered.
std::vector<std::array<float, 4>> Sorted(const TilePoints& t) {
  std::vector<std::array<float, 4>> v;
  for (size_t i = 0; i < t.points.size(); ++i)
    v.push_back({t.points[i].x(), t.points[i].y(), t.points[i].z(), float(t.intensities[i])});
  std::sort(v.begin(), v.end());
  return v;
}

/// The largest distance from each point of `a` to the nearest of `b` that has the same
/// intensity (brute force over a small cloud), or infinity if one has none.
double WorstMatch(const TilePoints& a, const TilePoints& b) {
  double worst = 0.0;
  for (size_t i = 0; i < a.points.size(); ++i) {
    double best = INFINITY;
    for (size_t j = 0; j < b.points.size(); ++j) {
      if (a.intensities[i] != b.intensities[j]) continue;
      best = std::min(best, double((a.points[i] - b.points[j]).cwiseAbs().maxCoeff()));
    }
    worst = std::max(worst, best);
  }
  return worst;
}

TEST(TileQuantization, BitsKeepTheErrorWithinWhatIsAsked) {
  EXPECT_EQ(TileQuantization::BitsFor(128.0, 0.005), 14);  // 3.9 mm
  const TileGrid grid = Grid64();
  const TileQuantization q = grid.Quantization(0);
  EXPECT_LE(q.MaxErrorM(), 0.005);
  EXPECT_GT(q.MaxErrorM(), 0.0025);  // not a bit more than needed
  EXPECT_FLOAT_EQ(grid.Quantization(2).range_m, 4.0f * q.range_m);
  EXPECT_TRUE(q.Covers(Eigen::Vector3f(0.0f, 63.9f, -31.0f)));
  EXPECT_FALSE(q.Covers(Eigen::Vector3f(0.0f, 0.0f, -33.0f)));
  EXPECT_FALSE(q.Covers(Eigen::Vector3f(NAN, 0.0f, 0.0f)));
}

TEST(TileCodec, RoundTripWithinTheStatedErrorAndLosslessOnItsGrid) {
  const TileQuantization q = Grid64().Quantization(0);
  const TilePoints tile = RandomTile(2000, q, 1);
  std::string bytes, error;
  ASSERT_TRUE(EncodeTile(tile, q, 5, &bytes, &error)) << error;
  TilePoints back;
  TileQuantization grid;
  ASSERT_TRUE(DecodeTile(bytes, &back, &error, &grid)) << error;
  EXPECT_EQ(back.utm_zone, "50N");
  EXPECT_EQ(back.origin, tile.origin);
  EXPECT_EQ(grid.bits, q.bits);
  EXPECT_EQ(grid.range_m, q.range_m);
  ASSERT_EQ(back.points.size(), tile.points.size());
  EXPECT_LE(WorstMatch(tile, back), q.MaxErrorM() * 1.0001);
  EXPECT_LT(8.0 * bytes.size() / tile.points.size(), 64.0);  // random points compress least

  std::string again;
  ASSERT_TRUE(EncodeTile(back, grid, 5, &again, &error)) << error;
  TilePoints twice;
  ASSERT_TRUE(DecodeTile(again, &twice, &error)) << error;
  EXPECT_EQ(Sorted(twice), Sorted(back));
}

TEST(TileCodec, RefusesWhatIsNotATile) {
  std::string bytes, error;
  TilePoints empty;
  const TileQuantization q = Grid64().Quantization(0);
  EXPECT_FALSE(EncodeTile(empty, q, 5, &bytes, &error));
  TilePoints off = RandomTile(10, q, 2);
  off.points[3].z() = 500.0f;
  EXPECT_FALSE(EncodeTile(off, q, 5, &bytes, &error));
  EXPECT_NE(error.find("point 3"), std::string::npos) << error;
  TilePoints tile;
  EXPECT_FALSE(DecodeTile("not draco at all", &tile, &error));
  EXPECT_FALSE(error.empty());
  ASSERT_TRUE(EncodeTile(RandomTile(100, q, 3), q, 5, &bytes, &error)) << error;
  EXPECT_FALSE(DecodeTile(bytes.substr(0, bytes.size() / 2), &tile, &error));
}

TEST(TileCodec, DebiansDracoDecoderReadsOurTiles) {
  test::ScratchDir dir("raillomer_tile_");
  ASSERT_FALSE(dir.path().empty());
  const TileQuantization q = Grid64().Quantization(0);
  const TilePoints tile = RandomTile(300, q, 4);
  std::string bytes, error;
  ASSERT_TRUE(EncodeTile(tile, q, 5, &bytes, &error)) << error;
  std::ofstream(dir.path() / "tile.drc", std::ios::binary) << bytes;
  const test::CommandResult r =
      test::RunCommand("draco_decoder -i " + (dir.path() / "tile.drc").string() + " -o " +
                           (dir.path() / "tile.ply").string(),
                       dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.out << r.err;
  // The PLY's vertices (x y z as float, then the generic attribute) are the tile's points.
  std::ifstream in(dir.path() / "tile.ply", std::ios::binary);
  std::string line;
  size_t vertices = 0;
  int floats = 0;
  while (std::getline(in, line) && line != "end_header") {
    if (line.rfind("element vertex ", 0) == 0) vertices = std::stoul(line.substr(15));
    if (line.rfind("property float", 0) == 0) ++floats;
  }
  ASSERT_EQ(vertices, tile.points.size());
  ASSERT_EQ(floats, 3);
  TilePoints decoded;
  for (size_t i = 0; i < vertices; ++i) {
    float p[3];
    in.read(reinterpret_cast<char*>(p), sizeof(p));
    decoded.points.emplace_back(p[0], p[1], p[2]);
  }
  ASSERT_TRUE(in.good());
  // Positions only (draco_decoder writes PLY positions): each within the stated error.
  for (const Eigen::Vector3f& p : tile.points) {
    float best = INFINITY;
    for (const Eigen::Vector3f& d : decoded.points)
      best = std::min(best, (p - d).cwiseAbs().maxCoeff());
    EXPECT_LE(best, q.MaxErrorM() * 1.0001);
  }
}

}  // namespace
}  // namespace raillomer::mapstore
