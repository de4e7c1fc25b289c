#include "server/metrics.h"

#include <cstdio>

namespace raillomer::server {

void Metrics::Observe(const std::string& route, int status, double seconds) {
  std::lock_guard<std::mutex> lock(mu_);
  ++requests_[{route, status}];
  Histogram& h = durations_[route];
  for (size_t i = 0; i < kBuckets.size(); ++i) {
    if (seconds <= kBuckets[i]) ++h.counts[i];
  }
  ++h.count;
  h.sum += seconds;
}

void Metrics::Write(std::string* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  char line[512];
  *out += "# HELP raillomer_http_requests_total HTTP requests answered, by route and status.\n";
  *out += "# TYPE raillomer_http_requests_total counter\n";
  for (const auto& [key, n] : requests_) {
    std::snprintf(line,
                  sizeof(line),
                  "raillomer_http_requests_total{route=\"%s\",status=\"%d\"} %llu\n",
                  key.first.c_str(),
                  key.second,
                  static_cast<unsigned long long>(n));
    *out += line;
  }
  *out += "# HELP raillomer_http_request_duration_seconds Time to answer a request, by route.\n";
  *out += "# TYPE raillomer_http_request_duration_seconds histogram\n";
  for (const auto& [route, h] : durations_) {
    for (size_t i = 0; i < kBuckets.size(); ++i) {
      std::snprintf(line,
                    sizeof(line),
                    "raillomer_http_request_duration_seconds_bucket{route=\"%s\",le=\"%g\"} %llu\n",
                    route.c_str(),
                    kBuckets[i],
                    static_cast<unsigned long long>(h.counts[i]));
      *out += line;
    }
    std::snprintf(line,
                  sizeof(line),
                  "raillomer_http_request_duration_seconds_bucket{route=\"%s\",le=\"+Inf\"} %llu\n"
                  "raillomer_http_request_duration_seconds_sum{route=\"%s\"} %.6f\n"
                  "raillomer_http_request_duration_seconds_count{route=\"%s\"} %llu\n",
                  route.c_str(),
                  static_cast<unsigned long long>(h.count),
                  route.c_str(),
                  h.sum,
                  route.c_str(),
                  static_cast<unsigned long long>(h.count));
    *out += line;
  }
}

}  // namespace raillomer::server
