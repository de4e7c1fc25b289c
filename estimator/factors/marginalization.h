#pragma once

#include <memory>
#include <unordered_map>
#include <vector>

#include <ceres/cost_function.h>
#include <ceres/loss_function.h>

#include <Eigen/Core>

namespace raillomer {

/// One factor taking part in marginalisation: its cost function, optional loss, its parameter
/// blocks, and which of them (indices into parameter_blocks) are marginalised away.
///
/// Pass only factors that touch a dropped block (others would be counted twice: once in the
/// prior and once in the window). A block dropped by one term is dropped in every term. The cost
/// functions are shared: add them to a ceres::Problem with DO_NOT_TAKE_OWNERSHIP (or give Ceres
/// its own instances).
struct MarginalizationTerm {
  std::shared_ptr<ceres::CostFunction> cost_function;
  std::shared_ptr<ceres::LossFunction> loss_function;  ///< may be null
  std::vector<double*> parameter_blocks;
  std::vector<int> drop_indices;
};

/// Builds the Schur-complement prior r_p of eq. (2) (after VINS-Mono's MarginalizationInfo).
///
/// Blocks are identified by address; a block of ambient size 7 is a pose (tangent size 6, see
/// PoseManifold), any other size is Euclidean. The kept blocks' values at marginalisation time
/// are copied as the linearisation point.
class MarginalizationInfo {
 public:
  void AddTerm(MarginalizationTerm term);
  /// Linearises every term, forms H = sum J^T J and b = sum J^T r, takes the Schur complement
  /// onto the kept blocks and factors the result as H' = J^T J, r0 = (J^T)^+ b' (so that
  /// J^T r0 = b'). Releases the terms on success. False if nothing is kept, a drop index is out
  /// of range, an address has two sizes or a cost function fails to evaluate.
  bool Marginalize();

  /// The kept blocks in prior order; `address_map` renames them (old address -> new address)
  /// when the window shifts its storage; blocks missing from the map keep their address.
  std::vector<double*> KeptBlocks(const std::unordered_map<double*, double*>& address_map) const;

  int kept_tangent_size() const { return kept_tangent_size_; }
  const std::vector<int>& kept_sizes() const { return kept_sizes_; }      ///< ambient
  const std::vector<int>& kept_offsets() const { return kept_offsets_; }  ///< tangent
  const std::vector<std::vector<double>>& kept_values() const { return kept_values_; }
  const Eigen::MatrixXd& linearized_jacobian() const { return linearized_jacobian_; }
  const Eigen::VectorXd& linearized_residual() const { return linearized_residual_; }

 private:
  std::vector<MarginalizationTerm> terms_;
  std::vector<double*> kept_blocks_;
  std::vector<int> kept_sizes_, kept_offsets_;
  std::vector<std::vector<double>> kept_values_;
  int kept_tangent_size_ = 0;
  Eigen::MatrixXd linearized_jacobian_;
  Eigen::VectorXd linearized_residual_;
};

/// The prior as a Ceres cost: r = r0 + J (x [-] x0), pose differences through PoseManifold::Minus.
/// Parameter blocks: MarginalizationInfo::KeptBlocks() in that order. The pose Jacobian uses the
/// exact inverse right Jacobian of SO(3) at Log(q0^-1 q).
class MarginalizationFactor : public ceres::CostFunction {
 public:
  explicit MarginalizationFactor(std::shared_ptr<const MarginalizationInfo> info);
  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override;

 private:
  std::shared_ptr<const MarginalizationInfo> info_;
};

}  // namespace raillomer
