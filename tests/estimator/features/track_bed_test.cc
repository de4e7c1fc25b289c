#include "estimator/features/track_bed.h"

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "estimator/features/rail_extraction.h"
#include "tests/estimator/features/sim_frames.h"

namespace raillomer {
namespace {

using test::BodyFrame;
using test::MakeSimulator;
using test::ScanFrame;

/// Rails 1.5 m apart along body x, their tops 3.8 m under the body origin.
RailExtraction StraightRails() {
  RailExtraction rails;
  rails.ok = true;
  rails.left_point = Eigen::Vector3d(5.0, 0.7535, -3.8);
  rails.right_point = Eigen::Vector3d(5.0, -0.7535, -3.8);
  rails.normal = Eigen::Vector3d::UnitZ();
  rails.distance = 3.8;
  return rails;
}

TEST(TrackBed, SelectsTheBedBetweenTheRailsOnly) {
  const TrackBedOptions options;
  const std::vector<Eigen::Vector3f> points = {
      {10.f, 0.2f, -4.0f},    // sleeper top, between the rails: kept
      {10.f, -0.5f, -4.1f},   // a face near the right rail's foot: kept
      {10.f, 0.75f, -3.8f},   // the left rail head: too high
      {10.f, 1.0f, -4.0f},    // beside the rails: too far out
      {3.f, 0.0f, -4.0f},     // too close
      {30.f, 0.0f, -4.0f},    // too far
      {10.f, 0.0f, -4.5f},    // deeper than any sleeper gap
      {10.f, 0.0f, -3.85f}};  // just under the rail tops: too shallow
  std::vector<Eigen::Vector3f> bed = SelectTrackBed(options, StraightRails(), points);
  ASSERT_EQ(bed.size(), 2u);
  EXPECT_FLOAT_EQ(bed[0].y(), 0.2f);
  EXPECT_FLOAT_EQ(bed[1].y(), -0.5f);

  RailExtraction failed = StraightRails();
  failed.ok = false;
  EXPECT_TRUE(SelectTrackBed(options, failed, points).empty());
}

TEST(TrackBed, ValidatesItsOptions) {
  std::string error;
  EXPECT_TRUE(TrackBedOptions{}.IsValid(&error)) << error;
  TrackBedOptions o;
  o.max_search_m = 0.3;  // half the sleeper spacing: the next sleeper would fit as well
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_NE(error.find("max_search_m"), std::string::npos) << error;
  o = TrackBedOptions{};
  o.sigma_m = -0.01;
  EXPECT_FALSE(o.IsValid(&error));
  EXPECT_NE(error.find("sigma_m"), std::string::npos) << error;
}

/// The down LiDAR's bed points of frames [first, last) of the simulator, each placed by the
/// truth into the body frame of frame `into`, the points of `into` itself shifted by `shift_m`
/// along its x axis.
std::vector<Eigen::Vector3d> BedPoints(const sim::Simulator& simulator,
                                       uint64_t first,
                                       uint64_t last,
                                       const Eigen::Isometry3d& T_world_into,
                                       const TrackBedOptions& options,
                                       Eigen::Vector3d* normal,
                                       double* distance) {
  std::vector<Eigen::Vector3d> out;
  for (uint64_t k = first; k < last; ++k) {
    const BodyFrame frame = ScanFrame(simulator, "down", k);
    const RailExtraction rails = ExtractRails(RailExtractionOptions{}, frame.points);
    if (!rails.ok) continue;
    const Eigen::Isometry3d T = T_world_into.inverse() * frame.T_world_body;
    for (const Eigen::Vector3f& p : SelectTrackBed(options, rails, frame.points))
      out.push_back(T * p.cast<double>());
    *normal = T.linear() * rails.normal;
    *distance = rails.distance - normal->dot(T.translation());
  }
  return out;
}

// On the simulator's track (sleepers every 0.6 m standing 0.19 m out of the ballast), a frame
// whose predicted motion is off along the track is put back onto the sleepers of the ten frames
// before it: the shift recovers the error within a few millimetres, and is zero without one.
TEST(TrackBed, RecoversAnAlongTrackErrorOnTheSimulatedSleepers) {
  auto simulator = MakeSimulator("poor_low_embankment_b");
  ASSERT_NE(simulator, nullptr);
  const TrackBedOptions options;
  int measured = 0;
  for (uint64_t k : {200u, 420u, 650u}) {
    const BodyFrame previous = ScanFrame(*simulator, "down", k - 1);
    Eigen::Vector3d normal;
    double distance = 0.0;
    const std::vector<Eigen::Vector3d> reference =
        BedPoints(*simulator, k - 10, k, previous.T_world_body, options, &normal, &distance);
    ASSERT_GT(reference.size(), 1000u) << "frame " << k;
    for (double error_m : {0.0, 0.045, -0.07}) {
      Eigen::Isometry3d T_into = previous.T_world_body;
      T_into.translation() -= error_m * previous.T_world_body.linear().col(0);
      const std::vector<Eigen::Vector3d> current =
          BedPoints(*simulator, k, k + 1, T_into, options, &normal, &distance);
      const TrackBedShift shift =
          EstimateTrackBedShift(options, reference, current, normal, distance);
      ASSERT_TRUE(shift.ok) << "frame " << k << ": " << shift.failure;
      EXPECT_NEAR(shift.shift_m, -error_m, 0.006) << "frame " << k << ", error " << error_m;
      EXPECT_GT(shift.sigma_m, 0.0);
      EXPECT_LT(shift.sigma_m, 0.01);
      ++measured;
    }
  }
  EXPECT_EQ(measured, 9);
}

// A bed without sleepers (a slab, snow, a level crossing's panel) says nothing along the track:
// no measurement rather than one pinned to the prediction.
TEST(TrackBed, AFlatBedGivesNoMeasurement) {
  const TrackBedOptions options;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> x(7.0, 21.0), y(-0.5, 0.5);
  std::normal_distribution<double> noise(0.0, 0.02);
  auto flat = [&](int n) {
    std::vector<Eigen::Vector3d> points;
    for (int i = 0; i < n; ++i) points.emplace_back(x(rng), y(rng), -4.0 + noise(rng));
    return points;
  };
  const TrackBedShift shift =
      EstimateTrackBedShift(options, flat(6000), flat(800), Eigen::Vector3d::UnitZ(), 3.8);
  EXPECT_FALSE(shift.ok);
  EXPECT_FALSE(shift.failure.empty());

  const TrackBedShift few =
      EstimateTrackBedShift(options, flat(6000), flat(20), Eigen::Vector3d::UnitZ(), 3.8);
  EXPECT_FALSE(few.ok);
  EXPECT_NE(few.failure.find("bed points"), std::string::npos) << few.failure;
}

}  // namespace
}  // namespace raillomer
