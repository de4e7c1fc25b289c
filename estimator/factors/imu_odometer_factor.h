#pragma once

#include <cstdint>
#include <memory>

#include <ceres/sized_cost_function.h>

#include "estimator/factors/pose_manifold.h"
#include "estimator/factors/preintegration.h"

namespace raillomer {

/// The IMU / odometer preintegration factor, eq. (19), whitened by the preintegrated covariance,
/// and the random walk of the odometer's misalignment m (NavState::m): 21 rows, eq. (19)'s 19
/// then m_j - m_i (kMisalignment). Parameter blocks: pose_i[7], speed_bias_i[9], odometer_i[3],
/// pose_j[7], speed_bias_j[9], odometer_j[3] (the odometer block: c, m). Analytic Jacobians
/// (pose Jacobians per the PoseManifold convention).
///
/// One departure from eq. (19): the component of d_phi along the odometer's axis is taken in
/// odometer units, times c_lin / c_i (c_lin the preintegration's linearisation scale), because
/// the odometer's noise is in its own units. In metres, the cost of odometer noise would fall
/// as c^2 and the solver would shrink a scale the data do not observe.
///
/// The square-root information is cached at construction; if the preintegration is changed
/// afterwards (Repropagate, Append), Evaluate notices through revision() and recomputes it on
/// every call, which is correct but slow: build a new factor instead.
class ImuOdometerFactor : public ceres::SizedCostFunction<21, 7, 9, 3, 7, 9, 3> {
 public:
  explicit ImuOdometerFactor(std::shared_ptr<const Preintegration> preintegration);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

  /// Row of m_j - m_i in the residual.
  static constexpr int kMisalignment = 19;

  /// The residual before whitening: Preintegration::Evaluate with the odometer-axis component
  /// of d_phi scaled by c_lin / c_i, then m_j - m_i.
  Eigen::Matrix<double, 21, 1> Residual(const NavState& i, const NavState& j) const;

  /// The whitening of eq. (19)'s rows in use (upper triangular, phi rows zero without odometer
  /// data); the misalignment rows are whitened by misalignment_weight().
  const Eigen::Matrix<double, 19, 19>& sqrt_information() const { return sqrt_information_; }
  /// 1 / (walk sqrt(dt)); 1e6 /rad when the walk is 0 (one constant misalignment).
  double misalignment_weight() const { return misalignment_weight_; }

 private:
  std::shared_ptr<const Preintegration> preintegration_;
  Eigen::Matrix<double, 19, 19> sqrt_information_;
  double misalignment_weight_;
  std::uint64_t revision_;
};

}  // namespace raillomer
