#include "api/stream.h"

#include <cinttypes>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>

namespace raillomer::api {
namespace {

/// Sequences are stored as SQLite integers: below 2^63.
constexpr uint64_t kMaxSequence = uint64_t{INT64_MAX};

/// Decimal digits only, at most `max`.
bool ParseWholeNumber(const std::string& text, uint64_t max, uint64_t* value) {
  if (text.empty() || text.size() > 20) return false;
  uint64_t v = 0;
  for (char c : text) {
    if (c < '0' || c > '9') return false;
    const uint64_t digit = static_cast<uint64_t>(c - '0');
    if (v > (max - digit) / 10) return false;
    v = v * 10 + digit;
  }
  *value = v;
  return true;
}

}  // namespace

std::string EncodeSubmapPcd(const Submap& s) {
  std::ostringstream h;
  h << "# .PCD v0.7 - RailLoMer submap: offsets from the origin below ("
    << (s.georeferenced ? "UTM zone " + s.utm_zone : std::string("local odometry frame")) << ")\n";
  char line[256];
  std::snprintf(line,
                sizeof(line),
                "# raillomer sequence %" PRIu64 " index %u keyframes %zu\n",
                s.sequence,
                s.index,
                s.keyframes.size());
  h << line;
  h << "# raillomer stamps " << FormatStampSeconds(s.first_stamp_ns) << " "
    << FormatStampSeconds(s.last_stamp_ns) << "\n";
  h << "# raillomer zone " << (s.georeferenced ? s.utm_zone : std::string("local")) << "\n";
  std::snprintf(line,
                sizeof(line),
                "# raillomer origin %.4f %.4f %.4f\n",
                s.origin.x(),
                s.origin.y(),
                s.origin.z());
  h << line;
  if (s.placement > 0) h << "# raillomer placement " << s.placement << "\n";
  for (const StampedPose& k : s.keyframes) h << "# raillomer keyframe " << FormatTumLine(k) << "\n";
  h << "VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
    << "WIDTH " << s.points.size() << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS "
    << s.points.size() << "\nDATA binary\n";
  std::string out = h.str();
  const size_t offset = out.size();
  out.resize(offset + 16 * s.points.size());
  for (size_t i = 0; i < s.points.size(); ++i) {
    const float v[4] = {s.points[i].x(),
                        s.points[i].y(),
                        s.points[i].z(),
                        i < s.intensities.size() ? s.intensities[i] : 0.f};
    std::memcpy(&out[offset + 16 * i], v, sizeof(v));
  }
  return out;
}

namespace {

/// What the header of a submap PCD has said so far.
struct PcdHeader {
  size_t points = 0;
  bool have_points = false, have_origin = false, have_fields = false;
  std::set<std::string> seen;  ///< single-valued raillomer lines
};

/// Reads one "# raillomer <what> ..." line (`in` after the "#") into the submap; returns why it
/// is bad, or an empty string.
std::string ParseRaillomerLine(std::istringstream& in,
                               const std::string& line,
                               PcdHeader* h,
                               Submap* s) {
  std::string tag, what;
  in >> tag >> what;
  if (tag != "raillomer") return "";
  if (what != "keyframe" && !h->seen.insert(what).second)
    return "the header has a second '" + what + "' line";
  const std::string bad = "bad line '" + line + "'";
  if (what == "sequence") {
    // Whole numbers only: ">>" would read "-5" into an unsigned as 2^64 - 5.
    std::string sequence, k1, index, k2, keyframes;
    uint64_t n = 0;
    if (!(in >> sequence >> k1 >> index >> k2 >> keyframes) || k1 != "index" || k2 != "keyframes" ||
        !ParseWholeNumber(sequence, kMaxSequence, &s->sequence) ||
        !ParseWholeNumber(index, UINT32_MAX, &n))
      return bad + " (sequence below 2^63, index below 2^32)";
    s->index = static_cast<uint32_t>(n);
  } else if (what == "stamps") {
    std::string a, b;
    if (!(in >> a >> b) || !ParseStampSeconds(a, &s->first_stamp_ns) ||
        !ParseStampSeconds(b, &s->last_stamp_ns))
      return bad;
  } else if (what == "zone") {
    std::string zone;
    in >> zone;
    s->georeferenced = zone != "local";
    if (s->georeferenced) {
      int z = 0;
      bool north = true;
      if (!ParseUtmZoneName(zone, &z, &north)) return "bad UTM zone '" + zone + "'";
      s->utm_zone = zone;
    }
  } else if (what == "origin") {
    if (!(in >> s->origin.x() >> s->origin.y() >> s->origin.z())) return bad;
    h->have_origin = true;
  } else if (what == "placement") {
    std::string placement;
    uint64_t n = 0;
    if (!(in >> placement) || !ParseWholeNumber(placement, UINT32_MAX, &n))
      return bad + " (placement below 2^32)";
    s->placement = static_cast<uint32_t>(n);
  } else if (what == "keyframe") {
    Trajectory t;
    std::string rest, ignored;
    std::getline(in, rest);
    if (!ParseTum(rest, &t, &ignored) || t.poses.size() != 1) return bad;
    s->keyframes.push_back(t.poses[0]);
  }
  return "";
}

/// Reads the header up to its DATA line, after which `pos` is the first byte of the points;
/// returns why it is bad, or an empty string.
std::string ReadPcdHeader(const std::string& bytes, size_t* pos, PcdHeader* h, Submap* s) {
  while (*pos < bytes.size()) {
    const size_t end = bytes.find('\n', *pos);
    if (end == std::string::npos) return "the header has no DATA line";
    const std::string line = bytes.substr(*pos, end - *pos);
    *pos = end + 1;
    std::istringstream in(line);
    std::string key;
    in >> key;
    if (key == "#") {
      const std::string why = ParseRaillomerLine(in, line, h, s);
      if (!why.empty()) return why;
    } else if (key == "FIELDS") {
      std::string rest;
      std::getline(in, rest);
      if (rest != " x y z intensity") return "fields are '" + rest + "', not x y z intensity";
      h->have_fields = true;
    } else if (key == "POINTS") {
      if (!(in >> h->points)) return "bad POINTS line";
      h->have_points = true;
    } else if (key == "DATA") {
      std::string kind;
      in >> kind;
      if (kind != "binary") return "DATA is '" + kind + "', not binary";
      break;
    }
  }
  if (!h->have_fields || !h->have_points || !h->have_origin || !h->seen.count("sequence"))
    return "the header lacks FIELDS, POINTS or the raillomer origin or sequence";
  return "";
}

}  // namespace

bool DecodeSubmapPcd(const std::string& bytes, Submap* s, std::string* error) {
  auto fail = [&](const std::string& m) {
    if (error) *error = "submap PCD: " + m;
    return false;
  };
  *s = Submap();
  size_t pos = 0;
  PcdHeader header;
  const std::string why = ReadPcdHeader(bytes, &pos, &header, s);
  if (!why.empty()) return fail(why);
  const size_t points = header.points;
  if (points > (bytes.size() - pos) / 16 || bytes.size() - pos != 16 * points) {
    return fail("expected " + std::to_string(16 * points) + " bytes of points, found " +
                std::to_string(bytes.size() - pos) + " (truncated?)");
  }
  s->points.resize(points);
  s->intensities.resize(points);
  for (size_t i = 0; i < points; ++i) {
    float v[4];
    std::memcpy(v, &bytes[pos + 16 * i], sizeof(v));
    s->points[i] = Eigen::Vector3f(v[0], v[1], v[2]);
    s->intensities[i] = v[3];
  }
  return true;
}

bool ReadSubmapFile(const std::string& path, Submap* submap, std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    if (error) *error = "cannot read " + path;
    return false;
  }
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (!DecodeSubmapPcd(bytes, submap, error)) {
    if (error) *error = path + ": " + *error;
    return false;
  }
  return true;
}

}  // namespace raillomer::api
