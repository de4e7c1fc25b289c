#include "server/routes.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>

#include "api/clock.h"
#include "api/trajectory.h"
#include "mapstore/schema.h"
#include "server/api_json.h"
#include "server/http_parse.h"
#include "server/route_util.h"

namespace raillomer::server {
namespace {

using nlohmann::json;

/// bbox=min_easting,min_northing,max_easting,max_northing; false (and a 400) if malformed.
bool BoxParam(const HttpRequest& req, HttpResponse& res, Eigen::AlignedBox2d* box) {
  const std::string text = req.Param("bbox");
  double v[4];
  size_t start = 0;
  for (int i = 0; i < 4; ++i) {
    const size_t end = i < 3 ? text.find(',', start) : text.size();
    if (end == std::string::npos || !ParseFiniteDouble(text.substr(start, end - start), &v[i])) {
      res.SetError(400,
                   "invalid",
                   "bbox must be min_easting,min_northing,max_easting,max_northing (numbers)");
      return false;
    }
    start = end + 1;
  }
  if (v[0] > v[2] || v[1] > v[3]) {
    res.SetError(
        400, "invalid", "bbox's minimum easting and northing must not exceed its maximum ones");
    return false;
  }
  *box = Eigen::AlignedBox2d(Eigen::Vector2d(v[0], v[1]), Eigen::Vector2d(v[2], v[3]));
  return true;
}

using api::NowNs;

/// Answers a GET of one stored record by the path's id: `get(id, &record)`, sent as JSON by
/// `to_json`, or the store's error.
template <typename Record, typename Get, typename ToJson>
void SendOne(const HttpRequest& req, HttpResponse& res, const char* what, Get get, ToJson to_json) {
  int64_t id = 0;
  if (!PathId(req, res, &id, what)) return;
  Record record;
  const mapstore::Result r = get(id, &record);
  if (!r) return SendResult(res, r);
  SendJson(res, to_json(record));
}

/// The API's handlers over the context's store, hub and metrics.
class Api {
 public:
  explicit Api(const ApiContext& c) : c_(c), store_(*c.store), hub_(*c.hub) {}

  void Health(const HttpRequest&, HttpResponse& res) {
    SendJson(res,
             {{"status", "ok"},
              {"schema_version", mapstore::LatestSchemaVersion()},
              {"runs", store_.ListRuns().size()}});
  }

  void MetricsText(const HttpRequest&, HttpResponse& res) {
    std::string out;
    c_.metrics->Write(&out);
    const mapstore::StoreStats s = store_.stats();
    const HubStats h = hub_.stats();
    const HttpFrontStats f = c_.front_stats();
    auto metric =
        [&](const char* name, const char* help, uint64_t v, const char* type = "counter") {
          out += std::string("# HELP ") + name + " " + help + "\n# TYPE " + name + " " + type +
                 "\n" + name + " " + std::to_string(v) + "\n";
        };
    metric("raillomer_submaps_stored_total", "Submaps stored.", s.submaps_stored);
    metric("raillomer_submaps_duplicate_total",
           "Submaps sent again (nothing changed).",
           s.submaps_duplicate);
    metric("raillomer_submaps_rejected_total", "Submaps refused.", s.submaps_rejected);
    metric("raillomer_submaps_recovered_total",
           "Submaps merged again from their payloads on opening, after a crash.",
           s.submaps_recovered);
    metric("raillomer_submaps_lost_total",
           "Submaps found without their payload on opening (acknowledged, then lost).",
           s.submaps_lost);
    metric("raillomer_submaps_lost",
           "Submaps of every run whose payload is lost and not sent again.",
           s.submaps_lost_stored,
           "gauge");
    metric("raillomer_points_ingested_total", "Points of stored submaps.", s.points_ingested);
    metric("raillomer_poses_stored_total", "Poses stored.", s.poses_stored);
    metric("raillomer_poses_duplicate_total",
           "Poses sent again (stored before: nothing changed).",
           s.poses_duplicate);
    metric("raillomer_tiles_written_total", "Tiles encoded and written.", s.tiles_written);
    metric("raillomer_hot_points", "Points in tiles held in memory.", s.hot_points, "gauge");
    metric("raillomer_hot_tiles", "Tiles held in memory.", s.hot_tiles, "gauge");
    metric("raillomer_live_clients", "WebSocket clients connected.", h.clients, "gauge");
    metric("raillomer_live_messages_sent_total", "Live messages written.", h.sent);
    metric("raillomer_live_messages_dropped_total",
           "Live messages dropped for slow clients.",
           h.dropped);
    metric("raillomer_live_refused_total", "Live connections refused.", h.refused);
    metric("raillomer_http_connections", "HTTP connections open.", f.connections_open, "gauge");
    metric("raillomer_http_connections_total", "HTTP connections accepted.", f.connections_total);
    metric("raillomer_http_refused_busy_total",
           "HTTP connections refused over max_connections.",
           f.refused_busy);
    metric("raillomer_http_header_timeouts_total",
           "HTTP connections closed waiting for a request header (header_timeout_s).",
           f.header_timeouts);
    metric("raillomer_http_io_timeouts_total",
           "HTTP connections closed waiting for a body or a slow reader (request_timeout_s).",
           f.body_timeouts);
    res.SetContent(std::move(out), "text/plain; version=0.0.4");
  }

