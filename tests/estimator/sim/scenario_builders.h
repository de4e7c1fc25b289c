#pragma once

// Building blocks for scenarios written in code by the simulator's tests.

#include "estimator/sim/scenario.h"

namespace raillomer::sim::test {

/// A straight of `length_m` at a grade.
inline AlignmentSegment Straight(double length_m, double gradient_permille = 0.0) {
  AlignmentSegment seg;
  seg.kind = AlignmentSegment::Kind::kStraight;
  seg.length_m = length_m;
  seg.gradient_permille = gradient_permille;
  return seg;
}

/// A circular curve (direction +1 left, -1 right) with clothoids, cant and grade.
inline AlignmentSegment Curve(double length_m,
                              double radius_m,
                              int direction,
                              double transition_m = 0.0,
                              double cant_mm = 0.0,
                              double gradient_permille = 0.0) {
  AlignmentSegment seg = Straight(length_m, gradient_permille);
  seg.kind = AlignmentSegment::Kind::kCurve;
  seg.radius_m = radius_m;
  seg.direction = direction;
  seg.transition_m = transition_m;
  seg.cant_mm = cant_mm;
  return seg;
}

/// Motion phases: keep the speed for a time or a distance, or change it.
inline MotionPhase ForSeconds(double s) { return {MotionPhase::Kind::kForSeconds, s, 0.5}; }
inline MotionPhase ForMetres(double m) { return {MotionPhase::Kind::kForMetres, m, 0.5}; }
inline MotionPhase ToSpeed(double mps, double accel) {
  return {MotionPhase::Kind::kToSpeed, mps, accel};
}

}  // namespace raillomer::sim::test
