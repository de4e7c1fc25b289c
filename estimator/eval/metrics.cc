#include "estimator/eval/metrics.h"

#include <algorithm>
#include <cmath>

namespace raillomer::eval {

namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;
// Path lengths are sums of many steps; a segment that is 100 m "exactly" may sum to 99.9999999.
constexpr double kDistanceTolerance_m = 1e-6;

}  // namespace

AteStats ComputeAte(const std::vector<PosePair>& pairs, const Eigen::Isometry3d& T_truth_est) {
  AteStats stats;
  stats.num_poses = pairs.size();
  if (pairs.empty()) return stats;
  stats.errors_m.reserve(pairs.size());
  double sum = 0.0;
  double sum_sq = 0.0;
  for (size_t i = 0; i < pairs.size(); ++i) {
    const Eigen::Vector3d p_est_aligned = T_truth_est * pairs[i].T_world_est.translation();
    const double error = (p_est_aligned - pairs[i].T_world_truth.translation()).norm();
    stats.errors_m.push_back(error);
    sum += error;
    sum_sq += error * error;
    if (i == 0 || error > stats.max_m) {
      stats.max_m = error;
      stats.max_index = i;
    }
  }
  const double n = static_cast<double>(pairs.size());
  stats.mean_m = sum / n;
  stats.rmse_m = std::sqrt(sum_sq / n);
  stats.max_stamp_ns = pairs[stats.max_index].stamp_ns;
  stats.max_distance_m = pairs[stats.max_index].distance_m;
  std::vector<double> sorted = stats.errors_m;
  const size_t mid = sorted.size() / 2;
  std::nth_element(sorted.begin(), sorted.begin() + mid, sorted.end());
  stats.median_m = sorted[mid];
  if (sorted.size() % 2 == 0) {
    const double lower = *std::max_element(sorted.begin(), sorted.begin() + mid);
    stats.median_m = 0.5 * (stats.median_m + lower);
  }
  return stats;
}

bool RpeOptions::IsValid(std::string* error) const {
  if (!(segment_length_m > 0.0) || !std::isfinite(segment_length_m)) {
    if (error)
      *error = "segment_length_m must be positive, got " + std::to_string(segment_length_m);
    return false;
  }
  if (!(start_step_m >= 0.0) || !std::isfinite(start_step_m)) {
    if (error) *error = "start_step_m must be >= 0, got " + std::to_string(start_step_m);
    return false;
  }
  return true;
}

RpeStats ComputeRpe(const std::vector<PosePair>& pairs, const RpeOptions& options) {
  RpeStats stats;
  stats.segment_length_m = options.segment_length_m;
  if (!options.IsValid(nullptr) || pairs.size() < 2) return stats;
  double sum_m = 0.0, sum_sq_m = 0.0;
  double sum_pct = 0.0, sum_sq_pct = 0.0;
  double sum_deg = 0.0, sum_sq_deg = 0.0;
  size_t j = 0;
  double next_start_m = pairs.front().distance_m;
  // Distances never decrease along the pairs, so both i and j only move forward.
  for (size_t i = 0; i < pairs.size(); ++i) {
    if (pairs[i].distance_m < next_start_m - kDistanceTolerance_m) continue;
    next_start_m = pairs[i].distance_m + options.start_step_m;
    const double target_m = pairs[i].distance_m + options.segment_length_m;
    j = std::max(j, i + 1);
    while (j < pairs.size() && pairs[j].distance_m < target_m - kDistanceTolerance_m) ++j;
    if (j >= pairs.size()) break;  // Later starts cannot complete a segment either.
    double trans_m = 0.0, deg = 0.0;
    if (options.position_only) {
      const Eigen::Vector3d d_est = options.R_truth_est * (pairs[j].T_world_est.translation() -
                                                           pairs[i].T_world_est.translation());
      const Eigen::Vector3d d_truth =
          pairs[j].T_world_truth.translation() - pairs[i].T_world_truth.translation();
      trans_m = (d_est - d_truth).norm();
    } else {
      const Eigen::Isometry3d delta_est = pairs[i].T_world_est.inverse() * pairs[j].T_world_est;
      const Eigen::Isometry3d delta_truth =
          pairs[i].T_world_truth.inverse() * pairs[j].T_world_truth;
      trans_m = (delta_est.translation() - delta_truth.translation()).norm();
      deg = RotationAngle(delta_est.linear().transpose() * delta_truth.linear()) * kRadToDeg;
    }
    const double length_m = pairs[j].distance_m - pairs[i].distance_m;
    const double pct = trans_m / length_m * 100.0;
    sum_m += trans_m;
    sum_sq_m += trans_m * trans_m;
    sum_pct += pct;
    sum_sq_pct += pct * pct;
    sum_deg += deg;
    sum_sq_deg += deg * deg;
    ++stats.num_segments;
  }
  if (stats.num_segments == 0) return stats;
  const double n = static_cast<double>(stats.num_segments);
  stats.valid = true;
  stats.has_rotation = !options.position_only;
  stats.trans_mean_m = sum_m / n;
  stats.trans_rmse_m = std::sqrt(sum_sq_m / n);
  stats.trans_mean_pct = sum_pct / n;
  stats.trans_rmse_pct = std::sqrt(sum_sq_pct / n);
  stats.rot_mean_deg = sum_deg / n;
  stats.rot_rmse_deg = std::sqrt(sum_sq_deg / n);
  return stats;
}

DriftStats ComputeEndDrift(const std::vector<PosePair>& pairs,
                           AlignmentMode mode,
                           bool position_only) {
  DriftStats stats;
  if (pairs.size() < 2) return stats;
  stats.valid = true;
  stats.T_truth_est = AlignByPose(pairs.front().T_world_est, pairs.front().T_world_truth, mode);
  if (position_only) {
    stats.T_truth_est = Eigen::Isometry3d::Identity();
    if (mode != AlignmentMode::kNone) {
      stats.T_truth_est.translation() =
          pairs.front().T_world_truth.translation() - pairs.front().T_world_est.translation();
    }
  }
  const Eigen::Vector3d p_end = stats.T_truth_est * pairs.back().T_world_est.translation();
  stats.end_error_m = (p_end - pairs.back().T_world_truth.translation()).norm();
  stats.distance_m = pairs.back().distance_m - pairs.front().distance_m;
  stats.has_drift_pct = stats.distance_m > 0.0;
  if (stats.has_drift_pct) stats.end_drift_pct = stats.end_error_m / stats.distance_m * 100.0;
  return stats;
}

bool EstimateIsPositionOnly(const std::vector<PosePair>& pairs) {
  return !pairs.empty() && std::all_of(pairs.begin(), pairs.end(), [](const PosePair& pair) {
    return pair.T_world_est.linear() == Eigen::Matrix3d::Identity();
  });
}

}  // namespace raillomer::eval
