#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "mapstore/change_detection.h"
#include "mapstore/clearance.h"
#include "mapstore/map_store.h"
#include "mapstore/run_registration.h"

namespace raillomer::mapstore {

/// Settings of a comparison of two stored runs of a line.
struct RunComparisonOptions {
  double stretch_m = 80.0;     ///< compared a stretch of chainage at a time
  double corridor_m = 20.0;    ///< points this far from the centreline take part
  double look_back_m = 100.0;  ///< sensor poses this far before a stretch saw into it
  /// The part of the line compared, chainage in metres (the line's offset included); the whole
  /// line by default.
  double from_m = -std::numeric_limits<double>::infinity();
  double to_m = std::numeric_limits<double>::infinity();
  RegistrationOptions registration;
  ChangeOptions change;
  ClearanceOptions clearance;
};

/// A change between two runs, placed on the line.
struct RunChange {
  StretchChange::Kind kind = StretchChange::Kind::kAdded;
  Eigen::Vector3d centre_utm = Eigen::Vector3d::Zero();  ///< in the reference run's map
  std::string utm_zone;
  double chainage_m = 0.0;  ///< the line's chainage (its offset included)
  double offset_m = 0.0;    ///< from the track centre, positive left of increasing chainage
  Eigen::Vector3d size_m = Eigen::Vector3d::Zero();  ///< along, across, height
  double height_above_rail_min_m = 0.0, height_above_rail_max_m = 0.0;
  double margin_m = 0.0;           ///< against the structure gauge, negative inside
  bool intrudes_envelope = false;  ///< added and inside the gauge (a removed object is gone)
  double seen_empty_share = 0.0;
  size_t voxels = 0;
};

/// What a comparison did, stretch by stretch.
struct RunComparisonSummary {
  size_t stretches = 0, stretches_compared = 0;
  double km = 0.0;
  double registration_rms_m = 0.0;  ///< the inliers' RMS over the compared stretches
  size_t objects = 0, not_observed = 0;
};

/// Compares a later run of a line with a reference run, stretch by stretch along the line's
/// centreline: each stretch of the later run registered onto the reference, then compared on
/// occupancy (CompareStretch), each change placed on the line and checked against the
/// structure gauge. `progress` (if given) is called after each stretch with its chainage.
Result CompareRuns(const MapStore& store,
                   int64_t reference_run,
                   int64_t later_run,
                   const RunComparisonOptions& options,
                   std::vector<RunChange>* changes,
                   RunComparisonSummary* summary,
                   const std::function<void(double chainage_m)>& progress = nullptr);

}  // namespace raillomer::mapstore
