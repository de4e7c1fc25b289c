// The two registration stages of the submap mapping on a constructed corridor with known
// geometry: ICP and NDT recover a known offset, the scan-to-submap stage repairs a keyframe
// whose odometry pose is off, the submap-to-submap stage moves a misplaced submap onto its
// predecessor, all but the GNSS pull, and a second pass over the same track is registered onto
// the first from the archive of finished submaps.
#include <cmath>
#include <random>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/factors/pose_manifold.h"
#include "estimator/mapping/submap_archive.h"
#include "estimator/mapping/submap_builder.h"
#include "estimator/mapping/submap_registration.h"

namespace raillomer {
namespace {

using Vec3 = Eigen::Vector3d;

Eigen::Isometry3d Pose(const Vec3& t, double yaw) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
  T.translation() = t;
  return T;
}

/// Points with 1 cm of Gaussian noise on each axis, from a seeded generator.
class NoisyPoints {
 public:
  explicit NoisyPoints(unsigned seed) : rng_(seed) {}
  void Add(const Vec3& p) { points_.push_back(p + Vec3(noise_(rng_), noise_(rng_), noise_(rng_))); }
  std::vector<Vec3> Take() { return std::move(points_); }

 private:
  std::mt19937 rng_;
  std::normal_distribution<double> noise_{0.0, 0.01};
  std::vector<Vec3> points_;
};

/// A corridor in its own frame (x along the track): ground, a wall on either side with
/// recesses, boxes, and masts every 8 m, sampled every 0.1 m with 1 cm noise.
std::vector<Vec3> Corridor(double length_m) {
  NoisyPoints points(7);
  const auto add = [&](const Vec3& p) { points.Add(p); };
  for (double x = -10.0; x < length_m; x += 0.1) {
    for (double y = -6.0; y <= 6.0; y += 0.2) add(Vec3(x, y, 0.0));
    // Walls with a 0.5 m recess every 12 m, so the along-track position is observable.
    const bool recess = std::fmod(x + 100.0, 12.0) < 3.0;
    for (double z = 0.0; z < 4.0; z += 0.1) {
      add(Vec3(x, recess ? 7.5 : 7.0, z));
      add(Vec3(x, -7.0, z));
    }
  }
  // The recesses' end faces, and a 1 m box every 9 m beside the track.
  for (double x = -12.0; x < length_m; x += 12.0) {
    for (double y = 7.0; y <= 7.5; y += 0.1) {
      for (double z = 0.0; z < 4.0; z += 0.1) {
        add(Vec3(x, y, z));
        add(Vec3(x + 3.0, y, z));
      }
    }
  }
  for (double x = 3.0; x < length_m; x += 9.0) {
    for (double u = 0.0; u <= 1.0; u += 0.1) {
      for (double v = 0.0; v <= 1.0; v += 0.1) {
        add(Vec3(x, -5.0 + u, v));
        add(Vec3(x + 1.0, -5.0 + u, v));
        add(Vec3(x + u, -5.0, v));
        add(Vec3(x + u, -4.0, v));
        add(Vec3(x + u, -5.0 + v, 1.0));
      }
    }
  }
  for (double x = 0.0; x < length_m; x += 8.0) {
    for (double a = 0.0; a < 2.0 * M_PI; a += 0.3) {
      for (double z = 0.0; z < 6.0; z += 0.1) {
        add(Vec3(x + 0.15 * std::cos(a), 4.0 + 0.15 * std::sin(a), z));
      }
    }
  }
  return points.Take();
}

/// What a sensor at pose T sees of the corridor (within 25 m), in its own frame.
std::vector<Eigen::Vector3f> Scan(const std::vector<Vec3>& world, const Eigen::Isometry3d& T) {
  std::vector<Eigen::Vector3f> out;
  const Eigen::Isometry3d inv = T.inverse();
  for (const Vec3& p : world) {
    if ((p - T.translation()).head<2>().norm() < 25.0) out.push_back((inv * p).cast<float>());
  }
  return out;
}

std::vector<Eigen::Vector3f> ToFloat(const std::vector<Vec3>& points) {
  std::vector<Eigen::Vector3f> out;
  for (const Vec3& p : points) out.push_back(p.cast<float>());
  return out;
}

TEST(Registration, IcpAndNdtRecoverAKnownOffset) {
  const std::vector<Vec3> world = Corridor(40.0);
  const Eigen::Isometry3d truth = Pose(Vec3(10.0, 0.3, 0.0), 0.0);
  const std::vector<Eigen::Vector3f> scan = Scan(world, truth);
  const std::vector<Eigen::Vector3f> target = ToFloat(world);
  // The guess is 0.25 m and 0.5 deg off.
  const Eigen::Isometry3d guess = Pose(Vec3(10.2, 0.45, 0.05), 0.5 * M_PI / 180.0);

  const Registration icp = IcpRegister(scan, target, guess, IcpOptions{});
  EXPECT_TRUE(icp.converged);
  EXPECT_LT((icp.T_target_source.translation() - truth.translation()).norm(), 0.02);
  double t = 0.0, r = 0.0;
  CorrectionSize(truth, icp.T_target_source, &t, &r);
  EXPECT_LT(r, 0.1 * M_PI / 180.0);

  const Registration ndt = NdtRegister(scan, target, guess, NdtOptions{});
  EXPECT_TRUE(ndt.converged);
  EXPECT_LT((ndt.T_target_source.translation() - truth.translation()).norm(), 0.05);
  CorrectionSize(truth, ndt.T_target_source, &t, &r);
  EXPECT_LT(r, 0.2 * M_PI / 180.0);
}

// A submap's guess from the chain can be off by a milliradian of pitch or roll about its
// origin, which lies behind its points: NDT takes it out. (PCL's NDT stops on the translation
// of a step alone: with a large epsilon it stops after one step with the rotation left in
// place; see NdtOptions::transformation_epsilon.)
TEST(Registration, NdtTakesOutASmallRotationAboutTheOrigin) {
  const std::vector<Vec3> world = Corridor(60.0);
  const Eigen::Isometry3d truth = Pose(Vec3(10.0, 0.0, 0.0), 0.0);
  const std::vector<Eigen::Vector3f> scan = Scan(world, truth);
  const std::vector<Eigen::Vector3f> target = ToFloat(world);
  const Vec3 axes[] = {Vec3::UnitY(), Vec3::UnitX()};
  for (const Vec3& axis : axes) {
    Eigen::Isometry3d guess = truth;
    guess.linear() = truth.linear() * Eigen::AngleAxisd(1.5e-3, axis).toRotationMatrix();
    const Registration ndt = NdtRegister(scan, target, guess, NdtOptions{});
    EXPECT_TRUE(ndt.converged);
    double t = 0.0, r = 0.0;
    CorrectionSize(truth, ndt.T_target_source, &t, &r);
    EXPECT_LT(r, 0.3e-3) << "about " << axis.transpose() << " after " << ndt.iterations
                         << " iterations";
    EXPECT_LT(t, 0.01);
  }
}

/// Bare track: ground 12 m wide and two rails, sampled every 0.1 m with 1 cm noise.
std::vector<Vec3> BareTrack(double length_m) {
  NoisyPoints points(11);
  const auto add = [&](const Vec3& p) { points.Add(p); };
  for (double x = -10.0; x < length_m; x += 0.1) {
    for (double y = -6.0; y <= 6.0; y += 0.2) add(Vec3(x, y, 0.0));
    for (const double y : {-0.75, 0.75}) {
      for (double z = 0.0; z <= 0.17; z += 0.03) add(Vec3(x, y, z));
      add(Vec3(x, y - 0.035, 0.17));
      add(Vec3(x, y + 0.035, 0.17));
    }
  }
  return points.Take();
}

/// The cost (x - d)' I (x - d) of the quadratic model HoldPoorlySeenTurn works on.
double ModelCost(const Eigen::Matrix<double, 6, 6>& I,
                 const Eigen::Matrix<double, 6, 1>& x,
                 const Eigen::Matrix<double, 6, 1>& d) {
  return (x - d).dot(I * (x - d));
}

Eigen::Matrix<double, 6, 1> AboutPivot(const Eigen::Isometry3d& delta, const Vec3& pivot) {
  const Eigen::AngleAxisd turn(delta.linear());
  Eigen::Matrix<double, 6, 1> x;
  x << delta * pivot - pivot, turn.angle() * turn.axis();
  return x;
}

// Where the turn is held, what remains is the best correction without it: on the model about
// the pivot, no change of the five other directions does better, and the turn is zero.
TEST(Registration, AHeldTurnLeavesTheBestCorrectionWithoutIt) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::Matrix<double, 6, 6> A;
  for (int i = 0; i < 36; ++i) A(i / 6, i % 6) = n(rng);
  const Eigen::Matrix<double, 6, 6> information = A.transpose() * A * 1e4;
  const Vec3 pivot(12.0, -3.0, 1.5);
  Eigen::Isometry3d delta = Eigen::Isometry3d::Identity();
  delta.linear() = Eigen::AngleAxisd(4e-3, Vec3(0.1, -0.2, 1.0).normalized()).toRotationMatrix();
  delta.translation() = Vec3(0.05, -0.12, 0.02);
  const Eigen::Matrix<double, 6, 1> d = AboutPivot(delta, pivot);

