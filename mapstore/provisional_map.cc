#include "mapstore/provisional_map.h"

#include <algorithm>

namespace raillomer::mapstore {

int64_t ProvisionalRun::MappedUntil() const {
  return pieces.empty() ? 0 : pieces.back()->last_stamp_ns;
}

Result ProvisionalMap::Check(const RunInfo& info,
                             bool georeferenced,
                             const std::string& zone) const {
  const std::string run = "run " + std::to_string(info.id);
  if (info.status != "live")
    return {Outcome::kConflict, run + " is finished: provisional output is for a live run"};
  if (!georeferenced) return {Outcome::kInvalid, "provisional output must be georeferenced (UTM)"};
  if (!info.utm_zone.empty() && info.utm_zone != zone)
    return {Outcome::kInvalid, run + " lies in UTM zone " + info.utm_zone + ", not " + zone};
  auto held = runs_.find(info.id);
  if (held != runs_.end() && !held->second.utm_zone.empty() && held->second.utm_zone != zone)
    return {
        Outcome::kInvalid,
        run + "'s provisional output lies in UTM zone " + held->second.utm_zone + ", not " + zone};
  return {};
}

size_t ProvisionalMap::PointsOf(const ProvisionalRun& run) const {
  size_t n = 0;
  for (const auto& piece : run.pieces) n += piece->points.size();
  return n;
}

Result ProvisionalMap::AddPoses(const RunInfo& info,
                                const std::vector<api::StreamPose>& poses,
                                int* added) {
  *added = 0;
  std::lock_guard<std::mutex> lock(mu_);
  for (const api::StreamPose& p : poses) {
    const Result r = Check(info, p.georeferenced, p.utm_zone);
    if (!r) return r;
  }
  ProvisionalRun& run = runs_[info.id];
  if (run.poses.size() + poses.size() > options_.max_poses_per_run)
    return {Outcome::kInvalid,
            "run " + std::to_string(info.id) + " would hold more than " +
                std::to_string(options_.max_poses_per_run) + " provisional poses"};
  std::vector<api::StreamPose> sorted = poses;
  std::sort(sorted.begin(), sorted.end(), [](const auto& a, const auto& b) {
    return a.stamp_ns < b.stamp_ns;
  });
  for (const api::StreamPose& p : sorted) {
    if (!run.poses.empty() && p.stamp_ns <= run.poses.back().stamp_ns) continue;
    run.poses.push_back(p);
    run.utm_zone = p.utm_zone;
    ++*added;
  }
  return {};
}

Result ProvisionalMap::AddSubmap(const RunInfo& info, const api::Submap& submap) {
  std::lock_guard<std::mutex> lock(mu_);
  const Result r = Check(info, submap.georeferenced, submap.utm_zone);
  if (!r) return r;
  ProvisionalRun& run = runs_[info.id];
  if (run.MappedUntil() >= submap.last_stamp_ns) return {Outcome::kDuplicate, ""};
  if (PointsOf(run) + submap.points.size() > options_.max_points_per_run)
    return {Outcome::kInvalid,
            "run " + std::to_string(info.id) + " would hold more than " +
                std::to_string(options_.max_points_per_run) + " provisional points"};
  auto piece = std::make_shared<ProvisionalPiece>();
  piece->first_stamp_ns = submap.first_stamp_ns;
  piece->last_stamp_ns = submap.last_stamp_ns;
  piece->placement = submap.placement;
  piece->origin = submap.origin;
  piece->points = submap.points;
  run.pieces.push_back(std::move(piece));
  run.utm_zone = submap.utm_zone;
  return {};
}

template <typename Fn>
void ProvisionalMap::PruneWith(int64_t run_id, Fn prune) {
  std::lock_guard<std::mutex> lock(mu_);
  auto found = runs_.find(run_id);
  if (found == runs_.end()) return;
  ProvisionalRun& run = found->second;
  prune(run);
  if (run.poses.empty() && run.pieces.empty()) runs_.erase(found);
}

void ProvisionalMap::PrunePoses(int64_t run_id, int64_t final_ns) {
  PruneWith(run_id, [&](ProvisionalRun& run) {
    run.poses.erase(run.poses.begin(),
                    std::find_if(run.poses.begin(), run.poses.end(), [&](const auto& p) {
                      return p.stamp_ns > final_ns;
                    }));
  });
}

void ProvisionalMap::PruneMap(int64_t run_id, int64_t final_ns) {
  PruneWith(run_id, [&](ProvisionalRun& run) {
    run.pieces.erase(run.pieces.begin(),
                     std::find_if(run.pieces.begin(), run.pieces.end(), [&](const auto& piece) {
                       return piece->last_stamp_ns > final_ns;
                     }));
  });
}

void ProvisionalMap::Drop(int64_t run) {
  std::lock_guard<std::mutex> lock(mu_);
  runs_.erase(run);
}

bool ProvisionalMap::Get(int64_t run, ProvisionalRun* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  auto found = runs_.find(run);
  if (found == runs_.end()) return false;
  *out = found->second;
  return true;
}

std::vector<std::vector<Eigen::Vector3d>> ProvisionalPointsIn(const ProvisionalRun& run,
                                                              const Eigen::AlignedBox2d& box) {
  std::vector<uint32_t> placements;
  std::vector<std::vector<Eigen::Vector3d>> out;
  for (const auto& piece : run.pieces) {
    const size_t group =
        std::find(placements.begin(), placements.end(), piece->placement) - placements.begin();
    if (group == placements.size()) {
      placements.push_back(piece->placement);
      out.emplace_back();
    }
    for (const Eigen::Vector3f& q : piece->points) {
      const Eigen::Vector3d p = piece->origin + q.cast<double>();
      if (box.contains(p.head<2>())) out[group].push_back(p);
    }
  }
  out.erase(std::remove_if(out.begin(), out.end(), [](const auto& g) { return g.empty(); }),
            out.end());
  return out;
}

}  // namespace raillomer::mapstore
