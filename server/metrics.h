#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>

namespace raillomer::server {

/// Request counters and latency histograms, written out in Prometheus' text format.
class Metrics {
 public:
  /// One answered request: its route (the pattern, not the path), status and duration.
  void Observe(const std::string& route, int status, double seconds);
  /// Adds the request metrics to `out`.
  void Write(std::string* out) const;

 private:
  static constexpr std::array<double, 12> kBuckets = {
      0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 5.0};
  struct Histogram {
    std::array<uint64_t, kBuckets.size()> counts{};
    uint64_t count = 0;
    double sum = 0.0;
  };
  mutable std::mutex mu_;
  std::map<std::pair<std::string, int>, uint64_t> requests_;
  std::map<std::string, Histogram> durations_;
};

}  // namespace raillomer::server