  Eigen::Isometry3d kept = delta;
  EXPECT_FALSE(HoldPoorlySeenTurn(information, pivot, 0.0, &kept));
  EXPECT_TRUE(kept.isApprox(delta));

  Eigen::Isometry3d held = delta;
  ASSERT_TRUE(HoldPoorlySeenTurn(information, pivot, 1e3, &held));
  const Eigen::Matrix<double, 6, 1> x = AboutPivot(held, pivot);
  EXPECT_NEAR(x(5), 0.0, 1e-9);
  EXPECT_GT(std::fabs(x(1) - d(1)), 1e-4) << "the sideways part moves with the turn taken out";
  // The model's information is about the origin: move it to the pivot as the function does.
  Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Identity();
  J.topRightCorner<3, 3>() = Skew(pivot);
  const Eigen::Matrix<double, 6, 6> I = J.transpose() * information * J;
  const double best = ModelCost(I, x, d);
  for (int i = 0; i < 5; ++i) {
    for (const double step : {-1e-4, 1e-4}) {
      Eigen::Matrix<double, 6, 1> y = x;
      y(i) += step;
      EXPECT_GT(ModelCost(I, y, d), best) << "direction " << i;
    }
  }
}

// Along a built-up corridor NDT sees the turn (its walls, boxes and masts lie all along the
// submap); on bare track, ground and two rails, it hardly does and the turn is held.
TEST(Registration, TheTurnIsHeldOnBareTrackButNotAlongABuiltUpCorridor) {
  // As the submap builder registers: both clouds in one frame, the source around a pivot 10 m
  // from the origin, misplaced by 2 mrad and 5 cm sideways.
  const Vec3 pivot(10.0, 0.0, 0.0);
  const Eigen::Isometry3d misplaced = Pose(pivot + Vec3(0.0, 0.05, 0.0), 2e-3) * Pose(-pivot, 0.0);
  const auto held = [&](const std::vector<Vec3>& world) {
    std::vector<Eigen::Vector3f> source;
    for (const Vec3& p : world) {
      if ((p - pivot).head<2>().norm() < 25.0) source.push_back((misplaced * p).cast<float>());
    }
    const Registration ndt =
        NdtRegister(source, ToFloat(world), Eigen::Isometry3d::Identity(), NdtOptions{});
    EXPECT_TRUE(ndt.converged);
    Eigen::Isometry3d delta = ndt.T_target_source;
    return HoldPoorlySeenTurn(ndt.information, pivot, SubmapOptions{}.ndt_min_turn_arm_m, &delta);
  };
  EXPECT_FALSE(held(Corridor(60.0)));
  EXPECT_TRUE(held(BareTrack(60.0)));
}

