#include "mapstore/clearance.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "mapstore/chainage.h"

namespace raillomer::mapstore {
namespace {

/// The distance from `p` to the segment a-b.
double SegmentDistance(const Eigen::Vector2d& p,
                       const Eigen::Vector2d& a,
                       const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double t =
      ab.squaredNorm() > 0.0 ? std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
  return (p - (a + t * ab)).norm();
}

/// True if `p` lies inside the polygon (even-odd rule).
bool Inside(const std::vector<Eigen::Vector2d>& polygon, const Eigen::Vector2d& p) {
  bool inside = false;
  for (size_t i = 0, j = polygon.size() - 1; i < polygon.size(); j = i++) {
    const Eigen::Vector2d& a = polygon[i];
    const Eigen::Vector2d& b = polygon[j];
    if ((a.y() > p.y()) != (b.y() > p.y()) &&
        p.x() < (b.x() - a.x()) * (p.y() - a.y()) / (b.y() - a.y()) + a.x())
      inside = !inside;
  }
  return inside;
}

}  // namespace

bool ClearanceOptions::IsValid(std::string* error) const {
  if (gauge_outline.size() < 3) return *error = "the gauge outline needs at least 3 corners", false;
  for (const Eigen::Vector2d& c : gauge_outline)
    if (!c.allFinite()) return *error = "the gauge outline's corners must be numbers", false;
  if (!(widen_below_radius_m >= 0.0)) return *error = "widen_below_radius_m must be >= 0", false;
  if (!(vegetation_zone_m >= 0.0 && vegetation_allowance_m >= 0.0))
    return *error = "vegetation_zone_m and vegetation_allowance_m must be >= 0", false;
  return true;
}

SectionPoint ToSection(const TrackSection& section, double horizontal_offset_m, double z_m) {
  // The rail plane is turned about the track direction by the cant: left side up for a
  // positive cant.
  const double s = std::clamp(section.cant_m / kRailHeadSpacingM, -1.0, 1.0);
  const double c = std::sqrt(1.0 - s * s);
  const double dz = z_m - section.rail_height_m;
  return {c * horizontal_offset_m + s * dz, -s * horizontal_offset_m + c * dz};
}

std::vector<Eigen::Vector2d> StructureGauge::Outline(const TrackSection& section) const {
  std::vector<Eigen::Vector2d> outline = options_.gauge_outline;
  const double radius = std::abs(section.curvature_per_m) > 0.0
                            ? 1.0 / std::abs(section.curvature_per_m)
                            : std::numeric_limits<double>::infinity();
  if (!(radius < options_.widen_below_radius_m)) return outline;
  // The inside of the curve is the side it turns to.
  const double inside_sign = section.curvature_per_m > 0.0 ? 1.0 : -1.0;
  for (Eigen::Vector2d& corner : outline) {
    const bool inside = corner.x() * inside_sign > 0.0;
    const double widen_m = (inside ? 40.5 : 44.0) / radius;
    corner.x() += (corner.x() >= 0.0 ? 1.0 : -1.0) * widen_m;
  }
  return outline;
}

double StructureGauge::Margin(const TrackSection& section, const SectionPoint& point) const {
  const std::vector<Eigen::Vector2d> outline = Outline(section);
  const Eigen::Vector2d p(point.lateral_m, point.height_m);
  double nearest = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < outline.size(); ++i)
    nearest = std::min(nearest, SegmentDistance(p, outline[i], outline[(i + 1) % outline.size()]));
  return Inside(outline, p) ? -nearest : nearest;
}

double StructureGauge::VegetationMargin(const SectionPoint& point) const {
  const double distance = std::abs(point.lateral_m);
  if (distance >= options_.vegetation_zone_m) return std::numeric_limits<double>::infinity();
  return (distance - options_.vegetation_allowance_m) - point.height_m;
}

void ClearanceTally::SecondLowest::Add(double v) {
  if (v < lowest) {
    second = lowest;
    lowest = v;
  } else if (v < second) {
    second = v;
  }
}

void ClearanceTally::Add(const TrackSection& section, const SectionPoint& point) {
  margin_.Add(gauge_.Margin(section, point));
  vegetation_margin_.Add(gauge_.VegetationMargin(point));
  height_min_.Add(point.height_m);
  height_max_negated_.Add(-point.height_m);
}

}  // namespace raillomer::mapstore
