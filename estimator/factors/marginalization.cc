#include "estimator/factors/marginalization.h"

#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "estimator/factors/pose_manifold.h"

namespace raillomer {
namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Eigenvalues at or below this are treated as zero (as in VINS-Mono).
constexpr double kEigenvalueEpsilon = 1e-8;

int TangentSize(int ambient_size) {
  return ambient_size == kPoseSize ? kPoseTangentSize : ambient_size;
}

/// Inverse of the right Jacobian of SO(3), exact: Jr^-1(phi) = I + [phi]x / 2 +
/// (1 / |phi|^2 - (1 + cos|phi|) / (2 |phi| sin|phi|)) [phi]x^2.
Eigen::Matrix3d RightJacobianInverse(const Eigen::Vector3d& phi) {
  const double angle = phi.norm();
  const Eigen::Matrix3d phi_hat = Skew(phi);
  double coefficient;
  if (angle < 1e-4) {
    coefficient = 1.0 / 12.0 + angle * angle / 720.0;
  } else {
    coefficient = 1.0 / (angle * angle) - (1.0 + std::cos(angle)) / (2.0 * angle * std::sin(angle));
  }
  return Eigen::Matrix3d::Identity() + 0.5 * phi_hat + coefficient * phi_hat * phi_hat;
}

/// Scales a residual and its tangent Jacobian like Ceres's Corrector so that the squared norm
/// of the result matches the robustified cost to second order. False if the loss has no slope.
bool ApplyLoss(const ceres::LossFunction& loss, Eigen::VectorXd* residual, Eigen::MatrixXd* jac) {
  const double sq_norm = residual->squaredNorm();
  double rho[3];
  loss.Evaluate(sq_norm, rho);
  if (!(rho[1] > 0.0)) return false;
  const double sqrt_rho1 = std::sqrt(rho[1]);
  double residual_scaling = sqrt_rho1;
  double alpha_sq_norm = 0.0;
  if (sq_norm > 0.0 && rho[2] > 0.0) {
    const double alpha = 1.0 - std::sqrt(1.0 + 2.0 * sq_norm * rho[2] / rho[1]);
    residual_scaling = sqrt_rho1 / (1.0 - alpha);
    alpha_sq_norm = alpha / sq_norm;
  }
  if (alpha_sq_norm != 0.0) {
    const Eigen::RowVectorXd r_t_j = residual->transpose() * *jac;
    *jac -= alpha_sq_norm * *residual * r_t_j;
  }
  *jac *= sqrt_rho1;
  *residual *= residual_scaling;
  return true;
}

/// The blocks of a marginalisation in order [dropped..., kept...], each group in order of first
/// appearance, with their sizes and offsets in the tangent space.
struct BlockLayout {
  std::vector<double*> blocks;
  std::vector<int> ambient_sizes;
  std::unordered_map<double*, int> index;  ///< address -> position in `blocks`
  std::vector<int> tangent_offsets;
  int num_dropped_blocks = 0;
  int dropped_size = 0;  ///< tangent size of the dropped blocks
  int total_size = 0;

