#pragma once

// Registration bias at true poses: how far the scan-to-map registration pulls a frame away from
// the truth when both the frame and the local map are placed exactly. The estimator's own
// feature extraction and matching run on the simulator's LiDAR frames, each deskewed with the
// true motion and matched at its true pose against a map of the earlier frames' features placed
// at their true poses; the LiDAR-only solution from there is the pull. A pull that keeps its
// sign frame after frame is a bias: the estimator's map follows its own estimates, so such a
// bias turns into drift (and into its IMU bias estimates) rather than averaging out.

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/backend/scan_matching.h"

namespace raillomer {
struct EstimatorConfig;
namespace sim {
class Simulator;
}
}  // namespace raillomer

namespace raillomer::eval {

/// Where a solution lies from the truth, in the true body frame: T_true^-1 T_solution as a
/// translation (m) and a rotation vector (rad; x roll, y pitch, z yaw).
struct PosePull {
  Eigen::Vector3d translation_m = Eigen::Vector3d::Zero();
  Eigen::Vector3d rotation_rad = Eigen::Vector3d::Zero();
};

/// Where the LiDAR-only solution of `matches` (SolveLidarOnly from T_world_body_start, the pose
/// they were matched at) lies from the truth.
PosePull RegistrationPull(const LidarMatches& matches,
                          const Eigen::Isometry3d& T_world_body_start,
                          const Eigen::Isometry3d& T_world_body_true,
                          int iterations);

struct RegistrationBiasOptions {
  double duration_s = 0.0;  ///< 0: the whole scenario
  double window_s = 5.0;    ///< the report's time windows
  int min_matches = 50;     ///< a frame (or one LiDAR of it) with fewer is not solved
  int iterations = 4;       ///< of the LiDAR-only solution
  /// Each frame is matched and solved from truth * start_offset (body frame) instead of the
  /// truth: the pull then shows how much of such an error the registration takes back.
  Eigen::Isometry3d start_offset = Eigen::Isometry3d::Identity();
  /// Which matches the solutions use: a pull that one class alone shows is that class's.
  enum class Matches { kAll, kPlanes, kEdges };
  Matches matches = Matches::kAll;
};

/// The mean pull over a span of frames.
struct PullSummary {
  int frames = 0;  ///< frames solved
  PosePull mean;
};

struct RegistrationBiasWindow {
  double t_from_s = 0.0, t_to_s = 0.0;  ///< scenario time
  PullSummary both;                     ///< all LiDARs' matches together
};

struct RegistrationBiasReport {
  int frames = 0;    ///< frames with at least one LiDAR
  PullSummary both;  ///< all LiDARs' matches together, whole run
  std::vector<std::string> lidar_names;
  std::vector<PullSummary> per_lidar;  ///< each LiDAR's matches alone, whole run
  std::vector<RegistrationBiasWindow> windows;
};

/// Runs the simulator to its end (or options.duration_s) and measures the pulls with the
/// estimator configuration `config` (its rig must be the simulator's: raillomer-sim's rig.yaml,
/// optionally with an `estimator:` section). `progress` (may be empty) gets the scenario time
/// now and then. False with `error` set when the rig and the simulator do not fit together.
bool MeasureRegistrationBias(sim::Simulator* simulator,
                             const EstimatorConfig& config,
                             const RegistrationBiasOptions& options,
                             RegistrationBiasReport* report,
                             std::string* error,
                             const std::function<void(double)>& progress = {});

}  // namespace raillomer::eval
