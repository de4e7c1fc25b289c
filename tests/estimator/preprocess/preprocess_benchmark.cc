// Preprocessing and LOAM features on simulated frames: time per stage, what the filters remove by
// point kind, and feature counts per scenario and LiDAR. Not a test: prints one line per LiDAR.
//
//   bench_preprocess [--frames N] [--every S] [--repeat R] [--exempt-intensity I] [scenario ...]
//
// Frames are taken every S seconds from 5 s into the run; each stage is timed R times on the same
// frame and the fastest run counts (the machine is shared; the minimum is the stage's own cost).

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include "estimator/features/loam_features.h"
#include "estimator/preprocess/filters.h"
#include "estimator/sim/simulator.h"

namespace raillomer {
namespace {

using Clock = std::chrono::steady_clock;
using sim::PointKind;

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

constexpr int kKinds = 5;

/// Sums over the frames of one LiDAR.
struct Totals {
  size_t frames = 0;
  size_t kind_in[kKinds] = {}, kind_out[kKinds] = {};
  size_t surface_in = 0;  ///< true returns beyond min_range_m
  size_t edges = 0, planes = 0;
  size_t min_edges = std::numeric_limits<size_t>::max(), max_edges = 0;
  size_t min_planes = std::numeric_limits<size_t>::max(), max_planes = 0;
  double ms_convert = 0, ms_preprocess = 0, ms_deskew = 0, ms_features = 0, ms_worst = 0;
  double ms_filter[3] = {};  ///< near/far, flicker, bleeding
};

/// The command line.
struct BenchOptions {
  int frames = 10, repeat = 5;
  double every_s = 2.0;
  std::vector<std::string> names;
  PreprocessOptions pre;
};

/// Reads the command line into `options`; false on an unknown flag (usage printed).
bool ParseArgs(int argc, char** argv, BenchOptions* options) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--frames" && i + 1 < argc) {
      options->frames = std::max(1, std::atoi(argv[++i]));
    } else if (arg == "--every" && i + 1 < argc) {
      options->every_s = std::atof(argv[++i]);
    } else if (arg == "--repeat" && i + 1 < argc) {
      options->repeat = std::max(1, std::atoi(argv[++i]));
    } else if (arg == "--exempt-intensity" && i + 1 < argc) {
      options->pre.flicker_exempt_intensity = std::atof(argv[++i]);
    } else if (!arg.empty() && arg[0] == '-') {
      std::fprintf(stderr,
                   "usage: bench_preprocess [--frames N] [--every S] [--repeat R] "
                   "[--exempt-intensity I] [scenario ...]\n");
      return false;
    } else {
      options->names.push_back(arg);
    }
  }
  if (options->names.empty())
    options->names = {"rich_low_station_a", "poor_high_open_a", "poor_low_embankment_b"};
  return true;
}

/// Point kinds by exact coordinates (the filters do not move points).
using KindOf = std::map<std::tuple<float, float, float>, int>;

/// Counts one frame's points by kind into `t` and returns the kind of each return.
KindOf CountKinds(const io::LidarFrame& message,
                  const std::vector<PointKind>& kinds,
                  const PreprocessOptions& pre,
                  Totals* t) {
  KindOf kind_of;
  for (size_t i = 0; i < message.points.size(); ++i) {
    const io::LivoxPoint& p = message.points[i];
    const int kind = static_cast<int>(kinds[i]);
    ++t->kind_in[kind];
    if (kinds[i] == PointKind::kNoReturn) continue;
    kind_of[{p.x, p.y, p.z}] = kind;
    if (kinds[i] == PointKind::kSurface && Eigen::Vector3f(p.x, p.y, p.z).norm() >= pre.min_range_m)
      ++t->surface_in;
  }
  return kind_of;
}

/// The fastest of `repeat` runs of each stage on one frame.
struct StageTimes {
  double convert = 1e9, preprocess = 1e9, deskew = 1e9, features = 1e9;
  double filter[3] = {1e9, 1e9, 1e9};  ///< near/far, flicker, bleeding
  double Sum() const { return convert + preprocess + deskew + features; }
};

/// Times conversion, Preprocess() stage by stage, deskew and features on one frame; counts the
/// kinds the filters keep into `t` and returns the features.
FeatureSet TimeStages(const BenchOptions& options,
                      const io::LidarFrame& message,
                      const KindOf& kind_of,
                      const sim::LivoxHorizonModel& lidar,
                      int unit,
                      double period_s,
                      const Eigen::Isometry3d& T_end_start,
                      StageTimes* best,
                      Totals* t) {
  const LoamFeatureOptions feature_options;
  FeatureSet features;
  for (int r = 0; r < options.repeat; ++r) {
    auto start = Clock::now();
    Scan scan = ScanFromLidarFrame(message, unit, period_s);
    best->convert = std::min(best->convert, MsSince(start));
    start = Clock::now();
    auto filter_start = Clock::now();
    RemoveNearAndFarPoints(options.pre, &scan, nullptr);
    best->filter[0] = std::min(best->filter[0], MsSince(filter_start));
    filter_start = Clock::now();
    RemoveSunFlicker(options.pre, &scan, nullptr);
    best->filter[1] = std::min(best->filter[1], MsSince(filter_start));
    filter_start = Clock::now();
    RemoveBoundaryBleeding(options.pre, &scan, nullptr);
    best->filter[2] = std::min(best->filter[2], MsSince(filter_start));
    best->preprocess = std::min(best->preprocess, MsSince(start));
    if (r == 0) {
      for (const ScanPoint& p : scan.points) ++t->kind_out[kind_of.at({p.p.x(), p.p.y(), p.p.z()})];
    }
    start = Clock::now();
    Deskew(lidar.T_body_lidar(), T_end_start, &scan);
    best->deskew = std::min(best->deskew, MsSince(start));
    start = Clock::now();
    features = ExtractLoamFeatures(feature_options, scan);
    best->features = std::min(best->features, MsSince(start));
  }
  return features;
}

