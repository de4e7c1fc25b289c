#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "api/trajectory.h"

namespace raillomer::eval {

/// Options for pairing estimate poses with the truth interpolated at their stamps.
struct AssociationOptions {
  /// Largest gap between the two bracketing truth poses that may be interpolated across (s).
  double max_gap_s = 0.5;

  /// True when the options are usable; otherwise false with a message.
  bool IsValid(std::string* error) const;
};

/// One estimate pose with the truth interpolated at its stamp.
struct PosePair {
  int64_t stamp_ns = 0;
  Eigen::Isometry3d T_world_est = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d T_world_truth = Eigen::Isometry3d::Identity();
  /// Truth path length from the first matched stamp to this one (m); reverse running counts too.
  double distance_m = 0.0;
};

/// The matched pairs of AssociatePoses plus what was skipped and why.
struct Association {
  /// False if the inputs are unusable (unordered stamps, bad options); see error.
  bool ok = false;
  std::string error;
  std::vector<PosePair> pairs;
  size_t num_estimate_poses = 0;
  size_t num_truth_poses = 0;
  /// Estimate poses before the first or after the last truth stamp.
  size_t num_skipped_outside = 0;
  /// Estimate poses whose bracketing truth poses are more than max_gap_s apart.
  size_t num_skipped_gap = 0;

  /// All skipped estimate poses.
  size_t num_skipped() const { return num_skipped_outside + num_skipped_gap; }
};

/// Interpolates between two poses at stamp_ns: linear in position, slerp in rotation.
api::StampedPose InterpolatePose(const api::StampedPose& a,
                                 const api::StampedPose& b,
                                 int64_t stamp_ns);

/// Pairs every estimate pose with the truth interpolated at its stamp from the two bracketing
/// truth poses; skips poses outside the truth's span or across a truth gap above max_gap_s.
/// Both trajectories must have strictly increasing stamps.
Association AssociatePoses(const api::Trajectory& estimate,
                           const api::Trajectory& truth,
                           const AssociationOptions& options);

/// Converts a stamped pose to T_world_body.
Eigen::Isometry3d ToIsometry(const api::StampedPose& pose);

}  // namespace raillomer::eval
