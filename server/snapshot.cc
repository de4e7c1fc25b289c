#include "server/snapshot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "server/canvas.h"

namespace raillomer::server {
namespace {

using mapstore::Result;

constexpr Rgb kWhite{255, 255, 255}, kInk{40, 40, 40}, kGrid{225, 225, 225};
constexpr Rgb kBefore{60, 110, 210}, kAfter{240, 120, 20}, kChange{220, 20, 30},
    kGauge{20, 150, 60};
constexpr int kPanel = 420, kHeader = 52, kFooter = 24;

/// The track frame at the change: along (increasing chainage), left, up; heights above the
/// rail plane.
struct TrackFrame {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  ///< the centreline at the change
  Eigen::Vector2d along = Eigen::Vector2d::UnitX(), left = Eigen::Vector2d::UnitY();
  mapstore::TrackSection section;

  /// along, lateral (left positive), height above the rail plane (cant-tilted section).
  Eigen::Vector3d Of(const Eigen::Vector3d& p) const {
    const Eigen::Vector2d d = (p - origin).head<2>();
    const mapstore::SectionPoint q = ToSection(section, left.dot(d), p.z());
    return {along.dot(d), q.lateral_m, q.height_m};
  }
};

/// The track frame from the line's centreline around the change, moved across to the track the
/// change's offset was measured from; the rail plane from the
/// reference's rail heads (the highest points 0.6-0.85 m either side, below the body's path).
Result FrameAt(const mapstore::MapStore& store,
               const mapstore::StoredChange& s,
               const std::vector<mapstore::ExportPoint>& reference,
               TrackFrame* f) {
  mapstore::TrackSegment segment;
  const Result r =
      store.Segment(s.line, s.change.chainage_m - 3.0, s.change.chainage_m + 3.0, &segment);
  if (!r) return r;
  if (segment.samples.size() < 2)
    return {mapstore::Outcome::kNotFound, "no centreline around the change"};
  const double at = s.change.chainage_m;
  const mapstore::TrackSample* mid = &segment.samples.front();
  for (const mapstore::TrackSample& t : segment.samples)
    if (std::abs(t.point.chainage_m - at) < std::abs(mid->point.chainage_m - at)) mid = &t;
  const Eigen::Vector2d d =
      (segment.samples.back().point.p - segment.samples.front().point.p).head<2>();
  f->along = d.normalized();
  f->left = Eigen::Vector2d(-f->along.y(), f->along.x());
  f->origin = mid->point.p +
              (at - mid->point.chainage_m) * Eigen::Vector3d(f->along.x(), f->along.y(), 0.0);
  // Across onto the track the change was measured from: a run compared with other than the
  // line's reference has its own map, off the line's centreline by its GNSS error.
  const double centre_lateral = f->left.dot((s.change.centre_utm - f->origin).head<2>());
  f->origin.head<2>() += (centre_lateral - s.change.offset_m) * f->left;
  std::vector<double> heads;
  for (const mapstore::ExportPoint& p : reference) {
    const Eigen::Vector2d q = (p.p - f->origin).head<2>();
    const double lateral = std::abs(f->left.dot(q)), dz = p.p.z() - f->origin.z();
    if (lateral >= 0.6 && lateral <= 0.85 && std::abs(f->along.dot(q)) < 6.0 && dz < -0.5)
      heads.push_back(dz);
  }
  std::sort(heads.begin(), heads.end());
  const double drop = heads.size() >= 10 ? heads[heads.size() * 9 / 10] : -2.0;
  f->section = {f->origin.z() + drop, mid->point.cant_m, mid->curvature_per_m};
  return {};
}

/// A panel's window onto metres: x and y ranges fitted into the panel at one scale.
struct Window {
  int left = 0, top = 0;
  double x0 = 0, y0 = 0, scale = 1;  ///< metres at the panel's left, bottom; pixels per metre
  bool flip_x = false;
  int X(double x) const {
    const double u = flip_x ? -x - x0 : x - x0;
    return left + static_cast<int>(std::lround(u * scale));
  }
  int Y(double y) const { return top + kPanel - static_cast<int>(std::lround((y - y0) * scale)); }
};

Window Fit(int left, double x_min, double x_max, double y_min, double y_max, bool flip_x) {
  Window w;
  w.left = left;
  w.top = kHeader;
  w.flip_x = flip_x;
  w.scale = std::min(kPanel / (x_max - x_min), kPanel / (y_max - y_min));
  const double cx = flip_x ? -0.5 * (x_min + x_max) : 0.5 * (x_min + x_max);
  w.x0 = cx - 0.5 * kPanel / w.scale;
  w.y0 = 0.5 * (y_min + y_max) - 0.5 * kPanel / w.scale;
  return w;
}

/// Grid lines every metre (every 5 m darker) over a panel; the 5 m lines are numbered in
/// metres along the panel's bottom and left edges, so that distances can be read off.
void Grid(Canvas& c, const Window& w) {
  for (int m = -200; m <= 200; ++m) {
    const Rgb colour = m % 5 == 0 ? Rgb{200, 200, 200} : kGrid;
    const int x = w.X(m), y = w.Y(m);
    if (x > w.left && x < w.left + kPanel) c.Line(x, w.top, x, w.top + kPanel, colour);
    if (y > w.top && y < w.top + kPanel) c.Line(w.left, y, w.left + kPanel, y, colour);
  }
  for (int m = -200; m <= 200; m += 5) {
    const std::string label = std::to_string(m);
    const int x = w.X(m) + 2, y = w.Y(m) - 8;
    if (x > w.left + 10 && x + Canvas::TextWidth(label) < w.left + kPanel)
      c.Text(x, w.top + kPanel - 9, label, kInk);
    if (y > w.top && y < w.top + kPanel - 20) c.Text(w.left + 2, y, label, kInk);
  }
}

void Points(Canvas& c,
            const Window& w,
            const std::vector<Eigen::Vector3d>& track_points,
            int x_axis,
            int y_axis,
            const Eigen::AlignedBox3d& keep,
            Rgb colour) {
  for (const Eigen::Vector3d& p : track_points) {
    if (!keep.contains(p)) continue;
    const int x = w.X(p[x_axis]), y = w.Y(p[y_axis]);
    if (x >= w.left && x < w.left + kPanel && y >= w.top && y < w.top + kPanel)
      c.Dot(x, y, 0, colour);
  }
}

std::string Format(const char* format, double a, double b = 0.0, double c = 0.0) {
  char text[160];
  std::snprintf(text, sizeof(text), format, a, b, c);
  return text;
}

/// The run's points in a UTM box; the later run's moved where the comparison registered it.
Result Load(const mapstore::MapStore& store,
            int64_t run,
            const Eigen::AlignedBox2d& box,
            const mapstore::StretchFrame* frame,
            std::vector<mapstore::ExportPoint>* out) {
  mapstore::ExportRequest request;
  request.run_id = run;
  request.has_box = true;
  request.box = box;
  request.max_points = 5'000'000;
  std::string zone;
  const Result r = store.Export(request, out, &zone);
  if (!r || !frame) return r;
  for (mapstore::ExportPoint& p : *out)
    p.p = frame->T_reference_later * (p.p - frame->origin) + frame->origin;
  return {};
}

/// What a snapshot shows, in the track frame at the change: both runs' points, where the
/// change is, and how far the panels reach.
struct Scene {
  TrackFrame track;
  std::vector<Eigen::Vector3d> before, after;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double half_along = 0.0, lateral_min = 0.0, lateral_max = 0.0, top = 0.0;
};

/// Both runs' points around the change (the later where the comparison registered it), and
/// the track frame there.
Result LoadScene(const mapstore::MapStore& store,
                 const mapstore::ChangeStore& changes,
                 const mapstore::StoredChange& s,
                 Scene* scene) {
  const mapstore::RunChange& c = s.change;
  mapstore::StretchFrame frame;
  Result r = changes.Frame(s.run_id, c.stretch, &frame);
  if (!r) return r;
  scene->half_along = std::max(6.0, 0.5 * c.size_m.x() + 4.0);
  scene->lateral_min = std::min(-3.5, c.offset_m - 0.5 * c.size_m.y() - 2.0);
  scene->lateral_max = std::max(3.5, c.offset_m + 0.5 * c.size_m.y() + 2.0);
  scene->top = std::max(8.0, c.height_above_rail_max_m + 1.5);
  const double reach =
      std::max(scene->half_along, std::max(-scene->lateral_min, scene->lateral_max)) + 2.0;
  const Eigen::AlignedBox2d box(c.centre_utm.head<2>().array() - reach,
                                c.centre_utm.head<2>().array() + reach);
  std::vector<mapstore::ExportPoint> before, after;
  r = Load(store, s.reference_run, box, nullptr, &before);
  if (r) r = Load(store, s.run_id, box, &frame, &after);
  if (r) r = FrameAt(store, s, before, &scene->track);
  if (!r) return r;
  for (const mapstore::ExportPoint& p : before) scene->before.push_back(scene->track.Of(p.p));
  for (const mapstore::ExportPoint& p : after) scene->after.push_back(scene->track.Of(p.p));
  scene->centre = scene->track.Of(c.centre_utm);
  return {};
}

/// The structure gauge: its outline in the section, its widest lateral reach in the plan; and
/// the track centre, dashed.
void DrawGauge(Canvas& canvas,
               const Window& plan,
               const Window& section,
               const std::vector<Eigen::Vector2d>& outline,
               double top) {
  double gauge_left = 0.0, gauge_right = 0.0;
  for (size_t i = 0; i < outline.size(); ++i) {
    const Eigen::Vector2d& a = outline[i];
    const Eigen::Vector2d& b = outline[(i + 1) % outline.size()];
    canvas.Line(section.X(a.x()), section.Y(a.y()), section.X(b.x()), section.Y(b.y()), kGauge);
    gauge_left = std::max(gauge_left, a.x());
    gauge_right = std::min(gauge_right, a.x());
  }
  for (double lateral : {gauge_left, gauge_right})
    canvas.Line(plan.left, plan.Y(lateral), plan.left + kPanel, plan.Y(lateral), kGauge);
  canvas.Line(plan.left, plan.Y(0.0), plan.left + kPanel, plan.Y(0.0), kInk, 4);
  canvas.Line(section.X(0.0), section.Y(-1.5), section.X(0.0), section.Y(top), kInk, 4);
}

/// The change's extent along, across and up, around its centre, in both panels.
void DrawChange(Canvas& canvas,
                const Window& plan,
                const Window& section,
                const mapstore::RunChange& c,
                const Eigen::Vector3d& centre) {
  const double ax = 0.5 * c.size_m.x(), ay = 0.5 * c.size_m.y();
  canvas.Rect(plan.X(centre.x() - ax),
              plan.Y(c.offset_m + ay),
              plan.X(centre.x() + ax),
              plan.Y(c.offset_m - ay),
              kChange);
  canvas.Rect(section.X(c.offset_m + ay),
              section.Y(c.height_above_rail_max_m),
              section.X(c.offset_m - ay),
              section.Y(c.height_above_rail_min_m),
              kChange);
}

/// Where across the track, as the title says it: "2.3 M LEFT", or "ACROSS 5.7 M R - 10.3 M L".
std::string PlaceWords(const mapstore::RunChange& c) {
  if (mapstore::LiesAcross(c))
    return Format("ACROSS %.1f M ", std::abs(c.offset_from_m)) +
           (c.offset_from_m >= 0.0 ? "L" : "R") + Format(" - %.1f M ", std::abs(c.offset_to_m)) +
           (c.offset_to_m >= 0.0 ? "L" : "R");
  return Format("%.1f M ", std::abs(c.offset_m)) + (c.offset_m >= 0.0 ? "LEFT" : "RIGHT");
}

/// What and where (the title), the panels' names and the legend.
void DrawWords(Canvas& canvas, const Window& section, const mapstore::StoredChange& s) {
  const mapstore::RunChange& c = s.change;
  const std::string title =
      std::string(mapstore::ToString(c.kind)) + " #" + std::to_string(s.id) +
      Format("  KM %.3f  ", c.chainage_m / 1000.0) + PlaceWords(c) +
      (c.intrudes_envelope ? "  INTRUDES THE GAUGE" : "") +
      (std::isfinite(c.margin_m) ? Format("  MARGIN %.2f M", c.margin_m) : "");
  // Twice the size where it fits across the picture, else at the legend's size.
  const int scale = 10 + Canvas::TextWidth(title, 2) <= canvas.width() - 10 ? 2 : 1;
  canvas.Text(10, scale == 2 ? 8 : 12, title, c.intrudes_envelope ? kChange : kInk, scale);
  canvas.Text(10, 32, "PLAN (ALONG ->, LEFT UP)", kInk);
  canvas.Text(section.left, 32, "SECTION (LOOKING ALONG, HEIGHT ABOVE RAIL)", kInk);
  const int y = kHeader + kPanel + 8;
  canvas.Fill(10, y, 20, y + 7, kBefore);
  canvas.Text(26, y, "BEFORE: RUN " + std::to_string(s.reference_run), kInk);
  canvas.Fill(170, y, 180, y + 7, kAfter);
  canvas.Text(186, y, "AFTER: RUN " + std::to_string(s.run_id), kInk);
  canvas.Fill(330, y, 340, y + 7, kGauge);
  canvas.Text(346, y, "GAUGE", kInk);
  canvas.Text(420,
              y,
              Format("GRID 1 M, NUMBERED IN M   SIZE %.1f X %.1f X %.1f M",
                     c.size_m.x(),
                     c.size_m.y(),
                     c.size_m.z()),
              kInk);
}

}  // namespace

Result RenderSnapshot(const mapstore::MapStore& store,
                      const mapstore::ChangeStore& changes,
                      const mapstore::StoredChange& s,
                      const mapstore::ClearanceOptions& clearance,
                      std::string* png) {
  Scene scene;
  const Result r = LoadScene(store, changes, s, &scene);
  if (!r) return r;
  const Eigen::Vector3d& centre = scene.centre;
  Canvas canvas(2 * kPanel + 30, kHeader + kPanel + kFooter, kWhite);
  // Plan: along to the right, left side up, everything above a metre below the rails.
  const Window plan = Fit(10,
                          centre.x() - scene.half_along,
                          centre.x() + scene.half_along,
                          scene.lateral_min,
                          scene.lateral_max,
                          false);
  // Section: seen along increasing chainage, so the track's left is on the picture's left;
  // the points of a slab as long as the change.
  const Window section =
      Fit(kPanel + 20, scene.lateral_min, scene.lateral_max, -1.5, scene.top, true);
  Grid(canvas, plan);
  Grid(canvas, section);
  const double half_slab = 0.5 * s.change.size_m.x() + 0.3;
  const Eigen::AlignedBox3d plan_keep(Eigen::Vector3d(-1e9, -1e9, -1.0),
                                      Eigen::Vector3d(1e9, 1e9, 1e9));
  const Eigen::AlignedBox3d slab(Eigen::Vector3d(centre.x() - half_slab, -1e9, -1e9),
                                 Eigen::Vector3d(centre.x() + half_slab, 1e9, 1e9));
  Points(canvas, plan, scene.before, 0, 1, plan_keep, kBefore);
  Points(canvas, plan, scene.after, 0, 1, plan_keep, kAfter);
  Points(canvas, section, scene.before, 1, 2, slab, kBefore);
  Points(canvas, section, scene.after, 1, 2, slab, kAfter);
  DrawGauge(canvas,
            plan,
            section,
            mapstore::StructureGauge(clearance).Outline(scene.track.section),
            scene.top);
  DrawChange(canvas, plan, section, s.change, centre);
  for (const Window* w : {&plan, &section})
    canvas.Rect(w->left, w->top, w->left + kPanel, w->top + kPanel, kInk);
  DrawWords(canvas, section, s);
  *png = canvas.Png();
  return {};
}

}  // namespace raillomer::server
