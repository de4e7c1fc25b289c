#pragma once

#include <functional>
#include <vector>

#include "mapstore/change_store.h"
#include "mapstore/map_store.h"
#include "server/change_worker.h"
#include "server/http_front.h"
#include "server/live_hub.h"
#include "server/metrics.h"
#include "server/server_config.h"
#include "server/tile_cache.h"

namespace raillomer::server {

/// What the API's handlers work on; owned by the server, alive while it serves.
struct ApiContext {
  const ServerConfig* config = nullptr;
  mapstore::MapStore* store = nullptr;
  LiveHub* hub = nullptr;
  Metrics* metrics = nullptr;
  TileCache* tiles = nullptr;
  mapstore::ChangeStore* changes = nullptr;
  ChangeWorker* change_worker = nullptr;
  mapstore::ProvisionalMap* provisional = nullptr;  ///< live runs' provisional output
  std::function<HttpFrontStats()> front_stats;
};

/// Every route of the REST API (api/openapi.yaml), /health and /metrics, with its access and
/// body limit.
std::vector<HttpRoute> ApiRoutes(const ApiContext& context);
/// The change-detection routes (change_routes.cc), part of ApiRoutes.
std::vector<HttpRoute> ChangeRoutes(const ApiContext& context);

}  // namespace raillomer::server
