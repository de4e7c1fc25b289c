#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "api/trajectory.h"
#include "estimator/eval/alignment.h"
#include "estimator/eval/association.h"
#include "estimator/eval/metrics.h"

namespace raillomer::eval {

/// Everything that sets how a trajectory is scored (one struct, defaults as the CLI's).
struct EvalOptions {
  AlignmentMode align = AlignmentMode::kNone;
  /// Largest truth gap interpolated across (s).
  double max_gap_s = 0.5;
  /// Relative error segment length (m).
  double segment_length_m = 100.0;
  /// Along-track spacing of relative error start poses (m).
  double rpe_start_step_m = 1.0;

  /// True when the options are usable; otherwise false with a message.
  bool IsValid(std::string* error) const;
};

/// The scores of one estimate against one truth, as the paper's Table III, with diagnostics.
struct EvalResult {
  /// False on unusable input (see error); the figures are then not set.
  bool ok = false;
  std::string error;
  /// Things worth telling the user that do not stop the evaluation.
  std::vector<std::string> warnings;
  EvalOptions options;
  /// UTM zone shared by the inputs ("50N"), empty if neither has one.
  std::string utm_zone;
  Association association;
  /// Least-squares alignment used for the ATE.
  Alignment alignment;
  AteStats ate;
  RpeStats rpe;
  DriftStats drift;
  /// Truth path length over the matched span (m) and its duration (s).
  double distance_m = 0.0;
  double duration_s = 0.0;
  int64_t first_stamp_ns = 0;
  int64_t last_stamp_ns = 0;
};

/// Minimum number of matched poses an evaluation needs.
constexpr size_t kMinMatchedPoses = 2;

/// Associates, aligns and scores the estimate against the truth (no file I/O).
EvalResult Evaluate(const api::Trajectory& estimate,
                    const api::Trajectory& truth,
                    const EvalOptions& options);

}  // namespace raillomer::eval
