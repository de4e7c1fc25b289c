#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>

#include <Eigen/Core>

namespace raillomer::mapstore {

/// A cell of a cubic grid in a local frame (doubles of a few hundred metres at most): the
/// key of the voxel hashes of registration and change detection.
struct GridCell {
  int64_t x = 0, y = 0, z = 0;
  bool operator==(const GridCell& o) const { return x == o.x && y == o.y && z == o.z; }
  GridCell operator+(const GridCell& o) const { return {x + o.x, y + o.y, z + o.z}; }
};

struct GridCellHash {
  size_t operator()(const GridCell& c) const {
    return static_cast<size_t>(c.x * 73856093) ^ static_cast<size_t>(c.y * 19349663) ^
           static_cast<size_t>(c.z * 83492791);
  }
};

inline GridCell CellOf(const Eigen::Vector3d& p, double side) {
  return {static_cast<int64_t>(std::floor(p.x() / side)),
          static_cast<int64_t>(std::floor(p.y() / side)),
          static_cast<int64_t>(std::floor(p.z() / side))};
}

/// The centre of a cell.
inline Eigen::Vector3d CentreOf(const GridCell& c, double side) {
  return Eigen::Vector3d(c.x + 0.5, c.y + 0.5, c.z + 0.5) * side;
}

}  // namespace raillomer::mapstore
