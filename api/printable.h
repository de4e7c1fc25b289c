#pragma once

#include <cstddef>
#include <string_view>

namespace raillomer::api {

/// Whether UTF-8 text prints as it is: no control character (C0, DEL, C1; with `line_breaks`,
/// tab, line feed and carriage return are allowed), no line or paragraph separator and no
/// bidirectional embedding, override or isolate (U+2028-U+202E, U+2066-U+2069), which make a
/// name or a note display as other than it is.
inline bool Printable(std::string_view s, bool line_breaks = false) {
  const auto at = [&s](size_t i) { return i < s.size() ? static_cast<unsigned char>(s[i]) : 0; };
  for (size_t i = 0; i < s.size(); ++i) {
    const unsigned char c = at(i);
    if ((c < 0x20 && !(line_breaks && (c == '\t' || c == '\n' || c == '\r'))) || c == 0x7f)
      return false;
    if (c == 0xc2 && at(i + 1) >= 0x80 && at(i + 1) <= 0x9f) return false;
    if (c == 0xe2 && at(i + 1) == 0x80 && at(i + 2) >= 0xa8 && at(i + 2) <= 0xae) return false;
    if (c == 0xe2 && at(i + 1) == 0x81 && at(i + 2) >= 0xa6 && at(i + 2) <= 0xa9) return false;
  }
  return true;
}

/// The characters of UTF-8 text: its bytes that start one (not continuation bytes).
inline size_t Utf8Characters(std::string_view s) {
  size_t n = 0;
  for (char c : s) n += (static_cast<unsigned char>(c) & 0xc0) != 0x80;
  return n;
}

}  // namespace raillomer::api