TEST(Registration, TooFewPointsIsNotConverged) {
  const std::vector<Eigen::Vector3f> few = {Eigen::Vector3f::Zero()};
  EXPECT_FALSE(IcpRegister(few, few, Eigen::Isometry3d::Identity(), IcpOptions{}).converged);
  EXPECT_FALSE(NdtRegister(few, few, Eigen::Isometry3d::Identity(), NdtOptions{}).converged);
}

/// Keyframes 2 m apart along a corridor placed at UTM-sized coordinates, heading 30 deg.
struct CorridorRun {
  std::vector<Vec3> world;
  Eigen::Isometry3d T_utm_corridor = Pose(Vec3(432100.0, 3585200.0, 30.0), 30.0 * M_PI / 180.0);
  explicit CorridorRun(double length_m) : world(Corridor(length_m)) {}
  Eigen::Isometry3d Truth(int k) const {
    return T_utm_corridor * Pose(Vec3(2.0 * k, 0.0, 2.0), 0.0);
  }
  SubmapKeyframe Keyframe(int k, const Eigen::Isometry3d& odom, const Vec3& gnss_offset) const {
    SubmapKeyframe kf;
    kf.stamp_ns = 1'600'000'000'000'000'000 + k * 100'000'000LL;
    kf.T_odom_body = odom;
    kf.T_world_body = Truth(k);
    kf.T_world_body.translation() += gnss_offset;
    kf.georeferenced = true;
    kf.utm_zone = "50N";
    kf.points_body = Scan(world, Pose(Vec3(2.0 * k, 0.0, 2.0), 0.0));
    return kf;
  }
};

