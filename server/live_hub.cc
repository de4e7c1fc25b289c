#include "server/live_hub.h"

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <limits>
#include <mutex>
#include <set>
#include <thread>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>
#include <nlohmann/json.hpp>

#include "api/clock.h"
#include "server/api_json.h"
#include "server/http_parse.h"

namespace raillomer::server {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;

using api::NowNs;

/// One message for every subscriber of a run (run 0: for everyone).
struct Message {
  int64_t run_id = 0;
  bool pose = false;  ///< poses are dropped first when a client falls behind
  std::string text;
};

/// The value of `key` in the target's query string ("" if absent).
std::string QueryValue(const std::string& target, const std::string& key) {
  const size_t q = target.find('?');
  if (q == std::string::npos) return "";
  std::string query = target.substr(q + 1);
  size_t pos = 0;
  while (pos <= query.size()) {
    const size_t end = std::min(query.find('&', pos), query.size());
    const std::string pair = query.substr(pos, end - pos);
    const size_t eq = pair.find('=');
    if (eq != std::string::npos && pair.substr(0, eq) == key) return pair.substr(eq + 1);
    pos = end + 1;
  }
  return "";
}

}  // namespace

class LiveHub::Impl {
 public:
  class WsSession;
  class HttpSession;

  Impl(const Options& options, Authorize authorize)
      : options_(options), authorize_(std::move(authorize)), acceptor_(ioc_) {}

  bool Start(std::string* error) {
    beast::error_code ec;
    const auto address = net::ip::make_address(options_.host, ec);
    if (ec) {
      *error = "bad WebSocket host '" + options_.host + "': " + ec.message();
      return false;
    }
    const tcp::endpoint endpoint(address, static_cast<unsigned short>(options_.port));
    acceptor_.open(endpoint.protocol(), ec);
    if (!ec) acceptor_.set_option(net::socket_base::reuse_address(true), ec);
    if (!ec) acceptor_.bind(endpoint, ec);
    if (!ec) acceptor_.listen(net::socket_base::max_listen_connections, ec);
    if (ec) {
      *error = "cannot listen for WebSocket clients on " + options_.host + ":" +
               std::to_string(options_.port) + ": " + ec.message();
      return false;
    }
    port_ = acceptor_.local_endpoint().port();
    Accept();
    for (int i = 0; i < std::max(1, options_.threads); ++i)
      threads_.emplace_back([this] { ioc_.run(); });
    return true;
  }

  void Stop() {
    ioc_.stop();
    for (std::thread& t : threads_) t.join();
    threads_.clear();
  }

  void Accept();

  void Add(const std::shared_ptr<WsSession>& session) {
    std::lock_guard<std::mutex> lock(mu_);
    sessions_.erase(std::remove_if(sessions_.begin(),
                                   sessions_.end(),
                                   [](const std::weak_ptr<WsSession>& w) { return w.expired(); }),
                    sessions_.end());
    sessions_.push_back(session);
    ++connections_;
  }

  void Publish(std::shared_ptr<const Message> message);

  Options options_;
  Authorize authorize_;
  net::io_context ioc_;
  tcp::acceptor acceptor_;
  std::vector<std::thread> threads_;
  int port_ = 0;
  mutable std::mutex mu_;
  std::vector<std::weak_ptr<WsSession>> sessions_;
  std::atomic<uint64_t> clients_{0}, pending_{0}, connections_{0}, refused_{0}, sent_{0},
      dropped_{0};
};

/// An accepted WebSocket client: its subscriptions and its bounded queue, all on its strand.
class LiveHub::Impl::WsSession : public std::enable_shared_from_this<WsSession> {
 public:
  WsSession(Impl* hub, tcp::socket&& socket, std::set<int64_t> runs)
      : hub_(hub), ws_(std::move(socket)), runs_(std::move(runs)) {}
  ~WsSession() { --hub_->clients_; }

  void Run(http::request<http::string_body> request) {
    ++hub_->clients_;
    // A fixed kernel send buffer: what a client has not taken waits in the bounded queue, where
    // it can be dropped, not in an ever-growing socket buffer.
    beast::error_code ignored;
    beast::get_lowest_layer(ws_).socket().set_option(net::socket_base::send_buffer_size(64 * 1024),
                                                     ignored);
    ws_.set_option(websocket::stream_base::timeout::suggested(beast::role_type::server));
    ws_.read_message_max(kMaxCommandBytes);  // a longer message closes the connection (1009)
    ws_.async_accept(request, [self = shared_from_this()](beast::error_code ec) {
      if (ec) return;
      self->hub_->Add(self);
      self->Read();
    });
  }

