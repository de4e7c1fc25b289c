#pragma once

#include <string>

namespace raillomer::api {

/// Writes a file under a temporary name beside the target and renames it into place on Commit(),
/// so a reader never sees a half-written output. Without Commit() the temporary is removed.
class AtomicFile {
 public:
  explicit AtomicFile(std::string path);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  /// The name to write to until Commit().
  const std::string& temp_path() const { return temp_path_; }
  const std::string& path() const { return path_; }
  /// Renames the temporary to the final name; false with a message on failure.
  bool Commit(std::string* error);

 private:
  std::string path_;
  std::string temp_path_;
  bool committed_ = false;
};

/// Writes `content` to `path` atomically; false with a message naming the path on failure.
bool WriteFileAtomically(const std::string& path, const std::string& content, std::string* error);

}  // namespace raillomer::api