  int kept_size() const { return total_size - dropped_size; }
};

/// Orders the terms' blocks (a block dropped by any term is dropped everywhere); false when a
/// term is malformed, an address comes with two sizes, or nothing is kept.
bool LayOutBlocks(const std::vector<MarginalizationTerm>& terms, BlockLayout* layout) {
  // Every term names as many blocks as its cost function takes.
  for (const MarginalizationTerm& term : terms) {
    if (term.cost_function == nullptr ||
        term.cost_function->parameter_block_sizes().size() != term.parameter_blocks.size()) {
      return false;
    }
  }
  std::unordered_set<double*> dropped_set;
  for (const MarginalizationTerm& term : terms) {
    for (int index : term.drop_indices) {
      if (index < 0 || index >= static_cast<int>(term.parameter_blocks.size())) return false;
      dropped_set.insert(term.parameter_blocks[index]);
    }
  }
  auto add_blocks = [&](bool dropped) {
    for (const MarginalizationTerm& term : terms) {
      const std::vector<int32_t>& sizes = term.cost_function->parameter_block_sizes();
      for (size_t k = 0; k < term.parameter_blocks.size(); ++k) {
        double* block = term.parameter_blocks[k];
        if ((dropped_set.count(block) > 0) != dropped) continue;
        auto [it, inserted] = layout->index.emplace(block, static_cast<int>(layout->blocks.size()));
        if (inserted) {
          layout->blocks.push_back(block);
          layout->ambient_sizes.push_back(sizes[k]);
        } else if (layout->ambient_sizes[it->second] != sizes[k]) {
          return false;  // one address used with two sizes
        }
      }
    }
    return true;
  };
  if (!add_blocks(true)) return false;
  layout->num_dropped_blocks = static_cast<int>(layout->blocks.size());
  if (!add_blocks(false)) return false;
  if (static_cast<int>(layout->blocks.size()) == layout->num_dropped_blocks) return false;
  layout->tangent_offsets.resize(layout->blocks.size());
  for (size_t k = 0; k < layout->blocks.size(); ++k) {
    layout->tangent_offsets[k] = layout->total_size;
    layout->total_size += TangentSize(layout->ambient_sizes[k]);
    if (static_cast<int>(k) + 1 == layout->num_dropped_blocks) {
      layout->dropped_size = layout->total_size;
    }
  }
  return true;
}

/// One term evaluated at the blocks' values: its residual and tangent Jacobian (pose blocks keep
/// their first 6 columns, PoseManifold), robustified, with each block's column offset.
struct LinearizedTerm {
  Eigen::VectorXd residual;
  Eigen::MatrixXd jacobian;
  std::vector<int> offsets;
  bool informative = true;  ///< false where the loss has no slope
};

/// False if the cost function fails to evaluate.
bool LinearizeTerm(const MarginalizationTerm& term, LinearizedTerm* out) {
  const ceres::CostFunction& cost = *term.cost_function;
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  const int num_residuals = cost.num_residuals();
  const size_t num_blocks = term.parameter_blocks.size();
  std::vector<RowMatrix> ambient_jacobians(num_blocks);
  std::vector<double*> jacobian_pointers(num_blocks);
  out->offsets.resize(num_blocks);
  int term_size = 0;
  for (size_t k = 0; k < num_blocks; ++k) {
    ambient_jacobians[k].resize(num_residuals, sizes[k]);
    jacobian_pointers[k] = ambient_jacobians[k].data();
    out->offsets[k] = term_size;
    term_size += TangentSize(sizes[k]);
  }
  out->residual.resize(num_residuals);
  std::vector<const double*> values(term.parameter_blocks.begin(), term.parameter_blocks.end());
  if (!cost.Evaluate(values.data(), out->residual.data(), jacobian_pointers.data())) return false;
  out->jacobian.resize(num_residuals, term_size);
  for (size_t k = 0; k < num_blocks; ++k) {
    out->jacobian.middleCols(out->offsets[k], TangentSize(sizes[k])) =
        ambient_jacobians[k].leftCols(TangentSize(sizes[k]));
  }
  out->informative = term.loss_function == nullptr ||
                     ApplyLoss(*term.loss_function, &out->residual, &out->jacobian);
  return true;
}

/// Adds a linearised term's J^T J and J^T r to the blocks' H and b (eq. 2).
void AccumulateTerm(const MarginalizationTerm& term,
                    const LinearizedTerm& lin,
                    const BlockLayout& layout,
                    Eigen::MatrixXd* hessian,
                    Eigen::VectorXd* gradient) {
  const std::vector<int32_t>& sizes = term.cost_function->parameter_block_sizes();
  const size_t num_blocks = term.parameter_blocks.size();
  const Eigen::MatrixXd term_hessian = lin.jacobian.transpose() * lin.jacobian;
  const Eigen::VectorXd term_gradient = lin.jacobian.transpose() * lin.residual;
  for (size_t a = 0; a < num_blocks; ++a) {
    const int row = layout.tangent_offsets[layout.index.at(term.parameter_blocks[a])];
    const int rows = TangentSize(sizes[a]);
    gradient->segment(row, rows) += term_gradient.segment(lin.offsets[a], rows);
    for (size_t c = 0; c < num_blocks; ++c) {
      const int col = layout.tangent_offsets[layout.index.at(term.parameter_blocks[c])];
      const int cols = TangentSize(sizes[c]);
      hessian->block(row, col, rows, cols) +=
          term_hessian.block(lin.offsets[a], lin.offsets[c], rows, cols);
    }
  }
}

/// The Schur complement of H and b onto the kept blocks, Hmm^-1 through a clipped eigen
/// decomposition.
void SchurComplement(const Eigen::MatrixXd& hessian,
                     const Eigen::VectorXd& gradient,
                     int dropped_size,
                     int kept_size,
                     Eigen::MatrixXd* prior_hessian,
                     Eigen::VectorXd* prior_gradient) {
  Eigen::MatrixXd hkm_hmm_inverse = Eigen::MatrixXd::Zero(kept_size, dropped_size);
  if (dropped_size > 0) {
    const Eigen::MatrixXd hmm =
        0.5 * (hessian.topLeftCorner(dropped_size, dropped_size) +
               hessian.topLeftCorner(dropped_size, dropped_size).transpose());
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> hmm_solver(hmm);
    const Eigen::VectorXd hmm_inverse_values =
        (hmm_solver.eigenvalues().array() > kEigenvalueEpsilon)
            .select(hmm_solver.eigenvalues().array().inverse(), 0.0);
    hkm_hmm_inverse = hessian.bottomLeftCorner(kept_size, dropped_size) *
                      hmm_solver.eigenvectors() * hmm_inverse_values.asDiagonal() *
                      hmm_solver.eigenvectors().transpose();
  }
  *prior_hessian = hessian.bottomRightCorner(kept_size, kept_size) -
                   hkm_hmm_inverse * hessian.topRightCorner(dropped_size, kept_size);
  *prior_hessian = 0.5 * (*prior_hessian + prior_hessian->transpose()).eval();
  *prior_gradient = gradient.tail(kept_size) - hkm_hmm_inverse * gradient.head(dropped_size);
}

}  // namespace