  void Deliver(std::shared_ptr<const Message> message) {
    net::post(ws_.get_executor(),
              [self = shared_from_this(), message]() { self->Enqueue(std::move(message)); });
  }

 private:
  void Read() {
    ws_.async_read(buffer_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) return;  // closed: the session ends with its last handler
      self->OnCommand(beast::buffers_to_string(self->buffer_.data()));
      self->buffer_.consume(self->buffer_.size());
      self->Read();
    });
  }

  void OnCommand(const std::string& text) {
    nlohmann::json reply;
    std::set<int64_t> add, remove;
    const std::string error = ParseCommand(text, &add, &remove);
    if (!error.empty()) {
      reply = {{"type", "error"}, {"message", error}};
    } else if (const std::set<int64_t> runs = Subscribed(add, remove);
               !runs.count(0) && runs.size() > kMaxRuns) {
      reply = {{"type", "error"},
               {"message",
                "at most " + std::to_string(kMaxRuns) +
                    " runs at once: subscribe to \"all\" to follow more"}};
    } else {
      runs_ = Subscribed(add, remove);
      reply = {{"type", "subscribed"}, {"runs", nlohmann::json::array()}};
      for (int64_t r : runs_)
        reply["runs"].push_back(r == 0 ? nlohmann::json("all") : nlohmann::json(r));
    }
    auto m = std::make_shared<Message>();
    m->text = JsonText(reply);
    Push(std::move(m));
  }

  /// The runs this client would follow after a command.
  std::set<int64_t> Subscribed(const std::set<int64_t>& add,
                               const std::set<int64_t>& remove) const {
    std::set<int64_t> runs = runs_;
    runs.insert(add.begin(), add.end());
    for (int64_t r : remove) runs.erase(r);
    return runs;
  }

  /// A command's runs to follow and to let go (0: every run); what is wrong with it, or "".
  static std::string ParseCommand(const std::string& text,
                                  std::set<int64_t>* add,
                                  std::set<int64_t>* remove) {
    nlohmann::json command;
    const std::string unparsed = ParseJson(text, &command);
    if (!unparsed.empty()) return "a command must be JSON: " + unparsed;
    if (!command.is_object() ||
        (!command.contains("subscribe") && !command.contains("unsubscribe")))
      return "send {\"subscribe\": [run ids]} or {\"subscribe\": \"all\"}, or "
             "{\"unsubscribe\": [...]}";
    const std::string unknown = UnknownMember(command, {"subscribe", "unsubscribe"});
    if (!unknown.empty()) return unknown;
    for (const auto& [key, value] : command.items()) {
      const std::string wrong = RunsOf(value, key == "subscribe" ? add : remove);
      if (!wrong.empty()) return key + ": " + wrong;
    }
    return "";
  }

  /// "all", a run id or an array of them into `out`; what is wrong, or "".
  static std::string RunsOf(const nlohmann::json& v, std::set<int64_t>* out) {
    if (v.is_string() && v.get<std::string>() == "all") {
      out->insert(0);
      return "";
    }
    const nlohmann::json runs = v.is_array() ? v : nlohmann::json::array({v});
    if (runs.size() > kMaxRuns) return "at most " + std::to_string(kMaxRuns) + " runs at once";
    for (const nlohmann::json& r : runs) {
      // A run id is a whole number from 1.
      if (!FitsInt64(r) || r.get<int64_t>() < 1)
        return "\"all\", a run id or a list of run ids (whole numbers from 1), not " + r.dump();
      out->insert(r.get<int64_t>());
    }
    return "";
  }

  void Enqueue(std::shared_ptr<const Message> m) {
    if (m->run_id != 0 && !runs_.count(m->run_id) && !runs_.count(0)) return;
    Push(std::move(m));
  }

  void Push(std::shared_ptr<const Message> m) {
    if (queue_.size() >= hub_->options_.queue_messages) {
      // Full: the oldest queued pose goes (the front may be being written), else the oldest
      // message that is not being written.
      const size_t first = writing_ ? 1 : 0;
      size_t victim = queue_.size();
      for (size_t i = first; i < queue_.size(); ++i) {
        if (queue_[i]->pose) {
          victim = i;
          break;
        }
      }
      if (victim == queue_.size()) victim = first;
      if (victim < queue_.size()) {
        queue_.erase(queue_.begin() + static_cast<std::ptrdiff_t>(victim));
      } else {
        ++hub_->dropped_;  // nothing can go: the new one does
        return;
      }
      ++hub_->dropped_;
    }
    queue_.push_back(std::move(m));
    if (!writing_) Write();
  }

  void Write() {
    writing_ = true;
    ws_.text(true);
    ws_.async_write(net::buffer(queue_.front()->text),
                    [self = shared_from_this()](beast::error_code ec, size_t) {
                      self->queue_.pop_front();
                      if (ec) {
                        self->queue_.clear();
                        self->writing_ = false;
                        return;
                      }
                      ++self->hub_->sent_;
                      if (!self->queue_.empty()) {
                        self->Write();
                      } else {
                        self->writing_ = false;
                      }
                    });
  }

  /// Runs one client follows at most; a command is a few dozen bytes, kMaxCommandBytes at most.
  static constexpr size_t kMaxRuns = 256;
  static constexpr size_t kMaxCommandBytes = 16 * 1024;

  Impl* hub_;
  websocket::stream<beast::tcp_stream> ws_;
  beast::flat_buffer buffer_;
  std::set<int64_t> runs_;  ///< 0: every run
  std::deque<std::shared_ptr<const Message>> queue_;
  bool writing_ = false;
};

