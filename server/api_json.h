#pragma once

// The API's JSON: stored records as JSON objects, and request bodies parsed into records with
// a message naming what is wrong. nlohmann/json stays out of the other server headers.

#include <initializer_list>
#include <string>

#include <nlohmann/json.hpp>

#include "api/stream.h"
#include "mapstore/map_store.h"

namespace raillomer::server {

nlohmann::json RunJson(const mapstore::RunInfo& run);
nlohmann::json TileJson(const mapstore::TileInfo& tile);
nlohmann::json LineJson(const mapstore::LineInfo& line);
nlohmann::json PoiJson(const mapstore::Poi& poi);

/// `j` as JSON text; bytes of its strings that are not UTF-8 (a client's) are replaced, never
/// thrown on.
std::string JsonText(const nlohmann::json& j);

/// `text` as JSON into `out`; what is wrong with it, or "". A member named twice in one object
/// is wrong: a plain parse keeps the last, so a client's first value would vanish unsaid.
std::string ParseJson(const std::string& text, nlohmann::json* out);

/// The first member of `object` not among `known`, as a message listing those; "" if none.
/// `ignored` are members a client may send back as it read them (id, timestamps): allowed,
/// never written.
std::string UnknownMember(const nlohmann::json& object,
                          std::initializer_list<const char*> known,
                          std::initializer_list<const char*> ignored = {});

/// UTM of `zone` to WGS84 [lon, lat, h]; false outside the zone's range.
bool Wgs84(const std::string& zone, const Eigen::Vector3d& p_utm, nlohmann::json* lon_lat_h);

/// A point of interest from a JSON body: kind, position [easting, northing, height], utm_zone,
/// and optionally name, line and properties (an object).
bool ParsePoi(const nlohmann::json& j, mapstore::Poi* poi, std::string* error);

/// A pose of a batch: {"sequence", "stamp_ns", "georeferenced", "utm_zone", "p": [x, y, z],
/// "q": [x, y, z, w]}; the sequence is a whole number the index can hold (below 2^63).
bool ParsePose(const nlohmann::json& j, api::StreamPose* pose, std::string* error);

/// Whether a JSON value is an integer an int64_t holds (an unsigned one beyond it would wrap).
bool FitsInt64(const nlohmann::json& v);
/// An optional integer member of an object: left as it is when absent.
bool ReadInt(const nlohmann::json& j, const char* key, int64_t* value, std::string* error);

}  // namespace raillomer::server