void MarginalizationInfo::AddTerm(MarginalizationTerm term) { terms_.push_back(std::move(term)); }

bool MarginalizationInfo::Marginalize() {
  kept_blocks_.clear();
  kept_sizes_.clear();
  kept_offsets_.clear();
  kept_values_.clear();
  kept_tangent_size_ = 0;
  linearized_jacobian_.resize(0, 0);
  linearized_residual_.resize(0);
  BlockLayout layout;
  if (!LayOutBlocks(terms_, &layout)) return false;
  const int kept_size = layout.kept_size();

  // Eq. (2): H = sum J^T J, b = sum J^T r over every term, in tangent coordinates.
  Eigen::MatrixXd hessian = Eigen::MatrixXd::Zero(layout.total_size, layout.total_size);
  Eigen::VectorXd gradient = Eigen::VectorXd::Zero(layout.total_size);
  for (const MarginalizationTerm& term : terms_) {
    LinearizedTerm lin;
    if (!LinearizeTerm(term, &lin)) return false;
    if (!lin.informative) continue;  // zero slope: the term carries no information
    AccumulateTerm(term, lin, layout, &hessian, &gradient);
  }
  Eigen::MatrixXd prior_hessian;
  Eigen::VectorXd prior_gradient;
  SchurComplement(
      hessian, gradient, layout.dropped_size, kept_size, &prior_hessian, &prior_gradient);

  // H' = J^T J with J = S^1/2 V^T, and J^T r0 = b' gives r0 = S^-1/2 V^T b'.
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> prior_solver(prior_hessian);
  const Eigen::ArrayXd eigenvalues = prior_solver.eigenvalues().array();
  const Eigen::VectorXd sqrt_values =
      (eigenvalues > kEigenvalueEpsilon).select(eigenvalues.sqrt(), 0.0);
  const Eigen::VectorXd inverse_sqrt_values =
      (eigenvalues > kEigenvalueEpsilon).select(eigenvalues.sqrt().inverse(), 0.0);
  linearized_jacobian_ = sqrt_values.asDiagonal() * prior_solver.eigenvectors().transpose();
  linearized_residual_ =
      inverse_sqrt_values.asDiagonal() * prior_solver.eigenvectors().transpose() * prior_gradient;

  // The kept blocks, their sizes and their values as the linearisation point.
  for (size_t k = layout.num_dropped_blocks; k < layout.blocks.size(); ++k) {
    kept_blocks_.push_back(layout.blocks[k]);
    kept_sizes_.push_back(layout.ambient_sizes[k]);
    kept_offsets_.push_back(layout.tangent_offsets[k] - layout.dropped_size);
    kept_values_.emplace_back(layout.blocks[k], layout.blocks[k] + layout.ambient_sizes[k]);
  }
  kept_tangent_size_ = kept_size;
  // Release the terms: a term may be the previous prior, whose info holds its own terms, and
  // keeping them would chain every prior since start-up.
  terms_.clear();
  return true;
}

