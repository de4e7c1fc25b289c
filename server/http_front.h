#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace raillomer::server {

/// Who may call a route.
enum class Access {
  kRead,   ///< anyone, or a read token when reads need one
  kWrite,  ///< the ingest token
};

/// A request as a handler sees it: read whole, checked against the front's limits and the
/// route's access before the handler runs.
struct HttpRequest {
  std::string method;                ///< "GET", "POST", ... (HEAD is served as GET)
  std::string path;                  ///< percent-decoded
  std::vector<std::string> matches;  ///< [0] the raw path, then the route's captures, decoded
  std::vector<std::pair<std::string, std::string>> params;   ///< the query, decoded
  std::vector<std::pair<std::string, std::string>> headers;  ///< as received
  std::string body;

  bool HasParam(const std::string& name) const;
  /// The first value of query parameter `name` ("" if absent).
  std::string Param(const std::string& name) const;
  /// The value of header `name`, matched without regard to case ("" if absent).
  std::string Header(const std::string& name) const;
};

/// A handler's answer. The body is one of: owned bytes, shared bytes (a cached tile, sent
/// without a copy), a file streamed from disk, or pieces made one after another on a worker
/// (an export, which never sits in memory whole).
struct HttpResponse {
  int status = 200;
  std::string content_type;
  std::string body;
  std::shared_ptr<const std::string> shared_body;
  std::string file_path;  ///< with file_size: the body is this file
  uint64_t file_size = 0;
  /// With produced_size (the whole body's bytes): appends the body's next piece; false on an
  /// error, which closes the connection (the length sent cannot be kept).
  std::function<bool(std::string* piece)> produce;
  uint64_t produced_size = 0;
  std::vector<std::pair<std::string, std::string>> headers;
  bool close = false;  ///< the connection closes after this answer

  void SetHeader(const std::string& name, const std::string& value);
  void SetContent(std::string bytes, const std::string& type);
  void SetSharedContent(std::shared_ptr<const std::string> bytes, const std::string& type);
  /// An error as the API states it: the status and {"error": {"code", "message"}}.
  void SetError(int status, const std::string& code, const std::string& message);
  /// The body's size, whatever holds it.
  uint64_t BodySize() const;
};

using HttpHandler = std::function<void(const HttpRequest&, HttpResponse&)>;

struct HttpRoute {
  std::string method;  ///< GET, POST, PUT, PATCH or DELETE
  /// The path with captures in braces, as OpenAPI writes it: "/api/v1/runs/{run}/tiles"
  /// (a capture is one segment, matched still percent-encoded and decoded for the handler).
  std::string pattern;
  std::string name;  ///< for metrics
  Access access = Access::kRead;
  /// The largest body the route takes; a route that takes none still reads up to
  /// HttpLimits::max_small_body_bytes.
  uint64_t max_body_bytes = 0;
  bool ranges = false;  ///< a GET answer serves Range requests (one range)
  HttpHandler handler;
  /// Optional: answers from memory on the event loop, without the hop to a worker, or
  /// returns false to leave the request to `handler` (a cached tile is the case).
  std::function<bool(const HttpRequest&, HttpResponse&)> fast_handler;
};

/// The limits every connection and request is held to, all enforced before a body is read
/// and before the handler runs.
struct HttpLimits {
  int io_threads = 2;    ///< the event loop's threads: connections hold none
  int http_threads = 8;  ///< threads that run handlers (the store's reads and writes)
  int max_connections = 1000;
  uint64_t max_header_bytes = 16 * 1024;      ///< request line and header fields together
  uint64_t max_small_body_bytes = 64 * 1024;  ///< for routes that take no body
  /// A request's header must arrive within this time of the connection opening or of the
  /// previous answer (an idle keep-alive connection is closed after it).
  int header_timeout_s = 10;
  int request_timeout_s = 30;  ///< each read of a body and each write of an answer
};

struct HttpFrontStats {
  uint64_t connections_open = 0;
  uint64_t connections_total = 0;
  uint64_t refused_busy = 0;     ///< over max_connections
  uint64_t header_timeouts = 0;  ///< closed waiting for a request's header
  uint64_t body_timeouts = 0;    ///< closed waiting for a body or a slow reader
  uint64_t refused = 0;          ///< requests the front answered itself (4xx) before a handler
};

/// The HTTP/1.1 front (Boost.Beast): an event loop on a few threads serves every connection,
/// so slow clients hold no thread; handlers run on a worker pool. Each request's header is
/// bounded in size and time; authorization, Content-Encoding (refused: bodies are never
/// decompressed) and the route's body limit are checked before a byte of the body is read;
/// chunked bodies are held to the same limit as they arrive. Paths no route matches are the
/// viewer's static files (GET and HEAD) when a web root is given.
class HttpFront {
 public:
  struct Hooks {
    /// True if `token` ("" if none was given) may call a route of this access.
    std::function<bool(const std::string& token, Access access)> authorize;
    /// Each answered request: the route's name ("static", "other" for the front's own
    /// refusals), its status and the seconds from the header to the answer.
    std::function<void(const std::string& route, int status, double seconds)> observe;
  };

  HttpFront(HttpLimits limits, std::vector<HttpRoute> routes, std::string web_root, Hooks hooks);
  ~HttpFront();
  HttpFront(const HttpFront&) = delete;
  HttpFront& operator=(const HttpFront&) = delete;

  /// Binds (port 0: the OS picks) and starts serving; false with a message naming what failed.
  bool Start(const std::string& host, int port, std::string* error);
  /// Stops accepting, lets running handlers finish and closes every connection.
  void Stop();
  int port() const;
  HttpFrontStats stats() const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace raillomer::server
