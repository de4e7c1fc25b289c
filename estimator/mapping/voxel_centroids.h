#pragma once

#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

namespace raillomer {

/// A voxel's key: 21 bits per axis, wrapping. Two voxels share a key only 2^21 voxels apart
/// (200 km at 0.1 m), never both in one submap or among a few recent ones.
inline uint64_t VoxelKey(const Eigen::Vector3d& p, double voxel_m) {
  constexpr uint64_t kMask = (1ull << 21) - 1;
  const auto axis = [&](double v) {
    return static_cast<uint64_t>(static_cast<int64_t>(std::floor(v / voxel_m))) & kMask;
  };
  return (axis(p.x()) << 42) | (axis(p.y()) << 21) | axis(p.z());
}

/// Thins points to one per voxel: the centroid of the voxel's points and their mean
/// intensity, in the order the voxels were first seen.
class VoxelCentroids {
 public:
  explicit VoxelCentroids(double voxel_m) : voxel_m_(voxel_m) {}
  void Add(const Eigen::Vector3d& p, float intensity) {
    const uint64_t key = VoxelKey(p, voxel_m_);
    Cell& c = cells_[key];
    if (c.n == 0) order_.push_back(key);
    c.sum += p;
    c.intensity += intensity;
    ++c.n;
  }
  /// fn(key, centroid, mean intensity) for every voxel.
  template <typename Fn>
  void ForEach(Fn&& fn) const {
    for (uint64_t key : order_) {
      const Cell& c = cells_.at(key);
      fn(key, Eigen::Vector3d(c.sum / c.n), static_cast<float>(c.intensity / c.n));
    }
  }

 private:
  struct Cell {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double intensity = 0.0;
    int n = 0;
  };
  double voxel_m_;
  std::unordered_map<uint64_t, Cell> cells_;
  std::vector<uint64_t> order_;
};

}  // namespace raillomer