TEST(SubmapBuilder, ScanToSubmapIcpRepairsAKeyframeTheOdometryPutWrong) {
  const CorridorRun run(40.0);
  SubmapOptions options;
  options.ndt = false;
  SubmapBuilder builder(options);
  // The odometry frame is an arbitrary frame; keyframe 7's odometry pose is 0.15 m off
  // sideways and 0.3 deg in yaw.
  const Eigen::Isometry3d T_odom_utm = Pose(Vec3(-432000.0, -3585000.0, -25.0), -0.2);
  std::vector<api::Submap> done;
  for (int k = 0; k < 10; ++k) {
    Eigen::Isometry3d odom = T_odom_utm * run.Truth(k);
    SubmapKeyframe kf = run.Keyframe(k, odom, Vec3::Zero());
    if (k == 7) {
      kf.T_odom_body = odom * Pose(Vec3(0.0, 0.15, 0.0), 0.3 * M_PI / 180.0);
      kf.odometry_suspect = true;  // its solve hit the iteration limit
    }
    for (api::Submap& s : builder.Add(kf)) done.push_back(s);
  }
  ASSERT_EQ(done.size(), 1u);
  EXPECT_EQ(builder.stats().icp_odometry + builder.stats().icp_gnss, 1u);
  EXPECT_EQ(builder.stats().icp_failed, 0u);
  for (int k = 0; k < 10; ++k) {
    EXPECT_LT((done[0].keyframes[k].p_world - run.Truth(k).translation()).norm(), 0.02)
        << "keyframe " << k;
  }
}

/// Two submaps of ten keyframes; the second's GNSS poses are moved by `gnss_offset`, its
/// odometry poses by `odometry_offset` (a jump of the odometry between the two).
std::vector<api::Submap> TwoSubmaps(const SubmapOptions& options,
                                    const Vec3& gnss_offset,
                                    const Vec3& odometry_offset,
                                    SubmapStats* stats) {
  const CorridorRun run(60.0);
  SubmapBuilder builder(options);
  std::vector<api::Submap> done;
  const Eigen::Isometry3d T_odom_utm = Pose(Vec3(-432000.0, -3585000.0, -25.0), 0.4);
  for (int k = 0; k < 20; ++k) {
    Eigen::Isometry3d odom = T_odom_utm * run.Truth(k);
    if (k >= 10) odom.translation() += T_odom_utm.linear() * odometry_offset;  // world axes
    const SubmapKeyframe kf = run.Keyframe(k, odom, k < 10 ? Vec3::Zero() : gnss_offset);
    for (api::Submap& s : builder.Add(kf)) done.push_back(s);
  }
  for (api::Submap& s : builder.Flush()) done.push_back(s);  // the second waits for its NDT
  *stats = builder.stats();
  return done;
}

Vec3 Sideways(double lateral_m, double up_m, double along_m = 0.0) {
  return CorridorRun(0.0).T_utm_corridor.linear() * Vec3(along_m, lateral_m, up_m);
}

