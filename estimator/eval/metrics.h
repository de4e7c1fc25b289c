#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/eval/alignment.h"
#include "estimator/eval/association.h"

namespace raillomer::eval {

/// Absolute trajectory error: translational error |T_truth_est * p_est - p_truth| per pose.
struct AteStats {
  size_t num_poses = 0;
  double rmse_m = 0.0;
  double mean_m = 0.0;
  double median_m = 0.0;
  double max_m = 0.0;
  /// Index into the pairs, stamp and along-track distance of the largest error.
  size_t max_index = 0;
  int64_t max_stamp_ns = 0;
  double max_distance_m = 0.0;
  /// The error of every pair, in pair order (m).
  std::vector<double> errors_m;
};

/// Computes the ATE of the pairs after mapping the estimate with T_truth_est.
AteStats ComputeAte(const std::vector<PosePair>& pairs, const Eigen::Isometry3d& T_truth_est);

/// Options for the relative (KITTI-style) error over fixed lengths of track.
struct RpeOptions {
  /// Truth path length each segment spans (m).
  double segment_length_m = 100.0;
  /// Along-track spacing of segment start poses (m); keeps long runs fast and stops a standing
  /// train from weighting one place many times.
  double start_step_m = 1.0;
  /// The estimate has positions only (every orientation the identity, as in a receiver's
  /// fixes): the segments' displacements are compared in the world frame, the estimate's
  /// turned by this rotation (the alignment's), and no rotation error is reported.
  bool position_only = false;
  Eigen::Matrix3d R_truth_est = Eigen::Matrix3d::Identity();

  /// True when the options are usable; otherwise false with a message.
  bool IsValid(std::string* error) const;
};

/// Relative error over segments of segment_length_m of truth path. The per-segment percentage
/// divides by the segment's actual truth path length (at least segment_length_m).
struct RpeStats {
  /// False when the matched span is shorter than one segment; the figures are then meaningless.
  bool valid = false;
  double segment_length_m = 0.0;
  size_t num_segments = 0;
  double trans_mean_m = 0.0;
  double trans_rmse_m = 0.0;
  double trans_mean_pct = 0.0;
  double trans_rmse_pct = 0.0;
  /// Rotation error angle per segment (deg); not measured for a position-only estimate.
  bool has_rotation = true;
  double rot_mean_deg = 0.0;
  double rot_rmse_deg = 0.0;
};

/// For start poses every start_step_m of path, takes the first pose j at least segment_length_m
/// further along and compares (T_est_i^-1 T_est_j) with (T_truth_i^-1 T_truth_j); O(n).
RpeStats ComputeRpe(const std::vector<PosePair>& pairs, const RpeOptions& options);

/// Error at the last pose after aligning the estimate by its first matched pose only.
struct DriftStats {
  /// False if there are fewer than two pairs.
  bool valid = false;
  /// |p_est_end' - p_truth_end| (m).
  double end_error_m = 0.0;
  /// end_error_m / distance_m * 100; false in has_drift_pct when the truth did not move.
  double end_drift_pct = 0.0;
  bool has_drift_pct = false;
  /// Truth path length over the matched span (m).
  double distance_m = 0.0;
  /// The first-pose alignment that was applied.
  Eigen::Isometry3d T_truth_est = Eigen::Isometry3d::Identity();
};

/// End-point drift with the estimate aligned by its first pair in the given degrees of freedom.
/// `position_only`: the estimate has no orientation, so the first pose aligns by its
/// position alone.
DriftStats ComputeEndDrift(const std::vector<PosePair>& pairs,
                           AlignmentMode mode,
                           bool position_only = false);

/// True when every estimate orientation is exactly the identity: a trajectory of positions
/// only (a receiver's fixes), whose relative poses mean nothing.
bool EstimateIsPositionOnly(const std::vector<PosePair>& pairs);

}  // namespace raillomer::eval
