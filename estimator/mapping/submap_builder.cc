#include "estimator/mapping/submap_builder.h"

#include "estimator/mapping/voxel_centroids.h"

#include <algorithm>
#include <cmath>

namespace raillomer {

SubmapBuilder::SubmapBuilder(int keyframes_per_submap, double voxel_m)
    : keyframes_per_submap_(std::max(1, keyframes_per_submap)), voxel_m_(voxel_m) {}

api::Submap SubmapBuilder::Close() {
  api::Submap s = std::move(*open_);
  open_.reset();
  if (voxel_m_ <= 0.0 || s.points.empty()) return s;
  VoxelCentroids grid(voxel_m_);
  for (size_t i = 0; i < s.points.size(); ++i)
    grid.Add(s.points[i].cast<double>(), s.intensities[i]);
  s.points.clear();
  s.intensities.clear();
  grid.ForEach([&](uint64_t, const Eigen::Vector3d& p, float intensity) {
    s.points.push_back(p.cast<float>());
    s.intensities.push_back(intensity);
  });
  return s;
}

std::vector<api::Submap> SubmapBuilder::Add(int64_t stamp_ns,
                                            const Eigen::Isometry3d& T_world_body,
                                            bool georeferenced,
                                            const std::string& utm_zone,
                                            const std::vector<Eigen::Vector3f>& points_body,
                                            const std::vector<float>& intensities) {
  std::vector<api::Submap> done;
  if (open_ && (open_->georeferenced != georeferenced || open_->utm_zone != utm_zone))
    done.push_back(Close());
  if (!open_) {
    open_.emplace();
    open_->index = next_index_++;
    open_->first_stamp_ns = stamp_ns;
    open_->georeferenced = georeferenced;
    open_->utm_zone = utm_zone;
    open_->origin = T_world_body.translation().array().round().matrix();
  }
  api::Submap& s = *open_;
  s.last_stamp_ns = stamp_ns;
  api::StampedPose pose;
  pose.stamp_ns = stamp_ns;
  pose.p_world = T_world_body.translation();
  pose.q_world_body = Eigen::Quaterniond(T_world_body.linear()).normalized();
  s.keyframes.push_back(pose);
  // Offsets from the origin in double, then to float: a few hundred metres at most.
  const Eigen::Matrix3d R = T_world_body.linear();
  const Eigen::Vector3d t = T_world_body.translation() - s.origin;
  s.points.reserve(s.points.size() + points_body.size());
  for (size_t i = 0; i < points_body.size(); ++i) {
    s.points.push_back((R * points_body[i].cast<double>() + t).cast<float>());
    s.intensities.push_back(i < intensities.size() ? intensities[i] : 0.f);
  }
  if (static_cast<int>(s.keyframes.size()) >= keyframes_per_submap_) done.push_back(Close());
  return done;
}

std::optional<api::Submap> SubmapBuilder::Flush() {
  if (!open_) return std::nullopt;
  return Close();
}

}  // namespace raillomer
