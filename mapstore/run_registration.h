#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer::mapstore {

/// Settings of the run-to-run registration of one stretch.
struct RegistrationOptions {
  /// Coarse to fine: the first stage pairs points up to this far apart (the runs' GNSS
  /// placements differ by metres), each next stage half as far, down to max_correspondence_m;
  /// each stage thins both clouds to voxels of a fifth of its distance (at least voxel_m).
  double initial_correspondence_m = 4.0;
  double max_correspondence_m = 0.5;
  double voxel_m = 0.2;
  double normal_radius_m = 0.5;  ///< a fixed point's neighbourhood for its surface normal
  /// A neighbourhood is a plane when its smallest eigenvalue is below this share of the sum;
  /// other points pair point to point.
  double planarity = 0.05;
  int max_iterations = 30;  ///< per stage
  /// Each stage pairs at most this many of the moving cloud's voxel centroids (an even
  /// sample): a stretch's structure is told by far fewer than its hundreds of thousands.
  size_t max_moving_points = 60000;
  /// ... and the stages before the last at most this many: they only bring the clouds within
  /// the last stage's reach.
  size_t coarse_moving_points = 15000;
  /// The robust kernel's (Geman-McClure) scale: 1.5 times the median residual, never below
  /// half the stage's correspondence distance nor this, so that what changed between the runs
  /// does not pull.
  double kernel_floor_m = 0.03;
  double converged_step_m = 0.0005;  ///< stop when a step moves the cloud less than this
  /// The stages before the last stop sooner, when a step moves the cloud less than this share
  /// of their correspondence distance: the next stage starts within its reach all the same.
  double coarse_converged_share = 0.01;
  bool IsValid(std::string* error) const;
};

/// What a registration came to.
struct RegistrationResult {
  Eigen::Isometry3d T_fixed_moving = Eigen::Isometry3d::Identity();
  bool converged = false;
  int iterations = 0;
  size_t pairs = 0;    ///< correspondences in the last iteration
  size_t inliers = 0;  ///< of them within the kernel's scale
  double rms_m = 0.0;  ///< RMS of the inliers' residuals (point to plane where planar)
  /// The smallest eigenvalue of the normal equations' translation block over the largest: near
  /// zero where the stretch cannot tell a shift (a featureless straight along the track).
  double translation_conditioning = 0.0;
};

/// Registers `moving` onto `fixed`, robust point-to-plane ICP from `initial` (T_fixed_moving).
/// Both clouds are in one local frame with coordinates of a few hundred metres at most (take
/// UTM minus a stretch origin): doubles, but small.
RegistrationResult RegisterClouds(const std::vector<Eigen::Vector3d>& fixed,
                                  const std::vector<Eigen::Vector3d>& moving,
                                  const Eigen::Isometry3d& initial,
                                  const RegistrationOptions& options);

/// A fixed cloud to register clouds onto, one after another: its voxel centroids, normals and
/// grids for each stage are worked out once, for all of them.
class RegistrationTarget {
 public:
  /// Keeps a reference to `fixed`, which must outlive the target.
  RegistrationTarget(const std::vector<Eigen::Vector3d>& fixed, const RegistrationOptions& o);
  ~RegistrationTarget();
  RegistrationTarget(const RegistrationTarget&) = delete;
  RegistrationTarget& operator=(const RegistrationTarget&) = delete;

  /// Registers `moving` as RegisterClouds does.
  RegistrationResult Register(const std::vector<Eigen::Vector3d>& moving,
                              const Eigen::Isometry3d& initial);
  /// How well `moving` fits at `T_fixed_moving` as it stands: the pairs, inliers and RMS of
  /// the last stage's first iteration, the transform unchanged.
  RegistrationResult Check(const std::vector<Eigen::Vector3d>& moving,
                           const Eigen::Isometry3d& T_fixed_moving);

 private:
  struct Level;
  /// The fixed cloud at a stage's voxel side, made on first use.
  Level& LevelFor(double voxel_m);
  /// One stage (`stage.voxel_m` its voxels, `distance` its correspondence distance) on
  /// `moving`, thinned to those voxels; false if either cloud is too small to pair.
  bool RunStage(const std::vector<Eigen::Vector3d>& moving,
                double distance,
                const RegistrationOptions& stage,
                RegistrationResult* result);

  const std::vector<Eigen::Vector3d>& points_;
  RegistrationOptions o_;
  std::vector<std::pair<double, std::unique_ptr<Level>>> levels_;
};

/// The centroids of the points in each voxel of side `voxel_m`.
std::vector<Eigen::Vector3d> VoxelCentroids(const std::vector<Eigen::Vector3d>& points,
                                            double voxel_m);

}  // namespace raillomer::mapstore
