#pragma once

// Poses for tests: a rigid transform from a position and yaw, pitch, roll.

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer::test {

/// Pose from a position and yaw, pitch, roll (rad), ZYX order: yaw about z, then pitch about
/// the new y, then roll about the new x.
inline Eigen::Isometry3d PoseYpr(const Eigen::Vector3d& p,
                                 double yaw,
                                 double pitch = 0.0,
                                 double roll = 0.0) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  T.translation() = p;
  return T;
}

}  // namespace raillomer::test
