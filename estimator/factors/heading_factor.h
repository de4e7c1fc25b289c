#pragma once

#include <ceres/sized_cost_function.h>

#include <Eigen/Geometry>

namespace raillomer {

/// The heading of a body attitude: the direction of its x axis in the world's horizontal plane,
/// counter-clockwise from world x (rad, in (-pi, pi]).
double HeadingOf(const Eigen::Matrix3d& R_world_body);
double HeadingOf(const Eigen::Quaterniond& q_world_body);

/// Holds a pose's heading to a reference (a straight track's, StraightTrackDetector):
/// r = wrap(heading(q) - heading_ref) / sigma. Roll and pitch are free. Parameter block:
/// pose[7] (Jacobian in the pose manifold's tangent, as every pose factor).
class HeadingHoldFactor : public ceres::SizedCostFunction<1, 7> {
 public:
  HeadingHoldFactor(double heading_ref_rad, double sigma_rad);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  double heading_ref_, weight_;
};

}  // namespace raillomer
