// Ingest speed, compression and position error of the map store on a run's submaps (the
// estimator's <out>/submaps folder): every submap is read into memory first, then ingested into a
// fresh store and the tiles written, timed from the first submap to the last tile. Then the
// level-0 tiles are decoded and each point checked against the nearest submap point.
//
//   map_store_benchmark --submaps <dir> [--store <dir>] [--repeat N] [--no-error-check]
//                       [--tile-m M] [--draco-speed N] [--flush-points N]
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>
#include <unordered_map>
#include <vector>

#include <sys/resource.h>

#include "api/stream.h"
#include "mapstore/map_store.h"
#include "mapstore/tile_codec.h"

using namespace raillomer;

namespace {

double Seconds(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

int64_t Cell(double v, double size) { return static_cast<int64_t>(std::floor(v / size)); }

struct CellKey {
  int64_t x, y, z;
  bool operator==(const CellKey& o) const { return x == o.x && y == o.y && z == o.z; }
};
struct CellHash {
  size_t operator()(const CellKey& k) const {
    return std::hash<int64_t>()(k.x * 73856093 ^ k.y * 19349663 ^ k.z * 83492791);
  }
};

/// The command line.
struct Args {
  std::string submaps_dir, store_dir = "/tmp/raillomer_store_benchmark";
  int repeat = 1;
  bool error_check = true;
  mapstore::StoreOptions options;
};

/// The command line into `a`; false (usage printed) on anything it does not know.
bool ParseArgs(int argc, char** argv, Args* a) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--submaps" && i + 1 < argc) {
      a->submaps_dir = argv[++i];
    } else if (arg == "--store" && i + 1 < argc) {
      a->store_dir = argv[++i];
    } else if (arg == "--tile-m" && i + 1 < argc) {
      a->options.grid.tile_m = std::atof(argv[++i]);
    } else if (arg == "--draco-speed" && i + 1 < argc) {
      a->options.draco_speed = std::atoi(argv[++i]);
    } else if (arg == "--flush-points" && i + 1 < argc) {
      a->options.flush_dirty_points = std::strtoull(argv[++i], nullptr, 10);
    } else if (arg == "--no-error-check") {
      a->error_check = false;
    } else if (arg == "--repeat" && i + 1 < argc) {
      a->repeat = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr,
                   "usage: %s --submaps <dir> [--store <dir>] [--repeat N] [--no-error-check] "
                   "[--tile-m M] [--draco-speed N] [--flush-points N]\n",
                   argv[0]);
      return false;
    }
  }
  if (a->submaps_dir.empty()) {
    std::fprintf(stderr, "map_store_benchmark: --submaps <dir> is required\n");
    return false;
  }
  return true;
}

/// The run's georeferenced submaps in memory: their payloads (with --repeat, the run again
/// shifted 10 km north, as a longer run), the first pass decoded, and the points sent.
struct Payloads {
  std::vector<std::string> payloads;
  std::vector<api::Submap> submaps;
  size_t points = 0;
};

bool LoadPayloads(const Args& a, Payloads* out, std::string* error) {
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::directory_iterator(a.submaps_dir)) {
    if (e.path().extension() == ".pcd") files.push_back(e.path().string());
  }
  std::sort(files.begin(), files.end());
  if (files.empty()) return *error = "no .pcd submaps in " + a.submaps_dir, false;
  for (int r = 0; r < a.repeat; ++r) {
    for (const std::string& f : files) {
      api::Submap s;
      if (!api::ReadSubmapFile(f, &s, error)) return false;
      if (!s.georeferenced) continue;
      s.origin.y() += 10000.0 * r;
      s.sequence += 1'000'000ull * r;
      out->points += s.points.size();
      out->payloads.push_back(api::EncodeSubmapPcd(s));
      if (r == 0) out->submaps.push_back(std::move(s));
    }
  }
  if (out->submaps.empty())
    return *error = "no submap in " + a.submaps_dir + " is georeferenced", false;
  return true;
}

/// Bits per point and the quantisation's bound, level by level.
void PrintLevels(const mapstore::MapStore& store, int64_t run, const Eigen::AlignedBox2d& box) {
  std::vector<mapstore::TileInfo> tiles;
  for (int level = 0; level < store.options().grid.levels; ++level) {
    store.TilesInBox(run, level, box, &tiles);
    int64_t tile_points = 0, tile_bytes = 0;
    for (const auto& t : tiles) {
      tile_points += t.points;
      tile_bytes += t.bytes;
    }
    std::printf("level %d: %zu tiles, %lld points, %.2f bits per point (max error %.2f mm)\n",
                level,
                tiles.size(),
                static_cast<long long>(tile_points),
                8.0 * tile_bytes / std::max<int64_t>(1, tile_points),
                tiles.empty() ? 0.0 : 1000.0 * tiles[0].max_error_m);
  }
}

