#pragma once

#include <cmath>
#include <cstdint>
#include <string>

#include <Eigen/Core>

#include "mapstore/tile_codec.h"

namespace raillomer::mapstore {

/// A tile: square cells of a UTM zone's grid at a level of detail. Level 0 is the full detail;
/// each level up doubles the tile's side and the voxel a point stands for.
struct TileKey {
  int level = 0;
  int64_t ix = 0, iy = 0;  ///< floor(easting / side), floor(northing / side)
  bool operator==(const TileKey& o) const { return level == o.level && ix == o.ix && iy == o.iy; }
  bool operator<(const TileKey& o) const {
    if (level != o.level) return level < o.level;
    if (ix != o.ix) return ix < o.ix;
    return iy < o.iy;
  }
  std::string ToString() const {
    return std::to_string(level) + "/" + std::to_string(ix) + "/" + std::to_string(iy);
  }
};

struct TileKeyHash {
  size_t operator()(const TileKey& k) const {
    return std::hash<int64_t>()((k.ix * 73856093) ^ (k.iy * 19349663) ^ (k.level * 83492791));
  }
};

/// The tiling of every run: tile side and voxel at level 0, the number of levels, and the
/// largest position error the level-0 quantisation may make.
struct TileGrid {
  /// 32 m: about 30 000 points (60 KB) per level-0 tile on a corridor; smaller tiles serve
  /// faster and merge faster (ingest 2.6 against 2.2 million points per second at 64 m).
  double tile_m = 32.0;
  double voxel_m = 0.1;
  int levels = 4;
  double max_error_m = 0.005;

  bool IsValid(std::string* error) const {
    if (!(tile_m >= 8.0 && tile_m <= 4096.0)) return *error = "tile_m must be in [8, 4096]", false;
    if (!(voxel_m >= 0.01 && voxel_m <= tile_m / 16.0))
      return *error = "voxel_m must be in [0.01, tile_m / 16]", false;
    if (levels < 1 || levels > 12) return *error = "levels must be in [1, 12]", false;
    if (!(max_error_m >= 0.0001 && max_error_m <= voxel_m))
      return *error = "max_error_m must be in [0.0001, voxel_m]", false;
    return true;
  }
  double TileM(int level) const { return std::ldexp(tile_m, level); }
  double VoxelM(int level) const { return std::ldexp(voxel_m, level); }
  TileKey KeyOf(const Eigen::Vector3d& p_utm, int level) const {
    const double side = TileM(level);
    return {level,
            static_cast<int64_t>(std::floor(p_utm.x() / side)),
            static_cast<int64_t>(std::floor(p_utm.y() / side))};
  }
  /// The tile's south-west corner (UTM) at height z_ref_m: the tile frame's origin.
  Eigen::Vector3d Origin(const TileKey& key, double z_ref_m) const {
    const double side = TileM(key.level);
    return {static_cast<double>(key.ix) * side, static_cast<double>(key.iy) * side, z_ref_m};
  }
  /// The quantisation grid of a tile at `level` (tile frame): a cube twice the tile's side,
  /// from half a side below the tile's reference height, so the tile holds structures up to
  /// 1.5 sides above it; the error scales with the level, as the voxel does.
  TileQuantization Quantization(int level) const {
    TileQuantization q;
    const double side = TileM(level);
    q.range_m = static_cast<float>(2.0 * side);
    q.grid_origin = Eigen::Vector3f(0.0f, 0.0f, static_cast<float>(-0.5 * side));
    q.bits = TileQuantization::BitsFor(2.0 * tile_m, max_error_m);
    return q;
  }
};

}  // namespace raillomer::mapstore
