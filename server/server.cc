#include "server/server.h"

#include <chrono>
#include <condition_variable>
#include <mutex>

#include "api/clock.h"
#include "server/change_json.h"
#include "server/http_front.h"
#include "server/live_hub.h"
#include "server/metrics.h"
#include "server/routes.h"
#include "server/tile_cache.h"

namespace raillomer::server {
namespace {

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

}  // namespace

class Server::Impl {
 public:
  explicit Impl(ServerConfig config) : config_(std::move(config)) {}

  bool Start(std::string* error) {
    if (!config_.IsValid(error)) return false;
    store_ = mapstore::MapStore::Open(config_.data_dir, config_.store, error);
    if (!store_) return false;
    if (!ResolveIngestToken(&config_, &token_path_, error)) return false;
    if (!StartHub(error)) return false;
    store_->SetTileListener([this](const std::vector<mapstore::TileUpdate>& u) {
      tiles_.Invalidate(u);
      hub_->PublishTiles(u);
    });
    if (!StartChanges(error)) return false;
    ApiContext context;
    context.config = &config_;
    context.store = store_.get();
    context.hub = hub_.get();
    context.metrics = &metrics_;
    context.tiles = &tiles_;
    context.changes = changes_.get();
    context.change_worker = worker_.get();
    context.provisional = &provisional_;
    context.front_stats = [this] { return http_->stats(); };
    HttpFront::Hooks hooks;
    hooks.authorize = [this](const std::string& token, Access access) {
      return access == Access::kWrite ? CanWrite(token) : CanRead(token);
    };
    hooks.observe = [this](const std::string& route, int status, double seconds) {
      metrics_.Observe(route, status, seconds);
    };
    http_ = std::make_unique<HttpFront>(
        config_.http, ApiRoutes(context), config_.web_root, std::move(hooks));
    if (!http_->Start(config_.host, config_.port, error)) {
      *error += " (in use, or not an address of this machine?)";
      return false;
    }
    return true;
  }

  bool StartHub(std::string* error) {
    LiveHub::Options o;
    o.host = config_.host;
    o.port = config_.ws_port != 0 ? config_.ws_port : config_.port != 0 ? config_.port + 1 : 0;
    o.threads = config_.ws_threads;
    o.queue_messages = config_.ws_queue_messages;
    o.max_clients = config_.ws_max_clients;
    o.header_timeout_s = config_.http.header_timeout_s;
    hub_ = std::make_unique<LiveHub>(o, [this](const std::string& t) { return CanRead(t); });
    return hub_->Start(error);
  }

  /// Change detection's records and its worker, which announces what it finds on the hub.
  bool StartChanges(std::string* error) {
    changes_ = mapstore::ChangeStore::Open(store_->IndexPath(), error);
    if (!changes_) return false;
    worker_ =
        std::make_unique<ChangeWorker>(store_.get(),
                                       changes_.get(),
                                       &provisional_,
                                       config_.changes,
                                       [this](const std::vector<mapstore::StoredChange>& found,
                                              const std::vector<mapstore::StoredChange>& closed,
                                              const std::vector<mapstore::StoredChange>& withdrawn,
                                              const mapstore::DetectionState& state) {
                                         AnnounceChanges(found, closed, withdrawn, state);
                                       });
    worker_->Start();
    return true;
  }

  void AnnounceChanges(const std::vector<mapstore::StoredChange>& found,
                       const std::vector<mapstore::StoredChange>& closed,
                       const std::vector<mapstore::StoredChange>& withdrawn,
                       const mapstore::DetectionState& state) {
    nlohmann::json features = nlohmann::json::array(), closing = nlohmann::json::array(),
                   gone = nlohmann::json::array();
    for (const mapstore::StoredChange& c : found) features.push_back(ChangeFeature(c));
    for (const mapstore::StoredChange& c : closed) closing.push_back(ChangeFeature(c));
    for (const mapstore::StoredChange& c : withdrawn) gone.push_back(c.id);
    hub_->PublishMessage(state.run_id,
                         nlohmann::json{{"type", "change"},
                                        {"run", state.run_id},
                                        {"changes", features},
                                        {"closed", closing},
                                        {"withdrawn", gone},
                                        {"detection", DetectionJson(state, "")},
                                        {"sent_ns", api::NowNs()}}
                             .dump());
  }

  void Stop() {
    {
      std::lock_guard<std::mutex> lock(stop_mu_);
      if (stopped_) return;
      stopped_ = true;
    }
    if (http_) http_->Stop();      // running handlers finish first
    if (worker_) worker_->Stop();  // the stretch under way finishes first
    if (hub_) hub_->Stop();
    worker_.reset();
    changes_.reset();
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

  ServerConfig config_;
  std::string token_path_;
  std::unique_ptr<mapstore::MapStore> store_;
  std::unique_ptr<mapstore::ChangeStore> changes_;
  mapstore::ProvisionalMap provisional_;
  std::unique_ptr<ChangeWorker> worker_;
  std::unique_ptr<LiveHub> hub_;
  std::unique_ptr<HttpFront> http_;
  Metrics metrics_;
  TileCache tiles_{256u << 20};
  std::mutex stop_mu_;
  std::condition_variable stop_cv_;
  bool stopped_ = false;
};

Server::Server(ServerConfig config) : impl_(std::make_unique<Impl>(std::move(config))) {}
Server::~Server() { impl_->Stop(); }
bool Server::Start(std::string* error) { return impl_->Start(error); }
void Server::Wait() { impl_->Wait(); }
void Server::Stop() { impl_->Stop(); }
int Server::port() const { return impl_->http_ ? impl_->http_->port() : -1; }
int Server::ws_port() const { return impl_->hub_ ? impl_->hub_->port() : -1; }
const std::string& Server::token_path() const { return impl_->token_path_; }
const ServerConfig& Server::config() const { return impl_->config_; }
const mapstore::RecoveryReport& Server::recovery() const { return impl_->store_->recovery(); }

}  // namespace raillomer::server
