#include "mapstore/change_detection.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <limits>
#include <unordered_map>
#include <unordered_set>

#include <octomap/OcTree.h>

#include "mapstore/grid_cell.h"
#include "mapstore/voxel_set.h"

namespace raillomer::mapstore {
namespace {

using VoxelMap = std::unordered_set<GridCell, GridCellHash>;

/// The voxels a stretch's points occupy: the cells in the order of their first point, and
/// their keys in an open-addressing set for the many lookups of the comparison.
class Voxels {
 public:
  Voxels(const std::vector<Eigen::Vector3d>& points, double voxel_m) {
    keys_.Reserve(points.size());  // the store's points are already a voxel apart
    for (const Eigen::Vector3d& p : points) {
      const GridCell c = CellOf(p, voxel_m);
      if (keys_.Insert(Key(c))) cells_.push_back(c);
    }
  }
  bool Has(const GridCell& c) const { return keys_.Contains(Key(c)); }
  const std::vector<GridCell>& cells() const { return cells_; }

 private:
  /// 21 bits an axis: a stretch's local frame spans far less than 2^20 voxels every way.
  static uint64_t Key(const GridCell& c) {
    constexpr int64_t kHalf = int64_t{1} << 20;
    constexpr uint64_t kMask = (uint64_t{1} << 21) - 1;
    return (static_cast<uint64_t>(c.x + kHalf) & kMask) << 42 |
           (static_cast<uint64_t>(c.y + kHalf) & kMask) << 21 |
           (static_cast<uint64_t>(c.z + kHalf) & kMask);
  }
  VoxelSet keys_;
  std::vector<GridCell> cells_;
};

/// The cell offsets whose centres lie within `radius_m` of a cell's centre.
std::vector<GridCell> OffsetsWithin(double radius_m, double voxel_m) {
  const int64_t r = static_cast<int64_t>(std::ceil(radius_m / voxel_m));
  const double limit = (radius_m / voxel_m) * (radius_m / voxel_m) + 1e-9;
  std::vector<GridCell> offsets;
  for (int64_t x = -r; x <= r; ++x)
    for (int64_t y = -r; y <= r; ++y)
      for (int64_t z = -r; z <= r; ++z)
        if (static_cast<double>(x * x + y * y + z * z) <= limit) offsets.push_back({x, y, z});
  // Nearest first: an unchanged voxel mostly has its counterpart in its own cell or next to it.
  std::sort(offsets.begin(), offsets.end(), [](const GridCell& a, const GridCell& b) {
    return a.x * a.x + a.y * a.y + a.z * a.z < b.x * b.x + b.y * b.y + b.z * b.z;
  });
  return offsets;
}

/// The voxels of `of` with no voxel of `in` within the offsets.
std::vector<GridCell> Missing(const Voxels& of,
                              const Voxels& in,
                              const std::vector<GridCell>& offsets) {
  std::vector<GridCell> missing;
  for (const GridCell& c : of.cells()) {
    const bool near = std::any_of(
        offsets.begin(), offsets.end(), [&](const GridCell& d) { return in.Has(c + d); });
    if (!near) missing.push_back(c);
  }
  return missing;
}

/// Connected groups of the cells, joined where they lie within the offsets of each other.
std::vector<std::vector<GridCell>> Clusters(const std::vector<GridCell>& cells,
                                            const std::vector<GridCell>& offsets) {
  VoxelMap left(cells.begin(), cells.end());
  std::vector<std::vector<GridCell>> clusters;
  for (const GridCell& seed : cells) {
    if (!left.erase(seed)) continue;
    std::vector<GridCell> cluster{seed};
    std::deque<GridCell> queue{seed};
    while (!queue.empty()) {
      const GridCell c = queue.front();
      queue.pop_front();
      for (const GridCell& d : offsets) {
        if (!left.erase(c + d)) continue;
        cluster.push_back(c + d);
        queue.push_back(c + d);
      }
    }
    clusters.push_back(std::move(cluster));
  }
  return clusters;
}

/// A run's occupied voxels: OctoMap's key space and its ray traversal (Amanatides and Woo's, as
/// in its castRay) over cells held in an open-addressing set, which a stretch fills and probes
/// many times faster than the tree's nodes. Every other cell is unknown, which a ray crosses.
class Occupancy {
 public:
  enum class Hit { kNone, kBefore, kBeyond };

