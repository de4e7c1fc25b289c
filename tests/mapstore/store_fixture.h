#pragma once

// A map store in a scratch folder for the tests of what works on stored runs.

#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "mapstore/map_store.h"
#include "tests/support/process.h"

namespace raillomer::mapstore {

/// A store that writes its tiles only when asked (Flush, FinishRun), fresh for each test.
class StoreTest : public ::testing::Test {
 protected:
  void SetUp() override {
    StoreOptions options;
    options.flush_interval_ms = 0;
    std::string error;
    store_ = MapStore::Open(dir_.path().string(), options, &error);
    ASSERT_TRUE(store_) << error;
  }

  test::ScratchDir dir_{"raillomer_store_test_"};
  std::unique_ptr<MapStore> store_;
};

}  // namespace raillomer::mapstore
