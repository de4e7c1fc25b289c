// The voxel key set: every inserted key found, once, through the table's growth; others not.
#include "mapstore/voxel_set.h"

#include <cstdint>
#include <random>
#include <set>

#include <gtest/gtest.h>

namespace raillomer::mapstore {
namespace {

TEST(VoxelSet, HoldsWhatWasInsertedOnceAndNothingElseThroughGrowth) {
  VoxelSet set;
  EXPECT_FALSE(set.Contains(0));  // empty: no table yet
  std::mt19937_64 rng(7);
  std::set<uint64_t> inserted;
  for (int i = 0; i < 20000; ++i) {
    // Packed keys as the comparison makes them, zero and the largest included.
    const uint64_t key = i == 0 ? 0 : i == 1 ? ~uint64_t{0} - 1 : rng() >> (rng() % 40);
    EXPECT_EQ(set.Insert(key), inserted.insert(key).second) << key;
  }
  EXPECT_EQ(set.size(), inserted.size());
  for (uint64_t key : inserted) EXPECT_TRUE(set.Contains(key)) << key;
  size_t absent = 0;
  for (int i = 0; i < 20000; ++i) {
    const uint64_t key = rng();
    if (inserted.count(key)) continue;
    ++absent;
    EXPECT_FALSE(set.Contains(key)) << key;
  }
  EXPECT_GT(absent, 19000u);
}

}  // namespace
}  // namespace raillomer::mapstore