TEST(SubmapBuilder, TheChainPlacesASubmapByTheOdometryPulledTowardsGnss) {
  SubmapOptions options;
  options.icp = false;
  options.ndt = false;
  SubmapStats stats;
  // The second submap's GNSS poses are 0.4 m off sideways, 0.2 m up and 0.6 m ahead: the
  // chain keeps it on the first, moved only the pull's share of the way along the track and
  // gnss_pull_along_excess of the 0.1 m beyond 1/4 of chain_reset_m (sideways and in height
  // not at all: there the chain follows GNSS through its heading and slope, and those have
  // only begun to turn).
  const Vec3 offset = Sideways(0.4, 0.2, 0.6);
  const std::vector<api::Submap> done = TwoSubmaps(options, offset, Vec3::Zero(), &stats);
  ASSERT_EQ(done.size(), 2u);
  EXPECT_EQ(stats.chained, 1u);
  EXPECT_EQ(stats.chain_resets, 0u);
  const CorridorRun run(0.0);
  const double barrier = 0.25 * options.chain_reset_m;
  const Vec3 pulled = Sideways(
      0.0, 0.0, options.gnss_pull * 0.6 + options.gnss_pull_along_excess * (0.6 - barrier));
  for (int k = 0; k < 10; ++k) {
    const Vec3 left = done[1].keyframes[k].p_world - run.Truth(10 + k).translation();
    EXPECT_LT((left - pulled).norm(), 0.005) << left.transpose();
  }
  // Without the heading loop the pull acts sideways too.
  SubmapOptions sideways_pull = options;
  sideways_pull.gnss_heading_length_m = 0.0;
  const std::vector<api::Submap> old = TwoSubmaps(sideways_pull, offset, Vec3::Zero(), &stats);
  ASSERT_EQ(old.size(), 2u);
  const Vec3 both = options.gnss_pull * Sideways(0.4, 0.0, 0.6);
  EXPECT_LT((old[1].keyframes[5].p_world - run.Truth(15).translation() - both).norm(), 0.005);
  // 1.9 m off sideways is 0.4 m beyond 3/4 of chain_reset_m: with gnss_pull_excess the pull
  // takes its share of that.
  SubmapOptions with_excess = options;
  with_excess.gnss_pull_excess = 0.2;
  const std::vector<api::Submap> excess =
      TwoSubmaps(with_excess, Sideways(1.9, 0.0), Vec3::Zero(), &stats);
  ASSERT_EQ(excess.size(), 2u);
  EXPECT_EQ(stats.chain_resets, 0u);
  const Vec3 back = 0.2 * Sideways(1.9 - 0.75 * options.chain_reset_m, 0.0);
  EXPECT_LT((excess[1].keyframes[5].p_world - run.Truth(15).translation() - back).norm(), 0.005);
  // 3 m off is beyond chain_reset_m: GNSS places the submap.
  const Vec3 far = Sideways(3.0, 0.0);
  const std::vector<api::Submap> reset = TwoSubmaps(options, far, Vec3::Zero(), &stats);
  EXPECT_EQ(stats.chain_resets, 1u);
  EXPECT_LT((reset[1].keyframes[5].p_world - run.Truth(15).translation() - far).norm(), 0.005);
  // Along the track the chain may be twice as far off: 3 m ahead it is pulled, 5 m ahead
  // GNSS places it.
  const std::vector<api::Submap> ahead =
      TwoSubmaps(options, Sideways(0.0, 0.0, 3.0), Vec3::Zero(), &stats);
  EXPECT_EQ(stats.chain_resets, 0u);
  const Vec3 forward = Sideways(
      0.0, 0.0, options.gnss_pull * 3.0 + options.gnss_pull_along_excess * (3.0 - barrier));
  EXPECT_LT((ahead[1].keyframes[5].p_world - run.Truth(15).translation() - forward).norm(), 0.005);
  const Vec3 farther = Sideways(0.0, 0.0, 5.0);
  const std::vector<api::Submap> leap = TwoSubmaps(options, farther, Vec3::Zero(), &stats);
  EXPECT_EQ(stats.chain_resets, 1u);
  EXPECT_LT((leap[1].keyframes[5].p_world - run.Truth(15).translation() - farther).norm(), 0.005);
}

/// 150 submaps of 20 m whose GNSS poses lie `gnss_offset` (UTM) from the truth from the second
/// submap on, placed by the chain alone (no registration, no points), with the loops faster
/// than the defaults for a short run: 0.4 mrad a 20 m submap, 4 mm at a seam.
std::vector<api::Submap> ChainTowards(const Vec3& gnss_offset) {
  SubmapOptions options;
  options.icp = false;
  options.ndt = false;
  options.gnss_height_length_m = 400.0;
  options.gnss_heading_length_m = 400.0;
  options.gnss_max_tilt_rate_rad_per_m = 2e-5;
  options.gnss_max_turn_rate_rad_per_m = 2e-5;
  const CorridorRun run(0.0);
  SubmapBuilder builder(options);
  std::vector<api::Submap> done;
  const Eigen::Isometry3d T_odom_utm = Pose(Vec3(-432000.0, -3585000.0, -25.0), 0.4);
  for (int k = 0; k < 1500; ++k) {
    const SubmapKeyframe kf =
        run.Keyframe(k, T_odom_utm * run.Truth(k), k < 10 ? Vec3::Zero() : gnss_offset);
    for (api::Submap& s : builder.Add(kf)) done.push_back(s);
  }
  for (api::Submap& s : builder.Flush()) done.push_back(s);
  return done;
}

