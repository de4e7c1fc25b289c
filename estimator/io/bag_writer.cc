#include "estimator/io/bag_writer.h"

#include <exception>
#include <type_traits>
#include <utility>

#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <sensor_msgs/Imu.h>
#include <sensor_msgs/JointState.h>
#include <sensor_msgs/NavSatFix.h>

#include "api/atomic_file.h"
#include "estimator/io/livox_custom_msg.h"

namespace raillomer::io {
namespace {

constexpr int64_t kNsPerS = 1000000000;
// ros::Time holds uint32 seconds.
constexpr int64_t kMaxRosTimeNs = int64_t{0xFFFFFFFF} * kNsPerS + (kNsPerS - 1);

bool ToRosTime(int64_t ns, const char* what, ros::Time* time, std::string* error) {
  if (ns < 0 || ns > kMaxRosTimeNs) {
    *error = std::string(what) + " " + std::to_string(ns) +
             " ns is outside the range of ros::Time (0 .. 2^32 s)";
    return false;
  }
  time->sec = static_cast<uint32_t>(ns / kNsPerS);
  time->nsec = static_cast<uint32_t>(ns % kNsPerS);
  return true;
}

bool FillHeader(int64_t stamp_ns,
                const std::string& frame_id,
                uint32_t seq,
                std_msgs::Header* header,
                std::string* error) {
  header->seq = seq;
  header->frame_id = frame_id;
  return ToRosTime(stamp_ns, "header stamp", &header->stamp, error);
}

bool Convert(const LidarFrame& in,
             uint32_t seq,
             livox_ros_driver::CustomMsg* out,
             std::string* error) {
  if (!FillHeader(in.stamp_ns, in.frame_id, seq, &out->header, error)) return false;
  if (in.points.size() > 0xFFFFFFFFu) {
    *error = "lidar frame has more than 2^32 points";
    return false;
  }
  out->timebase = in.timebase_ns;
  out->point_num = static_cast<uint32_t>(in.points.size());
  out->lidar_id = in.lidar_id;
  out->points.resize(in.points.size());
  for (size_t i = 0; i < in.points.size(); ++i) {
    const LivoxPoint& p = in.points[i];
    livox_ros_driver::CustomPoint& q = out->points[i];
    q.offset_time = p.offset_time_ns;
    q.x = p.x;
    q.y = p.y;
    q.z = p.z;
    q.reflectivity = p.reflectivity;
    q.tag = p.tag;
    q.line = p.line;
  }
  return true;
}

bool Convert(const ImuSample& in, uint32_t seq, sensor_msgs::Imu* out, std::string* error) {
  if (!FillHeader(in.stamp_ns, in.frame_id, seq, &out->header, error)) return false;
  // No orientation estimate: REP 145 / sensor_msgs/Imu say element 0 of its covariance is -1.
  out->orientation.x = 0.0;
  out->orientation.y = 0.0;
  out->orientation.z = 0.0;
  out->orientation.w = 1.0;
  out->orientation_covariance.fill(0.0);
  out->orientation_covariance[0] = -1.0;
  out->angular_velocity.x = in.angular_velocity_radps.x();
  out->angular_velocity.y = in.angular_velocity_radps.y();
  out->angular_velocity.z = in.angular_velocity_radps.z();
  out->linear_acceleration.x = in.linear_acceleration_mps2.x();
  out->linear_acceleration.y = in.linear_acceleration_mps2.y();
  out->linear_acceleration.z = in.linear_acceleration_mps2.z();
  out->angular_velocity_covariance.fill(0.0);
  out->linear_acceleration_covariance.fill(0.0);
  for (int i = 0; i < 3; ++i) {
    out->angular_velocity_covariance[4 * i] = in.gyro_noise_var;
    out->linear_acceleration_covariance[4 * i] = in.accel_noise_var;
  }
  return true;
}

bool Convert(const GnssFix& in, uint32_t seq, sensor_msgs::NavSatFix* out, std::string* error) {
  if (!FillHeader(in.stamp_ns, in.frame_id, seq, &out->header, error)) return false;
  out->status.status = in.status;
  out->status.service = in.service;
  out->latitude = in.latitude_deg;
  out->longitude = in.longitude_deg;
  out->altitude = in.altitude_m;
  for (size_t i = 0; i < 9; ++i) out->position_covariance[i] = in.position_covariance[i];
  out->position_covariance_type = in.position_covariance_type;
  return true;
}

bool Convert(const WheelOdometry& in,
             uint32_t seq,
             sensor_msgs::JointState* out,
             std::string* error) {
  if (!FillHeader(in.stamp_ns, in.frame_id, seq, &out->header, error)) return false;
  out->name = {"wheel"};
  out->position = {in.position_rad};
  out->velocity = {in.velocity_radps};
  out->effort.clear();
  return true;
}

const char* RosTypeOf(const SensorMessage& message) {
  switch (message.data.index()) {
    case 0:
      return ros::message_traits::DataType<livox_ros_driver::CustomMsg>::value();
    case 1:
      return ros::message_traits::DataType<sensor_msgs::Imu>::value();
    case 2:
      return ros::message_traits::DataType<sensor_msgs::NavSatFix>::value();
    default:
      return ros::message_traits::DataType<sensor_msgs::JointState>::value();
  }
}

}  // namespace

struct BagWriter::Impl {
  explicit Impl(const std::string& path) : file(path) {}
  ~Impl() {
    // Close the bag before `file` removes the temporary; a failing close must not escape.
    try {
      bag.close();
    } catch (const std::exception&) {
    }
  }

