#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "api/stream.h"
#include "mapstore/map_store.h"

namespace raillomer::mapstore {

/// A provisional submap's points in UTM (float offsets from `origin`), the time it spans and
/// the placement it comes from (api::Submap::placement).
struct ProvisionalPiece {
  int64_t first_stamp_ns = 0, last_stamp_ns = 0;
  uint32_t placement = 0;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3f> points;
};

/// What a live run has sent ahead of its final output, in time order.
struct ProvisionalRun {
  std::string utm_zone;
  std::vector<api::StreamPose> poses;
  std::vector<std::shared_ptr<const ProvisionalPiece>> pieces;
  /// The last stamp of the pieces (what the provisional map holds up to); 0 with none.
  int64_t MappedUntil() const;
};

/// Limits of what the server holds of provisional output.
struct ProvisionalOptions {
  size_t max_points_per_run = 8'000'000;
  size_t max_poses_per_run = 200'000;
};

/// The provisional poses and submaps of live runs: what an estimator sends where its GNSS graph
/// cannot place its output yet (a run's start, an outage), placed as well as it can for now.
/// They stay in memory and out of the tiles: the run's final poses and submaps replace them as
/// they arrive (PrunePoses, PruneMap), and change detection compares a stretch on them ahead of the
/// final map and again once that holds the stretch. A server restarted loses them, which costs only
/// time.
class ProvisionalMap {
 public:
  explicit ProvisionalMap(ProvisionalOptions options = {}) : options_(options) {}

  /// Adds georeferenced poses of a live run (`info`), in `zone`; kInvalid naming what is wrong
  /// (not georeferenced, another zone than the run's or the earlier ones, over the limit).
  /// Poses at or before the newest held one are duplicates and skipped.
  Result AddPoses(const RunInfo& info, const std::vector<api::StreamPose>& poses, int* added);
  /// Adds a georeferenced submap of a live run, likewise.
  Result AddSubmap(const RunInfo& info, const api::Submap& submap);
  /// Drops what the run's final output now covers: poses up to `final_ns`, or pieces that end
  /// by `final_ns`.
  void PrunePoses(int64_t run, int64_t final_ns);
  void PruneMap(int64_t run, int64_t final_ns);
  /// Forgets a run (it finished, or was deleted).
  void Drop(int64_t run);
  /// A copy of what the run has (the pieces shared); false if nothing.
  bool Get(int64_t run, ProvisionalRun* out) const;

 private:
  /// kConflict unless the run is live; kInvalid unless georeferenced in a zone that fits the
  /// run and what it holds.
  Result Check(const RunInfo& info, bool georeferenced, const std::string& zone) const;
  size_t PointsOf(const ProvisionalRun& run) const;
  /// Applies `prune` to the run's held output; forgets the run once nothing is left.
  template <typename Fn>
  void PruneWith(int64_t run, Fn prune);

  ProvisionalOptions options_;
  mutable std::mutex mu_;
  std::map<int64_t, ProvisionalRun> runs_;
};

/// The points of provisional pieces within a UTM box (easting, northing), a list a placement
/// (pieces of one placement fit one another, pieces of two can lie apart), in the order the
/// placements first come; none empty.
std::vector<std::vector<Eigen::Vector3d>> ProvisionalPointsIn(const ProvisionalRun& run,
                                                              const Eigen::AlignedBox2d& box);

}  // namespace raillomer::mapstore