/// How far the chain climbs to GNSS (or turns to it), and its largest step at a seam in that
/// direction: beyond the slope across the last two keyframes of the earlier submap (2 m
/// apart), any difference between it and the next submap's first keyframe is the seam's.
struct Approach {
  double largest_step_m = 0.0;
  double at_fifth_m = 0.0;  ///< the offset reached 600 m in
  double at_end_m = 0.0;
};
Approach Follow(const std::vector<api::Submap>& done, const Vec3& direction) {
  const CorridorRun run(0.0);
  const auto offset = [&](size_t s, int k) {
    return direction.dot(done[s].keyframes[static_cast<size_t>(k)].p_world -
                         run.Truth(10 * static_cast<int>(s) + k).translation());
  };
  Approach a;
  for (size_t s = 1; s < done.size(); ++s) {
    const double within = offset(s - 1, 9) - offset(s - 1, 8);
    a.largest_step_m =
        std::max(a.largest_step_m, std::fabs(offset(s, 0) - offset(s - 1, 9) - within));
  }
  a.at_fifth_m = offset(done.size() / 5, 5);
  a.at_end_m = offset(done.size() - 1, 5);
  return a;
}

// From the second submap on GNSS says the track lies 1 m higher than the odometry has it. A
// height pull would step each submap up at its seam (a rail-head step in the map: 5 cm at a
// 5 % pull); the height loop tilts the chain instead, so consecutive submaps still meet, and
// within a few natural lengths the chain reaches the GNSS height.
TEST(SubmapBuilder, TheChainClimbsToTheGnssHeightWithoutAStepAtAnySeam) {
  const std::vector<api::Submap> done = ChainTowards(Vec3(0.0, 0.0, 1.0));
  ASSERT_EQ(done.size(), 150u);
  const Approach a = Follow(done, Vec3::UnitZ());
  EXPECT_LT(a.largest_step_m, 0.005);
  EXPECT_NEAR(a.at_end_m, 1.0, 0.1);
  EXPECT_GT(a.at_fifth_m, 0.3);  // climbing by 600 m, not still level
}

// The same sideways: GNSS says the track lies 1 m to the left. A sideways pull would step each
// submap across at its seam (2-5 cm between submaps that see the same wall, on the simulator's
// runs); the heading loop turns the chain instead.
TEST(SubmapBuilder, TheChainTurnsToTheGnssTrackWithoutAStepAtAnySeam) {
  const Vec3 left = Sideways(1.0, 0.0);
  const std::vector<api::Submap> done = ChainTowards(left);
  ASSERT_EQ(done.size(), 150u);
  const Approach a = Follow(done, left);
  EXPECT_LT(a.largest_step_m, 0.005);
  EXPECT_NEAR(a.at_end_m, 1.0, 0.1);
  EXPECT_GT(a.at_fifth_m, 0.3);
  // Along the track and in height it stays on the truth.
  EXPECT_LT(std::fabs(Follow(done, Vec3::UnitZ()).at_end_m), 0.02);
}

TEST(SubmapBuilder, SubmapToSubmapNdtMovesAMisplacedSubmapOntoItsPredecessor) {
  SubmapOptions options;
  options.icp = false;
  SubmapStats stats;
  // The odometry jumps 0.2 m sideways between the submaps; GNSS is right, so the chain puts
  // the second submap 0.19 m off, and NDT takes it back onto the first. (Along the track NDT
  // is not used: there the scale-corrected odometry is trusted over a repetitive corridor.)
  const Vec3 jump = Sideways(0.2, 0.0);
  const std::vector<api::Submap> done = TwoSubmaps(options, Vec3::Zero(), jump, &stats);
  ASSERT_EQ(done.size(), 2u);
  EXPECT_EQ(stats.ndt_applied, 1u);
  const CorridorRun run(0.0);
  const Vec3 left = done[1].keyframes[5].p_world - run.Truth(15).translation();
  EXPECT_LT(left.norm(), 0.03) << left.transpose();
  options.ndt = false;
  const std::vector<api::Submap> without = TwoSubmaps(options, Vec3::Zero(), jump, &stats);
  EXPECT_GT((without[1].keyframes[5].p_world - run.Truth(15).translation()).norm(), 0.15);
}