/// A new connection: reads the HTTP upgrade request, checks the path and the token.
class LiveHub::Impl::HttpSession : public std::enable_shared_from_this<HttpSession> {
 public:
  HttpSession(Impl* hub, tcp::socket&& socket) : hub_(hub), stream_(std::move(socket)) {
    ++hub_->pending_;
  }
  ~HttpSession() { --hub_->pending_; }

  void Run() {
    if (hub_->pending_ + hub_->clients_ > static_cast<uint64_t>(hub_->options_.max_clients)) {
      http::request<http::string_body> none;
      Refuse(none,
             http::status::service_unavailable,
             "the live hub has ws_max_clients (" + std::to_string(hub_->options_.max_clients) +
                 ") connections open");
      return;
    }
    stream_.expires_after(std::chrono::seconds(hub_->options_.header_timeout_s));
    parser_.header_limit(16 * 1024);
    parser_.body_limit(64 * 1024);
    http::async_read(
        stream_, buffer_, parser_, [self = shared_from_this()](beast::error_code ec, size_t) {
          if (!ec) return self->OnRequest();
          self->RefuseUnread(ec);
        });
  }

 private:
  void OnRequest() {
    http::request<http::string_body> request = parser_.release();
    const std::string target(request.target());
    const std::string path = target.substr(0, target.find('?'));
    std::string token = QueryValue(target, "token");
    const auto auth = request.find(http::field::authorization);
    if (auth != request.end()) {
      const std::string value(auth->value());
      if (value.rfind("Bearer ", 0) == 0) token = value.substr(7);
    }
    if (!websocket::is_upgrade(request) || (path != "/live" && path != "/api/v1/live")) {
      Refuse(request, http::status::not_found, "the live hub is a WebSocket at /live");
      return;
    }
    if (!hub_->authorize_(token)) {
      Refuse(request, http::status::unauthorized, "a valid read token is needed");
      return;
    }
    if (request[http::field::sec_websocket_key].empty() ||
        request[http::field::sec_websocket_version] != "13") {
      Refuse(request,
             http::status::bad_request,
             "a WebSocket upgrade needs Sec-WebSocket-Key and Sec-WebSocket-Version: 13");
      return;
    }
    std::set<int64_t> runs;
    const std::string run = QueryValue(target, "run");
    if (!run.empty()) {
      int64_t id = 0;
      if (!ParseInt64(run, 1, std::numeric_limits<int64_t>::max(), &id)) {
        Refuse(request, http::status::bad_request, "run must be a run id (got '" + run + "')");
        return;
      }
      runs.insert(id);
    }
    stream_.expires_never();
    std::make_shared<WsSession>(hub_, stream_.release_socket(), std::move(runs))
        ->Run(std::move(request));
  }

  /// An upgrade request that could not be read whole: answered when it broke a limit or did
  /// not parse; a connection closed or timed out gets nothing.
  void RefuseUnread(beast::error_code ec) {
    http::request<http::string_body> none;
    if (ec == http::error::header_limit)
      Refuse(none,
             http::status::request_header_fields_too_large,
             "the upgrade's header is over 16 KiB");
    else if (ec == http::error::body_limit)
      Refuse(none, http::status::payload_too_large, "an upgrade request carries no body");
    else if (ec.category() == http::make_error_code(http::error::bad_method).category() &&
             ec != http::error::end_of_stream && ec != http::error::partial_message)
      Refuse(
          none, http::status::bad_request, "the upgrade request does not parse: " + ec.message());
  }

