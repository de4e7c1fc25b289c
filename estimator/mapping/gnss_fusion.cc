#include "estimator/mapping/gnss_fusion.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <ceres/ceres.h>
#include <ceres/normal_prior.h>

#include "estimator/factors/gnss_factors.h"
#include "estimator/factors/heading_factor.h"

namespace raillomer {

namespace {

Eigen::Matrix3d Rz(double yaw) {
  return Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

/// Turns and stretches the position `p` horizontally about `from` so that a position carried
/// the same way to `reached` would land on `to`; leaves it for a span under 10 m or one the
/// odometry would have to stretch by more than 10 %.
void SpanFit(const Eigen::Vector3d& from,
             const Eigen::Vector3d& to,
             const Eigen::Vector3d& reached,
             Eigen::Vector3d* p) {
  const Eigen::Vector2d want = (to - from).head<2>(), got = (reached - from).head<2>();
  if (want.norm() < 10.0 || got.norm() < 10.0) return;
  const double stretch = want.norm() / got.norm();
  if (std::fabs(stretch - 1.0) > 0.1) return;
  const double turn = std::atan2(got.x() * want.y() - got.y() * want.x(), got.dot(want));
  const Eigen::Matrix2d R = stretch * Eigen::Rotation2Dd(turn).toRotationMatrix();
  p->head<2>() = from.head<2>() + R * (*p - from).head<2>();
}

/// The weak prior at zero on the odometry's drift over the window: [ln scale, heading rate].
ceres::CostFunction* DriftPrior(const GnssFusionOptions& options) {
  return new ceres::NormalPrior(Eigen::Vector2d(1.0 / options.scale_prior_sigma,
                                                1.0 / options.heading_drift_prior_sigma_rad_per_m)
                                    .asDiagonal()
                                    .toDenseMatrix(),
                                ceres::Vector::Zero(2));
}

/// A soft prior that holds the oldest node (x: its [x, y, z, yaw]) where dropped nodes put it.
ceres::CostFunction* OldestNodePrior(const double* x, const GnssFusionOptions& options) {
  return new GnssPositionFactor(Eigen::Vector3d(x[0], x[1], x[2]),
                                Eigen::Vector3d::Zero(),
                                0.5 * options.sigma_horizontal_m,
                                0.5 * options.sigma_vertical_m);
}

/// The odometry link between consecutive nodes `dist` m apart, its noise growing with `dist`.
ceres::CostFunction* OdometryLink(const Eigen::Vector3d& dp,
                                  double dyaw,
                                  double dist,
                                  const GnssFusionOptions& options) {
  return new FourDofBetweenFactor(dp,
                                  dyaw,
                                  dist,
                                  options.drift_fraction * dist + 0.05,
                                  options.vertical_drift_fraction * dist + 0.05,
                                  options.yaw_drift_rad_per_m * dist + 1e-4);
}

/// Solves the pose graph: sparse normal Cholesky, at most 20 iterations, no logging.
void SolveQuietly(ceres::Problem* problem) {
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  solver_options.max_num_iterations = 20;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, problem, &summary);
}

}  // namespace

double GnssFusion::Correction::SignedLength(const Eigen::Vector3d& p_odom) const {
  const Eigen::Vector3d chord = p_odom - anchor_odom;
  const double along =
      chord.x() * std::cos(anchor_yaw_odom) + chord.y() * std::sin(anchor_yaw_odom);
  return along >= 0.0 ? chord.norm() : -chord.norm();
}

Eigen::Vector3d GnssFusion::Correction::Apply(const Eigen::Vector3d& p_odom) const {
  const double u = SignedLength(p_odom);
  return anchor_enu +
         std::exp(ln_scale) * (Rz(yaw_rad + 0.5 * yaw_rate * u) * (p_odom - anchor_odom));
}

Eigen::Isometry3d GnssFusion::Correction::Apply(const Eigen::Isometry3d& T_odom) const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Rz(yaw_rad + yaw_rate * SignedLength(T_odom.translation())) * T_odom.linear();
  T.translation() = Apply(T_odom.translation());
  return T;
}

GnssFusion::GnssFusion(const GnssFusionOptions& options,
                       std::function<void(const std::string&)> warn,
                       std::function<void(const std::string&)> info)
    : options_(options), warn_(std::move(warn)), info_(std::move(info)) {}

