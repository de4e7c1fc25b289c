#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "api/stream.h"

namespace raillomer {

/// Groups consecutive keyframes into submaps (paper IV.E: 10 keyframes each). A keyframe's
/// deskewed cloud is carried from the body frame into the world with its final pose; the submap
/// keeps float offsets from a double-precision origin, its first keyframe's position rounded to
/// whole metres, so UTM coordinates are never stored in a float.
class SubmapBuilder {
 public:
  /// A completed submap keeps one point (the centroid) per voxel of voxel_m (0: all points):
  /// its keyframes overlap, and the union would repeat each surface ten times.
  explicit SubmapBuilder(int keyframes_per_submap = 10, double voxel_m = 0.1);

  /// Adds a keyframe: T_world_body absolute (UTM when georeferenced, else the local frame).
  /// Returns the submaps it completes (without their sequence numbers): none or one, or two
  /// when its frame differs from the open submap's (local versus UTM), which closes that first.
  std::vector<api::Submap> Add(int64_t stamp_ns,
                               const Eigen::Isometry3d& T_world_body,
                               bool georeferenced,
                               const std::string& utm_zone,
                               const std::vector<Eigen::Vector3f>& points_body,
                               const std::vector<float>& intensities);
  /// The open submap, if it has any keyframe (end of the run).
  std::optional<api::Submap> Flush();

 private:
  api::Submap Close();
  int keyframes_per_submap_;
  double voxel_m_;
  uint32_t next_index_ = 0;
  std::optional<api::Submap> open_;
};

}  // namespace raillomer