  void Info(const HttpRequest&, HttpResponse& res) {
    const mapstore::TileGrid& g = store_.options().grid;
    const mapstore::ClearanceOptions& k = c_.config->changes.comparison.clearance;
    json outline = json::array();
    for (const Eigen::Vector2d& corner : k.gauge_outline)
      outline.push_back({corner.x(), corner.y()});
    SendJson(res,
             {{"name", "raillomer-server"},
              {"api", "v1"},
              {"schema_version", mapstore::LatestSchemaVersion()},
              {"ws_port", hub_.port()},
              {"ws_path", "/live"},
              {"tiles",
               {{"tile_m", g.tile_m},
                {"voxel_m", g.voxel_m},
                {"levels", g.levels},
                {"max_error_m", g.Quantization(0).MaxErrorM()}}},
              // What the viewer draws in its cross-sections: the gauge the changes are checked
              // against (lateral m, left positive; height above the rail plane m).
              {"clearance",
               {{"gauge_outline", outline},
                {"widen_below_radius_m", k.widen_below_radius_m},
                {"vegetation_zone_m", k.vegetation_zone_m},
                {"vegetation_allowance_m", k.vegetation_allowance_m}}}});
  }

  void CreateRun(const HttpRequest& req, HttpResponse& res) {
    json body;
    if (!ParseObject(req, res, &body) || !OnlyMembers(body, res, {"line", "vehicle", "start_ns"}))
      return;
    if (!body.contains("line") || !body["line"].is_string() || !body.contains("vehicle") ||
        !body["vehicle"].is_string())
      return res.SetError(400, "invalid", "a run needs line and vehicle (strings)");
    mapstore::NewRun run;
    run.line = body["line"];
    run.vehicle = body["vehicle"];
    std::string error;
    if (!ReadInt(body, "start_ns", &run.start_ns, &error))
      return res.SetError(400, "invalid", error);
    mapstore::RunInfo info;
    const mapstore::Result r = store_.CreateRun(run, &info);
    if (!r) return SendResult(res, r);
    hub_.PublishRun(info);
    res.status = 201;
    res.SetHeader("Location", "/api/v1/runs/" + std::to_string(info.id));
    SendJson(res, RunJson(info));
  }

  void ListRuns(const HttpRequest&, HttpResponse& res) {
    json runs = json::array();
    for (const auto& r : store_.ListRuns()) runs.push_back(RunJson(r));
    SendJson(res, {{"runs", runs}});
  }

  void GetRun(const HttpRequest& req, HttpResponse& res) {
    SendOne<mapstore::RunInfo>(
        req, res, "run", [this](int64_t id, auto* run) { return store_.GetRun(id, run); }, RunJson);
  }

