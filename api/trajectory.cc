#include "api/trajectory.h"

#include <cerrno>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>

#include "api/atomic_file.h"

namespace raillomer::api {

namespace {

bool ParseDouble(const std::string& text, double* value) {
  if (text.empty()) return false;
  char* end = nullptr;
  errno = 0;
  *value = std::strtod(text.c_str(), &end);
  return errno == 0 && end == text.c_str() + text.size() && std::isfinite(*value);
}

}  // namespace

bool ParseUtmZoneName(const std::string& text, int* zone, bool* north) {
  if (text.size() < 2 || text.size() > 3) return false;
  const char hemisphere = text.back();
  if (hemisphere != 'N' && hemisphere != 'S') return false;
  int number = 0;
  for (size_t i = 0; i + 1 < text.size(); ++i) {
    if (text[i] < '0' || text[i] > '9') return false;
    number = number * 10 + (text[i] - '0');
  }
  if (number < 1 || number > 60) return false;
  *zone = number;
  *north = hemisphere == 'N';
  return true;
}

std::string FormatStampSeconds(int64_t stamp_ns) {
  const bool negative = stamp_ns < 0;
  const uint64_t magnitude =
      negative ? static_cast<uint64_t>(-(stamp_ns + 1)) + 1 : static_cast<uint64_t>(stamp_ns);
  char buffer[48];
  std::snprintf(buffer,
                sizeof(buffer),
                "%s%" PRIu64 ".%09" PRIu64,
                negative ? "-" : "",
                static_cast<uint64_t>(magnitude / 1000000000ULL),
                static_cast<uint64_t>(magnitude % 1000000000ULL));
  return buffer;
}

bool ParseStampSeconds(const std::string& text, int64_t* stamp_ns) {
  size_t i = 0;
  bool negative = false;
  if (i < text.size() && (text[i] == '-' || text[i] == '+')) negative = text[i++] == '-';
  int64_t whole = 0;
  size_t whole_digits = 0;
  while (i < text.size() && text[i] >= '0' && text[i] <= '9') {
    if (whole > (INT64_MAX / 1000000000LL) / 10) return false;
    whole = whole * 10 + (text[i++] - '0');
    ++whole_digits;
  }
  int64_t fraction = 0;
  size_t fraction_digits = 0;
  if (i < text.size() && text[i] == '.') {
    ++i;
    while (i < text.size() && text[i] >= '0' && text[i] <= '9') {
      if (fraction_digits < 9) {
        fraction = fraction * 10 + (text[i] - '0');
        ++fraction_digits;
      }
      ++i;
    }
  }
  if (i != text.size() || whole_digits + fraction_digits == 0) {
    // Fall back to scientific notation ("1.6e9"), rounded to the nanosecond.
    double seconds = 0.0;
    if (!ParseDouble(text, &seconds) || std::fabs(seconds) > 9.2e9) return false;
    *stamp_ns = static_cast<int64_t>(std::llround(seconds * 1e9));
    return true;
  }
  for (size_t d = fraction_digits; d < 9; ++d) fraction *= 10;
  const int64_t value = whole * 1000000000LL + fraction;
  *stamp_ns = negative ? -value : value;
  return true;
}

bool ParseTum(const std::string& text, Trajectory* trajectory, std::string* error) {
  trajectory->poses.clear();
  trajectory->utm_zone.clear();
  std::istringstream in(text);
  std::string line;
  int line_number = 0;
  auto fail = [&](const std::string& what) {
    if (error) *error = "line " + std::to_string(line_number) + ": " + what;
    return false;
  };
  while (std::getline(in, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos) continue;
    if (line[first] == '#') {
      std::istringstream comment(line.substr(first + 1));
      std::string key, zone;
      if (comment >> key && key == "utm_zone") {
        int number = 0;
        bool north = true;
        if (!(comment >> zone) || !ParseUtmZoneName(zone, &number, &north)) {
          return fail("bad utm_zone comment '" + line + "' (expected e.g. '# utm_zone 50N')");
        }
        trajectory->utm_zone = zone;
      }
      continue;
    }
    std::istringstream fields(line);
    std::string token[8];
    int count = 0;
    std::string extra;
    while (count < 8 && fields >> token[count]) ++count;
    if (count != 8 || (fields >> extra)) {
      return fail("expected 8 fields 't x y z qx qy qz qw', got '" + line + "'");
    }
    StampedPose pose;
    if (!ParseStampSeconds(token[0], &pose.stamp_ns))
      return fail("bad timestamp '" + token[0] + "'");
    double v[7];
    for (int k = 0; k < 7; ++k) {
      if (!ParseDouble(token[k + 1], &v[k])) return fail("bad number '" + token[k + 1] + "'");
    }
    pose.p_world = Eigen::Vector3d(v[0], v[1], v[2]);
    pose.q_world_body = Eigen::Quaterniond(v[6], v[3], v[4], v[5]);
    const double norm = pose.q_world_body.norm();
    if (std::fabs(norm - 1.0) > 1e-3) {
      return fail("quaternion is not unit length (norm " + std::to_string(norm) + ")");
    }
    pose.q_world_body.normalize();
    if (!trajectory->poses.empty() && pose.stamp_ns <= trajectory->poses.back().stamp_ns) {
      return fail("timestamp " + token[0] + " does not increase");
    }
    trajectory->poses.push_back(pose);
  }
  return true;
}

bool ReadTum(const std::string& path, Trajectory* trajectory, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    if (error) *error = "cannot open " + path + ": " + std::strerror(errno);
    return false;
  }
  std::stringstream buffer;
  buffer << in.rdbuf();
  std::string message;
  if (!ParseTum(buffer.str(), trajectory, &message)) {
    if (error) *error = path + ": " + message;
    return false;
  }
  return true;
}

std::string FormatTumLine(const StampedPose& pose) {
  const Eigen::Quaterniond& q = pose.q_world_body;
  char buffer[256];
  std::snprintf(buffer,
                sizeof(buffer),
                " %.6f %.6f %.6f %.9f %.9f %.9f %.9f",
                pose.p_world.x(),
                pose.p_world.y(),
                pose.p_world.z(),
                q.x(),
                q.y(),
                q.z(),
                q.w());
  return FormatStampSeconds(pose.stamp_ns) + buffer;
}

std::string FormatTum(const Trajectory& trajectory) {
  std::string text;
  text.reserve(trajectory.poses.size() * 96 + 32);
  if (!trajectory.utm_zone.empty()) text += "# utm_zone " + trajectory.utm_zone + "\n";
  for (const StampedPose& pose : trajectory.poses) {
    text += FormatTumLine(pose);
    text += '\n';
  }
  return text;
}

bool WriteTum(const std::string& path, const Trajectory& trajectory, std::string* error) {
  return WriteFileAtomically(path, FormatTum(trajectory), error);
}

}  // namespace raillomer::api
