#include "mapstore/run_comparison.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <unordered_set>

#include "mapstore/change_shape.h"
#include "mapstore/grid_cell.h"
#include "mapstore/tile_codec.h"

namespace raillomer::mapstore {
namespace {

Result Fail(Outcome outcome, std::string message) { return {outcome, std::move(message)}; }

/// How far the later run's points reach beyond the reference's before registration: room for
/// the GNSS's difference between runs.
constexpr double kShiftRoomM = 5.0;

/// The stretch's centreline: chainage to position, direction and the geometry around it.
class Stretch {
 public:
  explicit Stretch(std::vector<TrackSample> samples) : samples_(std::move(samples)) {
    const Eigen::Vector2d chord = (samples_.back().point.p - samples_.front().point.p).head<2>();
    const double length = chord.norm();
    chord_ = length > 0.0 ? Eigen::Vector2d(chord / length) : Eigen::Vector2d::UnitX();
    chord_scale_ = length > 0.0 ? static_cast<double>(samples_.size() - 1) / length : 0.0;
  }

  const Eigen::Vector3d& origin() const { return samples_.front().point.p; }
  double first_m() const { return samples_.front().point.chainage_m; }
  double last_m() const { return samples_.back().point.chainage_m; }

  /// The sample nearest `p` (horizontal) and `p`'s signed offset from the centre (positive
  /// left of increasing chainage) and its distance along from that sample. The search starts
  /// where `p` projects onto the stretch's chord and walks downhill: along a stretch of track
  /// (radius hundreds of metres, a hundred metres long) the distance to the centreline's
  /// samples has one minimum for every point of the corridor.
  const TrackSample& Nearest(const Eigen::Vector3d& p, double* offset_m, double* along_m) const {
    const auto distance = [&](size_t i) {
      return (samples_[i].point.p - p).head<2>().squaredNorm();
    };
    const size_t last = samples_.size() - 1;
    const double t = (p - samples_.front().point.p).head<2>().dot(chord_) * chord_scale_;
    size_t best = static_cast<size_t>(std::clamp(std::lround(t), 0L, static_cast<long>(last)));
    double best_d = distance(best);
    for (int step : {1, -1}) {
      for (size_t i = best; (step > 0 ? i < last : i > 0);) {
        i += step;
        const double d = distance(i);
        if (d >= best_d) break;
        best = i;
        best_d = d;
      }
    }
    const Eigen::Vector2d tangent = Tangent(best);
    const Eigen::Vector2d d = (p - samples_[best].point.p).head<2>();
    *offset_m = tangent.x() * d.y() - tangent.y() * d.x();
    *along_m = tangent.dot(d);
    return samples_[best];
  }

  /// The horizontal unit direction of increasing chainage at sample i.
  Eigen::Vector2d Tangent(size_t i) const {
    const size_t a = i > 0 ? i - 1 : 0, b = std::min(i + 1, samples_.size() - 1);
    const Eigen::Vector2d d = (samples_[b].point.p - samples_[a].point.p).head<2>();
    return d.norm() > 0.0 ? Eigen::Vector2d(d.normalized()) : Eigen::Vector2d::UnitX();
  }

  /// Points within `corridor_m` of the centreline and at most `beyond_m` past its ends, in the
  /// stretch's frame (UTM minus origin).
  std::vector<Eigen::Vector3d> Local(const std::vector<Eigen::Vector3d>& utm,
                                     double corridor_m,
                                     double beyond_m) const {
    std::vector<Eigen::Vector3d> out;
    for (const Eigen::Vector3d& p : utm)
      if (Within(p, corridor_m, beyond_m)) out.push_back(p - origin());
    return out;
  }

  bool Within(const Eigen::Vector3d& p_utm, double corridor_m, double beyond_m) const {
    double offset = 0.0, along = 0.0;
    Nearest(p_utm, &offset, &along);
    return std::abs(offset) <= corridor_m && std::abs(along) <= std::max(beyond_m, 1.0);
  }

  /// The middle sample's position (UTM).
  Eigen::Vector3d Mid() const { return samples_[samples_.size() / 2].point.p; }
  /// The horizontal unit direction of increasing chainage at a sample of this stretch.
  Eigen::Vector2d TangentAt(const TrackSample& s) const {
    return Tangent(static_cast<size_t>(&s - samples_.data()));
  }

  /// The UTM point `along_m` of chainage past sample `s` and `offset_m` to its left.
  Eigen::Vector2d ToUtm(const TrackSample& s, double along_m, double offset_m) const {
    const size_t i = static_cast<size_t>(&s - samples_.data());
    const Eigen::Vector2d t = Tangent(i);
    return s.point.p.head<2>() + along_m * t + offset_m * Eigen::Vector2d(-t.y(), t.x());
  }

  Eigen::AlignedBox2d Box(double margin_m) const {
    Eigen::AlignedBox2d box;
    for (const TrackSample& s : samples_) box.extend(s.point.p.head<2>());
    box.min().array() -= margin_m;
    box.max().array() += margin_m;
    return box;
  }

