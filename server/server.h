#pragma once

#include <memory>
#include <string>

#include "server/server_config.h"

namespace raillomer::server {

/// raillomer-server: the REST API (cpp-httplib) and the live WebSocket hub (Boost.Beast) over a
/// map store. REST lives under /api/v1/ (api/openapi.yaml describes it), health at /health,
/// Prometheus metrics at /metrics, the viewer's static files (web_root) at /.
class Server {
 public:
  explicit Server(ServerConfig config);
  ~Server();
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  /// Opens the store, settles the ingest token, binds both ports and starts serving on
  /// background threads; false with a message naming what failed.
  bool Start(std::string* error);
  /// Blocks until Stop() (from another thread or a signal handler's thread).
  void Wait();
  void Stop();

  int port() const;
  int ws_port() const;
  /// Where the ingest token is kept ("" if the config gives it).
  const std::string& token_path() const;
  const ServerConfig& config() const;
  /// What opening the store recovered and found lost (after Start).
  const mapstore::RecoveryReport& recovery() const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace raillomer::server
