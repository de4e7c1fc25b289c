#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/io/sensor_messages.h"
#include "estimator/sim/raycaster.h"
#include "estimator/sim/scenario.h"

namespace raillomer::sim {

/// What produced a simulated point (ground truth for tests; not in the bag).
enum class PointKind : uint8_t {
  kNoReturn,    ///< nothing within range: a zero point, as the Livox driver sends it
  kSurface,     ///< a true return from the world
  kSunFlicker,  ///< a spurious return towards the sun
  kBleeding,    ///< a mixed return between a foreground and a background edge
  kBody,        ///< a return from the vehicle itself
};

/// A Livox Horizon: 6 lasers sweeping an 81.7 x 25.1 deg field of view in a non-repetitive
/// pattern, each point cast from the sensor pose at its own time (a truly skewed scan).
class LivoxHorizonModel {
 public:
  LivoxHorizonModel(const Scenario& scenario, const LidarConfig& config, uint32_t seed);

  /// Unit direction in the sensor frame and laser line of point `index` in frame `frame`.
  Eigen::Vector3d Direction(uint64_t frame, uint32_t index, uint8_t* line) const;
  /// Time of point `index` after the frame's first point, in nanoseconds.
  uint32_t OffsetNs(uint32_t index) const;
  const Eigen::Isometry3d& T_body_lidar() const { return T_body_lidar_; }
  const LidarConfig& config() const { return config_; }

  /// Scans frame `frame` whose first point is at run time t0_s. `body_pose(t)` gives
  /// T_world_body. Fills the Livox points (sensor frame) and, if given, what made each point.
  void Scan(uint64_t frame,
            double t0_s,
            const std::function<Eigen::Isometry3d(double)>& body_pose,
            const RayCaster& caster,
            std::vector<io::LivoxPoint>* points,
            std::vector<PointKind>* kinds) const;

 private:
  struct SensorTrack;
  struct FrameNoise;
  struct Echo;
  /// The sensor's poses over a frame starting at t0_s.
  SensorTrack TrackOverFrame(double t0_s,
                             const std::function<Eigen::Isometry3d(double)>& body_pose) const;
  /// The return of the beam along `dir` (sensor frame) at t_s into the frame: the vehicle's own
  /// body, a surface, sun flicker, or nothing.
  Echo Measure(const Eigen::Vector3d& dir,
               double t_s,
               const SensorTrack& track,
               const RayCaster& caster,
               FrameNoise* noise) const;
  /// A surface return between two of ranges a and b that differ much may land between them.
  void Bleed(double a, double b, FrameNoise* noise, Echo* echo) const;
  /// Range to the vehicle body along a sensor-frame ray, or a negative number.
  double BodyRange(const Eigen::Vector3d& dir_sensor) const;

  const Scenario& scenario_;
  LidarConfig config_;
  uint32_t seed_;
  Eigen::Isometry3d T_body_lidar_;
  int64_t period_ns_;
  uint32_t groups_per_sweep_;  ///< firings of the 6 lasers in one horizontal sweep
  Eigen::Vector3d sun_world_;
  double sun_cos_;                ///< cosine of the sun cone's half angle (sun flicker)
  Eigen::AlignedBox3d body_box_;  ///< vehicle roof edge, body frame
};

}  // namespace raillomer::sim