 private:
  std::vector<TrackSample> samples_;
  Eigen::Vector2d chord_;     ///< first to last sample, unit
  double chord_scale_ = 0.0;  ///< samples per metre along the chord
};

/// A run's level-0 points in a UTM box, each tile read and decoded once.
Result PointsIn(const MapStore& store,
                int64_t run,
                const Eigen::AlignedBox2d& box,
                std::vector<Eigen::Vector3d>* out) {
  out->clear();
  std::vector<TileInfo> tiles;
  Result r = store.TilesInBox(run, 0, box, &tiles);
  if (!r) return r;
  std::string bytes, error;
  TilePoints tile;
  for (const TileInfo& t : tiles) {
    r = store.Tile(run, t.key, nullptr, &bytes);
    if (!r) return r;
    if (!DecodeTile(bytes, &tile, &error))
      return Fail(Outcome::kError,
                  "tile " + t.key.ToString() + " of run " + std::to_string(run) + ": " + error);
    for (const Eigen::Vector3f& q : tile.points) {
      const Eigen::Vector3d p = tile.origin + q.cast<double>();
      if (box.contains(p.head<2>())) out->push_back(p);
    }
  }
  return {};
}

/// The sensor poses of a run in a UTM box, in a stretch's frame.
std::vector<Eigen::Isometry3d> SensorsIn(const std::vector<api::StreamPose>& poses,
                                         const Eigen::AlignedBox2d& box,
                                         const Eigen::Vector3d& origin) {
  std::vector<Eigen::Isometry3d> sensors;
  for (const api::StreamPose& p : poses) {
    if (!p.georeferenced || !box.contains(p.p.head<2>())) continue;
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = p.q.normalized().toRotationMatrix();
    T.translation() = p.p - origin;
    sensors.push_back(T);
  }
  return sensors;
}

/// Where a later run's path lies off the reference's in a stretch, as the shift that brings it
/// back: both trains rode the same track, so the median of its poses' offsets across and
/// above the centreline (the reference's path) is the difference of the runs' GNSS placements
/// there, bar the part along the track, which the registration finds.
Eigen::Isometry3d PathOffset(const Stretch& stretch, const std::vector<Eigen::Isometry3d>& poses) {
  std::vector<double> across, up;
  for (const Eigen::Isometry3d& pose : poses) {
    const Eigen::Vector3d p = pose.translation() + stretch.origin();
    double offset = 0.0, along = 0.0;
    const TrackSample& s = stretch.Nearest(p, &offset, &along);
    if (std::abs(along) > 1.0 || std::abs(offset) > 10.0) continue;  // beyond the stretch
    across.push_back(offset);
    up.push_back(p.z() - s.point.p.z());
  }
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  if (across.size() < 5) return T;
  const auto median = [](std::vector<double>* v) {
    std::nth_element(v->begin(), v->begin() + v->size() / 2, v->end());
    return (*v)[v->size() / 2];
  };
  const double lateral = median(&across), vertical = median(&up);
  const Eigen::Vector3d mid = stretch.Mid();
  double offset = 0.0, along = 0.0;
  const TrackSample& s = stretch.Nearest(mid, &offset, &along);
  const Eigen::Vector2d t = stretch.TangentAt(s);
  T.translation() =
      -(lateral * Eigen::Vector3d(-t.y(), t.x(), 0.0) + vertical * Eigen::Vector3d::UnitZ());
  return T;
}

/// The line's centreline (its reference run's path) moved across and up onto another run's path
/// there: both trains rode the same track, but each run's map lies where its own GNSS put it,
/// metres apart. Compared with a run other than the line's reference, offsets and the gauge
/// are measured from the track in that run's map. Along the track the maps' difference stays
/// (no path tells it): chainage is the line's to within it.
void OntoPath(const std::vector<api::StreamPose>& poses, std::vector<TrackSample>* samples) {
  const Stretch line(*samples);
  const Eigen::Isometry3d back = PathOffset(line, SensorsIn(poses, line.Box(10.0), line.origin()));
  for (TrackSample& s : *samples) s.point.p -= back.translation();
}

/// The rail plane's height below the centreline (the body's path): the rail heads are the
/// highest points in the strips 0.6-0.85 m either side, a little below the body.
double RailDrop(const Stretch& stretch, const std::vector<Eigen::Vector3d>& local) {
  std::vector<double> heads;
  for (const Eigen::Vector3d& q : local) {
    const Eigen::Vector3d p = q + stretch.origin();
    double offset = 0.0, along = 0.0;
    const TrackSample& s = stretch.Nearest(p, &offset, &along);
    const double dz = p.z() - s.point.p.z();
    if (std::abs(offset) >= 0.6 && std::abs(offset) <= 0.85 && dz < -0.5) heads.push_back(dz);
  }
  if (heads.size() < 20) return std::numeric_limits<double>::quiet_NaN();
  std::sort(heads.begin(), heads.end());
  return heads[heads.size() * 9 / 10];
}

/// The rail heads' heights (above the centreline) along each rail, per 2 m of the stretch: the
/// 90th percentile of the points 0.6-0.85 m either side within 0.15 m of the rail plane.
std::map<std::pair<int64_t, int>, double> RailHeads(const Stretch& stretch,
                                                    const std::vector<Eigen::Vector3d>& local,
                                                    double drop_m) {
  std::map<std::pair<int64_t, int>, std::vector<double>> bins;
  for (const Eigen::Vector3d& q : local) {
    const Eigen::Vector3d p = q + stretch.origin();
    double offset = 0.0, along = 0.0;
    const TrackSample& s = stretch.Nearest(p, &offset, &along);
    const double dz = p.z() - s.point.p.z();
    if (std::abs(offset) < 0.6 || std::abs(offset) > 0.85 || std::abs(dz - drop_m) > 0.15) continue;
    const double chainage = s.point.chainage_m + along;
    bins[{static_cast<int64_t>(std::floor(chainage / 2.0)), offset > 0.0 ? 1 : -1}].push_back(dz);
  }
  std::map<std::pair<int64_t, int>, double> heads;
  for (auto& [key, z] : bins) {
    if (z.size() < 5) continue;
    std::sort(z.begin(), z.end());
    heads[key] = z[z.size() * 9 / 10];
  }
  return heads;
}

/// The registered runs' disagreement on the rails: the RMS of the differences of their rail
/// heads' heights, 2 m by 2 m along both rails (NaN with fewer than 5 pieces of rail in both).
double RailResidual(const Stretch& stretch,
                    const std::vector<Eigen::Vector3d>& reference,
                    const std::vector<Eigen::Vector3d>& later,
                    double drop_m) {
  const auto a = RailHeads(stretch, reference, drop_m), b = RailHeads(stretch, later, drop_m);
  double sum = 0.0;
  size_t n = 0;
  for (const auto& [key, z] : a) {
    const auto other = b.find(key);
    if (other == b.end()) continue;
    sum += (other->second - z) * (other->second - z);
    ++n;
  }
  return n >= 5 ? std::sqrt(sum / n) : std::numeric_limits<double>::quiet_NaN();
}

/// The compared parts of a stretch and what placing a change there needs.
struct StretchParts {
  RunStretch reference, later;
  /// The later run's points by placement, before registration (LoadParts): its final output's,
  /// then its provisional output's a placement each; none empty. RegisterLater gathers those
  /// that fit one another in `later`.
  std::vector<std::vector<Eigen::Vector3d>> later_placements;
  double rail_drop_m = 0.0;
  double lod_m = 0.0;
  double voxel_m = 0.0;  ///< the comparison's voxel (ChangeOptions::voxel_m)
};

size_t PointsInBox(const std::vector<Eigen::Vector3d>& points, const Eigen::AlignedBox3d& box) {
  return static_cast<size_t>(std::count_if(
      points.begin(), points.end(), [&](const Eigen::Vector3d& p) { return box.contains(p); }));
}

/// A run's map and poses, for loading its part of a stretch: its final output and, if given,
/// its provisional output.
struct RunSource {
  int64_t id = 0;
  const std::vector<api::StreamPose>* poses = nullptr;
  const ProvisionalRun* provisional = nullptr;
};

/// Each run's points and sensors around a stretch. Both reach overlap_m past the stretch's
/// ends (the later 5 m more every way, room for the registration's shift), so an object across
/// an end is seen whole; the stretch that holds its centre reports it.
Result LoadParts(const MapStore& store,
                 const Stretch& stretch,
                 const RunComparisonOptions& o,
                 const RunSource& reference,
                 const RunSource& later,
                 StretchParts* parts) {
  const double reach = o.corridor_m + o.overlap_m + kShiftRoomM;
  std::vector<Eigen::Vector3d> utm;
  Result r = PointsIn(store, reference.id, stretch.Box(reach), &utm);
  if (!r) return r;
  parts->reference.points = stretch.Local(utm, o.corridor_m, o.overlap_m);
  r = PointsIn(store, later.id, stretch.Box(reach + kShiftRoomM), &utm);
  if (!r) return r;
  std::vector<std::vector<Eigen::Vector3d>> placements;
  placements.push_back(std::move(utm));
  if (later.provisional) {
    for (std::vector<Eigen::Vector3d>& p :
         ProvisionalPointsIn(*later.provisional, stretch.Box(reach + kShiftRoomM)))
      placements.push_back(std::move(p));
  }
  for (const std::vector<Eigen::Vector3d>& p : placements) {
    std::vector<Eigen::Vector3d> local =
        stretch.Local(p, o.corridor_m + kShiftRoomM, o.overlap_m + kShiftRoomM);
    if (!local.empty()) parts->later_placements.push_back(std::move(local));
  }
  const Eigen::AlignedBox2d seen_from = stretch.Box(o.look_back_m);
  parts->reference.sensors = SensorsIn(*reference.poses, seen_from, stretch.origin());
  parts->later.sensors = SensorsIn(*later.poses, seen_from, stretch.origin());
  if (later.provisional) {
    const std::vector<Eigen::Isometry3d> more =
        SensorsIn(later.provisional->poses, seen_from, stretch.origin());
    parts->later.sensors.insert(parts->later.sensors.end(), more.begin(), more.end());
  }
  return {};
}

/// `points` of the later run moved by its registration, cut a metre beyond the reference's:
/// what the reference has near its cut is compared with all the later run has there.
std::vector<Eigen::Vector3d> MoveLater(const Stretch& stretch,
                                       const RunComparisonOptions& o,
                                       const Eigen::Isometry3d& T_reference_later,
                                       const std::vector<Eigen::Vector3d>& points) {
  std::vector<Eigen::Vector3d> registered;
  for (const Eigen::Vector3d& p : points) {
    const Eigen::Vector3d q = T_reference_later * p;
    if (stretch.Within(q + stretch.origin(), o.corridor_m + 1.0, o.overlap_m + 1.0))
      registered.push_back(q);
  }
  return registered;
}

/// Whether a placement fits where the largest one was registered (`check`,
/// RegistrationTarget::Check): about as many of its pairs inliers, about as close. Most do:
/// the GNSS graph moves little once settled.
bool FitsLargest(const RegistrationResult& check, const RegistrationResult& largest) {
  if (check.pairs == 0 || largest.pairs == 0) return false;
  auto share = [](const RegistrationResult& r) {
    return static_cast<double>(r.inliers) / static_cast<double>(r.pairs);
  };
  return share(check) >= 0.9 * share(largest) && check.rms_m <= 1.25 * largest.rms_m + 0.005;
}

/// Registers the later run's points and sensors onto the reference and moves them there. A live
/// run's points can come in several placements (its final output and provisional output the
/// GNSS fusion placed at different times, up to a metre apart). The largest one is registered
/// and its fit stands for the stretch; another joins it where it fits that fit (FitsLargest)
/// and is left out where it does not, so that no surface shows twice; the final comparison
/// has all of it. (Registering each on its own would take the registration's time again, at a
/// run's start, when the cores are busiest.) Returns the largest placement's fit.
RegistrationResult RegisterLater(const Stretch& stretch,
                                 const RunComparisonOptions& o,
                                 StretchParts* parts) {
  std::vector<std::vector<Eigen::Vector3d>>& placements = parts->later_placements;
  std::stable_sort(placements.begin(), placements.end(), [](const auto& a, const auto& b) {
    return a.size() > b.size();
  });
  RegistrationTarget reference(parts->reference.points, o.registration);
  RegistrationResult largest;
  parts->later.points.clear();
  for (size_t i = 0; i < placements.size(); ++i) {
    if (i == 0) {
      largest = reference.Register(placements[i], PathOffset(stretch, parts->later.sensors));
      if (!(largest.rms_m <= o.max_registration_rms_m)) break;
    } else if (!FitsLargest(reference.Check(placements[i], largest.T_fixed_moving), largest)) {
      continue;
    }
    std::vector<Eigen::Vector3d> moved =
        MoveLater(stretch, o, largest.T_fixed_moving, placements[i]);
    if (parts->later.points.empty())
      parts->later.points = std::move(moved);
    else
      parts->later.points.insert(parts->later.points.end(), moved.begin(), moved.end());
  }
  for (Eigen::Isometry3d& s : parts->later.sensors) s = largest.T_fixed_moving * s;
  return largest;
}

/// M3C2's LoD95 with each map's voxel quantisation (sigma = voxel / sqrt 12) and the
/// registration's residual, never below the comparison's own threshold.
double LevelOfDetection(const ChangeOptions& o, double registration_rms_m) {
  const double quantisation = o.voxel_m / std::sqrt(12.0);
  return std::max(o.level_of_detection_m,
                  1.96 * std::sqrt(2.0 * quantisation * quantisation +
                                   registration_rms_m * registration_rms_m));
}

/// The points of the run that has the change (the later run's for what was added, the
/// reference's for what is gone) in its voxels: where it was measured, on the same footing as
/// the rail heads the rail plane comes from (a voxel's centre lies up to half a voxel off).
std::vector<Eigen::Vector3d> PointsOf(const StretchChange& c, const StretchParts& parts) {
  std::unordered_set<GridCell, GridCellHash> cells;
  for (const Eigen::Vector3d& v : c.voxels) cells.insert(CellOf(v, parts.voxel_m));
  const std::vector<Eigen::Vector3d>& run =
      c.kind == StretchChange::Kind::kAdded ? parts.later.points : parts.reference.points;
  std::vector<Eigen::Vector3d> points;
  for (const Eigen::Vector3d& p : run)
    if (cells.count(CellOf(p, parts.voxel_m))) points.push_back(p);
  return points.empty() ? c.voxels : points;
}

/// The change's heights above the rail plane and its margins against the gauge and the
/// vegetation rule, from its points.
void CheckClearance(const std::vector<Eigen::Vector3d>& points,
                    const Stretch& stretch,
                    const StretchParts& parts,
                    const StructureGauge& gauge,
                    RunChange* out) {
  ClearanceTally tally(gauge);
  for (const Eigen::Vector3d& q : points) {
    const Eigen::Vector3d p = q + stretch.origin();
    double o = 0.0, a = 0.0;
    const TrackSample& s = stretch.Nearest(p, &o, &a);
    const TrackSection section{
        s.point.p.z() + parts.rail_drop_m, s.point.cant_m, s.curvature_per_m};
    tally.Add(section, ToSection(section, o, p.z()));
  }
  out->margin_m = tally.margin_m();
  out->vegetation_margin_m = tally.vegetation_margin_m();
  out->height_above_rail_min_m = tally.height_min_m();
  out->height_above_rail_max_m = tally.height_max_m();
}

/// A change of a stretch placed on the line and checked against the gauge and the vegetation
/// rule.
RunChange Place(const StretchChange& c,
                const Stretch& stretch,
                const StretchParts& parts,
                const StructureGauge& gauge,
                const std::string& zone) {
  RunChange out;
  out.kind = c.kind == StretchChange::Kind::kAdded ? ChangeKind::kAdded : ChangeKind::kRemoved;
  out.utm_zone = zone;
  out.voxels = c.voxels.size();
  out.seen_empty_share = c.seen_empty_share;
  // Reached often and seen empty throughout: near 1; a few rays, or a split verdict: lower.
  out.confidence = c.seen_empty_share * (1.0 - std::exp(-static_cast<double>(c.samples) / 3.0));
  out.lod_m = parts.lod_m;
  out.centre_utm = c.centre + stretch.origin();
  double offset = 0.0, along = 0.0;
  const TrackSample& at = stretch.Nearest(out.centre_utm, &offset, &along);
  out.chainage_m = at.point.chainage_m + along;
  out.offset_m = offset;
  CheckClearance(PointsOf(c, parts), stretch, parts, gauge, &out);
  Eigen::AlignedBox3d extent;  // along (from `at`), across, up
  for (const Eigen::Vector3d& v : c.voxels) {
    const Eigen::Vector3d p = v + stretch.origin();
    double o = 0.0, a = 0.0;
    const TrackSample& s = stretch.Nearest(p, &o, &a);
    extent.extend(Eigen::Vector3d(s.point.chainage_m + a - at.point.chainage_m, o, p.z()));
  }
  out.size_m = extent.sizes();
  const double half = 0.5 * parts.voxel_m;
  out.size_m.array() += 2.0 * half;
  for (const auto& [a, o] : {std::pair{extent.min().x() - half, extent.min().y() - half},
                             {extent.max().x() + half, extent.min().y() - half},
                             {extent.max().x() + half, extent.max().y() + half},
                             {extent.min().x() - half, extent.max().y() + half}})
    out.footprint_utm.push_back(stretch.ToUtm(at, a, o));
  out.offset_from_m = extent.min().y() - half;
  out.offset_to_m = extent.max().y() + half;
  Eigen::AlignedBox3d box = c.box;
  box.min().array() -= half;
  box.max().array() += half;
  out.points_reference = PointsInBox(parts.reference.points, box);
  out.points_later = PointsInBox(parts.later.points, box);
  return out;
}

/// Drops the pieces of the catenary's wires (CatenaryWirePiece) from both `found` and
/// `placed`, which pair by index; kept in the summary's rejected ones when it keeps them.
void DropWirePieces(const RunComparisonOptions& o,
                    std::vector<StretchChange>* found,
                    std::vector<RunChange>* placed,
                    StretchSummary* summary) {
  std::vector<StretchChange> found_kept;
  std::vector<RunChange> kept;
  for (size_t i = 0; i < placed->size(); ++i) {
    if (!CatenaryWirePiece((*placed)[i], o)) {
      found_kept.push_back(std::move((*found)[i]));
      kept.push_back(std::move((*placed)[i]));
    } else if (o.change.keep_rejected) {
      summary->rejected.emplace_back(std::move((*found)[i]), "a piece of the catenary's wires");
    }
  }
  *found = std::move(found_kept);
  *placed = std::move(kept);
}

/// Vegetation centred on its trunk, placed on the line again from there (a mast, tall with a
/// wide top too, keeps the centre of its pole and cantilever).
void CentreTrees(const Stretch& stretch,
                 const RunComparisonOptions& o,
                 const std::vector<StretchChange>& found,
                 std::vector<RunChange>* placed) {
  for (size_t i = 0; i < placed->size(); ++i) {
    RunChange& c = (*placed)[i];
    Eigen::Vector2d trunk;
    if (c.kind != ChangeKind::kVegetation || !TrunkCentre(c, found[i].voxels, o.trunk_m, &trunk))
      continue;
    c.centre_utm.head<2>() = trunk + stretch.origin().head<2>();
    double offset = 0.0, along = 0.0;
    const TrackSample& at = stretch.Nearest(c.centre_utm, &offset, &along);
    c.chainage_m = at.point.chainage_m + along;
    c.offset_m = offset;
  }
}

/// Added objects that grow out of what the reference had above the ground (a crown, a hedge)
/// become vegetation.
void MarkVegetation(const Stretch& stretch,
                    const StretchParts& parts,
                    const RunComparisonOptions& o,
                    const std::vector<StretchChange>& found,
                    std::vector<RunChange>* placed) {
  std::unordered_set<GridCell, GridCellHash> high;
  const auto build = [&] {
    for (const Eigen::Vector3d& q : parts.reference.points) {
      double offset = 0.0, along = 0.0;
      const TrackSample& s = stretch.Nearest(q + stretch.origin(), &offset, &along);
      const double above = q.z() + stretch.origin().z() - s.point.p.z() - parts.rail_drop_m;
      if (above > o.vegetation_above_rail_m) high.insert(CellOf(q, o.vegetation_near_m));
    }
  };
  for (size_t i = 0; i < placed->size(); ++i) {
    RunChange& c = (*placed)[i];
    if (c.kind != ChangeKind::kAdded || c.height_above_rail_min_m < 0.5) {
      if (c.kind == ChangeKind::kAdded && TreeShaped(c, found[i].voxels))
        c.kind = ChangeKind::kVegetation;
      continue;
    }
    if (high.empty()) build();
    size_t near = 0;
    for (const Eigen::Vector3d& v : found[i].voxels) {
      const GridCell cell = CellOf(v, o.vegetation_near_m);
      bool hit = false;
      for (int64_t dx = -1; dx <= 1 && !hit; ++dx)
        for (int64_t dy = -1; dy <= 1 && !hit; ++dy)
          for (int64_t dz = -1; dz <= 1 && !hit; ++dz)
            hit = high.count(cell + GridCell{dx, dy, dz}) > 0;
      near += hit ? 1 : 0;
    }
    if (TreeShaped(c, found[i].voxels) ||
        near >= o.vegetation_share * static_cast<double>(found[i].voxels.size()))
      c.kind = ChangeKind::kVegetation;
  }
}

bool SameShape(const RunChange& a, const RunChange& b, double tolerance) {
  for (int k = 0; k < 3; ++k) {
    const double big = std::max(a.size_m[k], b.size_m[k]);
    if (std::abs(a.size_m[k] - b.size_m[k]) > tolerance * big + 0.2) return false;
  }
  return true;
}

/// An added and a removed object of one shape near each other become one moved object, where
/// it stands now.
void PairMoved(const RunComparisonOptions& o, std::vector<RunChange>* placed) {
  std::vector<bool> gone(placed->size(), false);
  for (size_t i = 0; i < placed->size(); ++i) {
    RunChange& added = (*placed)[i];
    if (added.kind != ChangeKind::kAdded) continue;
    size_t best = placed->size();
    double best_d = o.moved_within_m;
    for (size_t j = 0; j < placed->size(); ++j) {
      const RunChange& removed = (*placed)[j];
      if (gone[j] || removed.kind != ChangeKind::kRemoved) continue;
      const double d = (removed.centre_utm - added.centre_utm).head<2>().norm();
      if (d < best_d && SameShape(added, removed, o.moved_size_tolerance)) {
        best = j;
        best_d = d;
      }
    }
    if (best == placed->size()) continue;
    gone[best] = true;
    added.kind = ChangeKind::kMoved;
    added.moved_from_utm = (*placed)[best].centre_utm;
    added.moved_m = best_d;
    added.confidence = std::min(added.confidence, (*placed)[best].confidence);
  }
  size_t k = 0;
  for (size_t i = 0; i < placed->size(); ++i) {
    if (gone[i]) continue;
    if (k != i) (*placed)[k] = std::move((*placed)[i]);
    ++k;
  }
  placed->resize(k);
}

/// The chainage range of poses on the line; false if none lies on it. `chainage_m` (if given)
/// gets each pose's (NaN where off the line).
bool ChainageRange(const MapStore& store,
                   int64_t run,
                   const std::vector<api::StreamPose>& poses,
                   double* first_m,
                   double* last_m,
                   std::vector<double>* chainage_m = nullptr) {
  std::vector<double> chainage;
  if (poses.empty() || !store.ChainageOfPoses(run, poses, &chainage)) return false;
  *first_m = std::numeric_limits<double>::infinity();
  *last_m = -std::numeric_limits<double>::infinity();
  for (double c : chainage) {
    if (std::isnan(c)) continue;
    *first_m = std::min(*first_m, c);
    *last_m = std::max(*last_m, c);
  }
  if (chainage_m) *chainage_m = std::move(chainage);
  return *first_m <= *last_m;
}

/// Whether both runs have at least 1000 points of the stretch (the later run's over all its
/// placements).
bool EnoughPoints(const StretchParts& parts) {
  size_t later_points = 0;
  for (const std::vector<Eigen::Vector3d>& p : parts.later_placements) later_points += p.size();
  return parts.reference.points.size() >= 1000 && later_points >= 1000;
}

/// The rail plane's height below the centreline into `parts` (0 where the rails were not seen)
/// and the registered runs' disagreement on the rails (RailResidual; NaN there).
double MeasureRails(const Stretch& stretch, StretchParts* parts) {
  const double drop = RailDrop(stretch, parts->reference.points);
  parts->rail_drop_m = std::isnan(drop) ? 0.0 : drop;
  return std::isnan(drop)
             ? drop
             : RailResidual(
                   stretch, parts->reference.points, parts->later.points, parts->rail_drop_m);
}

/// The changes of a registered stretch (CompareStretch), placed on the line and checked
/// against the gauge: the catenary's wire pieces dropped, vegetation told and centred on its
/// trunk, moved objects paired. `out` gets the stretch's summary and its rails' RMS.
std::vector<RunChange> FindChanges(const Stretch& stretch,
                                   const RunComparisonOptions& o,
                                   const RegistrationResult& fit,
                                   const std::string& zone,
                                   bool provisional,
                                   StretchParts* parts,
                                   StretchOutcome* out) {
  std::vector<StretchChange> found =
      CompareStretch(parts->reference, parts->later, o.change, &out->summary);
  out->rail_rms_m = MeasureRails(stretch, parts);
  parts->lod_m = LevelOfDetection(o.change, fit.rms_m);
  parts->voxel_m = o.change.voxel_m;
  const StructureGauge gauge(o.clearance);
  std::vector<RunChange> placed;
  for (const StretchChange& c : found) placed.push_back(Place(c, stretch, *parts, gauge, zone));
  // A thin member over the track is the catenary's before it is growth: a tunnel's crown
  // beside a bracket reads as what growth comes out of.
  DropWirePieces(o, &found, &placed, &out->summary);
  MarkVegetation(stretch, *parts, o, found, &placed);
  CentreTrees(stretch, o, found, &placed);
  PairMoved(o, &placed);
  if (provisional) {
    // Provisional output can lack points the final map will have (a LiDAR's gap, a piece not
    // sent yet), so what it does not show is not told gone: removals wait for the final map.
    placed.erase(std::remove_if(placed.begin(),
                                placed.end(),
                                [](const RunChange& c) { return c.kind == ChangeKind::kRemoved; }),
                 placed.end());
  }
  return placed;
}

}  // namespace

bool LiesAcross(const RunChange& c) {
  constexpr double kRailM = 0.7175;  // a rail's centre from the track's (standard gauge, 1435 mm)
  return c.offset_from_m <= -kRailM && c.offset_to_m >= kRailM;
}

const char* SideOf(const RunChange& c) {
  if (LiesAcross(c)) return "across";
  return c.offset_m >= 0.0 ? "left" : "right";
}

const char* ToString(ChangeKind kind) {
  switch (kind) {
    case ChangeKind::kAdded:
      return "added";
    case ChangeKind::kRemoved:
      return "removed";
    case ChangeKind::kMoved:
      return "moved";
    case ChangeKind::kVegetation:
      return "vegetation";
  }
  return "added";
}

bool ParseChangeKind(const std::string& name, ChangeKind* kind) {
  for (ChangeKind k :
       {ChangeKind::kAdded, ChangeKind::kRemoved, ChangeKind::kMoved, ChangeKind::kVegetation})
    if (name == ToString(k)) {
      *kind = k;
      return true;
    }
  return false;
}

bool RunComparisonOptions::IsValid(std::string* error) const {
  if (!(stretch_m >= 10.0 && corridor_m > 0.0 && overlap_m >= 0.0 && look_back_m >= 0.0 &&
        moved_within_m >= 0.0 && moved_size_tolerance >= 0.0 && vegetation_share > 0.0 &&
        vegetation_near_m > 0.0 && trunk_m > 0.0 && wire_zone_half_width_m >= 0.0 &&
        wire_piece_max_m >= 0.0)) {
    *error = "comparison options out of range (stretch_m >= 10, corridor_m > 0, ...)";
    return false;
  }
  return change.IsValid(error) && clearance.IsValid(error) && registration.IsValid(error);
}

bool CatenaryWirePiece(const RunChange& c, const RunComparisonOptions& o) {
  // A member in any direction: a wire along the track, a dropper or a bracket upright.
  std::array<double, 3> sides = {c.size_m.x(), c.size_m.y(), c.size_m.z()};
  std::sort(sides.begin(), sides.end());
  const double thin = o.change.thin_m + 1e-9;
  return (c.kind == ChangeKind::kAdded || c.kind == ChangeKind::kRemoved) &&
         std::abs(c.offset_m) <= o.wire_zone_half_width_m &&
         c.height_above_rail_min_m >= o.wire_zone_above_rail_m && sides[1] <= thin &&
         sides[2] <= o.wire_piece_max_m;
}

RunComparison::RunComparison(const MapStore& store, const RunComparisonOptions& options)
    : store_(store), options_(options) {}

Result RunComparison::Prepare(const MapStore& store,
                              int64_t reference_run,
                              int64_t later_run,
                              const RunComparisonOptions& o,
                              std::unique_ptr<RunComparison>* out,
                              const ProvisionalRun* provisional) {
  std::string error;
  if (!o.IsValid(&error)) return Fail(Outcome::kInvalid, error);
  if (reference_run == later_run)
    return Fail(Outcome::kInvalid, "a run cannot be compared with itself");
  std::unique_ptr<RunComparison> c(new RunComparison(store, o));
  Result r = c->ReadRuns(reference_run, later_run);
  if (!r) return r;
  double ref_first = 0.0, ref_last = 0.0;
  r = c->ReadReach(reference_run, later_run, &ref_first, &ref_last);
  if (!r) return r;
  c->TakeProvisional(provisional, later_run, ref_first, ref_last);
  c->CutStretches();
  *out = std::move(c);
  return {};
}

Result RunComparison::ReadRuns(int64_t reference_run, int64_t later_run) {
  Result r = store_.GetRun(later_run, &later_);
  if (!r) return r;
  r = store_.GetRun(reference_run, &reference_);
  if (!r) return Fail(r.outcome, "reference: " + r.message);
  if (reference_.line != later_.line)
    return Fail(Outcome::kInvalid,
                "run " + std::to_string(later_run) + " is of line '" + later_.line + "', run " +
                    std::to_string(reference_run) + " of '" + reference_.line + "'");
  if (reference_.status != "finished")
    return Fail(Outcome::kConflict,
                "the reference run " + std::to_string(reference_run) + " is still live");
  if (!later_.utm_zone.empty() && reference_.utm_zone != later_.utm_zone)
    return Fail(Outcome::kInvalid,
                "the runs lie in different UTM zones (" + reference_.utm_zone + " and " +
                    later_.utm_zone + ")");
  r = store_.GetLine(reference_.line, &line_);
  if (!r) return r;
  if (line_.reference_run == 0)
    return Fail(Outcome::kConflict, "line '" + line_.name + "' has no centreline yet");
  r = store_.Trajectory(reference_run, &reference_poses_);
  if (r) r = store_.Trajectory(later_run, &later_poses_);
  return r;
}

Result RunComparison::ReadReach(int64_t reference_run,
                                int64_t later_run,
                                double* ref_first_m,
                                double* ref_last_m) {
  double first = 0.0, last = 0.0;
  if (!ChainageRange(store_, reference_run, reference_poses_, ref_first_m, ref_last_m))
    return Fail(Outcome::kInvalid,
                "the reference run " + std::to_string(reference_run) +
                    " has no pose on the line's centreline");
  later_reach_m_ = -std::numeric_limits<double>::infinity();
  if (ChainageRange(store_, later_run, later_poses_, &first, &last, &later_chainage_m_)) {
    if (last < *ref_first_m || first > *ref_last_m)
      return Fail(Outcome::kInvalid,
                  "runs " + std::to_string(later_run) + " and " + std::to_string(reference_run) +
                      " do not overlap along the line");
    later_reach_m_ = last;
  } else if (!later_poses_.empty() && later_.status == "finished") {
    return Fail(Outcome::kInvalid,
                "run " + std::to_string(later_run) + " has no pose on line '" + line_.name +
                    "''s centreline: it does not overlap the reference");
  }
  return {};
}

void RunComparison::TakeProvisional(const ProvisionalRun* provisional,
                                    int64_t later_run,
                                    double ref_first_m,
                                    double ref_last_m) {
  if (!provisional || provisional->utm_zone != reference_.utm_zone ||
      (!later_.utm_zone.empty() && later_.utm_zone != provisional->utm_zone))
    return;
  provisional_ = *provisional;
  double first = 0.0;
  if (ChainageRange(store_,
                    later_run,
                    provisional_.poses,
                    &first,
                    &provisional_reach_m_,
                    &provisional_chainage_m_) &&
      (provisional_reach_m_ < ref_first_m || first > ref_last_m))
    provisional_reach_m_ = -std::numeric_limits<double>::infinity();
}

void RunComparison::CutStretches() {
  const RunComparisonOptions& o = options_;
  const double start = line_.chainage_offset_m, end = start + line_.length_m;
  for (int i = 0; start + i * o.stretch_m < end; ++i) {
    StretchRange s{i, start + i * o.stretch_m, std::min(start + (i + 1) * o.stretch_m, end)};
    s.from_m = std::max(s.from_m, o.from_m);
    s.to_m = std::min(s.to_m, o.to_m);
    if (s.from_m < s.to_m) stretches_.push_back(s);
  }
}

double RunComparison::ReachUntil(int64_t stamp_ns, bool provisional) const {
  double reach = -std::numeric_limits<double>::infinity();
  auto extend = [&](const std::vector<api::StreamPose>& poses,
                    const std::vector<double>& chainage) {
    for (size_t i = 0; i < chainage.size(); ++i)
      if (poses[i].stamp_ns <= stamp_ns && !std::isnan(chainage[i]))
        reach = std::max(reach, chainage[i]);
  };
  extend(later_poses_, later_chainage_m_);
  if (provisional) extend(provisional_.poses, provisional_chainage_m_);
  return reach;
}

Result RunComparison::Compare(const StretchRange& range,
                              StretchOutcome* out,
                              bool provisional) const {
  const auto t0 = std::chrono::steady_clock::now();
  const RunComparisonOptions& o = options_;
  *out = StretchOutcome();
  out->range = range;
  out->provisional = provisional;
  TrackSegment segment;
  if (!store_.Segment(line_.name, range.from_m, range.to_m, &segment) ||
      segment.samples.size() < 2) {
    out->skipped = "too short a piece of centreline";
    return {};
  }
  if (reference_.id != line_.reference_run) OntoPath(reference_poses_, &segment.samples);
  const Stretch stretch(std::move(segment.samples));
  out->origin = stretch.origin();
  StretchParts parts;
  const Result r = LoadParts(store_,
                             stretch,
                             o,
                             {reference_.id, &reference_poses_},
                             {later_.id, &later_poses_, provisional ? &provisional_ : nullptr},
                             &parts);
  if (!r) return r;
  if (!EnoughPoints(parts)) {
    out->skipped = "fewer than 1000 points of a run there";
    return {};
  }
  // The later run onto the reference, from where its path lies off the reference's.
  const RegistrationResult fit = RegisterLater(stretch, o, &parts);
  out->registration_rms_m = fit.rms_m;
  if (!(fit.rms_m <= o.max_registration_rms_m)) {
    // Compared misregistered, everything would differ: better none than a field of false
    // changes.
    out->skipped = "the runs did not register (RMS " + std::to_string(fit.rms_m) + " m)";
    return {};
  }
  out->compared = true;
  out->T_reference_later = fit.T_fixed_moving;
  std::vector<RunChange> placed =
      FindChanges(stretch, o, fit, reference_.utm_zone, provisional, &parts, out);
  KeepOwn(range, std::move(placed), out);
  out->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return {};
}

void RunComparison::KeepOwn(const StretchRange& range,
                            std::vector<RunChange> placed,
                            StretchOutcome* out) const {
  const double line_start = line_.chainage_offset_m, line_end = line_start + line_.length_m;
  const bool first = range.from_m <= line_start + 1e-6, last = range.to_m >= line_end - 1e-6;
  for (RunChange& c : placed) {
    // The later run's points reach a metre beyond the reference's every way: what lies beyond
    // the corridor there has nothing of the reference to compare with; an object centred in
    // the overlap with the next or previous stretch is that stretch's.
    if (std::abs(c.offset_m) > options_.corridor_m || (c.chainage_m < range.from_m && !first) ||
        (c.chainage_m >= range.to_m && !last))
      continue;
    // What is gone cannot be in the way: only what is there now intrudes.
    c.intrudes_envelope = c.kind != ChangeKind::kRemoved && c.margin_m < 0.0;
    c.stretch = range.index;
    out->changes.push_back(std::move(c));
  }
}

Result CompareRuns(const MapStore& store,
                   int64_t reference_run,
                   int64_t later_run,
                   const RunComparisonOptions& options,
                   std::vector<RunChange>* changes,
                   RunComparisonSummary* summary,
                   const std::function<Result(const StretchOutcome&)>& each_stretch) {
  changes->clear();
  *summary = RunComparisonSummary();
  std::unique_ptr<RunComparison> comparison;
  Result r = RunComparison::Prepare(store, reference_run, later_run, options, &comparison);
  if (!r) return r;
  double rms_sq = 0.0, rail_sq = 0.0;
  size_t rails = 0;
  for (const StretchRange& range : comparison->stretches()) {
    ++summary->stretches;
    StretchOutcome outcome;
    r = comparison->Compare(range, &outcome);
    if (r && each_stretch) r = each_stretch(outcome);
    if (!r) return r;
    if (!outcome.compared) continue;
    for (RunChange& c : outcome.changes) changes->push_back(std::move(c));
    ++summary->stretches_compared;
    summary->km += (range.to_m - range.from_m) / 1000.0;
    summary->objects += outcome.summary.objects;
    summary->not_observed += outcome.summary.not_observed;
    rms_sq += outcome.registration_rms_m * outcome.registration_rms_m;
    if (!std::isnan(outcome.rail_rms_m)) {
      rail_sq += outcome.rail_rms_m * outcome.rail_rms_m;
      ++rails;
    }
  }
  if (summary->stretches_compared > 0)
    summary->registration_rms_m = std::sqrt(rms_sq / summary->stretches_compared);
  if (rails > 0) summary->rail_rms_m = std::sqrt(rail_sq / rails);
  return {};
}

}  // namespace raillomer::mapstore
