#pragma once
// livox_ros_driver/CustomMsg and CustomPoint for rosbag without the Livox driver package.
//
// This header pulls in ROS serialization headers: include it only from .cc files (the bag reader,
// the bag writer and their tests), never from a public header.
//
// The message definitions are the ones livox_ros_driver v2.x publishes (msg/CustomMsg.msg,
// msg/CustomPoint.msg), in the gendeps full-text form rosbag stores in the connection header.
// genmsg re-hashes them to the md5 sums below (tests/estimator/io checks this with python rosbag).
// Comments are part of the text rosbag stores; "costom" is the upstream spelling, keep it.

#include <cstdint>
#include <vector>

#include <boost/array.hpp>
#include <boost/shared_ptr.hpp>

#include <ros/message_traits.h>
#include <ros/serialization.h>
#include <std_msgs/Header.h>

namespace livox_ros_driver {

/// One point: offset from the frame's timebase (ns), position (m), reflectivity, tag, laser line.
struct CustomPoint {
  uint32_t offset_time = 0;
  float x = 0.f;
  float y = 0.f;
  float z = 0.f;
  uint8_t reflectivity = 0;
  uint8_t tag = 0;
  uint8_t line = 0;

  typedef boost::shared_ptr<CustomPoint> Ptr;
  typedef boost::shared_ptr<CustomPoint const> ConstPtr;
};

/// One Livox frame: header, timebase of the first point (ns), and the points.
struct CustomMsg {
  std_msgs::Header header;
  uint64_t timebase = 0;
  uint32_t point_num = 0;
  uint8_t lidar_id = 0;
  boost::array<uint8_t, 3> rsvd = {{0, 0, 0}};
  std::vector<CustomPoint> points;

  typedef boost::shared_ptr<CustomMsg> Ptr;
  typedef boost::shared_ptr<CustomMsg const> ConstPtr;
};

/// md5 sums of the two message types as ROS computes them.
inline constexpr const char* kCustomMsgMd5 = "e4d6829bdfe657cb6c21a746c86b21a6";
inline constexpr const char* kCustomPointMd5 = "109a3cc548bb1f96626be89a5008bd6d";

}  // namespace livox_ros_driver

