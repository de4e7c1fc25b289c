#pragma once

#include <cmath>
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
  /// The factor's fix is the median of the accepted fixes in a window of this length centred
  /// on the factor's epoch, each carried to the epoch by the odometry: enough fixes to outvote
  /// a multipath jump that got through the gate. The factor joins the graph half a window
  /// after its epoch.
  double factor_window_s = 10.0;
  /// The noise the factor assumes. The receiver's reported covariance is not used: SPP
  /// receivers claim decimetres while their errors wander by metres over minutes.
  double sigma_horizontal_m = 1.0;
  double sigma_vertical_m = 2.5;
  /// Fixes whose horizontal distance from the prediction exceeds gate_m plus three times the
  /// odometry drift since the last accepted fix are multipath outliers.
  double gate_m = 5.0;
  /// Odometry drift assumed per metre travelled: position (fraction) and heading (rad/m).
  double drift_fraction = 0.005;
  /// The same for the odometry's height between two nodes (plus 5 cm). Linked tightly in
  /// height, the graph averages the receiver's wandering height over many nodes instead of
  /// following it; that pays only where the odometry's height holds. The default odometry
  /// climbs at up to 0.7 mrad (at constant speed its pitch and the accelerometer's x bias
  /// trade; at most 0.34 mrad through tunnel_gnss_outage's tunnel, GNSS off), so the default
  /// leaves it 1 mrad. At the horizontal fraction's 0.005 the graph took in the receiver's height
  /// wherever it came back from an outage 2-4 m off; 0.0003 suits an odometry with a tight
  /// accelerometer bias prior (docs/notebook/estimator-results.md: the height).
  double vertical_drift_fraction = 0.001;
  double yaw_drift_rad_per_m = 5e-6;
  /// The graph also estimates the odometry's systematic drift over its window, a scale error
  /// and a heading drift per metre, with these prior spreads around zero; the newest estimate
  /// also corrects the poses after the newest node.
  double scale_prior_sigma = 0.01;
  double heading_drift_prior_sigma_rad_per_m = 2e-5;
  int max_nodes = 60;  ///< pose-graph nodes kept (one per factor)
  /// Published poses stay continuous: when a re-solve moves the graph under poses already
  /// published, the difference fades out over this much travel (m) instead of stepping the
  /// trajectory, which would tear the map at the step. 0 publishes the graph as it stands.
  double continuity_length_m = 200.0;
  /// No pose is settled before the graph has this many nodes: the first nodes' headings rest
  /// on the alignment's short baseline and still move by milliradians.
  int min_settled_nodes = 3;
  /// When GNSS returns after a gap (no factor for more than 1.5 factor periods, e.g. a tunnel)
  /// or the alignment is re-solved, a horizontal difference above this (m) is applied at once,
  /// the height still fading: the graph then corrects drift it could not see. Any other re-solve
  /// fades, however far it moves the graph: the receiver's height wanders by metres, and a new node
  /// moved the graph's height by 0.5-0.9 m on 10 of the 19 suite runs, a step in the trajectory.
  /// The submap chain's target (MapTarget) takes every move above this at once.
  double continuity_max_step_m = 0.5;
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

  /// The end of the run: a last factor on the newest fixes, if any came after the newest one.
  void Finish();

  bool aligned() const { return aligned_; }
  /// Counts the alignments and the graph's solves: poses placed by ToEnu under one revision
  /// fit one another; a new revision can move the newest poses' placement.
  uint64_t revision() const { return revision_; }
  /// UTM (easting, northing, height) of the local ENU frame's origin; valid once aligned.
  const Eigen::Vector3d& origin_utm() const { return origin_utm_; }
  /// An odometry pose in the local ENU frame with the newest correction (valid once aligned).
  Eigen::Isometry3d ToEnu(const Eigen::Isometry3d& T_odom_body) const;
  /// The same for a pose at time t_s, smoothed: a pose between two nodes of the graph is
  /// carried from both and blended, so the drift between them is spread over the span instead
  /// of showing as a jump at the newer node. Poses after the newest node are extrapolated.
  Eigen::Isometry3d ToEnu(const Eigen::Isometry3d& T_odom_body, double t_s) const;
  /// The pose to publish for the odometry pose at time t_s (time order): ToEnu(T, t_s), plus
  /// how far the graph has moved the last published position since it went out, fading with
  /// exp(-travel / continuity_length_m); after a GNSS gap or a re-solved alignment, a
  /// horizontal move above continuity_max_step_m is taken at once instead (the height still
  /// fades). Valid once aligned.
  Eigen::Isometry3d Publish(const Eigen::Isometry3d& T_odom_body, double t_s);
  /// Where the submap chain is pulled for the odometry pose at time t_s (time order, every
  /// pose): as Publish, but any move above continuity_max_step_m is taken at once. The chain
  /// smooths the pull itself (SubmapOptions); pulled towards Publish's faded pose instead, two
  /// suite runs' worst rail segments went from 2.0 and 2.6 cm to 3.3 cm. Valid once aligned.
  Eigen::Isometry3d MapTarget(const Eigen::Isometry3d& T_odom_body, double t_s);
  /// The odometry's scale error as the graph estimates it: true distance = scale x odometry.
  double odometry_scale() const { return std::exp(drift_[0]); }
  /// Poses up to this time lie between nodes of the graph (-inf before the first).
  double settled_until_s() const;
  /// How long a consumer holds poses for the fusion (the estimator, raillomer-gnss-replay).
  /// Not aligned yet with poses held over `held_s`: true once that reaches max_hold_s (30 s
  /// while no usable fix has come at all), when the run should stay in the local frame.
  bool AlignmentOverdue(double held_s, double max_hold_s) const;
  /// Aligned: the pose at t_s may go out once the graph has a node after it (it is then smoothed
  /// between two nodes); once it has waited prompt_latency_s behind the newest pose (newest_s)
  /// while the graph keeps pace (settled, a recent node, fixes still accepted; 0: off); or once
  /// it has waited max_latency_s (a GNSS outage). The latter two are carried from the newest
  /// node.
  bool Releases(double t_s, double newest_s, double prompt_latency_s, double max_latency_s) const;
  const GnssFusionStats& stats() const { return stats_; }
  /// The UTM zone in use (the rig's, or the first fix's standard zone).
  const geo::UtmZone& zone() const { return options_.zone; }
  /// Why the alignment has not happened yet (empty once aligned).
  const std::string& pending_reason() const { return pending_reason_; }

 private:
  struct Pair {
    double t_s;
    Eigen::Isometry3d T_odom_body;  ///< odometry pose at the fix epoch
    Eigen::Vector3d antenna_odom;   ///< odometry antenna position at the fix epoch
    Eigen::Vector3d fix_enu;
    double distance_m;     ///< odometry path length at the fix epoch
    bool outlier = false;  ///< gated out as multipath
  };
  struct Node {
    double x[4];             ///< georeferenced [x, y, z, yaw] (ENU)
    Eigen::Vector3d p_odom;  ///< odometry position
    double yaw_odom = 0.0;   ///< odometry yaw
    double distance_m = 0.0;
    double t_s = 0.0;
    Eigen::Vector3d fix_enu;           ///< the node's GNSS fix
    Eigen::Vector3d antenna_levelled;  ///< lever arm rotated by roll and pitch
  };
  /// Odometry -> ENU: the newest node's 4-DoF pose, with the odometry's estimated drift
  /// removed from the motion since that node (u: signed path length from the anchor, taken as
  /// the chord length, negative behind it).
  struct Correction {
    Eigen::Vector3d anchor_odom = Eigen::Vector3d::Zero();
    Eigen::Vector3d anchor_enu = Eigen::Vector3d::Zero();
    double anchor_yaw_odom = 0.0;
    double yaw_rad = 0.0;   ///< ENU yaw minus odometry yaw at the anchor
    double ln_scale = 0.0;  ///< odometry scale error (log)
    double yaw_rate = 0.0;  ///< heading correction per metre from the anchor
    double SignedLength(const Eigen::Vector3d& p_odom) const;
    Eigen::Vector3d Apply(const Eigen::Vector3d& p_odom) const;
    Eigen::Isometry3d Apply(const Eigen::Isometry3d& T_odom) const;
  };
  Correction NodeCorrection(const Node& n) const;
  void Process(const Pair& pair);
  /// Gates a fix against the prediction and, at a factor epoch, adds a node and re-solves.
  /// Returns the horizontal innovation, or NaN for an outlier.
  Eigen::Vector2d Fuse(const Pair& pair);
  double Gate(const Pair& pair) const;
  /// Median innovation (against the newest correction) of the accepted fixes within half a
  /// factor window of epoch_s.
  Eigen::Vector3d MedianInnovation(double epoch_s) const;
  bool OdometryAt(double t_s, Eigen::Isometry3d* T, double* distance_m) const;
  void Align(const std::vector<Pair>& pairs, bool resolve);
  void AddNode(const Pair& pair, const Eigen::Vector3d& fix_enu);
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
  uint64_t revision_ = 0;
  std::string pending_reason_ = "no usable GNSS fix yet";
  Correction correction_;
  double drift_[2] = {0.0, 0.0};  ///< [ln scale, heading rate] of the odometry (window)
  std::deque<Node> nodes_;
  bool nodes_dropped_ = false;          ///< the graph has slid: the oldest node carries a prior
  double last_factor_period_ = -1e300;  ///< floor(t / factor_period_s) of the newest factor
  std::deque<Pair> accepted_;           ///< accepted fixes of the last factor_window_s
  /// Accepted fixes further apart than this are a gap (a 1 Hz receiver may miss one).
  static constexpr double kFixGapS = 2.0;
  double fixes_since_s_ = 0.0;  ///< the first accepted fix since the newest gap
  bool node_pending_ = false;   ///< a factor epoch waits for the fixes after it
  Pair pending_epoch_{};
  double last_accept_distance_m_ = 0.0;
  std::vector<Eigen::Vector2d> rejected_innovations_;

  /// The last pose handed out, for a consumer's continuity (Publish, MapTarget).
  struct Continuity {
    /// Any move above continuity_max_step_m is taken at once (MapTarget's); else only where
    /// step_allowed (Publish's).
    bool step_always = false;
    bool valid = false;
    /// The graph has moved for a reason a fade would hide (GNSS back after a gap, a re-solved
    /// alignment): the next pose may step by more than continuity_max_step_m.
    bool step_allowed = false;
    double t_s = 0.0;
    Eigen::Isometry3d odom = Eigen::Isometry3d::Identity();
    Eigen::Isometry3d enu = Eigen::Isometry3d::Identity();
  };
  /// ToEnu(T_odom_body, t_s) plus the fading part of how far the graph has moved c's last pose
  /// since it went out; a move above continuity_max_step_m is taken at once where c allows a
  /// step (for Publish, its horizontal part, where that alone is above it).
  Eigen::Isometry3d Continue(const Eigen::Isometry3d& T_odom_body, double t_s, Continuity* c);
  Continuity published_, map_target_{/*step_always=*/true};
};

}  // namespace raillomer
