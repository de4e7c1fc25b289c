#pragma once

// LAS 1.2 (ASPRS), point format 0 at 1 mm, for every program that writes or reads map files: the
// server's exports and the estimator's global map.

#include <cstddef>
#include <cstdint>
#include <ctime>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer::api {

/// For writers that stream their points: the records are relative to an offset, and the
/// header, which needs the count and the bounds, is encoded once they are known.
namespace las {

constexpr double kScale = 0.001;     ///< 1 mm on every axis
constexpr size_t kRecordBytes = 20;  ///< point format 0

/// What the header says of the points.
struct Header {
  uint64_t points = 0;
  Eigen::AlignedBox3d bounds;  ///< of the points (extend it with each); empty for none
  /// "50N": the system identifier names it and the GeoTIFF key record gives its EPSG code
  /// (WGS 84 / UTM, 326zz north, 327zz south), so GIS tools place the points. Empty for a
  /// local frame, a user-defined system (32767) in metres.
  std::string utm_zone;
  std::string software = "raillomer";  ///< generating software (up to 32 characters)
  std::time_t created = 0;             ///< the file's creation day (UTC); 0 leaves it unset
};

/// The offset that the records of the header's points are relative to: their minimum corner,
/// whole metres.
Eigen::Vector3d OffsetOf(const Header& header);
/// The EPSG code of WGS 84 / UTM for "50N" or "33S"; 0 if the text is no UTM zone.
int EpsgOfUtmZone(const std::string& utm_zone);
/// The public header (bounds as the points are stored, to the millimetre) and the GeoTIFF key
/// record. False with a message if LAS 1.2 cannot hold
/// the points (over 2^32 - 1 of them, or farther than 2^31 mm from the offset).
bool EncodeHeader(const Header& header, std::string* out, std::string* error);
/// Appends one point record (first of one return, never classified).
void AppendRecord(std::string* out,
                  const Eigen::Vector3d& p,
                  const Eigen::Vector3d& offset,
                  uint16_t intensity);

/// A whole LAS file read back: its points, intensities, system identifier, the projected
/// system's EPSG code from its GeoTIFF key record (0 without one, 32767 user-defined) and its
/// creation day. False with a message otherwise.
struct Contents {
  std::vector<Eigen::Vector3d> points;
  std::vector<uint16_t> intensities;
  std::string system_identifier;
  int epsg = 0;
  int creation_year = 0, creation_day = 0;
  Eigen::Vector3d min = Eigen::Vector3d::Zero(), max = Eigen::Vector3d::Zero();  ///< header bounds
};
bool Decode(const std::string& bytes, Contents* contents, std::string* error);

}  // namespace las

}  // namespace raillomer::api
