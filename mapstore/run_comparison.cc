#include "mapstore/run_comparison.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace raillomer::mapstore {
namespace {

Result Fail(Outcome outcome, std::string message) { return {outcome, std::move(message)}; }

/// The stretch's centreline: chainage to position, direction and the geometry around it.
class Stretch {
 public:
  explicit Stretch(std::vector<TrackSample> samples) : samples_(std::move(samples)) {}

  const Eigen::Vector3d& origin() const { return samples_.front().point.p; }
  double first_m() const { return samples_.front().point.chainage_m; }
  double last_m() const { return samples_.back().point.chainage_m; }

  /// The sample nearest `p` (horizontal) and `p`'s signed offset from the centre (positive
  /// left of increasing chainage) and its distance along from that sample.
  const TrackSample& Nearest(const Eigen::Vector3d& p, double* offset_m, double* along_m) const {
    size_t best = 0;
    double best_d = std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < samples_.size(); ++i) {
      const double d = (samples_[i].point.p - p).head<2>().squaredNorm();
      if (d < best_d) {
        best_d = d;
        best = i;
      }
    }
    const Eigen::Vector2d t = Tangent(best);
    const Eigen::Vector2d d = (p - samples_[best].point.p).head<2>();
    *offset_m = t.x() * d.y() - t.y() * d.x();
    *along_m = t.dot(d);
    return samples_[best];
  }

  /// The horizontal unit direction of increasing chainage at sample i.
  Eigen::Vector2d Tangent(size_t i) const {
    const size_t a = i > 0 ? i - 1 : 0, b = std::min(i + 1, samples_.size() - 1);
    const Eigen::Vector2d d = (samples_[b].point.p - samples_[a].point.p).head<2>();
    return d.norm() > 0.0 ? Eigen::Vector2d(d.normalized()) : Eigen::Vector2d::UnitX();
  }