void GnssFusion::Warn(const std::string& key, const std::string& message) {
  const uint64_t n = ++warning_counts_[key];
  // The first few of a kind in full, then every 100th, with the count.
  if (!warn_) return;
  if (n <= 3) {
    warn_(message);
  } else if (n % 100 == 0) {
    warn_(message + " (" + std::to_string(n) + " so far)");
  }
}

void GnssFusion::AddFix(const io::GnssFix& fix) {
  if (options_.zone.zone == 0 && std::isfinite(fix.latitude_deg) &&
      std::isfinite(fix.longitude_deg) && std::abs(fix.latitude_deg) <= 84.0 &&
      std::abs(fix.longitude_deg) <= 180.0 &&
      (fix.latitude_deg != 0.0 || fix.longitude_deg != 0.0)) {
    // No zone in the rig: the standard zone of the first plausible fix.
    options_.zone = geo::StandardZone(fix.latitude_deg, fix.longitude_deg);
  }
  Eigen::Vector3d utm;
  const std::string reason = geo::CheckFix(fix, options_.zone, options_.check, &utm);
  const double t = static_cast<double>(fix.stamp_ns) * 1e-9;
  if (!reason.empty()) {
    ++stats_.rejected;
    std::ostringstream m;
    m.precision(3);
    m << std::fixed << "GNSS fix at " << t << " s rejected: " << reason;
    Warn("rejected", m.str());
    return;
  }
  ++stats_.fixes;
  if (!have_origin_) {
    // The local ENU frame's origin: the first fix, rounded to whole metres.
    origin_utm_ = utm.array().round().matrix();
    have_origin_ = true;
  }
  pending_fixes_.emplace_back(t, utm);
}

bool GnssFusion::OdometryAt(double t_s, Eigen::Isometry3d* T, double* distance_m) const {
  if (odometry_.size() < 2 || t_s < odometry_.front().first || t_s > odometry_.back().first)
    return false;
  size_t k = 1;
  while (k + 1 < odometry_.size() && odometry_[k].first < t_s) ++k;
  const auto& [t0, T0] = odometry_[k - 1];
  const auto& [t1, T1] = odometry_[k];
  const double f = t1 > t0 ? (t_s - t0) / (t1 - t0) : 0.0;
  *T = Eigen::Isometry3d::Identity();
  T->translation() = (1.0 - f) * T0.translation() + f * T1.translation();
  T->linear() = Eigen::Quaterniond(T0.linear())
                    .slerp(f, Eigen::Quaterniond(T1.linear()))
                    .normalized()
                    .toRotationMatrix();
  *distance_m = (1.0 - f) * odometry_distance_m_[k - 1] + f * odometry_distance_m_[k];
  return true;
}

void GnssFusion::AddOdometry(int64_t stamp_ns, const Eigen::Isometry3d& T_odom_body) {
  const double t = static_cast<double>(stamp_ns) * 1e-9;
  if (!odometry_.empty()) {
    if (t <= odometry_.back().first) return;
    distance_m_ += (T_odom_body.translation() - odometry_.back().second.translation()).norm();
  }
  odometry_.emplace_back(t, T_odom_body);
  odometry_distance_m_.push_back(distance_m_);
  while (odometry_.size() > 2 && odometry_.front().first < t - 5.0) {
    odometry_.pop_front();
    odometry_distance_m_.pop_front();
  }
  while (!pending_fixes_.empty() && pending_fixes_.front().first <= t) {
    const auto [t_fix, utm] = pending_fixes_.front();
    pending_fixes_.pop_front();
    Eigen::Isometry3d T_fix;
    double distance = 0.0;
    if (!OdometryAt(t_fix, &T_fix, &distance)) continue;  // before the odometry started
    Pair pair{t_fix, T_fix, T_fix * options_.p_body_antenna, utm - origin_utm_, distance};
    Process(pair);
  }
}

