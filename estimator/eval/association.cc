#include "estimator/eval/association.h"

#include <algorithm>
#include <cmath>

namespace raillomer::eval {

namespace {

bool StrictlyIncreasing(const api::Trajectory& trajectory, size_t* bad_index) {
  for (size_t i = 1; i < trajectory.poses.size(); ++i) {
    if (trajectory.poses[i].stamp_ns <= trajectory.poses[i - 1].stamp_ns) {
      *bad_index = i;
      return false;
    }
  }
  return true;
}

/// False with a message naming the first pose whose stamp does not increase, truth first.
bool CheckStamps(const api::Trajectory& estimate,
                 const api::Trajectory& truth,
                 std::string* error) {
  size_t bad = 0;
  if (!StrictlyIncreasing(truth, &bad)) {
    *error = "truth stamps do not increase at pose " + std::to_string(bad);
    return false;
  }
  if (!StrictlyIncreasing(estimate, &bad)) {
    *error = "estimate stamps do not increase at pose " + std::to_string(bad);
    return false;
  }
  return true;
}

/// Along-track distances of the truth poses (m), zero at the first.
std::vector<double> CumulativeDistances(const std::vector<api::StampedPose>& gt) {
  // Cumulative truth path length at every truth pose, so the along-track distance of any stamp
  // is O(1): cumulative[k] + |p(t) - p_k|.
  std::vector<double> cumulative_m(gt.size(), 0.0);
  for (size_t k = 1; k < gt.size(); ++k) {
    cumulative_m[k] = cumulative_m[k - 1] + (gt[k].p_world - gt[k - 1].p_world).norm();
  }
  return cumulative_m;
}

/// Whether the truth is known at a stamp, or why not.
enum class TruthLookup { kFound, kOutside, kAcrossGap };

/// The truth at stamp t: moves the bracket start *k forward to t and interpolates there.
TruthLookup TruthAt(const std::vector<api::StampedPose>& gt,
                    int64_t t,
                    int64_t max_gap_ns,
                    size_t* k,
                    api::StampedPose* truth_pose) {
  if (gt.empty() || t < gt.front().stamp_ns || t > gt.back().stamp_ns) {
    return TruthLookup::kOutside;
  }
  while (*k + 1 < gt.size() && gt[*k + 1].stamp_ns <= t) ++*k;
  if (gt[*k].stamp_ns == t) {
    *truth_pose = gt[*k];
    return TruthLookup::kFound;
  }
  // Here gt[k].stamp_ns < t < gt[k + 1].stamp_ns.
  if (gt[*k + 1].stamp_ns - gt[*k].stamp_ns > max_gap_ns) return TruthLookup::kAcrossGap;
  *truth_pose = InterpolatePose(gt[*k], gt[*k + 1], t);
  return TruthLookup::kFound;
}

}  // namespace

bool AssociationOptions::IsValid(std::string* error) const {
  if (!(max_gap_s > 0.0) || !std::isfinite(max_gap_s)) {
    if (error) *error = "max_gap_s must be a positive number, got " + std::to_string(max_gap_s);
    return false;
  }
  return true;
}

Eigen::Isometry3d ToIsometry(const api::StampedPose& pose) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = pose.q_world_body.normalized().toRotationMatrix();
  T.translation() = pose.p_world;
  return T;
}

api::StampedPose InterpolatePose(const api::StampedPose& a,
                                 const api::StampedPose& b,
                                 int64_t stamp_ns) {
  api::StampedPose pose;
  pose.stamp_ns = stamp_ns;
  const int64_t span_ns = b.stamp_ns - a.stamp_ns;
  if (span_ns == 0 || stamp_ns == a.stamp_ns) {
    pose.p_world = a.p_world;
    pose.q_world_body = a.q_world_body;
    return pose;
  }
  if (stamp_ns == b.stamp_ns) {
    pose.p_world = b.p_world;
    pose.q_world_body = b.q_world_body;
    return pose;
  }
  // Integer differences first, so large epoch stamps lose no precision.
  const double f = static_cast<double>(stamp_ns - a.stamp_ns) / static_cast<double>(span_ns);
  pose.p_world = a.p_world + f * (b.p_world - a.p_world);
  pose.q_world_body = a.q_world_body.slerp(f, b.q_world_body).normalized();
  return pose;
}

Association AssociatePoses(const api::Trajectory& estimate,
                           const api::Trajectory& truth,
                           const AssociationOptions& options) {
  Association result;
  result.num_estimate_poses = estimate.poses.size();
  result.num_truth_poses = truth.poses.size();
  if (!options.IsValid(&result.error)) return result;
  if (!CheckStamps(estimate, truth, &result.error)) return result;
  const std::vector<api::StampedPose>& gt = truth.poses;
  const int64_t max_gap_ns = static_cast<int64_t>(std::llround(options.max_gap_s * 1e9));
  const std::vector<double> cumulative_m = CumulativeDistances(gt);

  bool have_first = false;
  double first_distance_m = 0.0;
  result.pairs.reserve(estimate.poses.size());
  size_t k = 0;  // Bracket start; stamps increase, so it only moves forward.
  for (const api::StampedPose& est : estimate.poses) {
    api::StampedPose truth_pose;
    const TruthLookup lookup = TruthAt(gt, est.stamp_ns, max_gap_ns, &k, &truth_pose);
    if (lookup == TruthLookup::kOutside) {
      ++result.num_skipped_outside;
      continue;
    }
    if (lookup == TruthLookup::kAcrossGap) {
      ++result.num_skipped_gap;
      continue;
    }
    const double distance_m = cumulative_m[k] + (truth_pose.p_world - gt[k].p_world).norm();
    if (!have_first) {
      have_first = true;
      first_distance_m = distance_m;
    }
    PosePair pair;
    pair.stamp_ns = est.stamp_ns;
    pair.T_world_est = ToIsometry(est);
    pair.T_world_truth = ToIsometry(truth_pose);
    pair.distance_m = distance_m - first_distance_m;
    result.pairs.push_back(pair);
  }
  result.ok = true;
  return result;
}

}  // namespace raillomer::eval
