#include "server/api_json.h"

#include <algorithm>
#include <cstdint>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <GeographicLib/UTMUPS.hpp>

#include "api/trajectory.h"

namespace raillomer::server {

using nlohmann::json;

std::string JsonText(const json& j) {
  return j.dump(-1, ' ', false, json::error_handler_t::replace);
}

namespace {

/// A key as a message quotes it: JSON-escaped, at most 64 bytes of it.
std::string QuotedKey(const std::string& key) {
  std::string quoted = JsonText(key.substr(0, 64));
  if (key.size() > 64) quoted.insert(quoted.size() - 1, "...");
  return quoted;
}

/// The DOM parser's events, with each object's keys noted and checked as it closes: the first
/// key found named twice in one object is kept. nlohmann's SAX calls are resolved at compile
/// time, so hiding three of its DOM parser's members takes their place; unlike a parser
/// callback this costs next to nothing.
class KeyCheckingParser : public nlohmann::detail::json_sax_dom_parser<json> {
 public:
  explicit KeyCheckingParser(json* out) : json_sax_dom_parser(*out, true) {}

  bool start_object(std::size_t n) {
    if (keys_.size() <= open_) keys_.emplace_back();
    keys_[open_++].clear();  // the vectors are reused, object after object
    return json_sax_dom_parser::start_object(n);
  }
  bool key(std::string& name) {
    keys_[open_ - 1].push_back(name);
    return json_sax_dom_parser::key(name);
  }
  bool end_object() {
    if (twice_.empty()) twice_ = NamedTwice(&keys_[--open_]);
    return json_sax_dom_parser::end_object();
  }
  const std::string& twice() const { return twice_; }

 private:
  /// A key `keys` holds twice, or "" (`keys` may be reordered).
  static std::string NamedTwice(std::vector<std::string>* keys) {
    if (keys->size() > 16) {  // a large object: sorted, so no pair is compared twice
      std::sort(keys->begin(), keys->end());
      const auto same = std::adjacent_find(keys->begin(), keys->end());
      return same == keys->end() ? "" : *same;
    }
    for (auto k = keys->begin(); k != keys->end(); ++k)
      if (std::find(k + 1, keys->end(), *k) != keys->end()) return *k;
    return "";
  }