void GnssFusion::Process(const Pair& pair) {
  pairs_.push_back(pair);
  while (!pairs_.empty() &&
         pairs_.front().t_s < pair.t_s - std::max(600.0, options_.resolve_window_s))
    pairs_.pop_front();
  if (!aligned_) {
    Align(std::vector<Pair>(pairs_.begin(), pairs_.end()), false);
    return;
  }
  const Eigen::Vector2d innovation = Fuse(pair);
  if (innovation.allFinite()) {
    rejected_innovations_.clear();
    return;
  }
  // An outlier.
  pairs_.back().outlier = true;
  ++stats_.outliers;
  const Eigen::Vector3d off = pair.fix_enu - correction_.Apply(pair.antenna_odom);
  std::ostringstream m;
  m.precision(1);
  m << std::fixed << "GNSS fix at " << pair.t_s << " s is " << off.head<2>().norm()
    << " m off the odometry (gate " << Gate(pair) << " m): ignored as multipath";
  Warn("outlier", m.str());
  rejected_innovations_.push_back(off.head<2>());
  if (static_cast<int>(rejected_innovations_.size()) < options_.resolve_after_rejections) return;
  // Many fixes in a row off the prediction, but in agreement with each other: the odometry
  // or the alignment has degraded (e.g. after a long outage). Re-solve on the recent fixes.
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& v : rejected_innovations_) mean += v;
  mean /= static_cast<double>(rejected_innovations_.size());
  double spread = 0.0;
  for (const auto& v : rejected_innovations_) spread = std::max(spread, (v - mean).norm());
  if (spread < 2.0 * options_.sigma_horizontal_m) {
    std::vector<Pair> recent;
    for (const Pair& p : pairs_) {
      if (p.t_s >= pair.t_s - options_.resolve_window_s) recent.push_back(p);
    }
    for (Pair& p : recent) p.outlier = false;
    Align(recent, true);
  }
  if (!rejected_innovations_.empty()) rejected_innovations_.erase(rejected_innovations_.begin());
}

double GnssFusion::Gate(const Pair& pair) const {
  const double drift = options_.drift_fraction * (pair.distance_m - last_accept_distance_m_);
  return options_.gate_m + 3.0 * std::max(0.0, drift);
}

Eigen::Vector2d GnssFusion::Fuse(const Pair& pair) {
  const Eigen::Vector3d innovation = pair.fix_enu - correction_.Apply(pair.antenna_odom);
  const double gate = Gate(pair);
  if (innovation.head<2>().norm() > gate ||
      std::abs(innovation.z()) > gate + 3.0 * options_.sigma_vertical_m) {
    return Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
  }
  last_accept_distance_m_ = pair.distance_m;
  if (accepted_.empty() || pair.t_s - accepted_.back().t_s > kFixGapS) fixes_since_s_ = pair.t_s;
  accepted_.push_back(pair);
  // Factors on a fixed grid of epochs (the first accepted fix of each period), so that the
  // graph does not depend on when the alignment happened or which fixes were outliers.
  const double period = std::floor(pair.t_s / options_.factor_period_s + 1e-9);
  if (period > last_factor_period_ && !node_pending_) {
    last_factor_period_ = period;
    node_pending_ = true;
    pending_epoch_ = pair;
  }
  const double half = 0.5 * options_.factor_window_s;
  if (node_pending_ && pair.t_s >= pending_epoch_.t_s + half - 1e-6) {
    // The factor's fix: the epoch's prediction plus the median innovation (against the
    // newest correction) of the accepted fixes within half a window of the epoch. The
    // median outvotes the smaller multipath jumps that got through the gate; centring the
    // window cancels the odometry's drift across it.
    node_pending_ = false;
    const Eigen::Vector3d m = MedianInnovation(pending_epoch_.t_s);
    AddNode(pending_epoch_, correction_.Apply(pending_epoch_.antenna_odom) + m);
    ++stats_.factors;
    Optimize();
  }
  while (!accepted_.empty() && accepted_.front().t_s < pair.t_s - options_.factor_window_s)
    accepted_.pop_front();
  return innovation.head<2>();
}

Eigen::Vector3d GnssFusion::MedianInnovation(double epoch_s) const {
  const double half = 0.5 * options_.factor_window_s;
  std::vector<Eigen::Vector3d> innovations;
  for (const Pair& p : accepted_) {
    if (std::abs(p.t_s - epoch_s) <= half + 1e-6)
      innovations.push_back(p.fix_enu - correction_.Apply(p.antenna_odom));
  }
  if (innovations.empty()) return Eigen::Vector3d::Zero();
  Eigen::Vector3d m;
  std::vector<double> v(innovations.size());
  for (int axis = 0; axis < 3; ++axis) {
    for (size_t i = 0; i < innovations.size(); ++i) v[i] = innovations[i][axis];
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    m[axis] = v[v.size() / 2];
  }
  return m;
}

