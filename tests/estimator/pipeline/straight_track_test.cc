#include "estimator/pipeline/straight_track.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <tuple>

namespace raillomer {
namespace {

/// The heading (rad) a track of straight, clothoid transition and circular arc has at distance s
/// from the straight's start (a left turn), as the paper's lines are built (RAIL_FACTS:
/// transitions of 40-150 m, radii from 800 m at 120 km/h).
struct Track {
  double straight_m = 1500.0;
  double transition_m = 150.0;
  double radius_m = 2000.0;
  double HeadingAt(double s) const {
    if (s <= straight_m) return 0.0;
    const double u = s - straight_m;
    if (u <= transition_m) return u * u / (2.0 * transition_m * radius_m);
    return transition_m / (2.0 * radius_m) + (u - transition_m) / radius_m;
  }
};

/// Feeds the detector a run along `track` at `speed` (10 Hz frames), the gyro's raw heading
/// carrying the car body's hunting sway (0.3 mrad at 0.7 Hz) and a bias of `bias_rps`, of which
/// the estimator knows `estimate_rps`. Returns the distance at which the straight was first
/// recognised and at which it ended (-1: never).
struct Passage {
  double started_at_m = -1.0, ended_at_m = -1.0;
  int restarts = 0;
  double restarted_at_m = -1.0;
  double worst_heading_rad = 0.0;  ///< the track's heading at its largest while taken as straight
};
Passage Drive(const Track& track,
              double speed_mps,
              double bias_rps,
              double estimate_rps,
              double until_m,
              StraightTrackOptions options = {}) {
  StraightTrackDetector detector(options);
  Passage run;
  double previous = 0.0;
  for (int k = 0;; ++k) {
    const double t = 0.1 * k, s = speed_mps * t;
    if (s > until_m) break;
    const double heading =
        track.HeadingAt(s) + 3e-4 * std::sin(2.0 * M_PI * 0.7 * t) + bias_rps * t;
    detector.Add(t, k == 0 ? 0.0 : heading - previous, estimate_rps);
    previous = heading;
    if (detector.started()) {
      if (run.started_at_m < 0.0) {
        run.started_at_m = s;
      } else {
        ++run.restarts;
        run.restarted_at_m = s;
      }
    }
    if (detector.ended() && run.ended_at_m < 0.0) run.ended_at_m = s;
    if (detector.straight()) {
      run.worst_heading_rad = std::max(run.worst_heading_rad, std::abs(track.HeadingAt(s)));
    }
  }
  return run;
}

TEST(StraightTrack, RecognisesAStraightAfterItsDetectionSpan) {
  const Track track;
  const Passage run = Drive(track, 33.3, 5e-5, 0.0, 1400.0);
  // 5 s at 33.3 m/s, the first frame at 0 m: recognised at 167 m, and never lost on the straight
  // despite the sway and a bias error of 50 urad/s.
  EXPECT_NEAR(run.started_at_m, 5.0 * 33.3, 4.0);
  EXPECT_LT(run.ended_at_m, 0.0);
  EXPECT_EQ(run.restarts, 0);
}

TEST(StraightTrack, LetsGoWithinAFewTensOfMetresOfACurvesTransition) {
  // The heading grows with the square of the distance into a transition: 1 mrad after 24 m
  // of a 150 m transition into a 2000 m radius, 9 m of a 40 m one into 1000 m.
  for (const auto& [transition_m, radius_m, speed_mps, within_m] :
       {std::tuple{150.0, 2000.0, 33.3, 30.0},
        std::tuple{40.0, 1000.0, 33.3, 14.0},
        std::tuple{150.0, 3000.0, 7.0, 33.0},
        std::tuple{120.0, 1200.0, 22.0, 24.0}}) {
    Track track;
    track.transition_m = transition_m;
    track.radius_m = radius_m;
    const Passage run = Drive(track, speed_mps, -5e-5, 0.0, track.straight_m + 400.0);
    const std::string what = std::to_string(transition_m) + " m into " + std::to_string(radius_m) +
                             " m at " + std::to_string(speed_mps) + " m/s";
    ASSERT_GT(run.started_at_m, 0.0) << what;
    EXPECT_GT(run.ended_at_m, track.straight_m) << what;
    EXPECT_LT(run.ended_at_m, track.straight_m + within_m) << what;
    // Slowly into a long transition, its first tens of metres may be taken for straight again
    // (5 s of it lie on a line), but never where the track has turned by more than 1.5 mrad,
    // and never the arc.
    EXPECT_LT(run.worst_heading_rad, 1.5e-3)
        << what << ": ended at " << run.ended_at_m << " m, taken for straight again at "
        << run.restarted_at_m << " m";
    if (run.restarts > 0) {
      EXPECT_LT(run.restarted_at_m, track.straight_m + transition_m) << what;
    }
  }
}

TEST(StraightTrack, ASteadyCurveIsNotStraight) {
  // A curve's heading is a line in time too; its slope (v / R) gives it away: 5.6 mrad/s on a
  // 6 km radius at 120 km/h, 0.6 mrad/s at 4 m/s on 6 km.
  for (const double speed_mps : {33.3, 4.0}) {
    Track track;
    track.straight_m = 0.0;
    track.transition_m = 1e-6;
    track.radius_m = 6000.0;
    const Passage run = Drive(track, speed_mps, 0.0, 0.0, 60.0 * speed_mps);
    EXPECT_LT(run.started_at_m, 0.0) << speed_mps << " m/s";
  }
}

TEST(StraightTrack, TheEstimatedBiasIsTakenOffTheRate) {
  // A gyro 2 mrad/s off: straight once the estimator knows its bias, not before.
  const Track track;
  EXPECT_GT(Drive(track, 33.3, 2e-3, 2e-3, 1400.0).started_at_m, 0.0);
  EXPECT_LT(Drive(track, 33.3, 2e-3, 0.0, 1400.0).started_at_m, 0.0);
}

TEST(StraightTrack, GivesTheBodysSwayAboutTheLine) {
  // The gyro's heading on a straight: a bias slope and a 0.3 mrad sway at 0.7 Hz. Its deviation
  // from the fitted line is the sway (to the little of it the line takes in).
  StraightTrackDetector detector({});
  auto sway = [](double t) { return 3e-4 * std::sin(2.0 * M_PI * 0.7 * t); };
  double previous = 0.0;
  for (int k = 0; k <= 100; ++k) {
    const double t = 0.1 * k, heading = 1e-4 * t + sway(t);
    detector.Add(t, k == 0 ? 0.0 : heading - previous, 1e-4);
    previous = heading;
  }
  ASSERT_TRUE(detector.straight());
  EXPECT_NEAR(detector.rate_rps(), 0.0, 2e-5);
  for (const double t : {6.0, 7.3, 8.8, 10.0}) {
    EXPECT_NEAR(detector.DeviationAt(t), sway(t), 5e-5) << t;
  }
  EXPECT_EQ(detector.DeviationAt(1.05), 0.0);  // not a time given to Add()
}

TEST(StraightTrack, ResetForgetsTheHistory) {
  StraightTrackDetector detector({});
  for (int k = 0; k <= 60; ++k) detector.Add(0.1 * k, 0.0, 0.0);
  EXPECT_TRUE(detector.straight());
  detector.Reset();
  EXPECT_FALSE(detector.straight());
  EXPECT_FALSE(detector.ended());
  for (int k = 0; k < 40; ++k) detector.Add(10.0 + 0.1 * k, 0.0, 0.0);
  EXPECT_FALSE(detector.straight());  // 3.9 s of history is not 5
}

TEST(StraightTrack, OptionsAreValidated) {
  std::string error;
  EXPECT_TRUE(StraightTrackOptions{}.IsValid(&error)) << error;
  StraightTrackOptions o;
  o.sigma_rad = -1e-3;
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_NE(error.find("sigma_rad"), std::string::npos);
  o = {};
  o.detect_s = 0.1;
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_NE(error.find("detect_s"), std::string::npos);
  o = {};
  o.tolerance_rad = 0.0;
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_NE(error.find("tolerance_rad"), std::string::npos);
  o = {};
  o.max_rate_rps = std::nan("");
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_NE(error.find("max_rate_rps"), std::string::npos);
}

}  // namespace
}  // namespace raillomer