  /// The error code a refusal's body names.
  static const char* CodeOf(http::status status) {
    switch (status) {
      case http::status::unauthorized:
        return "unauthorized";
      case http::status::service_unavailable:
        return "busy";
      case http::status::not_found:
        return "not_found";
      case http::status::request_header_fields_too_large:
        return "header_too_large";
      case http::status::payload_too_large:
        return "too_large";
      default:
        return "bad_request";
    }
  }

  void Refuse(const http::request<http::string_body>& request,
              http::status status,
              const std::string& message) {
    ++hub_->refused_;
    stream_.expires_after(std::chrono::seconds(5));
    auto response = std::make_shared<http::response<http::string_body>>(status, request.version());
    response->set(http::field::content_type, "application/json");
    // The message may quote a target that is not UTF-8.
    response->body() = JsonText({{"error", {{"code", CodeOf(status)}, {"message", message}}}});
    response->prepare_payload();
    http::async_write(
        stream_, *response, [self = shared_from_this(), response](beast::error_code, size_t) {
          beast::error_code ignored;
          self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
        });
  }

  Impl* hub_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  http::request_parser<http::string_body> parser_;
};

void LiveHub::Impl::Accept() {
  acceptor_.async_accept(net::make_strand(ioc_), [this](beast::error_code ec, tcp::socket s) {
    if (!ec) std::make_shared<HttpSession>(this, std::move(s))->Run();
    if (acceptor_.is_open()) Accept();
  });
}

void LiveHub::Impl::Publish(std::shared_ptr<const Message> message) {
  std::vector<std::shared_ptr<WsSession>> live;
  {
    std::lock_guard<std::mutex> lock(mu_);
    for (const auto& w : sessions_) {
      if (auto s = w.lock()) live.push_back(std::move(s));
    }
  }
  for (const auto& s : live) s->Deliver(message);
}

LiveHub::LiveHub(const Options& options, Authorize authorize)
    : impl_(std::make_unique<Impl>(options, std::move(authorize))) {}

LiveHub::~LiveHub() { Stop(); }

bool LiveHub::Start(std::string* error) { return impl_->Start(error); }
int LiveHub::port() const { return impl_->port_; }
void LiveHub::Stop() { impl_->Stop(); }

void LiveHub::PublishPose(int64_t run_id, const api::StreamPose& p) {
  auto m = std::make_shared<Message>();
  m->run_id = run_id;
  m->pose = true;
  m->text = nlohmann::json{
      {"type", "pose"},
      {"run", run_id},
      {"sequence", p.sequence},
      {"stamp_ns", p.stamp_ns},
      {"georeferenced", p.georeferenced},
      {"utm_zone", p.utm_zone},
      {"p", {p.p.x(), p.p.y(), p.p.z()}},
      {"q", {p.q.x(), p.q.y(), p.q.z(), p.q.w()}},
      {"sent_ns",
       NowNs()}}.dump();
  impl_->Publish(std::move(m));
}

void LiveHub::PublishTiles(const std::vector<mapstore::TileUpdate>& updates) {
  std::map<int64_t, nlohmann::json> by_run;
  for (const mapstore::TileUpdate& u : updates) {
    by_run[u.run_id].push_back(
        {{"level", u.key.level}, {"ix", u.key.ix}, {"iy", u.key.iy}, {"version", u.version}});
  }
  for (auto& [run, tiles] : by_run) {
    auto m = std::make_shared<Message>();
    m->run_id = run;
    m->text =
        nlohmann::json{{"type", "tiles"}, {"run", run}, {"tiles", tiles}, {"sent_ns", NowNs()}}
            .dump();
    impl_->Publish(std::move(m));
  }
}

void LiveHub::PublishRun(const mapstore::RunInfo& run) {
  auto m = std::make_shared<Message>();
  m->run_id = run.id;
  m->text = nlohmann::json{
      {"type", "run"},
      {"run", run.id},
      {"status", run.status},
      {"line", run.line},
      {"submaps", run.submaps},
      {"sent_ns",
       NowNs()}}.dump();
  impl_->Publish(std::move(m));
}

void LiveHub::PublishMessage(int64_t run_id, std::string json_text) {
  auto m = std::make_shared<Message>();
  m->run_id = run_id;
  m->text = std::move(json_text);
  impl_->Publish(std::move(m));
}

HubStats LiveHub::stats() const {
  HubStats s;
  s.clients = impl_->clients_;
  s.connections = impl_->connections_;
  s.refused = impl_->refused_;
  s.sent = impl_->sent_;
  s.dropped = impl_->dropped_;
  return s;
}

}  // namespace raillomer::server