TEST(SubmapArchive, ReturnsTheStoredPointsInsideABoxAsOffsetsFromTheAskedOrigin) {
  SubmapArchive archive;
  EXPECT_TRUE(archive.on_disk());
  const Vec3 origin_a(432100.0, 3585200.0, 30.0);
  const Vec3 origin_b(432150.0, 3585200.0, 31.0);
  // Submap 0: a line of points along x, 0..40 m from its origin; submap 1: 50 m further,
  // another line; submap 2: the same ground as submap 0 but in another zone.
  std::vector<Eigen::Vector3f> line;
  for (int i = 0; i <= 40; ++i) line.emplace_back(static_cast<float>(i), 0.5f, 0.25f);
  archive.Put(0, "50N", origin_a, line);
  archive.Put(1, "50N", origin_b, line);
  archive.Put(2, "51N", origin_a, line);
  archive.Put(3, "50N", origin_a, {});  // nothing to store
  EXPECT_EQ(archive.size(), 3u);

  // A box 30..60 m east of origin_a, asked in a frame 10 m east and 1 m up of it.
  const Vec3 query = origin_a + Vec3(10.0, 0.0, 1.0);
  const Eigen::AlignedBox3f box(Eigen::Vector3f(20.0f, -1.0f, -2.0f),
                                Eigen::Vector3f(50.0f, 1.0f, 2.0f));
  std::vector<uint32_t> ids;
  const std::vector<Eigen::Vector3f> got = archive.Within("50N", query, box, {}, &ids);
  EXPECT_EQ(ids, (std::vector<uint32_t>{0, 1}));
  // Submap 0 gives x = 30..40 m of origin_a (11 points), submap 1 x = 50..60 (11 points).
  ASSERT_EQ(got.size(), 22u);
  for (const Eigen::Vector3f& p : got) {
    EXPECT_TRUE(box.contains(p));
    EXPECT_NEAR(std::round(p.x()), p.x(), 1e-6);
    EXPECT_NEAR(p.y(), 0.5f, 1e-6);
  }
  EXPECT_NEAR(got.front().x(), 20.0f, 1e-6);  // 30 m of origin_a, 10 m of query's
  EXPECT_NEAR(got.front().z(), -0.75f, 1e-6);
  EXPECT_NEAR(got.back().x(), 50.0f, 1e-6);  // 60 m of origin_a = 10 m of origin_b
  EXPECT_NEAR(got.back().z(), 0.25f, 1e-6);

  EXPECT_TRUE(archive.Within("52N", query, box, {}, &ids).empty());
  EXPECT_TRUE(ids.empty());
  // Only the submaps the filter takes.
  const std::vector<Eigen::Vector3f> second = archive.Within(
      "50N", query, box, [](uint32_t id) { return id == 1; }, &ids);
  EXPECT_EQ(ids, (std::vector<uint32_t>{1}));
  EXPECT_EQ(second.size(), 11u);
  const Eigen::AlignedBox3f beyond(Eigen::Vector3f(200.0f, -1.0f, -2.0f),
                                   Eigen::Vector3f(300.0f, 1.0f, 2.0f));
  EXPECT_TRUE(archive.Within("50N", query, beyond).empty());
}

/// The submaps of a train that runs 78 m out along `run`'s corridor and back over the same
/// track, whose odometry is exact on the way out and off by `drift` (UTM axes) on the way back,
/// and whose GNSS agrees with the odometry (no help on the way back).
std::vector<api::Submap> OutAndBack(const CorridorRun& run,
                                    const Vec3& drift,
                                    SubmapOptions options,
                                    SubmapStats* stats) {
  const Eigen::Isometry3d T_odom_utm = Pose(Vec3(-432000.0, -3585000.0, -25.0), 0.4);
  options.icp = false;
  options.gnss_pull = 0.0;
  options.gnss_pull_vertical = 0.0;
  SubmapBuilder builder(options);
  std::vector<api::Submap> done;
  std::vector<int> along;  // keyframe positions, out (0..39) and back (39..0)
  for (int k = 0; k < 40; ++k) along.push_back(k);
  for (int k = 39; k >= 0; --k) along.push_back(k);
  for (size_t i = 0; i < along.size(); ++i) {
    const bool back = i >= 40;
    // Reversing, the body keeps facing the same way: the keyframe poses are the outward ones.
    Eigen::Isometry3d odom = T_odom_utm * run.Truth(along[i]);
    if (back) odom.translation() += T_odom_utm.linear() * drift;
    const SubmapKeyframe kf = run.Keyframe(along[i], odom, back ? drift : Vec3::Zero());
    for (api::Submap& s : builder.Add(kf)) done.push_back(s);
  }
  for (api::Submap& s : builder.Flush()) done.push_back(s);
  *stats = builder.stats();
  return done;
}