void GnssFusion::Finish() {
  if (!aligned_ || accepted_.empty()) return;
  // The run ends before the next factor's window is complete: a last node on the newest fix
  // (its window is the fixes before it), so that the poses after the previous node come out
  // between two nodes instead of extrapolated.
  if (node_pending_) {  // its window is cut short by the end
    node_pending_ = false;
    AddNode(pending_epoch_,
            correction_.Apply(pending_epoch_.antenna_odom) + MedianInnovation(pending_epoch_.t_s));
    ++stats_.factors;
    Optimize();
  }
  const Pair& last = accepted_.back();
  if (!nodes_.empty() && last.t_s <= nodes_.back().t_s + 1e-6) return;
  AddNode(last, correction_.Apply(last.antenna_odom) + MedianInnovation(last.t_s));
  ++stats_.factors;
  Optimize();
}

void GnssFusion::Align(const std::vector<Pair>& pairs, bool resolve) {
  std::vector<Eigen::Vector3d> odom, enu;
  for (const Pair& p : pairs) {
    if (p.outlier) continue;
    odom.push_back(p.antenna_odom);
    enu.push_back(p.fix_enu);
  }
  const geo::GnssAlignment a = geo::AlignToGnss(odom, enu, options_.alignment);
  if (!a.ok) {
    pending_reason_ = a.reason;
    return;
  }
  const Eigen::Vector3d before = correction_.Apply(pairs.back().antenna_odom);
  correction_ = Correction();
  ++revision_;
  correction_.anchor_enu = a.T_enu_odom.t;
  correction_.yaw_rad = a.T_enu_odom.yaw_rad;
  drift_[0] = drift_[1] = 0.0;
  aligned_ = true;
  pending_reason_.clear();
  nodes_.clear();
  nodes_dropped_ = false;
  accepted_.clear();
  node_pending_ = false;
  last_factor_period_ = -1e300;
  last_accept_distance_m_ = pairs.front().distance_m;
  rejected_innovations_.clear();
  // The fixes the alignment was solved on seed the pose graph, one factor per period as if
  // they had come in aligned: the graph starts with their whole baseline, not a single node.
  for (const Pair& p : pairs) {
    if (!p.outlier) Fuse(p);
  }
  std::ostringstream m;
  m.precision(2);
  m << std::fixed;
  if (resolve) {
    ++stats_.realignments;
    published_.step_allowed = true;
    m << "GNSS alignment re-solved on " << a.inliers << " fixes: the position moved by "
      << (correction_.Apply(pairs.back().antenna_odom) - before).norm() << " m";
  } else {
    m << "aligned to UTM zone " << options_.zone.Name() << " on " << a.inliers << " fixes over "
      << a.extent_m << " m (" << a.outliers << " outliers): heading "
      << a.T_enu_odom.yaw_rad * 180.0 / M_PI << " deg, RMS " << a.rms_m << " m";
  }
  if (info_) info_(m.str());
}

void GnssFusion::AddNode(const Pair& pair, const Eigen::Vector3d& fix_enu) {
  const Eigen::Isometry3d& T_odom_body = pair.T_odom_body;
  Node n;
  n.p_odom = T_odom_body.translation();
  n.yaw_odom = HeadingOf(T_odom_body.linear());
  n.distance_m = pair.distance_m;
  n.t_s = pair.t_s;
  n.fix_enu = fix_enu;
  n.antenna_levelled = Rz(-n.yaw_odom) * T_odom_body.linear() * options_.p_body_antenna;
  // No factor for more than a period and a half: the receiver was out (a tunnel, a station
  // roof), and this node corrects drift the graph could not see.
  if (!nodes_.empty() && n.t_s - nodes_.back().t_s > 1.5 * options_.factor_period_s)
    published_.step_allowed = true;
  const Eigen::Isometry3d T = correction_.Apply(T_odom_body);
  n.x[0] = T.translation().x();
  n.x[1] = T.translation().y();
  n.x[2] = T.translation().z();
  n.x[3] = HeadingOf(T.linear());
  nodes_.push_back(n);
  while (static_cast<int>(nodes_.size()) > options_.max_nodes) {
    nodes_.pop_front();
    nodes_dropped_ = true;
  }
}

