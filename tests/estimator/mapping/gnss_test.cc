// GNSS georeferencing on generated data with known answers.
#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "estimator/factors/gnss_factors.h"
#include "estimator/geo/gnss.h"
#include "estimator/mapping/gnss_fusion.h"

namespace raillomer {
namespace {

constexpr double kDeg = M_PI / 180.0;

io::GnssFix FixAt(const geo::UtmZone& zone, const Eigen::Vector3d& utm, int64_t stamp_ns) {
  io::GnssFix fix;
  fix.stamp_ns = stamp_ns;
  const Eigen::Vector2d ll = geo::UtmToGeographic(zone, utm.x(), utm.y());
  fix.latitude_deg = ll.x();
  fix.longitude_deg = ll.y();
  fix.altitude_m = utm.z();
  return fix;
}

TEST(GnssFix, UnusableFixesAreRejectedWithTheReason) {
  geo::UtmZone zone;
  ASSERT_TRUE(geo::ParseZone("50N", &zone));
  EXPECT_EQ(zone.zone, 50);
  EXPECT_TRUE(zone.north);
  geo::UtmZone bad;
  EXPECT_FALSE(geo::ParseZone("61N", &bad));
  EXPECT_FALSE(geo::ParseZone("50X", &bad));
  EXPECT_FALSE(geo::ParseZone("N", &bad));

  const geo::FixCheckOptions options;
  const io::GnssFix good = FixAt(zone, {432000.0, 3585000.0, 30.0}, 0);
  Eigen::Vector3d utm;
  EXPECT_EQ(geo::CheckFix(good, zone, options, &utm), "");
  EXPECT_NEAR(utm.x(), 432000.0, 1e-3);
  EXPECT_NEAR(utm.y(), 3585000.0, 1e-3);

  auto reason = [&](io::GnssFix f) { return geo::CheckFix(f, zone, options, &utm); };
  io::GnssFix f = good;
  f.latitude_deg = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(reason(f).find("NaN"), std::string::npos);
  f = good;
  f.latitude_deg = 0.0;
  f.longitude_deg = 0.0;
  EXPECT_NE(reason(f).find("both 0"), std::string::npos);
  f = good;
  f.altitude_m = 1e6;
  EXPECT_NE(reason(f).find("absurd height"), std::string::npos);
  f = good;
  f.latitude_deg = -f.latitude_deg;
  EXPECT_NE(reason(f).find("southern hemisphere"), std::string::npos);
  f = good;
  f.longitude_deg += 20.0;
  EXPECT_NE(reason(f).find("outside UTM zone 50N"), std::string::npos);
  f = good;
  f.longitude_deg = 121.5;  // 1.5 deg past the zone's edge: a line that runs on is still usable
  EXPECT_EQ(reason(f), "");
  f = good;
  f.status = -1;
  EXPECT_NE(reason(f).find("no fix"), std::string::npos);
}

TEST(GnssAlignment, RecoversAKnownYawAndOffsetDespiteMultipath) {
  // Odometry along a gentle curve; the fixes are the same path turned by 37 deg, shifted, with
  // 0.3 m noise and every 7th fix thrown 5-30 m by multipath.
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.3);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const geo::FourDof truth{37.0 * kDeg, Eigen::Vector3d(120.0, -45.0, 3.0)};
  std::vector<Eigen::Vector3d> odom, enu;
  for (int k = 0; k < 60; ++k) {
    const double s = 5.0 * k;
    const Eigen::Vector3d p(s, 0.0005 * s * s, 0.01 * s);
    odom.push_back(p);
    Eigen::Vector3d z = truth.Apply(p) + Eigen::Vector3d(noise(rng), noise(rng), noise(rng));
    if (k % 7 == 3) {
      const double a = 2.0 * M_PI * uniform(rng), m = 5.0 + 25.0 * uniform(rng);
      z += Eigen::Vector3d(m * std::cos(a), m * std::sin(a), 0.0);
    }
    enu.push_back(z);
  }
  const geo::GnssAlignment a = geo::AlignToGnss(odom, enu, geo::GnssAlignmentOptions());
  ASSERT_TRUE(a.ok) << a.reason;
  EXPECT_NEAR(a.T_enu_odom.yaw_rad, truth.yaw_rad, 0.1 * kDeg);
  EXPECT_LT((a.T_enu_odom.t - truth.t).head<2>().norm(), 0.5);
  EXPECT_NEAR(a.T_enu_odom.t.z(), truth.t.z(), 0.2);
  EXPECT_EQ(a.outliers, 9);
  EXPECT_LT(a.rms_m, 0.6);

