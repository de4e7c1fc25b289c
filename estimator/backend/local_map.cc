#include "estimator/backend/local_map.h"

#include <algorithm>
#include <cmath>

namespace raillomer {

LocalMap::LocalMap(double voxel_m, int max_points_per_voxel)
    : voxel_m_(voxel_m),
      min_spacing_sq_(0.0625 * voxel_m * voxel_m),
      max_points_(static_cast<size_t>(max_points_per_voxel)) {}

Eigen::Vector3i LocalMap::VoxelOf(const Eigen::Vector3d& p) const {
  return Eigen::Vector3i(static_cast<int>(std::floor(p.x() / voxel_m_)),
                         static_cast<int>(std::floor(p.y() / voxel_m_)),
                         static_cast<int>(std::floor(p.z() / voxel_m_)));
}

LocalMap::Key LocalMap::KeyOf(const Eigen::Vector3i& v) const {
  // 21 bits per axis: +-1e6 voxels, far more than any line's extent at sub-metre voxels.
  const uint64_t mask = (1ULL << 21) - 1;
  return ((static_cast<uint64_t>(v.x()) & mask) << 42) |
         ((static_cast<uint64_t>(v.y()) & mask) << 21) | (static_cast<uint64_t>(v.z()) & mask);
}

void LocalMap::Add(const std::vector<Eigen::Vector3d>& points_world) {
  for (const Eigen::Vector3d& p : points_world) {
    std::vector<Eigen::Vector3d>& voxel = voxels_[KeyOf(VoxelOf(p))];
    if (voxel.size() >= max_points_) continue;
    const bool crowded = std::any_of(voxel.begin(), voxel.end(), [&](const Eigen::Vector3d& q) {
      return (q - p).squaredNorm() < min_spacing_sq_;
    });
    if (crowded) continue;
    if (voxel.empty()) voxel.reserve(max_points_);
    voxel.push_back(p);
    ++num_points_;
  }
}

void LocalMap::Rotate(const Eigen::Matrix3d& R) {
  std::vector<Eigen::Vector3d> points;
  points.reserve(num_points_);
  for (const auto& [key, voxel] : voxels_) {
    for (const Eigen::Vector3d& p : voxel) points.push_back(R * p);
  }
  voxels_.clear();
  num_points_ = 0;
  Add(points);
}

void LocalMap::RemoveFar(const Eigen::Vector3d& center, double radius_m) {
  const double limit_sq = radius_m * radius_m;
  for (auto it = voxels_.begin(); it != voxels_.end();) {
    if (!it->second.empty() && (it->second.front() - center).squaredNorm() > limit_sq) {
      num_points_ -= it->second.size();
      it = voxels_.erase(it);
    } else {
      ++it;
    }
  }
}

int LocalMap::KNearest(const Eigen::Vector3d& query,
                       int k,
                       double max_distance_m,
                       Eigen::Vector3d* out) const {
  // A small sorted list of (distance^2, point): k is at most a handful.
  constexpr int kMaxK = 16;
  k = std::min(k, kMaxK);
  double best_d[kMaxK];
  const Eigen::Vector3d* best_p[kMaxK];
  int found = 0;
  double worst = max_distance_m * max_distance_m;
  const Eigen::Vector3i center = VoxelOf(query);
  const int reach = std::max(1, static_cast<int>(std::ceil(max_distance_m / voxel_m_ - 0.5)));
  for (int dx = -reach; dx <= reach; ++dx) {
    for (int dy = -reach; dy <= reach; ++dy) {
      for (int dz = -reach; dz <= reach; ++dz) {
        const auto it = voxels_.find(KeyOf(center + Eigen::Vector3i(dx, dy, dz)));
        if (it == voxels_.end()) continue;
        for (const Eigen::Vector3d& p : it->second) {
          const double d = (p - query).squaredNorm();
          if (d >= worst && found == k) continue;
          if (d > max_distance_m * max_distance_m) continue;
          int i = found < k ? found++ : k - 1;
          while (i > 0 && best_d[i - 1] > d) {
            best_d[i] = best_d[i - 1];
            best_p[i] = best_p[i - 1];
            --i;
          }
          best_d[i] = d;
          best_p[i] = &p;
          if (found == k) worst = best_d[k - 1];
        }
      }
    }
  }
  for (int i = 0; i < found; ++i) out[i] = *best_p[i];
  return found;
}

}  // namespace raillomer
