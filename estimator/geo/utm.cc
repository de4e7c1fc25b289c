#include "estimator/geo/utm.h"

#include <GeographicLib/UTMUPS.hpp>

#include "api/trajectory.h"

namespace raillomer::geo {

std::string UtmZone::Name() const { return std::to_string(zone) + (north ? "N" : "S"); }

bool ParseZone(const std::string& text, UtmZone* zone) {
  return api::ParseUtmZoneName(text, &zone->zone, &zone->north);
}

UtmZone StandardZone(double latitude_deg, double longitude_deg) {
  UtmZone zone;
  zone.zone = GeographicLib::UTMUPS::StandardZone(latitude_deg, longitude_deg);
  zone.north = latitude_deg >= 0.0;
  return zone;
}

Eigen::Vector2d GeographicToUtm(const UtmZone& zone, double latitude_deg, double longitude_deg) {
  int zone_out = 0;
  bool north_out = true;
  double x = 0.0, y = 0.0;
  GeographicLib::UTMUPS::Forward(latitude_deg, longitude_deg, zone_out, north_out, x, y, zone.zone);
  // Forward reports the hemisphere of the latitude; shift the northing if the zone says otherwise.
  if (north_out != zone.north) y += zone.north ? -10000000.0 : 10000000.0;
  return {x, y};
}

Eigen::Vector2d UtmToGeographic(const UtmZone& zone, double easting_m, double northing_m) {
  double lat = 0.0, lon = 0.0;
  GeographicLib::UTMUPS::Reverse(zone.zone, zone.north, easting_m, northing_m, lat, lon);
  return {lat, lon};
}

}  // namespace raillomer::geo
