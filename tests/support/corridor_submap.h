#pragma once

// Generated submaps of a straight corridor in UTM for the map store and server tests.

#include <cstdint>

#include "api/stream.h"

namespace raillomer::test {

/// Where the corridor starts (UTM zone 50N).
inline Eigen::Vector3d CorridorStart() { return {432100.0, 3585200.0, 30.0}; }

/// Submap i of a corridor along easting: ground 8 m wide and a wall 3 m high, 40 m long from
/// 20 i m (so consecutive submaps overlap by half), on the 0.1 m voxel grid's centres as the
/// estimator's voxel filter leaves them; sequence 10 + 2 i.
inline api::Submap CorridorSubmap(uint32_t i) {
  api::Submap s;
  s.sequence = 10 + 2 * i;
  s.index = i;
  s.first_stamp_ns = 1'600'000'000'000'000'000 + int64_t{i} * 2'000'000'000;
  s.last_stamp_ns = s.first_stamp_ns + 1'900'000'000;
  s.georeferenced = true;
  s.utm_zone = "50N";
  s.origin = CorridorStart() + Eigen::Vector3d(20.0 * i, 0.0, 0.0);
  for (int x = 0; x < 400; ++x) {
    for (int y = -40; y < 40; ++y) {
      s.points.emplace_back(0.1f * x + 0.05f, 0.1f * y + 0.05f, 0.05f);
      s.intensities.push_back(static_cast<float>((x + y + 1000) % 200));
    }
    for (int z = 0; z < 30; ++z) {
      s.points.emplace_back(0.1f * x + 0.05f, 4.05f, 0.1f * z + 0.05f);
      s.intensities.push_back(220.0f);
    }
  }
  api::StampedPose k;
  k.stamp_ns = s.first_stamp_ns;
  k.p_world = s.origin;
  s.keyframes.push_back(k);
  return s;
}

}  // namespace raillomer::test
