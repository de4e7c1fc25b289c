#pragma once

#include <cstdint>
#include <memory>

#include <Eigen/Core>

#include "estimator/sim/world.h"

namespace raillomer::sim {

/// The first surface along a ray.
struct RayHit {
  bool hit = false;
  double range_m = 0.0;
  Material material = Material::kGround;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< unit, facing the ray origin
};

/// Casts rays into a triangle mesh with Intel Embree. Thread-safe for concurrent Cast() calls.
class RayCaster {
 public:
  explicit RayCaster(const Mesh& mesh);
  ~RayCaster();
  RayCaster(const RayCaster&) = delete;
  RayCaster& operator=(const RayCaster&) = delete;

  /// Nearest hit within max_range_m along the unit direction `dir` from `origin`.
  RayHit Cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double max_range_m) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::vector<Material> materials_;
};

}  // namespace raillomer::sim
