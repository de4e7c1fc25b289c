#include "estimator/sim/alignment.h"

#include <algorithm>
#include <cmath>

namespace raillomer::sim {

namespace {
constexpr double kRailCentreSpacingM = 1.5;
constexpr double kKnotSpacingM = 5.0;
}  // namespace

void PiecewiseLinear::Add(double s, double value) {
  if (!s_.empty() && s <= s_.back()) {
    // Same chainage twice: a step. Nudge so the function stays single valued.
    s = s_.back() + 1e-6;
  }
  if (s_.empty()) {
    integral_.push_back(0.0);
  } else {
    integral_.push_back(integral_.back() + 0.5 * (v_.back() + value) * (s - s_.back()));
  }
  s_.push_back(s);
  v_.push_back(value);
}

size_t PiecewiseLinear::Piece(double s) const {
  if (s_.size() < 2 || s <= s_.front()) return 0;
  const auto it = std::upper_bound(s_.begin(), s_.end(), s);
  const size_t i = static_cast<size_t>(it - s_.begin()) - 1;
  return std::min(i, s_.size() - 2);
}

double PiecewiseLinear::Slope(double s) const {
  if (s_.size() < 2 || s < s_.front() || s > s_.back()) return 0.0;
  const size_t i = Piece(s);
  const double length = s_[i + 1] - s_[i];
  const double u = (s - s_[i]) / length;
  const double shape = eased_ ? 6.0 * u * (1.0 - u) : 1.0;
  return (v_[i + 1] - v_[i]) / length * shape;
}

double PiecewiseLinear::Value(double s) const {
  if (s_.empty()) return 0.0;
  if (s <= s_.front()) return v_.front();
  if (s >= s_.back()) return v_.back();
  const size_t i = Piece(s);
  const double u = (s - s_[i]) / (s_[i + 1] - s_[i]);
  const double shape = eased_ ? u * u * (3.0 - 2.0 * u) : u;
  return v_[i] + (v_[i + 1] - v_[i]) * shape;
}

double PiecewiseLinear::Integral(double s) const {
  if (s_.empty()) return 0.0;
  if (s <= s_.front()) return v_.front() * (s - s_.front());
  if (s >= s_.back()) return integral_.back() + v_.back() * (s - s_.back());
  const size_t i = Piece(s);
  const double length = s_[i + 1] - s_[i];
  const double u = (s - s_[i]) / length;
  // ∫ shape du from 0 to u: u^2/2 (linear) or u^3 - u^4/2 (smoothstep); both 1/2 at u = 1.
  const double area = eased_ ? u * u * u - 0.5 * u * u * u * u : 0.5 * u * u;
  return integral_[i] + v_[i] * u * length + (v_[i + 1] - v_[i]) * length * area;
}

Eigen::Vector3d TrackPoint::Left() const {
  return {-std::sin(heading_rad), std::cos(heading_rad), 0.0};
}

Eigen::Matrix3d TrackPoint::Rotation() const {
  return (Eigen::AngleAxisd(heading_rad, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(-std::atan(grade), Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll_rad, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

Alignment::Alignment(const Scenario& scenario) {
  heading0_ = (90.0 - scenario.initial_azimuth_deg) * M_PI / 180.0;
  std::vector<double> boundaries;
  double s = 0.0;
  curvature_.Add(0.0, 0.0);
  cant_.Add(0.0, 0.0);
  std::vector<std::pair<double, double>> grade_steps;  // (chainage, grade from there)
  for (const AlignmentSegment& seg : scenario.alignment) {
    grade_steps.emplace_back(s, seg.gradient_permille / 1000.0);
    if (seg.kind == AlignmentSegment::Kind::kStraight) {
      s += seg.length_m;
      curvature_.Add(s, 0.0);
      cant_.Add(s, 0.0);
    } else {
      const double k = seg.direction / seg.radius_m;
      const double cant = -seg.direction * seg.cant_mm / 1000.0;  // outer rail raised
      if (seg.transition_m > 0.0) {
        s += seg.transition_m;
        curvature_.Add(s, k);
        cant_.Add(s, cant);
      } else {
        curvature_.Add(s, k);
        cant_.Add(s, cant);
      }
      s += seg.length_m;
      curvature_.Add(s, k);
      cant_.Add(s, cant);
      if (seg.transition_m > 0.0) s += seg.transition_m;
      curvature_.Add(s, 0.0);
      cant_.Add(s, 0.0);
    }
  }
  length_m_ = s;

  // Grades change linearly over a vertical curve centred on each segment boundary.
  const double half = 0.5 * scenario.vertical_curve_m;
  double previous = grade_steps.empty() ? 0.0 : grade_steps.front().second;
  grade_.Add(0.0, previous);
  for (size_t i = 1; i < grade_steps.size(); ++i) {
    const double at = grade_steps[i].first;
    const double g = grade_steps[i].second;
    if (g == previous) continue;
    grade_.Add(std::max(at - half, 1e-3), previous);
    grade_.Add(at + half, g);
    previous = g;
  }
  grade_.Add(length_m_ + 1.0, previous);

  // Position knots: every 5 m, integrated from the start.
  knot_s_.push_back(0.0);
  knot_xy_.push_back(Eigen::Vector2d::Zero());
  while (knot_s_.back() < length_m_) {
    const double a = knot_s_.back();
    const double b = std::min(a + kKnotSpacingM, length_m_);
    knot_xy_.push_back(knot_xy_.back() + Integrate(a, b));
    knot_s_.push_back(b);
  }
}

Eigen::Vector2d Alignment::Integrate(double s0, double s1) const {
  // Gauss-Legendre, 6 points: the heading is a smooth quadratic within 5 m.
  static const double kX[6] = {-0.9324695142031521,
                               -0.6612093864662645,
                               -0.2386191860831969,
                               0.2386191860831969,
                               0.6612093864662645,
                               0.9324695142031521};
  static const double kW[6] = {0.1713244923791704,
                               0.3607615730481386,
                               0.4679139345726910,
                               0.4679139345726910,
                               0.3607615730481386,
                               0.1713244923791704};
  const double mid = 0.5 * (s0 + s1), half = 0.5 * (s1 - s0);
  Eigen::Vector2d sum = Eigen::Vector2d::Zero();
  for (int i = 0; i < 6; ++i) {
    const double psi = heading0_ + curvature_.Integral(mid + half * kX[i]);
    sum += kW[i] * Eigen::Vector2d(std::cos(psi), std::sin(psi));
  }
  return half * sum;
}

TrackPoint Alignment::At(double s) const {
  TrackPoint p;
  const double clamped = std::clamp(s, 0.0, length_m_);
  const auto it = std::upper_bound(knot_s_.begin(), knot_s_.end(), clamped);
  const size_t k = std::max<size_t>(1, static_cast<size_t>(it - knot_s_.begin())) - 1;
  Eigen::Vector2d xy = knot_xy_[k] + Integrate(knot_s_[k], clamped);
  p.heading_rad = heading0_ + curvature_.Integral(clamped);
  if (s != clamped) {  // continue straight beyond the ends
    xy += (s - clamped) * Eigen::Vector2d(std::cos(p.heading_rad), std::sin(p.heading_rad));
  }
  p.position = Eigen::Vector3d(xy.x(), xy.y(), grade_.Integral(s));
  p.grade = grade_.Value(s);
  p.curvature = curvature_.Value(clamped);
  p.cant_m = cant_.Value(clamped);
  p.roll_rad = std::asin(std::clamp(p.cant_m / kRailCentreSpacingM, -0.2, 0.2));
  return p;
}

Eigen::Vector3d Alignment::Beside(double s, double lateral_m, double height_m) const {
  const TrackPoint p = At(s);
  return p.position + lateral_m * p.Left() + Eigen::Vector3d(0.0, 0.0, height_m);
}

}  // namespace raillomer::sim
