#include "estimator/eval/evaluation.h"

#include <cmath>

namespace raillomer::eval {

bool EvalOptions::IsValid(std::string* error) const {
  AssociationOptions association;
  association.max_gap_s = max_gap_s;
  RpeOptions rpe;
  rpe.segment_length_m = segment_length_m;
  rpe.start_step_m = rpe_start_step_m;
  return association.IsValid(error) && rpe.IsValid(error);
}

namespace {

/// Sets the shared UTM zone; false on two different zones, a warning on one left unaligned.
bool CheckFrames(const api::Trajectory& estimate,
                 const api::Trajectory& truth,
                 AlignmentMode align,
                 EvalResult* result) {
  // Frames: two different UTM zones can never be compared; one georeferenced and one local
  // trajectory only make sense once aligned.
  if (!estimate.utm_zone.empty() && !truth.utm_zone.empty() &&
      estimate.utm_zone != truth.utm_zone) {
    result->error = "estimate is in UTM zone " + estimate.utm_zone + " but truth in " +
                    truth.utm_zone + "; convert one of them first";
    return false;
  }
  result->utm_zone = !truth.utm_zone.empty() ? truth.utm_zone : estimate.utm_zone;
  if (estimate.utm_zone.empty() != truth.utm_zone.empty() && align == AlignmentMode::kNone) {
    result->warnings.push_back(std::string("only the ") +
                               (truth.utm_zone.empty() ? "estimate" : "truth") +
                               " has a utm_zone line (" + result->utm_zone +
                               ") and --align is none; the two may be in different frames");
  }
  return true;
}

/// Pairs the estimate with the truth; false with an error unless kMinMatchedPoses pairs match.
bool Associate(const api::Trajectory& estimate,
               const api::Trajectory& truth,
               const EvalOptions& options,
               EvalResult* result) {
  AssociationOptions association_options;
  association_options.max_gap_s = options.max_gap_s;
  result->association = AssociatePoses(estimate, truth, association_options);
  if (!result->association.ok) {
    result->error = result->association.error;
    return false;
  }
  const std::vector<PosePair>& pairs = result->association.pairs;
  if (pairs.size() < kMinMatchedPoses) {
    result->error =
        "only " + std::to_string(pairs.size()) + " of " + std::to_string(estimate.poses.size()) +
        " estimate poses match the truth in time (" +
        std::to_string(result->association.num_skipped_outside) + " outside the truth's span, " +
        std::to_string(result->association.num_skipped_gap) + " across truth gaps above " +
        std::to_string(options.max_gap_s) + " s); need at least " +
        std::to_string(kMinMatchedPoses);
    return false;
  }
  return true;
}

/// Aligns the matched estimate positions to the truth's; warns when the alignment is not unique.
void Align(const std::vector<PosePair>& pairs, AlignmentMode align, EvalResult* result) {
  std::vector<Eigen::Vector3d> p_est, p_truth;
  p_est.reserve(pairs.size());
  p_truth.reserve(pairs.size());
  for (const PosePair& pair : pairs) {
    p_est.push_back(pair.T_world_est.translation());
    p_truth.push_back(pair.T_world_truth.translation());
  }
  result->alignment = AlignPoints(p_est, p_truth, align);
  if (result->alignment.degenerate) {
    result->warnings.push_back(std::string("the ") + ToString(align) +
                               " alignment is not unique (the matched truth is too straight or "
                               "too short to fix the rotation)");
  }
}

/// Scores the relative error and the end drift; warns when the estimate has positions only.
void ScoreRelativeError(const std::vector<PosePair>& pairs,
                        const EvalOptions& options,
                        EvalResult* result) {
  RpeOptions rpe_options;
  rpe_options.segment_length_m = options.segment_length_m;
  rpe_options.start_step_m = options.rpe_start_step_m;
  rpe_options.position_only = EstimateIsPositionOnly(pairs);
  rpe_options.R_truth_est = result->alignment.T_truth_est.linear();
  if (rpe_options.position_only) {
    result->warnings.push_back(
        "the estimate has positions only (every orientation is the identity): its relative "
        "error compares displacements in the world frame, and no rotation error is reported");
  }
  result->rpe = ComputeRpe(pairs, rpe_options);
  result->drift = ComputeEndDrift(pairs, options.align, rpe_options.position_only);
}

}  // namespace

EvalResult Evaluate(const api::Trajectory& estimate,
                    const api::Trajectory& truth,
                    const EvalOptions& options) {
  EvalResult result;
  result.options = options;
  if (!options.IsValid(&result.error)) return result;
  if (!CheckFrames(estimate, truth, options.align, &result)) return result;
  if (!Associate(estimate, truth, options, &result)) return result;
  const std::vector<PosePair>& pairs = result.association.pairs;
  Align(pairs, options.align, &result);
  result.ate = ComputeAte(pairs, result.alignment.T_truth_est);
  ScoreRelativeError(pairs, options, &result);

  result.first_stamp_ns = pairs.front().stamp_ns;
  result.last_stamp_ns = pairs.back().stamp_ns;
  result.duration_s = static_cast<double>(result.last_stamp_ns - result.first_stamp_ns) * 1e-9;
  result.distance_m = pairs.back().distance_m;
  result.ok = true;
  return result;
}

}  // namespace raillomer::eval
