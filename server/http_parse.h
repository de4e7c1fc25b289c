#pragma once

// The parts of an HTTP request the front reads itself, as pure functions: percent-decoding,
// query strings, byte ranges, cookies and strict numbers. Nothing here throws.

#include <cstdint>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace raillomer::server {

/// Decodes %XX escapes (and '+' as a space when `plus_is_space`, as in a query string). False
/// if an escape is malformed or the result holds a NUL byte, which no path or value may.
bool PercentDecode(std::string_view in, bool plus_is_space, std::string* out);

/// A query string's name=value pairs, decoded, in order; false with `error` saying why if one
/// does not decode or a name comes twice (which of the two values to take is a guess).
bool ParseQuery(std::string_view query,
                std::vector<std::pair<std::string, std::string>>* params,
                std::string* error);

/// Bytes first..last (inclusive) of an entity.
struct ByteRange {
  uint64_t first = 0, last = 0;
};

enum class RangeAnswer {
  kWhole,          ///< no usable Range: the whole entity answers (200)
  kPart,           ///< one satisfiable range (206)
  kUnsatisfiable,  ///< one range that lies beyond the entity (416)
};

/// Reads a Range header against an entity of `size` bytes. One range ("bytes=a-b", "bytes=a-",
/// "bytes=-n") is served; several ranges, another unit or a malformed header answer the whole
/// entity, as RFC 9110 allows, so no request can ask for more bytes than the entity has.
RangeAnswer ParseRange(std::string_view header, uint64_t size, ByteRange* range);

/// A whole decimal integer in [min, max]: an optional '-', digits, nothing else (no spaces,
/// no exponent, no fraction).
bool ParseInt64(std::string_view text, int64_t min, int64_t max, int64_t* value);

/// A whole finite decimal number ("12.345", "-3", "1e3"); nothing else around it.
bool ParseFiniteDouble(std::string_view text, double* value);

/// The value of cookie `name` in a Cookie header ("" if it is not there).
std::string CookieValue(std::string_view header, std::string_view name);

/// Whether an If-None-Match header names `etag`: `*`, or a comma-separated list holding it
/// (compared weakly, as RFC 9110 asks for If-None-Match: W/ prefixes aside).
bool EtagMatches(std::string_view if_none_match, std::string_view etag);

/// ASCII case-insensitive equality, for header names and tokens.
bool EqualsIgnoreCase(std::string_view a, std::string_view b);

/// A route's path as OpenAPI writes it: literal segments and captures in braces
/// ("/api/v1/runs/{run}/tiles"). It matches a raw path of as many segments whose literals
/// are equal and whose captures are not empty.
class PathPattern {
 public:
  explicit PathPattern(std::string_view pattern);
  /// True if `raw_path` matches; `captures` (if given) gets the captured segments, still
  /// percent-encoded, in order.
  bool Match(std::string_view raw_path, std::vector<std::string_view>* captures) const;

 private:
  std::vector<std::string> literals_;  ///< per segment; "" where it is a capture
  std::vector<bool> captures_;
};

}  // namespace raillomer::server
