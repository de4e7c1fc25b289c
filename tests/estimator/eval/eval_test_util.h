#pragma once

#include <cmath>
#include <cstdint>
#include <functional>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "api/trajectory.h"
#include "tests/support/poses.h"

namespace raillomer::eval::testing {

/// 1.6e9 s: epoch-sized stamps so precision problems would show.
constexpr int64_t kStartStampNs = 1600000000LL * 1000000000LL;

/// A trajectory of n poses, dt_s apart, with pose i from make_pose(i).
inline api::Trajectory MakeTrajectory(int n,
                                      double dt_s,
                                      const std::function<Eigen::Isometry3d(int)>& make_pose) {
  api::Trajectory trajectory;
  for (int i = 0; i < n; ++i) {
    const Eigen::Isometry3d T = make_pose(i);
    api::StampedPose pose;
    pose.stamp_ns = kStartStampNs + static_cast<int64_t>(std::llround(i * dt_s * 1e9));
    pose.p_world = T.translation();
    pose.q_world_body = Eigen::Quaterniond(T.linear()).normalized();
    trajectory.poses.push_back(pose);
  }
  return trajectory;
}

/// Pose from a position and yaw, pitch, roll (rad), ZYX order.
inline Eigen::Isometry3d Pose(const Eigen::Vector3d& p,
                              double yaw,
                              double pitch = 0.0,
                              double roll = 0.0) {
  return test::PoseYpr(p, yaw, pitch, roll);
}

/// A curved 3D run: an arc of radius 150 m with a gentle up-and-down and pitching, 1 m per pose.
inline api::Trajectory CurvedTruth(int n = 600) {
  return MakeTrajectory(n, 0.1, [](int i) {
    const double s = i;
    const double radius = 150.0;
    const Eigen::Vector3d p(radius * std::sin(s / radius),
                            radius * (1.0 - std::cos(s / radius)),
                            5.0 * std::sin(s / 50.0));
    return Pose(p, s / radius, 0.1 * std::cos(s / 50.0), 0.02 * std::sin(s / 30.0));
  });
}

/// A straight run from `start` along heading yaw, step_m per pose, dt 0.1 s.
inline api::Trajectory StraightTruth(int n,
                                     double step_m,
                                     const Eigen::Vector3d& start,
                                     double yaw) {
  const Eigen::Vector3d direction(std::cos(yaw), std::sin(yaw), 0.0);
  return MakeTrajectory(n, 0.1, [=](int i) { return Pose(start + i * step_m * direction, yaw); });
}

/// Every pose left-multiplied by T_new_old.
inline api::Trajectory Transformed(const api::Trajectory& trajectory,
                                   const Eigen::Isometry3d& T_new_old) {
  api::Trajectory out = trajectory;
  for (api::StampedPose& pose : out.poses) {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.linear() = pose.q_world_body.toRotationMatrix();
    T.translation() = pose.p_world;
    const Eigen::Isometry3d T_new = T_new_old * T;
    pose.p_world = T_new.translation();
    pose.q_world_body = Eigen::Quaterniond(T_new.linear()).normalized();
  }
  return out;
}

/// Positions scaled about the first pose by `scale`; orientations unchanged.
inline api::Trajectory Scaled(const api::Trajectory& trajectory, double scale) {
  api::Trajectory out = trajectory;
  const Eigen::Vector3d origin = trajectory.poses.front().p_world;
  for (api::StampedPose& pose : out.poses) pose.p_world = origin + scale * (pose.p_world - origin);
  return out;
}

}  // namespace raillomer::eval::testing
