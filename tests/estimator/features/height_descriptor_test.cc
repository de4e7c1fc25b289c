#include "estimator/features/height_descriptor.h"

#include <cmath>
#include <cstdio>
#include <ctime>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

std::unique_ptr<sim::Simulator> MakeSimulator(const std::string& name) {
  sim::Scenario scenario;
  std::string error;
  EXPECT_TRUE(sim::LoadScenario(name, &scenario, &error)) << error;
  auto simulator = sim::Simulator::Create(scenario, sim::SimOptions{}, &error);
  EXPECT_NE(simulator, nullptr) << error;
  return simulator;
}

/// One LiDAR frame in the body frame at its end time, deskewed with the truth.
struct BodyFrame {
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();  ///< at the frame's end
  std::vector<Eigen::Vector3f> points;
};

BodyFrame ScanFrame(const sim::Simulator& simulator, const std::string& unit, uint64_t frame) {
  BodyFrame out;
  const sim::LivoxHorizonModel* lidar = nullptr;
  for (const sim::LivoxHorizonModel& l : simulator.lidars()) {
    if (l.config().name == unit) lidar = &l;
  }
  if (lidar == nullptr) return out;
  const double period = 1.0 / simulator.scenario().lidar_rate_hz;
  const double t0 = frame * period;
  const sim::TruthMotion& truth = simulator.truth();
  std::vector<io::LivoxPoint> points;
  lidar->Scan(
      frame, t0, [&truth](double t) { return truth.Pose(t); }, simulator.caster(), &points, nullptr);
  out.T_world_body = truth.Pose(t0 + period);
  const Eigen::Isometry3d T_end_world = out.T_world_body.inverse();
  out.points.reserve(points.size());
  for (const io::LivoxPoint& p : points) {
    if (p.x == 0.f && p.y == 0.f && p.z == 0.f) continue;  // no return
    const Eigen::Vector3d p_body = lidar->T_body_lidar() * Eigen::Vector3d(p.x, p.y, p.z);
    out.points.push_back(
        (T_end_world * truth.Pose(t0 + p.offset_time_ns * 1e-9) * p_body).cast<float>());
  }
  return out;
}

double CpuMs(const timespec& a, const timespec& b) {
  return (b.tv_sec - a.tv_sec) * 1e3 + (b.tv_nsec - a.tv_nsec) * 1e-6;
}

TEST(HeightDescriptorTest, Dump) {
  auto simulator = MakeSimulator("demo");
  const HeightDescriptorOptions options;
  for (int f : {100, 101}) {
    const BodyFrame a = ScanFrame(*simulator, "up", f);
    const HeightDescriptor d = ComputeHeightDescriptor(options, a.points);
    std::printf("frame %d (%zu points)\n", f, a.points.size());
    for (int i = d.rows - 1; i >= 0; --i) {
      std::printf("%6.2f ", options.y_min_m + (i + 0.5) * options.bin_m);
      for (int j = 0; j < d.cols; ++j) {
        const float v = d.cells(i, j);
        std::printf("%c", v <= 0 ? '.' : (v < 10 ? '0' + static_cast<int>(v) : 'A' + std::min(25, static_cast<int>(v) - 10)));
      }
      std::printf("\n");
    }
  }
}

