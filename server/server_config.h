#pragma once

#include <string>
#include <utility>
#include <vector>

#include "mapstore/map_store.h"
#include "server/change_worker.h"
#include "server/http_front.h"

namespace raillomer::server {

/// Everything raillomer-server runs with: a YAML file (`--config`) overridden by flags.
struct ServerConfig {
  std::string data_dir;            ///< the store's folder (index, tiles, tokens)
  std::string host = "127.0.0.1";  ///< the address to listen on
  int port = 8470;                 ///< HTTP; 0 lets the OS pick
  int ws_port = 0;                 ///< WebSocket live hub; 0: port + 1 (or OS-picked with port 0)
  /// The bearer token for ingest and every write. Empty: read from <data_dir>/ingest.token,
  /// generated there on first start.
  std::string ingest_token;
  /// Reads (GET, the live hub) need a token too when true: read_token, or the ingest token.
  bool reads_need_token = false;
  std::string read_token;
  size_t max_body_bytes = 64u << 20;   ///< a submap body beyond it is refused (413)
  size_t max_json_bytes = 8u << 20;    ///< a pose batch's JSON body beyond it is refused (413)
  size_t max_poses_per_batch = 10000;  ///< more poses in one batch are refused (413)
  /// The HTTP front's limits and threads: the keys io_threads, http_threads, max_connections,
  /// max_header_bytes, header_timeout_s and request_timeout_s at the top level.
  HttpLimits http;
  /// An export of more points is refused. Exports are sent a tile at a time (their points
  /// never sit in memory whole), so this bounds the work of one, not its memory.
  size_t max_export_points = 200'000'000;
  int max_concurrent_exports = 2;  ///< exports under way at once (503 beyond)
  int ws_threads = 2;
  int ws_max_clients = 256;        ///< live connections open at once, upgraded or not
  size_t ws_queue_messages = 512;  ///< per live client; beyond it old poses are dropped
  std::string web_root;            ///< the viewer's static files (empty: none served)
  mapstore::StoreOptions store;
  /// Change detection (the `changes:` section): on or off, when a live run's stretch is
  /// compared, the comparison's stretch and corridor, and the clearance it checks against.
  ChangeWorkerOptions changes;

  bool IsValid(std::string* error) const;
};

/// Reads a YAML config into `config` (keys left out keep their values); unknown keys and
/// values of the wrong type are refused with the file, line and key.
bool LoadServerConfig(const std::string& path, ServerConfig* config, std::string* error);

/// Every value in effect, as (key, value) in config-file spelling, tokens redacted.
std::vector<std::pair<std::string, std::string>> DescribeConfig(const ServerConfig& config);

/// The ingest token in effect: the config's, else <data_dir>/ingest.token, which is generated
/// (32 random bytes, hex, mode 0600) if missing. `path` gets where it is kept ("" if config).
bool ResolveIngestToken(ServerConfig* config, std::string* path, std::string* error);

}  // namespace raillomer::server
