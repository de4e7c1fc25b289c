#pragma once

#include <cstdint>
#include <string>

namespace raillomer::server {

/// The viewer's static files: a request path resolved to a regular file inside the web root,
/// never outside it (no "..", no symlink that leads out, no NUL, no backslash).
class StaticFiles {
 public:
  /// `root` is resolved once (realpath); an empty or missing root serves nothing.
  explicit StaticFiles(const std::string& root);

  bool enabled() const { return !root_.empty(); }

  struct File {
    std::string path;  ///< resolved, inside the root
    uint64_t size = 0;
    int64_t mtime_ns = 0;
    std::string content_type;
    std::string etag;  ///< quoted, from size and modification time
  };
  /// Resolves a decoded request path ("/", "/index.html", "/assets/app.js"); a folder answers
  /// its index.html. False when there is no such file inside the root.
  bool Resolve(const std::string& decoded_path, File* file) const;

 private:
  std::string root_;  ///< realpath of the web root, without a trailing '/'
};

/// The Content-Type for a file name's extension (application/octet-stream if unknown).
std::string ContentTypeOf(const std::string& path);

}  // namespace raillomer::server