std::vector<double*> MarginalizationInfo::KeptBlocks(
    const std::unordered_map<double*, double*>& address_map) const {
  std::vector<double*> renamed;
  renamed.reserve(kept_blocks_.size());
  for (double* block : kept_blocks_) {
    const auto it = address_map.find(block);
    renamed.push_back(it == address_map.end() ? block : it->second);
  }
  return renamed;
}

MarginalizationFactor::MarginalizationFactor(std::shared_ptr<const MarginalizationInfo> info)
    : info_(std::move(info)) {
  set_num_residuals(info_->kept_tangent_size());
  std::vector<int32_t>* sizes = mutable_parameter_block_sizes();
  sizes->assign(info_->kept_sizes().begin(), info_->kept_sizes().end());
}

bool MarginalizationFactor::Evaluate(double const* const* parameters,
                                     double* residuals,
                                     double** jacobians) const {
  const int n = info_->kept_tangent_size();
  const std::vector<int>& sizes = info_->kept_sizes();
  const std::vector<int>& offsets = info_->kept_offsets();
  const std::vector<std::vector<double>>& x0 = info_->kept_values();
  const Eigen::MatrixXd& jacobian = info_->linearized_jacobian();

  // dx = x [-] x0 per block (PoseManifold::Minus for poses).
  Eigen::VectorXd dx(n);
  std::vector<Eigen::Vector3d> rotation_deltas(sizes.size(), Eigen::Vector3d::Zero());
  for (size_t k = 0; k < sizes.size(); ++k) {
    const int size = sizes[k];
    const int offset = offsets[k];
    if (size == kPoseSize) {
      const Eigen::Map<const Eigen::Vector3d> p(parameters[k]);
      const Eigen::Map<const Eigen::Quaterniond> q(parameters[k] + 3);
      const Eigen::Map<const Eigen::Vector3d> p0(x0[k].data());
      const Eigen::Map<const Eigen::Quaterniond> q0(x0[k].data() + 3);
      rotation_deltas[k] = LogQuaternion(q0.conjugate() * q);
      dx.segment<3>(offset) = p - p0;
      dx.segment<3>(offset + 3) = rotation_deltas[k];
    } else {
      dx.segment(offset, size) = Eigen::Map<const Eigen::VectorXd>(parameters[k], size) -
                                 Eigen::Map<const Eigen::VectorXd>(x0[k].data(), size);
    }
  }
  // Eq. (2): the prior r_p, linear in the tangent difference.
  Eigen::Map<Eigen::VectorXd>(residuals, n) = info_->linearized_residual() + jacobian * dx;

  if (jacobians == nullptr) return true;
  for (size_t k = 0; k < sizes.size(); ++k) {
    if (jacobians[k] == nullptr) continue;
    const int size = sizes[k];
    const int offset = offsets[k];
    Eigen::Map<RowMatrix> block_jacobian(jacobians[k], n, size);
    if (size == kPoseSize) {
      block_jacobian.leftCols<3>() = jacobian.middleCols<3>(offset);
      // Log(Exp(dx_rot) Exp(dtheta)) = dx_rot + Jr^-1(dx_rot) dtheta + O(dtheta^2).
      block_jacobian.middleCols<3>(3) =
          jacobian.middleCols<3>(offset + 3) * RightJacobianInverse(rotation_deltas[k]);
      block_jacobian.col(6).setZero();
    } else {
      block_jacobian = jacobian.middleCols(offset, size);
    }
  }
  return true;
}

}  // namespace raillomer