  Occupancy(const RunStretch& run, const ChangeOptions& o)
      : run_(run),
        keys_(o.occupancy_m),
        tan_azimuth_(std::tan(o.fov_half_azimuth_deg * M_PI / 180.0)),
        tan_elevation_(std::tan(o.fov_half_elevation_deg * M_PI / 180.0)),
        min_range_sq_(o.min_range_m * o.min_range_m),
        max_range_sq_(o.max_range_m * o.max_range_m) {
    for (const Eigen::Isometry3d& sensor : run.sensors) to_sensor_.push_back(sensor.inverse());
    // Each point's cell (with its highest point) and its 26 neighbours.
    std::vector<octomap::OcTreeKey> own;
    for (const Eigen::Vector3d& p : run.points) {
      octomap::OcTreeKey key;
      if (!keys_.coordToKeyChecked(octomap::point3d(p.x(), p.y(), p.z()), key)) continue;
      const auto [cell, added] = top_.emplace(Pack(key), static_cast<float>(p.z()));
      if (added)
        own.push_back(key);
      else
        cell->second = std::max(cell->second, static_cast<float>(p.z()));
    }
    occupied_.Reserve(8 * own.size());
    for (const octomap::OcTreeKey& k : own)
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dz = -1; dz <= 1; ++dz)
            occupied_.Insert(Pack(octomap::OcTreeKey(static_cast<octomap::key_type>(k[0] + dx),
                                                     static_cast<octomap::key_type>(k[1] + dy),
                                                     static_cast<octomap::key_type>(k[2] + dz))));
  }

  /// Whether this run saw `v` empty: a ray from one of its sensors that had `v` in view passed
  /// through it and hit something beyond. `reached` tells if some ray got that far at all
  /// (not occluded before it).
  bool SeenEmpty(const Eigen::Vector3d& v, const ChangeOptions& o, bool* reached) const {
    *reached = false;
    std::vector<size_t> in_view;
    for (size_t i = 0; i < run_.sensors.size(); ++i)
      if (InView(to_sensor_[i], v)) in_view.push_back(i);
    const size_t n = std::min(o.sensors_sampled, in_view.size());
    for (size_t k = 0; k < n; ++k) {
      const Eigen::Vector3d origin = run_.sensors[in_view[k * in_view.size() / n]].translation();
      const Eigen::Vector3d ray = v - origin;
      const double range = ray.norm();
      Eigen::Vector3d end;
      const Eigen::Vector3d last = origin + (range + 30.0) * (ray / range);
      // No return: a Livox reports nothing, so nothing is known. Or occluded before `v`.
      if (Cast(origin, ray / range, range - 2.5 * o.occupancy_m, last, &end) != Hit::kBeyond)
        continue;
      const double at = (end - origin).norm();
      if (at > range + o.beyond_m) {
        *reached = true;
        return true;
      }
      // A ray coming down onto `v` that struck only the grown shell of what lies below it (the
      // ground under a low object) came through to it: if this run's points around `v` all lie
      // more than the level of detection under the voxel's bottom, `v` was empty. A ray rising
      // to `v` (something hanging) meets what lies below it first: no evidence then.
      if (ray.z() < 0.0 && OnlyBelow(v, o.level_of_detection_m + 0.5 * o.voxel_m) &&
          !StruckBefore(origin, last, range)) {
        *reached = true;
        return true;
      }
      // A ray grazing down past `v` into the ground just behind it tells nothing of `v`
      // (an object standing low): only a hit level with it or above says it is there.
      if (end.z() < v.z() - 2.0 * o.occupancy_m) continue;
      *reached = true;
    }
    return false;
  }

 private:
  static uint64_t Pack(const octomap::OcTreeKey& k) {
    return static_cast<uint64_t>(k[0]) << 32 | static_cast<uint64_t>(k[1]) << 16 | k[2];
  }

  Eigen::Vector3d Centre(const octomap::OcTreeKey& key) const {
    const octomap::point3d c = keys_.keyToCoord(key);
    return {c.x(), c.y(), c.z()};
  }

