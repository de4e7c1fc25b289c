#pragma once

#include <cstdint>
#include <cstdio>
#include <deque>
#include <memory>
#include <string>
#include <unordered_set>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "api/stream.h"

namespace raillomer {

struct MapExportOptions {
  /// Points are thinned to one (the centroid) per voxel of this size; 0 keeps every point.
  double voxel_m = 0.1;
  /// Keep only points inside this horizontal box (world / UTM easting and northing).
  bool has_box = false;
  Eigen::Vector2d box_min = Eigen::Vector2d::Zero(), box_max = Eigen::Vector2d::Zero();
  /// Voxels of this many recent submaps are remembered so that overlapping submaps do not
  /// repeat a voxel; older ones are forgotten, which keeps memory independent of run length.
  int remembered_submaps = 24;
};

/// Writes a global map from submaps as they come, in the format its extension names: binary
/// little-endian PLY or PCD with double x y z (UTM easting, northing, ellipsoidal height when
/// georeferenced: exact to well below a millimetre) and float intensity, or LAS 1.2 (1 mm, the
/// intensity rounded, the UTM zone as an EPSG code; see api/las.h). Points stream to a temporary
/// file; Close writes the header with the count (and for LAS the bounds) and moves the file into
/// place.
class MapExporter {
 public:
  /// Nullptr with a message if the extension is not .ply / .pcd / .las or the file cannot be
  /// written.
  static std::unique_ptr<MapExporter> Open(const std::string& path,
                                           const MapExportOptions& options,
                                           std::string* error);
  ~MapExporter();
  /// A submap in another frame than the first one (local versus UTM) is skipped and counted.
  void Add(const api::Submap& submap);
  bool Close(std::string* error);
  uint64_t points() const { return points_; }
  uint64_t skipped_submaps() const { return skipped_submaps_; }

 private:
  MapExporter() = default;
  /// Writes `header` and the body's points (as LAS records about `las_offset` for LAS) to `tmp`.
  bool WriteMapFile(const std::string& tmp,
                    const std::string& header,
                    const Eigen::Vector3d& las_offset,
                    std::string* error) const;
  std::string path_, body_path_;
  enum class Format { kPly, kPcd, kLas } format_ = Format::kPly;
  MapExportOptions options_;
  std::FILE* body_ = nullptr;
  uint64_t points_ = 0, skipped_submaps_ = 0;
  Eigen::AlignedBox3d bounds_;  ///< of the points written
  bool have_frame_ = false, georeferenced_ = false;
  std::string utm_zone_;
  std::deque<std::unordered_set<uint64_t>> recent_voxels_;
};

/// Reads a map written by MapExporter (any of its formats; a LAS file's system identifier is its
/// comment, its intensities come back rounded). False with a message naming the file.
bool ReadMapFile(const std::string& path,
                 std::vector<Eigen::Vector3d>* points,
                 std::vector<float>* intensities,
                 std::string* comment,
                 std::string* error);

}  // namespace raillomer
