#include "server/static_files.h"

#include <limits.h>
#include <stdlib.h>
#include <sys/stat.h>

#include <cstdio>
#include <map>

namespace raillomer::server {
namespace {

/// realpath(3) as a string; "" if the path does not resolve.
std::string RealPath(const std::string& path) {
  char resolved[PATH_MAX];
  if (!::realpath(path.c_str(), resolved)) return "";
  return resolved;
}

/// True if every segment of the path is a plain name: none is empty, ".", ".." or holds a
/// backslash or a control character.
bool PlainSegments(const std::string& path) {
  size_t start = 1;  // after the leading '/'
  while (start <= path.size()) {
    const size_t end = std::min(path.find('/', start), path.size());
    const std::string segment = path.substr(start, end - start);
    if (end == path.size() && segment.empty()) break;  // a trailing '/': the folder's index
    if (segment.empty() || segment == "." || segment == "..") return false;
    for (unsigned char c : segment)
      if (c < 0x20 || c == 0x7f || c == '\\') return false;
    start = end + 1;
  }
  return true;
}

}  // namespace

StaticFiles::StaticFiles(const std::string& root) {
  if (!root.empty()) root_ = RealPath(root);
}

bool StaticFiles::Resolve(const std::string& decoded_path, File* file) const {
  if (root_.empty() || decoded_path.empty() || decoded_path[0] != '/' ||
      !PlainSegments(decoded_path))
    return false;
  std::string candidate = root_ + decoded_path;
  struct stat st {};
  if (::stat(candidate.c_str(), &st) == 0 && S_ISDIR(st.st_mode)) {
    if (candidate.back() != '/') candidate += '/';
    candidate += "index.html";
  }
  // The resolved file must lie inside the root: a symlink may point within it, never out.
  const std::string real = RealPath(candidate);
  if (real.empty() || real.compare(0, root_.size() + 1, root_ + "/") != 0) return false;
  if (::stat(real.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return false;
  file->path = real;
  file->size = static_cast<uint64_t>(st.st_size);
  file->mtime_ns = static_cast<int64_t>(st.st_mtim.tv_sec) * 1'000'000'000 + st.st_mtim.tv_nsec;
  file->content_type = ContentTypeOf(real);
  char etag[64];
  std::snprintf(etag,
                sizeof(etag),
                "\"%llx-%llx\"",
                static_cast<unsigned long long>(file->size),
                static_cast<unsigned long long>(file->mtime_ns));
  file->etag = etag;
  return true;
}

std::string ContentTypeOf(const std::string& path) {
  static const std::map<std::string, std::string> types = {
      {"html", "text/html; charset=utf-8"},
      {"js", "text/javascript; charset=utf-8"},
      {"mjs", "text/javascript; charset=utf-8"},
      {"css", "text/css; charset=utf-8"},
      {"json", "application/json"},
      {"map", "application/json"},
      {"wasm", "application/wasm"},
      {"png", "image/png"},
      {"jpg", "image/jpeg"},
      {"svg", "image/svg+xml"},
      {"ico", "image/x-icon"},
      {"txt", "text/plain; charset=utf-8"},
      {"woff2", "font/woff2"},
  };
  const size_t dot = path.rfind('.');
  const size_t slash = path.rfind('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash))
    return "application/octet-stream";
  const auto it = types.find(path.substr(dot + 1));
  return it == types.end() ? "application/octet-stream" : it->second;
}

}  // namespace raillomer::server
