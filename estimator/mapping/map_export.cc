#include "estimator/mapping/map_export.h"

#include "api/las.h"
#include "estimator/mapping/voxel_centroids.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace raillomer {

namespace {

constexpr size_t kRecordBytes = 3 * sizeof(double) + sizeof(float);
// Records converted to LAS per read of the temporary file.
constexpr size_t kLasChunkRecords = 65536;

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

std::unique_ptr<MapExporter> MapExporter::Open(const std::string& path,
                                               const MapExportOptions& options,
                                               std::string* error) {
  std::unique_ptr<MapExporter> e(new MapExporter());
  if (EndsWith(path, ".ply")) {
    e->format_ = Format::kPly;
  } else if (EndsWith(path, ".pcd")) {
    e->format_ = Format::kPcd;
  } else if (EndsWith(path, ".las")) {
    e->format_ = Format::kLas;
  } else {
    *error = "--map " + path + ": the file must end in .ply, .pcd or .las";
    return nullptr;
  }
  if (!(options.voxel_m >= 0.0)) {
    *error = "--map-voxel must be >= 0 m";
    return nullptr;
  }
  e->path_ = path;
  e->options_ = options;
  e->body_path_ = path + ".points.tmp";
  e->body_ = std::fopen(e->body_path_.c_str(), "wb");
  if (!e->body_) {
    *error = "cannot write " + e->body_path_ + " (next to the map " + path + ")";
    return nullptr;
  }
  return e;
}

MapExporter::~MapExporter() {
  if (body_) {
    std::fclose(body_);
    std::remove(body_path_.c_str());
  }
}

void MapExporter::Add(const api::Submap& s) {
  if (!body_) return;
  if (!have_frame_) {
    have_frame_ = true;
    georeferenced_ = s.georeferenced;
    utm_zone_ = s.utm_zone;
  } else if (s.georeferenced != georeferenced_ || s.utm_zone != utm_zone_) {
    ++skipped_submaps_;
    return;
  }
  auto inside = [&](const Eigen::Vector3d& p) {
    return !options_.has_box || (p.x() >= options_.box_min.x() && p.x() <= options_.box_max.x() &&
                                 p.y() >= options_.box_min.y() && p.y() <= options_.box_max.y());
  };
  char record[kRecordBytes];
  auto write = [&](const Eigen::Vector3d& p, float intensity) {
    std::memcpy(record, p.data(), 3 * sizeof(double));
    std::memcpy(record + 3 * sizeof(double), &intensity, sizeof(float));
    std::fwrite(record, 1, kRecordBytes, body_);
    bounds_.extend(p);
    ++points_;
  };
  if (options_.voxel_m <= 0.0) {
    for (size_t i = 0; i < s.points.size(); ++i) {
      const Eigen::Vector3d p = s.origin + s.points[i].cast<double>();
      if (inside(p)) write(p, i < s.intensities.size() ? s.intensities[i] : 0.f);
    }
    return;
  }
  // One point per voxel: the centroid of the submap's points in it, unless a recent submap
  // already filled that voxel.
  VoxelCentroids grid(options_.voxel_m);
  for (size_t i = 0; i < s.points.size(); ++i) {
    const Eigen::Vector3d p = s.origin + s.points[i].cast<double>();
    if (inside(p)) grid.Add(p, i < s.intensities.size() ? s.intensities[i] : 0.f);
  }
  std::unordered_set<uint64_t> mine;
  grid.ForEach([&](uint64_t key, const Eigen::Vector3d& p, float intensity) {
    mine.insert(key);
    for (const auto& set : recent_voxels_) {
      if (set.count(key)) return;
    }
    write(p, intensity);
  });
  recent_voxels_.push_back(std::move(mine));
  while (static_cast<int>(recent_voxels_.size()) > options_.remembered_submaps)
    recent_voxels_.pop_front();
}

namespace {

/// The PLY or PCD header of a map of `points` points in `frame`.
std::string TextHeader(bool ply, uint64_t points, const std::string& frame) {
  std::ostringstream h;
  if (ply) {
    h << "ply\nformat binary_little_endian 1.0\ncomment RailLoMer map in " << frame << "\n"
      << "element vertex " << points << "\nproperty double x\nproperty double y\n"
      << "property double z\nproperty float intensity\nend_header\n";
  } else {
    h << "# .PCD v0.7 - RailLoMer map in " << frame << "\nVERSION 0.7\nFIELDS x y z intensity\n"
      << "SIZE 8 8 8 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH " << points
      << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS " << points << "\nDATA binary\n";
  }
  return h.str();
}

/// Converts the body's records (x, y, z doubles and a float intensity) into LAS point records
/// relative to `offset`, a chunk at a time; returns how many it converted.
uint64_t CopyLasRecords(std::istream& body, std::ostream& out, const Eigen::Vector3d& offset) {
  uint64_t converted = 0;
  std::vector<char> chunk(kLasChunkRecords * kRecordBytes);
  std::string records;
  while (body.read(chunk.data(), static_cast<std::streamsize>(chunk.size())) || body.gcount() > 0) {
    records.clear();
    const size_t n = static_cast<size_t>(body.gcount()) / kRecordBytes;
    for (size_t i = 0; i < n; ++i) {
      Eigen::Vector3d p;
      float intensity = 0.f;
      std::memcpy(p.data(), &chunk[i * kRecordBytes], 3 * sizeof(double));
      std::memcpy(&intensity, &chunk[i * kRecordBytes + 3 * sizeof(double)], sizeof(float));
      const float clamped = std::isfinite(intensity) ? std::clamp(intensity, 0.f, 65535.f) : 0.f;
      api::las::AppendRecord(&records, p, offset, static_cast<uint16_t>(std::lround(clamped)));
    }
    out.write(records.data(), static_cast<std::streamsize>(records.size()));
    converted += n;
  }
  return converted;
}

}  // namespace

bool MapExporter::Close(std::string* error) {
  if (!body_) return true;
  const bool write_failed = std::ferror(body_) != 0;
  std::fclose(body_);
  body_ = nullptr;
  if (write_failed) {
    *error = "writing " + body_path_ + " failed (disk full?)";
    std::remove(body_path_.c_str());
    return false;
  }
  std::string header;
  Eigen::Vector3d las_offset = Eigen::Vector3d::Zero();
  if (format_ == Format::kLas) {
    api::las::Header las;
    las.points = points_;
    las.bounds = bounds_;
    if (georeferenced_) las.utm_zone = utm_zone_;
    las.software = "raillomer-estimator";
    las.created = std::time(nullptr);
    if (!api::las::EncodeHeader(las, &header, error)) {
      *error = "--map " + path_ + ": " + *error + "; write .ply or .pcd, or thin with --map-voxel";
      std::remove(body_path_.c_str());
      return false;
    }
    // The records are relative to an offset at the map's minimum corner, known only now.
    las_offset = api::las::OffsetOf(las);
  } else {
    const std::string frame =
        georeferenced_ ? "UTM zone " + utm_zone_ + " (easting, northing, ellipsoidal height)"
                       : std::string("the estimator's local odometry frame (not georeferenced)");
    header = TextHeader(format_ == Format::kPly, points_, frame);
  }
  const std::string tmp = path_ + ".tmp";
  const bool written = WriteMapFile(tmp, header, las_offset, error);
  std::remove(body_path_.c_str());
  if (!written) return false;
  std::error_code ec;
  std::filesystem::rename(tmp, path_, ec);
  if (ec) {
    *error = "cannot move " + tmp + " to " + path_ + ": " + ec.message();
    return false;
  }
  return true;
}

bool MapExporter::WriteMapFile(const std::string& tmp,
                               const std::string& header,
                               const Eigen::Vector3d& las_offset,
                               std::string* error) const {
  std::ofstream out(tmp, std::ios::binary);
  std::ifstream body(body_path_, std::ios::binary);
  if (!body) {
    *error = "cannot read back " + body_path_;
    return false;
  }
  out << header;
  if (format_ == Format::kLas) {
    const uint64_t converted = CopyLasRecords(body, out, las_offset);
    if (converted != points_) {
      *error = "read back " + std::to_string(converted) + " of the " + std::to_string(points_) +
               " points from " + body_path_;
      return false;
    }
  } else if (points_ > 0) {
    out << body.rdbuf();
  }
  if (!out) {
    *error = "cannot write " + tmp;
    return false;
  }
  return true;
}

namespace {

/// What a PLY or PCD header says of its points; `pos` is the first byte of the points once
/// `done`.
struct TextHeaderInfo {
  size_t pos = 0, count = 0;
  bool have_count = false, done = false;
};

/// Reads one header line (its first word `key`); returns why it is not the exporter's layout,
/// or an empty string.
std::string ReadHeaderLine(bool ply,
                           const std::string& key,
                           std::istringstream& ls,
                           std::string* comment,
                           TextHeaderInfo* h) {
  if (comment && (key == "comment" || key == "#")) {
    std::getline(ls, *comment);
  } else if (ply && key == "element") {
    std::string what;
    ls >> what >> h->count;
    h->have_count = what == "vertex";
  } else if (ply && key == "format") {
    std::string format;
    ls >> format;
    if (format != "binary_little_endian") return "not binary little-endian PLY";
  } else if (ply && key == "property") {
    std::string type, name;
    ls >> type >> name;
    if ((name == "intensity" && type != "float") || (name != "intensity" && type != "double"))
      return "property " + name + " is " + type + ", not the exporter's layout";
  } else if (!ply && key == "SIZE") {
    std::string rest;
    std::getline(ls, rest);
    if (rest != " 8 8 8 4") return "SIZE is '" + rest + "', not the exporter's 8 8 8 4";
  } else if (!ply && key == "POINTS") {
    ls >> h->count;
    h->have_count = true;
  } else if ((ply && key == "end_header") || (!ply && key == "DATA")) {
    h->done = true;
  }
  return "";
}

/// Reads a PLY or PCD header up to its last line; returns why it is bad, or an empty string.
std::string ReadTextHeader(const std::string& bytes, std::string* comment, TextHeaderInfo* h) {
  const bool ply = bytes.rfind("ply\n", 0) == 0;
  while (h->pos < bytes.size() && !h->done) {
    const size_t end = bytes.find('\n', h->pos);
    if (end == std::string::npos) break;
    const std::string line = bytes.substr(h->pos, end - h->pos);
    h->pos = end + 1;
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    const std::string why = ReadHeaderLine(ply, key, ls, comment, h);
    if (!why.empty()) return why;
  }
  if (!h->done || !h->have_count) return "no complete PLY or PCD header";
  return "";
}

}  // namespace

bool ReadMapFile(const std::string& path,
                 std::vector<Eigen::Vector3d>* points,
                 std::vector<float>* intensities,
                 std::string* comment,
                 std::string* error) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    *error = "cannot read " + path;
    return false;
  }
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto fail = [&](const std::string& m) {
    *error = path + ": " + m;
    return false;
  };
  if (bytes.rfind("LASF", 0) == 0) {
    api::las::Contents las;
    std::string why;
    if (!api::las::Decode(bytes, &las, &why)) return fail(why);
    *points = std::move(las.points);
    intensities->assign(las.intensities.begin(), las.intensities.end());
    if (comment) *comment = las.system_identifier;
    return true;
  }
  TextHeaderInfo h;
  const std::string why = ReadTextHeader(bytes, comment, &h);
  if (!why.empty()) return fail(why);
  if (bytes.size() - h.pos != h.count * kRecordBytes) {
    return fail("expected " + std::to_string(h.count) + " points (" +
                std::to_string(h.count * kRecordBytes) + " bytes), found " +
                std::to_string(bytes.size() - h.pos) + " bytes");
  }
  points->resize(h.count);
  intensities->resize(h.count);
  for (size_t i = 0; i < h.count; ++i) {
    const char* r = bytes.data() + h.pos + i * kRecordBytes;
    std::memcpy((*points)[i].data(), r, 3 * sizeof(double));
    std::memcpy(&(*intensities)[i], r + 3 * sizeof(double), sizeof(float));
  }
  return true;
}

}  // namespace raillomer