  /// Whether the cell is occupied (a point's or grown around one), and then its centre.
  bool Occupied(const octomap::OcTreeKey& key, Eigen::Vector3d* centre) const {
    if (!occupied_.Contains(Pack(key))) return false;
    *centre = Centre(key);
    return true;
  }

  /// Visits the cells on the segment from `origin` to `end`, from the origin's up to the one
  /// before the end's, until `visit` returns true; false if the segment leaves the key space.
  /// Amanatides and Woo's traversal as OctoMap's computeRayKeys does it, to the same cells,
  /// but cell by cell: most rays stop at their first occupied cell, long before the end.
  template <typename Visit>
  bool Walk(const octomap::point3d& origin, const octomap::point3d& end, Visit visit) const {
    octomap::OcTreeKey key, key_end;
    if (!keys_.coordToKeyChecked(origin, key) || !keys_.coordToKeyChecked(end, key_end))
      return false;
    if (key == key_end || visit(key)) return true;
    octomap::point3d direction = end - origin;
    const float length = static_cast<float>(direction.norm());
    direction /= length;
    int step[3];
    double t_max[3], t_delta[3];
    for (int i = 0; i < 3; ++i) {
      step[i] = direction(i) > 0.0f ? 1 : (direction(i) < 0.0f ? -1 : 0);
      if (step[i] == 0) {
        t_max[i] = t_delta[i] = std::numeric_limits<double>::max();
        continue;
      }
      const double border =
          keys_.keyToCoord(key[i]) + static_cast<float>(step[i] * keys_.getResolution() * 0.5);
      t_max[i] = (border - origin(i)) / direction(i);
      t_delta[i] = keys_.getResolution() / std::fabs(direction(i));
    }
    while (true) {
      const int dim =
          t_max[0] < t_max[1] ? (t_max[0] < t_max[2] ? 0 : 2) : (t_max[1] < t_max[2] ? 1 : 2);
      key[dim] = static_cast<octomap::key_type>(key[dim] + step[dim]);
      t_max[dim] += t_delta[dim];
      if (key == key_end || std::min({t_max[0], t_max[1], t_max[2]}) > length) return true;
      if (visit(key)) return true;
    }
  }

  /// Where the ray from `origin` along the unit `direction` to `last` first meets an occupied
  /// cell: none, a cell whose centre lies nearer than `before_m` (occluded), or `end`, the
  /// centre of the first beyond. As OctoMap's castRay, but an occluded ray is mostly blocked
  /// near its target: the ray is walked back from just past `before_m` to the origin first,
  /// and on from there only if nothing blocked it.
  Hit Cast(const Eigen::Vector3d& origin,
           const Eigen::Vector3d& direction,
           double before_m,
           const Eigen::Vector3d& last,
           Eigen::Vector3d* end) const {
    const octomap::point3d sensor(origin.x(), origin.y(), origin.z());
    const Eigen::Vector3d past = origin + (before_m + keys_.getResolution()) * direction;
    const octomap::point3d split(past.x(), past.y(), past.z());
    const double before_sq = before_m * before_m;
    Hit hit = Hit::kNone;
    auto occupied = [&](const octomap::OcTreeKey& key) {
      Eigen::Vector3d centre;
      if (!Occupied(key, &centre)) return false;
      if ((centre - origin).squaredNorm() < before_sq) {
        hit = Hit::kBefore;
        return true;
      }
      *end = centre;
      hit = Hit::kBeyond;
      return false;  // walking back: a cell nearer the origin may be hit first
    };
    octomap::OcTreeKey own;
    if (!Walk(split, sensor, occupied) || !keys_.coordToKeyChecked(sensor, own)) return Hit::kNone;
    if (hit != Hit::kBefore)
      occupied(own);  // the sensor's own cell, which the walk back leaves out
    if (hit != Hit::kNone) return hit;
    Walk(split, octomap::point3d(last.x(), last.y(), last.z()), [&](const octomap::OcTreeKey& key) {
      if (!Occupied(key, end)) return false;
      hit = Hit::kBeyond;
      return true;
    });
    return hit;
  }

