#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "estimator/geo/gnss.h"
#include "estimator/io/sensor_messages.h"

namespace raillomer {

/// Options of the GNSS fusion (paper IV.A and IV.D).
struct GnssFusionOptions {
  geo::UtmZone zone;                                         ///< the run's zone (rig utm_zone)
  Eigen::Vector3d p_body_antenna = Eigen::Vector3d::Zero();  ///< antenna lever arm, body frame
  /// A GNSS factor joins the pose graph at most this often (paper: every 10 s).
  double factor_period_s = 10.0;
  /// The noise the factor assumes. The receiver's reported covariance is not used: SPP
  /// receivers claim decimetres while their errors wander by metres over minutes.
  double sigma_horizontal_m = 1.0;
  double sigma_vertical_m = 2.5;
  /// Fixes whose horizontal distance from the prediction exceeds gate_m plus three times the
  /// odometry drift since the last accepted fix are multipath outliers.
  double gate_m = 5.0;
  /// Odometry drift assumed per metre travelled: position (fraction) and heading (rad/m).
  double drift_fraction = 0.005;
  double yaw_drift_rad_per_m = 5e-6;
  int max_nodes = 60;  ///< pose-graph nodes kept (one per factor)
  /// After this many consecutive rejected fixes that agree with each other within
  /// 2 * sigma_horizontal_m, the alignment is re-solved on the recent fixes.
  int resolve_after_rejections = 8;
  double resolve_window_s = 60.0;
  geo::GnssAlignmentOptions alignment;
  geo::FixCheckOptions check;
};

/// Counters of the GNSS fusion.
struct GnssFusionStats {
  uint64_t fixes = 0;     ///< usable fixes received
  uint64_t rejected = 0;  ///< unusable fixes (see warnings for the reasons)
  uint64_t outliers = 0;  ///< usable fixes gated out as multipath
  uint64_t factors = 0;   ///< GNSS factors added
  uint64_t realignments = 0;
};

/// Georeferences the odometry with GNSS: aligns the odometry frame to UTM in 4-DoF once the
/// train has moved far enough (eq. 3-6), then keeps a 4-DoF pose graph of the odometry at the
/// fix epochs with a GNSS factor every factor_period_s (eq. 31, robust Cauchy loss behind an
/// innovation gate; its fix is the median of the period's accepted fixes, carried to the
/// factor's epoch by the odometry), and maps each odometry pose into a local ENU frame (UTM minus
/// origin_utm) with the newest correction. The odometry itself is not changed: its local map stays
/// consistent, and the correction is a smooth 4-DoF drift removal on top.
class GnssFusion {
 public:
  /// `warn` gets problems (rejected fixes, outliers), `info` the alignments; either may be
  /// empty.
  GnssFusion(const GnssFusionOptions& options,
             std::function<void(const std::string&)> warn,
             std::function<void(const std::string&)> info);

  /// A fix from the receiver (any order relative to the odometry, within a few seconds).
  void AddFix(const io::GnssFix& fix);
  /// A final odometry pose (time order). Fixes up to this time are processed.
  void AddOdometry(int64_t stamp_ns, const Eigen::Isometry3d& T_odom_body);

  bool aligned() const { return aligned_; }
  /// UTM (easting, northing, height) of the local ENU frame's origin; valid once aligned.
  const Eigen::Vector3d& origin_utm() const { return origin_utm_; }
  /// An odometry pose in the local ENU frame with the newest correction (valid once aligned).
  Eigen::Isometry3d ToEnu(const Eigen::Isometry3d& T_odom_body) const;
  const GnssFusionStats& stats() const { return stats_; }
  /// The UTM zone in use (the rig's, or the first fix's standard zone).
  const geo::UtmZone& zone() const { return options_.zone; }
  /// Why the alignment has not happened yet (empty once aligned).
  const std::string& pending_reason() const { return pending_reason_; }

 private:
  struct Pair {
    double t_s;
    Eigen::Vector3d antenna_odom;  ///< odometry antenna position at the fix epoch
    Eigen::Vector3d fix_enu;
    double distance_m;  ///< odometry path length at the fix epoch
  };
  struct Node {
    double x[4];             ///< georeferenced [x, y, z, yaw] (ENU)
    Eigen::Vector3d p_odom;  ///< odometry position
    double yaw_odom = 0.0;   ///< odometry yaw
    double distance_m = 0.0;
    Eigen::Vector3d fix_enu;           ///< the node's GNSS fix
    Eigen::Vector3d antenna_levelled;  ///< lever arm rotated by roll and pitch
  };
  void Process(const Pair& pair, const Eigen::Isometry3d& T_odom_body);
  bool OdometryAt(double t_s, Eigen::Isometry3d* T, double* distance_m) const;
  void Align(const std::vector<Pair>& pairs, bool resolve);
  void AddNode(const Pair& pair, const Eigen::Isometry3d& T_odom_body);
  void Optimize();
  void Warn(const std::string& key, const std::string& message);

  GnssFusionOptions options_;
  std::function<void(const std::string&)> warn_, info_;
  GnssFusionStats stats_;
  std::map<std::string, uint64_t> warning_counts_;

  std::deque<std::pair<double, Eigen::Vector3d>> pending_fixes_;  ///< (t, utm) not yet paired
  std::deque<std::pair<double, Eigen::Isometry3d>> odometry_;     ///< recent poses
  std::deque<double> odometry_distance_m_;
  double distance_m_ = 0.0;
  bool have_origin_ = false;
  Eigen::Vector3d origin_utm_ = Eigen::Vector3d::Zero();
  std::deque<Pair> pairs_;  ///< recent fixes with their odometry (alignment and re-solving)

  bool aligned_ = false;
  std::string pending_reason_ = "no usable GNSS fix yet";
  geo::FourDof correction_;  ///< odometry frame -> ENU, from the newest node
  std::deque<Node> nodes_;
  bool nodes_dropped_ = false;  ///< the graph has slid: the oldest node carries a prior
  double last_factor_t_s_ = -1e300;
  std::vector<Eigen::Vector3d> period_innovations_;  ///< accepted since the last factor
  double last_accept_distance_m_ = 0.0;
  std::vector<Eigen::Vector2d> rejected_innovations_;
};

}  // namespace raillomer