  void FinishRun(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id)) return;
    json body = json::object();
    if (!req.body.empty() && (!ParseObject(req, res, &body) || !OnlyMembers(body, res, {"end_ns"})))
      return;
    int64_t end_ns = NowNs();
    std::string error;
    if (!ReadInt(body, "end_ns", &end_ns, &error)) return res.SetError(400, "invalid", error);
    mapstore::RunInfo info;
    const mapstore::Result r = store_.FinishRun(id, end_ns, &info);
    if (!r) return SendResult(res, r);
    if (r.outcome == mapstore::Outcome::kOk) hub_.PublishRun(info);
    c_.provisional->Drop(id);
    if (c_.change_worker) c_.change_worker->Notify();
    SendJson(res, RunJson(info));
  }

  void IngestSubmap(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id)) return;
    mapstore::IngestReceipt receipt;
    const mapstore::Result r = store_.IngestSubmap(id, req.body, &receipt);
    if (!r) return SendResult(res, r);
    c_.provisional->PruneMap(id, receipt.last_stamp_ns);  // the final map holds it now
    res.status = r.outcome == mapstore::Outcome::kDuplicate ? 200 : 201;
    SendJson(res,
             {{"duplicate", r.outcome == mapstore::Outcome::kDuplicate},
              {"points", receipt.points},
              {"points_new", receipt.points_new},
              {"points_off_grid", receipt.points_off_grid}});
  }

  /// A batch of poses ({"poses": [...]}); false with the response set if it is not one.
  bool ParsePoseBatch(const HttpRequest& req,
                      HttpResponse& res,
                      std::vector<api::StreamPose>* out) {
    json body;
    if (!ParseObject(req, res, &body) || !OnlyMembers(body, res, {"poses"})) return false;
    if (!body.contains("poses") || !body["poses"].is_array()) {
      res.SetError(400, "invalid", "the body needs \"poses\": [...]");
      return false;
    }
    if (body["poses"].size() > c_.config->max_poses_per_batch) {
      res.SetError(413,
                   "too_large",
                   "a batch holds at most " + std::to_string(c_.config->max_poses_per_batch) +
                       " poses (max_poses_per_batch); this one has " +
                       std::to_string(body["poses"].size()));
      return false;
    }
    std::string error;
    for (const auto& p : body["poses"]) {
      api::StreamPose pose;
      if (!ParsePose(p, &pose, &error)) {
        res.SetError(400, "invalid", error);
        return false;
      }
      out->push_back(pose);
    }
    return true;
  }

  void IngestPoses(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    std::vector<api::StreamPose> poses;
    if (!PathId(req, res, &id) || !ParsePoseBatch(req, res, &poses)) return;
    int stored = 0;
    std::vector<bool> added;
    const mapstore::Result r = store_.IngestPoses(id, poses, &stored, &added);
    if (!r) return SendResult(res, r);
    int64_t newest_ns = 0;
    for (const api::StreamPose& p : poses) newest_ns = std::max(newest_ns, p.stamp_ns);
    c_.provisional->PrunePoses(id, newest_ns);
    // Live: exactly the poses this batch added, in sequence order (a re-sent batch publishes
    // nothing).
    std::vector<const api::StreamPose*> live;
    for (size_t i = 0; i < poses.size(); ++i)
      if (added[i]) live.push_back(&poses[i]);
    std::sort(live.begin(), live.end(), [](const auto* a, const auto* b) {
      return a->sequence < b->sequence;
    });
    for (const api::StreamPose* p : live) hub_.PublishPose(id, *p);
    SendJson(res, {{"stored", stored}, {"received", poses.size()}});
  }

  /// Provisional poses and submaps (mapstore::ProvisionalMap): held in memory for change
  /// detection until the run's final output replaces them.
  void ProvisionalPoses(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    std::vector<api::StreamPose> poses;
    mapstore::RunInfo info;
    if (!PathId(req, res, &id) || !ParsePoseBatch(req, res, &poses)) return;
    mapstore::Result r = store_.GetRun(id, &info);
    int added = 0;
    if (r) r = c_.provisional->AddPoses(info, poses, &added);
    if (!r) return SendResult(res, r);
    if (c_.change_worker) c_.change_worker->Notify();
    SendJson(res, {{"held", added}, {"received", poses.size()}});
  }

  void ProvisionalSubmap(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id)) return;
    api::Submap submap;
    std::string error;
    if (!api::DecodeSubmapPcd(req.body, &submap, &error))
      return res.SetError(400, "invalid", "not a submap: " + error);
    if (submap.points.size() > store_.options().max_points_per_submap)
      return res.SetError(413,
                          "too_large",
                          "a submap holds at most " +
                              std::to_string(store_.options().max_points_per_submap) + " points");
    mapstore::RunInfo info;
    mapstore::Result r = store_.GetRun(id, &info);
    if (r) r = c_.provisional->AddSubmap(info, submap);
    if (!r) return SendResult(res, r);
    if (c_.change_worker) c_.change_worker->Notify();
    res.status = r.outcome == mapstore::Outcome::kDuplicate ? 200 : 201;
    SendJson(res,
             {{"duplicate", r.outcome == mapstore::Outcome::kDuplicate},
              {"points", submap.points.size()}});
  }

  void TileIndex(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0, level = 0;
    if (!PathId(req, res, &id) || !IntParam(req, res, "level", 0, Levels() - 1, &level)) return;
    Eigen::AlignedBox2d box(Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(1e6, 1e7));
    if (req.HasParam("bbox") && !BoxParam(req, res, &box)) return;
    std::vector<mapstore::TileInfo> tiles;
    const mapstore::Result r = store_.TilesInBox(id, static_cast<int>(level), box, &tiles);
    if (!r) return SendResult(res, r);
    json list = json::array();
    for (const auto& t : tiles) list.push_back(TileJson(t));
    SendJson(res, {{"run", id}, {"level", level}, {"tiles", list}});
  }

  void GetTile(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    mapstore::TileKey key;
    if (!TileOf(req, res, &id, &key)) return;
    std::shared_ptr<const TileCache::Entry> tile = c_.tiles->Get(id, key);
    if (!tile) {
      auto entry = std::make_shared<TileCache::Entry>();
      const mapstore::Result r = store_.Tile(id, key, &entry->info, &entry->bytes);
      if (!r) return SendResult(res, r);
      tile = entry;
      c_.tiles->Put(tile);
    }
    SendTile(req, res, tile);
  }

  /// GetTile on the event loop when the tile is in the cache (or the path names none).
  bool GetCachedTile(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    mapstore::TileKey key;
    if (!TileOf(req, res, &id, &key)) return true;
    std::shared_ptr<const TileCache::Entry> tile = c_.tiles->Get(id, key);
    if (!tile) return false;
    SendTile(req, res, tile);
    return true;
  }

  /// The run and tile of the path; false with a 404 set.
  bool TileOf(const HttpRequest& req, HttpResponse& res, int64_t* id, mapstore::TileKey* key) {
    int64_t level = 0, ix = 0, iy = 0;
    constexpr int64_t kIndex = int64_t{1} << 40;
    if (!PathId(req, res, id)) return false;
    if (!ParseInt64(req.matches[2], 0, Levels() - 1, &level) ||
        !ParseInt64(req.matches[3], -kIndex, kIndex, &ix) ||
        !ParseInt64(req.matches[4], -kIndex, kIndex, &iy)) {
      res.SetError(404, "not_found", "no such tile");
      return false;
    }
    *key = mapstore::TileKey{static_cast<int>(level), ix, iy};
    return true;
  }

  static void SendTile(const HttpRequest& req,
                       HttpResponse& res,
                       const std::shared_ptr<const TileCache::Entry>& tile) {
    const mapstore::TileInfo& info = tile->info;
    res.SetHeader("ETag", info.etag);
    // A tile of a live run changes as submaps arrive: revalidate with its ETag.
    res.SetHeader("Cache-Control", "no-cache");
    res.SetHeader("X-Tile-Origin",
                  std::to_string(info.origin.x()) + " " + std::to_string(info.origin.y()) + " " +
                      std::to_string(info.origin.z()));
    res.SetHeader("X-Tile-Zone", info.utm_zone);
    if (EtagMatches(req.Header("If-None-Match"), info.etag)) {
      res.status = 304;
      return;
    }
    // Straight from the cached bytes, without a copy.
    res.SetSharedContent(std::shared_ptr<const std::string>(tile, &tile->bytes),
                         "application/octet-stream");
  }

  void Trajectory(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id)) return;
    const std::string format = req.HasParam("format") ? req.Param("format") : "geojson";
    if (format != "geojson" && format != "tum")
      return res.SetError(400, "invalid", "format must be geojson or tum");
    mapstore::RunInfo run;
    std::vector<api::StreamPose> poses;
    mapstore::Result r = store_.GetRun(id, &run);
    if (r) r = store_.Trajectory(id, &poses);
    if (!r) return SendResult(res, r);
    // Every georeferenced pose of a run is in the run's zone (the store refuses others).
    const std::string& zone = run.utm_zone;
    if (format == "tum") return TrajectoryTum(poses, zone, res);
    // GeoJSON (RFC 7946): WGS84 longitude, latitude, ellipsoidal height. Every run is
    // referenced to its line's centreline: the chainage of each pose (null off the line, or
    // before the line has one).
    std::vector<double> chainage;
    r = store_.ChainageOfPoses(id, poses, &chainage);
    if (!r) return SendResult(res, r);
    json coordinates = json::array(), chainage_m = json::array();
    for (size_t i = 0; i < poses.size(); ++i) {
      json point;
      if (!poses[i].georeferenced || poses[i].utm_zone != zone || !Wgs84(zone, poses[i].p, &point))
        continue;
      coordinates.push_back(point);
      chainage_m.push_back(std::isnan(chainage[i]) ? json(nullptr) : json(chainage[i]));
    }
    json feature = {
        {"type", "Feature"},
        {"geometry", {{"type", "LineString"}, {"coordinates", coordinates}}},
        {"properties",
         {{"run", id}, {"poses", poses.size()}, {"utm_zone", zone}, {"chainage_m", chainage_m}}}};
    SendJson(res, {{"type", "FeatureCollection"}, {"features", {feature}}}, "application/geo+json");
  }

  static void TrajectoryTum(const std::vector<api::StreamPose>& poses,
                            const std::string& zone,
                            HttpResponse& res) {
    std::string out;
    if (!zone.empty()) out += "# utm_zone " + zone + "\n";
    for (const auto& p : poses) {
      if (!zone.empty() && (!p.georeferenced || p.utm_zone != zone)) continue;
      out += api::FormatTumLine({p.stamp_ns, p.p, p.q}) + "\n";
    }
    res.SetContent(std::move(out), "text/plain");
  }

  void ListLines(const HttpRequest&, HttpResponse& res) {
    std::vector<mapstore::LineInfo> lines;
    const mapstore::Result r = store_.ListLines(&lines);
    if (!r) return SendResult(res, r);
    json list = json::array();
    for (const auto& l : lines) list.push_back(LineJson(l));
    SendJson(res, {{"lines", list}});
  }

  void GetLine(const HttpRequest& req, HttpResponse& res) {
    mapstore::LineInfo line;
    const mapstore::Result r = store_.GetLine(req.matches[1], &line);
    if (!r) return SendResult(res, r);
    SendJson(res, LineJson(line));
  }

  void Segment(const HttpRequest& req, HttpResponse& res) {
    if (!req.HasParam("from_km") || !req.HasParam("to_km"))
      return res.SetError(
          400, "invalid", "from_km and to_km (kilometres of chainage) are required numbers");
    double from_m = 0.0, to_m = 0.0;
    if (!KmParam(req, res, "from_km", &from_m) || !KmParam(req, res, "to_km", &to_m)) return;
    const double from_km = from_m / 1000.0, to_km = to_m / 1000.0;
    mapstore::TrackSegment segment;
    const mapstore::Result r = store_.Segment(req.matches[1], from_m, to_m, &segment);
    if (!r) return SendResult(res, r);
    json coordinates = json::array(), chainage = json::array(), curvature = json::array(),
         gradient = json::array(), cant = json::array();
    for (const auto& s : segment.samples) {
      json c;
      if (!Wgs84(segment.line.utm_zone, s.point.p, &c)) continue;
      coordinates.push_back(c);
      chainage.push_back(s.point.chainage_m);
      curvature.push_back(s.curvature_per_m);
      gradient.push_back(s.gradient * 1000.0);
      cant.push_back(s.point.cant_m * 1000.0);
    }
    json tiles = json::array();
    for (const auto& t : segment.tiles) tiles.push_back(TileJson(t));
    const json feature = {{"type", "Feature"},
                          {"geometry", {{"type", "LineString"}, {"coordinates", coordinates}}},
                          {"properties",
                           {{"line", segment.line.name},
                            {"reference_run", segment.line.reference_run},
                            {"utm_zone", segment.line.utm_zone},
                            {"from_km", from_km},
                            {"to_km", to_km},
                            {"profile",
                             {{"chainage_m", chainage},
                              {"curvature_per_m", curvature},
                              {"gradient_per_mille", gradient},
                              {"cant_mm", cant}}},
                            {"tiles", tiles}}}};
    SendJson(res, {{"type", "FeatureCollection"}, {"features", {feature}}}, "application/geo+json");
  }

  void PinKmPost(const HttpRequest& req, HttpResponse& res) {
    json body;
    if (!ParseObject(req, res, &body) ||
        !OnlyMembers(body, res, {"km", "easting", "northing", "label"}))
      return;
    if (!body.contains("km") || !body["km"].is_number() || !body.contains("easting") ||
        !body["easting"].is_number() || !body.contains("northing") || !body["northing"].is_number())
      return res.SetError(
          400,
          "invalid",
          "a km post needs km, easting and northing (numbers; UTM of the line's zone)");
    if (body.contains("label") && !body["label"].is_string())
      return res.SetError(400, "invalid", "label must be a string");
    const std::string label = body.value("label", std::string());
    mapstore::LineInfo line;
    const mapstore::Result r = store_.PinKmPost(
        req.matches[1],
        label,
        body["km"].get<double>() * 1000.0,
        Eigen::Vector2d(body["easting"].get<double>(), body["northing"].get<double>()),
        &line);
    if (!r) return SendResult(res, r);
    SendJson(res, LineJson(line));
  }

  void CreatePoi(const HttpRequest& req, HttpResponse& res) {
    json body;
    if (!ParseObject(req, res, &body)) return;
    mapstore::Poi poi;
    std::string error;
    if (!ParsePoi(body, &poi, &error)) return res.SetError(400, "invalid", error);
    const mapstore::Result r = store_.CreatePoi(&poi);
    if (!r) return SendResult(res, r);
    res.status = 201;
    res.SetHeader("Location", "/api/v1/pois/" + std::to_string(poi.id));
    SendJson(res, PoiJson(poi));
  }

  void ListPois(const HttpRequest& req, HttpResponse& res) {
    Eigen::AlignedBox2d box;
    const Eigen::AlignedBox2d* in = nullptr;
    if (req.HasParam("bbox")) {
      if (!BoxParam(req, res, &box)) return;
      in = &box;
    }
    std::vector<mapstore::Poi> pois;
    const mapstore::Result r = store_.ListPois(req.Param("line"), in, &pois);
    if (!r) return SendResult(res, r);
    json list = json::array();
    for (const auto& p : pois) list.push_back(PoiJson(p));
    SendJson(res, {{"pois", list}});
  }

  void GetPoi(const HttpRequest& req, HttpResponse& res) {
    SendOne<mapstore::Poi>(
        req,
        res,
        "point of interest",
        [this](int64_t id, auto* poi) { return store_.GetPoi(id, poi); },
        PoiJson);
  }

  void UpdatePoi(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id, "point of interest")) return;
    json body;
    if (!ParseObject(req, res, &body)) return;
    mapstore::Poi poi;
    std::string error;
    if (!ParsePoi(body, &poi, &error)) return res.SetError(400, "invalid", error);
    poi.id = id;
    const mapstore::Result r = store_.UpdatePoi(&poi);
    if (!r) return SendResult(res, r);
    SendJson(res, PoiJson(poi));
  }

  void DeletePoi(const HttpRequest& req, HttpResponse& res) {
    int64_t id = 0;
    if (!PathId(req, res, &id, "point of interest")) return;
    const mapstore::Result r = store_.DeletePoi(id);
    if (!r) return SendResult(res, r);
    res.status = 204;
  }

  void Export(const HttpRequest& req, HttpResponse& res) {
    mapstore::ExportRequest request;
    if (!ExportRequestOf(req, res, &request)) return;
    mapstore::ExportFormat format = mapstore::ExportFormat::kLas;
    if (req.HasParam("format") && !mapstore::ParseExportFormat(req.Param("format"), &format))
      return res.SetError(400, "invalid", "format must be ply, pcd or las");
    // Exports read every tile they cover twice (to count, then to send): a few at a time.
    auto slot = std::make_shared<ExportSlot>(&exports_running_);
    if (slot->running() > c_.config->max_concurrent_exports)
      return res.SetError(503,
                          "busy",
                          std::to_string(c_.config->max_concurrent_exports) +
                              " exports are running (max_concurrent_exports); try again shortly");
    auto stream = std::make_shared<ExportStream>();
    stream->slot = slot;
    const mapstore::Result r = store_.PrepareExport(request, &stream->cursor);
    if (!r) return SendResult(res, r);
    const mapstore::ExportCursor& cursor = *stream->cursor;
    std::string why;
    if (!stream->encoder.Begin(
            format, cursor.points(), cursor.bounds(), cursor.utm_zone(), &stream->head, &why))
      return res.SetError(413,
                          "too_large",
                          std::to_string(cursor.points()) + " points: " + why +
                              "; ask for ply or pcd, or a smaller box");
    res.SetHeader("Content-Disposition",
                  "attachment; filename=\"run-" + std::to_string(request.run_id) + "." +
                      mapstore::ExtensionOf(format) + "\"");
    res.SetHeader("X-Points", std::to_string(cursor.points()));
    res.content_type = "application/octet-stream";
    // The file goes out a tile at a time: its points never sit in memory whole.
    res.produced_size = stream->head.size() + cursor.points() * stream->encoder.RecordBytes();
    res.produce = [stream](std::string* piece) { return stream->Next(piece); };
  }

  /// One export under way: counted while it lives.
  class ExportSlot {
   public:
    explicit ExportSlot(std::atomic<int>* running) : running_(running), now_(++*running) {}
    ~ExportSlot() { --*running_; }
    int running() const { return now_; }

   private:
    std::atomic<int>* running_;
    int now_;
  };

  /// An export being sent: the header, then each tile's points encoded.
  struct ExportStream {
    std::shared_ptr<ExportSlot> slot;
    std::unique_ptr<mapstore::ExportCursor> cursor;
    mapstore::ExportEncoder encoder;
    std::string head;
    bool head_sent = false;
    std::vector<mapstore::ExportPoint> points;

    bool Next(std::string* piece) {
      if (!head_sent) {
        head_sent = true;
        *piece = std::move(head);
        if (!piece->empty()) return true;
      }
      while (piece->empty() && !cursor->done()) {
        if (!cursor->Next(&points)) return false;
        piece->reserve(points.size() * encoder.RecordBytes());
        for (const mapstore::ExportPoint& p : points) encoder.Append(p, piece);
      }
      return !piece->empty();
    }
  };

  /// The export's run, level, box or km range from the path and query; false with a 400 set.
  bool ExportRequestOf(const HttpRequest& req, HttpResponse& res, mapstore::ExportRequest* out) {
    int64_t level = 0;
    if (!PathId(req, res, &out->run_id) || !IntParam(req, res, "level", 0, Levels() - 1, &level) ||
        !NumberParam(req, res, "half_width_m", &out->half_width_m))
      return false;
    out->level = static_cast<int>(level);
    out->max_points = c_.config->max_export_points;
    const bool along = req.HasParam("line");
    if (along && req.HasParam("bbox")) {
      res.SetError(400, "invalid", "give bbox, or line with from_km and to_km, not both");
      return false;
    }
    for (const char* name : {"from_km", "to_km", "half_width_m"}) {
      if (!along && req.HasParam(name)) {
        res.SetError(
            400, "invalid", std::string(name) + " goes with line (an export along a line)");
        return false;
      }
    }
    if (along) {
      if (!req.HasParam("from_km") || !req.HasParam("to_km")) {
        res.SetError(400, "invalid", "an export along a line needs from_km and to_km");
        return false;
      }
      if (!KmParam(req, res, "from_km", &out->from_m) || !KmParam(req, res, "to_km", &out->to_m))
        return false;
      out->line = req.Param("line");
    }
    if (req.HasParam("bbox")) {
      if (!BoxParam(req, res, &out->box)) return false;
      out->has_box = true;
    }
    return true;
  }

 private:
  int64_t Levels() const { return store_.options().grid.levels; }

  ApiContext c_;
  mapstore::MapStore& store_;
  LiveHub& hub_;
  std::atomic<int> exports_running_{0};
};

}  // namespace

