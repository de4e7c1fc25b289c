#include "estimator/mapping/submap_builder.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>

#include "estimator/mapping/voxel_centroids.h"

namespace raillomer {
namespace {

std::vector<Eigen::Vector3f> Thinned(const std::vector<Eigen::Vector3f>& points, double voxel_m) {
  VoxelCentroids grid(voxel_m);
  for (const Eigen::Vector3f& p : points) grid.Add(p.cast<double>(), 0.f);
  std::vector<Eigen::Vector3f> out;
  grid.ForEach([&](uint64_t, const Eigen::Vector3d& p, float) { out.push_back(p.cast<float>()); });
  return out;
}

/// The horizontal unit vectors ahead of and to the left of `R_world_body`'s heading; false
/// when it points straight up or down.
bool Horizontal(const Eigen::Matrix3d& R_world_body,
                Eigen::Vector3d* ahead,
                Eigen::Vector3d* left) {
  Eigen::Vector3d heading = R_world_body.col(0);
  heading.z() = 0.0;
  if (heading.norm() < 1e-6) return false;
  *ahead = heading.normalized();
  *left = Eigen::Vector3d::UnitZ().cross(*ahead);
  return true;
}

bool Within(const Eigen::Isometry3d& guess,
            const Eigen::Isometry3d& result,
            double max_m,
            double max_deg) {
  double translation_m = 0.0, rotation_rad = 0.0;
  CorrectionSize(guess, result, &translation_m, &rotation_rad);
  return translation_m <= max_m && rotation_rad <= max_deg * M_PI / 180.0;
}

}  // namespace

std::vector<Eigen::Isometry3d> WithoutSideSlip(const std::vector<Eigen::Isometry3d>& poses,
                                               size_t anchor,
                                               const Eigen::Vector3d& p_body_wheel,
                                               double max_jump_m) {
  std::vector<Eigen::Isometry3d> out = poses;
  if (poses.size() < 2) return out;
  anchor = std::min(anchor, poses.size() - 1);
  auto wheel = [&p_body_wheel](const Eigen::Isometry3d& T) { return T * p_body_wheel; };
  // The wheel point's steps in the pairs' mean axes.
  const size_t n = poses.size();
  std::vector<Eigen::Matrix3d> R(n - 1);
  std::vector<Eigen::Vector3d> d(n - 1);
  for (size_t k = 0; k + 1 < n; ++k) {
    const Eigen::Quaterniond a(poses[k].linear()), b(poses[k + 1].linear());
    R[k] = a.slerp(0.5, b).toRotationMatrix();
    d[k] = R[k].transpose() * (wheel(poses[k + 1]) - wheel(poses[k]));
  }
  // The slip the steps share, sideways per metre forward: a least-squares fit (a reversal
  // counts the same), fitted again without the steps that jump across by more than max_jump_m
  // beside it.
  std::vector<uint8_t> jump(n - 1, 0);
  auto fit = [&]() {
    double sideways = 0.0, forward = 0.0;
    for (size_t k = 0; k + 1 < n; ++k) {
      if (jump[k]) continue;
      sideways += d[k].y() * d[k].x();
      forward += d[k].x() * d[k].x();
    }
    return forward > 1e-12 ? sideways / forward : 0.0;
  };
  double slip = fit();
  for (size_t k = 0; k + 1 < n; ++k) jump[k] = std::abs(d[k].y() - slip * d[k].x()) > max_jump_m;
  slip = fit();
  auto step = [&](size_t k) {
    Eigen::Vector3d e = d[k];
    e.y() = jump[k] ? 0.0 : e.y() - slip * e.x();
    return Eigen::Vector3d(R[k] * e);
  };
  // Each body position follows its rebuilt wheel point.
  auto place = [&](size_t k, const Eigen::Vector3d& w) {
    out[k].translation() = w - poses[k].linear() * p_body_wheel;
  };
  for (size_t k = anchor; k + 1 < n; ++k) place(k + 1, wheel(out[k]) + step(k));
  for (size_t k = anchor; k-- > 0;) place(k, wheel(out[k + 1]) - step(k));
  return out;
}

SubmapBuilder::SubmapBuilder(const SubmapOptions& options) : options_(options) {
  options_.keyframes = std::max(1, options_.keyframes);
}

void SubmapBuilder::RegisterKeyframes(const Eigen::Vector3d& origin,
                                      std::vector<Eigen::Isometry3d>* P) {
  const size_t n = open_.size();
  const size_t anchor = n / 2;
  const bool any = std::any_of(
      open_.begin(), open_.end(), [&](const SubmapKeyframe& k) { return k.odometry_suspect; });
  if (!any) return;
  VoxelCentroids target(options_.icp_target_voxel_m);
  auto add = [&](size_t k) {
    const Eigen::Isometry3d& T = (*P)[k];
    for (const Eigen::Vector3f& p : open_[k].points_body) target.Add(T * p.cast<double>(), 0.f);
  };
  add(anchor);
  // Outward from the anchor, so each keyframe meets the neighbours it overlaps most.
  std::vector<size_t> order;
  for (size_t k = anchor + 1; k < n; ++k) order.push_back(k);
  for (size_t k = anchor; k-- > 0;) order.push_back(k);
  std::vector<Eigen::Vector3f> target_points;
  for (size_t k : order) {
    if (!open_[k].odometry_suspect) {
      add(k);
      continue;
    }
    target_points.clear();
    target.ForEach([&](uint64_t, const Eigen::Vector3d& p, float) {
      target_points.push_back(p.cast<float>());
    });
    auto accept = [&](const Registration& r, const Eigen::Isometry3d& guess) {
      return r.converged && r.fitness_m2 <= options_.icp_max_fitness_m2 &&
             Within(guess,
                    r.T_target_source,
                    options_.icp_max_correction_m,
                    options_.icp_max_correction_deg);
    };
    const Eigen::Isometry3d odometry_guess = (*P)[k];
    const Registration r =
        IcpRegister(open_[k].points_body, target_points, odometry_guess, options_.icp_options);
    if (accept(r, odometry_guess)) {
      (*P)[k] = r.T_target_source;
      ++stats_.icp_odometry;
    } else {
      // The paper's fallback: the GNSS pose as the initial guess.
      Eigen::Isometry3d gnss_guess = open_[k].T_world_body;
      gnss_guess.translation() -= origin;
      const Registration g =
          IcpRegister(open_[k].points_body, target_points, gnss_guess, options_.icp_options);
      if (accept(g, gnss_guess)) {
        (*P)[k] = g.T_target_source;
        ++stats_.icp_gnss;
      } else {
        ++stats_.icp_failed;
      }
    }
    add(k);
  }
}

bool SubmapBuilder::StartNdt(Pending* p, bool chained) {
  // The overlap only: points beyond it cannot match and only cost time.
  const api::Submap& s = p->submap;
  Eigen::AlignedBox3f source_box, target_box;
  for (const Eigen::Vector3f& q : s.points) source_box.extend(q);
  const float margin = static_cast<float>(2.0 * options_.ndt_options.resolution_m);
  source_box.min().array() -= margin;
  source_box.max().array() += margin;
  // The previous submap, and any of an earlier pass over the same ground.
  const Eigen::Vector3d anchor = p->P[p->anchor].translation() + s.origin;
  const auto take = [&](uint32_t id) {
    if (id + 1 == s.index) return true;
    if (id >= placed_.size()) return false;
    const Placed& e = placed_[id];
    return p->travel_anchor_m - e.travel_m - (anchor - e.anchor).norm() >= options_.revisit_min_m;
  };
  std::vector<uint32_t> ids;
  std::vector<Eigen::Vector3f> target =
      archive_.Within(s.utm_zone, s.origin, source_box, take, &ids);
  if (target.empty()) return false;
  p->revisit = std::any_of(ids.begin(), ids.end(), [&](uint32_t id) { return id + 1 != s.index; });
  if (p->revisit) ++stats_.ndt_revisits;
  for (const Eigen::Vector3f& t : target) target_box.extend(t);
  target_box.min().array() -= margin;
  target_box.max().array() += margin;
  std::vector<Eigen::Vector3f> source;
  source.reserve(s.points.size());
  for (const Eigen::Vector3f& q : s.points)
    if (target_box.contains(q)) source.push_back(q);
  NdtOptions ndt = options_.ndt_options;
  ndt.coarse_pass = ndt.coarse_pass && !chained;  // the chain's guess is within centimetres
  // Where submaps overlap, the union holds each surface several times over: thinned again, the
  // target (and NDT's memory) stays the size of the ground it covers.
  const bool several = ids.size() > 1;
  const double voxel_m = options_.ndt_target_voxel_m;
  p->ndt =
      std::async(std::launch::async,
                 [source = std::move(source), target = std::move(target), several, voxel_m, ndt]() {
                   return NdtRegister(source,
                                      several ? Thinned(target, voxel_m) : target,
                                      Eigen::Isometry3d::Identity(),
                                      ndt);
                 });
  return true;
}

void SubmapBuilder::FinishPending(std::vector<api::Submap>* done) {
  Pending p = std::move(*pending_);
  pending_.reset();
  const Registration r = p.ndt.get();
  // Along the track only where the registration sees it: on a corridor that repeats itself
  // every mast spacing NDT slides, and the odometry (its scale corrected by GNSS) is better.
  // Onto an earlier pass it takes far less to see it: nothing else ties the two passes along
  // the track, and the earlier pass holds the result, so no slide is carried along the chain.
  // The slide is taken out before the trust region is checked, so that it does not throw
  // away the height and the turn that NDT did see.
  // Likewise the turn about the vertical: where the corridor offers little to turn against (a
  // bare curve), NDT's turn wanders by milliradians from one submap to the next, and each one
  // registered onto the last carries the heading along the chain, which then walks sideways off
  // the track. The placement's heading is GNSS-corrected and better there.
  Eigen::Isometry3d delta = r.T_target_source;
  if (r.converged) {
    const Eigen::Vector3d a = p.P[p.anchor].translation();
    if (options_.ndt_min_turn_arm_m > 0.0 &&
        HoldPoorlySeenTurn(r.information, a, options_.ndt_min_turn_arm_m, &delta)) {
      ++stats_.ndt_turn_held;
    }
    Eigen::Vector3d along = p.P[p.anchor].linear().col(0);
    along.z() = 0.0;
    if (along.norm() > 1e-6) {
      along.normalize();
      const Eigen::Matrix3d translation_information = r.information.topLeftCorner<3, 3>();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(translation_information);
      const double strongest = std::max(eig.eigenvalues().maxCoeff(), 1e-12);
      const double ratio = along.dot(translation_information * along) / strongest;
      const double min_ratio = p.revisit ? options_.ndt_min_along_information_revisit
                                         : options_.ndt_min_along_information;
      if (ratio < min_ratio) {
        delta.translation() -= along * along.dot(delta * a - a);
      }
    }
  }
  if (r.converged && Within(Eigen::Isometry3d::Identity(),
                            delta,
                            options_.ndt_max_correction_m,
                            options_.ndt_max_correction_deg)) {
    ++stats_.ndt_applied;
    for (Eigen::Vector3f& q : p.submap.points) q = (delta * q.cast<double>()).cast<float>();
    for (Eigen::Isometry3d& T : p.P) T = delta * T;
  } else {
    ++stats_.ndt_rejected;
  }
  done->push_back(Finalize(std::move(p)));
}

api::Submap SubmapBuilder::Finalize(Pending p) {
  api::Submap& s = p.submap;
  if (p.chained && (options_.gnss_pull > 0.0 || options_.gnss_pull_vertical > 0.0)) {
    // Move the submap rigidly so that its anchor goes gnss_pull of the way to its GNSS pose.
    const Eigen::Isometry3d target = PullTarget(p);
    const Eigen::Isometry3d delta = target * p.P[p.anchor].inverse();  // local frame
    for (Eigen::Vector3f& q : s.points) q = (delta * q.cast<double>()).cast<float>();
    for (Eigen::Isometry3d& T : p.P) T = delta * T;
  }
  for (size_t k = 0; k < p.P.size(); ++k) {
    s.keyframes[k].p_world = p.P[k].translation() + s.origin;
    s.keyframes[k].q_world_body = Eigen::Quaterniond(p.P[k].linear()).normalized();
  }
  if (s.georeferenced) {
    Remember(p);
  } else {
    previous_.reset();
  }
  ++stats_.submaps;
  return std::move(s);
}

Eigen::Isometry3d SubmapBuilder::PullTarget(const Pending& p) const {
  // The anchor goes gnss_pull of the way to its GNSS pose (gnss_pull_vertical of the way in
  // height; along the track only with the heading loop). The target is local (minus origin).
  const api::Submap& s = p.submap;
  Eigen::Isometry3d anchor = p.P[p.anchor];
  anchor.translation() += s.origin;
  const Eigen::Isometry3d& gnss = p.T_gnss_anchor;
  const double k = options_.gnss_pull;
  Eigen::Isometry3d target = Eigen::Isometry3d::Identity();
  target.linear() = Eigen::Quaterniond(anchor.linear())
                        .slerp(k, Eigen::Quaterniond(gnss.linear()))
                        .normalized()
                        .toRotationMatrix();
  Eigen::Vector3d step = k * (gnss.translation() - anchor.translation());
  step.z() = options_.gnss_pull_vertical * (gnss.translation().z() - anchor.translation().z());
  Eigen::Vector3d ahead, left;
  if (options_.gnss_heading_length_m > 0.0 && Horizontal(anchor.linear(), &ahead, &left)) {
    // Sideways the heading loop follows GNSS, so the step keeps only its along-track share.
    // Beyond that, each way takes a share of the gap past a barrier, so that a chain that has
    // strayed comes back a little each submap instead of being torn back by metres at a
    // reset: along the track gnss_pull_along_excess past 1/4 of chain_reset_m (where the
    // odometry runs long or short for a while), sideways gnss_pull_excess past 3/4 of it
    // (where the loop has not kept up).
    const Eigen::Vector3d gap = gnss.translation() - anchor.translation();
    const auto excess = [](double g, double barrier) {
      return g - std::clamp(g, -barrier, barrier);
    };
    const double along =
        ahead.dot(step) +
        options_.gnss_pull_along_excess * excess(ahead.dot(gap), 0.25 * options_.chain_reset_m);
    const double across =
        options_.gnss_pull_excess * excess(left.dot(gap), 0.75 * options_.chain_reset_m);
    step.head<2>() = (along * ahead + across * left).head<2>();
  }
  target.translation() = anchor.translation() + step - s.origin;
  return target;
}

void SubmapBuilder::Remember(const Pending& p) {
  const api::Submap& s = p.submap;
  if (options_.ndt) {
    archive_.Put(s.index, s.utm_zone, s.origin, Thinned(s.points, options_.ndt_target_voxel_m));
    if (placed_.size() <= s.index) placed_.resize(s.index + 1);
    placed_[s.index] = {p.P[p.anchor].translation() + s.origin, p.travel_anchor_m};
  }
  Previous next;
  next.utm_zone = s.utm_zone;
  next.T_world_anchor = p.P[p.anchor];
  next.T_world_anchor.translation() += s.origin;
  next.T_odom_anchor = p.T_odom_anchor;
  next.R_level_anchor = p.T_gnss_anchor.linear();
  previous_ = std::move(next);
}

Eigen::Matrix3d SubmapBuilder::Tilt(const Eigen::Matrix3d& R_world_body) const {
  Eigen::Vector3d ahead, left;
  if (!Horizontal(R_world_body, &ahead, &left)) return Eigen::Matrix3d::Identity();
  // About left: nose up; about up: a turn to the left.
  return Eigen::AngleAxisd(heading_.angle_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
         Eigen::AngleAxisd(-height_.angle_rad, left).toRotationMatrix();
}

void SubmapBuilder::Steer(
    Loop* loop, double length_m, double rate_rad_per_m, double error_m, double travel_m) const {
  if (!(length_m > 0.0)) return;
  // e'' = -kp e' - ki e for the distance e along the path: critically damped with natural
  // length L when kp = 2 / L and ki = 1 / L^2.
  const double kp = 2.0 / length_m, ki = 1.0 / (length_m * length_m);
  const double max_angle = options_.gnss_max_tilt_rad;
  loop->integral_m2 =
      std::clamp(loop->integral_m2 + error_m * travel_m, -max_angle / ki, max_angle / ki);
  const double wanted = std::clamp(kp * error_m + ki * loop->integral_m2, -max_angle, max_angle);
  const double turn = rate_rad_per_m * travel_m;
  loop->angle_rad += std::clamp(wanted - loop->angle_rad, -turn, turn);
}

Eigen::Isometry3d SubmapBuilder::PlaceAnchor(const SubmapKeyframe& anchor,
                                             bool* chained,
                                             Eigen::Matrix3d* tilt) {
  *chained = false;
  *tilt = Eigen::Matrix3d::Identity();
  const Eigen::Isometry3d& gnss = anchor.T_world_body;
  if (!anchor.georeferenced || !previous_ || previous_->utm_zone != anchor.utm_zone) return gnss;
  *tilt = Tilt(gnss.linear());
  double travel_m = 0.0;
  const Eigen::Isometry3d chain = Chain(anchor, *tilt, &travel_m);
  const Eigen::Vector3d off = gnss.translation() - chain.translation();
  Steer(&height_,
        options_.gnss_height_length_m,
        options_.gnss_max_tilt_rate_rad_per_m,
        off.z(),
        travel_m);
  Eigen::Vector3d ahead, left;
  const bool level = Horizontal(gnss.linear(), &ahead, &left);
  if (level) {
    Steer(&heading_,
          options_.gnss_heading_length_m,
          options_.gnss_max_turn_rate_rad_per_m,
          left.dot(off),
          travel_m);
  }
  // Across the track a gap of chain_reset_m tears the map; along it the chain may lag or lead
  // twice as far (a step along the track moves nothing on the rails or the side walls).
  const bool far = level ? std::fabs(left.dot(off)) > options_.chain_reset_m ||
                               std::fabs(ahead.dot(off)) > 2.0 * options_.chain_reset_m
                         : off.head<2>().norm() > options_.chain_reset_m;
  if (far) {
    // GNSS places it across and along the track; the height stays the chain's: a single-point
    // receiver's height wanders by metres, and taking it would tear the map by as much.
    ++stats_.chain_resets;
    Eigen::Isometry3d T = chain;
    T.translation().head<2>() = gnss.translation().head<2>();
    return T;
  }
  ++stats_.chained;
  *chained = true;
  return chain;
}

Eigen::Isometry3d SubmapBuilder::Chain(const SubmapKeyframe& anchor,
                                       const Eigen::Matrix3d& tilt,
                                       double* travel_m) const {
  // The previous submap's position carried by the odometry's motion since its anchor, turned
  // into the world by the current GNSS correction and with the odometry's scale error taken
  // out; the orientation is the GNSS-corrected one. Carrying the orientation along the chain
  // too would carry an early heading error (the alignment's, before the graph has settled)
  // into every later submap, which then walks sideways off the track. Path and orientation
  // are both tilted by the height and heading loops, and by the roll and pitch that NDT and the
  // pull left the previous submap with against its own GNSS orientation: NDT then only has this
  // submap's own difference to take out, and one that stops early (PCL's sometimes stops at
  // its first step) leaves no step in roll or pitch at the seam. The pull takes that carried
  // tilt out again, a share per submap.
  const Eigen::Isometry3d& gnss = anchor.T_world_body;
  const Eigen::AngleAxisd left_over(previous_->T_world_anchor.linear() *
                                    previous_->R_level_anchor.transpose());
  Eigen::Vector3d carried = left_over.angle() * left_over.axis();
  carried.z() = 0.0;  // heading stays the GNSS correction's (see above)
  Eigen::Matrix3d R_tilt = tilt;
  if (carried.norm() > 1e-12) {
    R_tilt = Eigen::AngleAxisd(carried.norm(), carried.normalized()).toRotationMatrix() * R_tilt;
  }
  const Eigen::Matrix3d R_correction =
      R_tilt * gnss.linear() * anchor.T_odom_body.linear().transpose();
  const Eigen::Vector3d motion = anchor.odometry_scale * (anchor.T_odom_body.translation() -
                                                          previous_->T_odom_anchor.translation());
  *travel_m = motion.norm();
  Eigen::Isometry3d chain = gnss;
  chain.linear() = R_tilt * gnss.linear();
  chain.translation() = previous_->T_world_anchor.translation() + R_correction * motion;
  return chain;
}

void SubmapBuilder::Close(std::vector<api::Submap>* done) {
  if (pending_) FinishPending(done);  // its placement seeds this submap's chain
  const SubmapKeyframe& first = open_.front();
  Pending p;
  api::Submap& s = p.submap;
  s.index = next_index_++;
  s.first_stamp_ns = first.stamp_ns;
  s.last_stamp_ns = open_.back().stamp_ns;
  s.georeferenced = first.georeferenced;
  s.utm_zone = first.utm_zone;
  s.origin = first.T_world_body.translation().array().round().matrix();
  PlaceKeyframes(&p);
  GatherPoints(&p);
  open_.clear();
  open_travel_m_.clear();
  if (s.georeferenced && options_.ndt && StartNdt(&p, p.chained)) {
    pending_ = std::move(p);
    return;
  }
  done->push_back(Finalize(std::move(p)));
}

void SubmapBuilder::PlaceKeyframes(Pending* p) {
  // Local poses (world minus origin): the middle keyframe placed by PlaceAnchor, the others by
  // the odometry relative to it. The relative motion is taken first, in odometry magnitudes.
  const size_t n = open_.size();
  p->anchor = n / 2;
  p->T_odom_anchor = open_[p->anchor].T_odom_body;
  p->T_gnss_anchor = open_[p->anchor].T_world_body;
  p->travel_anchor_m = open_travel_m_[p->anchor];
  bool chained = false;
  Eigen::Matrix3d tilt;
  Eigen::Isometry3d A = PlaceAnchor(open_[p->anchor], &chained, &tilt);
  p->T_gnss_anchor.linear() = tilt * p->T_gnss_anchor.linear();  // the pull keeps the tilt
  p->chained = chained;
  A.translation() -= p->submap.origin;
  const Eigen::Isometry3d odom_anchor_inv = p->T_odom_anchor.inverse();
  std::vector<Eigen::Isometry3d> odom(n);
  for (size_t k = 0; k < n; ++k) odom[k] = open_[k].T_odom_body;
  if (options_.remove_side_slip)
    odom =
        WithoutSideSlip(odom, p->anchor, options_.p_body_odometer, options_.side_slip_max_jump_m);
  p->P.resize(n);
  for (size_t k = 0; k < n; ++k) p->P[k] = A * (odom_anchor_inv * odom[k]);
  if (options_.icp && n > 1) RegisterKeyframes(p->submap.origin, &p->P);
}

void SubmapBuilder::GatherPoints(Pending* p) const {
  api::Submap& s = p->submap;
  const float max_range_squared =
      options_.max_range_m > 0.0 ? static_cast<float>(options_.max_range_m * options_.max_range_m)
                                 : std::numeric_limits<float>::infinity();
  for (size_t k = 0; k < open_.size(); ++k) {
    const SubmapKeyframe& kf = open_[k];
    for (size_t i = 0; i < kf.points_body.size(); ++i) {
      if (kf.points_body[i].squaredNorm() > max_range_squared) continue;
      s.points.push_back((p->P[k] * kf.points_body[i].cast<double>()).cast<float>());
      s.intensities.push_back(i < kf.intensities.size() ? kf.intensities[i] : 0.f);
    }
    api::StampedPose pose;  // filled in by Finalize
    pose.stamp_ns = kf.stamp_ns;
    s.keyframes.push_back(pose);
  }
  if (options_.voxel_m > 0.0 && !s.points.empty()) {
    // Offsets are at most a few hundred metres: float keeps them to well below a millimetre.
    VoxelCentroids grid(options_.voxel_m);
    for (size_t i = 0; i < s.points.size(); ++i)
      grid.Add(s.points[i].cast<double>(), s.intensities[i]);
    s.points.clear();
    s.intensities.clear();
    grid.ForEach([&](uint64_t, const Eigen::Vector3d& q, float intensity) {
      s.points.push_back(q.cast<float>());
      s.intensities.push_back(intensity);
    });
  }
}

SubmapBuilder::~SubmapBuilder() {
  if (pending_ && pending_->ndt.valid()) pending_->ndt.wait();
}

std::vector<api::Submap> SubmapBuilder::Add(SubmapKeyframe keyframe) {
  std::vector<api::Submap> done;
  if (pending_ && pending_->ndt.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
    FinishPending(&done);
  }
  if (!open_.empty() && (open_.front().georeferenced != keyframe.georeferenced ||
                         open_.front().utm_zone != keyframe.utm_zone)) {
    Close(&done);
  }
  if (last_odom_) travel_m_ += (keyframe.T_odom_body.translation() - *last_odom_).norm();
  last_odom_ = keyframe.T_odom_body.translation();
  open_travel_m_.push_back(travel_m_);
  open_.push_back(std::move(keyframe));
  if (static_cast<int>(open_.size()) >= options_.keyframes) Close(&done);
  return done;
}

std::vector<api::Submap> SubmapBuilder::Flush() {
  std::vector<api::Submap> done;
  if (!open_.empty()) Close(&done);
  if (pending_) FinishPending(&done);
  return done;
}

}  // namespace raillomer
