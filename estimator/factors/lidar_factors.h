#pragma once

#include <memory>
#include <optional>
#include <vector>

#include <ceres/cost_function.h>
#include <ceres/sized_cost_function.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/factors/pose_manifold.h"

namespace raillomer {

/// One point-to-plane term of a frame (eq. 21): r = weight * (normal . (R p_body + t) + d).
struct PlaneTerm {
  Eigen::Vector3d p_body;
  Eigen::Vector3d normal;  ///< unit, world frame
  double d = 0.0;
  double weight = 1.0;
};

/// One point-to-line term of a frame (eq. 20): r = weight * (I - u u^T)(R p_body + t - a).
struct LineTerm {
  LineTerm(const Eigen::Vector3d& p_body,
           const Eigen::Vector3d& point_world,
           const Eigen::Vector3d& direction_world,
           double weight);
  /// Leaves the residual's component along the unit `axis` (world) out: the term then says
  /// nothing along it.
  void Ignore(const Eigen::Vector3d& axis);
  Eigen::Vector3d p_body;
  Eigen::Vector3d point;
  Eigen::Matrix3d projector;
  double weight = 1.0;
};

/// Point-to-plane distance, eq. (21): r = w * (n . (R p_body + t) + d).
/// Parameter block: pose[7] (T_world_body). `n` is a unit normal in the world frame.
class PointToPlaneFactor : public ceres::SizedCostFunction<1, 7> {
 public:
  PointToPlaneFactor(const Eigen::Vector3d& p_body,
                     const Eigen::Vector3d& normal_world,
                     double d,
                     double weight);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  PlaneTerm term_;
};

/// Point-to-line distance, eq. (20), as the 3-vector r = w * (I - u u^T)(R p_body + t - a).
/// Parameter block: pose[7]. `a` is a point on the line, `u` its unit direction (world frame).
class PointToLineFactor : public ceres::SizedCostFunction<3, 7> {
 public:
  PointToLineFactor(const Eigen::Vector3d& p_body,
                    const Eigen::Vector3d& point_world,
                    const Eigen::Vector3d& direction_world,
                    double weight);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  LineTerm term_;
};

/// All of one frame's LiDAR terms on one pose, each robustified by a Huber loss of scale `huber`
/// (on |r|, as ceres::HuberLoss), folded into one residual block of 7.
///
/// Thousands of one-row residual blocks per frame cost Ceres far more in bookkeeping than in
/// arithmetic. This block sums them itself: at the evaluation point it forms the robustified
/// normal equations H = sum rho' J^T J, g = sum rho' J^T r (Ceres' own treatment of a Huber
/// loss) and returns the 6 rows J' = S^1/2 V^T, r' = S^-1/2 V^T g from H = V S V^T, so that
/// J'^T J' = H and J'^T r' = g, plus a seventh row, sqrt(sum rho - |r'|^2), with no Jacobian, so
/// that the block's cost is exactly the frame's robust cost. Every Gauss-Newton or
/// Levenberg-Marquardt step, and a marginalisation, sees the same system as with one block per
/// term.
class LidarFrameCost : public ceres::SizedCostFunction<7, 7> {
 public:
  LidarFrameCost(std::vector<PlaneTerm> planes, std::vector<LineTerm> lines, double huber);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

  size_t size() const { return planes_.size() + lines_.size(); }

 private:
  /// The terms' robustified cost (the sum of rho) at the pose; with H given, their
  /// Huber-weighted normal equations H (upper triangle) and g.
  double Accumulate(const double* pose_parameters,
                    Eigen::Matrix<double, 6, 6>* H,
                    Eigen::Matrix<double, 6, 1>* g) const;
  std::vector<PlaneTerm> planes_;
  std::vector<LineTerm> lines_;
  double huber_;
};

/// What a remapped LiDAR frame no longer sees (solution remapping, Zhang et al.; the degeneracy
/// measure of eq. 25 and the heading information): the translation along `direction` (world
/// frame) away from `p0`, and/or the turn about world z away from `q0`.
struct PoseRemapping {
  std::optional<Eigen::Vector3d> direction;  ///< the weakest translation, with p0
  Eigen::Vector3d p0 = Eigen::Vector3d::Zero();
  std::optional<Eigen::Quaterniond> q0;  ///< set: the heading is left out
  /// With q0: the heading is not held at q0's but put where the LiDAR itself would turn it
  /// for the rest of the pose (its profile, LidarOnlySolution::heading_z0 and heading_gain of
  /// scan_matching.h): the turn about world z since q0 is heading_z0 + heading_gain .
  /// [p - heading_p_ref; the turn about world x and y since q0]. Held at q0's heading, a frame
  /// whose registration pulls the heading would pass that pull on sideways (the points ahead lie
  /// off by the turn), and the odometer's sideways term would turn it back into heading. Zero gain
  /// and z0: held at q0's heading.
  double heading_z0 = 0.0;
  Eigen::Matrix<double, 5, 1> heading_gain = Eigen::Matrix<double, 5, 1>::Zero();
  Eigen::Vector3d heading_p_ref = Eigen::Vector3d::Zero();
};

/// Wraps a cost over one pose block so that it no longer sees what `remapping` names: it is
/// evaluated at the pose with those parts taken out (p0 + (I - u u^T)(p - p0); the rotation
/// since q0 without its part about world z). A LiDAR frame that cannot observe a direction (a
/// plain cutting seen along the track; a heading held only by soft creases) then neither pulls
/// nor holds the pose along it, and the other factors decide. Jacobian columns: the first 6
/// of 7.
class RemappedPoseCost : public ceres::CostFunction {
 public:
  RemappedPoseCost(std::shared_ptr<ceres::CostFunction> inner, const PoseRemapping& remapping);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  std::shared_ptr<ceres::CostFunction> inner_;
  PoseRemapping remapping_;
  Eigen::Matrix3d projector_ = Eigen::Matrix3d::Identity();  ///< I - u u^T
};

/// Rail-plane factor, eq. (28-30): the rail plane measured in body frame i, moved into body
/// frame j by the relative pose T_i^-1 T_j, against the plane measured in frame j.
/// r = [sqrt_w_normal * (R_ij^T n_i - n_j) (3); sqrt_w_distance * (d_i + n_i . t_ij - d_j) (1)].
/// Parameter blocks: pose_i[7], pose_j[7].
class RailPlaneFactor : public ceres::SizedCostFunction<4, 7, 7> {
 public:
  RailPlaneFactor(const Eigen::Vector3d& normal_i,
                  double distance_i,
                  const Eigen::Vector3d& normal_j,
                  double distance_j,
                  double sqrt_weight_normal,
                  double sqrt_weight_distance);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  Eigen::Vector3d n_i_, n_j_;
  double d_i_, d_j_, w_n_, w_d_;
};

/// Height-descriptor factor, eq. (27) turned into a displacement: the forward motion between
/// frames i and j in body frame i, r = (e_x . R_i^T (p_j - p_i) - dx) / sigma.
/// Parameter blocks: pose_i[7], pose_j[7].
class LongitudinalShiftFactor : public ceres::SizedCostFunction<1, 7, 7> {
 public:
  LongitudinalShiftFactor(double dx_m, double sigma_m);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  double dx_, sigma_;
};

}  // namespace raillomer
