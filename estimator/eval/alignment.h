#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer::eval {

/// Degrees of freedom removed before the estimate is compared with the truth.
enum class AlignmentMode {
  kNone,     ///< Compared as they are (georeferenced output).
  kSe3,      ///< Rotation and translation, no scale (Umeyama / Horn).
  kFourDof,  ///< Yaw about z plus 3D translation; roll and pitch errors stay visible.
};

/// "none", "se3" or "4dof".
const char* ToString(AlignmentMode mode);

/// Parses "none", "se3" or "4dof"; false on anything else.
bool ParseAlignmentMode(const std::string& text, AlignmentMode* mode);

/// A rigid transform that maps the estimate's world frame onto the truth's, with diagnostics.
struct Alignment {
  AlignmentMode mode = AlignmentMode::kNone;
  /// p_truth ~= T_truth_est * p_est.
  Eigen::Isometry3d T_truth_est = Eigen::Isometry3d::Identity();
  /// Number of point pairs used.
  size_t num_points = 0;
  /// True if the rotation is not unique (e.g. all points on a line, or a single point).
  bool degenerate = false;
  /// RMS position difference before and after applying T_truth_est (m).
  double rmse_before_m = 0.0;
  double rmse_after_m = 0.0;
};

/// Least-squares alignment of p_est onto p_truth (same length) in the given degrees of freedom:
/// se3 by Umeyama without scale, 4dof by closed-form 2D Umeyama on xy plus the mean z offset.
Alignment AlignPoints(const std::vector<Eigen::Vector3d>& p_est,
                      const std::vector<Eigen::Vector3d>& p_truth,
                      AlignmentMode mode);

/// Transform that makes one estimate pose coincide with one truth pose in the given degrees of
/// freedom (none: identity; 4dof: best yaw and the position; se3: the whole pose).
Eigen::Isometry3d AlignByPose(const Eigen::Isometry3d& T_world_est,
                              const Eigen::Isometry3d& T_world_truth,
                              AlignmentMode mode);

/// The yaw angle whose rotation about z is closest to R (maximises trace(Rz(yaw)^T R)), rad.
double BestYaw(const Eigen::Matrix3d& R);

/// Rotation angle of R in radians, in [0, pi].
double RotationAngle(const Eigen::Matrix3d& R);

}  // namespace raillomer::eval
