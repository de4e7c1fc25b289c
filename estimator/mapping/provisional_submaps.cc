#include "estimator/mapping/provisional_submaps.h"

#include <algorithm>
#include <cmath>

namespace raillomer {

ProvisionalSubmaps::ProvisionalSubmaps(int keyframes, double voxel_m, double max_range_m)
    : keyframes_(std::max(1, keyframes)), voxel_m_(voxel_m), max_range_m_(max_range_m) {}

std::vector<api::Submap> ProvisionalSubmaps::Add(int64_t stamp_ns,
                                                 const Eigen::Isometry3d& T_utm_body,
                                                 const std::string& zone,
                                                 uint32_t placement,
                                                 const std::vector<Eigen::Vector3f>& points_body,
                                                 const std::vector<float>& intensities) {
  std::vector<api::Submap> done;
  // One zone, one placement and one stretch of time a submap.
  if (!open_.keyframes.empty() && (open_.utm_zone != zone || open_.placement != placement ||
                                   (stamp_ns - open_.last_stamp_ns) * 1e-9 > kMaxGapS))
    done.push_back(*Flush());
  if (open_.keyframes.empty()) {
    open_.georeferenced = true;
    open_.utm_zone = zone;
    open_.placement = placement;
    open_.origin = T_utm_body.translation();
    open_.first_stamp_ns = stamp_ns;
  }
  open_.last_stamp_ns = stamp_ns;
  open_.keyframes.push_back(
      {stamp_ns, T_utm_body.translation(), Eigen::Quaterniond(T_utm_body.linear()).normalized()});
  // The keyframe's frame relative to the origin, in doubles: UTM never goes into a float.
  Eigen::Isometry3d T_local_body = T_utm_body;
  T_local_body.translation() -= open_.origin;
  const double range_sq = max_range_m_ * max_range_m_;
  for (size_t i = 0; i < points_body.size(); ++i) {
    const Eigen::Vector3d p_body = points_body[i].cast<double>();
    if (max_range_m_ > 0.0 && p_body.squaredNorm() > range_sq) continue;
    const Eigen::Vector3d p = T_local_body * p_body;
    if (voxel_m_ > 0.0) {
      // 21 bits an axis around the origin: +-104 km at 0.1 m, far beyond a submap.
      uint64_t key = 0;
      for (int a = 0; a < 3; ++a)
        key =
            (key << 21) | (static_cast<uint64_t>(static_cast<int64_t>(std::floor(p[a] / voxel_m_)) +
                                                 (int64_t{1} << 20)) &
                           ((uint64_t{1} << 21) - 1));
      if (!voxels_.insert(key).second) continue;
    }
    open_.points.push_back(p.cast<float>());
    open_.intensities.push_back(i < intensities.size() ? intensities[i] : 0.0f);
  }
  if (static_cast<int>(open_.keyframes.size()) >= keyframes_) done.push_back(*Flush());
  return done;
}

std::optional<api::Submap> ProvisionalSubmaps::Flush() {
  if (open_.keyframes.empty()) return std::nullopt;
  api::Submap done = std::move(open_);
  done.sequence = next_sequence_;
  done.index = static_cast<uint32_t>(next_sequence_);
  ++next_sequence_;
  open_ = api::Submap();
  voxels_.clear();
  return done;
}

}  // namespace raillomer
