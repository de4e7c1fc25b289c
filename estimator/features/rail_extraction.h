#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace raillomer {

/// Options of the rail-track extraction (paper IV.C, Fig. 8), for the down-looking LiDAR.
struct RailExtractionOptions {
  double body_above_rail_top_m = 3.8;   ///< rig: body (IMU) origin above the rail top
  double gauge_m = 1.435;               ///< track gauge
  double rail_head_width_m = 0.07;      ///< region-growing distance to a fitted line
  double candidate_half_width_m = 0.5;  ///< search band around each nominal rail
  double seed_length_m = 3.0;           ///< initial seed area length (from the nearest return)
  double max_length_m = 20.0;           ///< rails are grown to this length from the seed start
  double min_forward_m = 3.0;           ///< ignore points closer than this along x
  double max_forward_m = 60.0;          ///< ignore points farther than this along x
  double max_tilt_deg = 3.0;            ///< body roll/pitch allowance of the track-bed band
  double min_rail_height_m = 0.1;       ///< a seed line must stand this far above the bed
  int ransac_iterations = 100;          ///< of the seed line pair and of the rail plane
  int min_rail_points = 30;             ///< per rail, else extraction fails
  uint32_t random_seed = 1;             ///< RANSAC sampling (deterministic per call)
  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// The two rails under the vehicle and the rail plane, in the body frame.
struct RailExtraction {
  bool ok = false;
  std::string failure;  ///< why not ok
  /// Each rail as a line: a point and a unit direction.
  Eigen::Vector3d left_point = Eigen::Vector3d::Zero(), left_direction = Eigen::Vector3d::UnitX();
  Eigen::Vector3d right_point = Eigen::Vector3d::Zero(), right_direction = Eigen::Vector3d::UnitX();
  std::vector<Eigen::Vector3f> left_points, right_points;  ///< grown rail-head points
  /// Rail plane n . x + d = 0, unit n pointing up (n.z > 0), body frame (eq. 28-30).
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  double distance = 0.0;
  double plane_rms_m = 0.0;  ///< RMS distance of the rail points to the plane
};

/// Finds the track bed from the mounting geometry, takes local-maximum-height candidates near
/// each rail, fits a RANSAC line per rail, grows each within rail_head_width_m up to
/// max_length_m, and fits the rail plane to both rails. `points_body` are the down LiDAR's
/// deskewed points in the body frame. The seed lines are found as a pair one gauge apart, the
/// rails grow as a parallel pair that may bend (curves), and the plane is fitted to the rail
/// tops. Fails (ok false, `failure` says why) without two rails, e.g. no track in view.
RailExtraction ExtractRails(const RailExtractionOptions& options,
                            const std::vector<Eigen::Vector3f>& points_body);

}  // namespace raillomer
