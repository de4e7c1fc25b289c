#pragma once

// Plain values in and out of byte strings, in the machine's order (little-endian on every
// platform we build for), for the binary file formats: PLY, PCD and LAS.

#include <cstddef>
#include <cstring>
#include <string>

namespace raillomer::api {

template <typename T>
void AppendRaw(std::string* out, T value) {
  char bytes[sizeof(T)];
  std::memcpy(bytes, &value, sizeof(T));
  out->append(bytes, sizeof(T));
}

/// The caller has checked that the bytes reach at + sizeof(T).
template <typename T>
T ReadRaw(const std::string& in, size_t at) {
  T value;
  std::memcpy(&value, in.data() + at, sizeof(T));
  return value;
}

}  // namespace raillomer::api
