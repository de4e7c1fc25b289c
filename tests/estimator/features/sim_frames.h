#pragma once

// Simulated LiDAR frames in the body frame with exact truth, shared by the feature tests.

#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace raillomer::test {

/// A built-in scenario by name, or a scenario from YAML text.
inline std::unique_ptr<sim::Simulator> MakeSimulator(const std::string& name_or_yaml) {
  sim::Scenario scenario;
  std::string error;
  const bool parsed = name_or_yaml.find('\n') == std::string::npos
                          ? sim::LoadScenario(name_or_yaml, &scenario, &error)
                          : sim::ParseScenario(name_or_yaml, "test", &scenario, &error);
  EXPECT_TRUE(parsed) << error;
  if (!parsed) return nullptr;
  auto simulator = sim::Simulator::Create(scenario, sim::SimOptions{}, &error);
  EXPECT_NE(simulator, nullptr) << error;
  return simulator;
}

/// One LiDAR frame in the body frame at its end time, deskewed with the truth: each point is
/// moved with the body pose at its own time, T_body_end^-1 * T_world_body(t) * p_body.
struct BodyFrame {
  double t_end = 0.0;
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();  ///< at t_end
  std::vector<Eigen::Vector3f> points;
};

/// Frame `frame` of the LiDAR named `unit` ("up" or "down"); empty if there is no such LiDAR.
inline BodyFrame ScanFrame(const sim::Simulator& simulator,
                           const std::string& unit,
                           uint64_t frame) {
  BodyFrame out;
  const sim::LivoxHorizonModel* lidar = nullptr;
  for (const sim::LivoxHorizonModel& l : simulator.lidars()) {
    if (l.config().name == unit) lidar = &l;
  }
  if (lidar == nullptr) return out;
  const double period = 1.0 / simulator.scenario().lidar_rate_hz;
  const double t0 = static_cast<double>(frame) * period;
  const sim::TruthMotion& truth = simulator.truth();
  std::vector<io::LivoxPoint> points;
  lidar->Scan(
      frame,
      t0,
      [&truth](double t) { return truth.Pose(t); },
      simulator.caster(),
      &points,
      nullptr);
  out.t_end = t0 + period;
  out.T_world_body = truth.Pose(out.t_end);
  const Eigen::Isometry3d T_end_world = out.T_world_body.inverse();
  out.points.reserve(points.size());
  for (const io::LivoxPoint& p : points) {
    if (p.x == 0.f && p.y == 0.f && p.z == 0.f) continue;  // no return
    const Eigen::Vector3d p_body = lidar->T_body_lidar() * Eigen::Vector3d(p.x, p.y, p.z);
    const double t = t0 + p.offset_time_ns * 1e-9;
    out.points.push_back((T_end_world * truth.Pose(t) * p_body).cast<float>());
  }
  return out;
}

}  // namespace raillomer::test
