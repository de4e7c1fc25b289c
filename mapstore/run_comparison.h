#pragma once

#include <algorithm>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "mapstore/change_detection.h"
#include "mapstore/clearance.h"
#include "mapstore/map_store.h"
#include "mapstore/provisional_map.h"
#include "mapstore/run_registration.h"

namespace raillomer::mapstore {

/// Settings of a comparison of two stored runs of a line.
struct RunComparisonOptions {
  double stretch_m = 80.0;     ///< compared a stretch of chainage at a time
  double corridor_m = 20.0;    ///< points this far from the centreline take part
  double overlap_m = 10.0;     ///< ... and this far past the stretch's ends
  double look_back_m = 100.0;  ///< sensor poses this far before a stretch saw into it
  /// The part of the line compared, chainage in metres (the line's offset included); the whole
  /// line by default.
  double from_m = -std::numeric_limits<double>::infinity();
  double to_m = std::numeric_limits<double>::infinity();
  RegistrationOptions registration;
  /// A stretch whose registration leaves a larger RMS is not compared (reported as skipped):
  /// misregistered, everything would differ.
  double max_registration_rms_m = 0.04;
  ChangeOptions change;
  ClearanceOptions clearance;
  /// An added and a removed object pair as one moved object when they lie this close and
  /// their sizes differ by at most moved_size_tolerance (a share of each dimension).
  double moved_within_m = 10.0;
  double moved_size_tolerance = 0.35;
  /// Added growth is vegetation when this share of its voxels lies within vegetation_near_m of
  /// the reference's points higher than vegetation_above_rail_m (a crown it grows out of).
  double vegetation_share = 0.3;
  double vegetation_near_m = 1.0;
  double vegetation_above_rail_m = 1.5;
  /// Vegetation is centred on its trunk: its lowest third when at most this wide.
  double trunk_m = 1.0;
  /// The catenary's wires run within wire_zone_half_width_m of the track centre (stagger
  /// included) and at least wire_zone_above_rail_m above the rails (RAIL_FACTS: contact wire
  /// 5.33-6.5 m), hung on droppers and, in tunnels, on brackets from the crown. A LiDAR hits a
  /// 1-cm wire or a 4-cm bracket only now and then, so each run maps a different scatter of it:
  /// a thin piece there (two sides at most change.thin_m), along the track or upright and at
  /// most wire_piece_max_m long, is no change (CatenaryWirePiece).
  double wire_zone_half_width_m = 0.6;
  double wire_zone_above_rail_m = 4.5;
  double wire_piece_max_m = 5.0;
  bool IsValid(std::string* error) const;
};

/// What a change is: something there now that the reference saw empty (`added`), something
/// the reference had that the later run saw empty (`removed`), an added and a removed object
/// of one shape near each other (`moved`), or added growth on what the reference had above
/// the ground (`vegetation`).
enum class ChangeKind { kAdded, kRemoved, kMoved, kVegetation };
const char* ToString(ChangeKind kind);
/// The kind named `name`; false if there is none.
bool ParseChangeKind(const std::string& name, ChangeKind* kind);

/// A change between two runs, placed on the line.
struct RunChange {
  ChangeKind kind = ChangeKind::kAdded;
  int stretch = 0;                                       ///< the stretch it was found in
  Eigen::Vector3d centre_utm = Eigen::Vector3d::Zero();  ///< in the reference run's map
  std::string utm_zone;
  /// The footprint's corners (UTM easting, northing): the extent along and across the track.
  std::vector<Eigen::Vector2d> footprint_utm;
  double chainage_m = 0.0;  ///< the line's chainage (its offset included)
  double offset_m = 0.0;    ///< from the track centre, positive left of increasing chainage
  /// The footprint's extent across the track: its right and its left edge's offsets (a tree
  /// lying across the track has them on either side of the centre).
  double offset_from_m = 0.0, offset_to_m = 0.0;
  Eigen::Vector3d size_m = Eigen::Vector3d::Zero();  ///< along, across, height
  double height_above_rail_min_m = 0.0, height_above_rail_max_m = 0.0;
  double margin_m = 0.0;           ///< against the structure gauge, negative inside
  bool intrudes_envelope = false;  ///< there now and inside the gauge (what is gone is not)
  /// Against the vegetation zone: negative when something there now grows taller than the
  /// rule allows, +infinity when nothing of it lies in the zone.
  double vegetation_margin_m = 0.0;
  double lod_m = 0.0;       ///< the smallest change told from noise and misregistration there
  double confidence = 0.0;  ///< 0-1: how much of it the other run saw empty, and how often
  double seen_empty_share = 0.0;
  size_t voxels = 0;
  size_t points_reference = 0, points_later = 0;  ///< in its box, in each run
  /// A moved object: where it stood in the reference, and how far it went.
  Eigen::Vector3d moved_from_utm = Eigen::Vector3d::Zero();
  double moved_m = 0.0;
};

/// Whether a change's footprint reaches over both rails (a tree lying over them).
bool LiesAcross(const RunChange& change);
/// Which side of the track a change lies on: "left" or "right" of increasing chainage (its
/// centre's), or "across" when it lies across.
const char* SideOf(const RunChange& change);

/// A stretch of the line: the chainage it covers (the line's offset included).
struct StretchRange {
  int index = 0;
  double from_m = 0.0, to_m = 0.0;
};

/// One stretch compared: whether both runs had enough of it, the later run's registration onto
/// the reference (the transform in the stretch's frame, whose origin is `origin`), and what
/// differed.
struct StretchOutcome {
  StretchRange range;
  bool compared = false;
  std::string skipped;  ///< why it was not compared
  double registration_rms_m = 0.0;
  /// The registered runs' rail heads' height differences, RMS (NaN where the rails were not
  /// seen well enough in both).
  double rail_rms_m = std::numeric_limits<double>::quiet_NaN();
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Isometry3d T_reference_later = Eigen::Isometry3d::Identity();
  StretchSummary summary;
  std::vector<RunChange> changes;
  double seconds = 0.0;
  /// Compared on the later run's provisional output too: compared again once its final
  /// output holds the stretch.
  bool provisional = false;
};

/// What a comparison did, stretch by stretch.
struct RunComparisonSummary {
  size_t stretches = 0, stretches_compared = 0;
  double km = 0.0;
  double registration_rms_m = 0.0;  ///< the inliers' RMS over the compared stretches
  double rail_rms_m = std::numeric_limits<double>::quiet_NaN();  ///< on the rails (NaN: unseen)
  size_t objects = 0, not_observed = 0;
};

/// Whether an added or removed change is a piece of the catenary's wires, droppers or brackets
/// that one run happened to sample and the other did not
/// (RunComparisonOptions::wire_zone_half_width_m).
bool CatenaryWirePiece(const RunChange& change, const RunComparisonOptions& o);

/// A later run of a line compared with a reference run, stretch by stretch along the line's
/// centreline: each stretch of the later run registered onto the reference, then compared on
/// occupancy (CompareStretch), each change placed on the line and checked against the
/// structure gauge. Stretches are numbered from the centreline's start, so a stretch keeps its
/// number while the later run grows.
class RunComparison {
 public:
  /// Checks the runs (one line, one zone, the reference finished, the runs overlapping where
  /// the later has poses) and reads their poses; kInvalid / kNotFound / kConflict naming why.
  /// `provisional` (if given) is the later run's provisional output (ProvisionalMap), which
  /// stretches its final output does not hold yet can be compared on; ignored in another zone.
  static Result Prepare(const MapStore& store,
                        int64_t reference_run,
                        int64_t later_run,
                        const RunComparisonOptions& options,
                        std::unique_ptr<RunComparison>* out,
                        const ProvisionalRun* provisional = nullptr);

