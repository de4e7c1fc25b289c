#include "mapstore/store_lock.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace raillomer::mapstore {
namespace {

/// The process id the lock file names, as text ("" if unreadable).
std::string OwnerOf(int fd) {
  char text[32] = {};
  const ssize_t n = pread(fd, text, sizeof(text) - 1, 0);
  std::string pid(text, n > 0 ? static_cast<size_t>(n) : 0);
  while (!pid.empty() && (pid.back() == '\n' || pid.back() == ' ')) pid.pop_back();
  return pid;
}

}  // namespace

std::unique_ptr<StoreLock> StoreLock::Acquire(const std::string& dir, std::string* error) {
  const std::string path = dir + "/store.lock";
  const int fd = open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0600);
  if (fd < 0) {
    *error = "cannot open " + path + ": " + std::strerror(errno);
    return nullptr;
  }
  if (flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    const std::string owner = OwnerOf(fd);
    close(fd);
    *error = err == EWOULDBLOCK ? "the store in " + dir + " is in use by another process" +
                                      (owner.empty() ? "" : " (pid " + owner + ")") +
                                      ": stop it first, or work on a copy of the folder"
                                : "cannot lock " + path + ": " + std::strerror(err);
    return nullptr;
  }
  const std::string pid = std::to_string(getpid()) + "\n";
  if (ftruncate(fd, 0) != 0 || pwrite(fd, pid.data(), pid.size(), 0) < 0) {
    *error = "cannot write " + path + ": " + std::strerror(errno);
    close(fd);
    return nullptr;
  }
  return std::unique_ptr<StoreLock>(new StoreLock(fd));
}

StoreLock::~StoreLock() {
  if (fd_ >= 0) close(fd_);  // closing the only descriptor releases the lock
}

}  // namespace raillomer::mapstore
