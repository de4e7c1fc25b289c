#pragma once

#include <chrono>
#include <cstdint>

namespace raillomer::api {

/// Wall-clock time in nanoseconds since the Unix epoch: the stamps the store and the API keep.
inline int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace raillomer::api