  template <typename RosMessage, typename Struct>
  bool WriteAs(const SensorMessage& message, const Struct& data, std::string* error) {
    ros::Time bag_time;
    if (!ToRosTime(message.receive_ns, "receive time", &bag_time, error)) return false;
    if (bag_time < ros::TIME_MIN) {
      *error = "receive time must be at least 1 ns (rosbag rejects time 0)";
      return false;
    }
    RosMessage ros_message;
    const uint64_t seq = counts[message.topic];
    if (!Convert(data, static_cast<uint32_t>(seq), &ros_message, error)) return false;
    bag.write(message.topic, bag_time, ros_message);
    return true;
  }

  api::AtomicFile file;  // declared before `bag`: destroyed after it
  rosbag::Bag bag;
  std::map<std::string, uint64_t> counts;
  std::map<std::string, std::string> topic_types;
  uint64_t total = 0;
  bool closed = false;
};

BagWriter::BagWriter(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

BagWriter::~BagWriter() = default;

std::unique_ptr<BagWriter> BagWriter::Open(const std::string& path,
                                           const BagWriterOptions& options,
                                           std::string* error) {
  std::string ignored;
  if (!error) error = &ignored;
  if (path.empty()) {
    *error = "bag path is empty";
    return nullptr;
  }
  if (options.chunk_threshold_bytes == 0) {
    *error = "chunk_threshold_bytes must be positive";
    return nullptr;
  }
  auto impl = std::make_unique<Impl>(path);
  try {
    impl->bag.open(impl->file.temp_path(), rosbag::bagmode::Write);
    impl->bag.setCompression(options.lz4_compression ? rosbag::compression::LZ4
                                                     : rosbag::compression::Uncompressed);
    impl->bag.setChunkThreshold(options.chunk_threshold_bytes);
  } catch (const std::exception& e) {
    *error = "cannot open bag " + impl->file.temp_path() + " for writing: " + e.what();
    return nullptr;
  }
  return std::unique_ptr<BagWriter>(new BagWriter(std::move(impl)));
}

bool BagWriter::Write(const SensorMessage& message, std::string* error) {
  std::string ignored;
  if (!error) error = &ignored;
  Impl& d = *impl_;
  if (d.closed) {
    *error = "bag " + d.file.path() + " is already closed";
    return false;
  }
  if (message.topic.empty() || message.topic[0] != '/') {
    *error = "topic '" + message.topic + "' must start with '/'";
    return false;
  }
  // rosbag keys connections by topic only: a second type on one topic would corrupt the bag.
  const std::string type = RosTypeOf(message);
  auto [it, inserted] = d.topic_types.emplace(message.topic, type);
  if (!inserted && it->second != type) {
    *error = "topic " + message.topic + " already carries " + it->second + ", cannot write " + type;
    return false;
  }
  bool ok = false;
  try {
    ok = std::visit(
        [&](const auto& data) {
          using T = std::decay_t<decltype(data)>;
          if constexpr (std::is_same_v<T, LidarFrame>) {
            return d.WriteAs<livox_ros_driver::CustomMsg>(message, data, error);
          } else if constexpr (std::is_same_v<T, ImuSample>) {
            return d.WriteAs<sensor_msgs::Imu>(message, data, error);
          } else if constexpr (std::is_same_v<T, GnssFix>) {
            return d.WriteAs<sensor_msgs::NavSatFix>(message, data, error);
          } else {
            return d.WriteAs<sensor_msgs::JointState>(message, data, error);
          }
        },
        message.data);
  } catch (const std::exception& e) {
    *error = "cannot write " + message.topic + " to " + d.file.temp_path() + ": " + e.what();
    ok = false;
  }
  if (inserted && !ok) d.topic_types.erase(message.topic);
  if (!ok) return false;
  ++d.counts[message.topic];
  ++d.total;
  return true;
}

bool BagWriter::Close(std::string* error) {
  std::string ignored;
  if (!error) error = &ignored;
  Impl& d = *impl_;
  if (d.closed) {
    *error = "bag " + d.file.path() + " is already closed";
    return false;
  }
  d.closed = true;
  try {
    d.bag.close();
  } catch (const std::exception& e) {
    *error = "cannot finish bag " + d.file.temp_path() + ": " + e.what();
    return false;
  }
  return d.file.Commit(error);
}

const std::string& BagWriter::path() const { return impl_->file.path(); }

const std::map<std::string, uint64_t>& BagWriter::message_counts() const { return impl_->counts; }

uint64_t BagWriter::total_messages() const { return impl_->total; }

}  // namespace raillomer::io
