#pragma once

#include <cstdint>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

namespace raillomer {

/// A voxel-hashed map of feature points in the world frame with k-nearest-neighbour search
/// (the local map of scan-to-map registration). Each voxel holds a few well-spread points, and
/// voxels far from the vehicle are dropped, so memory stays bounded on any run length.
class LocalMap {
 public:
  LocalMap(double voxel_m, int max_points_per_voxel);

  /// Inserts points; a point closer than a quarter voxel to one already held is skipped.
  void Add(const std::vector<Eigen::Vector3d>& points_world);
  /// Moves every point by R (about the origin), e.g. when the world frame is re-levelled.
  void Rotate(const Eigen::Matrix3d& R);
  /// Drops the voxels farther than radius_m from center.
  void RemoveFar(const Eigen::Vector3d& center, double radius_m);
  /// Up to k nearest points within max_distance_m, nearest first; returns how many.
  int KNearest(const Eigen::Vector3d& query,
               int k,
               double max_distance_m,
               Eigen::Vector3d* out) const;

  size_t num_points() const { return num_points_; }
  size_t num_voxels() const { return voxels_.size(); }
  bool empty() const { return num_points_ == 0; }

 private:
  using Key = uint64_t;
  Key KeyOf(const Eigen::Vector3i& v) const;
  Eigen::Vector3i VoxelOf(const Eigen::Vector3d& p) const;

  double voxel_m_;
  double min_spacing_sq_;
  size_t max_points_;
  size_t num_points_ = 0;
  std::unordered_map<Key, std::vector<Eigen::Vector3d>> voxels_;
};

}  // namespace raillomer