/// The submaps' points (UTM, doubles) on a 0.1 m grid.
using PointGrid = std::unordered_map<CellKey, std::vector<Eigen::Vector3d>, CellHash>;

PointGrid GridOf(const std::vector<api::Submap>& submaps) {
  PointGrid grid;
  for (const api::Submap& s : submaps) {
    for (const Eigen::Vector3f& p : s.points) {
      const Eigen::Vector3d q = s.origin + p.cast<double>();
      grid[{Cell(q.x(), 0.1), Cell(q.y(), 0.1), Cell(q.z(), 0.1)}].push_back(q);
    }
  }
  return grid;
}

/// The distance (largest coordinate) from `q` to the nearest point of the grid's cells around
/// it; infinity if none is near.
double NearestError(const PointGrid& grid, const Eigen::Vector3d& q) {
  double best = INFINITY;
  for (int dx = -1; dx <= 1; ++dx)
    for (int dy = -1; dy <= 1; ++dy)
      for (int dz = -1; dz <= 1; ++dz) {
        auto it = grid.find({Cell(q.x(), 0.1) + dx, Cell(q.y(), 0.1) + dy, Cell(q.z(), 0.1) + dz});
        if (it == grid.end()) continue;
        for (const Eigen::Vector3d& s : it->second)
          best = std::min(best, (s - q).cwiseAbs().maxCoeff());
      }
  return best;
}

/// Each level-0 point of the first pass against the nearest submap point: the largest error
/// and the points checked.
bool LargestError(const mapstore::MapStore& store,
                  int64_t run,
                  const Eigen::AlignedBox2d& box,
                  const std::vector<api::Submap>& submaps,
                  double* worst,
                  size_t* checked,
                  std::string* error) {
  const PointGrid source = GridOf(submaps);
  std::vector<mapstore::TileInfo> tiles;
  store.TilesInBox(run, 0, box, &tiles);
  for (const auto& t : tiles) {
    if (t.origin.y() >= submaps.front().origin.y() + 5000.0) continue;  // a repeated pass
    std::string bytes;
    mapstore::TilePoints decoded;
    store.Tile(run, t.key, nullptr, &bytes);
    if (!mapstore::DecodeTile(bytes, &decoded, error)) return false;
    for (const Eigen::Vector3f& p : decoded.points) {
      *worst = std::max(*worst, NearestError(source, decoded.origin + p.cast<double>()));
      ++*checked;
    }
  }
  return true;
}

int Fail(const std::string& message) {
  std::fprintf(stderr, "map_store_benchmark: %s\n", message.c_str());
  return 1;
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  if (!ParseArgs(argc, argv, &a)) return 2;
  Payloads in;
  std::string error;
  if (!LoadPayloads(a, &in, &error)) return Fail(error);
  std::filesystem::remove_all(a.store_dir);
  auto store = mapstore::MapStore::Open(a.store_dir, a.options, &error);
  if (!store) return Fail(error);
  mapstore::RunInfo run;
  store->CreateRun({"benchmark", "RLM-1", 0}, &run);
  std::printf("ingesting %zu submaps, %zu points\n", in.payloads.size(), in.points);
  const auto t0 = std::chrono::steady_clock::now();
  for (const std::string& p : in.payloads) {
    const mapstore::Result r = store->IngestSubmap(run.id, p, nullptr);
    if (!r) return Fail(r.message);
  }
  const auto t_ingested = std::chrono::steady_clock::now();
  const mapstore::Result flushed = store->Flush();
  const auto t1 = std::chrono::steady_clock::now();
  if (!flushed) return Fail(flushed.message);
  const double seconds = Seconds(t0, t1);
  const mapstore::StoreStats stats = store->stats();

  const Eigen::AlignedBox2d everywhere(Eigen::Vector2d(0, 0), Eigen::Vector2d(1e6, 1e7));
  PrintLevels(*store, run.id, everywhere);
  double worst = 0.0;
  size_t checked = 0;
  if (a.error_check &&
      !LargestError(*store, run.id, everywhere, in.submaps, &worst, &checked, &error))
    return Fail(error);
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  std::printf(
      "ingest: %.2f s (submaps %.2f s, last flush %.2f s; %llu flushes), %.2f million points "
      "per second (%llu off the height range; %llu tile points encoded)\n",
      seconds,
      Seconds(t0, t_ingested),
      Seconds(t_ingested, t1),
      static_cast<unsigned long long>(stats.flushes),
      in.points / seconds / 1e6,
      static_cast<unsigned long long>(stats.points_off_grid),
      static_cast<unsigned long long>(stats.points_encoded));
  std::printf("position error: largest %.2f mm over %zu level-0 points\n", 1000.0 * worst, checked);
  std::printf("peak RSS %.0f MB (the submaps held in memory included)\n", usage.ru_maxrss / 1024.0);
  return 0;
}