  // Too short a baseline: no alignment, and the reason says how far the train has moved.
  std::vector<Eigen::Vector3d> short_odom(odom.begin(), odom.begin() + 12);
  std::vector<Eigen::Vector3d> short_enu(enu.begin(), enu.begin() + 12);
  const geo::GnssAlignment s = geo::AlignToGnss(short_odom, short_enu, geo::GnssAlignmentOptions());
  EXPECT_FALSE(s.ok);
  EXPECT_NE(s.reason.find("has moved 55 m of the 100 m"), std::string::npos) << s.reason;
}

/// Central differences of a cost over plain (Euclidean) parameter blocks.
void ExpectJacobiansMatchNumeric(const ceres::CostFunction& cost,
                                 std::vector<std::vector<double>> blocks) {
  const int m = cost.num_residuals();
  std::vector<double*> params;
  for (auto& b : blocks) params.push_back(b.data());
  std::vector<std::vector<double>> analytic(blocks.size());
  std::vector<double*> jac;
  for (size_t k = 0; k < blocks.size(); ++k) {
    analytic[k].resize(static_cast<size_t>(m) * blocks[k].size());
    jac.push_back(analytic[k].data());
  }
  std::vector<double> r(static_cast<size_t>(m)), rp(r), rm(r);
  ASSERT_TRUE(cost.Evaluate(params.data(), r.data(), jac.data()));
  const double h = 1e-6;
  for (size_t k = 0; k < blocks.size(); ++k) {
    for (size_t c = 0; c < blocks[k].size(); ++c) {
      const double x = blocks[k][c];
      blocks[k][c] = x + h;
      cost.Evaluate(params.data(), rp.data(), nullptr);
      blocks[k][c] = x - h;
      cost.Evaluate(params.data(), rm.data(), nullptr);
      blocks[k][c] = x;
      for (int i = 0; i < m; ++i) {
        const double numeric = (rp[i] - rm[i]) / (2.0 * h);
        EXPECT_NEAR(analytic[k][static_cast<size_t>(i) * blocks[k].size() + c], numeric, 1e-6)
            << "block " << k << " row " << i << " column " << c;
      }
    }
  }
}

TEST(GnssFactors, JacobiansMatchNumericDifferentiation) {
  const GnssPositionFactor gnss(
      Eigen::Vector3d(10.0, -3.0, 2.0), Eigen::Vector3d(0.4, -0.2, 0.3), 1.0, 2.5);
  ExpectJacobiansMatchNumeric(gnss, {{9.0, -2.5, 1.0, 0.7}});
  const FourDofBetweenFactor between(Eigen::Vector3d(30.0, 1.0, 0.3), 0.02, 31.0, 0.2, 0.07, 1e-3);
  ExpectJacobiansMatchNumeric(between,
                              {{1.0, 2.0, 0.5, 2.9}, {-20.0, 27.0, 0.9, 3.05}, {0.003, 2e-3}});
}

TEST(GnssFactors, TheGnssFactorIsZeroAtTheAntenna) {
  // The antenna 0.3 m up and 1 m forward of a body at yaw 90 deg sits 1 m north of it.
  const GnssPositionFactor f(
      Eigen::Vector3d(5.0, 6.0, 7.3), Eigen::Vector3d(1.0, 0.0, 0.3), 1.0, 2.0);
  const double x[4] = {5.0, 5.0, 7.0, M_PI / 2.0};
  const double* p[1] = {x};
  double r[3];
  ASSERT_TRUE(f.Evaluate(p, r, nullptr));
  EXPECT_NEAR(Eigen::Vector3d(r[0], r[1], r[2]).norm(), 0.0, 1e-12);
}

/// A run through GnssFusion: odometry along a 6 km line with a curve, drifting in heading
/// (0.3 deg over the run) and scale (0.1 %), and 1 Hz fixes of the true antenna position with
/// 0.3 m noise; `outlier_every` > 0 throws every n-th fix 5-30 m off. Returns the georeferenced
/// positions at every odometry pose after the alignment, and the truth beside them.
struct FusionRun {
  std::vector<Eigen::Vector3d> estimate, truth;
  /// After the run: the poses between the first and the newest node, smoothed, and the truth.
  std::vector<Eigen::Vector3d> smoothed, smoothed_truth;
  /// Poses released as the estimator releases them (once settled), through Publish and, for
  /// comparison, straight from the graph at that moment; the truth beside them.
  std::vector<Eigen::Vector3d> published, released, released_truth;
  GnssFusionStats stats;
};

/// The true body pose at t: 30 m/s straight, then a 2 km curve of radius 3 km, then straight.
Eigen::Isometry3d TrueFusionPose(double t) {
  constexpr double kSpeed = 30.0, kHeading0 = 0.6;
  const double s = kSpeed * t;
  double heading = kHeading0, x = 0.0, y = 0.0;
  const double ds = 1.0;
  for (double u = 0.0; u < s; u += ds) {
    const double step = std::min(ds, s - u);
    if (u > 1500.0 && u < 3500.0) heading += step / 3000.0;
    x += step * std::cos(heading);
    y += step * std::sin(heading);
  }
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(heading, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(x, y, 0.002 * s);
  return T;
}

/// Odometry's increment: the true one, 0.1 % long and turning 1e-6 rad per metre too much.
Eigen::Isometry3d DriftingIncrement(const Eigen::Isometry3d& prev_truth,
                                    const Eigen::Isometry3d& T) {
  Eigen::Isometry3d inc = prev_truth.inverse() * T;
  inc.translation() *= 1.001;
  inc.linear() =
      Eigen::AngleAxisd(1e-6 * inc.translation().norm(), Eigen::Vector3d::UnitZ()) * inc.linear();
  return inc;
}

/// Feeds GnssFusion and records what it gives back, as FusionRun describes.
class FusionDriver {
 public:
  explicit FusionDriver(int outlier_every)
      : options_(MakeOptions()),
        fusion_(options_, nullptr, nullptr),
        outlier_every_(outlier_every) {}

  /// One odometry pose at t (and a fix every second).
  void Step(int k) {
    const double t = 0.1 * k;
    const int64_t stamp = static_cast<int64_t>(std::llround(t * 1e9));
    const Eigen::Isometry3d T = TrueFusionPose(t);
    odom_ = odom_ * DriftingIncrement(prev_truth_, T);
    prev_truth_ = T;
    if (k % 10 == 0) fusion_.AddFix(FixAt(options_.zone, NoisyFix(T), stamp));
    fusion_.AddOdometry(stamp, odom_);
    odometry_.emplace_back(t, odom_);
    truth_.push_back(kOrigin + T.translation());
    if (fusion_.aligned()) {
      run_.estimate.push_back(fusion_.ToEnu(odom_).translation() + fusion_.origin_utm());
      run_.truth.push_back(kOrigin + T.translation());
    }
    ReleaseSettled();
  }

  /// The run's figures, with the smoothed poses up to the newest settled time.
  FusionRun Finish() {
    run_.stats = fusion_.stats();
    for (size_t i = 0; i < odometry_.size(); ++i) {
      if (!fusion_.aligned() || odometry_[i].first > fusion_.settled_until_s()) continue;
      run_.smoothed.push_back(fusion_.ToEnu(odometry_[i].second, odometry_[i].first).translation() +
                              fusion_.origin_utm());
      run_.smoothed_truth.push_back(truth_[i]);
    }
    return run_;
  }

 private:
  static GnssFusionOptions MakeOptions() {
    GnssFusionOptions options;
    options.zone.zone = 50;
    options.zone.north = true;
    options.p_body_antenna = Eigen::Vector3d(0.0, 0.0, 0.3);
    return options;
  }

  /// The antenna's true position with 0.3 m noise; every outlier_every-th fix 5-30 m off.
  Eigen::Vector3d NoisyFix(const Eigen::Isometry3d& T) {
    Eigen::Vector3d z = kOrigin + T * options_.p_body_antenna +
                        Eigen::Vector3d(noise_(rng_), noise_(rng_), noise_(rng_));
    if (outlier_every_ > 0 && ++fix_count_ % outlier_every_ == 0) {
      const double a = 2.0 * M_PI * uniform_(multipath_rng_);
      const double m = 5.0 + 25.0 * uniform_(multipath_rng_);
      z += Eigen::Vector3d(m * std::cos(a), m * std::sin(a), 0.0);
    }
    return z;
  }

  /// Poses the fusion has settled, released through Publish and straight from the graph.
  void ReleaseSettled() {
    for (; next_release_ < odometry_.size() &&
           odometry_[next_release_].first <= fusion_.settled_until_s();
         ++next_release_) {
      const auto& [t_s, T_odom] = odometry_[next_release_];
      run_.released.push_back(fusion_.ToEnu(T_odom, t_s).translation() + fusion_.origin_utm());
      run_.published.push_back(fusion_.Publish(T_odom, t_s).translation() + fusion_.origin_utm());
      run_.released_truth.push_back(truth_[next_release_]);
    }
  }

  inline static const Eigen::Vector3d kOrigin{432000.0, 3585000.0, 30.0};
  const GnssFusionOptions options_;
  GnssFusion fusion_;
  const int outlier_every_;
  // Separate generators: the runs with and without outliers see the same receiver noise.
  std::mt19937 rng_{11}, multipath_rng_{12};
  std::normal_distribution<double> noise_{0.0, 0.3};
  std::uniform_real_distribution<double> uniform_{0.0, 1.0};
  int fix_count_ = 0;
  std::vector<std::pair<double, Eigen::Isometry3d>> odometry_;
  std::vector<Eigen::Vector3d> truth_;
  Eigen::Isometry3d odom_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d prev_truth_ = TrueFusionPose(0.0);
  size_t next_release_ = 0;
  FusionRun run_;
};

FusionRun RunFusion(int outlier_every) {
  FusionDriver driver(outlier_every);
  for (int k = 0; k <= 2000; ++k) driver.Step(k);  // 200 s at 10 Hz
  return driver.Finish();
}

double MaxError(const std::vector<Eigen::Vector3d>& estimate,
                const std::vector<Eigen::Vector3d>& truth) {
  double worst = 0.0;
  for (size_t i = 0; i < estimate.size(); ++i)
    worst = std::max(worst, (estimate[i] - truth[i]).norm());
  return worst;
}

TEST(GnssFusion, KeepsADriftingOdometryOnTheFixes) {
  const FusionRun run = RunFusion(0);

  ASSERT_GT(run.estimate.size(), 1900u);  // aligned within the first 100 m or so
  EXPECT_GE(run.stats.factors, 18u);
  EXPECT_EQ(run.stats.outliers, 0u);
  // Without GNSS the odometry is about 20 m off after 6 km; with it, within a metre as the
  // poses come (extrapolated from the newest node), and within half that once smoothed
  // between nodes.
  EXPECT_LT(MaxError(run.estimate, run.truth), 1.0);
  ASSERT_GT(run.smoothed.size(), 1800u);
  EXPECT_LT(MaxError(run.smoothed, run.smoothed_truth), 0.5);
}

/// The largest change between consecutive poses that the truth does not have (m).
double LargestStep(const std::vector<Eigen::Vector3d>& estimate,
                   const std::vector<Eigen::Vector3d>& truth,
                   const Eigen::Vector3d& axes = Eigen::Vector3d::Ones()) {
  double worst = 0.0;
  for (size_t i = 1; i < estimate.size(); ++i) {
    const Eigen::Vector3d step = (estimate[i] - estimate[i - 1]) - (truth[i] - truth[i - 1]);
    worst = std::max(worst, step.cwiseProduct(axes).norm());
  }
  return worst;
}

/// The same in height, and horizontally.
double LargestHeightStep(const std::vector<Eigen::Vector3d>& estimate,
                         const std::vector<Eigen::Vector3d>& truth) {
  return LargestStep(estimate, truth, Eigen::Vector3d::UnitZ());
}
double LargestHorizontalStep(const std::vector<Eigen::Vector3d>& estimate,
                             const std::vector<Eigen::Vector3d>& truth) {
  return LargestStep(estimate, truth, Eigen::Vector3d(1.0, 1.0, 0.0));
}

TEST(GnssFusion, PublishedPosesDoNotStepWhenTheGraphMovesUnderThem) {
  const FusionRun run = RunFusion(0);
  ASSERT_GT(run.published.size(), 1500u);
  // Each re-solve moves the graph under poses already out: taken as it stands, the trajectory
  // steps at every new node; published, the difference fades over 200 m instead.
  const double released_step = LargestStep(run.released, run.released_truth);
  const double published_step = LargestStep(run.published, run.released_truth);
  EXPECT_GT(released_step, 0.02);
  EXPECT_LT(published_step, 0.01);
  EXPECT_LT(published_step, 0.25 * released_step);
  EXPECT_LT(MaxError(run.published, run.released_truth), 0.6);
}

/// A fusion in zone 50N beside a straight track, 30 m/s at a heading of 0.6 rad from `origin`.
struct StraightTrack {
  GnssFusionOptions options = Zone50N();
  GnssFusion fusion{options, nullptr, nullptr};
  Eigen::Vector3d origin{432000.0, 3585000.0, 30.0};
  double speed = 30.0;
  Eigen::Vector3d ahead{std::cos(0.6), std::sin(0.6), 0.0};

  static GnssFusionOptions Zone50N() {
    GnssFusionOptions o;
    o.zone.zone = 50;
    o.zone.north = true;
    return o;
  }
};

/// Published and released (graph as it stands) positions of a straight run at 30 m/s with 1 Hz
/// fixes on the antenna, whose height jumps by `height_jump_m` at 100 s, with no fixes from
/// `outage_from_s` to `outage_to_s` while the odometry runs long by `outage_scale_error`. Poses are
/// released as the estimator releases them: once settled, or 30 s late at most
/// (gnss_max_latency_s). The graph's odometry links let the height wander by
/// `vertical_drift_fraction` of the path.
struct ContinuityRun {
  std::vector<Eigen::Vector3d> published, map_target, released, truth;
};

ContinuityRun RunContinuity(
    double height_jump_m,
    double outage_from_s,
    double outage_to_s,
    double vertical_drift_fraction = GnssFusionOptions().vertical_drift_fraction,
    double outage_scale_error = 0.002) {
  StraightTrack track;
  track.options.vertical_drift_fraction = vertical_drift_fraction;
  GnssFusion fusion(track.options, nullptr, nullptr);
  ContinuityRun run;
  std::vector<std::pair<double, Eigen::Isometry3d>> odometry;
  std::vector<Eigen::Vector3d> truth;
  Eigen::Isometry3d odom = Eigen::Isometry3d::Identity();
  size_t next_release = 0;
  for (int k = 0; k <= 2400; ++k) {  // 240 s at 10 Hz
    const double t = 0.1 * k;
    const int64_t stamp = static_cast<int64_t>(std::llround(t * 1e9));
    const bool out = t >= outage_from_s && t < outage_to_s;
    if (k > 0) odom.translation().x() += 0.1 * track.speed * (out ? 1.0 + outage_scale_error : 1.0);
    const Eigen::Vector3d p = track.origin + track.speed * t * track.ahead;
    if (k % 10 == 0 && !out) {
      const double up = t >= 100.0 ? height_jump_m : 0.0;
      fusion.AddFix(FixAt(track.options.zone, p + Eigen::Vector3d(0.0, 0.0, up), stamp));
    }
    fusion.AddOdometry(stamp, odom);
    odometry.emplace_back(t, odom);
    truth.push_back(p);
    for (; fusion.aligned() && next_release < odometry.size() &&
           (odometry[next_release].first <= fusion.settled_until_s() ||
            odometry[next_release].first <= t - 30.0);
         ++next_release) {
      const auto& [t_s, T_odom] = odometry[next_release];
      run.released.push_back(fusion.ToEnu(T_odom, t_s).translation() + fusion.origin_utm());
      run.published.push_back(fusion.Publish(T_odom, t_s).translation() + fusion.origin_utm());
      run.map_target.push_back(fusion.MapTarget(T_odom, t_s).translation() + fusion.origin_utm());
      run.truth.push_back(truth[next_release]);
    }
  }
  return run;
}

TEST(GnssFusion, AReceiverWhoseHeightWandersMovesThePublishedPathWithoutAStep) {
  // The receiver's height jumps by 4 m, as a single-point fix's height wanders by metres. With
  // the graph's links as loose in height as sideways, each new node moves the graph's height by
  // more than continuity_max_step_m, and the trajectory must still fade there, not step (it
  // stepped by 0.5-0.9 m on 10 of the 19 suite runs).
  const ContinuityRun run = RunContinuity(4.0, 1e9, 1e9, GnssFusionOptions().drift_fraction);
  ASSERT_GT(run.published.size(), 2000u);
  EXPECT_GT(LargestStep(run.released, run.truth), 0.5);
  EXPECT_LT(LargestStep(run.published, run.truth), 0.05);
  // The submap chain's target takes such a move at once: the chain smooths the pull itself.
  EXPECT_GT(LargestStep(run.map_target, run.truth), 0.5);
}

/// RMS height error (m) of a straight run at 30 m/s whose odometry is exact, with 1 Hz fixes
/// whose height wanders as a single-point receiver's does (2 m, over a 200 s period) and whose
/// horizontal position is exact: of the fixes (`fixes_rms`) and of the poses as the estimator
/// releases them once settled (`released_rms`), through a graph whose odometry links let the
/// height wander by `vertical_drift_fraction` of the path between nodes.
struct HeightRun {
  double fixes_rms = 0.0, released_rms = 0.0;
};

HeightRun RunWanderingHeight(double vertical_drift_fraction) {
  StraightTrack track;
  track.options.vertical_drift_fraction = vertical_drift_fraction;
  GnssFusion fusion(track.options, nullptr, nullptr);
  std::vector<std::pair<double, Eigen::Isometry3d>> odometry;
  std::vector<Eigen::Vector3d> truth;
  Eigen::Isometry3d odom = Eigen::Isometry3d::Identity();
  size_t next_release = 0;
  double fixes_sq = 0.0, released_sq = 0.0;
  int fixes = 0, released = 0;
  for (int k = 0; k <= 4800; ++k) {  // 480 s at 10 Hz
    const double t = 0.1 * k;
    const int64_t stamp = static_cast<int64_t>(std::llround(t * 1e9));
    if (k > 0) odom.translation().x() += 0.1 * track.speed;
    const Eigen::Vector3d p = track.origin + track.speed * t * track.ahead;
    if (k % 10 == 0) {
      const double up = 2.0 * std::sin(2.0 * M_PI * t / 200.0);
      fusion.AddFix(FixAt(track.options.zone, p + Eigen::Vector3d(0.0, 0.0, up), stamp));
      fixes_sq += up * up;
      ++fixes;
    }
    fusion.AddOdometry(stamp, odom);
    odometry.emplace_back(t, odom);
    truth.push_back(p);
    for (; fusion.aligned() && next_release < odometry.size() &&
           odometry[next_release].first <= fusion.settled_until_s();
         ++next_release) {
      const auto& [t_s, T_odom] = odometry[next_release];
      const Eigen::Vector3d q = fusion.Publish(T_odom, t_s).translation() + fusion.origin_utm();
      const double dz = q.z() - truth[next_release].z();
      released_sq += dz * dz;
      ++released;
    }
  }
  HeightRun run;
  run.fixes_rms = std::sqrt(fixes_sq / std::max(1, fixes));
  run.released_rms = std::sqrt(released_sq / std::max(1, released));
  EXPECT_GT(released, 4000);
  return run;
}

TEST(GnssFusion, TheReceiversWanderingHeightIsAveragedOverManyNodes) {
  // An odometry whose height holds to a few centimetres per node, where the receiver's wanders
  // by metres over minutes: linked that tightly in height (gnss.vertical_drift_fraction
  // 0.0003), the graph averages the height over many nodes. With the links as loose in height
  // as sideways (the default), the path follows the fixes' wander.
  const HeightRun tight = RunWanderingHeight(0.0003);
  const HeightRun loose = RunWanderingHeight(GnssFusionOptions().drift_fraction);
  EXPECT_NEAR(tight.fixes_rms, std::sqrt(2.0), 0.05);
  EXPECT_LT(tight.released_rms, 0.5 * tight.fixes_rms);
  EXPECT_GT(loose.released_rms, 0.7 * loose.fixes_rms);
}

TEST(GnssFusion, WhenGnssReturnsAfterAnOutageItsCorrectionIsTakenAtOnce) {
  // 60 s (1.8 km) without fixes and the odometry 0.2 % long: 3.6 m of drift the graph could
  // not see. The first node after the outage corrects it in one step, as a fade would leave
  // the path metres off for hundreds of metres.
  const ContinuityRun run = RunContinuity(0.0, 100.0, 160.0);
  ASSERT_GT(run.published.size(), 2000u);
  EXPECT_GT(LargestStep(run.published, run.truth), 1.0);
  // The receiver comes back 4 m higher: that is its height wandering, not drift of the
  // odometry, whose height holds through an outage. The horizontal correction still steps;
  // the height fades, though the graph's height moves by more than continuity_max_step_m.
  const ContinuityRun higher = RunContinuity(4.0, 100.0, 160.0, GnssFusionOptions().drift_fraction);
  ASSERT_GT(higher.published.size(), 2000u);
  EXPECT_GT(LargestStep(higher.published, higher.truth), 1.0);
  EXPECT_GT(LargestHeightStep(higher.released, higher.truth), 0.5);
  EXPECT_LT(LargestHeightStep(higher.published, higher.truth), 0.05);
}

TEST(GnssFusion, AfterAnOutageASmallHorizontalCorrectionFadesWhileTheHeightMovesByMetres) {
  // The odometry runs only 0.02 % long through the outage (0.36 m) and the receiver comes back
  // 4 m higher. The graph moves the poses held through the outage by metres, nearly all of it
  // in height: a step is allowed only where the horizontal move alone calls for one. Counted
  // with the height, the 0.36 m went in at once (tunnel_gnss_outage seed 2 stepped 0.37 m
  // sideways where GNSS came back).
  const ContinuityRun run =
      RunContinuity(4.0, 100.0, 160.0, GnssFusionOptions().drift_fraction, 0.0002);
  ASSERT_GT(run.published.size(), 2000u);
  EXPECT_GT(LargestHeightStep(run.released, run.truth), 0.5);
  EXPECT_GT(LargestHorizontalStep(run.released, run.truth), 0.2);
  EXPECT_LT(LargestStep(run.published, run.truth), 0.05);
}

TEST(GnssFusion, MultipathJumpsLeaveTheTrajectoryAlone) {
  const FusionRun clean = RunFusion(0);
  const FusionRun jumpy = RunFusion(5);  // every 5th fix 5-30 m off
  // The outliers may delay the alignment by a few fixes: compare the poses both runs have.
  ASSERT_GT(jumpy.estimate.size(), 1800u);
  EXPECT_GE(jumpy.stats.outliers, 30u);
  const size_t offset = clean.estimate.size() - jumpy.estimate.size();
  double worst = 0.0;
  for (size_t i = 0; i < jumpy.estimate.size(); ++i)
    worst = std::max(worst, (clean.estimate[i + offset] - jumpy.estimate[i]).norm());
  EXPECT_LT(worst, 0.5);
  EXPECT_LT(MaxError(jumpy.estimate, jumpy.truth), 1.0);
  EXPECT_LT(MaxError(jumpy.smoothed, jumpy.smoothed_truth), 0.5);
}

/// How long each pose of a straight run at 30 m/s (1 Hz fixes, none from 100 to 160 s) waits
/// for GnssFusion::Releases with a prompt latency (the outage's limit, 120 s, never reached),
/// and whether the graph had a node after it when it went out.
struct ReleaseRun {
  std::vector<double> stamp_s, waited_s;
  std::vector<bool> smoothed;
};

ReleaseRun RunReleases(double prompt_latency_s) {
  StraightTrack track;
  ReleaseRun run;
  std::deque<double> held;
  for (int k = 0; k <= 2400; ++k) {  // 240 s at 10 Hz
    const double t = 0.1 * k;
    const int64_t stamp = static_cast<int64_t>(std::llround(t * 1e9));
    Eigen::Isometry3d odom = Eigen::Isometry3d::Identity();
    odom.translation().x() = track.speed * t;
    if (k % 10 == 0 && (t < 100.0 || t >= 160.0))
      track.fusion.AddFix(
          FixAt(track.options.zone, track.origin + track.speed * t * track.ahead, stamp));
    track.fusion.AddOdometry(stamp, odom);
    held.push_back(t);
    while (track.fusion.aligned() && !held.empty() &&
           track.fusion.Releases(held.front(), t, prompt_latency_s, 120.0)) {
      run.stamp_s.push_back(held.front());
      run.waited_s.push_back(t - held.front());
      run.smoothed.push_back(held.front() <= track.fusion.settled_until_s());
      held.pop_front();
    }
  }
  return run;
}

TEST(GnssFusion, WhileFixesKeepComingPosesGoOutPromptlyAndInAnOutageTheyWaitForANode) {
  const ReleaseRun prompt = RunReleases(3.0), patient = RunReleases(0.0);
  ASSERT_FALSE(prompt.stamp_s.empty());
  ASSERT_FALSE(patient.stamp_s.empty());
  double prompt_worst = 0.0, patient_worst = 0.0;
  for (size_t i = 0; i < prompt.stamp_s.size(); ++i) {
    const double t = prompt.stamp_s[i];
    // Settled and fixes all round: out 3 s after it was measured.
    if (t > 60.0 && t < 95.0) prompt_worst = std::max(prompt_worst, prompt.waited_s[i]);
    // From the outage's start to its end: smoothed by the node after the outage.
    if (t >= 99.5 && t < 160.0) {
      EXPECT_TRUE(prompt.smoothed[i]) << "pose at " << t << " s";
    }
  }
  for (size_t i = 0; i < patient.stamp_s.size(); ++i) {
    if (patient.stamp_s[i] > 60.0 && patient.stamp_s[i] < 95.0)
      patient_worst = std::max(patient_worst, patient.waited_s[i]);
  }
  EXPECT_NEAR(prompt_worst, 3.0, 0.15);
  EXPECT_GT(patient_worst, 10.0);  // a node every 10 s, half a window after its epoch
}

TEST(GnssFusion, ThroughAnOutageThePathIsTheOdometrysFittedToBothEnds) {
  // A straight line at 30 m/s with 1 Hz fixes on the track except for a 60 s outage (1.8 km).
  // Before the outage the odometry turns 2e-6 rad per metre too much (which the graph takes as
  // a heading drift of the run); inside it, it turns 2 mrad to the left and back. Between the
  // two nodes around the outage the path must be the odometry's, turned and stretched to meet
  // both: the window's drift rate, an average that need not describe this span, bent it by the
  // rate times the span squared over 8, and the two nodes' headings, which disagree with the
  // odometry's turn between them, bowed it out by a quarter of their difference times the span.
  StraightTrack track;
  GnssFusion& fusion = track.fusion;
  const double speed = track.speed;
  const double outage_from_s = 100.0, outage_to_s = 160.0;
  const double turn_rad_per_m = 2e-3 / (0.5 * speed * (outage_to_s - outage_from_s));
  std::vector<std::pair<double, Eigen::Isometry3d>> odometry;
  Eigen::Isometry3d odom = Eigen::Isometry3d::Identity();
  for (int k = 0; k <= 2400; ++k) {  // 240 s at 10 Hz
    const double t = 0.1 * k;
    const int64_t stamp = static_cast<int64_t>(std::llround(t * 1e9));
    if (k > 0) {
      double yaw_rad_per_m = 0.0;
      if (t <= outage_from_s)
        yaw_rad_per_m = 2e-6;
      else if (t <= 0.5 * (outage_from_s + outage_to_s))
        yaw_rad_per_m = turn_rad_per_m;
      else if (t <= outage_to_s)
        yaw_rad_per_m = -turn_rad_per_m;
      Eigen::Isometry3d step = Eigen::Isometry3d::Identity();
      step.translation().x() = 0.1 * speed;
      step.linear() = Eigen::AngleAxisd(yaw_rad_per_m * 0.1 * speed, Eigen::Vector3d::UnitZ())
                          .toRotationMatrix();
      odom = odom * step;
    }
    if (k % 10 == 0 && (t < outage_from_s || t >= outage_to_s))
      fusion.AddFix(FixAt(track.options.zone, track.origin + speed * t * track.ahead, stamp));
    fusion.AddOdometry(stamp, odom);
    odometry.emplace_back(t, odom);
  }
  fusion.Finish();
  ASSERT_TRUE(fusion.aligned());
  ASSERT_GT(fusion.settled_until_s(), outage_to_s);
  const size_t from = static_cast<size_t>(outage_from_s * 10);
  const size_t to = static_cast<size_t>(outage_to_s * 10);
  auto at = [&](size_t i) -> Eigen::Vector3d {
    return fusion.ToEnu(odometry[i].second, odometry[i].first).translation();
  };
  auto odom_at = [&](size_t i) -> Eigen::Vector3d { return odometry[i].second.translation(); };
  // The odometry's path through the outage, turned and stretched onto the estimate's ends.
  const Eigen::Vector2d want = (at(to) - at(from)).head<2>();
  const Eigen::Vector2d got = (odom_at(to) - odom_at(from)).head<2>();
  const double turn = std::atan2(got.x() * want.y() - got.y() * want.x(), got.dot(want));
  const Eigen::Matrix2d fit =
      want.norm() / got.norm() * Eigen::Rotation2Dd(turn).toRotationMatrix();
  double off = 0.0;
  for (size_t i = from; i <= to; ++i) {
    const Eigen::Vector2d expected =
        at(from).head<2>() + fit * (odom_at(i) - odom_at(from)).head<2>();
    off = std::max(off, (at(i).head<2>() - expected).norm());
  }
  EXPECT_LT(off, 0.01);
}

}  // namespace
}  // namespace raillomer
