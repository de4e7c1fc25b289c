#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/backend/local_map.h"
#include "estimator/preprocess/scan.h"

namespace raillomer {

/// A planar feature point (body frame) and the map plane n . x + d = 0 it lies on (world).
struct PlaneMatch {
  Eigen::Vector3d p_body;
  Eigen::Vector3d normal;
  double d = 0.0;
};

/// An edge feature point (body frame) and the map line through `point` along `direction`.
struct LineMatch {
  Eigen::Vector3d p_body;
  Eigen::Vector3d point;
  Eigen::Vector3d direction;
  /// Its map neighbours spread more than MatchOptions::line_soft_spread_m about their line.
  bool soft = false;
};

/// Correspondences of one LiDAR frame against the local map (eq. 20-21).
struct LidarMatches {
  std::vector<PlaneMatch> planes;
  std::vector<LineMatch> lines;
  size_t size() const { return planes.size() + lines.size(); }
};

/// Options of the correspondence search.
struct MatchOptions {
  int neighbours = 5;                 ///< the paper's 5 nearest map points
  double max_distance_m = 1.0;        ///< neighbours farther than this are not used
  double plane_max_residual_m = 0.2;  ///< every neighbour within this of its fitted plane
  double line_min_ratio = 3.0;        ///< largest / second eigenvalue of an edge's neighbours
  double line_max_spread_m = 0.0;     ///< > 0: RMS distance of an edge's neighbours from their line
  /// > 0: an edge whose neighbours spread more than this about their line is marked soft.
  double line_soft_spread_m = 0.0;
};

/// Finds plane and line correspondences for the features moved to the world by T_world_body.
LidarMatches MatchFeatures(const MatchOptions& options,
                           const FeatureSet& features,
                           const Eigen::Isometry3d& T_world_body,
                           const LocalMap& edge_map,
                           const LocalMap& plane_map);

/// The LiDAR-only solution of one frame's matches: its pose, and how well the matches constrain
/// it (the degeneracy measure of Zhang et al., used by eq. 25).
struct LidarOnlySolution {
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
  /// Smallest eigenvalue of the per-residual information of the translation (rotation
  /// eliminated by a Schur complement): about 1/3 when planes face every way, near 0 when a
  /// direction is unobserved (a long straight cutting).
  double degeneracy = 0.0;
  Eigen::Vector3d weakest_direction = Eigen::Vector3d::UnitX();  ///< world frame
  /// Per-residual information on the heading (rotation about world z) with the other five
  /// directions free, in 1/rad^2: how well the matches alone hold the heading.
  double heading_information = 0.0;
  /// The heading's profile at `T_linearized` (the pose the last iteration started from): for
  /// a pose moved from it by dp (world) and turned by phi (world rotation vector), the turn
  /// about world z the matches would then make, to first order,
  /// heading_z0 + heading_gain . [dp; phi_x; phi_y] (PoseRemapping).
  Eigen::Isometry3d T_linearized = Eigen::Isometry3d::Identity();
  double heading_z0 = 0.0;
  Eigen::Matrix<double, 5, 1> heading_gain = Eigen::Matrix<double, 5, 1>::Zero();
  int iterations = 0;
  bool converged = false;
};

/// Gauss-Newton on the point-to-plane and point-to-line distances of `matches` from `T_init`.
LidarOnlySolution SolveLidarOnly(const LidarMatches& matches,
                                 const Eigen::Isometry3d& T_init,
                                 int max_iterations);

}  // namespace raillomer
