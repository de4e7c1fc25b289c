#include "server/http_front.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <optional>
#include <thread>

#include <boost/asio.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <nlohmann/json.hpp>

#include "server/http_parse.h"
#include "server/static_files.h"

namespace raillomer::server {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using Clock = std::chrono::steady_clock;

/// Bytes of a body written per write: a slow reader gets io_timeout_s for each of them.
constexpr uint64_t kWriteChunkBytes = 256 * 1024;
/// After an answer that closes the connection, what the client still sends (a refused body)
/// is read and dropped, so the client reads the answer instead of a reset: while it keeps
/// coming (a pause of kLingerPause ends it), for at most kLingerTime. It costs no memory.
constexpr auto kLingerPause = std::chrono::seconds(2);
constexpr auto kLingerTime = std::chrono::seconds(30);

const char* StatusText(int status) {
  switch (status) {
    case 100:
      return "Continue";
    case 200:
      return "OK";
    case 201:
      return "Created";
    case 204:
      return "No Content";
    case 206:
      return "Partial Content";
    case 304:
      return "Not Modified";
    case 400:
      return "Bad Request";
    case 401:
      return "Unauthorized";
    case 403:
      return "Forbidden";
    case 404:
      return "Not Found";
    case 405:
      return "Method Not Allowed";
    case 408:
      return "Request Timeout";
    case 409:
      return "Conflict";
    case 411:
      return "Length Required";
    case 413:
      return "Content Too Large";
    case 415:
      return "Unsupported Media Type";
    case 416:
      return "Range Not Satisfiable";
    case 431:
      return "Request Header Fields Too Large";
    case 500:
      return "Internal Server Error";
    case 501:
      return "Not Implemented";
    case 503:
      return "Service Unavailable";
    default:
      return status < 300 ? "OK" : status < 500 ? "Client Error" : "Server Error";
  }
}

/// A header value without CR or LF, so no value can start a header of its own.
std::string HeaderSafe(const std::string& value) {
  std::string out;
  out.reserve(value.size());
  for (char c : value)
    if (c != '\r' && c != '\n') out += c;
  return out;
}

std::string Join(const std::vector<std::string>& items, const char* separator) {
  std::string out;
  for (const std::string& s : items) out += (out.empty() ? "" : separator) + s;
  return out;
}

}  // namespace

bool HttpRequest::HasParam(const std::string& name) const {
  for (const auto& [k, v] : params)
    if (k == name) return true;
  return false;
}

std::string HttpRequest::Param(const std::string& name) const {
  for (const auto& [k, v] : params)
    if (k == name) return v;
  return "";
}

std::string HttpRequest::Header(const std::string& name) const {
  for (const auto& [k, v] : headers)
    if (EqualsIgnoreCase(k, name)) return v;
  return "";
}

void HttpResponse::SetHeader(const std::string& name, const std::string& value) {
  for (auto& [k, v] : headers) {
    if (EqualsIgnoreCase(k, name)) {
      v = value;
      return;
    }
  }
  headers.emplace_back(name, value);
}

void HttpResponse::SetContent(std::string bytes, const std::string& type) {
  body = std::move(bytes);
  shared_body.reset();
  file_path.clear();
  produce = nullptr;
  content_type = type;
}

void HttpResponse::SetSharedContent(std::shared_ptr<const std::string> bytes,
                                    const std::string& type) {
  body.clear();
  shared_body = std::move(bytes);
  file_path.clear();
  produce = nullptr;
  content_type = type;
}

void HttpResponse::SetError(int code_status, const std::string& code, const std::string& message) {
  status = code_status;
  // Messages may quote request data: bytes that are not UTF-8 are replaced, never thrown on.
  SetContent(nlohmann::json{{"error", {{"code", code}, {"message", message}}}}.dump(
                 -1, ' ', false, nlohmann::json::error_handler_t::replace),
             "application/json");
}

uint64_t HttpResponse::BodySize() const {
  if (produce) return produced_size;
  if (!file_path.empty()) return file_size;
  return shared_body ? shared_body->size() : body.size();
}

