#pragma once

#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer::mapstore {

/// One run's part of a stretch, in the stretch's local frame (UTM minus its origin), the later
/// run already registered onto the reference: its map points and where its LiDARs were.
struct RunStretch {
  std::vector<Eigen::Vector3d> points;
  /// Sensor poses (x forward, z up): each LiDAR looked along x within the field of view below.
  std::vector<Eigen::Isometry3d> sensors;
};

/// Settings of the comparison of a stretch.
struct ChangeOptions {
  double voxel_m = 0.1;  ///< the maps' voxel (the store's level 0)
  /// A voxel of one run with no voxel of the other within this is a candidate change: the
  /// level of detection before the stretch's own noise and misregistration are added.
  double level_of_detection_m = 0.15;
  double cluster_gap_m = 0.25;            ///< candidate voxels this close form one object
  double min_object_m = 0.3;              ///< objects smaller in every direction are not reported
  size_t min_object_voxels = 6;           ///< nor objects of fewer voxels
  double fov_half_azimuth_deg = 40.85;    ///< Livox Horizon: 81.7 deg wide
  double fov_half_elevation_deg = 25.25;  ///< two units, +-12.7 deg pitch, 25.1 deg each
  double min_range_m = 2.0, max_range_m = 100.0;
  /// The other run's occupancy for the ray test: its points on a grid this coarse, each grown
  /// by a cell every way, so that a surface it sampled sparsely (far off, at a grazing angle)
  /// still stops a ray instead of letting it through its gaps.
  double occupancy_m = 0.2;
  /// The other run saw a candidate voxel empty when one of its rays passed through it and hit
  /// something at least this far beyond (a hit nearer is that voxel's own surface).
  double beyond_m = 0.6;
  /// Candidate voxels of an object tested for being seen empty: this many, one more for every
  /// voxels_per_sample of it, at most max_voxels_sampled.
  size_t voxels_sampled = 16;
  size_t voxels_per_sample = 50;
  size_t max_voxels_sampled = 64;
  /// Sensor poses tried per voxel, spread over those in view: enough that the share seen
  /// empty does not hang on which few were picked.
  size_t sensors_sampled = 12;
  /// An object is a change when the other run's rays reached at least min_seen_voxels of its
  /// sampled voxels and passed through this share of those they reached. A voxel no ray
  /// reached (occluded, beyond range, or towards the sky, where a LiDAR gets no return) is no
  /// evidence either way: an object with too few reached is not observed.
  double seen_empty_share = 0.5;
  size_t min_seen_voxels = 2;
  /// A thin object (two of its sides at most thin_m: a post, a dropper, a wire), which a
  /// LiDAR hits only now and then, needs this share seen empty.
  double thin_m = 0.25;
  double thin_seen_empty_share = 0.8;
  /// Keep the objects that were not changes (too small, not observed) in the summary, for
  /// explaining why something was not reported.
  bool keep_rejected = false;
  bool IsValid(std::string* error) const;
};

/// Something one run has and the other saw empty.
struct StretchChange {
  enum class Kind { kAdded, kRemoved };
  Kind kind = Kind::kAdded;
  std::vector<Eigen::Vector3d> voxels;  ///< centres, local frame
  Eigen::AlignedBox3d box;              ///< of the voxels, grown by half a voxel
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double seen_empty_share = 0.0;  ///< of the sampled voxels the other run reached, seen empty
  size_t samples = 0;             ///< sampled voxels that some ray of the other run reached
  size_t seen_empty = 0;          ///< of them, those it passed through
};

/// What a comparison found and left out, for the record.
struct StretchSummary {
  size_t candidates_added = 0, candidates_removed = 0;  ///< voxels
  size_t objects = 0;                                   ///< clusters of the minimum size
  size_t not_observed = 0;  ///< of them, the other run did not see the place
  /// With ChangeOptions::keep_rejected: the clusters that were not changes, each with its
  /// evidence, and why (`too small` or `not seen empty`).
  std::vector<std::pair<StretchChange, std::string>> rejected;
};

/// Compares a stretch of a later run with the reference: voxels one has and the other has not
/// within the level of detection, clustered into objects, each kept only where the other run's
/// rays (walked through its occupied voxels on OctoMap's key grid, from its sensor poses that
/// had the place in view) passed through it: what a run could not see is not observed, never
/// removed.
std::vector<StretchChange> CompareStretch(const RunStretch& reference,
                                          const RunStretch& later,
                                          const ChangeOptions& options,
                                          StretchSummary* summary = nullptr);

}  // namespace raillomer::mapstore