  /// Whether the ray from `origin` to `last` meets a cell holding a point of this run before
  /// `range_m` from `origin` (a surface it struck, not just the shell grown around one).
  bool StruckBefore(const Eigen::Vector3d& origin,
                    const Eigen::Vector3d& last,
                    double range_m) const {
    const double limit_sq =
        (range_m - 0.5 * keys_.getResolution()) * (range_m - 0.5 * keys_.getResolution());
    bool struck = false;
    Walk(octomap::point3d(origin.x(), origin.y(), origin.z()),
         octomap::point3d(last.x(), last.y(), last.z()),
         [&](const octomap::OcTreeKey& key) {
           if ((Centre(key) - origin).squaredNorm() >= limit_sq) return true;
           return struck = top_.count(Pack(key)) > 0;
         });
    return struck;
  }

  /// Whether this run saw the ground right beneath `v` (a point in its column of cells, one
  /// to three cells down) and nothing level with it: its points within a cell of `v`
  /// horizontally, from three cells below to one above, all lie more than `below_m` under it.
  /// Past the run's cut, where it has no points, their absence says nothing.
  bool OnlyBelow(const Eigen::Vector3d& v, double below_m) const {
    octomap::OcTreeKey k;
    if (!keys_.coordToKeyChecked(octomap::point3d(v.x(), v.y(), v.z()), k)) return false;
    bool beneath = false;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -3; dz <= 1; ++dz) {
          const auto cell =
              top_.find(Pack(octomap::OcTreeKey(static_cast<octomap::key_type>(k[0] + dx),
                                                static_cast<octomap::key_type>(k[1] + dy),
                                                static_cast<octomap::key_type>(k[2] + dz))));
          if (cell == top_.end()) continue;
          if (cell->second >= v.z() - below_m) return false;
          beneath = beneath || (dx == 0 && dy == 0 && dz < 0);
        }
    return beneath;
  }

  /// Whether `v` lies in the field of view of the sensor whose inverse pose is `to_sensor`:
  /// its azimuth and elevation within the half angles, told by their tangents (x > 0).
  bool InView(const Eigen::Isometry3d& to_sensor, const Eigen::Vector3d& v) const {
    const Eigen::Vector3d d = to_sensor * v;
    const double range_sq = d.squaredNorm();
    if (d.x() <= 0.0 || range_sq < min_range_sq_ || range_sq > max_range_sq_) return false;
    return std::abs(d.y()) <= tan_azimuth_ * d.x() &&
           std::abs(d.z()) <= tan_elevation_ * std::hypot(d.x(), d.y());
  }

  const RunStretch& run_;
  std::vector<Eigen::Isometry3d> to_sensor_;  ///< each sensor's pose inverted
  octomap::OcTree keys_;                      ///< the key space only: it holds no node
  std::unordered_map<uint64_t, float> top_;   ///< cells holding points: their highest point
  VoxelSet occupied_;                         ///< packed keys of those and of their neighbours
  double tan_azimuth_, tan_elevation_;        ///< of the field of view's half angles
  double min_range_sq_, max_range_sq_;
};

/// The share of its reached samples an object needs seen empty: more of a thin one (two sides
/// at most thin_m), which rays hit only now and then.
double RequiredShare(const Eigen::AlignedBox3d& box, const ChangeOptions& o) {
  const int thin = (box.sizes().array() <= o.thin_m + 1e-9).count();
  return thin >= 2 ? o.thin_seen_empty_share : o.seen_empty_share;
}

/// A cluster as a change if it is large enough and the other run saw its place empty.
bool Confirm(const std::vector<GridCell>& cluster,
             StretchChange::Kind kind,
             const Occupancy& other,
             const ChangeOptions& o,
             StretchChange* change) {
  change->kind = kind;
  change->voxels.clear();
  change->box.setEmpty();
  for (const GridCell& c : cluster) {
    change->voxels.push_back(CentreOf(c, o.voxel_m));
    change->box.extend(change->voxels.back());
  }
  change->box.min().array() -= 0.5 * o.voxel_m;
  change->box.max().array() += 0.5 * o.voxel_m;
  change->centre = change->box.center();
  if (cluster.size() < o.min_object_voxels || change->box.sizes().maxCoeff() < o.min_object_m)
    return false;
  // A large object gets more samples: a tree's crown, with sky behind most of it, is reached
  // by the other run's rays only here and there.
  const size_t n = std::min(
      cluster.size(),
      std::min(o.max_voxels_sampled, o.voxels_sampled + cluster.size() / o.voxels_per_sample));
  change->seen_empty = change->samples = 0;
  const double share = RequiredShare(change->box, o);
  for (size_t k = 0; k < n; ++k) {
    bool reached = false;
    change->seen_empty += other.SeenEmpty(change->voxels[k * cluster.size() / n], o, &reached);
    change->samples += reached;
    // Stop once even every sample left seen empty could not make it a change (unless the
    // evidence is asked for in full).
    const size_t left = n - k - 1;
    if (!o.keep_rejected && (change->seen_empty + left < o.min_seen_voxels ||
                             change->seen_empty + left < share * (change->samples + left)))
      break;
  }
  change->seen_empty_share =
      change->samples > 0 ? static_cast<double>(change->seen_empty) / change->samples : 0.0;
  return true;
}

}  // namespace