  std::vector<std::vector<std::string>> keys_;  // of each object open at this point
  size_t open_ = 0;
  std::string twice_;
};

}  // namespace

std::string ParseJson(const std::string& text, json* out) {
  KeyCheckingParser parser(out);
  try {
    json::sax_parse(text, &parser);
  } catch (const json::exception& e) {  // a parse error, or a number beyond a double
    // "[json.exception.parse_error.101] parse error at line 1, column 5: ...; last read: '...'":
    // where and what, without the tag or the bytes read (which need not be UTF-8).
    std::string what = e.what();
    const size_t tag = what.find("] ");
    if (tag != std::string::npos) what = what.substr(tag + 2);
    return what.substr(0, what.find("; last read"));
  }
  if (!parser.twice().empty())
    return "member " + QuotedKey(parser.twice()) + " appears twice in one object";
  return "";
}

std::string UnknownMember(const json& object,
                          std::initializer_list<const char*> known,
                          std::initializer_list<const char*> ignored) {
  const auto among = [](const std::string& key, std::initializer_list<const char*> names) {
    return std::any_of(names.begin(), names.end(), [&](const char* n) { return key == n; });
  };
  for (const auto& [key, value] : object.items()) {
    if (among(key, known) || among(key, ignored)) continue;
    std::string names;
    for (const char* n : known) names += (names.empty() ? "" : ", ") + std::string(n);
    return "unknown member " + QuotedKey(key) + " (" + names + ")";
  }
  return "";
}

json RunJson(const mapstore::RunInfo& r) {
  json j = {{"id", r.id},
            {"line", r.line},
            {"vehicle", r.vehicle},
            {"status", r.status},
            {"start_ns", r.start_ns},
            {"utm_zone", r.utm_zone.empty() ? json(nullptr) : json(r.utm_zone)},
            {"submaps", r.submaps},
            {"submaps_lost", r.submaps_lost},
            {"points", r.points},
            {"poses", r.poses},
            {"created_ns", r.created_ns}};
  j["end_ns"] = r.status == "finished" ? json(r.end_ns) : json(nullptr);
  return j;
}

json TileJson(const mapstore::TileInfo& t) {
  return {{"level", t.key.level},
          {"ix", t.key.ix},
          {"iy", t.key.iy},
          {"utm_zone", t.utm_zone},
          {"origin", {t.origin.x(), t.origin.y(), t.origin.z()}},
          {"points", t.points},
          {"bytes", t.bytes},
          {"version", t.version},
          {"etag", t.etag},
          {"max_error_m", t.max_error_m},
          {"url", "/api/v1/runs/" + std::to_string(t.run_id) + "/tiles/" + t.key.ToString()}};
}

json LineJson(const mapstore::LineInfo& l) {
  return {{"name", l.name},
          {"reference_run", l.reference_run == 0 ? json(nullptr) : json(l.reference_run)},
          {"utm_zone", l.utm_zone.empty() ? json(nullptr) : json(l.utm_zone)},
          {"length_m", l.length_m},
          {"chainage_offset_m", l.chainage_offset_m},
          {"km_posts", l.km_posts},
          {"runs", l.runs}};
}

bool Wgs84(const std::string& zone, const Eigen::Vector3d& p, json* out) {
  int number = 0;
  bool north = true;
  if (!api::ParseUtmZoneName(zone, &number, &north)) return false;
  double lat = 0.0, lon = 0.0;
  try {
    GeographicLib::UTMUPS::Reverse(number, north, p.x(), p.y(), lat, lon);
  } catch (const std::exception&) {
    return false;
  }
  *out = {lon, lat, p.z()};
  return true;
}

json PoiJson(const mapstore::Poi& p) {
  json properties = json::parse(p.properties_json, nullptr, false);
  if (properties.is_discarded()) properties = json::object();
  return {{"id", p.id},
          {"line", p.line.empty() ? json(nullptr) : json(p.line)},
          {"kind", p.kind},
          {"name", p.name},
          {"utm_zone", p.utm_zone},
          {"position", {p.p.x(), p.p.y(), p.p.z()}},
          {"properties", properties},
          {"created_ns", p.created_ns},
          {"updated_ns", p.updated_ns}};
}

namespace {

bool Numbers(const json& v, size_t n) {
  if (!v.is_array() || v.size() != n) return false;
  for (const auto& x : v)
    if (!x.is_number()) return false;
  return true;
}

/// A POI's properties nest at most this deep: a reader's JSON parser (Python's) may give up on
/// much deeper ones.
constexpr int kMaxPropertyDepth = 16;

/// How deep objects and arrays nest in `v` (1 for a flat object), walked without recursion.
int DepthOf(const json& v) {
  int deepest = 0;
  std::vector<std::pair<const json*, int>> open = {{&v, 1}};
  while (!open.empty()) {
    const auto [at, depth] = open.back();
    open.pop_back();
    if (!at->is_structured()) continue;
    deepest = std::max(deepest, depth);
    for (const json& child : *at) open.emplace_back(&child, depth + 1);
  }
  return deepest;
}

}  // namespace

bool ParsePoi(const json& j, mapstore::Poi* p, std::string* error) {
  *error = UnknownMember(j,
                         {"kind", "utm_zone", "position", "name", "line", "properties"},
                         {"id", "created_ns", "updated_ns"});
  if (!error->empty()) return false;
  if (!j.contains("kind") || !j["kind"].is_string() || !j.contains("utm_zone") ||
      !j["utm_zone"].is_string() || !j.contains("position") || !Numbers(j["position"], 3)) {
    *error =
        "a point of interest needs kind (string), utm_zone (string) and position [easting, "
        "northing, height]";
    return false;
  }
  if ((j.contains("name") && !j["name"].is_string()) ||
      (j.contains("line") && !j["line"].is_string() && !j["line"].is_null()) ||
      (j.contains("properties") && !j["properties"].is_object())) {
    *error = "name and line must be strings and properties an object";
    return false;
  }
  if (j.contains("properties") && DepthOf(j["properties"]) > kMaxPropertyDepth) {
    *error = "properties may nest at most " + std::to_string(kMaxPropertyDepth) + " levels deep";
    return false;
  }
  p->kind = j["kind"];
  p->utm_zone = j["utm_zone"];
  p->name = j.value("name", std::string());
  p->line = j.contains("line") && j["line"].is_string() ? j["line"].get<std::string>() : "";
  p->p = Eigen::Vector3d(j["position"][0].get<double>(),
                         j["position"][1].get<double>(),
                         j["position"][2].get<double>());
  p->properties_json = j.contains("properties") ? j["properties"].dump() : "{}";
  return true;
}

bool ParsePose(const json& j, api::StreamPose* p, std::string* error) {
  if (!j.is_object() || !j.contains("sequence") || !j["sequence"].is_number_unsigned() ||
      !j.contains("stamp_ns") || !j["stamp_ns"].is_number_integer() || !j.contains("p") ||
      !Numbers(j["p"], 3) || !j.contains("q") || !Numbers(j["q"], 4)) {
    *error = "a pose needs sequence (unsigned), stamp_ns (integer), p [x, y, z] and q [x, y, z, w]";
    return false;
  }
  p->sequence = j["sequence"].get<uint64_t>();
  if (p->sequence > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) {
    *error = "pose sequence " + std::to_string(p->sequence) + " is beyond 2^63 - 1";
    return false;
  }
  *error = UnknownMember(j, {"sequence", "stamp_ns", "georeferenced", "utm_zone", "p", "q"});
  if (!error->empty()) {
    *error = "pose " + std::to_string(p->sequence) + ": " + *error;
    return false;
  }
  p->stamp_ns = j["stamp_ns"].get<int64_t>();
  if ((j.contains("georeferenced") && !j["georeferenced"].is_boolean()) ||
      (j.contains("utm_zone") && !j["utm_zone"].is_string())) {
    *error = "a pose's georeferenced must be true or false and its utm_zone a string";
    return false;
  }
  p->georeferenced = j.value("georeferenced", false);
  p->utm_zone = j.value("utm_zone", std::string());
  p->p = Eigen::Vector3d(j["p"][0].get<double>(), j["p"][1].get<double>(), j["p"][2].get<double>());
  p->q = Eigen::Quaterniond(j["q"][3].get<double>(),
                            j["q"][0].get<double>(),
                            j["q"][1].get<double>(),
                            j["q"][2].get<double>());
  if (p->georeferenced) {
    int zone = 0;
    bool north = true;
    if (!api::ParseUtmZoneName(p->utm_zone, &zone, &north)) {
      *error = "pose " + std::to_string(p->sequence) + ": bad utm_zone '" + p->utm_zone + "'";
      return false;
    }
  }
  return true;
}

bool FitsInt64(const json& v) {
  return v.is_number_integer() &&
         !(v.is_number_unsigned() && v.get<uint64_t>() > static_cast<uint64_t>(INT64_MAX));
}

bool ReadInt(const json& j, const char* key, int64_t* value, std::string* error) {
  if (!j.contains(key)) return true;
  if (!FitsInt64(j[key])) {
    *error = std::string(key) + " must be an integer within 64 bits";
    return false;
  }
  *value = j[key].get<int64_t>();
  return true;
}

}  // namespace raillomer::server
