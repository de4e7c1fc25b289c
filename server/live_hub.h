#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "api/stream.h"
#include "mapstore/map_store.h"

namespace raillomer::server {

struct HubStats {
  uint64_t clients = 0;      ///< connected now
  uint64_t connections = 0;  ///< accepted since start
  uint64_t refused = 0;      ///< upgrade requests refused (no or wrong token, wrong path)
  uint64_t sent = 0;         ///< messages written to clients
  uint64_t dropped = 0;      ///< messages dropped for clients too slow to take them
};

/// The live WebSocket hub (Boost.Beast). A client connects to ws://host:port/live (with
/// ?token=... or an Authorization header when reads need a token), sends
/// {"subscribe": [run ids]} or {"subscribe": "all"} (and {"unsubscribe": [...]}), and receives
/// JSON messages: "pose" (each pose as it is ingested), "tiles" (tiles written, with their
/// versions), "run" (a run created or finished) and "change" (changes found or closed, with
/// the run's detection state). Each client has a bounded queue: when a
/// client cannot keep up, its oldest queued poses are dropped first and counted, so a slow
/// client never holds up the others.
class LiveHub {
 public:
  struct Options {
    std::string host = "127.0.0.1";
    int port = 0;  ///< 0: the OS picks
    int threads = 2;
    size_t queue_messages = 512;
    /// Connections open at once, upgraded or still sending their upgrade request; beyond it
    /// a new connection is refused (503).
    int max_clients = 256;
    int header_timeout_s = 10;  ///< for the upgrade request to arrive whole
  };
  /// True if the token (empty when the client gave none) may read.
  using Authorize = std::function<bool(const std::string& token)>;

  LiveHub(const Options& options, Authorize authorize);
  ~LiveHub();
  LiveHub(const LiveHub&) = delete;
  LiveHub& operator=(const LiveHub&) = delete;

  /// Binds and starts serving on its own threads; false with a message if it cannot bind.
  bool Start(std::string* error);
  int port() const;
  void Stop();

  void PublishPose(int64_t run_id, const api::StreamPose& pose);
  void PublishTiles(const std::vector<mapstore::TileUpdate>& updates);
  void PublishRun(const mapstore::RunInfo& run);
  /// Any other message of a run (a JSON object's text with its "type"): `change` messages.
  void PublishMessage(int64_t run_id, std::string json_text);
  HubStats stats() const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace raillomer::server
