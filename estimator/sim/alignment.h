#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/sim/scenario.h"

namespace raillomer::sim {

/// A function of chainage between knots, linear or eased (smoothstep, so its slope is
/// continuous), with its exact running integral.
class PiecewiseLinear {
 public:
  explicit PiecewiseLinear(bool eased = false) : eased_(eased) {}
  void Add(double s, double value);
  double Value(double s) const;
  double Integral(double s) const;  ///< from the first knot to s
  double Slope(double s) const;

 private:
  size_t Piece(double s) const;
  bool eased_;
  std::vector<double> s_, v_, integral_;
};

/// The track centreline at one chainage.
struct TrackPoint {
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  ///< centre of the rail-top plane
  double heading_rad = 0.0;  ///< tangent yaw, counter-clockwise from grid east
  double grade = 0.0;        ///< dz/ds
  double curvature = 0.0;    ///< 1/m, left turn > 0
  double cant_m = 0.0;       ///< superelevation, left rail raised > 0
  double roll_rad = 0.0;     ///< from the cant over the 1.5 m rail-centre spacing

  /// Horizontal unit vector pointing left of the direction of travel.
  Eigen::Vector3d Left() const;
  /// Orientation of the track frame (x along, y left, z up), with grade and cant.
  Eigen::Matrix3d Rotation() const;
};

/// Horizontal and vertical alignment of the line: clothoids, arcs with cant, eased grades.
class Alignment {
 public:
  explicit Alignment(const Scenario& scenario);

  double length_m() const { return length_m_; }
  /// The centreline at chainage s; beyond the ends it continues straight.
  TrackPoint At(double s) const;
  /// A world point beside the line: lateral (left > 0) in the horizontal plane, height above
  /// the rail-top plane at that chainage (cant ignored: for trackside objects).
  Eigen::Vector3d Beside(double s, double lateral_m, double height_m) const;

 private:
  Eigen::Vector2d Integrate(double s0, double s1) const;  ///< ∫ (cos ψ, sin ψ) ds

  double length_m_ = 0.0;
  double heading0_ = 0.0;
  PiecewiseLinear curvature_;                 ///< clothoids: linear
  PiecewiseLinear cant_{true}, grade_{true};  ///< eased: no roll/pitch rate steps
  std::vector<double> knot_s_;
  std::vector<Eigen::Vector2d> knot_xy_;
};

}  // namespace raillomer::sim
