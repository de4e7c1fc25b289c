#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "estimator/io/sensor_messages.h"

namespace raillomer::io {

/// Which bag topics carry which sensor. An empty name means "not read".
struct BagTopics {
  std::vector<std::string> lidar = {"/livox/lidar_up", "/livox/lidar_down"};
  std::string imu = "/imu/data";
  std::string gnss = "/gnss/fix";
  std::string odometer = "/odometer";

  /// No topic at all: BagReader then only summarises the bag (an `info` printout).
  static BagTopics None();
  /// False with a message if a name does not start with '/' or a topic is configured twice.
  bool IsValid(std::string* error) const;
};

/// One topic (and message type) stored in a bag.
struct BagTopicInfo {
  std::string topic;
  std::string type;
  std::string md5sum;
  uint64_t message_count = 0;
};

/// What a bag holds, as `rosbag info` shows it.
struct BagSummary {
  std::string path;
  uint64_t file_size_bytes = 0;
  /// False when the bag has no usable index (recording did not finish, or the file is truncated):
  /// then it is read by scanning its records, and `damage` says what is wrong.
  bool indexed = true;
  uint64_t message_count = 0;
  int64_t start_ns = 0;              ///< earliest bag time
  int64_t end_ns = 0;                ///< latest bag time
  std::vector<BagTopicInfo> topics;  ///< sorted by topic
  std::string damage;  ///< empty for a sound bag; else what is wrong and at which byte offset
  /// Multi-line text in the style of `rosbag info`.
  std::string ToString() const;
};

/// Reads a ROS1 bag of the sensor data contract as a SensorSource, in bag-time order.
///
/// Accepted message types: livox_ros_driver/CustomMsg or sensor_msgs/PointCloud2 on the lidar
/// topics (see bag_reader.cc for the PointCloud2 layouts), sensor_msgs/Imu, sensor_msgs/NavSatFix
/// and sensor_msgs/JointState (name "wheel"). A damaged bag (truncated, index missing, corrupt
/// records) yields every message before the damage, then Next() returns false and error() says
/// what happened and where. Never throws.
class BagReader : public SensorSource {
 public:
  /// Opens the bag and checks that every configured topic exists with an accepted type.
  /// nullptr and a message naming the problem (and the topics the bag has) on failure.
  static std::unique_ptr<BagReader> Open(const std::string& path,
                                         const BagTopics& topics,
                                         std::string* error);
  /// Summary of a bag without reading its messages; false and a message if it cannot be opened.
  static bool Inspect(const std::string& path, BagSummary* summary, std::string* error);

  ~BagReader() override;
  BagReader(const BagReader&) = delete;
  BagReader& operator=(const BagReader&) = delete;

  /// Next message of the configured topics in bag-time order; false at the end or on an error.
  bool Next(SensorMessage* message) override;
  /// Empty after a clean end; otherwise why reading stopped.
  const std::string& error() const;
  /// Topics, types, counts and time span of the whole bag.
  const BagSummary& Summary() const;
  /// Messages delivered by Next() so far, per topic.
  const std::map<std::string, uint64_t>& delivered_counts() const;

 private:
  struct Impl;
  explicit BagReader(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace raillomer::io
