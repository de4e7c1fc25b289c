// Benchmark: the simulator's real-time factor with both LiDARs at full rate, for the in-process
// source and for writing a bag, on a few corridors of different size.
//   bench_sim [--seconds 20] [--json out.json] [--scenario name ...]

#include <unistd.h>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "estimator/io/bag_writer.h"
#include "estimator/sim/simulator.h"

namespace {

using Clock = std::chrono::steady_clock;
namespace sim = raillomer::sim;

double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

long PeakRssKb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::atol(line.c_str() + 6);
  }
  return -1;
}

}  // namespace

int main(int argc, char** argv) {
  double seconds = 20.0;
  std::string json_path;
  std::vector<std::string> scenarios;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--seconds" && i + 1 < argc) {
      seconds = std::atof(argv[++i]);
    } else if (arg == "--json" && i + 1 < argc) {
      json_path = argv[++i];
    } else if (arg == "--scenario" && i + 1 < argc) {
      scenarios.push_back(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: bench_sim [--seconds S] [--json FILE] [--scenario NAME]...\n");
      return 2;
    }
  }
  if (scenarios.empty()) scenarios = {"rich_high_town_a", "poor_high_catenary_b", "long_20km"};

  nlohmann::json results = nlohmann::json::array();
  std::printf("%-22s %9s %10s %12s %12s %10s\n",
              "scenario",
              "triangles",
              "build_s",
              "source_rtf",
              "bag_rtf",
              "bag_MB/s");
  bool ok = true;
  for (const std::string& name : scenarios) {
    sim::Scenario scenario;
    std::string error;
    if (!sim::LoadScenario(name, &scenario, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
    sim::SimOptions options;
    options.duration_s = std::min(seconds, scenario.ProfileDurationS());

    // In-process source: every message generated, nothing written.
    auto start = Clock::now();
    auto source = sim::Simulator::Create(scenario, options, &error);
    if (!source) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
    const double build_s = Seconds(start);
    raillomer::io::SensorMessage message;
    uint64_t points = 0;
    start = Clock::now();
    while (source->Next(&message)) {
      if (auto* frame = std::get_if<raillomer::io::LidarFrame>(&message.data)) {
        points += frame->points.size();
      }
    }
    const double source_rtf = options.duration_s / Seconds(start);

    // The same run written to a bag.
    const std::string bag = (std::filesystem::temp_directory_path() /
                             ("bench_sim_" + std::to_string(::getpid()) + ".bag"))
                                .string();
    auto writer_source = sim::Simulator::Create(scenario, options, &error);
    auto writer = raillomer::io::BagWriter::Open(bag, {}, &error);
    if (!writer_source || !writer) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
    start = Clock::now();
    while (writer_source->Next(&message)) {
      if (!writer->Write(message, &error)) {
        std::fprintf(stderr, "%s\n", error.c_str());
        return 2;
      }
    }
    if (!writer->Close(&error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
    const double bag_s = Seconds(start);
    const double bag_mb = std::filesystem::file_size(bag) / 1e6;
    std::filesystem::remove(bag);
    const double bag_rtf = options.duration_s / bag_s;

    std::printf("%-22s %9zu %10.2f %12.2f %12.2f %10.1f\n",
                name.c_str(),
                source->world().mesh().triangles.size(),
                build_s,
                source_rtf,
                bag_rtf,
                bag_mb / bag_s);
    results.push_back({{"scenario", name},
                       {"simulated_s", options.duration_s},
                       {"triangles", source->world().mesh().triangles.size()},
                       {"world_build_s", build_s},
                       {"lidar_points", points},
                       {"source_real_time_factor", source_rtf},
                       {"bag_real_time_factor", bag_rtf},
                       {"bag_mb", bag_mb}});
    ok = ok && source_rtf >= 3.0;
  }
  const long rss = PeakRssKb();
  std::printf("peak RSS %.1f MB; target: in-process source >= 3x real time: %s\n",
              rss / 1024.0,
              ok ? "met" : "NOT met");
  if (!json_path.empty()) {
    std::ofstream(json_path) << nlohmann::json{{"results", results}, {"peak_rss_kb", rss}}.dump(2)
                             << "\n";
  }
  return ok ? 0 : 1;
}
