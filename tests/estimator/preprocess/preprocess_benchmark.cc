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

int Run(int argc, char** argv) {
  int frames = 10, repeat = 5;
  double every_s = 2.0;
  std::vector<std::string> names;
  PreprocessOptions pre_options;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--frames" && i + 1 < argc) {
      frames = std::max(1, std::atoi(argv[++i]));
    } else if (arg == "--every" && i + 1 < argc) {
      every_s = std::atof(argv[++i]);
    } else if (arg == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (arg == "--exempt-intensity" && i + 1 < argc) {
      pre_options.flicker_exempt_intensity = std::atof(argv[++i]);
    } else if (!arg.empty() && arg[0] == '-') {
      std::fprintf(stderr,
                   "usage: bench_preprocess [--frames N] [--every S] [--repeat R] "
                   "[--exempt-intensity I] [scenario ...]\n");
      return 2;
    } else {
      names.push_back(arg);
    }
  }
  if (names.empty()) names = {"rich_low_station_a", "poor_high_open_a", "poor_low_embankment_b"};
  const LoamFeatureOptions feature_options;
  for (const std::string& name : names) {
    sim::Scenario scenario;
    std::string error;
    if (!sim::LoadScenario(name, &scenario, &error)) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 1;
    }
    sim::SimOptions sim_options;
    sim_options.duration_s = 5.0 + frames * every_s;
    auto simulator = sim::Simulator::Create(scenario, sim_options, &error);
    if (!simulator) {
      std::fprintf(stderr, "%s\n", error.c_str());
      return 1;
    }
    const sim::TruthMotion& truth = simulator->truth();
    const double period_s = 1.0 / scenario.lidar_rate_hz;
    for (size_t unit = 0; unit < simulator->lidars().size(); ++unit) {
      const sim::LivoxHorizonModel& lidar = simulator->lidars()[unit];
      Totals t;
      for (int f = 0; f < frames; ++f) {
        const uint64_t frame = static_cast<uint64_t>((5.0 + f * every_s) / period_s);
        const double t0 = frame * period_s;
        io::LidarFrame message;
        message.timebase_ns = static_cast<uint64_t>(t0 * 1e9);
        std::vector<PointKind> kinds;
        lidar.Scan(
            frame,
            t0,
            [&truth](double time) { return truth.Pose(time); },
            simulator->caster(),
            &message.points,
            &kinds);
        // What produced each point, by its exact coordinates (the filters do not move points).
        std::map<std::tuple<float, float, float>, int> kind_of;
        for (size_t i = 0; i < message.points.size(); ++i) {
          const io::LivoxPoint& p = message.points[i];
          const int kind = static_cast<int>(kinds[i]);
          ++t.kind_in[kind];
          if (kinds[i] == PointKind::kNoReturn) continue;
          kind_of[{p.x, p.y, p.z}] = kind;
          if (kinds[i] == PointKind::kSurface &&
              Eigen::Vector3f(p.x, p.y, p.z).norm() >= pre_options.min_range_m) {
            ++t.surface_in;
          }
        }
        const Eigen::Isometry3d T_end_start = truth.Pose(t0 + period_s).inverse() * truth.Pose(t0);
        double best[4] = {1e9, 1e9, 1e9, 1e9}, filter_best[3] = {1e9, 1e9, 1e9};
        Scan scan;
        FeatureSet features;
        for (int r = 0; r < repeat; ++r) {
          auto start = Clock::now();
          scan = ScanFromLidarFrame(message, static_cast<int>(unit), period_s);
          best[0] = std::min(best[0], MsSince(start));
          // Preprocess() stage by stage.
          start = Clock::now();
          RemoveNearAndFarPoints(pre_options, &scan, nullptr);
          filter_best[0] = std::min(filter_best[0], MsSince(start));
          auto filter_start = Clock::now();
          RemoveSunFlicker(pre_options, &scan, nullptr);
          filter_best[1] = std::min(filter_best[1], MsSince(filter_start));
          filter_start = Clock::now();
          RemoveBoundaryBleeding(pre_options, &scan, nullptr);
          filter_best[2] = std::min(filter_best[2], MsSince(filter_start));
          best[1] = std::min(best[1], MsSince(start));
          if (r == 0) {
            for (const ScanPoint& p : scan.points)
              ++t.kind_out[kind_of.at({p.p.x(), p.p.y(), p.p.z()})];
          }
          start = Clock::now();
          Deskew(lidar.T_body_lidar(), T_end_start, &scan);
          best[2] = std::min(best[2], MsSince(start));
          start = Clock::now();
          features = ExtractLoamFeatures(feature_options, scan);
          best[3] = std::min(best[3], MsSince(start));
        }
        t.ms_convert += best[0];
        t.ms_preprocess += best[1];
        for (int i = 0; i < 3; ++i) t.ms_filter[i] += filter_best[i];
        t.ms_deskew += best[2];
        t.ms_features += best[3];
        t.ms_worst = std::max(t.ms_worst, best[0] + best[1] + best[2] + best[3]);
        t.edges += features.edges.size();
        t.planes += features.planes.size();
        t.min_edges = std::min(t.min_edges, features.edges.size());
        t.max_edges = std::max(t.max_edges, features.edges.size());
        t.min_planes = std::min(t.min_planes, features.planes.size());
        t.max_planes = std::max(t.max_planes, features.planes.size());
        ++t.frames;
      }
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
          lidar.config().name.c_str(),
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
  }
  return 0;
}

}  // namespace
}  // namespace raillomer

int main(int argc, char** argv) { return raillomer::Run(argc, argv); }
