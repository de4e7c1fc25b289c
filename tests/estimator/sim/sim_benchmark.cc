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

/// The command line.
struct Args {
  double seconds = 20.0;
  std::string json_path;
  std::vector<std::string> scenarios;
};

bool ParseArgs(int argc, char** argv, Args* a) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--seconds" && i + 1 < argc) {
      a->seconds = std::atof(argv[++i]);
    } else if (arg == "--json" && i + 1 < argc) {
      a->json_path = argv[++i];
    } else if (arg == "--scenario" && i + 1 < argc) {
      a->scenarios.push_back(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: bench_sim [--seconds S] [--json FILE] [--scenario NAME]...\n");
      return false;
    }
  }
  if (a->scenarios.empty())
    a->scenarios = {"rich_high_town_a", "poor_high_catenary_b", "long_20km"};
  return true;
}

/// One scenario's figures.
struct Measured {
  size_t triangles = 0;
  double build_s = 0.0, source_rtf = 0.0, bag_rtf = 0.0, bag_mb = 0.0, bag_s = 0.0;
  uint64_t points = 0;
};

/// The in-process source: every message generated, nothing written.
bool MeasureSource(const sim::Scenario& scenario,
                   const sim::SimOptions& options,
                   Measured* m,
                   std::string* error) {
  auto start = Clock::now();
  auto source = sim::Simulator::Create(scenario, options, error);
  if (!source) return false;
  m->build_s = Seconds(start);
  m->triangles = source->world().mesh().triangles.size();
  raillomer::io::SensorMessage message;
  start = Clock::now();
  while (source->Next(&message)) {
    if (auto* frame = std::get_if<raillomer::io::LidarFrame>(&message.data)) {
      m->points += frame->points.size();
    }
  }
  m->source_rtf = options.duration_s / Seconds(start);
  return true;
}

/// The same run written to a bag in the temporary folder (removed after).
bool MeasureBag(const sim::Scenario& scenario,
                const sim::SimOptions& options,
                Measured* m,
                std::string* error) {
  const std::string bag = (std::filesystem::temp_directory_path() /
                           ("bench_sim_" + std::to_string(::getpid()) + ".bag"))
                              .string();
  auto source = sim::Simulator::Create(scenario, options, error);
  auto writer = raillomer::io::BagWriter::Open(bag, {}, error);
  if (!source || !writer) return false;
  raillomer::io::SensorMessage message;
  const auto start = Clock::now();
  while (source->Next(&message)) {
    if (!writer->Write(message, error)) return false;
  }
  if (!writer->Close(error)) return false;
  m->bag_s = Seconds(start);
  m->bag_mb = std::filesystem::file_size(bag) / 1e6;
  std::filesystem::remove(bag);
  m->bag_rtf = options.duration_s / m->bag_s;
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  if (!ParseArgs(argc, argv, &a)) return 2;
  nlohmann::json results = nlohmann::json::array();
  std::printf("%-22s %9s %10s %12s %12s %10s\n",
              "scenario",
              "triangles",
              "build_s",
              "source_rtf",
              "bag_rtf",
              "bag_MB/s");
  bool ok = true;
  for (const std::string& name : a.scenarios) {
    sim::Scenario scenario;
    std::string error;
    if (!sim::LoadScenario(name, &scenario, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
    sim::SimOptions options;
    options.duration_s = std::min(a.seconds, scenario.ProfileDurationS());
    Measured m;
    if (!MeasureSource(scenario, options, &m, &error) ||
        !MeasureBag(scenario, options, &m, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 2;
    }
    std::printf("%-22s %9zu %10.2f %12.2f %12.2f %10.1f\n",
                name.c_str(),
                m.triangles,
                m.build_s,
                m.source_rtf,
                m.bag_rtf,
                m.bag_mb / m.bag_s);
    results.push_back({{"scenario", name},
                       {"simulated_s", options.duration_s},
                       {"triangles", m.triangles},
                       {"world_build_s", m.build_s},
                       {"lidar_points", m.points},
                       {"source_real_time_factor", m.source_rtf},
                       {"bag_real_time_factor", m.bag_rtf},
                       {"bag_mb", m.bag_mb}});
    ok = ok && m.source_rtf >= 3.0;
  }
  const long rss = PeakRssKb();
  std::printf("peak RSS %.1f MB; target: in-process source >= 3x real time: %s\n",
              rss / 1024.0,
              ok ? "met" : "NOT met");
  if (!a.json_path.empty()) {
    std::ofstream(a.json_path) << nlohmann::json{{"results", results}, {"peak_rss_kb", rss}}.dump(2)
                               << "\n";
  }
  return ok ? 0 : 1;
}
