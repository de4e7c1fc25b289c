#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "api/trajectory.h"
#include "estimator/geo/utm.h"
#include "estimator/io/sensor_messages.h"
#include "estimator/sim/alignment.h"
#include "estimator/sim/livox_model.h"
#include "estimator/sim/motion.h"
#include "estimator/sim/raycaster.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/sensor_models.h"
#include "estimator/sim/world.h"

namespace raillomer::sim {

/// The simulated IMU's true biases at one instant (the estimator's bias states, to compare).
struct ImuBiasSample {
  int64_t stamp_ns = 0;
  Eigen::Vector3d gyro = Eigen::Vector3d::Zero();   ///< rad/s
  Eigen::Vector3d accel = Eigen::Vector3d::Zero();  ///< m/s^2
};

/// Run options that are not part of the scenario.
struct SimOptions {
  double duration_s = -1.0;      ///< < 0: the whole motion profile
  std::optional<uint32_t> seed;  ///< overrides the scenario's noise seed
  bool lidar = true;             ///< false: IMU, odometer and GNSS only (fast)
};

/// The in-process sensor source: a simulated run of one scenario, message by message in
/// receive-time order, with its exact ground truth. The same messages go into run.bag.
class Simulator : public io::SensorSource {
 public:
  /// Builds the corridor and the sensor models; false with a message if options are invalid.
  static std::unique_ptr<Simulator> Create(const Scenario& scenario,
                                           const SimOptions& options,
                                           std::string* error);

  bool Next(io::SensorMessage* message) override;

  const Scenario& scenario() const { return scenario_; }
  const Alignment& alignment() const { return *alignment_; }
  const World& world() const { return *world_; }
  const TruthMotion& truth() const { return *truth_; }
  const RayCaster& caster() const { return *caster_; }
  const std::vector<LivoxHorizonModel>& lidars() const { return lidars_; }
  double duration_s() const { return duration_s_; }
  /// Run time of the last message handed out, for progress output.
  double last_time_s() const { return last_time_s_; }
  const geo::UtmZone& utm_zone() const { return zone_; }
  /// UTM position (easting, northing, ellipsoidal height) of the world frame's origin.
  const Eigen::Vector3d& origin_utm() const { return origin_utm_; }
  /// Absolute stamp of run time t.
  int64_t StampNs(double t) const;

  /// The body frame's true pose at run time t, in UTM.
  api::StampedPose TruthPose(double t) const;
  /// Ground truth at `rate_hz` over the run, in UTM with the zone set.
  api::Trajectory TruthTrajectory(double rate_hz) const;
  /// A fix of the simulated receiver as a pose in UTM (orientation unknown: identity).
  api::StampedPose FixInUtm(const io::GnssFix& fix) const;
  /// The IMU's true biases as simulated so far, at 10 Hz (the bias of the sample at each tenth
  /// of a second of run time).
  const std::vector<ImuBiasSample>& imu_bias_track() const { return imu_bias_track_; }
  /// imu_bias_track() as CSV (imu_bias.csv): stamp_s, gyro_bias_x/y/z, accel_bias_x/y/z, the
  /// names of the estimator's timing.csv columns.
  std::string ImuBiasCsv() const;
  /// The estimator's configuration for this rig (rig.yaml).
  std::string RigYaml() const;
  /// The corridor edits of a changed run, in UTM and WGS84 (changes.json).
  std::string ChangesJson() const;

 private:
  explicit Simulator(const Scenario& scenario);
  /// Scans frame `frame_index_` of every unit that is not blacked out into pending_frames_.
  void ScanFrames(double receive_t);

  Scenario scenario_;
  std::unique_ptr<Alignment> alignment_;
  std::unique_ptr<World> world_;
  std::unique_ptr<TruthMotion> truth_;
  std::unique_ptr<RayCaster> caster_;
  std::vector<LivoxHorizonModel> lidars_;
  std::unique_ptr<ImuModel> imu_;
  std::unique_ptr<OdometerModel> odometer_;
  std::unique_ptr<GnssModel> gnss_;
  geo::UtmZone zone_;
  Eigen::Vector3d origin_utm_ = Eigen::Vector3d::Zero();
  int64_t start_ns_ = 0;
  double duration_s_ = 0.0;
  double last_time_s_ = 0.0;

  // Scheduling: the next sample index of each stream.
  uint64_t imu_index_ = 0, odometer_index_ = 0, gnss_index_ = 0, frame_index_ = 0;
  /// Frames of the current frame index, scanned together (one thread per unit), handed out in
  /// unit order.
  std::vector<io::SensorMessage> pending_frames_;
  size_t next_pending_ = 0;
  std::vector<ImuBiasSample> imu_bias_track_;
  uint64_t imu_samples_per_bias_entry_ = 1;  ///< IMU samples between two bias track entries
};

}  // namespace raillomer::sim