TEST(HeightDescriptorTest, Curve) {
  auto simulator = MakeSimulator(getenv("HD_SCEN") ? getenv("HD_SCEN") : "poor_high_open_a");
  const HeightDescriptorOptions options;
  for (int f : {100, 200, 300}) {
    const BodyFrame a = ScanFrame(*simulator, "up", f);
    const BodyFrame b = ScanFrame(*simulator, "up", f + 1);
    const double truth_dx = (a.T_world_body.inverse() * b.T_world_body).translation().x();
    const HeightDescriptor da = ComputeHeightDescriptor(options, a.points);
    const HeightDescriptor db = ComputeHeightDescriptor(options, b.points);
    std::printf("f%d truth %.3f:", f, truth_dx);
    for (int k = -4; k <= 14; ++k) std::printf(" %d:%.3f", k, HeightDescriptorDistance(da, db, k));
    std::printf("\n");
    // Per-row contributions at k=0 and at truth.
    const int kt = static_cast<int>(std::lround(truth_dx / 0.5));
    for (int i = 0; i < da.rows; ++i) {
      HeightDescriptor ra = da, rb = db;
      ra.cells.setZero(); rb.cells.setZero();
      ra.cells.row(i) = da.cells.row(i); rb.cells.row(i) = db.cells.row(i);
      const int na = (da.cells.row(i).array() > 0).count(), nb = (db.cells.row(i).array() > 0).count();
      if (na == 0 || nb == 0) continue;
      std::printf("  row %6.2f n %2d/%2d  d0 %.3f dt %.3f\n", -20 + (i + 0.5) * 0.5, na, nb,
                  HeightDescriptorDistance(ra, rb, 0), HeightDescriptorDistance(ra, rb, kt));
    }
  }
}

TEST(HeightDescriptorTest, SurveySimulator) {
  const HeightDescriptorOptions options;
  for (const sim::ScenarioInfo& info : std::vector<sim::ScenarioInfo>{{"demo", ""}, {"rich_high_town_a", ""}, {"poor_high_open_a", ""}, {"tunnel_gnss_outage", ""}, {"rich_low_yard_b", ""}}) {
    auto simulator = MakeSimulator(info.name);
    ASSERT_NE(simulator, nullptr);
    const int frames = static_cast<int>(simulator->duration_s() * 10.0);
    const int samples = 30;
    int ok = 0, tried = 0;
    double err_sum = 0;
    double err_sq = 0, err_max = 0, z_sq = 0, sig_sum = 0, tmax = 0;
    for (int i = 0; i < samples; ++i) {
      const uint64_t f = static_cast<uint64_t>((i + 0.5) * (frames - 4) / samples);
      for (int gap : {1, 3}) {
        const BodyFrame a = ScanFrame(*simulator, "up", f);
        const BodyFrame b = ScanFrame(*simulator, "up", f + gap);
        if (a.points.empty() || b.points.empty()) continue;
        const double truth_dx = (a.T_world_body.inverse() * b.T_world_body).translation().x();
        timespec t0, t1;
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t0);
        const HeightDescriptor da = ComputeHeightDescriptor(options, a.points);
        const HeightDescriptor db = ComputeHeightDescriptor(options, b.points);
        const LongitudinalShift shift =
            EstimateLongitudinalShift(options, da, db, truth_dx + 0.4);
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t1);
        tmax = std::max(tmax, CpuMs(t0, t1) / 2.0);
        ++tried;
        if (getenv("HD_QUIET")) { if (!shift.ok) continue; } else
        if (!shift.ok) {
          std::printf("  %s f%d+%d: not ok (dist %.3f)\n", info.name.c_str(), (int)f, gap,
                      shift.distance);
          continue;
        }
        ++ok;
        const double err = shift.dx_m - truth_dx;
        if (std::fabs(err) > 0.15 && !getenv("HD_QUIET"))
          std::printf("  %s f%d+%d: dx %.3f truth %.3f err %.3f sigma %.3f dist %.3f\n",
                      info.name.c_str(), (int)f, gap, shift.dx_m, truth_dx, err, shift.sigma_m,
                      shift.distance);
        err_sq += err * err;
        err_sum += err;
        err_max = std::max(err_max, std::fabs(err));
        z_sq += err * err / (shift.sigma_m * shift.sigma_m);
        sig_sum += shift.sigma_m;
      }
    }
    std::printf("%-28s ok %2d/%d mean %+.3f rms %.3f max %.3f mean sigma %.3f rms z %.2f t %.2f ms\n",
                info.name.c_str(), ok, tried, err_sum / ok, std::sqrt(err_sq / ok), err_max, sig_sum / ok,
                std::sqrt(z_sq / ok), tmax);
  }
}

}  // namespace
}  // namespace raillomer
