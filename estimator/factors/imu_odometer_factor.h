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
/// The square-root information is cached at construction; if the preintegration is changed
/// afterwards (Repropagate, Append), Evaluate notices through revision() and recomputes it on
/// every call, which is correct but slow: build a new factor instead.
class ImuOdometerFactor : public ceres::SizedCostFunction<19, 7, 9, 1, 7, 9, 1> {
 public:
  explicit ImuOdometerFactor(std::shared_ptr<const Preintegration> preintegration);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

  /// The whitening matrix in use (upper triangular, phi rows zero without odometer data).
  const Eigen::Matrix<double, 19, 19>& sqrt_information() const { return sqrt_information_; }

 private:
  std::shared_ptr<const Preintegration> preintegration_;
  Eigen::Matrix<double, 19, 19> sqrt_information_;
  std::uint64_t revision_;
};

}  // namespace raillomer