class HttpFront::Impl {
 public:
  class Session;
  struct CompiledRoute {
    HttpRoute route;
    PathPattern pattern;
  };

  Impl(HttpLimits limits, std::vector<HttpRoute> routes, std::string web_root, Hooks hooks)
      : limits_(limits),
        files_(web_root),
        hooks_(std::move(hooks)),
        acceptor_(ioc_),
        retry_(ioc_),
        workers_(static_cast<size_t>(std::max(1, limits.http_threads))) {
    for (HttpRoute& r : routes) {
      PathPattern pattern(r.pattern);
      routes_.push_back({std::move(r), std::move(pattern)});
    }
  }

  bool Start(const std::string& host, int port, std::string* error) {
    beast::error_code ec;
    const auto address = net::ip::make_address(host, ec);
    if (ec) {
      *error = "bad host '" + host + "': " + ec.message();
      return false;
    }
    const tcp::endpoint endpoint(address, static_cast<unsigned short>(port));
    // SO_REUSEADDR (a restart right after a crash binds again), never SO_REUSEPORT (a second
    // server on the same port must fail, not share it).
    acceptor_.open(endpoint.protocol(), ec);
    if (!ec) acceptor_.set_option(net::socket_base::reuse_address(true), ec);
    if (!ec) acceptor_.bind(endpoint, ec);
    if (!ec) acceptor_.listen(net::socket_base::max_listen_connections, ec);
    if (ec) {
      *error = "cannot listen on " + host + ":" + std::to_string(port) + ": " + ec.message();
      return false;
    }
    port_ = acceptor_.local_endpoint().port();
    Accept();
    for (int i = 0; i < std::max(1, limits_.io_threads); ++i)
      threads_.emplace_back([this] { ioc_.run(); });
    return true;
  }

  void Stop() {
    if (stopping_.exchange(true)) return;
    net::post(ioc_, [this] {
      beast::error_code ignored;
      acceptor_.close(ignored);
      retry_.cancel();
    });
    workers_.join();  // running handlers finish; their answers go nowhere
    ioc_.stop();
    for (std::thread& t : threads_) t.join();
    threads_.clear();
  }

  void Accept() {
    acceptor_.async_accept(net::make_strand(ioc_), [this](beast::error_code ec, tcp::socket s) {
      if (ec == net::error::operation_aborted || stopping_) return;
      if (ec) {
        // Out of file descriptors or similar: wait a little instead of spinning on accept.
        retry_.expires_after(std::chrono::milliseconds(100));
        retry_.async_wait([this](beast::error_code e) {
          if (!e) Accept();
        });
        return;
      }
      beast::error_code ignored;
      s.set_option(tcp::no_delay(true), ignored);
      StartSession(std::move(s));
      Accept();
    });
  }

  void StartSession(tcp::socket socket);

  /// The route for a method and raw path; `allowed` gets the methods of routes whose pattern
  /// matches when none has the method.
  const CompiledRoute* Find(const std::string& method,
                            const std::string& raw_path,
                            std::vector<std::string_view>* captures,
                            std::vector<std::string>* allowed) const {
    for (const CompiledRoute& r : routes_) {
      if (!r.pattern.Match(raw_path, captures)) continue;
      if (r.route.method == method) return &r;
      allowed->push_back(r.route.method);
    }
    return nullptr;
  }

  void RunHandler(const HttpRoute& route, const HttpRequest& request, HttpResponse& response) {
    try {
      route.handler(request, response);
    } catch (const std::exception& e) {
      // A handler's bug, not the client's: still an answer, counted like any other.
      response = HttpResponse();
      response.SetError(500, "error", std::string("internal error: ") + e.what());
    } catch (...) {
      response = HttpResponse();
      response.SetError(500, "error", "internal error");
    }
  }

  HttpLimits limits_;
  StaticFiles files_;
  Hooks hooks_;
  std::vector<CompiledRoute> routes_;
  net::io_context ioc_;
  tcp::acceptor acceptor_;
  net::steady_timer retry_;
  net::thread_pool workers_;
  std::vector<std::thread> threads_;
  int port_ = 0;
  std::atomic<bool> stopping_{false};
  std::atomic<uint64_t> open_{0}, total_{0}, refused_busy_{0}, header_timeouts_{0},
      body_timeouts_{0}, refused_{0};
};