void GnssFusion::Optimize() {
  if (nodes_.size() >= 2) {
    ceres::Problem::Options problem_options;
    ceres::Problem problem(problem_options);
    for (Node& n : nodes_) problem.AddParameterBlock(n.x, 4);
    // The odometry's systematic drift over the window, with a weak prior at zero.
    problem.AddResidualBlock(DriftPrior(options_), nullptr, drift_);
    // Every node is free: its fix places it, the odometry links orient it. Once older nodes
    // have left the graph, the oldest keeps what they told it as a soft prior.
    if (nodes_dropped_) {
      problem.AddResidualBlock(
          OldestNodePrior(nodes_.front().x, options_), nullptr, nodes_.front().x);
    }
    for (size_t k = 0; k < nodes_.size(); ++k) {
      Node& n = nodes_[k];
      problem.AddResidualBlock(new GnssPositionFactor(n.fix_enu,
                                                      n.antenna_levelled,
                                                      options_.sigma_horizontal_m,
                                                      options_.sigma_vertical_m),
                               new ceres::CauchyLoss(2.0),
                               n.x);
      if (k == 0) continue;
      Node& prev = nodes_[k - 1];
      const double dist = std::max(0.0, n.distance_m - prev.distance_m);
      const Eigen::Vector3d dp = Rz(-prev.yaw_odom) * (n.p_odom - prev.p_odom);
      problem.AddResidualBlock(
          OdometryLink(dp, WrapAngle(n.yaw_odom - prev.yaw_odom), dist, options_),
          nullptr,
          prev.x,
          n.x,
          drift_);
    }
    SolveQuietly(&problem);
  }
  // The correction maps the newest node's odometry pose onto its georeferenced one.
  const Node& n = nodes_.back();
  correction_ = NodeCorrection(n);
  ++revision_;
}

GnssFusion::Correction GnssFusion::NodeCorrection(const Node& n) const {
  Correction c;
  c.anchor_odom = n.p_odom;
  c.anchor_enu = Eigen::Vector3d(n.x[0], n.x[1], n.x[2]);
  c.anchor_yaw_odom = n.yaw_odom;
  c.yaw_rad = WrapAngle(n.x[3] - n.yaw_odom);
  c.ln_scale = drift_[0];
  c.yaw_rate = drift_[1];
  return c;
}

Eigen::Isometry3d GnssFusion::ToEnu(const Eigen::Isometry3d& T_odom_body) const {
  return correction_.Apply(T_odom_body);
}

Eigen::Isometry3d GnssFusion::ToEnu(const Eigen::Isometry3d& T_odom_body, double t_s) const {
  if (nodes_.size() < 2 || t_s >= nodes_.back().t_s) return correction_.Apply(T_odom_body);
  if (t_s <= nodes_.front().t_s) return NodeCorrection(nodes_.front()).Apply(T_odom_body);
  size_t k = 1;
  while (nodes_[k].t_s < t_s) ++k;
  // Between two nodes: each carries the pose with the scale-corrected odometry, and the two
  // are blended by time, so the trajectory runs smoothly from one node to the next. The
  // window's heading drift rate is left out here: the two nodes already hold the heading at
  // either end, and the rate, an average over the window fitted to wandering fixes, only bends
  // the path between them (by the rate times the span squared over 8: 0.4 m through a 1.5 km
  // tunnel, where it made the run's largest error 1.68 m instead of 1.53 m).
  const Node& a = nodes_[k - 1];
  const Node& b = nodes_[k];
  Correction ca = NodeCorrection(a), cb = NodeCorrection(b);
  ca.yaw_rate = cb.yaw_rate = 0.0;
  const Eigen::Isometry3d A = ca.Apply(T_odom_body), B = cb.Apply(T_odom_body);
  // The two node headings need not agree with the odometry's turn between them (each rests on
  // the fixes around its node): carried from one node the path misses the other sideways, and
  // the blend of the two would bow out between them by a quarter of the heading difference
  // times the span. So each carried position is turned and stretched about its own node until
  // it meets the other node; the orientations keep the nodes' headings, blended.
  Eigen::Vector3d pa = A.translation(), pb = B.translation();
  SpanFit(ca.anchor_enu, cb.anchor_enu, ca.Apply(b.p_odom), &pa);
  SpanFit(cb.anchor_enu, ca.anchor_enu, cb.Apply(a.p_odom), &pb);
  const double w = (t_s - a.t_s) / (b.t_s - a.t_s);
  const double yaw_a = HeadingOf(A.linear() * T_odom_body.linear().transpose());
  const double yaw_b = HeadingOf(B.linear() * T_odom_body.linear().transpose());
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Rz(yaw_a + w * WrapAngle(yaw_b - yaw_a)) * T_odom_body.linear();
  T.translation() = (1.0 - w) * pa + w * pb;
  return T;
}

