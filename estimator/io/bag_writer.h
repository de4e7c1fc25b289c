#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>

#include "estimator/io/sensor_messages.h"

namespace raillomer::io {

/// Options of BagWriter.
struct BagWriterOptions {
  bool lz4_compression = false;             ///< compress chunks with LZ4 (rosbag --lz4)
  uint32_t chunk_threshold_bytes = 786432;  ///< rosbag's default chunk size (768 KiB)
};

/// Writes SensorMessages to a ROS1 bag in the sensor data contract's message types
/// (livox_ros_driver/CustomMsg, sensor_msgs/Imu, NavSatFix, JointState). The bag is written under a
/// temporary name beside `path` and renamed into place by Close(), so a half-written bag never
/// appears under its final name. Never throws; failures come back as messages.
class BagWriter {
 public:
  /// Opens the temporary file; nullptr and a message on failure.
  static std::unique_ptr<BagWriter> Open(const std::string& path,
                                         const BagWriterOptions& options,
                                         std::string* error);
  /// Without a successful Close() the temporary file is removed and no bag appears at path().
  ~BagWriter();
  BagWriter(const BagWriter&) = delete;
  BagWriter& operator=(const BagWriter&) = delete;

  /// Appends one message at bag time `message.receive_ns` (must be >= 1 ns). A topic keeps the
  /// message type of its first message. False with a message on bad input or I/O failure.
  bool Write(const SensorMessage& message, std::string* error);
  /// Writes the index, closes the bag and renames it to path(). False with a message on failure;
  /// then no bag appears at path().
  bool Close(std::string* error);

  const std::string& path() const;
  /// Messages written so far per topic.
  const std::map<std::string, uint64_t>& message_counts() const;
  /// Messages written so far over all topics.
  uint64_t total_messages() const;

 private:
  struct Impl;
  explicit BagWriter(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace raillomer::io
