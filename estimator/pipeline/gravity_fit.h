#pragma once

#include <Eigen/Core>

namespace raillomer {

/// Gravity in the world frame from the IMU against an estimated trajectory, for re-levelling
/// a frame that was levelled poorly (a start at speed, or moving off within the first
/// seconds). Over the states k of a stretch without gaps, the IMU's velocity increments rotated
/// into the world (accelerometer bias taken as zero) add up to the velocity change plus
/// gravity times the time: c_k = sum_{i <= k} R_i beta_i = v_k - v_0 + g t_k. Gravity is the
/// slope of the straight line through c_k - v_k against t_k, fitted over every state: taken
/// between the first and the last state alone, one velocity error e tilts the result by
/// e / (g T), and the first state's, straight after the initial levelling, is the worst. A gap
/// starts a new line, with its own offset and the same slope.
class GravityFit {
 public:
  /// Starts a line at a state of world velocity v (m/s).
  void Start(const Eigen::Vector3d& v);
  /// The next state on the line, dt_s after the previous one, with the IMU's velocity
  /// increment over the interval rotated into the world, R beta (m/s; gravity included, as the
  /// accelerometer reads it), and the state's velocity v. Before any Start() it starts the line
  /// at v instead.
  void Add(double dt_s, const Eigen::Vector3d& world_increment, const Eigen::Vector3d& v);
  /// Time covered by the lines (s).
  double duration_s() const { return duration_s_; }
  /// Gravity as the accelerometer reads it at rest (pointing up, m/s^2); false while no line
  /// spans any time.
  bool Gravity(Eigen::Vector3d* g) const;

 private:
  /// Adds the open line's centred sums (of t^2 and of t y) to *sxx and *sxy.
  void AddOpenLine(double* sxx, Eigen::Vector3d* sxy) const;
  void CloseLine();

  // The open line's sums: states, t, t^2, y and t y, with y = c - v.
  int n_ = 0;
  double t_ = 0.0, sum_t_ = 0.0, sum_tt_ = 0.0;
  Eigen::Vector3d c_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d sum_y_ = Eigen::Vector3d::Zero(), sum_ty_ = Eigen::Vector3d::Zero();
  // The closed lines' centred sums.
  double sxx_ = 0.0;
  Eigen::Vector3d sxy_ = Eigen::Vector3d::Zero();
  double duration_s_ = 0.0;
};

}  // namespace raillomer