bool ChangeOptions::IsValid(std::string* error) const {
  if (!(voxel_m > 0.0 && level_of_detection_m >= voxel_m && cluster_gap_m >= voxel_m))
    return *error = "voxel_m must be positive, level_of_detection_m and cluster_gap_m at least it",
           false;
  if (!(min_range_m >= 0.0 && max_range_m > min_range_m))
    return *error = "max_range_m must be above min_range_m", false;
  if (!(fov_half_azimuth_deg > 0.0 && fov_half_azimuth_deg < 90.0 && fov_half_elevation_deg > 0.0 &&
        fov_half_elevation_deg < 90.0))
    return *error = "fov_half_azimuth_deg and fov_half_elevation_deg must be in (0, 90)", false;
  if (!(seen_empty_share > 0.0 && seen_empty_share <= 1.0 && thin_seen_empty_share > 0.0 &&
        thin_seen_empty_share <= 1.0))
    return *error = "seen_empty_share and thin_seen_empty_share must be in (0, 1]", false;
  if (voxels_sampled < 1 || sensors_sampled < 1 || max_voxels_sampled < voxels_sampled ||
      voxels_per_sample < 1)
    return *error =
               "voxels_sampled, sensors_sampled and voxels_per_sample must be at least 1, "
               "max_voxels_sampled at least voxels_sampled",
           false;
  return true;
}

std::vector<StretchChange> CompareStretch(const RunStretch& reference,
                                          const RunStretch& later,
                                          const ChangeOptions& o,
                                          StretchSummary* summary) {
  StretchSummary s;
  const Voxels ref(reference.points, o.voxel_m);
  const Voxels now(later.points, o.voxel_m);
  const std::vector<GridCell> near = OffsetsWithin(o.level_of_detection_m, o.voxel_m);
  const std::vector<GridCell> joined = OffsetsWithin(o.cluster_gap_m, o.voxel_m);
  const std::vector<GridCell> added = Missing(now, ref, near);
  const std::vector<GridCell> removed = Missing(ref, now, near);
  s.candidates_added = added.size();
  s.candidates_removed = removed.size();
  std::vector<StretchChange> changes;
  // What one run has is a change only where the other run saw the place: its occupancy.
  auto confirm = [&](const std::vector<GridCell>& cells,
                     StretchChange::Kind kind,
                     const RunStretch& other_run) {
    if (cells.empty()) return;
    const Occupancy other(other_run, o);
    for (const std::vector<GridCell>& cluster : Clusters(cells, joined)) {
      StretchChange change;
      if (!Confirm(cluster, kind, other, o, &change)) {
        if (o.keep_rejected && cluster.size() >= o.min_object_voxels)
          s.rejected.emplace_back(std::move(change), "too small");
        continue;
      }
      ++s.objects;
      if (change.seen_empty >= o.min_seen_voxels &&
          change.seen_empty_share >= RequiredShare(change.box, o)) {
        changes.push_back(std::move(change));
      } else {
        ++s.not_observed;
        if (o.keep_rejected) s.rejected.emplace_back(std::move(change), "not seen empty");
      }
    }
  };
  confirm(added, StretchChange::Kind::kAdded, reference);
  confirm(removed, StretchChange::Kind::kRemoved, later);
  if (summary) *summary = s;
  return changes;
}

}  // namespace raillomer::mapstore
