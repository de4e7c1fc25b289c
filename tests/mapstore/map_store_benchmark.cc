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

}  // namespace

int main(int argc, char** argv) {
  std::string submaps_dir, store_dir = "/tmp/raillomer_store_benchmark";
  int repeat = 1;
  bool error_check = true;
  mapstore::StoreOptions options;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--submaps" && i + 1 < argc) {
      submaps_dir = argv[++i];
    } else if (a == "--store" && i + 1 < argc) {
      store_dir = argv[++i];
    } else if (a == "--tile-m" && i + 1 < argc) {
      options.grid.tile_m = std::atof(argv[++i]);
    } else if (a == "--draco-speed" && i + 1 < argc) {
      options.draco_speed = std::atoi(argv[++i]);
    } else if (a == "--flush-points" && i + 1 < argc) {
      options.flush_dirty_points = std::strtoull(argv[++i], nullptr, 10);
    } else if (a == "--no-error-check") {
      error_check = false;
    } else if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr,
                   "usage: %s --submaps <dir> [--store <dir>] [--repeat N] [--no-error-check] "
                   "[--tile-m M] [--draco-speed N] [--flush-points N]\n",
                   argv[0]);
      return 2;
    }
  }
  if (submaps_dir.empty()) {
    std::fprintf(stderr, "map_store_benchmark: --submaps <dir> is required\n");
    return 2;
  }
  std::vector<std::string> files;
  for (const auto& e : std::filesystem::directory_iterator(submaps_dir)) {
    if (e.path().extension() == ".pcd") files.push_back(e.path().string());
  }
  std::sort(files.begin(), files.end());
  if (files.empty()) {
    std::fprintf(stderr, "map_store_benchmark: no .pcd submaps in %s\n", submaps_dir.c_str());
    return 1;
  }
  // Payloads in memory; with --repeat the run is sent again shifted 10 km north, as a longer run.
  std::vector<std::string> payloads;
  std::vector<api::Submap> submaps;
  size_t points = 0;
  for (int r = 0; r < repeat; ++r) {
    for (const std::string& f : files) {
      api::Submap s;
      std::string error;
      if (!api::ReadSubmapFile(f, &s, &error)) {
        std::fprintf(stderr, "map_store_benchmark: %s\n", error.c_str());
        return 1;
      }
      if (!s.georeferenced) continue;
      s.origin.y() += 10000.0 * r;
      s.sequence += 1'000'000ull * r;
      points += s.points.size();
      payloads.push_back(api::EncodeSubmapPcd(s));
      if (r == 0) submaps.push_back(std::move(s));
    }
  }
  std::filesystem::remove_all(store_dir);
  std::string error;
  auto store = mapstore::MapStore::Open(store_dir, options, &error);
  if (!store) {
    std::fprintf(stderr, "map_store_benchmark: %s\n", error.c_str());
    return 1;
  }
  mapstore::RunInfo run;
  store->CreateRun({"benchmark", "RLM-1", 0}, &run);
  std::printf("ingesting %zu submaps, %zu points\n", payloads.size(), points);
  const auto t0 = std::chrono::steady_clock::now();
  for (const std::string& p : payloads) {
    const mapstore::Result r = store->IngestSubmap(run.id, p, nullptr);
    if (!r) {
      std::fprintf(stderr, "map_store_benchmark: %s\n", r.message.c_str());
      return 1;
    }
  }
  const auto t_ingested = std::chrono::steady_clock::now();
  const mapstore::Result flushed = store->Flush();
  const auto t1 = std::chrono::steady_clock::now();
  if (!flushed) {
    std::fprintf(stderr, "map_store_benchmark: %s\n", flushed.message.c_str());
    return 1;
  }
  const double seconds = Seconds(t0, t1);
  const mapstore::StoreStats stats = store->stats();

  // Compression and error, level by level.
  const Eigen::AlignedBox2d everywhere(Eigen::Vector2d(0, 0), Eigen::Vector2d(1e6, 1e7));
  std::vector<mapstore::TileInfo> tiles;
  for (int level = 0; level < store->options().grid.levels; ++level) {
    store->TilesInBox(run.id, level, everywhere, &tiles);
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
  // Each level-0 point of the first pass against the nearest submap point (UTM, doubles).
  std::unordered_map<CellKey, std::vector<Eigen::Vector3d>, CellHash> source;
  for (const api::Submap& s : submaps) {
    if (!error_check) break;
    for (const Eigen::Vector3f& p : s.points) {
      const Eigen::Vector3d q = s.origin + p.cast<double>();
      source[{Cell(q.x(), 0.1), Cell(q.y(), 0.1), Cell(q.z(), 0.1)}].push_back(q);
    }
  }
  store->TilesInBox(run.id, 0, everywhere, &tiles);
  double worst = 0.0;
  size_t checked = 0;
  for (const auto& t : tiles) {
    if (!error_check) break;
    if (t.origin.y() >= submaps.front().origin.y() + 5000.0) continue;  // a repeated pass
    std::string bytes;
    mapstore::TilePoints decoded;
    store->Tile(run.id, t.key, nullptr, &bytes);
    if (!mapstore::DecodeTile(bytes, &decoded, &error)) {
      std::fprintf(stderr, "map_store_benchmark: %s\n", error.c_str());
      return 1;
    }
    for (const Eigen::Vector3f& p : decoded.points) {
      const Eigen::Vector3d q = decoded.origin + p.cast<double>();
      double best = INFINITY;
      for (int dx = -1; dx <= 1; ++dx)
        for (int dy = -1; dy <= 1; ++dy)
          for (int dz = -1; dz <= 1; ++dz) {
            auto it =
                source.find({Cell(q.x(), 0.1) + dx, Cell(q.y(), 0.1) + dy, Cell(q.z(), 0.1) + dz});
            if (it == source.end()) continue;
            for (const Eigen::Vector3d& s : it->second)
              best = std::min(best, (s - q).cwiseAbs().maxCoeff());
          }
      worst = std::max(worst, best);
      ++checked;
    }
  }
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  std::printf(
      "ingest: %.2f s (submaps %.2f s, last flush %.2f s; %llu flushes), %.2f million points "
      "per second (%llu off the height range; %llu tile points encoded)\n",
      seconds,
      Seconds(t0, t_ingested),
      Seconds(t_ingested, t1),
      static_cast<unsigned long long>(stats.flushes),
      points / seconds / 1e6,
      static_cast<unsigned long long>(stats.points_off_grid),
      static_cast<unsigned long long>(stats.points_encoded));
  std::printf("position error: largest %.2f mm over %zu level-0 points\n", 1000.0 * worst, checked);
  std::printf("peak RSS %.0f MB (the submaps held in memory included)\n", usage.ru_maxrss / 1024.0);
  return 0;
}
