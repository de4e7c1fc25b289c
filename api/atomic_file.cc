#include "api/atomic_file.h"

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>

namespace raillomer::api {

AtomicFile::AtomicFile(std::string path)
    : path_(std::move(path)), temp_path_(path_ + ".tmp-" + std::to_string(::getpid())) {}

AtomicFile::~AtomicFile() {
  if (!committed_) std::remove(temp_path_.c_str());
}

bool AtomicFile::Commit(std::string* error) {
  if (std::rename(temp_path_.c_str(), path_.c_str()) != 0) {
    if (error)
      *error = "cannot rename " + temp_path_ + " to " + path_ + ": " + std::strerror(errno);
    return false;
  }
  committed_ = true;
  return true;
}

bool WriteFileAtomically(const std::string& path, const std::string& content, std::string* error) {
  AtomicFile file(path);
  {
    std::ofstream out(file.temp_path(), std::ios::binary | std::ios::trunc);
    if (!out) {
      if (error)
        *error = "cannot open " + file.temp_path() + " for writing: " + std::strerror(errno);
      return false;
    }
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    out.flush();
    if (!out) {
      if (error) *error = "cannot write " + file.temp_path() + ": " + std::strerror(errno);
      return false;
    }
  }
  return file.Commit(error);
}

}  // namespace raillomer::api
