#pragma once

#include <deque>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "estimator/factors/preintegration.h"

namespace ceres {
class CostFunction;
class LossFunction;
class Manifold;
class Problem;
}  // namespace ceres

namespace raillomer {

class MarginalizationInfo;

/// Options of the sliding-window smoother.
struct SlidingWindowOptions {
  int size = 6;                ///< states kept (eq. 2)
  int max_iterations = 20;     ///< Ceres iterations per Optimize()
  bool use_imu = true;         ///< false: states are poses only, linked by nothing but priors
  bool estimate_scale = true;  ///< false: the odometer scale stays at its initial value
  double initial_velocity_sigma_mps = 1.0;
  double initial_accel_bias_sigma = 3.0e-2;  ///< m/s^2: also takes up a residual tilt of ~0.2 deg
  /// m/s^2: the accelerometer bias prior after RotateWorld. The re-levelling took the bias as
  /// zero, so the tilt is as uncertain as the true bias; a loose prior here lets a bias (1 mrad of
  /// pitch per 0.01 m/s^2) take the place of gravity, and the pitch drifts with the LiDARs.
  double relevelled_accel_bias_sigma = 3.0e-3;
  double initial_gyro_bias_sigma = 2.0e-4;  ///< rad/s, about 5x an MTi-680G turn-on bias
  double initial_scale_sigma = 0.02;
  /// rad: prior of the odometer's misalignment (NavState::m: pitch, yaw) on the first state; a
  /// component of 0 is held at zero (the wheels' path is the odometer's x axis, as in the paper).
  Eigen::Vector2d initial_misalignment_sigma_rad = Eigen::Vector2d(3.0e-3, 0.0);
  int num_threads = 2;
};

/// One factor of the window: a cost, an optional robust loss, and the blocks it reads.
struct WindowTerm {
  std::shared_ptr<ceres::CostFunction> cost;
  std::shared_ptr<ceres::LossFunction> loss;
  std::vector<double*> blocks;
};

/// What one Optimize() did.
struct WindowSummary {
  int iterations = 0;
  double initial_cost = 0.0;
  double final_cost = 0.0;
  int residual_blocks = 0;
  bool converged = false;
};

/// The keyframe sliding window of eq. (2): states x_i = [p, v, q, b_a, b_g, c^O, m] linked by
/// IMU/odometer preintegration factors, with LiDAR, rail-plane and height-descriptor factors,
/// and a Schur-complement prior carrying what marginalised states knew.
class SlidingWindow {
 public:
  explicit SlidingWindow(const SlidingWindowOptions& options);
  ~SlidingWindow();
  SlidingWindow(const SlidingWindow&) = delete;
  SlidingWindow& operator=(const SlidingWindow&) = delete;

  /// Appends a state at time t_s. `preintegration` links it to the previous state (ignored for
  /// the first state, which gets priors instead, and when !use_imu).
  void Push(double t_s, const NavState& state, std::shared_ptr<Preintegration> preintegration);

  /// Replaces the LiDAR factor of the newest state: one cost over its pose block (a
  /// LidarFrameCost, robust within), or none when null.
  void SetNewestLidarFactor(std::shared_ptr<ceres::CostFunction> cost);
  /// Adds a factor over the poses of the two newest states (rail plane, longitudinal shift).
  void AddNewestPairFactor(std::shared_ptr<ceres::CostFunction> cost,
                           std::shared_ptr<ceres::LossFunction> loss);

  /// Adds a factor over the newest state's pose alone (the straight track's heading hold);
  /// ClearUnaryFactors() takes every such factor off the states still in the window.
  void AddNewestUnaryFactor(std::shared_ptr<ceres::CostFunction> cost);
  void ClearUnaryFactors();

  /// Solves the window (relinearising preintegrations whose biases moved).
  WindowSummary Optimize();

  /// True once the window holds more than `size` states: then PopOldest() must be called.
  bool Full() const;
  /// Marginalises the oldest state into the prior and removes it; returns its final state.
  NavState PopOldest(double* t_s);

  int size() const { return static_cast<int>(nodes_.size()); }
  NavState State(int index) const;
  double Time(int index) const;
  NavState Newest() const { return State(size() - 1); }
  /// The newest state's pose block (7 doubles), e.g. to build its factors.
  double* NewestPose();

  /// Re-levels the world frame: rotates every state (position, attitude, velocity) by
  /// R_new_old about the origin and zeroes the accelerometer biases, which had absorbed the
  /// old frame's tilt. With `forget_tilt_gyro_bias` the gyro's roll and pitch biases are zeroed
  /// too: in a frame levelled far off, they had turned the states towards the tilt that the
  /// odometer and the LiDARs asked for. The LiDAR factors (tied to the old frame's map) are
  /// dropped and the marginalisation prior is replaced by fresh priors on the oldest state; the
  /// unary factors (held in the old frame) are dropped too.
  void RotateWorld(const Eigen::Matrix3d& R_new_old, bool forget_tilt_gyro_bias = false);

 private:
  /// Relinearises the preintegrations whose biases or scale moved far from their
  /// linearisation point.
  void RelinearizeDrifted();
  /// The states' blocks, the odometer's held constant while it is held, and without the IMU
  /// every state but the newest.
  void AddParameterBlocks(ceres::Problem* problem) const;
  struct Node;
  std::vector<WindowTerm> AllTerms() const;
  /// The priors that anchor the frame at a state (the first one, or after RotateWorld).
  void AddAnchorPriors(Node* node, double accel_bias_sigma) const;

  SlidingWindowOptions options_;
  /// The odometer block's components held constant (the scale when not estimated, each
  /// misalignment component whose prior is 0), and the manifold holding them (null when none
  /// or all are held; all held, the block is set constant).
  std::vector<int> odometer_held_;
  std::unique_ptr<ceres::Manifold> odometer_manifold_;
  std::deque<std::unique_ptr<Node>> nodes_;
  WindowTerm prior_term_;
  bool has_prior_ = false;
};

}  // namespace raillomer
