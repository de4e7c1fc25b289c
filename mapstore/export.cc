#include "mapstore/export.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>

namespace raillomer::mapstore {
namespace {

template <typename T>
void Put(std::string* out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  out->append(bytes, sizeof(T));
}

template <typename T>
T Get(const std::string& in, size_t at) {
  T value;
  std::memcpy(&value, in.data() + at, sizeof(T));
  return value;
}

constexpr size_t kLasHeader = 227;
constexpr size_t kLasRecord = 20;
constexpr double kLasScale = 0.001;

}  // namespace

bool ParseExportFormat(const std::string& name, ExportFormat* format) {
  if (name == "ply")
    *format = ExportFormat::kPly;
  else if (name == "pcd")
    *format = ExportFormat::kPcd;
  else if (name == "las")
    *format = ExportFormat::kLas;
  else
    return false;
  return true;
}

const char* ExtensionOf(ExportFormat format) {
  switch (format) {
    case ExportFormat::kPly:
      return "ply";
    case ExportFormat::kPcd:
      return "pcd";
    case ExportFormat::kLas:
      return "las";
  }
  return "bin";
}

std::string EncodeExport(const std::vector<ExportPoint>& points,
                         ExportFormat format,
                         const std::string& utm_zone) {
  std::string out;
  const size_t n = points.size();
  if (format == ExportFormat::kPly || format == ExportFormat::kPcd) {
    std::ostringstream h;
    if (format == ExportFormat::kPly) {
      h << "ply\nformat binary_little_endian 1.0\ncomment RailLoMer export, UTM zone " << utm_zone
        << "\nelement vertex " << n
        << "\nproperty double x\nproperty double y\nproperty double z\nproperty uchar "
           "intensity\nend_header\n";
    } else {
      h << "# .PCD v0.7 - RailLoMer export, UTM zone " << utm_zone
        << "\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 8 8 8 1\nTYPE F F F U\nCOUNT 1 1 1 1\n"
           "WIDTH "
        << n << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << n << "\nDATA binary\n";
    }
    // The same records in both: three doubles and a byte.
    out = h.str();
    out.reserve(out.size() + 25 * n);
    for (const ExportPoint& p : points) {
      Put(&out, p.p.x());
      Put(&out, p.p.y());
      Put(&out, p.p.z());
      Put(&out, p.intensity);
    }
  } else {
    Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();
    if (n > 0) {
      lo = hi = points[0].p;
      for (const ExportPoint& p : points) {
        lo = lo.cwiseMin(p.p);
        hi = hi.cwiseMax(p.p);
      }
    }
    const Eigen::Vector3d offset = lo.array().floor().matrix();
    out.assign(kLasHeader, '\0');
    std::memcpy(&out[0], "LASF", 4);
    out[24] = 1;  // version 1.2
    out[25] = 2;
    std::string system = "RailLoMer UTM " + utm_zone;
    std::memcpy(&out[26], system.data(), std::min<size_t>(system.size(), 32));
    std::memcpy(&out[58], "raillomer-server", 16);
    auto at = [&](size_t offset_bytes, auto value) {
      std::memcpy(&out[offset_bytes], &value, sizeof(value));
    };
    at(94, static_cast<uint16_t>(kLasHeader));   // header size
    at(96, static_cast<uint32_t>(kLasHeader));   // offset to the points
    at(100, static_cast<uint32_t>(0));           // variable-length records
    out[104] = 0;                                // point format 0
    at(105, static_cast<uint16_t>(kLasRecord));  // record length
    at(107, static_cast<uint32_t>(n));           // legacy point count
    at(111, static_cast<uint32_t>(n));           // points by return (first return)
    for (int a = 0; a < 3; ++a) at(131 + 8 * a, kLasScale);
    for (int a = 0; a < 3; ++a) at(155 + 8 * a, offset[a]);
    at(179, hi.x());
    at(187, lo.x());
    at(195, hi.y());
    at(203, lo.y());
    at(211, hi.z());
    at(219, lo.z());
    out.reserve(kLasHeader + kLasRecord * n);
    for (const ExportPoint& p : points) {
      for (int a = 0; a < 3; ++a)
        Put(&out, static_cast<int32_t>(std::lround((p.p[a] - offset[a]) / kLasScale)));
      Put(&out, static_cast<uint16_t>(p.intensity));
      Put(&out, static_cast<uint8_t>(1 | (1 << 3)));  // return 1 of 1
      Put(&out, static_cast<uint8_t>(0));             // classification: never classified
      Put(&out, static_cast<int8_t>(0));              // scan angle
      Put(&out, static_cast<uint8_t>(0));             // user data
      Put(&out, static_cast<uint16_t>(0));            // point source
    }
  }
  return out;
}

bool DecodeExport(const std::string& bytes,
                  ExportFormat format,
                  std::vector<ExportPoint>* points,
                  std::string* error) {
  points->clear();
  if (format == ExportFormat::kLas) {
    if (bytes.size() < kLasHeader || bytes.compare(0, 4, "LASF") != 0)
      return *error = "not a LAS file", false;
    const uint32_t offset = Get<uint32_t>(bytes, 96), n = Get<uint32_t>(bytes, 107);
    const uint16_t record = Get<uint16_t>(bytes, 105);
    if (record < kLasRecord || bytes.size() < offset + static_cast<size_t>(record) * n)
      return *error = "the LAS file is truncated", false;
    double scale[3], shift[3];
    for (int a = 0; a < 3; ++a) {
      scale[a] = Get<double>(bytes, 131 + 8 * a);
      shift[a] = Get<double>(bytes, 155 + 8 * a);
    }
    for (uint32_t i = 0; i < n; ++i) {
      const size_t at = offset + static_cast<size_t>(record) * i;
      ExportPoint p;
      for (int a = 0; a < 3; ++a) p.p[a] = shift[a] + scale[a] * Get<int32_t>(bytes, at + 4 * a);
      p.intensity = static_cast<uint8_t>(Get<uint16_t>(bytes, at + 12));
      points->push_back(p);
    }
    return true;
  }
  const std::string end = format == ExportFormat::kPly ? "end_header\n" : "DATA binary\n";
  const std::string count = format == ExportFormat::kPly ? "element vertex " : "\nPOINTS ";
  const size_t header = bytes.find(end), c = bytes.find(count);
  if (header == std::string::npos || c == std::string::npos || c > header)
    return *error = "no header", false;
  const size_t n = std::strtoull(bytes.c_str() + c + count.size(), nullptr, 10);
  const size_t data = header + end.size();
  if (bytes.size() != data + 25 * n) return *error = "the point data has the wrong size", false;
  for (size_t i = 0; i < n; ++i) {
    ExportPoint p;
    for (int a = 0; a < 3; ++a) p.p[a] = Get<double>(bytes, data + 25 * i + 8 * a);
    p.intensity = Get<uint8_t>(bytes, data + 25 * i + 24);
    points->push_back(p);
  }
  return true;
}

}  // namespace raillomer::mapstore
