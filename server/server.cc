#include "server/server.h"

#include <sys/socket.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <thread>

#include <httplib.h>
#include <GeographicLib/UTMUPS.hpp>
#include <nlohmann/json.hpp>

#include "api/trajectory.h"
#include "mapstore/schema.h"
#include "server/live_hub.h"
#include "server/metrics.h"
#include "server/tile_cache.h"

namespace raillomer::server {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

/// Compares without an early exit, so the time taken says nothing about the token.
bool ConstantTimeEqual(const std::string& a, const std::string& b) {
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  const size_t n = std::max(a.size(), b.size());
  for (size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff |= x ^ y;
  }
  return diff == 0;
}

void SendError(httplib::Response& res,
               int status,
               const std::string& code,
               const std::string& message) {
  res.status = status;
  // Messages may quote request data: bytes that are not UTF-8 are replaced, never thrown on.
  res.set_content(json{{"error", {{"code", code}, {"message", message}}}}.dump(
                      -1, ' ', false, json::error_handler_t::replace),
                  "application/json");
}

int StatusOf(mapstore::Outcome outcome) {
  switch (outcome) {
    case mapstore::Outcome::kOk:
      return 200;
    case mapstore::Outcome::kDuplicate:
      return 200;
    case mapstore::Outcome::kInvalid:
      return 400;
    case mapstore::Outcome::kNotFound:
      return 404;
    case mapstore::Outcome::kConflict:
      return 409;
    case mapstore::Outcome::kError:
      return 500;
  }
  return 500;
}

void SendResult(httplib::Response& res, const mapstore::Result& r) {
  SendError(res, StatusOf(r.outcome), mapstore::ToString(r.outcome), r.message);
}

json RunJson(const mapstore::RunInfo& r) {
  json j = {{"id", r.id},
            {"line", r.line},
            {"vehicle", r.vehicle},
            {"status", r.status},
            {"start_ns", r.start_ns},
            {"utm_zone", r.utm_zone.empty() ? json(nullptr) : json(r.utm_zone)},
            {"submaps", r.submaps},
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
          {"runs", l.runs}};
}

/// UTM to WGS84 [lon, lat, h]; false outside the zone's range.
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

/// A point of interest from a JSON body: kind, position [easting, northing, height], utm_zone,
/// and optionally name, line and properties (an object).
bool ParsePoi(const json& j, mapstore::Poi* p, std::string* error) {
  auto number3 = [](const json& v) {
    return v.is_array() && v.size() == 3 && v[0].is_number() && v[1].is_number() &&
           v[2].is_number();
  };
  if (!j.contains("kind") || !j["kind"].is_string() || !j.contains("utm_zone") ||
      !j["utm_zone"].is_string() || !j.contains("position") || !number3(j["position"])) {
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

/// A JSON body as an object; false (and a 400 sent) if it is not one.
bool ParseObject(const httplib::Request& req, httplib::Response& res, json* out) {
  *out = json::parse(req.body, nullptr, false);
  if (out->is_discarded() || !out->is_object()) {
    SendError(res, 400, "invalid", "the body must be a JSON object");
    return false;
  }
  return true;
}

bool ReadInt(const json& j, const char* key, int64_t* value, std::string* error) {
  if (!j.contains(key)) return true;
  if (!j[key].is_number_integer()) {
    *error = std::string(key) + " must be an integer";
    return false;
  }
  *value = j[key].get<int64_t>();
  return true;
}

/// A pose of a batch: {"sequence", "stamp_ns", "georeferenced", "utm_zone", "p": [x, y, z],
/// "q": [x, y, z, w]}.
bool ParsePose(const json& j, api::StreamPose* p, std::string* error) {
  auto number3 = [](const json& v, size_t n) {
    if (!v.is_array() || v.size() != n) return false;
    for (const auto& x : v)
      if (!x.is_number()) return false;
    return true;
  };
  if (!j.is_object() || !j.contains("sequence") || !j["sequence"].is_number_unsigned() ||
      !j.contains("stamp_ns") || !j["stamp_ns"].is_number_integer() || !j.contains("p") ||
      !number3(j["p"], 3) || !j.contains("q") || !number3(j["q"], 4)) {
    *error = "a pose needs sequence (unsigned), stamp_ns (integer), p [x, y, z] and q [x, y, z, w]";
    return false;
  }
  p->sequence = j["sequence"].get<uint64_t>();
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

}  // namespace

class Server::Impl {
 public:
  explicit Impl(ServerConfig config) : config_(std::move(config)) {}

  bool Start(std::string* error) {
    if (!config_.IsValid(error)) return false;
    store_ = mapstore::MapStore::Open(config_.data_dir, config_.store, error);
    if (!store_) return false;
    if (!ResolveIngestToken(&config_, &token_path_, error)) return false;
    LiveHub::Options hub_options;
    hub_options.host = config_.host;
    hub_options.port = config_.ws_port != 0 ? config_.ws_port
                       : config_.port != 0  ? config_.port + 1
                                            : 0;
    hub_options.threads = config_.ws_threads;
    hub_options.queue_messages = config_.ws_queue_messages;
    hub_ =
        std::make_unique<LiveHub>(hub_options, [this](const std::string& t) { return CanRead(t); });
    if (!hub_->Start(error)) return false;
    store_->SetTileListener([this](const std::vector<mapstore::TileUpdate>& u) {
      tiles_.Invalidate(u);
      hub_->PublishTiles(u);
    });
    Routes();
    const int threads = config_.http_threads;
    http_.new_task_queue = [threads] { return new httplib::ThreadPool(threads); };
    http_.set_payload_max_length(config_.max_body_bytes);
    http_.set_read_timeout(config_.request_timeout_s, 0);
    http_.set_write_timeout(config_.request_timeout_s, 0);
    http_.set_keep_alive_timeout(std::min(config_.request_timeout_s, 5));
    // Keep-alive connections stay open (httplib closes after 5 requests by default), and small
    // answers go out at once rather than waiting on the client's delayed ACK (40 ms).
    http_.set_keep_alive_max_count(100000);
    http_.set_tcp_nodelay(true);
    // The listening socket: SO_REUSEADDR (a restart right after a crash binds again) but not
    // httplib's SO_REUSEPORT (a second server on the same port must fail, not share it); its
    // fd is kept to widen the accept backlog, which Debian's build of httplib leaves at 5 (64
    // clients connecting at once would wait for SYN retries, 1-3 s).
    int listen_fd = -1;
    http_.set_socket_options([&listen_fd](socket_t sock) {
      int yes = 1;
      setsockopt(sock, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof(yes));
      listen_fd = sock;
    });
    if (config_.port == 0) {
      port_ = http_.bind_to_any_port(config_.host);
    } else {
      port_ = http_.bind_to_port(config_.host, config_.port) ? config_.port : -1;
    }
    if (port_ < 0) {
      *error = "cannot listen on " + config_.host + ":" + std::to_string(config_.port) +
               " (in use, or not an address of this machine?)";
      return false;
    }
    if (listen_fd >= 0) ::listen(listen_fd, SOMAXCONN);
    thread_ = std::thread([this] { http_.listen_after_bind(); });
    const auto deadline = Clock::now() + std::chrono::seconds(10);
    while (!http_.is_running()) {
      if (Clock::now() > deadline) {
        *error = "the HTTP server did not start listening";
        return false;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    return true;
  }

  void Stop() {
    {
      std::lock_guard<std::mutex> lock(stop_mu_);
      if (stopped_) return;
      stopped_ = true;
    }
    http_.stop();
    if (thread_.joinable()) thread_.join();
    if (hub_) hub_->Stop();
    store_.reset();  // writes the last tiles
    stop_cv_.notify_all();
  }

  void Wait() {
    std::unique_lock<std::mutex> lock(stop_mu_);
    stop_cv_.wait(lock, [this] { return stopped_; });
  }

  bool CanWrite(const std::string& token) const {
    return !token.empty() && ConstantTimeEqual(token, config_.ingest_token);
  }
  bool CanRead(const std::string& token) const {
    if (!config_.reads_need_token) return true;
    if (token.empty()) return false;
    const bool read = !config_.read_token.empty() && ConstantTimeEqual(token, config_.read_token);
    return CanWrite(token) || read;
  }

  static std::string Bearer(const httplib::Request& req) {
    const std::string value = req.get_header_value("Authorization");
    return value.rfind("Bearer ", 0) == 0 ? value.substr(7) : std::string();
  }

  /// Wraps a handler: the token check, timing and metrics under the route's name.
  httplib::Server::Handler Route(const std::string& name, bool write, httplib::Server::Handler h) {
    return [this, name, write, h](const httplib::Request& req, httplib::Response& res) {
      const auto start = Clock::now();
      const std::string token = Bearer(req);
      if (write ? !CanWrite(token) : !CanRead(token)) {
        res.set_header("WWW-Authenticate", "Bearer");
        SendError(res,
                  401,
                  "unauthorized",
                  write ? "this needs the ingest token as 'Authorization: Bearer <token>'"
                        : "reads need a token as 'Authorization: Bearer <token>'");
      } else {
        try {
          h(req, res);
        } catch (const std::exception& e) {
          // A handler's bug, not the client's: still an answer, counted like any other.
          SendError(res, 500, "error", std::string("internal error: ") + e.what());
        }
        if (res.status == -1) res.status = 200;  // httplib's default, set after the handler
      }
      metrics_.Observe(
          name, res.status, std::chrono::duration<double>(Clock::now() - start).count());
    };
  }

  static bool RunId(const httplib::Request& req, httplib::Response& res, int64_t* id) {
    try {
      *id = std::stoll(req.matches[1]);
      return true;
    } catch (const std::exception&) {
      SendError(res, 404, "not_found", "no such run");
      return false;
    }
  }

  /// Answers a GET of one stored record by the path's id: `get(id, &record)`, sent as JSON by
  /// `to_json`, or the store's error.
  template <typename Record, typename Get, typename ToJson>
  static void SendOne(const httplib::Request& req,
                      httplib::Response& res,
                      Get get,
                      ToJson to_json) {
    int64_t id = 0;
    if (!RunId(req, res, &id)) return;
    Record record;
    const mapstore::Result r = get(id, &record);
    if (!r) return SendResult(res, r);
    res.set_content(to_json(record).dump(), "application/json");
  }

  void Routes();

  ServerConfig config_;
  std::string token_path_;
  std::unique_ptr<mapstore::MapStore> store_;
  std::unique_ptr<LiveHub> hub_;
  httplib::Server http_;
  Metrics metrics_;
  TileCache tiles_{256u << 20};
  int port_ = -1;
  std::thread thread_;
  std::mutex stop_mu_;
  std::condition_variable stop_cv_;
  bool stopped_ = false;
};

void Server::Impl::Routes() {
  http_.set_error_handler([this](const httplib::Request& req, httplib::Response& res) {
    // httplib's own refusals (no route, a body over the limit) get a JSON body too.
    if (!res.body.empty()) return;
    if (res.status == 413 &&
        req.get_header_value("Content-Type") == "application/x-www-form-urlencoded") {
      SendError(res,
                413,
                "too_large",
                "a form-urlencoded body is limited to 8192 bytes: send submaps as "
                "Content-Type: application/octet-stream and JSON as application/json");
    } else if (res.status == 413) {
      SendError(res,
                413,
                "too_large",
                "the request body is larger than the " + std::to_string(config_.max_body_bytes) +
                    " bytes allowed (max_body_bytes)");
    } else if (res.status == 404) {
      SendError(res, 404, "not_found", "no resource at " + req.path);
    } else {
      SendError(res, res.status, "bad_request", "the request could not be served");
    }
    metrics_.Observe("other", res.status, 0.0);
  });
  http_.set_exception_handler(
      [](const httplib::Request&, httplib::Response& res, std::exception_ptr ep) {
        std::string what = "internal error";
        try {
          std::rethrow_exception(ep);
        } catch (const std::exception& e) {
          what = e.what();
        } catch (...) {
        }
        SendError(res, 500, "error", what);
      });

  http_.Get("/health",
            Route("health", false, [this](const httplib::Request&, httplib::Response& res) {
              const auto runs = store_->ListRuns();
              res.set_content(json{{"status", "ok"},
                                   {"schema_version", mapstore::LatestSchemaVersion()},
                                   {"runs", runs.size()}}
                                  .dump(),
                              "application/json");
            }));

  http_.Get(
      "/metrics", Route("metrics", false, [this](const httplib::Request&, httplib::Response& res) {
        std::string out;
        metrics_.Write(&out);
        const mapstore::StoreStats s = store_->stats();
        const HubStats h = hub_->stats();
        auto counter =
            [&](const char* name, const char* help, uint64_t v, const char* type = "counter") {
              out += std::string("# HELP ") + name + " " + help + "\n# TYPE " + name + " " + type +
                     "\n" + name + " " + std::to_string(v) + "\n";
            };
        counter("raillomer_submaps_stored_total", "Submaps stored.", s.submaps_stored);
        counter("raillomer_submaps_duplicate_total",
                "Submaps sent again (nothing changed).",
                s.submaps_duplicate);
        counter("raillomer_submaps_rejected_total", "Submaps refused.", s.submaps_rejected);
        counter("raillomer_points_ingested_total", "Points of stored submaps.", s.points_ingested);
        counter("raillomer_poses_stored_total", "Poses stored.", s.poses_stored);
        counter("raillomer_tiles_written_total", "Tiles encoded and written.", s.tiles_written);
        counter("raillomer_hot_points", "Points in tiles held in memory.", s.hot_points, "gauge");
        counter("raillomer_live_clients", "WebSocket clients connected.", h.clients, "gauge");
        counter("raillomer_live_messages_sent_total", "Live messages written.", h.sent);
        counter("raillomer_live_messages_dropped_total",
                "Live messages dropped for slow clients.",
                h.dropped);
        counter("raillomer_live_refused_total", "Live connections refused.", h.refused);
        res.set_content(out, "text/plain; version=0.0.4");
      }));

  http_.Get("/api/v1/info",
            Route("info", false, [this](const httplib::Request&, httplib::Response& res) {
              const mapstore::TileGrid& g = store_->options().grid;
              res.set_content(json{{"name", "raillomer-server"},
                                   {"api", "v1"},
                                   {"schema_version", mapstore::LatestSchemaVersion()},
                                   {"ws_port", hub_->port()},
                                   {"ws_path", "/live"},
                                   {"tiles",
                                    {{"tile_m", g.tile_m},
                                     {"voxel_m", g.voxel_m},
                                     {"levels", g.levels},
                                     {"max_error_m", g.Quantization(0).MaxErrorM()}}}}
                                  .dump(),
                              "application/json");
            }));

  http_.Post(
      "/api/v1/runs",
      Route("runs.create", true, [this](const httplib::Request& req, httplib::Response& res) {
        json body;
        if (!ParseObject(req, res, &body)) return;
        mapstore::NewRun run;
        std::string error;
        if (!body.contains("line") || !body["line"].is_string() || !body.contains("vehicle") ||
            !body["vehicle"].is_string()) {
          SendError(res, 400, "invalid", "a run needs line and vehicle (strings)");
          return;
        }
        run.line = body["line"];
        run.vehicle = body["vehicle"];
        if (!ReadInt(body, "start_ns", &run.start_ns, &error)) {
          SendError(res, 400, "invalid", error);
          return;
        }
        mapstore::RunInfo info;
        const mapstore::Result r = store_->CreateRun(run, &info);
        if (!r) return SendResult(res, r);
        hub_->PublishRun(info);
        res.status = 201;
        res.set_header("Location", "/api/v1/runs/" + std::to_string(info.id));
        res.set_content(RunJson(info).dump(), "application/json");
      }));

  http_.Get("/api/v1/runs",
            Route("runs.list", false, [this](const httplib::Request&, httplib::Response& res) {
              json runs = json::array();
              for (const auto& r : store_->ListRuns()) runs.push_back(RunJson(r));
              res.set_content(json{{"runs", runs}}.dump(), "application/json");
            }));

  http_.Get(R"(/api/v1/runs/(\d+))",
            Route("runs.get", false, [this](const httplib::Request& req, httplib::Response& res) {
              SendOne<mapstore::RunInfo>(
                  req,
                  res,
                  [this](int64_t id, mapstore::RunInfo* info) { return store_->GetRun(id, info); },
                  RunJson);
            }));

  http_.Post(
      R"(/api/v1/runs/(\d+)/finish)",
      Route("runs.finish", true, [this](const httplib::Request& req, httplib::Response& res) {
        int64_t id = 0;
        if (!RunId(req, res, &id)) return;
        json body = json::object();
        if (!req.body.empty() && !ParseObject(req, res, &body)) return;
        int64_t end_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                             std::chrono::system_clock::now().time_since_epoch())
                             .count();
        std::string error;
        if (!ReadInt(body, "end_ns", &end_ns, &error)) return SendError(res, 400, "invalid", error);
        mapstore::RunInfo info;
        const mapstore::Result r = store_->FinishRun(id, end_ns, &info);
        if (!r) return SendResult(res, r);
        if (r.outcome == mapstore::Outcome::kOk) hub_->PublishRun(info);
        res.set_content(RunJson(info).dump(), "application/json");
      }));

  http_.Post(
      R"(/api/v1/runs/(\d+)/submaps)",
      Route("ingest.submap", true, [this](const httplib::Request& req, httplib::Response& res) {
        int64_t id = 0;
        if (!RunId(req, res, &id)) return;
        mapstore::IngestReceipt receipt;
        const mapstore::Result r = store_->IngestSubmap(id, req.body, &receipt);
        if (!r) return SendResult(res, r);
        res.status = r.outcome == mapstore::Outcome::kDuplicate ? 200 : 201;
        res.set_content(json{{"duplicate", r.outcome == mapstore::Outcome::kDuplicate},
                             {"points", receipt.points},
                             {"points_new", receipt.points_new},
                             {"points_off_grid", receipt.points_off_grid}}
                            .dump(),
                        "application/json");
      }));

  http_.Post(
      R"(/api/v1/runs/(\d+)/poses)",
      Route("ingest.poses", true, [this](const httplib::Request& req, httplib::Response& res) {
        int64_t id = 0;
        if (!RunId(req, res, &id)) return;
        json body;
        if (!ParseObject(req, res, &body)) return;
        if (!body.contains("poses") || !body["poses"].is_array())
          return SendError(res, 400, "invalid", "the body needs \"poses\": [...]");
        std::vector<api::StreamPose> poses;
        std::string error;
        for (const auto& p : body["poses"]) {
          api::StreamPose pose;
          if (!ParsePose(p, &pose, &error)) return SendError(res, 400, "invalid", error);
          poses.push_back(pose);
        }
        int stored = 0;
        std::vector<bool> added;
        const mapstore::Result r = store_->IngestPoses(id, poses, &stored, &added);
        if (!r) return SendResult(res, r);
        // Live: exactly the poses this batch added, in sequence order (a re-sent batch
        // publishes nothing).
        std::vector<const api::StreamPose*> live;
        for (size_t i = 0; i < poses.size(); ++i)
          if (added[i]) live.push_back(&poses[i]);
        std::sort(live.begin(), live.end(), [](const auto* a, const auto* b) {
          return a->sequence < b->sequence;
        });
        for (const api::StreamPose* p : live) hub_->PublishPose(id, *p);
        res.set_content(json{{"stored", stored}, {"received", poses.size()}}.dump(),
                        "application/json");
      }));

  http_.Get(
      R"(/api/v1/runs/(\d+)/tiles)",
      Route("tiles.index", false, [this](const httplib::Request& req, httplib::Response& res) {
        int64_t id = 0;
        if (!RunId(req, res, &id)) return;
        int level = 0;
        Eigen::AlignedBox2d box(Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(1e6, 1e7));
        try {
          if (req.has_param("level")) level = std::stoi(req.get_param_value("level"));
          if (req.has_param("bbox")) {
            double v[4];
            const std::string text = req.get_param_value("bbox");
            if (std::sscanf(text.c_str(), "%lf,%lf,%lf,%lf", &v[0], &v[1], &v[2], &v[3]) != 4)
              return SendError(res,
                               400,
                               "invalid",
                               "bbox must be min_easting,min_northing,max_easting,max_northing");
            box = Eigen::AlignedBox2d(Eigen::Vector2d(v[0], v[1]), Eigen::Vector2d(v[2], v[3]));
          }
        } catch (const std::exception&) {
          return SendError(res, 400, "invalid", "level must be an integer");
        }
        std::vector<mapstore::TileInfo> tiles;
        const mapstore::Result r = store_->TilesInBox(id, level, box, &tiles);
        if (!r) return SendResult(res, r);
        json list = json::array();
        for (const auto& t : tiles) list.push_back(TileJson(t));
        res.set_content(json{{"run", id}, {"level", level}, {"tiles", list}}.dump(),
                        "application/json");
      }));

  http_.Get(
      R"(/api/v1/runs/(\d+)/tiles/(\d+)/(-?\d+)/(-?\d+))",
      Route("tiles.get", false, [this](const httplib::Request& req, httplib::Response& res) {
        int64_t id = 0;
        if (!RunId(req, res, &id)) return;
        mapstore::TileKey key;
        try {
          key.level = std::stoi(req.matches[2]);
          key.ix = std::stoll(req.matches[3]);
          key.iy = std::stoll(req.matches[4]);
        } catch (const std::exception&) {
          return SendError(res, 404, "not_found", "no such tile");
        }
        std::shared_ptr<const TileCache::Entry> tile = tiles_.Get(id, key);
        if (!tile) {
          auto entry = std::make_shared<TileCache::Entry>();
          const mapstore::Result r = store_->Tile(id, key, &entry->info, &entry->bytes);
          if (!r) return SendResult(res, r);
          tile = entry;
          tiles_.Put(tile);
        }
        const mapstore::TileInfo& info = tile->info;
        res.set_header("ETag", info.etag);
        // A tile of a live run changes as submaps arrive: revalidate with its ETag.
        res.set_header("Cache-Control", "no-cache");
        res.set_header("X-Tile-Origin",
                       std::to_string(info.origin.x()) + " " + std::to_string(info.origin.y()) +
                           " " + std::to_string(info.origin.z()));
        res.set_header("X-Tile-Zone", info.utm_zone);
        if (req.get_header_value("If-None-Match") == info.etag) {
          res.status = 304;
          return;
        }
        // Straight from the cached bytes, without a copy.
        res.set_content_provider(tile->bytes.size(),
                                 "application/octet-stream",
                                 [tile](size_t offset, size_t length, httplib::DataSink& sink) {
                                   return sink.write(tile->bytes.data() + offset, length);
                                 });
      }));

  http_.Get(R"(/api/v1/runs/(\d+)/trajectory)",
            Route("trajectory", false, [this](const httplib::Request& req, httplib::Response& res) {
              int64_t id = 0;
              if (!RunId(req, res, &id)) return;
              const std::string format =
                  req.has_param("format") ? req.get_param_value("format") : "geojson";
              if (format != "geojson" && format != "tum")
                return SendError(res, 400, "invalid", "format must be geojson or tum");
              std::vector<api::StreamPose> poses;
              const mapstore::Result r = store_->Trajectory(id, &poses);
              if (!r) return SendResult(res, r);
              std::string zone;
              for (const auto& p : poses)
                if (p.georeferenced) zone = p.utm_zone;
              if (format == "tum") {
                std::string out;
                if (!zone.empty()) out += "# utm_zone " + zone + "\n";
                for (const auto& p : poses) {
                  if (!zone.empty() && (!p.georeferenced || p.utm_zone != zone)) continue;
                  out += api::FormatTumLine({p.stamp_ns, p.p, p.q}) + "\n";
                }
                res.set_content(out, "text/plain");
                return;
              }
              // GeoJSON (RFC 7946): WGS84 longitude, latitude, ellipsoidal height.
              // Every run is referenced to its line's centreline: the chainage of each pose
              // (null off the line, or before the line has one).
              std::vector<double> chainage;
              const mapstore::Result c = store_->ChainageOfPoses(id, poses, &chainage);
              if (!c) return SendResult(res, c);
              json coordinates = json::array(), chainage_m = json::array();
              for (size_t i = 0; i < poses.size(); ++i) {
                json point;
                if (!poses[i].georeferenced || poses[i].utm_zone != zone ||
                    !Wgs84(zone, poses[i].p, &point))
                  continue;
                coordinates.push_back(point);
                chainage_m.push_back(std::isnan(chainage[i]) ? json(nullptr) : json(chainage[i]));
              }
              json feature = {{"type", "Feature"},
                              {"geometry", {{"type", "LineString"}, {"coordinates", coordinates}}},
                              {"properties",
                               {{"run", id},
                                {"poses", poses.size()},
                                {"utm_zone", zone},
                                {"chainage_m", chainage_m}}}};
              res.set_content(json{{"type", "FeatureCollection"}, {"features", {feature}}}.dump(),
                              "application/geo+json");
            }));

  http_.Get("/api/v1/lines",
            Route("lines.list", false, [this](const httplib::Request&, httplib::Response& res) {
              std::vector<mapstore::LineInfo> lines;
              const mapstore::Result r = store_->ListLines(&lines);
              if (!r) return SendResult(res, r);
              json list = json::array();
              for (const auto& l : lines) list.push_back(LineJson(l));
              res.set_content(json{{"lines", list}}.dump(), "application/json");
            }));

  http_.Get(R"(/api/v1/lines/([^/]+))",
            Route("lines.get", false, [this](const httplib::Request& req, httplib::Response& res) {
              mapstore::LineInfo line;
              const mapstore::Result r = store_->GetLine(req.matches[1], &line);
              if (!r) return SendResult(res, r);
              res.set_content(LineJson(line).dump(), "application/json");
            }));

  http_.Get(
      R"(/api/v1/lines/([^/]+)/segment)",
      Route("lines.segment", false, [this](const httplib::Request& req, httplib::Response& res) {
        double from_km = 0.0, to_km = 0.0;
        try {
          if (!req.has_param("from_km") || !req.has_param("to_km")) throw std::invalid_argument("");
          size_t used = 0;
          const std::string a = req.get_param_value("from_km"), b = req.get_param_value("to_km");
          from_km = std::stod(a, &used);
          if (used != a.size()) throw std::invalid_argument("");
          to_km = std::stod(b, &used);
          if (used != b.size()) throw std::invalid_argument("");
        } catch (const std::exception&) {
          return SendError(res,
                           400,
                           "invalid",
                           "from_km and to_km (kilometres of chainage) are required numbers");
        }
        mapstore::TrackSegment segment;
        const mapstore::Result r =
            store_->Segment(req.matches[1], from_km * 1000.0, to_km * 1000.0, &segment);
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
        res.set_content(json{{"type", "FeatureCollection"}, {"features", {feature}}}.dump(),
                        "application/geo+json");
      }));

  http_.Post(
      R"(/api/v1/lines/([^/]+)/kmposts)",
      Route("lines.kmpost", true, [this](const httplib::Request& req, httplib::Response& res) {
        json body;
        if (!ParseObject(req, res, &body)) return;
        if (!body.contains("km") || !body["km"].is_number() || !body.contains("easting") ||
            !body["easting"].is_number() || !body.contains("northing") ||
            !body["northing"].is_number())
          return SendError(
              res,
              400,
              "invalid",
              "a km post needs km, easting and northing (numbers; UTM of the line's zone)");
        mapstore::LineInfo line;
        const mapstore::Result r = store_->PinKmPost(
            req.matches[1],
            (body.contains("label") && body["label"].is_string() ? body["label"].get<std::string>()
                                                                 : std::string()),
            body["km"].get<double>() * 1000.0,
            Eigen::Vector2d(body["easting"].get<double>(), body["northing"].get<double>()),
            &line);
        if (!r) return SendResult(res, r);
        res.set_content(LineJson(line).dump(), "application/json");
      }));

  http_.Post(
      "/api/v1/pois",
      Route("pois.create", true, [this](const httplib::Request& req, httplib::Response& res) {
        json body;
        if (!ParseObject(req, res, &body)) return;
        mapstore::Poi poi;
        std::string error;
        if (!ParsePoi(body, &poi, &error)) return SendError(res, 400, "invalid", error);
        const mapstore::Result r = store_->CreatePoi(&poi);
        if (!r) return SendResult(res, r);
        res.status = 201;
        res.set_header("Location", "/api/v1/pois/" + std::to_string(poi.id));
        res.set_content(PoiJson(poi).dump(), "application/json");
      }));

  http_.Get("/api/v1/pois",
            Route("pois.list", false, [this](const httplib::Request& req, httplib::Response& res) {
              Eigen::AlignedBox2d box;
              const Eigen::AlignedBox2d* in = nullptr;
              if (req.has_param("bbox")) {
                double v[4];
                if (std::sscanf(req.get_param_value("bbox").c_str(),
                                "%lf,%lf,%lf,%lf",
                                &v[0],
                                &v[1],
                                &v[2],
                                &v[3]) != 4)
                  return SendError(
                      res,
                      400,
                      "invalid",
                      "bbox must be min_easting,min_northing,max_easting,max_northing");
                box = Eigen::AlignedBox2d(Eigen::Vector2d(v[0], v[1]), Eigen::Vector2d(v[2], v[3]));
                in = &box;
              }
              std::vector<mapstore::Poi> pois;
              const mapstore::Result r = store_->ListPois(req.get_param_value("line"), in, &pois);
              if (!r) return SendResult(res, r);
              json list = json::array();
              for (const auto& p : pois) list.push_back(PoiJson(p));
              res.set_content(json{{"pois", list}}.dump(), "application/json");
            }));

  http_.Get(R"(/api/v1/pois/(\d+))",
            Route("pois.get", false, [this](const httplib::Request& req, httplib::Response& res) {
              SendOne<mapstore::Poi>(
                  req,
                  res,
                  [this](int64_t id, mapstore::Poi* poi) { return store_->GetPoi(id, poi); },
                  PoiJson);
            }));

  http_.Put(R"(/api/v1/pois/(\d+))",
            Route("pois.update", true, [this](const httplib::Request& req, httplib::Response& res) {
              int64_t id = 0;
              if (!RunId(req, res, &id)) return;
              json body;
              if (!ParseObject(req, res, &body)) return;
              mapstore::Poi poi;
              std::string error;
              if (!ParsePoi(body, &poi, &error)) return SendError(res, 400, "invalid", error);
              poi.id = id;
              const mapstore::Result r = store_->UpdatePoi(&poi);
              if (!r) return SendResult(res, r);
              res.set_content(PoiJson(poi).dump(), "application/json");
            }));

  http_.Delete(
      R"(/api/v1/pois/(\d+))",
      Route("pois.delete", true, [this](const httplib::Request& req, httplib::Response& res) {
        int64_t id = 0;
        if (!RunId(req, res, &id)) return;
        const mapstore::Result r = store_->DeletePoi(id);
        if (!r) return SendResult(res, r);
        res.status = 204;
      }));

  http_.Get(
      R"(/api/v1/runs/(\d+)/export)",
      Route("export", false, [this](const httplib::Request& req, httplib::Response& res) {
        int64_t id = 0;
        if (!RunId(req, res, &id)) return;
        mapstore::ExportRequest request;
        request.run_id = id;
        mapstore::ExportFormat format = mapstore::ExportFormat::kLas;
        if (req.has_param("format") &&
            !mapstore::ParseExportFormat(req.get_param_value("format"), &format))
          return SendError(res, 400, "invalid", "format must be ply, pcd or las");
        try {
          if (req.has_param("level")) request.level = std::stoi(req.get_param_value("level"));
          if (req.has_param("half_width_m"))
            request.half_width_m = std::stod(req.get_param_value("half_width_m"));
          if (req.has_param("line")) {
            request.line = req.get_param_value("line");
            request.from_m = 1000.0 * std::stod(req.get_param_value("from_km"));
            request.to_m = 1000.0 * std::stod(req.get_param_value("to_km"));
          }
        } catch (const std::exception&) {
          return SendError(res,
                           400,
                           "invalid",
                           "level, half_width_m, from_km and to_km must be numbers (a line needs "
                           "from_km and to_km)");
        }
        if (req.has_param("bbox")) {
          double v[4];
          if (std::sscanf(req.get_param_value("bbox").c_str(),
                          "%lf,%lf,%lf,%lf",
                          &v[0],
                          &v[1],
                          &v[2],
                          &v[3]) != 4)
            return SendError(res,
                             400,
                             "invalid",
                             "bbox must be min_easting,min_northing,max_easting,max_northing");
          request.has_box = true;
          request.box =
              Eigen::AlignedBox2d(Eigen::Vector2d(v[0], v[1]), Eigen::Vector2d(v[2], v[3]));
        }
        if (request.level < 0 || request.level >= store_->options().grid.levels)
          return SendError(
              res,
              400,
              "invalid",
              "level must be in [0, " + std::to_string(store_->options().grid.levels - 1) + "]");
        std::vector<mapstore::ExportPoint> points;
        std::string zone;
        const mapstore::Result r = store_->Export(request, &points, &zone);
        if (!r) return SendResult(res, r);
        std::string why;
        std::string body = mapstore::EncodeExport(points, format, zone, &why);
        if (body.empty())
          return SendError(res,
                           413,
                           "too_large",
                           std::to_string(points.size()) + " points: " + why +
                               "; ask for ply or pcd, or a smaller box");
        res.set_header("Content-Disposition",
                       "attachment; filename=\"run-" + std::to_string(id) + "." +
                           mapstore::ExtensionOf(format) + "\"");
        res.set_header("X-Points", std::to_string(points.size()));
        res.set_content(std::move(body), "application/octet-stream");
      }));

  if (!config_.web_root.empty()) http_.set_mount_point("/", config_.web_root);
}

Server::Server(ServerConfig config) : impl_(std::make_unique<Impl>(std::move(config))) {}
Server::~Server() { impl_->Stop(); }
bool Server::Start(std::string* error) { return impl_->Start(error); }
void Server::Wait() { impl_->Wait(); }
void Server::Stop() { impl_->Stop(); }
int Server::port() const { return impl_->port_; }
int Server::ws_port() const { return impl_->hub_ ? impl_->hub_->port() : -1; }
const std::string& Server::token_path() const { return impl_->token_path_; }
const ServerConfig& Server::config() const { return impl_->config_; }

}  // namespace raillomer::server
