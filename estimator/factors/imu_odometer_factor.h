#pragma once

#include <cstdint>
#include <memory>

#include <ceres/sized_cost_function.h>

#include "estimator/factors/pose_manifold.h"
#include "estimator/factors/preintegration.h"

namespace raillomer {

/// The IMU / odometer preintegration factor, eq. (19), whitened by the preintegrated covariance.
/// Parameter blocks: pose_i[7], speed_bias_i[9], scale_i[1], pose_j[7], speed_bias_j[9],
/// scale_j[1]. Analytic Jacobians (pose Jacobians per the PoseManifold convention).
///
/// One departure from eq. (19): the component of d_phi along the odometer's axis is taken in
/// odometer units, times c_lin / c_i (c_lin the preintegration's linearisation scale), because
/// the odometer's noise is in its own units. In metres, the cost of odometer noise would fall
/// as c^2 and the solver would shrink a scale the data do not observe.
///
/// The square-root information is cached at construction; if the preintegration is changed
/// afterwards (Repropagate, Append), Evaluate notices through revision() and recomputes it on
/// every call, which is correct but slow: build a new factor instead.
class ImuOdometerFactor : public ceres::SizedCostFunction<19, 7, 9, 1, 7, 9, 1> {
 public:
  explicit ImuOdometerFactor(std::shared_ptr<const Preintegration> preintegration);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

  /// The residual before whitening: Preintegration::Evaluate with the odometer-axis component
  /// of d_phi scaled by c_lin / c_i.
  Eigen::Matrix<double, 19, 1> Residual(const NavState& i, const NavState& j) const;

  /// The whitening matrix in use (upper triangular, phi rows zero without odometer data).
  const Eigen::Matrix<double, 19, 19>& sqrt_information() const { return sqrt_information_; }

 private:
  std::shared_ptr<const Preintegration> preintegration_;
  Eigen::Matrix<double, 19, 19> sqrt_information_;
  std::uint64_t revision_;
};

}  // namespace raillomer