namespace ros {
namespace message_traits {

template <>
struct IsMessage<::livox_ros_driver::CustomPoint> : TrueType {};
template <>
struct IsMessage<::livox_ros_driver::CustomPoint const> : TrueType {};
template <>
struct IsFixedSize<::livox_ros_driver::CustomPoint> : TrueType {};
template <>
struct IsFixedSize<::livox_ros_driver::CustomPoint const> : TrueType {};
template <>
struct HasHeader<::livox_ros_driver::CustomPoint> : FalseType {};
template <>
struct HasHeader<::livox_ros_driver::CustomPoint const> : FalseType {};

template <>
struct MD5Sum<::livox_ros_driver::CustomPoint> {
  static const char* value() { return ::livox_ros_driver::kCustomPointMd5; }
  static const char* value(const ::livox_ros_driver::CustomPoint&) { return value(); }
  static const uint64_t static_value1 = 0x109a3cc548bb1f96ULL;
  static const uint64_t static_value2 = 0x626be89a5008bd6dULL;
};

template <>
struct DataType<::livox_ros_driver::CustomPoint> {
  static const char* value() { return "livox_ros_driver/CustomPoint"; }
  static const char* value(const ::livox_ros_driver::CustomPoint&) { return value(); }
};

template <>
struct Definition<::livox_ros_driver::CustomPoint> {
  static const char* value() {
    return "# Livox costom pointcloud format.\n"
           "\n"
           "uint32 offset_time      # offset time relative to the base time\n"
           "float32 x               # X axis, unit:m\n"
           "float32 y               # Y axis, unit:m\n"
           "float32 z               # Z axis, unit:m\n"
           "uint8 reflectivity      # reflectivity, 0~255\n"
           "uint8 tag               # livox tag\n"
           "uint8 line              # laser number in lidar\n"
           "\n";
  }
  static const char* value(const ::livox_ros_driver::CustomPoint&) { return value(); }
};

template <>
struct IsMessage<::livox_ros_driver::CustomMsg> : TrueType {};
template <>
struct IsMessage<::livox_ros_driver::CustomMsg const> : TrueType {};
template <>
struct IsFixedSize<::livox_ros_driver::CustomMsg> : FalseType {};
template <>
struct IsFixedSize<::livox_ros_driver::CustomMsg const> : FalseType {};
template <>
struct HasHeader<::livox_ros_driver::CustomMsg> : TrueType {};
template <>
struct HasHeader<::livox_ros_driver::CustomMsg const> : TrueType {};

template <>
struct MD5Sum<::livox_ros_driver::CustomMsg> {
  static const char* value() { return ::livox_ros_driver::kCustomMsgMd5; }
  static const char* value(const ::livox_ros_driver::CustomMsg&) { return value(); }
  static const uint64_t static_value1 = 0xe4d6829bdfe657cbULL;
  static const uint64_t static_value2 = 0x6c21a746c86b21a6ULL;
};

template <>
struct DataType<::livox_ros_driver::CustomMsg> {
  static const char* value() { return "livox_ros_driver/CustomMsg"; }
  static const char* value(const ::livox_ros_driver::CustomMsg&) { return value(); }
};

template <>
struct Definition<::livox_ros_driver::CustomMsg> {
  static const char* value() {
    return "# Livox publish pointcloud msg format.\n"
           "\n"
           "Header header             # ROS standard message header\n"
           "uint64 timebase           # The time of first point\n"
           "uint32 point_num          # Total number of pointclouds\n"
           "uint8  lidar_id           # Lidar device id number\n"
           "uint8[3]  rsvd            # Reserved use\n"
           "CustomPoint[] points      # Pointcloud data\n"
           "\n"
           "\n"
           "================================================================================\n"
           "MSG: std_msgs/Header\n"
           "# Standard metadata for higher-level stamped data types.\n"
           "# This is generally used to communicate timestamped data \n"
           "# in a particular coordinate frame.\n"
           "# \n"
           "# sequence ID: consecutively increasing ID \n"
           "uint32 seq\n"
           "#Two-integer timestamp that is expressed as:\n"
           "# * stamp.sec: seconds (stamp_secs) since epoch (in Python the variable is called "
           "'secs')\n"
           "# * stamp.nsec: nanoseconds since stamp_secs (in Python the variable is called "
           "'nsecs')\n"
           "# time-handling sugar is provided by the client library\n"
           "time stamp\n"
           "#Frame this data is associated with\n"
           "string frame_id\n"
           "\n"
           "================================================================================\n"
           "MSG: livox_ros_driver/CustomPoint\n"
           "# Livox costom pointcloud format.\n"
           "\n"
           "uint32 offset_time      # offset time relative to the base time\n"
           "float32 x               # X axis, unit:m\n"
           "float32 y               # Y axis, unit:m\n"
           "float32 z               # Z axis, unit:m\n"
           "uint8 reflectivity      # reflectivity, 0~255\n"
           "uint8 tag               # livox tag\n"
           "uint8 line              # laser number in lidar\n"
           "\n";
  }
  static const char* value(const ::livox_ros_driver::CustomMsg&) { return value(); }
};

}  // namespace message_traits

namespace serialization {

template <>
struct Serializer<::livox_ros_driver::CustomPoint> {
  template <typename Stream, typename T>
  inline static void allInOne(Stream& stream, T m) {
    stream.next(m.offset_time);
    stream.next(m.x);
    stream.next(m.y);
    stream.next(m.z);
    stream.next(m.reflectivity);
    stream.next(m.tag);
    stream.next(m.line);
  }
  ROS_DECLARE_ALLINONE_SERIALIZER
};

template <>
struct Serializer<::livox_ros_driver::CustomMsg> {
  template <typename Stream, typename T>
  inline static void allInOne(Stream& stream, T m) {
    stream.next(m.header);
    stream.next(m.timebase);
    stream.next(m.point_num);
    stream.next(m.lidar_id);
    stream.next(m.rsvd);
    stream.next(m.points);
  }
  ROS_DECLARE_ALLINONE_SERIALIZER
};

}  // namespace serialization
}  // namespace ros
