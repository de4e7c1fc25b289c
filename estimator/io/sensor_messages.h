#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <variant>
#include <vector>

#include <Eigen/Core>

namespace raillomer::io {

/// One Livox point as in livox_ros_driver/CustomPoint: sensor frame, metres.
struct LivoxPoint {
  uint32_t offset_time_ns = 0;  ///< from the frame's timebase
  float x = 0.f, y = 0.f, z = 0.f;
  uint8_t reflectivity = 0;
  uint8_t tag = 0;  ///< bits 4-5: return number
  uint8_t line = 0;
};

/// One LiDAR frame as in livox_ros_driver/CustomMsg.
struct LidarFrame {
  int64_t stamp_ns = 0;      ///< header stamp (= timebase, the first point's time)
  std::string frame_id;      ///< sensor frame name, e.g. "livox_up"
  uint64_t timebase_ns = 0;  ///< absolute time of the first point
  uint8_t lidar_id = 0;
  std::vector<LivoxPoint> points;
};

/// One IMU sample (sensor_msgs/Imu): angular rate and specific force in the IMU (= body) frame.
struct ImuSample {
  int64_t stamp_ns = 0;
  std::string frame_id = "imu";
  Eigen::Vector3d angular_velocity_radps = Eigen::Vector3d::Zero();
  Eigen::Vector3d linear_acceleration_mps2 = Eigen::Vector3d::Zero();
  double gyro_noise_var = 0.0;   ///< diagonal of angular_velocity_covariance
  double accel_noise_var = 0.0;  ///< diagonal of linear_acceleration_covariance
};

/// One GNSS fix (sensor_msgs/NavSatFix), WGS84 with ellipsoidal height.
struct GnssFix {
  int64_t stamp_ns = 0;
  std::string frame_id = "gnss";
  int8_t status = 0;     ///< sensor_msgs/NavSatStatus: -1 no fix, 0 fix, 1 SBAS, 2 GBAS
  uint16_t service = 1;  ///< GPS=1, GLONASS=2, COMPASS=4, GALILEO=8
  double latitude_deg = 0.0, longitude_deg = 0.0, altitude_m = 0.0;
  std::array<double, 9> position_covariance{};  ///< ENU, m^2, row-major (as reported)
  uint8_t position_covariance_type = 2;         ///< 2 = COVARIANCE_TYPE_DIAGONAL_KNOWN
};

/// One wheel odometer reading (sensor_msgs/JointState with name [wheel]).
struct WheelOdometry {
  int64_t stamp_ns = 0;
  std::string frame_id = "odometer";
  double position_rad = 0.0;    ///< cumulative wheel angle, whole encoder pulses
  double velocity_radps = 0.0;  ///< wheel angular rate
};

/// A sensor message with the topic it travels on and the time it was received (bag time).
struct SensorMessage {
  std::string topic;
  int64_t receive_ns = 0;
  std::variant<LidarFrame, ImuSample, GnssFix, WheelOdometry> data;
};

/// A time-ordered stream of sensor messages: a bag on disk or the in-process simulator.
class SensorSource {
 public:
  virtual ~SensorSource() = default;
  /// Fills the next message in receive-time order; false at the end of the stream.
  virtual bool Next(SensorMessage* message) = 0;
};

}  // namespace raillomer::io
