#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer::api {

/// One pose of the body frame: T_world_body at stamp_ns (int64 nanoseconds).
struct StampedPose {
  int64_t stamp_ns = 0;
  Eigen::Vector3d p_world = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_body = Eigen::Quaterniond::Identity();
};

/// A trajectory as stored in a TUM file (`t x y z qx qy qz qw`, t in seconds).
struct Trajectory {
  std::vector<StampedPose> poses;
  /// UTM zone and hemisphere of the frame ("50N"), from a `# utm_zone 50N` line; empty if local.
  std::string utm_zone;
};

/// Parses a UTM zone name ("50N", "33S") into zone number 1..60 and hemisphere; false if malformed.
bool ParseUtmZoneName(const std::string& text, int* zone, bool* north);

/// Parses TUM text. Comment lines start with '#'; a `# utm_zone <zone><N|S>` line sets utm_zone.
/// Timestamps are parsed exactly to nanoseconds. Returns false with a message naming the line.
bool ParseTum(const std::string& text, Trajectory* trajectory, std::string* error);

/// Reads a TUM file; false with a message naming the file and line on failure.
bool ReadTum(const std::string& path, Trajectory* trajectory, std::string* error);

/// Formats one TUM line (no newline): nanosecond stamp, millimetre-exact positions.
std::string FormatTumLine(const StampedPose& pose);

/// Formats a whole trajectory, with the utm_zone line first when set.
std::string FormatTum(const Trajectory& trajectory);

/// Writes a TUM file atomically (temporary name, then rename).
bool WriteTum(const std::string& path, const Trajectory& trajectory, std::string* error);

/// Formats int64 nanoseconds as seconds with nine decimals ("1600000000.123456789").
std::string FormatStampSeconds(int64_t stamp_ns);

/// Parses seconds text ("1600000000.1234") exactly into nanoseconds; false if malformed.
bool ParseStampSeconds(const std::string& text, int64_t* stamp_ns);

}  // namespace raillomer::api
