#pragma once

#include <string>

#include <Eigen/Core>

namespace raillomer::geo {

/// A UTM zone and hemisphere, e.g. 50N.
struct UtmZone {
  int zone = 0;  ///< 1..60
  bool north = true;
  /// "50N" style name, as in the first line of a ground-truth TUM file.
  std::string Name() const;
};

/// Parses "50N" / "33S" (zone 1-60, hemisphere N or S); false on anything else.
bool ParseZone(const std::string& text, UtmZone* zone);

/// The standard UTM zone of a WGS84 position.
UtmZone StandardZone(double latitude_deg, double longitude_deg);

/// WGS84 (lat, lon in degrees) -> UTM (easting, northing in metres) in the given zone.
Eigen::Vector2d GeographicToUtm(const UtmZone& zone, double latitude_deg, double longitude_deg);

/// UTM (easting, northing) in the given zone -> WGS84 (latitude, longitude) in degrees.
Eigen::Vector2d UtmToGeographic(const UtmZone& zone, double easting_m, double northing_m);

}  // namespace raillomer::geo
