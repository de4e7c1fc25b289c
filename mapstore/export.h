#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer::mapstore {

enum class ExportFormat { kPly, kPcd, kLas };

/// "ply", "pcd" or "las"; false for anything else.
bool ParseExportFormat(const std::string& name, ExportFormat* format);
const char* ExtensionOf(ExportFormat format);

struct ExportPoint {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();  ///< UTM
  uint8_t intensity = 0;
};

/// Writes an export file piece by piece: the header, which needs the count and (LAS) the
/// bounds up front, then the points in as many calls as suit the writer.
class ExportEncoder {
 public:
  /// The header of a file of `count` points within `bounds` in `utm_zone`; false with the
  /// reason when the format cannot hold them (see api::las::EncodeHeader).
  bool Begin(ExportFormat format,
             size_t count,
             const Eigen::AlignedBox3d& bounds,
             const std::string& utm_zone,
             std::string* out,
             std::string* error);
  /// Appends one point's record.
  void Append(const ExportPoint& point, std::string* out) const;
  /// The bytes of one point's record.
  size_t RecordBytes() const;

 private:
  ExportFormat format_ = ExportFormat::kPly;
  Eigen::Vector3d offset_ = Eigen::Vector3d::Zero();  ///< LAS records are relative to it
};

/// The points as a file: binary PLY (double x y z, uchar intensity), binary PCD (x y z as F 8,
/// intensity as U 1) or LAS 1.2 (point format 0, 1 mm scale, the offset at the points' minimum
/// corner, the UTM zone in the header's system identifier and as a GeoTIFF key). Coordinates are
/// UTM in every case, so every tool places them without a transform. Empty, with the reason in
/// `error` if given, when LAS 1.2 cannot hold the points (see api::las::EncodeHeader).
std::string EncodeExport(const std::vector<ExportPoint>& points,
                         ExportFormat format,
                         const std::string& utm_zone,
                         std::string* error = nullptr);

/// Reads back what EncodeExport wrote (for tests and tools); false with a message otherwise.
bool DecodeExport(const std::string& bytes,
                  ExportFormat format,
                  std::vector<ExportPoint>* points,
                  std::string* error);

}  // namespace raillomer::mapstore