/// One connection: reads a request's header, checks it, reads its body, runs the handler on
/// the worker pool and writes the answer; then the next request, or the connection closes.
class HttpFront::Impl::Session : public std::enable_shared_from_this<Session> {
 public:
  Session(Impl* front, tcp::socket&& socket)
      : front_(front),
        stream_(std::move(socket)),
        buffer_(front->limits_.max_header_bytes + 64 * 1024) {
    ++front_->open_;
    ++front_->total_;
  }
  ~Session() {
    if (fd_ >= 0) ::close(fd_);
    --front_->open_;
  }

  void Start() {
    if (front_->open_ > static_cast<uint64_t>(front_->limits_.max_connections)) {
      ++front_->refused_busy_;
      keep_alive_ = false;
      return Refuse(503,
                    "busy",
                    "the server has max_connections (" +
                        std::to_string(front_->limits_.max_connections) +
                        ") connections open; try again shortly");
    }
    ReadHeader();
  }

 private:
  const HttpLimits& limits() const { return front_->limits_; }

  void ReadHeader() {
    parser_.emplace();
    parser_->header_limit(static_cast<std::uint32_t>(limits().max_header_bytes));
    // The largest body any route takes; the route's own limit is set once it is known.
    uint64_t largest = limits().max_small_body_bytes;
    for (const CompiledRoute& r : front_->routes_)
      largest = std::max(largest, r.route.max_body_bytes);
    parser_->body_limit(largest);
    route_ = nullptr;
    static_file_.reset();
    request_ = HttpRequest();
    route_name_ = "other";
    stream_.expires_after(std::chrono::seconds(limits().header_timeout_s));
    http::async_read_header(
        stream_, buffer_, *parser_, [self = shared_from_this()](beast::error_code ec, size_t) {
          self->OnHeader(ec);
        });
  }

  void OnHeader(beast::error_code ec) {
    started_ = Clock::now();
    keep_alive_ = false;
    if (ec == beast::error::timeout) {
      ++front_->header_timeouts_;
      return Close();
    }
    if (ec == http::error::end_of_stream || ec == net::error::eof ||
        ec == net::error::connection_reset || ec == net::error::operation_aborted)
      return Close();
    if (ec == http::error::header_limit)
      return Refuse(431,
                    "too_large",
                    "the request line and headers are larger than the " +
                        std::to_string(limits().max_header_bytes) + " bytes allowed");
    if (ec == http::error::body_limit) return RefuseBodyTooLarge();
    if (ec) return Refuse(400, "bad_request", "malformed HTTP request: " + ec.message());
    ReadRequestLine();
    std::string error;
    if (!Decode(&error)) return Refuse(400, "bad_request", error);
    if (!Route()) return;
    if (!Admit()) return;
    if (parser_->is_done()) return Dispatch();
    parser_->body_limit(BodyLimit());
    if (EqualsIgnoreCase(request_.Header("Expect"), "100-continue")) return Continue();
    ReadBody();
  }

  void ReadRequestLine() {
    const auto& h = parser_->get();
    request_.method = std::string(h.method_string());
    head_only_ = request_.method == "HEAD";
    if (head_only_) request_.method = "GET";
    target_ = std::string(h.target());
    for (const auto& field : h)
      request_.headers.emplace_back(std::string(field.name_string()), std::string(field.value()));
  }

  /// Splits the target into the raw path and the query, and decodes both.
  bool Decode(std::string* error) {
    const size_t q = target_.find('?');
    raw_path_ = target_.substr(0, q);
    if (raw_path_.empty() || raw_path_[0] != '/') {
      *error = "the request target must be a path starting with '/'";
      return false;
    }
    if (!PercentDecode(raw_path_, false, &request_.path)) {
      *error = "the path has a malformed %-escape or a NUL byte";
      return false;
    }
    if (q != std::string::npos && !ParseQuery(target_.substr(q + 1), &request_.params, error))
      return false;
    return true;
  }

