// A libFuzzer target for the submap decoder (api::DecodeSubmapPcd), the parser that every
// ingested byte goes through: it must never crash, hang or read out of bounds, and whatever it
// accepts must encode and decode again to the same submap. Built and run with clang by
// tests/tools/fuzz_submap_decoder.sh (slow tier).
#include <cstdint>
#include <string>

#include "api/stream.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  raillomer::api::Submap s;
  std::string error;
  if (!raillomer::api::DecodeSubmapPcd(bytes, &s, &error)) {
    if (error.empty()) __builtin_trap();  // a refusal always says why
    return 0;
  }
  if (s.points.size() != s.intensities.size()) __builtin_trap();
  raillomer::api::Submap again;
  if (!raillomer::api::DecodeSubmapPcd(raillomer::api::EncodeSubmapPcd(s), &again, &error))
    __builtin_trap();
  if (again.points.size() != s.points.size() || again.sequence != s.sequence ||
      again.utm_zone != s.utm_zone || again.keyframes.size() != s.keyframes.size())
    __builtin_trap();
  return 0;
}
