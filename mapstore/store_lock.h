#pragma once

#include <memory>
#include <string>

namespace raillomer::mapstore {

/// One process at a time in a store folder: an exclusive advisory lock (flock) on
/// `<dir>/store.lock`, which holds the owner's process id. The kernel drops it when the owner
/// exits, so a killed server leaves no stale lock.
class StoreLock {
 public:
  /// Takes the folder's lock; null with `error` naming the process that holds it.
  static std::unique_ptr<StoreLock> Acquire(const std::string& dir, std::string* error);
  ~StoreLock();
  StoreLock(const StoreLock&) = delete;
  StoreLock& operator=(const StoreLock&) = delete;

 private:
  explicit StoreLock(int fd) : fd_(fd) {}
  int fd_ = -1;
};

}  // namespace raillomer::mapstore
