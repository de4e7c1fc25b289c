#include "server/change_json.h"

#include <cmath>
#include <cstdio>

#include "server/api_json.h"

namespace raillomer::server {
namespace {

using nlohmann::json;

json Finite(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }
json Vec(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }
/// A run's or a change's id; null for none (0).
json Id(int64_t id) { return id == 0 ? json(nullptr) : json(id); }

/// The footprint as a closed WGS84 ring; the centre alone when it has none.
json Geometry(const mapstore::RunChange& c) {
  json ring = json::array();
  for (const Eigen::Vector2d& p : c.footprint_utm) {
    json lon_lat;
    if (!Wgs84(c.utm_zone, Eigen::Vector3d(p.x(), p.y(), c.centre_utm.z()), &lon_lat)) break;
    ring.push_back({lon_lat[0], lon_lat[1]});
  }
  if (ring.size() >= 3) {
    ring.push_back(ring.front());
    return {{"type", "Polygon"}, {"coordinates", {ring}}};
  }
  json centre;
  if (!Wgs84(c.utm_zone, c.centre_utm, &centre)) return nullptr;
  return {{"type", "Point"}, {"coordinates", centre}};
}

}  // namespace

json ChangeFeature(const mapstore::StoredChange& s) {
  const mapstore::RunChange& c = s.change;
  json centre = nullptr;
  Wgs84(c.utm_zone, c.centre_utm, &centre);
  json properties = {
      {"id", s.id},
      {"run", s.run_id},
      {"line", s.line},
      {"kind", mapstore::ToString(c.kind)},
      {"chainage_m", c.chainage_m},
      {"offset_m", c.offset_m},
      {"side", mapstore::SideOf(c)},
      {"offset_range_m", {c.offset_from_m, c.offset_to_m}},
      {"utm", Vec(c.centre_utm)},
      {"utm_zone", c.utm_zone},
      {"wgs84", centre},
      {"size_m", Vec(c.size_m)},
      {"height_above_rail_m", {c.height_above_rail_min_m, c.height_above_rail_max_m}},
      {"intrudes_envelope", c.intrudes_envelope},
      {"margin_m", Finite(c.margin_m)},
      {"vegetation_margin_m", Finite(c.vegetation_margin_m)},
      {"breaks_vegetation_rule",
       c.kind == mapstore::ChangeKind::kVegetation && c.vegetation_margin_m < 0.0},
      {"reference_run", s.reference_run},
      {"lod_m", c.lod_m},
      {"confidence", c.confidence},
      {"points", {{"reference", c.points_reference}, {"run", c.points_later}}},
      {"stretch", c.stretch},
      {"status", s.status},
      {"provisional", s.provisional},
      {"note", s.note},
      {"closed_by_run", Id(s.closed_by_run)},
      {"earlier_change", Id(s.earlier_change)},
      {"first_seen_run", s.first_seen_run},
      {"created_ns", s.created_ns},
      {"updated_ns", s.updated_ns},
      {"snapshot", "/api/v1/changes/" + std::to_string(s.id) + "/snapshot.png"}};
  if (c.kind == mapstore::ChangeKind::kMoved) {
    properties["moved_from_utm"] = Vec(c.moved_from_utm);
    properties["moved_m"] = c.moved_m;
  }
  return {{"type", "Feature"}, {"id", s.id}, {"geometry", Geometry(c)}, {"properties", properties}};
}

json DetectionJson(const mapstore::DetectionState& d, const std::string& reason) {
  json j = {{"status", d.status},
            {"reference_run", Id(d.reference_run)},
            {"registration_rms_m", d.stretches_compared > 0 ? json(d.registration_rms_m) : json()},
            {"rail_residual_m", Finite(d.rail_rms_m)},
            {"stretches_done", d.stretches_done},
            {"stretches_compared", d.stretches_compared},
            {"stretches_provisional", d.stretches_provisional},
            {"km_compared", d.km},
            {"compared_to_m", Finite(d.compared_to_m)},
            {"seconds", d.seconds}};
  if (!d.error.empty()) j["error"] = d.error;
  if (!reason.empty()) j["reason"] = reason;
  return j;
}

json ChangeCollection(const std::vector<mapstore::StoredChange>& changes, const json& detection) {
  json features = json::array();
  for (const mapstore::StoredChange& c : changes) features.push_back(ChangeFeature(c));
  return {{"type", "FeatureCollection"}, {"detection", detection}, {"features", features}};
}

namespace {

/// Free text as one CSV field: quoted, quotes doubled, and a leading = + - @ tab or carriage
/// return escaped with ' so that a spreadsheet shows the text instead of running a formula.
std::string CsvText(const std::string& text) {
  std::string out = "\"";
  if (!text.empty() && std::string("=+-@\t\r").find(text.front()) != std::string::npos) out += '\'';
  for (char ch : text) out += ch == '"' ? std::string("\"\"") : std::string(1, ch);
  return out + "\"";
}

}  // namespace

std::string ChangesCsv(const std::vector<mapstore::StoredChange>& changes) {
  std::string out =
      "id,run,reference_run,kind,chainage_m,offset_m,side,offset_from_m,offset_to_m,easting,"
      "northing,elevation,utm_zone,lon,lat,along_m,across_m,height_m,height_above_rail_min_m,"
      "height_above_rail_max_m,"
      "intrudes_envelope,margin_m,lod_m,confidence,provisional,first_seen_run,earlier_change,"
      "status,note\n";
  for (const mapstore::StoredChange& s : changes) {
    const mapstore::RunChange& c = s.change;
    json lon_lat = {nullptr, nullptr};
    Wgs84(c.utm_zone, c.centre_utm, &lon_lat);
    const std::string note = CsvText(s.note);
    char row[768];
    std::snprintf(row,
                  sizeof(row),
                  "%lld,%lld,%lld,%s,%.2f,%.2f,%s,%.2f,%.2f,%.3f,%.3f,%.3f,%s,%s,%s,%.2f,%.2f,%.2f,"
                  "%.2f,%.2f,"
                  "%s,%.2f,%.3f,%.2f,%s,%lld,%s,%s,",
                  static_cast<long long>(s.id),
                  static_cast<long long>(s.run_id),
                  static_cast<long long>(s.reference_run),
                  mapstore::ToString(c.kind),
                  c.chainage_m,
                  c.offset_m,
                  mapstore::SideOf(c),
                  c.offset_from_m,
                  c.offset_to_m,
                  c.centre_utm.x(),
                  c.centre_utm.y(),
                  c.centre_utm.z(),
                  c.utm_zone.c_str(),
                  lon_lat[0].dump().c_str(),
                  lon_lat[1].dump().c_str(),
                  c.size_m.x(),
                  c.size_m.y(),
                  c.size_m.z(),
                  c.height_above_rail_min_m,
                  c.height_above_rail_max_m,
                  c.intrudes_envelope ? "true" : "false",
                  c.margin_m,
                  c.lod_m,
                  c.confidence,
                  s.provisional ? "true" : "false",
                  static_cast<long long>(s.first_seen_run),
                  s.earlier_change != 0 ? std::to_string(s.earlier_change).c_str() : "",
                  s.status.c_str());
    out += row + note + "\n";
  }
  return out;
}

}  // namespace raillomer::server