  /// Finds the route, or the static file; false when the answer is already on its way.
  bool Route() {
    std::vector<std::string_view> captures;
    std::vector<std::string> allowed;
    const CompiledRoute* r = front_->Find(request_.method, raw_path_, &captures, &allowed);
    if (r) {
      route_ = &r->route;
      route_name_ = route_->name;
      request_.matches.push_back(raw_path_);
      for (const std::string_view capture : captures) {
        std::string decoded;
        if (!PercentDecode(capture, false, &decoded)) {
          Refuse(400, "bad_request", "a path segment has a malformed %-escape or a NUL byte");
          return false;
        }
        request_.matches.push_back(std::move(decoded));
      }
      return true;
    }
    if (!allowed.empty()) {
      HttpResponse res;
      res.SetError(405,
                   "method_not_allowed",
                   request_.method + " is not allowed on " + request_.path +
                       " (allowed: " + Join(allowed, ", ") + ")");
      res.SetHeader("Allow", Join(allowed, ", "));
      Refuse(std::move(res));
      return false;
    }
    StaticFiles::File file;
    if (request_.method == "GET" && front_->files_.enabled() &&
        request_.path.rfind("/api/", 0) != 0 && front_->files_.Resolve(request_.path, &file)) {
      static_file_ = file;
      route_name_ = "static";
      return true;
    }
    Refuse(404, "not_found", "no resource at " + request_.path);
    return false;
  }

  /// The token, from the Authorization header or, for reads only, the raillomer_token cookie
  /// or the token query parameter. A write takes the header alone: a browser sends a cookie
  /// with a form another page on this host posts (SameSite does not tell ports apart), never
  /// a header.
  std::string Token(Access access, bool* from_query) const {
    *from_query = false;
    const std::string auth = request_.Header("Authorization");
    if (auth.size() > 7 && EqualsIgnoreCase(auth.substr(0, 7), "Bearer ")) return auth.substr(7);
    if (access != Access::kRead) return "";
    const std::string cookie = CookieValue(request_.Header("Cookie"), "raillomer_token");
    if (!cookie.empty()) return cookie;
    if (request_.HasParam("token")) {
      *from_query = true;
      return request_.Param("token");
    }
    return "";
  }

  /// Authorization, Content-Encoding and the body's declared size, before any body is read;
  /// false when the refusal is on its way.
  bool Admit() {
    const Access access = route_ ? route_->access : Access::kRead;
    const auto authorizations =
        std::count_if(request_.headers.begin(), request_.headers.end(), [](const auto& h) {
          return EqualsIgnoreCase(h.first, "Authorization");
        });
    if (authorizations > 1) {  // which one counts would be a guess
      Refuse(400,
             "bad_request",
             "send one Authorization header, not " + std::to_string(authorizations));
      return false;
    }
    const std::string token = Token(access, &token_from_query_);
    if (!front_->hooks_.authorize(token, access)) {
      HttpResponse res;
      res.SetError(401,
                   "unauthorized",
                   access == Access::kWrite
                       ? "this needs the ingest token as 'Authorization: Bearer <token>'"
                       : "reads need a token as 'Authorization: Bearer <token>', the "
                         "raillomer_token cookie or ?token=");
      res.SetHeader("WWW-Authenticate", "Bearer");
      Refuse(std::move(res));
      return false;
    }
    // The cookie keeps a read token the viewer's address carried, for its later requests; only
    // where reads need one (then `token` is the server's own, nothing a client wrote).
    if (token_from_query_ && !front_->hooks_.authorize("", Access::kRead)) cookie_token_ = token;
    const std::string encoding = request_.Header("Content-Encoding");
    if (!encoding.empty() && !EqualsIgnoreCase(encoding, "identity")) {
      Refuse(415,
             "unsupported_media_type",
             "request bodies are never decompressed: send the body without Content-Encoding "
             "(got '" +
                 encoding + "')");
      return false;
    }
    const auto length = parser_->content_length();
    if (length && *length > BodyLimit()) {
      RefuseBodyTooLarge();
      return false;
    }
    return true;
  }