  /// The stretches within the options' range.
  const std::vector<StretchRange>& stretches() const { return stretches_; }
  /// How far along the line (chainage) the later run's poses reach; -infinity with none.
  /// With `provisional`, its provisional poses count too.
  double later_reach_m(bool provisional = false) const {
    return provisional ? std::max(later_reach_m_, provisional_reach_m_) : later_reach_m_;
  }
  /// How far along the line its poses up to `stamp_ns` reach (the last submap's end: what
  /// the map holds); -infinity with none.
  double ReachUntil(int64_t stamp_ns, bool provisional = false) const;
  /// The last stamp of the provisional output's submaps; 0 with none.
  int64_t provisional_mapped_until() const { return provisional_.MappedUntil(); }
  const LineInfo& line() const { return line_; }
  const RunInfo& reference() const { return reference_; }
  const RunInfo& later() const { return later_; }

  /// Compares one stretch; with `provisional`, on the later run's provisional output as well
  /// as its final one (the outcome says so).
  Result Compare(const StretchRange& range, StretchOutcome* out, bool provisional = false) const;

 private:
  RunComparison(const MapStore& store, const RunComparisonOptions& options);
  /// Reads both runs, their line and their poses; kInvalid / kNotFound / kConflict where they
  /// cannot be compared (another line or zone, the reference live, no centreline yet).
  Result ReadRuns(int64_t reference_run, int64_t later_run);
  /// The reference's chainage range (`ref_first_m` to `ref_last_m`) and how far the later run
  /// reaches; kInvalid where the reference has no pose on the line or the runs do not overlap.
  Result ReadReach(int64_t reference_run,
                   int64_t later_run,
                   double* ref_first_m,
                   double* ref_last_m);
  /// Keeps the later run's provisional output (ignored if absent or in another zone) and its
  /// reach, -infinity where it does not overlap the reference's range.
  void TakeProvisional(const ProvisionalRun* provisional,
                       int64_t later_run,
                       double ref_first_m,
                       double ref_last_m);
  /// Cuts the line into stretches of stretch_m, clipped to the options' range.
  void CutStretches();
  /// The changes of `placed` that are this stretch's: in the corridor, centred in the stretch
  /// (an object centred in the overlap is the neighbour's).
  void KeepOwn(const StretchRange& range, std::vector<RunChange> placed, StretchOutcome* out) const;

  const MapStore& store_;
  RunComparisonOptions options_;
  RunInfo reference_, later_;
  LineInfo line_;
  std::vector<api::StreamPose> reference_poses_, later_poses_;
  std::vector<double> later_chainage_m_;  ///< each later pose's, NaN off the line
  ProvisionalRun provisional_;
  std::vector<double> provisional_chainage_m_;  ///< each provisional pose's, NaN off the line
  std::vector<StretchRange> stretches_;
  double later_reach_m_ = 0.0;
  double provisional_reach_m_ = -std::numeric_limits<double>::infinity();
};

/// Compares every stretch of a later run with a reference run (RunComparison) and collects
/// the changes. `each_stretch` (if given) gets each stretch's outcome first; an error it
/// returns ends the comparison.
Result CompareRuns(const MapStore& store,
                   int64_t reference_run,
                   int64_t later_run,
                   const RunComparisonOptions& options,
                   std::vector<RunChange>* changes,
                   RunComparisonSummary* summary,
                   const std::function<Result(const StretchOutcome&)>& each_stretch = nullptr);

}  // namespace raillomer::mapstore
