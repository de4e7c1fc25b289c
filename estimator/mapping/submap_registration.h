#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer {

/// The outcome of one registration: the pose of the source frame in the target frame.
struct Registration {
  bool converged = false;   ///< within the iteration limit, with enough overlap
  int iterations = 0;       ///< NDT: iterations of its last pass (PCL's ICP does not report them)
  double fitness_m2 = 0.0;  ///< mean squared distance of the matched points
  Eigen::Isometry3d T_target_source = Eigen::Isometry3d::Identity();
  /// NDT only: the information (negative Hessian of the score) at the result, for telling
  /// well-constrained directions from degenerate ones. Parameters: the translation, then the
  /// turns about x, y and z, all about the source frame's origin.
  Eigen::Matrix<double, 6, 6> information = Eigen::Matrix<double, 6, 6>::Zero();
};

struct IcpOptions {
  int max_iterations = 30;
  double max_correspondence_m = 0.6;
  double source_voxel_m = 0.4;  ///< the source is thinned to one point per voxel first
  double transformation_epsilon = 1e-6;
};

struct NdtOptions {
  /// The target's normal-distribution cell size.
  double resolution_m = 1.0;
  /// A first pass at twice the resolution widens the capture range (for poor guesses).
  bool coarse_pass = true;
  int max_iterations = 35;
  double step_size_m = 0.1;
  /// NDT stops when a step moves the translation by less than this squared (m^2). PCL checks
  /// the translation only: at 1e-5 (3 mm) a guess off by a rotation about the cloud's origin
  /// stopped after a step or two with most of a milliradian of pitch left in place. At 1e-6
  /// (1 mm) it goes on; 1e-8 made the maps no sharper and cost a fifth of the speed.
  double transformation_epsilon = 1e-6;
  double source_voxel_m = 0.5;
  /// ...and then cut to at most this many by an even stride: NDT's cost grows with the source.
  size_t max_source_points = 5000;
};

/// Point-to-point ICP (PCL) of `source` onto `target`, starting from `guess` (both clouds in
/// metric frames near their origins: never UTM coordinates in floats). Converged means PCL
/// converged before max_iterations.
Registration IcpRegister(const std::vector<Eigen::Vector3f>& source,
                         const std::vector<Eigen::Vector3f>& target,
                         const Eigen::Isometry3d& guess,
                         const IcpOptions& options);

/// The normal distributions transform (PCL) of `source` onto `target` from `guess`, coarse to
/// fine. Converged means both passes converged before max_iterations.
Registration NdtRegister(const std::vector<Eigen::Vector3f>& source,
                         const std::vector<Eigen::Vector3f>& target,
                         const Eigen::Isometry3d& guess,
                         const NdtOptions& options);

/// How far a registration moved a pose from its guess: translation (m) and rotation (rad).
void CorrectionSize(const Eigen::Isometry3d& guess,
                    const Eigen::Isometry3d& result,
                    double* translation_m,
                    double* rotation_rad);

/// Takes the turn about the vertical out of an NDT correction `delta` (about the clouds' origin)
/// where the registration sees it poorly, and re-solves the other five directions with the turn
/// held: on the score's quadratic model about the result (`information`, as in Registration),
/// the best correction whose turn about `pivot` is zero. The turn counts as seen where its
/// information (the other directions free) is at least that of the strongest translation at a
/// lever arm of `min_arm_m`. Returns true when the turn was held.
bool HoldPoorlySeenTurn(const Eigen::Matrix<double, 6, 6>& information,
                        const Eigen::Vector3d& pivot,
                        double min_arm_m,
                        Eigen::Isometry3d* delta);

}  // namespace raillomer