  uint64_t BodyLimit() const {
    return route_ && route_->max_body_bytes > 0 ? route_->max_body_bytes
                                                : limits().max_small_body_bytes;
  }

  void RefuseBodyTooLarge() {
    const uint64_t limit = BodyLimit();
    Refuse(
        413,
        "too_large",
        "the request body is larger than the " + std::to_string(limit) + " bytes " +
            (route_ ? route_->name : std::string("this route")) + " takes" +
            (route_ && route_->max_body_bytes > limits().max_small_body_bytes ? " (max_body_bytes)"
                                                                              : ""));
  }

  void Continue() {
    static const std::string kContinue = "HTTP/1.1 100 Continue\r\n\r\n";
    stream_.expires_after(std::chrono::seconds(limits().request_timeout_s));
    net::async_write(
        stream_, net::buffer(kContinue), [self = shared_from_this()](beast::error_code ec, size_t) {
          if (ec) return self->Close();
          self->ReadBody();
        });
  }

  void ReadBody() {
    stream_.expires_after(std::chrono::seconds(limits().request_timeout_s));
    http::async_read_some(
        stream_, buffer_, *parser_, [self = shared_from_this()](beast::error_code ec, size_t) {
          if (ec == http::error::body_limit) return self->RefuseBodyTooLarge();
          if (ec == beast::error::timeout) {
            ++self->front_->body_timeouts_;
            return self->Close();
          }
          if (ec.category() == http::make_error_code(http::error::bad_chunk).category() &&
              ec != http::error::end_of_stream && ec != http::error::partial_message)
            return self->Refuse(400, "bad_request", "malformed request body: " + ec.message());
          if (ec) return self->Close();
          if (!self->parser_->is_done()) return self->ReadBody();
          self->Dispatch();
        });
  }

  void Dispatch() {
    keep_alive_ = parser_->keep_alive();
    if (static_file_) return AnswerFile();
    request_.body = std::move(parser_->get().body());
    if (route_->fast_handler) {
      HttpResponse res;
      if (route_->fast_handler(request_, res)) return Answer(std::move(res));
    }
    net::post(front_->workers_, [self = shared_from_this()] {
      HttpResponse res;
      self->front_->RunHandler(*self->route_, self->request_, res);
      net::post(self->stream_.get_executor(),
                [self, res = std::move(res)]() mutable { self->Answer(std::move(res)); });
    });
  }

  void AnswerFile() {
    const StaticFiles::File& f = *static_file_;
    HttpResponse res;
    res.SetHeader("ETag", f.etag);
    // Hashed build outputs never change under their name; the rest is revalidated.
    res.SetHeader("Cache-Control",
                  request_.path.rfind("/assets/", 0) == 0 ? "public, max-age=31536000, immutable"
                                                          : "no-cache");
    if (EtagMatches(request_.Header("If-None-Match"), f.etag)) {
      res.status = 304;
      return Answer(std::move(res));
    }
    res.content_type = f.content_type;
    res.file_path = f.path;
    res.file_size = f.size;
    Answer(std::move(res));
  }

  void Refuse(int status, const std::string& code, const std::string& message) {
    HttpResponse res;
    res.SetError(status, code, message);
    Refuse(std::move(res));
  }

  /// An answer of the front's own: the body, if any, is not read, so the connection closes.
  void Refuse(HttpResponse res) {
    ++front_->refused_;
    if (!parser_ || !parser_->is_header_done() || !parser_->is_done()) res.close = true;
    Answer(std::move(res));
  }