/// The largest distance (m) of the way back's keyframes (submaps 4-7) from the truth.
double WorstOnTheWayBack(const CorridorRun& run, const std::vector<api::Submap>& done) {
  double worst = 0.0;
  for (size_t s = 4; s < 8 && s < done.size(); ++s) {
    for (int k = 0; k < 10; ++k) {
      const int at = 39 - static_cast<int>(10 * (s - 4)) - k;
      worst = std::max(worst, (done[s].keyframes[k].p_world - run.Truth(at).translation()).norm());
    }
  }
  return worst;
}

TEST(SubmapBuilder, ASecondPassIsRegisteredOntoTheFirst) {
  // On the way back the odometry has drifted 0.12 m up and 0.1 m sideways: NDT onto the first
  // pass's submaps, which the way back overlaps, takes the second pass back onto it.
  const CorridorRun run(80.0);
  SubmapStats stats;
  const std::vector<api::Submap> done =
      OutAndBack(run, Sideways(0.1, 0.12), SubmapOptions{}, &stats);
  ASSERT_EQ(done.size(), 8u);
  EXPECT_GE(stats.ndt_revisits, 3u);
  EXPECT_LT(WorstOnTheWayBack(run, done), 0.03);
  // Without NDT the second pass stays where the odometry put it.
  SubmapOptions without_ndt;
  without_ndt.ndt = false;
  const std::vector<api::Submap> without =
      OutAndBack(run, Sideways(0.1, 0.12), without_ndt, &stats);
  EXPECT_GT((without[6].keyframes[5].p_world - run.Truth(14).translation()).norm(), 0.1);
}

TEST(SubmapBuilder, ASecondPassOffAlongTheTrackIsTakenBackOntoTheFirst) {
  // On the way back the odometry is 0.15 m off along the track, which this corridor shows NDT
  // only weakly (its recesses and boxes against the long walls and the ground; an information
  // share of 0.005-0.013): too weakly to take from one submap onto the last, where a slide
  // would be carried along the chain, but enough onto an earlier pass, which holds it. Each
  // registration takes a share of the offset (NDT converges slowly along a weak direction),
  // and the chain carries it on, so the way back comes closer submap by submap.
  const CorridorRun run(80.0);
  const Vec3 drift = Sideways(0.0, 0.0, 0.15);
  const auto along_error = [&](const std::vector<api::Submap>& done, size_t s) {
    const int at = 39 - static_cast<int>(10 * (s - 4)) - 5;
    return Sideways(0.0, 0.0, 1.0).dot(done[s].keyframes[5].p_world - run.Truth(at).translation());
  };
  SubmapStats stats;
  const std::vector<api::Submap> done = OutAndBack(run, drift, SubmapOptions{}, &stats);
  ASSERT_EQ(done.size(), 8u);
  EXPECT_GE(stats.ndt_revisits, 3u);
  EXPECT_NEAR(along_error(done, 4), 0.15, 0.01);  // the turn's submap: no earlier pass yet
  EXPECT_LT(along_error(done, 5), along_error(done, 4) - 0.03);
  EXPECT_LT(along_error(done, 6), along_error(done, 5) - 0.03);
  EXPECT_LT(along_error(done, 7), 0.05);
  // Held to the bar of one pass onto the last, the way back stays off along the track.
  SubmapOptions one_pass_bar;
  one_pass_bar.ndt_min_along_information_revisit = one_pass_bar.ndt_min_along_information;
  const std::vector<api::Submap> held = OutAndBack(run, drift, one_pass_bar, &stats);
  EXPECT_GT(along_error(held, 7), 0.13);
}

}  // namespace
}  // namespace raillomer