/// Adds one frame's times and feature counts to `t`.
void Accumulate(const StageTimes& best, const FeatureSet& features, Totals* t) {
  t->ms_convert += best.convert;
  t->ms_preprocess += best.preprocess;
  for (int i = 0; i < 3; ++i) t->ms_filter[i] += best.filter[i];
  t->ms_deskew += best.deskew;
  t->ms_features += best.features;
  t->ms_worst = std::max(t->ms_worst, best.Sum());
  t->edges += features.edges.size();
  t->planes += features.planes.size();
  t->min_edges = std::min(t->min_edges, features.edges.size());
  t->max_edges = std::max(t->max_edges, features.edges.size());
  t->min_planes = std::min(t->min_planes, features.planes.size());
  t->max_planes = std::max(t->max_planes, features.planes.size());
  ++t->frames;
}

/// Prints one LiDAR's line: features, what the filters removed by kind, and time per stage.
void PrintTotals(const std::string& name, const std::string& lidar, const Totals& t) {
  const double n = static_cast<double>(t.frames);
  auto removed = [&t](PointKind kind) {
    const int k = static_cast<int>(kind);
    return t.kind_in[k] ? 100.0 * (t.kind_in[k] - t.kind_out[k]) / t.kind_in[k] : 0.0;
  };
  const int surface = static_cast<int>(PointKind::kSurface);
  const int flicker = static_cast<int>(PointKind::kSunFlicker);
  const int bleeding = static_cast<int>(PointKind::kBleeding);
  std::printf(
      "%-22s %-5s frames %zu | edges %.0f [%zu..%zu] planes %.0f [%zu..%zu] | flicker %zu "
      "removed %.1f%% | bleeding %zu removed %.1f%% | surface kept %zu/%zu %.2f%% | ms "
      "convert %.2f preprocess %.2f (near/far %.2f flicker %.2f bleeding %.2f) deskew %.2f "
      "features %.2f worst %.2f\n",
      name.c_str(),
      lidar.c_str(),
      t.frames,
      t.edges / n,
      t.min_edges,
      t.max_edges,
      t.planes / n,
      t.min_planes,
      t.max_planes,
      t.kind_in[flicker],
      removed(PointKind::kSunFlicker),
      t.kind_in[bleeding],
      removed(PointKind::kBleeding),
      t.kind_out[surface],
      t.surface_in,
      100.0 * t.kind_out[surface] / std::max<size_t>(t.surface_in, 1),
      t.ms_convert / n,
      t.ms_preprocess / n,
      t.ms_filter[0] / n,
      t.ms_filter[1] / n,
      t.ms_filter[2] / n,
      t.ms_deskew / n,
      t.ms_features / n,
      t.ms_worst);
}

/// Benchmarks one LiDAR of a simulated scenario over the chosen frames.
Totals BenchLidar(const BenchOptions& options,
                  const sim::Simulator& simulator,
                  double period_s,
                  size_t unit) {
  const sim::TruthMotion& truth = simulator.truth();
  const sim::LivoxHorizonModel& lidar = simulator.lidars()[unit];
  Totals t;
  for (int f = 0; f < options.frames; ++f) {
    const uint64_t frame = static_cast<uint64_t>((5.0 + f * options.every_s) / period_s);
    const double t0 = frame * period_s;
    io::LidarFrame message;
    message.timebase_ns = static_cast<uint64_t>(t0 * 1e9);
    std::vector<PointKind> kinds;
    lidar.Scan(
        frame,
        t0,
        [&truth](double time) { return truth.Pose(time); },
        simulator.caster(),
        &message.points,
        &kinds);
    const KindOf kind_of = CountKinds(message, kinds, options.pre, &t);
    const Eigen::Isometry3d T_end_start = truth.Pose(t0 + period_s).inverse() * truth.Pose(t0);
    StageTimes best;
    const FeatureSet features = TimeStages(
        options, message, kind_of, lidar, static_cast<int>(unit), period_s, T_end_start, &best, &t);
    Accumulate(best, features, &t);
  }
  return t;
}

/// Simulates one scenario and prints a line per LiDAR; false (error printed) if it cannot.
bool BenchScenario(const BenchOptions& options, const std::string& name) {
  sim::Scenario scenario;
  std::string error;
  if (!sim::LoadScenario(name, &scenario, &error)) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return false;
  }
  sim::SimOptions sim_options;
  sim_options.duration_s = 5.0 + options.frames * options.every_s;
  auto simulator = sim::Simulator::Create(scenario, sim_options, &error);
  if (!simulator) {
    std::fprintf(stderr, "%s\n", error.c_str());
    return false;
  }
  const double period_s = 1.0 / scenario.lidar_rate_hz;
  for (size_t unit = 0; unit < simulator->lidars().size(); ++unit) {
    const Totals t = BenchLidar(options, *simulator, period_s, unit);
    PrintTotals(name, simulator->lidars()[unit].config().name, t);
  }
  return true;
}

int Run(int argc, char** argv) {
  BenchOptions options;
  if (!ParseArgs(argc, argv, &options)) return 2;
  for (const std::string& name : options.names)
    if (!BenchScenario(options, name)) return 1;
  return 0;
}

}  // namespace
}  // namespace raillomer

int main(int argc, char** argv) { return raillomer::Run(argc, argv); }
