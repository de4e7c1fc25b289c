#include "mapstore/export.h"

#include "api/las.h"
#include "api/raw_bytes.h"

#include <algorithm>
#include <cstring>
#include <ctime>
#include <sstream>

namespace raillomer::mapstore {

using api::AppendRaw;
using api::ReadRaw;

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

bool ExportEncoder::Begin(ExportFormat format,
                          size_t count,
                          const Eigen::AlignedBox3d& bounds,
                          const std::string& utm_zone,
                          std::string* out,
                          std::string* error) {
  format_ = format;
  if (format == ExportFormat::kLas) {
    api::las::Header header;
    header.points = count;
    header.bounds = bounds;
    header.utm_zone = utm_zone;
    header.software = "raillomer-server";
    header.created = std::time(nullptr);
    std::string why;
    if (!api::las::EncodeHeader(header, out, &why)) {
      if (error) *error = why;
      return false;
    }
    offset_ = api::las::OffsetOf(header);
    return true;
  }
  std::ostringstream h;
  if (format == ExportFormat::kPly) {
    h << "ply\nformat binary_little_endian 1.0\ncomment RailLoMer export, UTM zone " << utm_zone
      << "\nelement vertex " << count
      << "\nproperty double x\nproperty double y\nproperty double z\nproperty uchar "
         "intensity\nend_header\n";
  } else {
    h << "# .PCD v0.7 - RailLoMer export, UTM zone " << utm_zone
      << "\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 8 8 8 1\nTYPE F F F U\nCOUNT 1 1 1 1\n"
         "WIDTH "
      << count << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << count << "\nDATA binary\n";
  }
  *out += h.str();
  return true;
}

void ExportEncoder::Append(const ExportPoint& p, std::string* out) const {
  if (format_ == ExportFormat::kLas) return api::las::AppendRecord(out, p.p, offset_, p.intensity);
  // PLY and PCD: the same record, three doubles and a byte.
  AppendRaw(out, p.p.x());
  AppendRaw(out, p.p.y());
  AppendRaw(out, p.p.z());
  AppendRaw(out, p.intensity);
}

size_t ExportEncoder::RecordBytes() const {
  return format_ == ExportFormat::kLas ? api::las::kRecordBytes : 25;
}

std::string EncodeExport(const std::vector<ExportPoint>& points,
                         ExportFormat format,
                         const std::string& utm_zone,
                         std::string* error) {
  Eigen::AlignedBox3d bounds;
  for (const ExportPoint& p : points) bounds.extend(p.p);
  std::string out;
  ExportEncoder encoder;
  if (!encoder.Begin(format, points.size(), bounds, utm_zone, &out, error)) return std::string();
  out.reserve(out.size() + encoder.RecordBytes() * points.size());
  for (const ExportPoint& p : points) encoder.Append(p, &out);
  return out;
}

bool DecodeExport(const std::string& bytes,
                  ExportFormat format,
                  std::vector<ExportPoint>* points,
                  std::string* error) {
  points->clear();
  if (format == ExportFormat::kLas) {
    api::las::Contents las;
    if (!api::las::Decode(bytes, &las, error)) return false;
    points->resize(las.points.size());
    for (size_t i = 0; i < las.points.size(); ++i) {
      (*points)[i].p = las.points[i];
      (*points)[i].intensity = static_cast<uint8_t>(std::min<uint16_t>(las.intensities[i], 255));
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
    for (int a = 0; a < 3; ++a) p.p[a] = ReadRaw<double>(bytes, data + 25 * i + 8 * a);
    p.intensity = ReadRaw<uint8_t>(bytes, data + 25 * i + 24);
    points->push_back(p);
  }
  return true;
}

}  // namespace raillomer::mapstore
