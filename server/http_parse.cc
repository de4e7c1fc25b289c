#include "server/http_parse.h"

#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <limits>

namespace raillomer::server {
namespace {

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

std::string_view Trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

/// Digits only, as an unsigned number; false on anything else or an overflow.
bool ParseDigits(std::string_view s, uint64_t* value) {
  if (s.empty()) return false;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), *value);
  return ec == std::errc() && end == s.data() + s.size();
}

}  // namespace

bool PercentDecode(std::string_view in, bool plus_is_space, std::string* out) {
  out->clear();
  out->reserve(in.size());
  for (size_t i = 0; i < in.size(); ++i) {
    char c = in[i];
    if (c == '%') {
      if (i + 2 >= in.size()) return false;
      const int hi = HexValue(in[i + 1]), lo = HexValue(in[i + 2]);
      if (hi < 0 || lo < 0) return false;
      c = static_cast<char>(hi * 16 + lo);
      i += 2;
    } else if (c == '+' && plus_is_space) {
      c = ' ';
    }
    if (c == '\0') return false;
    out->push_back(c);
  }
  return true;
}

bool ParseQuery(std::string_view query,
                std::vector<std::pair<std::string, std::string>>* params,
                std::string* error) {
  params->clear();
  while (!query.empty()) {
    const size_t end = std::min(query.find('&'), query.size());
    const std::string_view pair = query.substr(0, end);
    query.remove_prefix(std::min(end + 1, query.size()));
    if (pair.empty()) continue;
    const size_t eq = pair.find('=');
    std::string name, value;
    if (!PercentDecode(pair.substr(0, eq), true, &name) ||
        (eq != std::string_view::npos && !PercentDecode(pair.substr(eq + 1), true, &value)))
      return *error = "the query string has a malformed %-escape or a NUL byte", false;
    for (const auto& [seen, unused] : *params)
      if (seen == name) return *error = "the query string names '" + name + "' twice", false;
    params->emplace_back(std::move(name), std::move(value));
  }
  return true;
}

RangeAnswer ParseRange(std::string_view header, uint64_t size, ByteRange* range) {
  header = Trim(header);
  constexpr std::string_view kUnit = "bytes=";
  if (header.size() < kUnit.size() || !EqualsIgnoreCase(header.substr(0, kUnit.size()), kUnit))
    return RangeAnswer::kWhole;
  const std::string_view spec = Trim(header.substr(kUnit.size()));
  if (spec.find(',') != std::string_view::npos) return RangeAnswer::kWhole;  // several ranges
  const size_t dash = spec.find('-');
  if (dash == std::string_view::npos) return RangeAnswer::kWhole;
  const std::string_view a = Trim(spec.substr(0, dash)), b = Trim(spec.substr(dash + 1));
  uint64_t first = 0, last = 0;
  if (a.empty()) {  // the last n bytes
    if (!ParseDigits(b, &last)) return RangeAnswer::kWhole;
    if (last == 0 || size == 0) return RangeAnswer::kUnsatisfiable;
    range->first = size - std::min(last, size);
    range->last = size - 1;
    return RangeAnswer::kPart;
  }
  if (!ParseDigits(a, &first)) return RangeAnswer::kWhole;
  if (b.empty()) {
    last = std::numeric_limits<uint64_t>::max();
  } else if (!ParseDigits(b, &last) || last < first) {
    return RangeAnswer::kWhole;
  }
  if (first >= size) return RangeAnswer::kUnsatisfiable;
  range->first = first;
  range->last = std::min(last, size - 1);
  return RangeAnswer::kPart;
}

bool ParseInt64(std::string_view text, int64_t min, int64_t max, int64_t* value) {
  if (text.empty() || (text.size() > 1 && text[0] == '+')) return false;
  int64_t v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v < min || v > max) return false;
  *value = v;
  return true;
}

bool ParseFiniteDouble(std::string_view text, double* value) {
  if (text.empty() || std::isspace(static_cast<unsigned char>(text.front()))) return false;
  const std::string copy(text);  // strtod needs a terminated string
  char* end = nullptr;
  const double v = std::strtod(copy.c_str(), &end);
  if (end != copy.c_str() + copy.size() || !std::isfinite(v)) return false;
  // strtod also reads hexadecimal and "inf"/"nan"; a decimal number is all that is meant.
  for (char c : copy)
    if (!(std::isdigit(static_cast<unsigned char>(c)) || c == '.' || c == '-' || c == '+' ||
          c == 'e' || c == 'E'))
      return false;
  *value = v;
  return true;
}

std::string CookieValue(std::string_view header, std::string_view name) {
  while (!header.empty()) {
    const size_t end = std::min(header.find(';'), header.size());
    const std::string_view pair = Trim(header.substr(0, end));
    header.remove_prefix(std::min(end + 1, header.size()));
    const size_t eq = pair.find('=');
    if (eq != std::string_view::npos && Trim(pair.substr(0, eq)) == name)
      return std::string(Trim(pair.substr(eq + 1)));
  }
  return "";
}

bool EtagMatches(std::string_view if_none_match, std::string_view etag) {
  const auto opaque = [](std::string_view tag) {
    return tag.substr(0, 2) == "W/" ? tag.substr(2) : tag;
  };
  if (etag.empty()) return false;
  while (!if_none_match.empty()) {
    const size_t end = std::min(if_none_match.find(','), if_none_match.size());
    const std::string_view tag = Trim(if_none_match.substr(0, end));
    if_none_match.remove_prefix(std::min(end + 1, if_none_match.size()));
    if (tag == "*" || opaque(tag) == opaque(etag)) return true;
  }
  return false;
}

bool EqualsIgnoreCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (std::tolower(static_cast<unsigned char>(a[i])) !=
        std::tolower(static_cast<unsigned char>(b[i])))
      return false;
  return true;
}

PathPattern::PathPattern(std::string_view pattern) {
  size_t start = 1;  // after the leading '/'
  while (start <= pattern.size()) {
    const size_t end = std::min(pattern.find('/', start), pattern.size());
    const std::string_view segment = pattern.substr(start, end - start);
    const bool capture = segment.size() >= 2 && segment.front() == '{' && segment.back() == '}';
    literals_.emplace_back(capture ? std::string_view() : segment);
    captures_.push_back(capture);
    start = end + 1;
  }
}

bool PathPattern::Match(std::string_view raw_path, std::vector<std::string_view>* captures) const {
  if (captures) captures->clear();
  if (raw_path.empty() || raw_path[0] != '/') return false;
  size_t start = 1, k = 0;
  while (start <= raw_path.size()) {
    if (k == literals_.size()) return false;
    const size_t end = std::min(raw_path.find('/', start), raw_path.size());
    const std::string_view segment = raw_path.substr(start, end - start);
    if (captures_[k]) {
      if (segment.empty()) return false;
      if (captures) captures->push_back(segment);
    } else if (segment != literals_[k]) {
      return false;
    }
    ++k;
    start = end + 1;
  }
  return k == literals_.size();
}

}  // namespace raillomer::server