std::vector<HttpRoute> ApiRoutes(const ApiContext& context) {
  auto api = std::make_shared<Api>(context);
  const ServerConfig& config = *context.config;
  auto route = [api](auto... args) { return MemberRoute(api, args...); };
  const Access R = Access::kRead, W = Access::kWrite;
  const uint64_t json_body = config.max_json_bytes, submap_body = config.max_body_bytes;
  HttpRoute tile =
      route("GET", "/api/v1/runs/{run}/tiles/{level}/{ix}/{iy}", "tiles.get", R, &Api::GetTile);
  tile.ranges = true;
  tile.fast_handler = [api](const HttpRequest& req, HttpResponse& res) {
    return api->GetCachedTile(req, res);
  };
  std::vector<HttpRoute> routes = {
      route("GET", "/health", "health", R, &Api::Health),
      route("GET", "/metrics", "metrics", R, &Api::MetricsText),
      route("GET", "/api/v1/info", "info", R, &Api::Info),
      route("POST", "/api/v1/runs", "runs.create", W, &Api::CreateRun),
      route("GET", "/api/v1/runs", "runs.list", R, &Api::ListRuns),
      route("GET", "/api/v1/runs/{run}", "runs.get", R, &Api::GetRun),
      route("POST", "/api/v1/runs/{run}/finish", "runs.finish", W, &Api::FinishRun),
      route("POST",
            "/api/v1/runs/{run}/submaps",
            "ingest.submap",
            W,
            &Api::IngestSubmap,
            submap_body),
      route("POST", "/api/v1/runs/{run}/poses", "ingest.poses", W, &Api::IngestPoses, json_body),
      route("POST",
            "/api/v1/runs/{run}/provisional/poses",
            "ingest.provisional_poses",
            W,
            &Api::ProvisionalPoses,
            json_body),
      route("POST",
            "/api/v1/runs/{run}/provisional/submaps",
            "ingest.provisional_submap",
            W,
            &Api::ProvisionalSubmap,
            submap_body),
      route("GET", "/api/v1/runs/{run}/tiles", "tiles.index", R, &Api::TileIndex),
      tile,
      route("GET", "/api/v1/runs/{run}/trajectory", "trajectory", R, &Api::Trajectory),
      route("GET", "/api/v1/runs/{run}/export", "export", R, &Api::Export),
      route("GET", "/api/v1/lines", "lines.list", R, &Api::ListLines),
      route("GET", "/api/v1/lines/{line}", "lines.get", R, &Api::GetLine),
      route("GET", "/api/v1/lines/{line}/segment", "lines.segment", R, &Api::Segment),
      route("POST", "/api/v1/lines/{line}/kmposts", "lines.kmpost", W, &Api::PinKmPost),
      route("POST", "/api/v1/pois", "pois.create", W, &Api::CreatePoi),
      route("GET", "/api/v1/pois", "pois.list", R, &Api::ListPois),
      route("GET", "/api/v1/pois/{id}", "pois.get", R, &Api::GetPoi),
      route("PUT", "/api/v1/pois/{id}", "pois.update", W, &Api::UpdatePoi),
      route("DELETE", "/api/v1/pois/{id}", "pois.delete", W, &Api::DeletePoi),
  };
  for (HttpRoute& r : ChangeRoutes(context)) routes.push_back(std::move(r));
  return routes;
}

}  // namespace raillomer::server
