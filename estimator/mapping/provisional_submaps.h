#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

#include <Eigen/Geometry>

#include "api/stream.h"

namespace raillomer {

/// Provisional submaps: the keyframes the GNSS fusion still holds back (a run's start before
/// its graph settles, an outage), placed where the fusion puts them for now, so that the
/// server can compare the stretch ahead of the final map (raillomer-server's provisional
/// output). No chain, no registration: the server registers every stretch onto its reference
/// anyway, and the final submaps replace these.
class ProvisionalSubmaps {
 public:
  /// `keyframes` a submap; one point a voxel of `voxel_m`; points within `max_range_m` of
  /// their keyframe (0: all).
  ProvisionalSubmaps(int keyframes, double voxel_m, double max_range_m);

  /// Adds a keyframe's points at its provisional pose (UTM, `zone`) of `placement`
  /// (api::Submap::placement); returns the submaps completed: one once `keyframes` have
  /// gathered, and the one gathered so far first when this keyframe is of another zone or
  /// placement or more than max_gap_s after it.
  std::vector<api::Submap> Add(int64_t stamp_ns,
                               const Eigen::Isometry3d& T_utm_body,
                               const std::string& zone,
                               uint32_t placement,
                               const std::vector<Eigen::Vector3f>& points_body,
                               const std::vector<float>& intensities);
  /// The submap gathered so far, if it holds any keyframe.
  std::optional<api::Submap> Flush();
  /// Submaps made so far.
  uint64_t made() const { return next_sequence_; }
  static constexpr double kMaxGapS = 2.0;

 private:
  int keyframes_;
  double voxel_m_, max_range_m_;
  api::Submap open_;
  std::unordered_set<uint64_t> voxels_;
  uint64_t next_sequence_ = 0;
};

}  // namespace raillomer
