#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace raillomer::mapstore {

/// How a tile's positions are quantised: a fixed grid per tile, so a tile decoded, merged with
/// new points and encoded again loses nothing more (the decoded points sit on the grid already).
/// Positions are offsets from the tile's double-precision origin; the grid covers the cube
/// [0, range_m)^3 from `grid_origin` (tile frame) with 2^bits - 1 steps per axis.
struct TileQuantization {
  Eigen::Vector3f grid_origin = Eigen::Vector3f::Zero();
  float range_m = 128.0f;
  int bits = 14;
  /// The largest position error the grid makes: half a step (and float rounding).
  double MaxErrorM() const;
  /// The fewest bits that keep the error at most max_error_m over range_m (at most 30).
  static int BitsFor(double range_m, double max_error_m);
  /// True if `p` (tile frame) lies on the grid's cube.
  bool Covers(const Eigen::Vector3f& p) const;
};

/// A tile's points.
struct TilePoints {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  ///< UTM, metres: the tile frame's origin
  std::string utm_zone;                              ///< "50N"
  std::vector<Eigen::Vector3f> points;               ///< offsets from origin
  std::vector<uint8_t> intensities;                  ///< one per point
};

/// Draco bytes of a tile: quantised positions (POSITION, float, 3) and intensity (GENERIC,
/// uint8, 1), with the tile origin ("raillomer_origin", three doubles), the zone
/// ("raillomer_utm_zone") and the grid's maximum error ("raillomer_max_error_m") as metadata,
/// so Google's decoder (and `draco_decoder`) reads it as an ordinary point cloud. Points off the
/// grid's cube must be dropped before (TileQuantization::Covers). `speed` is Draco's encoding
/// speed (0 smallest, 10 fastest); the kd-tree coder needs at most 9.
bool EncodeTile(const TilePoints& tile,
                const TileQuantization& quantization,
                int speed,
                std::string* bytes,
                std::string* error);

/// Decodes EncodeTile's bytes; false with a message if they are not a RailLoMer tile.
/// `quantization` (if given) gets the tile's grid back.
bool DecodeTile(const std::string& bytes,
                TilePoints* tile,
                std::string* error,
                TileQuantization* quantization = nullptr);

}  // namespace raillomer::mapstore
