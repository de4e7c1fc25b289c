#include "server/server_config.h"

#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "api/yaml_map_reader.h"

namespace raillomer::server {

bool ServerConfig::IsValid(std::string* error) const {
  if (data_dir.empty()) return *error = "data_dir (--data) is required", false;
  if (port < 0 || port > 65535) return *error = "port must be in [0, 65535]", false;
  if (ws_port < 0 || ws_port > 65535) return *error = "ws_port must be in [0, 65535]", false;
  if (max_body_bytes < 1024) return *error = "max_body_bytes must be at least 1024", false;
  if (max_json_bytes < 1024) return *error = "max_json_bytes must be at least 1024", false;
  if (max_poses_per_batch < 1) return *error = "max_poses_per_batch must be at least 1", false;
  if (http.max_header_bytes < 1024 || http.max_header_bytes > (1u << 20))
    return *error = "max_header_bytes must be in [1024, 1048576]", false;
  if (http.header_timeout_s < 1 || http.header_timeout_s > 600)
    return *error = "header_timeout_s must be in [1, 600]", false;
  if (http.request_timeout_s < 1 || http.request_timeout_s > 3600)
    return *error = "request_timeout_s must be in [1, 3600]", false;
  if (http.max_connections < 8 || http.max_connections > 1000000)
    return *error = "max_connections must be in [8, 1000000]", false;
  if (http.io_threads < 1 || http.io_threads > 64)
    return *error = "io_threads must be in [1, 64]", false;
  if (http.http_threads < 1 || http.http_threads > 1024)
    return *error = "http_threads must be in [1, 1024]", false;
  if (max_export_points < 1) return *error = "max_export_points must be at least 1", false;
  if (max_concurrent_exports < 1)
    return *error = "max_concurrent_exports must be at least 1", false;
  if (ws_threads < 1 || ws_threads > 64) return *error = "ws_threads must be in [1, 64]", false;
  if (ws_max_clients < 1) return *error = "ws_max_clients must be at least 1", false;
  if (ws_queue_messages < 8) return *error = "ws_queue_messages must be at least 8", false;
  if (!ingest_token.empty() && ingest_token.size() < 16)
    return *error = "ingest_token must be at least 16 characters", false;
  if (!read_token.empty() && read_token.size() < 16)
    return *error = "read_token must be at least 16 characters", false;
  if (changes.past_m < 0.0 || changes.mapped_past_m < 0.0)
    return *error = "changes.past_m and changes.mapped_past_m must be at least 0", false;
  if (changes.poll_ms < 10) return *error = "changes.poll_ms must be at least 10", false;
  if (changes.threads < 1 || changes.threads > 64)
    return *error = "changes.threads must be in [1, 64]", false;
  return store.IsValid(error) && changes.comparison.IsValid(error);
}

namespace {

/// The `changes:` section.
void ReadChanges(api::MapReader& c, ChangeWorkerOptions* o) {
  mapstore::RunComparisonOptions& k = o->comparison;
  c.Read("enabled", &o->enabled);
  c.Read("past_m", &o->past_m);
  c.Read("mapped_past_m", &o->mapped_past_m);
  c.Read("poll_ms", &o->poll_ms);
  c.Read("threads", &o->threads);
  c.Read("stretch_m", &k.stretch_m);
  c.Read("corridor_m", &k.corridor_m);
  c.Read("level_of_detection_m", &k.change.level_of_detection_m);
  c.Read("min_object_m", &k.change.min_object_m);
  c.Read("vegetation_zone_m", &k.clearance.vegetation_zone_m);
  c.Read("vegetation_allowance_m", &k.clearance.vegetation_allowance_m);
  if (c.Has("gauge_outline")) {
    std::vector<std::vector<double>> corners;
    c.Read("gauge_outline", &corners);
    k.clearance.gauge_outline.clear();
    for (const std::vector<double>& corner : corners) {
      if (corner.size() != 2)
        c.Fail(c.Node("gauge_outline"),
               "key 'changes.gauge_outline' must list [lateral_m, height_m] corners");
      k.clearance.gauge_outline.emplace_back(corner[0], corner[1]);
    }
  }
}

}  // namespace

bool LoadServerConfig(const std::string& path, ServerConfig* c, std::string* error) {
  std::error_code ec;
  const auto status = std::filesystem::status(path, ec);
  if (!std::filesystem::is_regular_file(status)) {
    *error = path + (std::filesystem::is_directory(status) ? ": a folder, not a config file"
                     : std::filesystem::exists(status)     ? ": not a regular file"
                                                           : ": no such file");
    return false;
  }
  try {
    const YAML::Node root_node = YAML::LoadFile(path);
    api::MapReader root(root_node, "", path);
    root.Read("data_dir", &c->data_dir);
    root.Read("host", &c->host);
    root.Read("port", &c->port);
    root.Read("ws_port", &c->ws_port);
    root.Read("ingest_token", &c->ingest_token);
    root.Read("reads_need_token", &c->reads_need_token);
    root.Read("read_token", &c->read_token);
    root.Read("max_body_bytes", &c->max_body_bytes);
    root.Read("max_json_bytes", &c->max_json_bytes);
    root.Read("max_poses_per_batch", &c->max_poses_per_batch);
    root.Read("max_header_bytes", &c->http.max_header_bytes);
    root.Read("header_timeout_s", &c->http.header_timeout_s);
    root.Read("request_timeout_s", &c->http.request_timeout_s);
    root.Read("max_connections", &c->http.max_connections);
    root.Read("io_threads", &c->http.io_threads);
    root.Read("http_threads", &c->http.http_threads);
    root.Read("max_export_points", &c->max_export_points);
    root.Read("max_concurrent_exports", &c->max_concurrent_exports);
    root.Read("ws_threads", &c->ws_threads);
    root.Read("ws_max_clients", &c->ws_max_clients);
    root.Read("ws_queue_messages", &c->ws_queue_messages);
    root.Read("web_root", &c->web_root);
    if (root.Has("store")) {
      api::MapReader s(root.Node("store"), "store", path);
      mapstore::StoreOptions& o = c->store;
      s.Read("tile_m", &o.grid.tile_m);
      s.Read("voxel_m", &o.grid.voxel_m);
      s.Read("levels", &o.grid.levels);
      s.Read("max_error_m", &o.grid.max_error_m);
      s.Read("max_points_per_submap", &o.max_points_per_submap);
      s.Read("hot_points_budget", &o.hot_points_budget);
      s.Read("hot_tiles_budget", &o.hot_tiles_budget);
      s.Read("max_submap_extent_m", &o.max_submap_extent_m);
      s.Read("draco_speed", &o.draco_speed);
      s.Read("encode_threads", &o.encode_threads);
      s.Read("flush_interval_ms", &o.flush_interval_ms);
      s.Read("flush_dirty_points", &o.flush_dirty_points);
      s.Finish();
    }
    if (root.Has("changes")) {
      api::MapReader changes(root.Node("changes"), "changes", path);
      ReadChanges(changes, &c->changes);
      changes.Finish();
    }
    root.Finish();
  } catch (const api::YamlError& e) {
    *error = e.what();
    return false;
  } catch (const YAML::Exception& e) {
    *error = path + ": " + e.what();
    return false;
  } catch (const std::exception& e) {  // the file could not be read
    *error = path + ": " + e.what();
    return false;
  }
  return true;
}

std::vector<std::pair<std::string, std::string>> DescribeConfig(const ServerConfig& c) {
  auto s = [](auto v) {
    std::ostringstream out;
    out << v;
    return out.str();
  };
  const mapstore::StoreOptions& o = c.store;
  const mapstore::RunComparisonOptions& k = c.changes.comparison;
  std::string outline;
  for (const Eigen::Vector2d& p : k.clearance.gauge_outline)
    outline += (outline.empty() ? "" : " ") + s(p.x()) + "," + s(p.y());
  return {
      {"data_dir", c.data_dir},
      {"host", c.host},
      {"port", s(c.port)},
      {"ws_port", s(c.ws_port)},
      {"ingest_token", c.ingest_token.empty() ? "(from data_dir/ingest.token)" : "(set, hidden)"},
      {"reads_need_token", c.reads_need_token ? "true" : "false"},
      {"read_token", c.read_token.empty() ? "(none)" : "(set, hidden)"},
      {"max_body_bytes", s(c.max_body_bytes)},
      {"max_json_bytes", s(c.max_json_bytes)},
      {"max_poses_per_batch", s(c.max_poses_per_batch)},
      {"max_header_bytes", s(c.http.max_header_bytes)},
      {"header_timeout_s", s(c.http.header_timeout_s)},
      {"request_timeout_s", s(c.http.request_timeout_s)},
      {"max_connections", s(c.http.max_connections)},
      {"io_threads", s(c.http.io_threads)},
      {"http_threads", s(c.http.http_threads)},
      {"max_export_points", s(c.max_export_points)},
      {"max_concurrent_exports", s(c.max_concurrent_exports)},
      {"ws_threads", s(c.ws_threads)},
      {"ws_max_clients", s(c.ws_max_clients)},
      {"ws_queue_messages", s(c.ws_queue_messages)},
      {"web_root",
       c.web_root.empty()
           ? "(none: build the viewer, npm --prefix web ci && npm --prefix web run build)"
           : c.web_root},
      {"store.tile_m", s(o.grid.tile_m)},
      {"store.voxel_m", s(o.grid.voxel_m)},
      {"store.levels", s(o.grid.levels)},
      {"store.max_error_m", s(o.grid.max_error_m)},
      {"store.max_points_per_submap", s(o.max_points_per_submap)},
      {"store.hot_points_budget", s(o.hot_points_budget)},
      {"store.hot_tiles_budget", s(o.hot_tiles_budget)},
      {"store.max_submap_extent_m", s(o.max_submap_extent_m)},
      {"store.draco_speed", s(o.draco_speed)},
      {"store.encode_threads", s(o.encode_threads)},
      {"store.flush_interval_ms", s(o.flush_interval_ms)},
      {"store.flush_dirty_points", s(o.flush_dirty_points)},
      {"changes.enabled", c.changes.enabled ? "true" : "false"},
      {"changes.past_m", s(c.changes.past_m)},
      {"changes.mapped_past_m", s(c.changes.mapped_past_m)},
      {"changes.poll_ms", s(c.changes.poll_ms)},
      {"changes.threads", s(c.changes.threads)},
      {"changes.stretch_m", s(k.stretch_m)},
      {"changes.corridor_m", s(k.corridor_m)},
      {"changes.level_of_detection_m", s(k.change.level_of_detection_m)},
      {"changes.min_object_m", s(k.change.min_object_m)},
      {"changes.vegetation_zone_m", s(k.clearance.vegetation_zone_m)},
      {"changes.vegetation_allowance_m", s(k.clearance.vegetation_allowance_m)},
      {"changes.gauge_outline", outline},
  };
}

bool ResolveIngestToken(ServerConfig* c, std::string* path, std::string* error) {
  path->clear();
  if (!c->ingest_token.empty()) return true;
  *path = c->data_dir + "/ingest.token";
  std::ifstream in(*path);
  if (in) {
    std::getline(in, c->ingest_token);
    if (c->ingest_token.size() < 16) {
      *error = *path + " holds no usable token (at least 16 characters); delete it to make one";
      return false;
    }
    return true;
  }
  std::random_device random;
  std::ostringstream hex;
  for (int i = 0; i < 32; ++i) {
    char byte[3];
    std::snprintf(byte, sizeof(byte), "%02x", static_cast<unsigned>(random() & 0xff));
    hex << byte;
  }
  c->ingest_token = hex.str();
  const mode_t old = umask(077);
  std::ofstream out(*path);
  out << c->ingest_token << "\n";
  umask(old);
  if (!out) {
    *error = "cannot write the ingest token to " + *path;
    return false;
  }
  return true;
}

}  // namespace raillomer::server
