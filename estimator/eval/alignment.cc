#include "estimator/eval/alignment.h"

#include <algorithm>
#include <cmath>

#include <Eigen/SVD>

#include "estimator/geo/gnss.h"

namespace raillomer::eval {

namespace {

// Relative size below which a singular value (or the 2D cross terms) counts as zero.
constexpr double kDegenerateRatio = 1e-12;

double Rmse(const std::vector<Eigen::Vector3d>& p_est,
            const std::vector<Eigen::Vector3d>& p_truth,
            const Eigen::Isometry3d& T_truth_est) {
  if (p_est.empty()) return 0.0;
  double sum = 0.0;
  for (size_t i = 0; i < p_est.size(); ++i) {
    sum += (T_truth_est * p_est[i] - p_truth[i]).squaredNorm();
  }
  return std::sqrt(sum / static_cast<double>(p_est.size()));
}

Eigen::Vector3d Mean(const std::vector<Eigen::Vector3d>& points) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : points) sum += p;
  return sum / static_cast<double>(points.size());
}

// Umeyama (1991) without scale: R = V diag(1, 1, d) U^T from the SVD of H = sum e' g'^T.
void AlignSe3(const std::vector<Eigen::Vector3d>& p_est,
              const std::vector<Eigen::Vector3d>& p_truth,
              Alignment* alignment) {
  const Eigen::Vector3d mean_est = Mean(p_est);
  const Eigen::Vector3d mean_truth = Mean(p_truth);
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < p_est.size(); ++i) {
    H += (p_est[i] - mean_est) * (p_truth[i] - mean_truth).transpose();
  }
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d& U = svd.matrixU();
  const Eigen::Matrix3d& V = svd.matrixV();
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  if ((V * U.transpose()).determinant() < 0.0) D(2, 2) = -1.0;
  const Eigen::Matrix3d R = V * D * U.transpose();
  const Eigen::Vector3d s = svd.singularValues();
  // Rank 2 still fixes the rotation (the det correction picks the third axis); rank <= 1 not.
  alignment->degenerate = !(s(0) > 0.0) || s(1) <= kDegenerateRatio * s(0);
  alignment->T_truth_est.linear() = R;
  alignment->T_truth_est.translation() = mean_truth - R * mean_est;
}

// Yaw about z plus translation: the closed-form 2D Umeyama fit the GNSS alignment uses.
void AlignFourDof(const std::vector<Eigen::Vector3d>& p_est,
                  const std::vector<Eigen::Vector3d>& p_truth,
                  Alignment* alignment) {
  bool degenerate = false;
  const geo::FourDof fit = geo::FitFourDof(p_est, p_truth, {}, &degenerate);
  alignment->degenerate = degenerate;
  alignment->T_truth_est = fit.Isometry();
}

}  // namespace

const char* ToString(AlignmentMode mode) {
  switch (mode) {
    case AlignmentMode::kNone:
      return "none";
    case AlignmentMode::kSe3:
      return "se3";
    case AlignmentMode::kFourDof:
      return "4dof";
  }
  return "unknown";
}

bool ParseAlignmentMode(const std::string& text, AlignmentMode* mode) {
  for (AlignmentMode m : {AlignmentMode::kNone, AlignmentMode::kSe3, AlignmentMode::kFourDof}) {
    if (text == ToString(m)) {
      *mode = m;
      return true;
    }
  }
  return false;
}

Alignment AlignPoints(const std::vector<Eigen::Vector3d>& p_est,
                      const std::vector<Eigen::Vector3d>& p_truth,
                      AlignmentMode mode) {
  Alignment alignment;
  alignment.mode = mode;
  alignment.num_points = std::min(p_est.size(), p_truth.size());
  if (p_est.size() != p_truth.size() || p_est.empty()) {
    alignment.degenerate = mode != AlignmentMode::kNone;
    return alignment;
  }
  switch (mode) {
    case AlignmentMode::kNone:
      break;
    case AlignmentMode::kSe3:
      AlignSe3(p_est, p_truth, &alignment);
      break;
    case AlignmentMode::kFourDof:
      AlignFourDof(p_est, p_truth, &alignment);
      break;
  }
  alignment.rmse_before_m = Rmse(p_est, p_truth, Eigen::Isometry3d::Identity());
  alignment.rmse_after_m = Rmse(p_est, p_truth, alignment.T_truth_est);
  return alignment;
}

double BestYaw(const Eigen::Matrix3d& R) {
  return std::atan2(R(1, 0) - R(0, 1), R(0, 0) + R(1, 1));
}

double RotationAngle(const Eigen::Matrix3d& R) {
  // atan2 of the axis-angle sine and cosine terms stays accurate near 0 and pi, unlike acos.
  const double cos_angle = 0.5 * (R.trace() - 1.0);
  const Eigen::Vector3d axis_sin(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
  return std::atan2(0.5 * axis_sin.norm(), cos_angle);
}

Eigen::Isometry3d AlignByPose(const Eigen::Isometry3d& T_world_est,
                              const Eigen::Isometry3d& T_world_truth,
                              AlignmentMode mode) {
  Eigen::Isometry3d T_truth_est = Eigen::Isometry3d::Identity();
  switch (mode) {
    case AlignmentMode::kNone:
      break;
    case AlignmentMode::kSe3:
      T_truth_est = T_world_truth * T_world_est.inverse();
      break;
    case AlignmentMode::kFourDof: {
      const Eigen::Matrix3d R_delta = T_world_truth.linear() * T_world_est.linear().transpose();
      const double yaw = BestYaw(R_delta);
      T_truth_est.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      T_truth_est.translation() =
          T_world_truth.translation() - T_truth_est.linear() * T_world_est.translation();
      break;
    }
  }
  return T_truth_est;
}

}  // namespace raillomer::eval