  /// Points within `corridor_m` of the centreline, in the stretch's frame (UTM minus origin).
  std::vector<Eigen::Vector3d> Local(const std::vector<Eigen::Vector3d>& utm,
                                     double corridor_m) const {
    std::vector<Eigen::Vector3d> out;
    for (const Eigen::Vector3d& p : utm) {
      double offset = 0.0, along = 0.0;
      Nearest(p, &offset, &along);
      if (std::abs(offset) <= corridor_m && std::abs(along) <= 1.0) out.push_back(p - origin());
    }
    return out;
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
};

/// A run's level-0 points in a UTM box.
Result PointsIn(const MapStore& store,
                int64_t run,
                const Eigen::AlignedBox2d& box,
                std::vector<Eigen::Vector3d>* out) {
  out->clear();
  ExportRequest request;
  request.run_id = run;
  request.has_box = true;
  request.box = box;
  request.max_points = 100'000'000;
  std::unique_ptr<ExportCursor> cursor;
  Result r = store.PrepareExport(request, &cursor);
  if (!r) return r;
  std::vector<ExportPoint> points;
  while (!cursor->done()) {
    r = cursor->Next(&points);
    if (!r) return r;
    for (const ExportPoint& p : points) out->push_back(p.p);
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

/// A change of a stretch placed on the line and checked against the gauge.
RunChange Place(const StretchChange& c,
                const Stretch& stretch,
                double rail_drop_m,
                const StructureGauge& gauge,
                const std::string& zone) {
  RunChange out;
  out.kind = c.kind;
  out.utm_zone = zone;
  out.voxels = c.voxels.size();
  out.seen_empty_share = c.seen_empty_share;
  out.centre_utm = c.centre + stretch.origin();
  double offset = 0.0, along = 0.0;
  const TrackSample& at = stretch.Nearest(out.centre_utm, &offset, &along);
  out.chainage_m = at.point.chainage_m + along;
  out.offset_m = offset;
  out.margin_m = std::numeric_limits<double>::infinity();
  out.height_above_rail_min_m = std::numeric_limits<double>::infinity();
  out.height_above_rail_max_m = -std::numeric_limits<double>::infinity();
  Eigen::AlignedBox3d extent;  // along, across, up
  for (const Eigen::Vector3d& v : c.voxels) {
    const Eigen::Vector3d p = v + stretch.origin();
    double o = 0.0, a = 0.0;
    const TrackSample& s = stretch.Nearest(p, &o, &a);
    const TrackSection section{s.point.p.z() + rail_drop_m, s.point.cant_m, s.curvature_per_m};
    const SectionPoint q = ToSection(section, o, p.z());
    out.margin_m = std::min(out.margin_m, gauge.Margin(section, q));
    out.height_above_rail_min_m = std::min(out.height_above_rail_min_m, q.height_m);
    out.height_above_rail_max_m = std::max(out.height_above_rail_max_m, q.height_m);
    extent.extend(Eigen::Vector3d(s.point.chainage_m + a, o, p.z()));
  }
  out.size_m = extent.sizes();
  // What is gone cannot be in the way: only what is there now intrudes.
  out.intrudes_envelope = c.kind == StretchChange::Kind::kAdded && out.margin_m < 0.0;
  return out;
}

}  // namespace

Result CompareRuns(const MapStore& store,
                   int64_t reference_run,
                   int64_t later_run,
                   const RunComparisonOptions& o,
                   std::vector<RunChange>* changes,
                   RunComparisonSummary* summary,
                   const std::function<void(double)>& progress) {
  changes->clear();
  *summary = RunComparisonSummary();
  RunInfo reference, later;
  Result r = store.GetRun(reference_run, &reference);
  if (r) r = store.GetRun(later_run, &later);
  if (!r) return r;
  if (reference.line != later.line)
    return Fail(Outcome::kInvalid,
                "run " + std::to_string(later_run) + " is of line '" + later.line + "', run " +
                    std::to_string(reference_run) + " of '" + reference.line + "'");
  if (reference.utm_zone != later.utm_zone)
    return Fail(Outcome::kInvalid, "the runs lie in different UTM zones");
  LineInfo line;
  r = store.GetLine(reference.line, &line);
  if (!r) return r;
  std::vector<api::StreamPose> reference_poses, later_poses;
  r = store.Trajectory(reference_run, &reference_poses);
  if (r) r = store.Trajectory(later_run, &later_poses);
  if (!r) return r;
  const StructureGauge gauge(o.clearance);
  double rms_sq = 0.0;
  const double first = std::max(line.chainage_offset_m, o.from_m);
  const double last = std::min(line.chainage_offset_m + line.length_m, o.to_m);
  for (double from = first; from < last; from += o.stretch_m) {
    ++summary->stretches;
    TrackSegment segment;
    if (!store.Segment(line.name, from, std::min(from + o.stretch_m, last), &segment) ||
        segment.samples.size() < 2)
      continue;
    const Stretch stretch(std::move(segment.samples));
    std::vector<Eigen::Vector3d> utm;
    RunStretch ref_part, later_part;
    r = PointsIn(store, reference_run, stretch.Box(o.corridor_m), &utm);
    if (!r) return r;
    ref_part.points = stretch.Local(utm, o.corridor_m);
    r = PointsIn(store, later_run, stretch.Box(o.corridor_m + 5.0), &utm);
    if (!r) return r;
    later_part.points = stretch.Local(utm, o.corridor_m + 5.0);
    const Eigen::AlignedBox2d seen_from = stretch.Box(o.look_back_m);
    ref_part.sensors = SensorsIn(reference_poses, seen_from, stretch.origin());
    later_part.sensors = SensorsIn(later_poses, seen_from, stretch.origin());
    if (ref_part.points.size() < 1000 || later_part.points.size() < 1000) continue;
    // The later run onto the reference: its points and its sensors.
    const RegistrationResult fit = RegisterClouds(
        ref_part.points, later_part.points, Eigen::Isometry3d::Identity(), o.registration);
    for (Eigen::Vector3d& p : later_part.points) p = fit.T_fixed_moving * p;
    for (Eigen::Isometry3d& s : later_part.sensors) s = fit.T_fixed_moving * s;
    StretchSummary stretch_summary;
    const std::vector<StretchChange> found =
        CompareStretch(ref_part, later_part, o.change, &stretch_summary);
    const double drop = RailDrop(stretch, ref_part.points);
    for (const StretchChange& c : found) {
      RunChange placed =
          Place(c, stretch, std::isnan(drop) ? 0.0 : drop, gauge, reference.utm_zone);
      // The later run's points reach 5 m further out (room for the registration's shift):
      // what lies beyond the corridor there has nothing of the reference to compare with.
      if (std::abs(placed.offset_m) <= o.corridor_m) changes->push_back(std::move(placed));
    }
    ++summary->stretches_compared;
    summary->km += (stretch.last_m() - stretch.first_m()) / 1000.0;
    summary->objects += stretch_summary.objects;
    summary->not_observed += stretch_summary.not_observed;
    rms_sq += fit.rms_m * fit.rms_m;
    if (progress) progress(stretch.last_m());
  }
  if (summary->stretches_compared > 0)
    summary->registration_rms_m = std::sqrt(rms_sq / summary->stretches_compared);
  return {};
}

}  // namespace raillomer::mapstore
