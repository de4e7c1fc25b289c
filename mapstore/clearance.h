#pragma once

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace raillomer::mapstore {

/// The clearance a line must keep: the structure gauge (a cross-section perpendicular to the
/// track, widths from the track centre, heights above the rail plane) and the vegetation zone.
struct ClearanceOptions {
  /// The gauge's outline as (lateral m, height m) corners, lateral positive to the left, in
  /// order around it. The default is RAIL_FACTS' electrified line: half-width 2.44 m from the
  /// rail plane to 6.55 m.
  std::vector<Eigen::Vector2d> gauge_outline = {
      {-2.44, 0.0}, {2.44, 0.0}, {2.44, 6.55}, {-2.44, 6.55}};
  /// On curves the gauge is widened (RAIL_FACTS, after GB 146.2) on the inside by 40500 / R mm
  /// and on the outside by 44000 / R mm (R radius m), where the radius is below this. The
  /// rule's third term, H h / 1500 mm on the inside (H height above rail, h cant), is the lean
  /// of the cant, which the section's frame already carries (ToSection).
  double widen_below_radius_m = 10000.0;
  /// Vegetation within this distance of the track centre ...
  double vegetation_zone_m = 6.0;
  /// ... may be no taller than its distance minus this.
  double vegetation_allowance_m = 3.0;

  bool IsValid(std::string* error) const;
};

/// The track where a cross-section is taken.
struct TrackSection {
  double rail_height_m = 0.0;    ///< the rail plane's height at the track centre (UTM z)
  double cant_m = 0.0;           ///< the left rail above the right, over 1.5 m between heads
  double curvature_per_m = 0.0;  ///< 1 / radius, positive turning left
};

/// A point of a cross-section: offset along the rail plane from the track centre (positive
/// left of increasing chainage) and height above the rail plane.
struct SectionPoint {
  double lateral_m = 0.0;
  double height_m = 0.0;
};

/// Places a point in the section: its horizontal offset from the centre and its height (UTM z),
/// turned into the rail plane's frame, which the cant tilts.
SectionPoint ToSection(const TrackSection& section, double horizontal_offset_m, double z_m);

/// The structure gauge swept along the track: its outline at a section and the margin of a
/// point against it.
class StructureGauge {
 public:
  explicit StructureGauge(ClearanceOptions options) : options_(std::move(options)) {}

  /// The outline at a section, widened on a curve: each corner moves outwards by the widening
  /// at its height, on the side it is on.
  std::vector<Eigen::Vector2d> Outline(const TrackSection& section) const;
  /// The signed distance (m) of a point from the outline: negative inside (how far it is in),
  /// positive outside (how much room it leaves).
  double Margin(const TrackSection& section, const SectionPoint& point) const;
  /// Vegetation: how much lower the point would have to be to keep the vegetation rule (its
  /// height at most its distance from the centre less the allowance, within the zone);
  /// negative when it breaks it, +infinity outside the zone.
  double VegetationMargin(const SectionPoint& point) const;

  const ClearanceOptions& options() const { return options_; }

 private:
  ClearanceOptions options_;
};

/// A change's clearance from its points: its margins against the gauge and the vegetation rule
/// and its heights above the rail plane. Each extreme is the one of the second most extreme
/// point (of the only one, if it is alone): a single return a quantisation step or a mixed
/// pixel beyond the rest does not put a change inside the gauge on its own.
class ClearanceTally {
 public:
  explicit ClearanceTally(const StructureGauge& gauge) : gauge_(gauge) {}

  void Add(const TrackSection& section, const SectionPoint& point);

  double margin_m() const { return margin_.Get(); }
  /// +infinity when no point lies in the vegetation zone.
  double vegetation_margin_m() const { return vegetation_margin_.Get(); }
  double height_min_m() const { return height_min_.Get(); }
  double height_max_m() const { return -height_max_negated_.Get(); }

 private:
  /// The second lowest value added, or the lowest while there is one (+infinity: none).
  struct SecondLowest {
    double lowest = std::numeric_limits<double>::infinity();
    double second = std::numeric_limits<double>::infinity();
    void Add(double v);
    double Get() const {
      return second < std::numeric_limits<double>::infinity() ? second : lowest;
    }
  };
  const StructureGauge& gauge_;
  SecondLowest margin_, vegetation_margin_, height_min_, height_max_negated_;
};

}  // namespace raillomer::mapstore