Eigen::Isometry3d GnssFusion::Continue(const Eigen::Isometry3d& T_odom_body,
                                       double t_s,
                                       Continuity* c) {
  Eigen::Isometry3d T = ToEnu(T_odom_body, t_s);
  if (c->valid && options_.continuity_length_m > 0.0) {
    const Eigen::Isometry3d now = ToEnu(c->odom, c->t_s);
    const Eigen::Vector3d dp = c->enu.translation() - now.translation();
    // What of the move still fades: all of it, unless a step is allowed and the move is above
    // continuity_max_step_m. Published poses fade the height even then, and step only where
    // the horizontal move alone is above it: the odometry's height holds through an outage,
    // and what moves it is the receiver's wandering height (with the height linked tightly,
    // lidar_blackout stepped 0.58 m down where GNSS came back; with the height counted in the
    // move, tunnel_gnss_outage seed 2 stepped 0.37 m sideways where the tunnel's poses, held
    // as long as they may be and extrapolated, met those smoothed after it).
    Eigen::Vector3d fading = dp;
    if (c->step_always && dp.norm() > options_.continuity_max_step_m) {
      fading = Eigen::Vector3d::Zero();
    } else if (c->step_allowed && dp.head<2>().norm() > options_.continuity_max_step_m) {
      fading = Eigen::Vector3d(0.0, 0.0, dp.z());
    }
    // Positions only: holding a yaw difference on the orientation while the positions follow
    // the graph would skew the body against its own path (crabbing), and every keyframe cloud
    // with it.
    const double travel = (T_odom_body.translation() - c->odom.translation()).norm();
    T.translation() += std::exp(-travel / options_.continuity_length_m) * fading;
  }
  c->valid = true;
  c->step_allowed = false;
  c->t_s = t_s;
  c->odom = T_odom_body;
  c->enu = T;
  return T;
}

Eigen::Isometry3d GnssFusion::Publish(const Eigen::Isometry3d& T_odom_body, double t_s) {
  return Continue(T_odom_body, t_s, &published_);
}

Eigen::Isometry3d GnssFusion::MapTarget(const Eigen::Isometry3d& T_odom_body, double t_s) {
  return Continue(T_odom_body, t_s, &map_target_);
}

bool GnssFusion::AlignmentOverdue(double held_s, double max_hold_s) const {
  return held_s >= (stats_.fixes == 0 ? std::min(30.0, max_hold_s) : max_hold_s);
}

bool GnssFusion::Releases(double t_s,
                          double newest_s,
                          double prompt_latency_s,
                          double max_latency_s) const {
  if (t_s <= settled_until_s()) return true;
  const double waited = newest_s - t_s;
  if (waited >= max_latency_s) return true;
  if (prompt_latency_s <= 0.0 || waited < prompt_latency_s) return false;
  // The graph keeps pace: a node at most a factor period and half a window before the pose
  // (one per period, each half a window after its epoch), and fixes accepted without a gap
  // from before the pose to the newest one. A pose carried from the newest node then moves by
  // no more than the odometry drifts over a span when the next joins; a pose in an outage or
  // a multipath patch waits, to be smoothed by the node after it.
  return settled_until_s() >= t_s - options_.factor_period_s - 0.5 * options_.factor_window_s &&
         !accepted_.empty() && fixes_since_s_ <= t_s && accepted_.back().t_s >= newest_s - kFixGapS;
}

double GnssFusion::settled_until_s() const {
  // The first nodes' headings rest on the alignment's short baseline and move by milliradians
  // as the graph grows; poses wait for min_settled_nodes nodes.
  if (!aligned_ || static_cast<int>(nodes_.size()) < std::max(1, options_.min_settled_nodes))
    return -std::numeric_limits<double>::infinity();
  return nodes_.back().t_s;
}

}  // namespace raillomer