  /// Serves one range of a whole GET answer when the route allows it and the client asks: the
  /// part of the body to send, or none for the whole body (or the error that replaced it).
  std::optional<ByteRange> ApplyRange(HttpResponse& res) {
    const bool ranges = route_ ? route_->ranges : static_file_.has_value();
    if (!ranges || res.status != 200) return std::nullopt;
    const uint64_t size = res.BodySize();
    res.SetHeader("Accept-Ranges", "bytes");
    const std::string header = request_.Header("Range");
    const std::string if_range = request_.Header("If-Range");
    if (header.empty()) return std::nullopt;
    if (!if_range.empty()) {
      for (const auto& [k, v] : res.headers)
        if (EqualsIgnoreCase(k, "ETag") && v != if_range) return std::nullopt;
    }
    ByteRange range;
    switch (ParseRange(header, size, &range)) {
      case RangeAnswer::kWhole:
        return std::nullopt;
      case RangeAnswer::kUnsatisfiable:
        res.SetError(416,
                     "range_not_satisfiable",
                     "the range lies beyond the " + std::to_string(size) + " bytes there are");
        res.SetHeader("Content-Range", "bytes */" + std::to_string(size));
        return std::nullopt;
      case RangeAnswer::kPart:
        res.status = 206;
        res.SetHeader("Content-Range",
                      "bytes " + std::to_string(range.first) + "-" + std::to_string(range.last) +
                          "/" + std::to_string(size));
        return range;
    }
    return std::nullopt;
  }

  void Answer(HttpResponse res) {
    response_ = std::move(res);
    // The extent is taken after the range is applied: a 416's error replaces the body.
    const std::optional<ByteRange> part = ApplyRange(response_);
    body_first_ = part ? part->first : 0;
    body_end_ = part ? part->last + 1 : response_.BodySize();
    if (front_->hooks_.observe)
      front_->hooks_.observe(route_name_,
                             response_.status,
                             std::chrono::duration<double>(Clock::now() - started_).count());
    if (!cookie_token_.empty())
      response_.SetHeader(
          "Set-Cookie", "raillomer_token=" + cookie_token_ + "; Path=/; HttpOnly; SameSite=Strict");
    cookie_token_.clear();
    keep_alive_ = keep_alive_ && !response_.close && !front_->stopping_;
    const bool no_body = response_.status == 204 || response_.status == 304 ||
                         (response_.status >= 100 && response_.status < 200);
    if (no_body) body_first_ = body_end_ = 0;
    head_ = "HTTP/1.1 " + std::to_string(response_.status) + " " + StatusText(response_.status) +
            "\r\n";
    if (!response_.content_type.empty() && !no_body)
      head_ += "Content-Type: " + HeaderSafe(response_.content_type) + "\r\n";
    if (!no_body) head_ += "Content-Length: " + std::to_string(body_end_ - body_first_) + "\r\n";
    for (const auto& [name, value] : response_.headers)
      head_ += HeaderSafe(name) + ": " + HeaderSafe(value) + "\r\n";
    head_ += keep_alive_ ? "Connection: keep-alive\r\n\r\n" : "Connection: close\r\n\r\n";
    head_sent_ = false;
    if (head_only_) body_end_ = body_first_;
    if (!response_.file_path.empty() && body_end_ > body_first_) {
      fd_ = ::open(response_.file_path.c_str(), O_RDONLY | O_CLOEXEC);
      if (fd_ < 0) return Close();
      chunk_.resize(static_cast<size_t>(std::min(kWriteChunkBytes, body_end_ - body_first_)));
    }
    WriteNext();
  }

  const char* BodyData() const {
    return response_.shared_body ? response_.shared_body->data() : response_.body.data();
  }

  void WriteNext() {
    if (response_.produce && body_first_ < body_end_) return Produce();
    std::vector<net::const_buffer> buffers;
    if (!head_sent_) buffers.push_back(net::buffer(head_));
    const uint64_t take = std::min(kWriteChunkBytes, body_end_ - body_first_);
    if (take > 0) {
      if (fd_ >= 0) {
        const ssize_t n = ::pread(fd_, chunk_.data(), take, static_cast<off_t>(body_first_));
        if (n <= 0) return Close();  // the file shrank under us: the length sent is wrong
        buffers.push_back(net::buffer(chunk_.data(), static_cast<size_t>(n)));
        pending_ = static_cast<uint64_t>(n);
      } else {
        buffers.push_back(net::buffer(BodyData() + body_first_, take));
        pending_ = take;
      }
    } else {
      pending_ = 0;
    }
    Write(buffers);
  }

  /// The next piece of a produced body, made on a worker, then written.
  void Produce() {
    net::post(front_->workers_, [self = shared_from_this()] {
      self->piece_.clear();
      const bool ok = self->response_.produce(&self->piece_);
      net::post(self->stream_.get_executor(), [self, ok] { self->WritePiece(ok); });
    });
  }

  void WritePiece(bool ok) {
    // A failed or misfit piece would make the length sent a lie: the connection closes.
    if (!ok || piece_.empty() || piece_.size() > body_end_ - body_first_) return Close();
    std::vector<net::const_buffer> buffers;
    if (!head_sent_) buffers.push_back(net::buffer(head_));
    buffers.push_back(net::buffer(piece_));
    pending_ = piece_.size();
    Write(buffers);
  }

  void Write(const std::vector<net::const_buffer>& buffers) {
    stream_.expires_after(std::chrono::seconds(limits().request_timeout_s));
    net::async_write(stream_, buffers, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec == beast::error::timeout) ++self->front_->body_timeouts_;
      if (ec) return self->Close();
      self->head_sent_ = true;
      self->body_first_ += self->pending_;
      if (self->body_first_ < self->body_end_) return self->WriteNext();
      self->Finish();
    });
  }

  void Finish() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
    response_ = HttpResponse();
    piece_ = std::string();
    if (keep_alive_) return ReadHeader();
    Linger();
  }

  /// Half-closes, then reads and drops what the client still sends (a body that was refused)
  /// for a moment, so the client reads the answer instead of a reset.
  void Linger() {
    beast::error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
    linger_.reset(new char[16 * 1024]);
    linger_end_ = Clock::now() + kLingerTime;
    LingerRead();
  }

  void LingerRead() {
    const auto left = linger_end_ - Clock::now();
    if (left <= Clock::duration::zero()) return Close();
    stream_.expires_after(std::min<Clock::duration>(kLingerPause, left));
    stream_.async_read_some(net::buffer(linger_.get(), 16 * 1024),
                            [self = shared_from_this()](beast::error_code ec, size_t) {
                              if (ec) return self->Close();
                              self->LingerRead();
                            });
  }

  void Close() {
    beast::error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ignored);
    stream_.socket().close(ignored);
  }

  Impl* front_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  // The request being served.
  const HttpRoute* route_ = nullptr;
  std::optional<StaticFiles::File> static_file_;
  HttpRequest request_;
  std::string target_, raw_path_, route_name_ = "other", cookie_token_;
  bool head_only_ = false, keep_alive_ = false, token_from_query_ = false;
  Clock::time_point started_ = Clock::now();
  // The answer being written.
  HttpResponse response_;
  std::string head_;
  bool head_sent_ = false;
  uint64_t body_first_ = 0, body_end_ = 0, pending_ = 0;
  int fd_ = -1;
  std::vector<char> chunk_;
  std::string piece_;  ///< of a produced body
  std::unique_ptr<char[]> linger_;
  Clock::time_point linger_end_;
};

void HttpFront::Impl::StartSession(tcp::socket socket) {
  std::make_shared<Session>(this, std::move(socket))->Start();
}

HttpFront::HttpFront(HttpLimits limits,
                     std::vector<HttpRoute> routes,
                     std::string web_root,
                     Hooks hooks)
    : impl_(std::make_unique<Impl>(
          limits, std::move(routes), std::move(web_root), std::move(hooks))) {}

HttpFront::~HttpFront() { Stop(); }

bool HttpFront::Start(const std::string& host, int port, std::string* error) {
  return impl_->Start(host, port, error);
}

void HttpFront::Stop() { impl_->Stop(); }

int HttpFront::port() const { return impl_->port_; }

HttpFrontStats HttpFront::stats() const {
  HttpFrontStats s;
  s.connections_open = impl_->open_;
  s.connections_total = impl_->total_;
  s.refused_busy = impl_->refused_busy_;
  s.header_timeouts = impl_->header_timeouts_;
  s.body_timeouts = impl_->body_timeouts_;
  s.refused = impl_->refused_;
  return s;
}

}  // namespace raillomer::server
