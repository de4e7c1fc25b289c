#include "mapstore/map_store.h"

#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <future>
#include <set>
#include <unordered_map>

#include "api/atomic_file.h"
#include "api/clock.h"
#include "api/printable.h"
#include "api/trajectory.h"
#include "mapstore/schema.h"
#include "mapstore/sqlite.h"
#include "mapstore/voxel_set.h"

namespace raillomer::mapstore {
namespace {

using api::NowNs;

std::string Hex64(uint64_t v) {
  char text[17];
  std::snprintf(text, sizeof(text), "%016" PRIx64, v);
  return text;
}

uint64_t Fnv1a(const std::string& bytes) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

/// A voxel of a tile (tile frame): x and y from 0, z from half a tile below the reference.
uint64_t TileVoxel(const Eigen::Vector3f& o, float inverse_voxel) {
  constexpr int64_t kBias = int64_t{1} << 20;
  constexpr uint64_t kMask = (uint64_t{1} << 21) - 1;
  const auto axis = [&](float v, int64_t bias) {
    return static_cast<uint64_t>(static_cast<int64_t>(std::floor(v * inverse_voxel)) + bias) &
           kMask;
  };
  return (axis(o.x(), 0) << 42) | (axis(o.y(), 0) << 21) | axis(o.z(), kBias);
}

/// A submap's points can go into the UTM tiles: georeferenced, finite, plausible UTM.
bool ValidSubmap(const api::Submap& s, const StoreOptions& options, std::string* error) {
  const size_t max_points = options.max_points_per_submap;
  if (!s.georeferenced) {
    *error = "the submap is not georeferenced (zone 'local'): only UTM submaps go into tiles";
    return false;
  }
  const Eigen::Vector3d& o = s.origin;
  if (!o.allFinite() || o.x() < 0.0 || o.x() > 1.0e6 || o.y() < 0.0 || o.y() > 1.0e7 ||
      std::abs(o.z()) > 1.0e4) {
    char text[160];
    std::snprintf(text,
                  sizeof(text),
                  "the submap origin (%g, %g, %g) is not a UTM position (easting 0-1000 km, "
                  "northing 0-10000 km)",
                  o.x(),
                  o.y(),
                  o.z());
    *error = text;
    return false;
  }
  if (s.points.empty()) {
    *error = "the submap has no points";
    return false;
  }
  if (s.points.size() > max_points) {
    *error = "the submap has " + std::to_string(s.points.size()) + " points, more than the " +
             std::to_string(max_points) + " allowed";
    return false;
  }
  for (size_t i = 0; i < s.points.size(); ++i) {
    if (!s.points[i].allFinite() || s.points[i].cwiseAbs().maxCoeff() > 1.0e4f ||
        !std::isfinite(s.intensities[i])) {
      *error = "point " + std::to_string(i) +
               " is not finite or lies more than 10 km from the submap origin";
      return false;
    }
  }
  if (s.last_stamp_ns < s.first_stamp_ns) {
    *error = "the submap's last stamp is before its first";
    return false;
  }
  Eigen::AlignedBox2f box;
  for (const Eigen::Vector3f& p : s.points) box.extend(p.head<2>());
  const float extent = box.sizes().maxCoeff();
  if (extent > options.max_submap_extent_m) {
    char text[160];
    std::snprintf(text,
                  sizeof(text),
                  "the submap's points spread over %.0f m, more than the %.0f m a submap may "
                  "span (max_submap_extent_m)",
                  extent,
                  options.max_submap_extent_m);
    *error = text;
    return false;
  }
  return true;
}

bool ValidPose(const api::StreamPose& p, std::string* error) {
  if (!p.p.allFinite() || !p.q.coeffs().allFinite() || std::abs(p.q.norm() - 1.0) > 1e-3) {
    *error = "pose " + std::to_string(p.sequence) +
             " has a non-finite position or a rotation that is not a unit quaternion";
    return false;
  }
  if (p.georeferenced && (p.p.x() < 0.0 || p.p.x() > 1.0e6 || p.p.y() < 0.0 || p.p.y() > 1.0e7)) {
    *error = "pose " + std::to_string(p.sequence) + " is georeferenced but not a UTM position";
    return false;
  }
  return true;
}

Result Fail(Outcome outcome, std::string message) { return {outcome, std::move(message)}; }

/// Metres as a whole number, however large (a cast to int of a huge one is undefined).
std::string Metres(double m) {
  char text[64];
  std::snprintf(text, sizeof(text), "%.0f", m);
  return text;
}

/// Whether a name holds at most `max` bytes and prints as it is (api::Printable).
bool Printable(const std::string& s, size_t max) { return s.size() <= max && api::Printable(s); }

}  // namespace

const char* ToString(Outcome outcome) {
  switch (outcome) {
    case Outcome::kOk:
      return "ok";
    case Outcome::kDuplicate:
      return "duplicate";
    case Outcome::kInvalid:
      return "invalid";
    case Outcome::kNotFound:
      return "not_found";
    case Outcome::kConflict:
      return "conflict";
    case Outcome::kError:
      return "error";
  }
  return "error";
}

bool StoreOptions::IsValid(std::string* error) const {
  if (!grid.IsValid(error)) return false;
  if (max_points_per_submap < 1) return *error = "max_points_per_submap must be positive", false;
  if (hot_points_budget < 100'000) return *error = "hot_points_budget must be >= 100000", false;
  if (hot_tiles_budget < 64) return *error = "hot_tiles_budget must be >= 64", false;
  if (!(max_submap_extent_m >= 10.0 && max_submap_extent_m <= 20000.0))
    return *error = "max_submap_extent_m must be in [10, 20000]", false;
  if (draco_speed < 0 || draco_speed > 9) return *error = "draco_speed must be in [0, 9]", false;
  if (encode_threads < 1 || encode_threads > 64)
    return *error = "encode_threads must be in [1, 64]", false;
  return true;
}

/// A tile being filled: its points, and the voxels they occupy.
struct MapStore::HotTile {
  TileKey key;
  TileQuantization quantization;
  TilePoints points;
  VoxelSet voxels;
  int64_t version = 0;  ///< of the written tile this one continues (0: none yet)
  bool dirty = false;
  int in_flight = 0;        ///< snapshots being encoded: not to be let go before they are written
  bool unreadable = false;  ///< its stored version could not be read: never written over
  uint64_t touched = 0;
};

/// Reader connections, reused: SQLite's WAL lets them read while the writer writes.
class MapStore::Readers {
 public:
  explicit Readers(std::string path) : path_(std::move(path)) {}
  class Lease {
   public:
    Lease(Readers* owner, std::unique_ptr<Database> db) : owner_(owner), db_(std::move(db)) {}
    ~Lease() {
      if (db_) owner_->Give(std::move(db_));
    }
    Lease(Lease&&) = default;
    explicit operator bool() const { return db_ != nullptr; }
    const Database& operator*() const { return *db_; }

   private:
    Readers* owner_;
    std::unique_ptr<Database> db_;
  };
  Lease Take(std::string* error) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (!idle_.empty()) {
        std::unique_ptr<Database> db = std::move(idle_.back());
        idle_.pop_back();
        return Lease(this, std::move(db));
      }
    }
    auto db = std::make_unique<Database>();
    if (!db->Open(path_, false, error)) db.reset();
    return Lease(this, std::move(db));
  }

 private:
  void Give(std::unique_ptr<Database> db) {
    std::lock_guard<std::mutex> lock(mu_);
    if (idle_.size() < 512) idle_.push_back(std::move(db));  // one per serving thread
  }
  std::string path_;
  std::mutex mu_;
  std::vector<std::unique_ptr<Database>> idle_;
};

MapStore::MapStore(const std::string& dir, const StoreOptions& options)
    : dir_(dir), options_(options) {}

MapStore::~MapStore() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (flusher_.joinable()) flusher_.join();
  if (writer_) Flush(nullptr);
}

std::unique_ptr<MapStore> MapStore::Open(const std::string& dir,
                                         const StoreOptions& options,
                                         std::string* error) {
  if (!options.IsValid(error)) {
    *error = "store options: " + *error;
    return nullptr;
  }
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) {
    *error = "cannot create the store folder " + dir + ": " + ec.message();
    return nullptr;
  }
  // The index, the payloads and the token are the server's alone: the folder is private.
  std::filesystem::permissions(dir, std::filesystem::perms::owner_all, ec);
  if (ec) {
    *error = "cannot make the store folder " + dir + " private (0700): " + ec.message();
    return nullptr;
  }
  std::unique_ptr<StoreLock> lock = StoreLock::Acquire(dir, error);
  if (!lock) return nullptr;
  std::unique_ptr<MapStore> store(new MapStore(dir, options));
  store->lock_ = std::move(lock);
  store->writer_ = std::make_unique<Database>();
  if (!store->writer_->Open(store->IndexPath(), true, error)) return nullptr;
  if (!MigrateSchema(*store->writer_, error)) {
    *error = store->IndexPath() + ": " + *error;
    return nullptr;
  }
  store->readers_ = std::make_unique<Readers>(store->IndexPath());
  if (!store->Recover(error)) return nullptr;
  if (options.flush_interval_ms > 0)
    store->flusher_ = std::thread([s = store.get()]() { s->FlushLoop(); });
  return store;
}

std::string MapStore::IncomingPath(int64_t run_id, uint64_t sequence) const {
  return dir_ + "/incoming/" + std::to_string(run_id) + "-" + std::to_string(sequence) + ".pcd";
}

bool MapStore::Recover(std::string* error) {
  std::unique_lock<std::mutex> lock(mu_);
  std::error_code ec;
  std::filesystem::create_directories(dir_ + "/incoming", ec);
  if (ec) {
    *error = "cannot create " + dir_ + "/incoming: " + ec.message();
    return false;
  }
  // Submaps acknowledged before a crash whose tiles were not all written: merge them again.
  Statement q(*writer_,
              "SELECT run_id, sequence FROM submaps WHERE tiled = 0 ORDER BY received_ns, run_id, "
              "sequence");
  if (!q.ok()) {
    *error = "cannot read the submaps to recover: " + q.error();
    return false;
  }
  std::vector<std::pair<int64_t, uint64_t>> lost;
  std::set<std::string> waiting;
  while (q.Step()) {
    const int64_t run = q.Int(0);
    const uint64_t sequence = static_cast<uint64_t>(q.Int(1));
    const std::string path = IncomingPath(run, sequence);
    api::Submap s;
    std::string message;
    if (!api::ReadSubmapFile(path, &s, &message)) {
      lost.emplace_back(run, sequence);  // the payload did not survive (a power cut)
      continue;
    }
    IngestReceipt receipt;
    Merge(run, s, &receipt);
    unflushed_.emplace_back(run, sequence);
    waiting.insert(path);
    recovery_.recovered.emplace_back(run, sequence);
    ++stats_.submaps_recovered;
  }
  if (!q.error().empty()) {
    *error = "cannot read the submaps to recover: " + q.error();
    return false;
  }
  for (const auto& [run, sequence] : lost) {
    if (!MarkLostLocked(run, sequence, error)) return false;
    recovery_.lost.emplace_back(run, sequence);
    ++stats_.submaps_lost;
  }
  // Payloads written but never acknowledged (a crash before the commit) are not the store's.
  for (const auto& e : std::filesystem::directory_iterator(dir_ + "/incoming", ec)) {
    if (!waiting.count(e.path().string())) std::filesystem::remove(e.path(), ec);
  }
  lock.unlock();
  const Result r = Flush(nullptr);
  if (!r) *error = r.message;
  return r.ok();
}

bool MapStore::MarkLostLocked(int64_t run_id, uint64_t sequence, std::string* error) {
  // The submap stays (its sequence is taken; the same bytes sent again restore it), but its
  // points leave the run's counts, which say what the tiles hold.
  Transaction t(*writer_);
  Statement mark(*writer_, "UPDATE submaps SET tiled = -1 WHERE run_id = ? AND sequence = ?");
  Statement count(*writer_,
                  "UPDATE runs SET submaps = submaps - 1, submaps_lost = submaps_lost + 1, "
                  "points = points - (SELECT points FROM submaps WHERE run_id = ? AND sequence = "
                  "?) WHERE id = ?");
  const int64_t seq = static_cast<int64_t>(sequence);
  if (!t.ok() || !count.Bind(1, run_id).Bind(2, seq).Bind(3, run_id).Run() ||
      !mark.Bind(1, run_id).Bind(2, seq).Run() || !t.Commit(error)) {
    *error = "cannot mark submap " + std::to_string(sequence) + " of run " +
             std::to_string(run_id) + " lost: " + writer_->Message();
    return false;
  }
  return true;
}

Result MapStore::RunLocked(const Database& db, int64_t run_id, RunInfo* out) const {
  Statement q(db,
              "SELECT id, line, vehicle, status, start_ns, end_ns, utm_zone, created_ns, "
              "submaps, points, poses, submaps_lost FROM runs WHERE id = ?");
  if (!q.ok()) return Fail(Outcome::kError, q.error());
  q.Bind(1, run_id);
  if (!q.Step()) {
    if (!q.error().empty()) return Fail(Outcome::kError, q.error());
    return Fail(Outcome::kNotFound, "no run " + std::to_string(run_id));
  }
  RunInfo r;
  r.id = q.Int(0);
  r.line = q.Text(1);
  r.vehicle = q.Text(2);
  r.status = q.Text(3);
  r.start_ns = q.Int(4);
  r.end_ns = q.IsNull(5) ? 0 : q.Int(5);
  r.utm_zone = q.Text(6);
  r.created_ns = q.Int(7);
  r.submaps = q.Int(8);
  r.points = q.Int(9);
  r.poses = q.Int(10);
  r.submaps_lost = q.Int(11);
  if (out) *out = r;
  return {};
}

Result MapStore::CreateRun(const NewRun& run, RunInfo* out) {
  if (run.line.empty() || !Printable(run.line, 200))
    return Fail(Outcome::kInvalid, "line must be 1-200 printable characters");
  if (run.vehicle.empty() || !Printable(run.vehicle, 200))
    return Fail(Outcome::kInvalid, "vehicle must be 1-200 printable characters");
  if (run.start_ns < 0) return Fail(Outcome::kInvalid, "start_ns must not be negative");
  std::lock_guard<std::mutex> lock(mu_);
  Transaction t(*writer_);
  if (!t.ok()) return Fail(Outcome::kError, writer_->Message());
  const int64_t now = NowNs();
  Statement line(*writer_, "INSERT OR IGNORE INTO lines (name, created_ns) VALUES (?, ?)");
  if (!line.Bind(1, run.line).Bind(2, now).Run()) return Fail(Outcome::kError, line.error());
  Statement insert(*writer_,
                   "INSERT INTO runs (line, vehicle, status, start_ns, created_ns) VALUES (?, ?, "
                   "'live', ?, ?)");
  if (!insert.Bind(1, run.line).Bind(2, run.vehicle).Bind(3, run.start_ns).Bind(4, now).Run())
    return Fail(Outcome::kError, insert.error());
  const int64_t id = writer_->LastInsertId();
  std::string error;
  if (!t.Commit(&error)) return Fail(Outcome::kError, error);
  return RunLocked(*writer_, id, out);
}

Result MapStore::GetRun(int64_t run_id, RunInfo* out) const {
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  return RunLocked(*db, run_id, out);
}

std::vector<RunInfo> MapStore::ListRuns() const {
  std::vector<RunInfo> runs;
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return runs;
  Statement q(*db, "SELECT id FROM runs ORDER BY id");
  while (q.Step()) {
    RunInfo r;
    if (RunLocked(*db, q.Int(0), &r)) runs.push_back(r);
  }
  return runs;
}

Result MapStore::FinishRun(int64_t run_id, int64_t end_ns, RunInfo* out) {
  Result r = Flush(nullptr);  // the run's tiles are all written when it is finished
  if (!r) return r;
  std::lock_guard<std::mutex> lock(mu_);
  RunInfo run;
  r = RunLocked(*writer_, run_id, &run);
  if (!r) return r;
  if (run.status == "finished") {
    if (out) *out = run;
    return {Outcome::kDuplicate, "run " + std::to_string(run_id) + " was finished before"};
  }
  if (end_ns < run.start_ns) return Fail(Outcome::kInvalid, "end_ns is before the run's start_ns");
  Statement u(*writer_, "UPDATE runs SET status = 'finished', end_ns = ? WHERE id = ?");
  if (!u.Bind(1, end_ns).Bind(2, run_id).Run()) return Fail(Outcome::kError, u.error());
  r = DefineCentrelineLocked(run);
  if (!r) return r;
  return RunLocked(*writer_, run_id, out);
}

Result MapStore::DefineCentrelineLocked(const RunInfo& run) {
  LineInfo line;
  Result r = LineLocked(*writer_, run.line, &line);
  if (!r) return r;
  if (line.reference_run != 0) return {};
  std::vector<api::StreamPose> poses;
  Statement q(*writer_,
              "SELECT georeferenced, utm_zone, x, y, z, qx, qy, qz, qw FROM poses WHERE run_id = "
              "? ORDER BY sequence");
  q.Bind(1, run.id);
  while (q.Step()) {
    api::StreamPose p;
    p.georeferenced = q.Int(0) != 0;
    p.utm_zone = q.Text(1);
    p.p = Eigen::Vector3d(q.Double(2), q.Double(3), q.Double(4));
    p.q = Eigen::Quaterniond(q.Double(8), q.Double(5), q.Double(6), q.Double(7));
    poses.push_back(p);
  }
  const std::vector<CentrelinePoint> centreline = BuildCentreline(poses, 1.0);
  if (centreline.size() < 2) return {};  // nothing usable: a later run may define it
  std::string zone;
  for (const auto& p : poses)
    if (p.georeferenced) {
      zone = p.utm_zone;
      break;
    }
  Transaction t(*writer_);
  if (!t.ok()) return Fail(Outcome::kError, writer_->Message());
  Statement put(*writer_,
                "INSERT INTO centreline (line, seq, chainage_m, x, y, z, cant_m) VALUES (?, ?, "
                "?, ?, ?, ?, ?)");
  for (size_t i = 0; i < centreline.size(); ++i) {
    const CentrelinePoint& c = centreline[i];
    put.Reset();
    put.Bind(1, run.line)
        .Bind(2, static_cast<int64_t>(i))
        .Bind(3, c.chainage_m)
        .Bind(4, c.p.x())
        .Bind(5, c.p.y())
        .Bind(6, c.p.z())
        .Bind(7, c.cant_m);
    if (!put.Run()) return Fail(Outcome::kError, put.error());
  }
  Statement set(*writer_, "UPDATE lines SET reference_run = ?, utm_zone = ? WHERE name = ?");
  if (!set.Bind(1, run.id).Bind(2, zone).Bind(3, run.line).Run())
    return Fail(Outcome::kError, set.error());
  std::string error;
  if (!t.Commit(&error)) return Fail(Outcome::kError, error);
  return {};
}

Result MapStore::LineLocked(const Database& db, const std::string& name, LineInfo* out) const {
  Statement q(
      db,
      "SELECT l.name, IFNULL(l.reference_run, 0), IFNULL(l.utm_zone, ''), "
      "l.chainage_offset_m, (SELECT IFNULL(MAX(chainage_m), 0) FROM centreline c WHERE "
      "c.line = l.name), (SELECT COUNT(*) FROM runs r WHERE r.line = l.name), "
      "(SELECT COUNT(*) FROM km_posts k WHERE k.line = l.name) FROM lines l WHERE l.name = ?");
  if (!q.ok()) return Fail(Outcome::kError, q.error());
  q.Bind(1, name);
  if (!q.Step()) {
    if (!q.error().empty()) return Fail(Outcome::kError, q.error());
    return Fail(Outcome::kNotFound, "no line '" + name + "'");
  }
  LineInfo l;
  l.name = q.Text(0);
  l.reference_run = q.Int(1);
  l.utm_zone = q.Text(2);
  l.chainage_offset_m = q.Double(3);
  l.length_m = q.Double(4);
  l.runs = q.Int(5);
  l.km_posts = q.Int(6);
  if (out) *out = l;
  return {};
}

Result MapStore::CentrelineLocked(const Database& db,
                                  const std::string& name,
                                  std::vector<CentrelinePoint>* out) const {
  Statement q(db, "SELECT chainage_m, x, y, z, cant_m FROM centreline WHERE line = ? ORDER BY seq");
  q.Bind(1, name);
  out->clear();
  while (q.Step()) {
    CentrelinePoint c;
    c.chainage_m = q.Double(0);
    c.p = Eigen::Vector3d(q.Double(1), q.Double(2), q.Double(3));
    c.cant_m = q.Double(4);
    out->push_back(c);
  }
  if (!q.error().empty()) return Fail(Outcome::kError, q.error());
  return {};
}

Result MapStore::ListLines(std::vector<LineInfo>* lines) const {
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  Statement q(*db, "SELECT name FROM lines ORDER BY name");
  lines->clear();
  while (q.Step()) {
    LineInfo l;
    const Result r = LineLocked(*db, q.Text(0), &l);
    if (!r) return r;
    lines->push_back(l);
  }
  return {};
}

Result MapStore::GetLine(const std::string& name, LineInfo* line) const {
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  return LineLocked(*db, name, line);
}

Result MapStore::Segment(const std::string& name,
                         double from_m,
                         double to_m,
                         TrackSegment* out) const {
  if (!std::isfinite(from_m) || !std::isfinite(to_m) || from_m >= to_m)
    return Fail(Outcome::kInvalid, "the chainage range must be finite with from < to");
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  Result r = LineLocked(*db, name, &out->line);
  if (!r) return r;
  if (out->line.reference_run == 0)
    return Fail(Outcome::kNotFound,
                "line '" + name + "' has no centreline yet (its first run is not finished)");
  std::vector<CentrelinePoint> centreline;
  r = CentrelineLocked(*db, name, &centreline);
  if (!r) return r;
  const double offset = out->line.chainage_offset_m;
  for (CentrelinePoint& c : centreline) c.chainage_m += offset;
  if (centreline.empty() || to_m < centreline.front().chainage_m ||
      from_m > centreline.back().chainage_m) {
    char text[160];
    std::snprintf(text,
                  sizeof(text),
                  "the line runs from km %.3f to km %.3f",
                  centreline.empty() ? 0.0 : centreline.front().chainage_m / 1000.0,
                  centreline.empty() ? 0.0 : centreline.back().chainage_m / 1000.0);
    return Fail(Outcome::kNotFound, std::string("no centreline in that range: ") + text);
  }
  out->samples.clear();
  Eigen::AlignedBox2d box;
  const std::vector<TrackSample> samples = TrackGeometry(centreline, 10.0);
  for (const TrackSample& s : samples) {
    if (s.point.chainage_m < from_m || s.point.chainage_m > to_m) continue;
    out->samples.push_back(s);
    box.extend(s.point.p.head<2>());
  }
  if (out->samples.empty()) {  // a range between two samples (a metre apart): the nearer one
    const double mid = 0.5 * (from_m + to_m);
    out->samples.push_back(*std::min_element(
        samples.begin(), samples.end(), [mid](const TrackSample& a, const TrackSample& b) {
          return std::abs(a.point.chainage_m - mid) < std::abs(b.point.chainage_m - mid);
        }));
    box.extend(out->samples.front().point.p.head<2>());
  }
  // The reference run's tiles within 10 m of the segment's centreline.
  const double margin = 10.0;
  const double side = options_.grid.TileM(0);
  std::vector<TileInfo> tiles;
  box.min().array() -= margin;
  box.max().array() += margin;
  r = TilesInBox(out->line.reference_run, 0, box, &tiles);
  if (!r) return r;
  out->tiles.clear();
  for (const TileInfo& t : tiles) {
    const Eigen::AlignedBox2d square(Eigen::Vector2d(t.key.ix * side, t.key.iy * side),
                                     Eigen::Vector2d((t.key.ix + 1) * side, (t.key.iy + 1) * side));
    const bool near =
        std::any_of(out->samples.begin(), out->samples.end(), [&](const TrackSample& s) {
          return square.exteriorDistance(s.point.p.head<2>()) <= margin;
        });
    if (near) out->tiles.push_back(t);
  }
  return {};
}

/// Which points of a run an export takes: those in its box and, along a line, within its half
/// width of the centreline.
struct ExportCursor::Filter {
  Eigen::AlignedBox2d box;
  std::vector<Eigen::Vector2d> centreline;
  double half_width_m = 0.0, cell_m = 1.0;
  std::unordered_map<uint64_t, std::vector<Eigen::Vector2d>> near;  ///< centreline by cell

  static uint64_t Key(int64_t x, int64_t y) {
    return (static_cast<uint64_t>(x) << 32) ^ static_cast<uint32_t>(y);
  }
  void Index() {
    cell_m = std::max(1.0, half_width_m);
    for (const Eigen::Vector2d& c : centreline)
      near[Key(static_cast<int64_t>(std::floor(c.x() / cell_m)),
               static_cast<int64_t>(std::floor(c.y() / cell_m)))]
          .push_back(c);
  }
  bool Takes(const Eigen::Vector2d& p) const {
    if (!box.contains(p)) return false;
    if (centreline.empty()) return true;
    const int64_t cx = static_cast<int64_t>(std::floor(p.x() / cell_m));
    const int64_t cy = static_cast<int64_t>(std::floor(p.y() / cell_m));
    for (int64_t dx = -1; dx <= 1; ++dx)
      for (int64_t dy = -1; dy <= 1; ++dy) {
        auto it = near.find(Key(cx + dx, cy + dy));
        if (it == near.end()) continue;
        for (const Eigen::Vector2d& c : it->second)
          if ((c - p).squaredNorm() <= half_width_m * half_width_m) return true;
      }
    return false;
  }
};

ExportCursor::ExportCursor(const MapStore* store, int64_t run_id, std::unique_ptr<Filter> filter)
    : store_(store), run_id_(run_id), filter_(std::move(filter)) {}

ExportCursor::~ExportCursor() = default;

Result ExportCursor::Read(const TileKey& key, std::vector<ExportPoint>* points) {
  points->clear();
  std::string bytes, error;
  Result r = store_->Tile(run_id_, key, nullptr, &bytes);
  if (!r) return r;
  TilePoints decoded;
  if (!DecodeTile(bytes, &decoded, &error))
    return Fail(Outcome::kError, "tile " + key.ToString() + ": " + error);
  if (zone_.empty()) zone_ = decoded.utm_zone;
  for (size_t i = 0; i < decoded.points.size(); ++i) {
    const Eigen::Vector3d p = decoded.origin + decoded.points[i].cast<double>();
    if (filter_->Takes(p.head<2>())) points->push_back({p, decoded.intensities[i]});
  }
  return {};
}

Result ExportCursor::Next(std::vector<ExportPoint>* points) {
  if (done()) return Fail(Outcome::kInvalid, "the export has no more tiles");
  const size_t k = next_++;
  Result r = Read(tiles_[k], points);
  if (!r) return r;
  if (points->size() < counts_[k])
    return Fail(Outcome::kError, "tile " + tiles_[k].ToString() + " lost points while exported");
  points->resize(counts_[k]);  // a live run's tile may have grown since it was counted
  return {};
}

Result MapStore::PrepareExport(const ExportRequest& request,
                               std::unique_ptr<ExportCursor>* out) const {
  auto filter = std::make_unique<ExportCursor::Filter>();
  if (!request.line.empty()) {
    if (!(request.half_width_m > 0.0 && request.half_width_m <= 200.0))
      return Fail(Outcome::kInvalid, "the half width must be in (0, 200] m");
    TrackSegment segment;
    Result r = Segment(request.line, request.from_m, request.to_m, &segment);
    if (!r) return r;
    for (const TrackSample& s : segment.samples) {
      filter->centreline.push_back(s.point.p.head<2>());
      filter->box.extend(s.point.p.head<2>());
    }
    filter->box.min().array() -= request.half_width_m;
    filter->box.max().array() += request.half_width_m;
    filter->half_width_m = request.half_width_m;
    filter->Index();
  } else if (request.has_box) {
    filter->box = request.box;
  } else {
    return Fail(Outcome::kInvalid, "an export needs a box or a line's km range");
  }
  std::vector<TileInfo> tiles;
  Result r = TilesInBox(request.run_id, request.level, filter->box, &tiles);
  if (!r) return r;
  RunInfo run;
  r = GetRun(request.run_id, &run);
  if (!r) return r;
  std::unique_ptr<ExportCursor> cursor(new ExportCursor(this, request.run_id, std::move(filter)));
  cursor->zone_ = run.utm_zone;  // also for an export with no point, whose header names it
  // The count (one pass, a tile at a time): the file's header needs it before any point.
  std::vector<ExportPoint> points;
  for (const TileInfo& t : tiles) {
    r = cursor->Read(t.key, &points);
    if (!r) return r;
    if (points.empty()) continue;
    cursor->tiles_.push_back(t.key);
    cursor->counts_.push_back(points.size());
    cursor->points_ += points.size();
    for (const ExportPoint& p : points) cursor->bounds_.extend(p.p);
    if (cursor->points_ > request.max_points)
      return Fail(Outcome::kInvalid,
                  "the export would hold more than " + std::to_string(request.max_points) +
                      " points: narrow the box or take a coarser level");
  }
  *out = std::move(cursor);
  return {};
}

Result MapStore::Export(const ExportRequest& request,
                        std::vector<ExportPoint>* points,
                        std::string* utm_zone) const {
  points->clear();
  std::unique_ptr<ExportCursor> cursor;
  Result r = PrepareExport(request, &cursor);
  if (!r) return r;
  std::vector<ExportPoint> tile;
  while (!cursor->done()) {
    r = cursor->Next(&tile);
    if (!r) return r;
    points->insert(points->end(), tile.begin(), tile.end());
  }
  *utm_zone = cursor->utm_zone();
  return {};
}

namespace {

bool ValidPoi(const Poi& p, std::string* error) {
  if (p.kind.empty() || !Printable(p.kind, 64))
    return *error = "kind must be 1-64 printable characters", false;
  if (!Printable(p.name, 200))
    return *error = "name must be at most 200 printable characters", false;
  if (!Printable(p.line, 200))
    return *error = "line must be at most 200 printable characters", false;
  int zone = 0;
  bool north = true;
  if (!api::ParseUtmZoneName(p.utm_zone, &zone, &north))
    return *error = "utm_zone must be a UTM zone such as 50N", false;
  if (!p.p.allFinite() || p.p.x() < 0.0 || p.p.x() > 1.0e6 || p.p.y() < 0.0 || p.p.y() > 1.0e7 ||
      std::abs(p.p.z()) > 1.0e4)
    return *error = "the position is not a UTM position", false;
  if (p.properties_json.size() > 65536) return *error = "properties are limited to 64 KiB", false;
  return true;
}

void ReadPoi(const Statement& q, Poi* p) {
  p->id = q.Int(0);
  p->line = q.Text(1);
  p->kind = q.Text(2);
  p->name = q.Text(3);
  p->utm_zone = q.Text(4);
  p->p = Eigen::Vector3d(q.Double(5), q.Double(6), q.Double(7));
  p->properties_json = q.Text(8);
  p->created_ns = q.Int(9);
  p->updated_ns = q.Int(10);
}

/// Binds a point of interest's fields as parameters 1-9 (line, kind, name, zone, x, y, z,
/// properties, updated_ns).
void BindPoi(Statement& q, const Poi& p) {
  q.Bind(1, p.line)
      .Bind(2, p.kind)
      .Bind(3, p.name)
      .Bind(4, p.utm_zone)
      .Bind(5, p.p.x())
      .Bind(6, p.p.y())
      .Bind(7, p.p.z())
      .Bind(8, p.properties_json)
      .Bind(9, p.updated_ns);
}

constexpr char kPoiColumns[] =
    "SELECT id, IFNULL(line, ''), kind, name, utm_zone, x, y, z, properties, created_ns, "
    "updated_ns FROM pois";

}  // namespace

Result MapStore::CreatePoi(Poi* poi) {
  std::string error;
  if (!ValidPoi(*poi, &error)) return Fail(Outcome::kInvalid, "point of interest: " + error);
  std::lock_guard<std::mutex> lock(mu_);
  if (!poi->line.empty()) {
    Result r = LineLocked(*writer_, poi->line, nullptr);
    if (!r) return r;
  }
  poi->created_ns = poi->updated_ns = NowNs();
  Statement q(*writer_,
              "INSERT INTO pois (line, kind, name, utm_zone, x, y, z, properties, updated_ns, "
              "created_ns) VALUES (NULLIF(?, ''), ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  BindPoi(q, *poi);
  q.Bind(10, poi->created_ns);
  if (!q.Run()) return Fail(Outcome::kError, q.error());
  poi->id = writer_->LastInsertId();
  return {};
}

Result MapStore::GetPoi(int64_t id, Poi* poi) const {
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  Statement q(*db, std::string(kPoiColumns) + " WHERE id = ?");
  q.Bind(1, id);
  if (!q.Step()) {
    if (!q.error().empty()) return Fail(Outcome::kError, q.error());
    return Fail(Outcome::kNotFound, "no point of interest " + std::to_string(id));
  }
  ReadPoi(q, poi);
  return {};
}

Result MapStore::ListPois(const std::string& line,
                          const Eigen::AlignedBox2d* box,
                          std::vector<Poi>* pois) const {
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  Statement q(*db,
              std::string(kPoiColumns) +
                  " WHERE (? = '' OR line = ?) AND x BETWEEN ? AND ? AND y BETWEEN ? AND ? "
                  "ORDER BY id");
  q.Bind(1, line)
      .Bind(2, line)
      .Bind(3, box ? box->min().x() : -1e300)
      .Bind(4, box ? box->max().x() : 1e300)
      .Bind(5, box ? box->min().y() : -1e300)
      .Bind(6, box ? box->max().y() : 1e300);
  pois->clear();
  while (q.Step()) {
    Poi p;
    ReadPoi(q, &p);
    pois->push_back(p);
  }
  if (!q.error().empty()) return Fail(Outcome::kError, q.error());
  return {};
}

Result MapStore::UpdatePoi(Poi* poi) {
  std::string error;
  if (!ValidPoi(*poi, &error)) return Fail(Outcome::kInvalid, "point of interest: " + error);
  std::lock_guard<std::mutex> lock(mu_);
  if (!poi->line.empty()) {
    Result r = LineLocked(*writer_, poi->line, nullptr);
    if (!r) return r;
  }
  poi->updated_ns = NowNs();
  Statement q(*writer_,
              "UPDATE pois SET line = NULLIF(?, ''), kind = ?, name = ?, utm_zone = ?, x = ?, y = "
              "?, z = ?, properties = ?, updated_ns = ? WHERE id = ?");
  BindPoi(q, *poi);
  q.Bind(10, poi->id);
  if (!q.Run()) return Fail(Outcome::kError, q.error());
  if (writer_->Changes() == 0)
    return Fail(Outcome::kNotFound, "no point of interest " + std::to_string(poi->id));
  Statement created(*writer_, "SELECT created_ns FROM pois WHERE id = ?");
  created.Bind(1, poi->id);
  if (created.Step()) poi->created_ns = created.Int(0);
  return {};
}

Result MapStore::DeletePoi(int64_t id) {
  std::lock_guard<std::mutex> lock(mu_);
  Statement q(*writer_, "DELETE FROM pois WHERE id = ?");
  q.Bind(1, id);
  if (!q.Run()) return Fail(Outcome::kError, q.error());
  if (writer_->Changes() == 0)
    return Fail(Outcome::kNotFound, "no point of interest " + std::to_string(id));
  return {};
}

Result MapStore::PinKmPost(const std::string& name,
                           const std::string& label,
                           double chainage_m,
                           const Eigen::Vector2d& p_utm,
                           LineInfo* out) {
  if (!std::isfinite(chainage_m) || !p_utm.allFinite())
    return Fail(Outcome::kInvalid, "a km post needs a finite chainage and position");
  if (p_utm.x() < 0.0 || p_utm.x() > 1.0e6 || p_utm.y() < 0.0 || p_utm.y() > 1.0e7)
    return Fail(Outcome::kInvalid, "a km post's easting and northing must be a UTM position");
  if (!Printable(label, 200))
    return Fail(Outcome::kInvalid, "label must be at most 200 printable characters");
  std::lock_guard<std::mutex> lock(mu_);
  LineInfo line;
  Result r = LineLocked(*writer_, name, &line);
  if (!r) return r;
  std::vector<CentrelinePoint> centreline;
  r = CentrelineLocked(*writer_, name, &centreline);
  if (!r) return r;
  if (centreline.empty())
    return Fail(Outcome::kConflict, "line '" + name + "' has no centreline to pin a post on yet");
  double off_m = 0.0;
  const double along = ProjectChainage(centreline, p_utm, &off_m);
  if (off_m > 50.0) {
    return Fail(Outcome::kInvalid,
                "the post lies " + Metres(off_m) + " m from the line's centreline (at most 50 m)");
  }
  Transaction t(*writer_);
  if (!t.ok()) return Fail(Outcome::kError, writer_->Message());
  Statement post(*writer_,
                 "INSERT INTO km_posts (line, chainage_m, x, y, z, label, created_ns) VALUES (?, "
                 "?, ?, ?, 0, ?, ?)");
  post.Bind(1, name)
      .Bind(2, chainage_m)
      .Bind(3, p_utm.x())
      .Bind(4, p_utm.y())
      .Bind(5, label)
      .Bind(6, NowNs());
  Statement set(*writer_, "UPDATE lines SET chainage_offset_m = ? WHERE name = ?");
  set.Bind(1, chainage_m - along).Bind(2, name);
  if (!post.Run()) return Fail(Outcome::kError, post.error());
  if (!set.Run()) return Fail(Outcome::kError, set.error());
  std::string error;
  if (!t.Commit(&error)) return Fail(Outcome::kError, error);
  return LineLocked(*writer_, name, out);
}

Result MapStore::IngestSubmap(int64_t run_id, const std::string& payload, IngestReceipt* receipt) {
  api::Submap s;
  const Result decoded = DecodeIngested(payload, &s);
  if (!decoded) return decoded;
  const std::string hash = Hex64(Fnv1a(payload));
  Eigen::AlignedBox3d box;
  for (const Eigen::Vector3f& p : s.points) box.extend(s.origin + p.cast<double>());

  std::unique_lock<std::mutex> lock(mu_);
  RunInfo run;
  Result r = RunLocked(*writer_, run_id, &run);
  if (!r) {
    ++stats_.submaps_rejected;
    return r;
  }
  const std::optional<Result> resent = ResentSubmapLocked(run_id, s, payload, hash, receipt);
  if (resent) return *resent;
  if (run.status != "live") {
    ++stats_.submaps_rejected;
    return Fail(Outcome::kConflict, "run " + std::to_string(run_id) + " is finished");
  }
  if (!run.utm_zone.empty() && run.utm_zone != s.utm_zone) {
    ++stats_.submaps_rejected;
    return Fail(Outcome::kInvalid,
                "submap " + std::to_string(s.sequence) + " is in UTM zone " + s.utm_zone +
                    ", run " + std::to_string(run_id) + " in " + run.utm_zone);
  }
  r = StoreSubmapLocked(run_id, s, payload, hash, box);
  if (!r) return r;
  ++stats_.submaps_stored;
  IngestReceipt local;
  Merge(run_id, s, &local);
  unflushed_.emplace_back(run_id, s.sequence);
  if (receipt) *receipt = local;
  dirty_points_ += local.points_new;
  if (dirty_points_ >= options_.flush_dirty_points) wake_.notify_all();
  if (OverBudgetLocked()) {
    // Over the memory budget: write what changed, then let the oldest tiles go.
    lock.unlock();
    const Result flushed = Flush(nullptr);
    lock.lock();
    if (flushed) EvictLocked();
  }
  return {};
}

Result MapStore::DecodeIngested(const std::string& payload, api::Submap* s) {
  std::string error;
  if (!api::DecodeSubmapPcd(payload, s, &error)) {
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.submaps_rejected;
    return Fail(Outcome::kInvalid, error);
  }
  if (!ValidSubmap(*s, options_, &error)) {
    std::lock_guard<std::mutex> lock(mu_);
    ++stats_.submaps_rejected;
    return Fail(Outcome::kInvalid, "submap " + std::to_string(s->sequence) + ": " + error);
  }
  return {};
}

std::optional<Result> MapStore::ResentSubmapLocked(int64_t run_id,
                                                   const api::Submap& s,
                                                   const std::string& payload,
                                                   const std::string& hash,
                                                   IngestReceipt* receipt) {
  Statement existing(*writer_,
                     "SELECT payload_hash, tiled FROM submaps WHERE run_id = ? AND sequence = ?");
  existing.Bind(1, run_id).Bind(2, static_cast<int64_t>(s.sequence));
  if (!existing.Step()) return std::nullopt;
  if (existing.Text(0) == hash && existing.Int(1) == -1) {
    // Its payload was lost before its tiles were written (a power cut): the same bytes sent
    // again restore it.
    return RestoreSubmapLocked(run_id, s, payload, receipt);
  }
  if (existing.Text(0) == hash) {
    ++stats_.submaps_duplicate;
    if (receipt) *receipt = IngestReceipt{s.points.size(), 0, 0, s.last_stamp_ns};
    return Result{Outcome::kDuplicate,
                  "submap " + std::to_string(s.sequence) + " of run " + std::to_string(run_id) +
                      " was stored before"};
  }
  ++stats_.submaps_rejected;
  return Fail(Outcome::kConflict,
              "run " + std::to_string(run_id) + " already has a different submap under sequence " +
                  std::to_string(s.sequence));
}

Result MapStore::RestoreSubmapLocked(int64_t run_id,
                                     const api::Submap& s,
                                     const std::string& payload,
                                     IngestReceipt* receipt) {
  std::string error;
  if (!api::WriteFileAtomically(IncomingPath(run_id, s.sequence), payload, &error))
    return Fail(Outcome::kError, "cannot keep the submap's payload: " + error);
  Transaction t(*writer_);
  Statement again(*writer_, "UPDATE submaps SET tiled = 0 WHERE run_id = ? AND sequence = ?");
  Statement count(*writer_,
                  "UPDATE runs SET submaps = submaps + 1, submaps_lost = submaps_lost - 1, "
                  "points = points + ? WHERE id = ?");
  if (!t.ok() || !again.Bind(1, run_id).Bind(2, static_cast<int64_t>(s.sequence)).Run() ||
      !count.Bind(1, static_cast<int64_t>(s.points.size())).Bind(2, run_id).Run() ||
      !t.Commit(&error))
    return Fail(Outcome::kError, "cannot restore the submap: " + writer_->Message());
  IngestReceipt restored;
  Merge(run_id, s, &restored);
  unflushed_.emplace_back(run_id, s.sequence);
  dirty_points_ += restored.points_new;
  if (receipt) *receipt = restored;
  return {};
}

Result MapStore::StoreSubmapLocked(int64_t run_id,
                                   const api::Submap& s,
                                   const std::string& payload,
                                   const std::string& hash,
                                   const Eigen::AlignedBox3d& box) {
  // The payload waits in the incoming folder until its points are in written tiles; it is
  // there before the submap is committed, so an acknowledged submap always has it.
  const std::string incoming = IncomingPath(run_id, s.sequence);
  std::string error;
  if (!api::WriteFileAtomically(incoming, payload, &error))
    return Fail(Outcome::kError, "cannot keep the submap's payload: " + error);
  auto forget = [&](const std::string& message) {
    std::error_code ec;
    std::filesystem::remove(incoming, ec);
    return Fail(Outcome::kError, message);
  };
  Transaction t(*writer_);
  if (!t.ok()) return forget(writer_->Message());
  Statement insert(*writer_,
                   "INSERT INTO submaps (run_id, sequence, idx, first_stamp_ns, last_stamp_ns, "
                   "utm_zone, origin_x, origin_y, origin_z, min_x, min_y, max_x, max_y, "
                   "points, keyframes, payload_hash, received_ns) VALUES "
                   "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  insert.Bind(1, run_id)
      .Bind(2, static_cast<int64_t>(s.sequence))
      .Bind(3, s.index)
      .Bind(4, s.first_stamp_ns)
      .Bind(5, s.last_stamp_ns)
      .Bind(6, s.utm_zone)
      .Bind(7, s.origin.x())
      .Bind(8, s.origin.y())
      .Bind(9, s.origin.z())
      .Bind(10, box.min().x())
      .Bind(11, box.min().y())
      .Bind(12, box.max().x())
      .Bind(13, box.max().y())
      .Bind(14, static_cast<int64_t>(s.points.size()))
      .Bind(15, static_cast<int64_t>(s.keyframes.size()))
      .Bind(16, hash)
      .Bind(17, NowNs());
  Statement count(*writer_,
                  "UPDATE runs SET submaps = submaps + 1, points = points + ?, utm_zone = ? "
                  "WHERE id = ?");
  count.Bind(1, static_cast<int64_t>(s.points.size())).Bind(2, s.utm_zone).Bind(3, run_id);
  if (!insert.Run()) return forget(insert.error());
  if (!count.Run()) return forget(count.error());
  if (!t.Commit(&error)) return forget(error);
  return {};
}

MapStore::HotTile* MapStore::Hot(int64_t run_id,
                                 const std::string& zone,
                                 const TileKey& key,
                                 double z_m) {
  const HotKey hk{run_id, key.level, key.ix, key.iy};
  auto it = hot_.find(hk);
  if (it != hot_.end()) return it->second.get();
  auto tile = std::make_unique<HotTile>();
  tile->key = key;
  const TileGrid& grid = options_.grid;
  // A tile written before continues: decode it (its points sit on its grid already).
  Statement q(*writer_,
              "SELECT version, bytes FROM tiles WHERE run_id = ? AND level = ? AND ix = ? AND "
              "iy = ?");
  q.Bind(1, run_id).Bind(2, key.level).Bind(3, key.ix).Bind(4, key.iy);
  std::string error;
  const bool stored = q.Step();
  if (stored && DecodeTile(q.Blob(1), &tile->points, &error, &tile->quantization)) {
    tile->version = q.Int(0);
    tile->voxels.Reserve(tile->points.points.size());
    for (const Eigen::Vector3f& p : tile->points.points)
      tile->voxels.Insert(TileVoxel(p, static_cast<float>(1.0 / grid.VoxelM(key.level))));
  } else {
    // A stored tile that cannot be read (an I/O error, corrupt bytes) is not replaced by this
    // one: see Flush.
    tile->unreadable = stored || !q.error().empty();
    tile->points = TilePoints();
    // The reference height on the coarsest voxel's lattice, like the corners, so that the
    // levels' voxels nest.
    const double lattice_m = grid.VoxelM(grid.levels - 1);
    tile->points.origin = grid.Origin(key, std::floor(z_m / lattice_m) * lattice_m);
    tile->points.utm_zone = zone;
    tile->quantization = grid.Quantization(key.level);
  }
  hot_points_ += tile->points.points.size();
  HotTile* raw = tile.get();
  hot_.emplace(hk, std::move(tile));
  return raw;
}

namespace {

/// A level's points grouped by tile; kept from level to level, so its vectors are reused.
struct TileGroups {
  std::vector<TileKey> keys;                              // the tiles this level's points fall in
  std::vector<std::vector<uint32_t>> bucket;              // ... and the points of each
  std::unordered_map<TileKey, size_t, TileKeyHash> slot;  // a key's place in `keys`
};

/// Groups the submap's `candidates` by their tile at `level`, tiles in the order of their
/// first point.
void GroupByTile(const api::Submap& s,
                 const std::vector<uint32_t>& candidates,
                 int level,
                 double tile_m,
                 TileGroups* groups) {
  std::vector<TileKey>& keys = groups->keys;
  std::vector<std::vector<uint32_t>>& bucket = groups->bucket;
  keys.clear();
  groups->slot.clear();
  for (auto& b : bucket) b.clear();
  const double inverse_side = 1.0 / tile_m;
  for (uint32_t i : candidates) {
    const Eigen::Vector3d p = s.origin + s.points[i].cast<double>();
    const TileKey key{level,
                      static_cast<int64_t>(std::floor(p.x() * inverse_side)),
                      static_cast<int64_t>(std::floor(p.y() * inverse_side))};
    // Consecutive points mostly share a tile: check the last one before the table.
    size_t k = keys.size();
    if (!keys.empty() && keys.back() == key) {
      k = keys.size() - 1;
    } else {
      const auto [it, inserted] = groups->slot.emplace(key, keys.size());
      k = it->second;
      if (inserted) {
        keys.push_back(key);
        if (bucket.size() < keys.size()) bucket.emplace_back();
      }
    }
    bucket[k].push_back(i);
  }
}

}  // namespace

void MapStore::Merge(int64_t run_id, const api::Submap& s, IngestReceipt* receipt) {
  const TileGrid& grid = options_.grid;
  receipt->points = s.points.size();
  receipt->last_stamp_ns = s.last_stamp_ns;
  ++touch_;
  // The levels' voxels nest (tile origins lie on the coarsest voxel's lattice), so a point
  // whose voxel was taken at one level finds its coarser voxels taken too: only the points
  // new at a level go on to the next.
  std::vector<uint32_t> candidates(s.points.size()), next;
  for (size_t i = 0; i < candidates.size(); ++i) candidates[i] = static_cast<uint32_t>(i);
  TileGroups groups;
  for (int level = 0; level < grid.levels && !candidates.empty(); ++level) {
    // Group the points by tile first: then each tile's voxels are filled in one tight loop.
    GroupByTile(s, candidates, level, grid.TileM(level), &groups);
    const float inverse_voxel = static_cast<float>(1.0 / grid.VoxelM(level));
    next.clear();
    for (size_t k = 0; k < groups.keys.size(); ++k)
      MergeTile(run_id, s, groups.keys[k], groups.bucket[k], inverse_voxel, receipt, &next);
    if (level == 0) receipt->points_new = next.size();
    candidates.swap(next);
  }
  stats_.points_ingested += s.points.size();
  stats_.points_off_grid += receipt->points_off_grid;
}

void MapStore::MergeTile(int64_t run_id,
                         const api::Submap& s,
                         const TileKey& key,
                         const std::vector<uint32_t>& points,
                         float inverse_voxel,
                         IngestReceipt* receipt,
                         std::vector<uint32_t>* next) {
  HotTile* tile = Hot(run_id, s.utm_zone, key, s.origin.z() + s.points[points[0]].z());
  tile->touched = touch_;
  // Offsets first, then the shift: both small, so float keeps them to a micrometre.
  const Eigen::Vector3f shift = (s.origin - tile->points.origin).cast<float>();
  const TileQuantization& q = tile->quantization;
  for (uint32_t i : points) {
    const Eigen::Vector3f o = s.points[i] + shift;
    if (!q.Covers(o)) {
      if (key.level == 0) ++receipt->points_off_grid;
      continue;
    }
    if (!tile->voxels.Insert(TileVoxel(o, inverse_voxel))) continue;
    tile->points.points.push_back(o);
    tile->points.intensities.push_back(
        static_cast<uint8_t>(std::clamp(std::lround(s.intensities[i]), 0L, 255L)));
    tile->dirty = true;
    ++hot_points_;
    next->push_back(i);
  }
}

/// One changed tile of a flush: its snapshot, then its encoding.
struct MapStore::FlushTile {
  HotKey key;
  TileKey tile;
  TilePoints points;
  TileQuantization quantization;
  int64_t version = 0;
  size_t points_count = 0;
  std::string bytes, error;
  bool ok = false;
};

/// What a flush writes: the changed tiles, and the submaps whose points they hold.
struct MapStore::FlushSnapshot {
  std::vector<FlushTile> tiles;
  std::vector<std::pair<int64_t, uint64_t>> submaps;
};

Result MapStore::Flush(std::vector<TileUpdate>* updated) {
  // One flush at a time, so tiles are written in the order their snapshots were taken.
  std::lock_guard<std::mutex> serial(flush_mu_);
  FlushSnapshot snapshot = TakeSnapshot();
  if (snapshot.tiles.empty() && snapshot.submaps.empty()) return {};
  EncodeSnapshot(&snapshot);

  std::unique_lock<std::mutex> lock(mu_);
  for (const FlushTile& p : snapshot.tiles) {
    if (!p.ok) return UndoFlushLocked(snapshot, "tile " + p.tile.ToString() + ": " + p.error);
  }
  // A tile that could not be read back when it was reopened is never written over: the
  // submaps of this snapshot keep their payloads (a restart merges them again).
  const bool poisoned =
      std::any_of(hot_.begin(), hot_.end(), [](const auto& h) { return h.second->unreadable; });
  std::vector<TileUpdate> done;
  const Result written = WriteSnapshotLocked(snapshot, poisoned, &done);
  if (!written) return UndoFlushLocked(snapshot, written.message);
  for (const FlushTile& p : snapshot.tiles) --hot_.at(p.key)->in_flight;
  stats_.tiles_written += done.size();
  for (const FlushTile& p : snapshot.tiles) stats_.points_encoded += p.points_count;
  ++stats_.flushes;
  if (poisoned) {
    // Keep the payloads; let the unreadable tiles go, so the next touch tries to read them again.
    unflushed_.insert(unflushed_.end(), snapshot.submaps.begin(), snapshot.submaps.end());
    snapshot.submaps.clear();
    DropUnreadableLocked();
  }
  if (updated) *updated = done;
  const auto listener = listener_;
  lock.unlock();
  for (const auto& [run, sequence] : snapshot.submaps) {
    std::error_code ec;
    std::filesystem::remove(IncomingPath(run, sequence), ec);
  }
  if (listener && !done.empty()) listener(done);
  return {};
}

MapStore::FlushSnapshot MapStore::TakeSnapshot() {
  std::lock_guard<std::mutex> lock(mu_);
  FlushSnapshot snapshot;
  for (auto& [k, tile] : hot_) {
    if (!tile->dirty) continue;
    FlushTile p;
    p.key = k;
    p.tile = tile->key;
    p.points = tile->points;
    p.points_count = tile->points.points.size();
    p.quantization = tile->quantization;
    p.version = ++tile->version;
    tile->dirty = false;
    ++tile->in_flight;
    snapshot.tiles.push_back(std::move(p));
  }
  snapshot.submaps.swap(unflushed_);
  dirty_points_ = 0;
  return snapshot;
}

void MapStore::EncodeSnapshot(FlushSnapshot* snapshot) const {
  // In parallel, with ingest going on: Draco is the slow part.
  std::vector<FlushTile>& tiles = snapshot->tiles;
  const int threads = std::max(1, std::min<int>(options_.encode_threads, tiles.size()));
  std::vector<std::future<void>> workers;
  for (int w = 0; w < threads; ++w) {
    workers.push_back(std::async(std::launch::async, [&, w]() {
      for (size_t i = w; i < tiles.size(); i += threads) {
        FlushTile& p = tiles[i];
        p.ok = EncodeTile(p.points, p.quantization, options_.draco_speed, &p.bytes, &p.error);
        p.points = TilePoints();  // let the copy go early
      }
    }));
  }
  for (auto& w : workers) w.get();
}

Result MapStore::UndoFlushLocked(const FlushSnapshot& snapshot, const std::string& message) {
  // The tiles are changed again and the submaps still unwritten: the next flush retries, and a
  // restart would merge the submaps again.
  for (const FlushTile& p : snapshot.tiles) {
    auto it = hot_.find(p.key);
    if (it == hot_.end()) continue;
    it->second->dirty = true;
    --it->second->in_flight;
  }
  unflushed_.insert(unflushed_.end(), snapshot.submaps.begin(), snapshot.submaps.end());
  return Fail(Outcome::kError, message);
}

Result MapStore::WriteSnapshotLocked(const FlushSnapshot& snapshot,
                                     bool poisoned,
                                     std::vector<TileUpdate>* done) {
  // Every statement lives and dies inside this function, under the lock: the writer
  // connection is not thread-safe.
  Transaction t(*writer_);
  if (!t.ok()) return Fail(Outcome::kError, writer_->Message());
  Statement put(*writer_,
                "INSERT OR REPLACE INTO tiles (run_id, level, ix, iy, utm_zone, origin_x, "
                "origin_y, origin_z, points, max_error_m, version, etag, updated_ns, bytes) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  const int64_t now = NowNs();
  for (const FlushTile& p : snapshot.tiles) {
    const HotTile& tile = *hot_.at(p.key);
    if (tile.unreadable) continue;
    put.Reset();
    put.Bind(1, std::get<0>(p.key))
        .Bind(2, p.tile.level)
        .Bind(3, p.tile.ix)
        .Bind(4, p.tile.iy)
        .Bind(5, tile.points.utm_zone)
        .Bind(6, tile.points.origin.x())
        .Bind(7, tile.points.origin.y())
        .Bind(8, tile.points.origin.z())
        .Bind(9, static_cast<int64_t>(p.points_count))
        .Bind(10, p.quantization.MaxErrorM())
        .Bind(11, p.version)
        .Bind(12, "\"" + std::to_string(p.version) + "-" + Hex64(Fnv1a(p.bytes)) + "\"")
        .Bind(13, now)
        .BindBlob(14, p.bytes);
    if (!put.Run()) return Fail(Outcome::kError, put.error());
    done->push_back({std::get<0>(p.key), p.tile, p.version});
  }
  if (!poisoned) {
    // Every submap of the snapshot is in written tiles now: its payload can go.
    Statement mark(*writer_, "UPDATE submaps SET tiled = 1 WHERE run_id = ? AND sequence = ?");
    for (const auto& [run, sequence] : snapshot.submaps) {
      mark.Reset();
      if (!mark.Bind(1, run).Bind(2, static_cast<int64_t>(sequence)).Run())
        return Fail(Outcome::kError, mark.error());
    }
  }
  std::string error;
  if (!t.Commit(&error)) return Fail(Outcome::kError, error);
  return {};
}

void MapStore::DropUnreadableLocked() {
  for (auto it = hot_.begin(); it != hot_.end();) {
    if (it->second->unreadable && it->second->in_flight == 0) {
      hot_points_ -= it->second->points.points.size();
      it = hot_.erase(it);
    } else {
      ++it;
    }
  }
}

bool MapStore::OverBudgetLocked() const {
  return hot_points_ > options_.hot_points_budget || hot_.size() > options_.hot_tiles_budget;
}

void MapStore::EvictLocked() {
  // Let the least recently touched written tiles go until half the budget is left.
  std::vector<std::pair<uint64_t, HotKey>> order;
  for (const auto& [k, tile] : hot_) {
    if (!tile->dirty && tile->in_flight == 0) order.emplace_back(tile->touched, k);
  }
  std::sort(order.begin(), order.end());
  for (const auto& [touched, k] : order) {
    if (hot_points_ <= options_.hot_points_budget / 2 &&
        hot_.size() <= options_.hot_tiles_budget / 2)
      break;
    hot_points_ -= hot_.at(k)->points.points.size();
    hot_.erase(k);
  }
}

void MapStore::SetTileListener(std::function<void(const std::vector<TileUpdate>&)> listener) {
  std::lock_guard<std::mutex> lock(mu_);
  listener_ = std::move(listener);
}

void MapStore::FlushLoop() {
  std::unique_lock<std::mutex> lock(mu_);
  while (!stopping_) {
    wake_.wait_for(lock, std::chrono::milliseconds(options_.flush_interval_ms), [&] {
      return stopping_ || dirty_points_ >= options_.flush_dirty_points;
    });
    if (stopping_) break;
    const bool work = dirty_points_ > 0 || !unflushed_.empty();
    lock.unlock();
    if (work) Flush(nullptr);
    lock.lock();
  }
}

Result MapStore::TilesInBox(int64_t run_id,
                            int level,
                            const Eigen::AlignedBox2d& box,
                            std::vector<TileInfo>* tiles) const {
  if (level < 0 || level >= options_.grid.levels)
    return Fail(Outcome::kInvalid,
                "level must be in [0, " + std::to_string(options_.grid.levels - 1) + "]");
  if (!box.min().allFinite() || !box.max().allFinite() || box.isEmpty())
    return Fail(Outcome::kInvalid, "the box is empty or not finite");
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  Result r = RunLocked(*db, run_id, nullptr);
  if (!r) return r;
  const double side = options_.grid.TileM(level);
  // Within UTM's range: tile indices of a box far beyond it would overflow.
  const Eigen::AlignedBox2d utm(Eigen::Vector2d(-1.0e6, -1.0e7), Eigen::Vector2d(2.0e6, 2.0e7));
  if (!utm.intersects(box)) {
    tiles->clear();
    return {};
  }
  const Eigen::AlignedBox2d clamped = box.intersection(utm);
  Statement q(*db,
              "SELECT ix, iy, utm_zone, origin_x, origin_y, origin_z, points, length(bytes), "
              "version, updated_ns, max_error_m, etag FROM tiles WHERE run_id = ? AND level = ? "
              "AND ix BETWEEN ? AND ? AND iy BETWEEN ? AND ? ORDER BY ix, iy");
  q.Bind(1, run_id)
      .Bind(2, level)
      .Bind(3, static_cast<int64_t>(std::floor(clamped.min().x() / side)))
      .Bind(4, static_cast<int64_t>(std::floor(clamped.max().x() / side)))
      .Bind(5, static_cast<int64_t>(std::floor(clamped.min().y() / side)))
      .Bind(6, static_cast<int64_t>(std::floor(clamped.max().y() / side)));
  tiles->clear();
  while (q.Step()) {
    TileInfo t;
    t.run_id = run_id;
    t.key = {level, q.Int(0), q.Int(1)};
    t.utm_zone = q.Text(2);
    t.origin = Eigen::Vector3d(q.Double(3), q.Double(4), q.Double(5));
    t.points = q.Int(6);
    t.bytes = q.Int(7);
    t.version = q.Int(8);
    t.updated_ns = q.Int(9);
    t.max_error_m = q.Double(10);
    t.etag = q.Text(11);
    tiles->push_back(t);
  }
  if (!q.error().empty()) return Fail(Outcome::kError, q.error());
  return {};
}

Result MapStore::Tile(int64_t run_id,
                      const TileKey& key,
                      TileInfo* info,
                      std::string* bytes) const {
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  Statement q(*db,
              "SELECT utm_zone, origin_x, origin_y, origin_z, points, version, updated_ns, "
              "max_error_m, etag, bytes FROM tiles WHERE run_id = ? AND level = ? AND ix = ? "
              "AND iy = ?");
  q.Bind(1, run_id).Bind(2, key.level).Bind(3, key.ix).Bind(4, key.iy);
  if (!q.Step()) {
    if (!q.error().empty()) return Fail(Outcome::kError, q.error());
    Result r = RunLocked(*db, run_id, nullptr);
    if (!r) return r;
    return Fail(Outcome::kNotFound,
                "run " + std::to_string(run_id) + " has no tile " + key.ToString());
  }
  if (info) {
    info->run_id = run_id;
    info->key = key;
    info->utm_zone = q.Text(0);
    info->origin = Eigen::Vector3d(q.Double(1), q.Double(2), q.Double(3));
    info->points = q.Int(4);
    info->version = q.Int(5);
    info->updated_ns = q.Int(6);
    info->max_error_m = q.Double(7);
    info->etag = q.Text(8);
  }
  std::string blob = q.Blob(9);
  if (info) info->bytes = static_cast<int64_t>(blob.size());
  if (bytes) *bytes = std::move(blob);
  return {};
}

namespace {

/// The UTM zone of a run's poses: `zone` (the run's, if it has one) or else the first
/// georeferenced pose's; kInvalid naming the first pose in another zone.
Result PosesZone(int64_t run_id, const std::vector<api::StreamPose>& poses, std::string* zone) {
  for (const api::StreamPose& p : poses) {
    if (!p.georeferenced) continue;
    if (zone->empty()) *zone = p.utm_zone;
    if (p.utm_zone != *zone)
      return Fail(Outcome::kInvalid,
                  "pose " + std::to_string(p.sequence) + " is in UTM zone " + p.utm_zone +
                      ", run " + std::to_string(run_id) + " in " + *zone);
  }
  return {};
}

/// Whether the stored pose in `get`'s row (stamp, position, rotation, zone) is `p`.
bool SamePose(const Statement& get, const api::StreamPose& p) {
  return get.Int(0) == p.stamp_ns && get.Double(1) == p.p.x() && get.Double(2) == p.p.y() &&
         get.Double(3) == p.p.z() && get.Double(4) == p.q.x() && get.Double(5) == p.q.y() &&
         get.Double(6) == p.q.z() && get.Double(7) == p.q.w() && get.Text(8) == p.utm_zone;
}

/// Binds a pose of run `run_id` as parameters 1-12 (run, sequence, stamp, georeferenced, zone,
/// x, y, z, qx, qy, qz, qw).
void BindPose(Statement& put, int64_t run_id, const api::StreamPose& p) {
  put.Bind(1, run_id)
      .Bind(2, static_cast<int64_t>(p.sequence))
      .Bind(3, p.stamp_ns)
      .Bind(4, p.georeferenced ? 1 : 0)
      .Bind(5, p.utm_zone)
      .Bind(6, p.p.x())
      .Bind(7, p.p.y())
      .Bind(8, p.p.z())
      .Bind(9, p.q.x())
      .Bind(10, p.q.y())
      .Bind(11, p.q.z())
      .Bind(12, p.q.w());
}

}  // namespace

Result MapStore::IngestPoses(int64_t run_id,
                             const std::vector<api::StreamPose>& poses,
                             int* stored,
                             std::vector<bool>* added_flags) {
  if (stored) *stored = 0;
  if (added_flags) added_flags->assign(poses.size(), false);
  std::vector<bool> fresh(poses.size(), false);
  std::string error;
  for (const api::StreamPose& p : poses) {
    if (!ValidPose(p, &error)) return Fail(Outcome::kInvalid, error);
  }
  std::lock_guard<std::mutex> lock(mu_);
  RunInfo run;
  Result r = RunLocked(*writer_, run_id, &run);
  if (!r) return r;
  // A run lies in one UTM zone: its first georeferenced pose or submap sets it.
  std::string zone = run.utm_zone;
  r = PosesZone(run_id, poses, &zone);
  if (!r) return r;
  Transaction t(*writer_);
  if (!t.ok()) return Fail(Outcome::kError, writer_->Message());
  int added = 0;
  r = InsertPosesLocked(run_id, run, poses, &fresh, &added);
  if (!r) return r;
  Statement count(*writer_, "UPDATE runs SET poses = poses + ?, utm_zone = ? WHERE id = ?");
  if (!zone.empty()) count.Bind(2, zone);
  if (!count.Bind(1, added).Bind(3, run_id).Run()) return Fail(Outcome::kError, count.error());
  if (!t.Commit(&error)) return Fail(Outcome::kError, error);
  stats_.poses_stored += added;
  stats_.poses_duplicate += poses.size() - static_cast<size_t>(added);
  if (stored) *stored = added;
  if (added_flags) *added_flags = fresh;
  if (added == 0 && !poses.empty())
    return {Outcome::kDuplicate, "every pose of the batch was stored before"};
  return {};
}

Result MapStore::InsertPosesLocked(int64_t run_id,
                                   const RunInfo& run,
                                   const std::vector<api::StreamPose>& poses,
                                   std::vector<bool>* fresh,
                                   int* added) {
  Statement get(*writer_,
                "SELECT stamp_ns, x, y, z, qx, qy, qz, qw, utm_zone FROM poses WHERE run_id = ? "
                "AND sequence = ?");
  Statement put(*writer_,
                "INSERT INTO poses (run_id, sequence, stamp_ns, georeferenced, utm_zone, x, y, z, "
                "qx, qy, qz, qw) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  for (size_t k = 0; k < poses.size(); ++k) {
    const api::StreamPose& p = poses[k];
    get.Reset();
    get.Bind(1, run_id).Bind(2, static_cast<int64_t>(p.sequence));
    if (get.Step()) {
      if (!SamePose(get, p))
        return Fail(Outcome::kConflict,
                    "run " + std::to_string(run_id) +
                        " already has a different pose under sequence " +
                        std::to_string(p.sequence));
      continue;
    }
    if (run.status != "live")
      return Fail(Outcome::kConflict, "run " + std::to_string(run_id) + " is finished");
    put.Reset();
    BindPose(put, run_id, p);
    if (!put.Run()) return Fail(Outcome::kError, put.error());
    ++*added;
    (*fresh)[k] = true;
  }
  return {};
}

Result MapStore::Trajectory(int64_t run_id, std::vector<api::StreamPose>* poses) const {
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  Result r = RunLocked(*db, run_id, nullptr);
  if (!r) return r;
  Statement q(*db,
              "SELECT sequence, stamp_ns, georeferenced, utm_zone, x, y, z, qx, qy, qz, qw FROM "
              "poses WHERE run_id = ? ORDER BY sequence");
  q.Bind(1, run_id);
  poses->clear();
  while (q.Step()) {
    api::StreamPose p;
    p.sequence = static_cast<uint64_t>(q.Int(0));
    p.stamp_ns = q.Int(1);
    p.georeferenced = q.Int(2) != 0;
    p.utm_zone = q.Text(3);
    p.p = Eigen::Vector3d(q.Double(4), q.Double(5), q.Double(6));
    p.q = Eigen::Quaterniond(q.Double(10), q.Double(7), q.Double(8), q.Double(9));
    poses->push_back(p);
  }
  if (!q.error().empty()) return Fail(Outcome::kError, q.error());
  return {};
}

Result MapStore::ChainageOfPoses(int64_t run_id,
                                 const std::vector<api::StreamPose>& poses,
                                 std::vector<double>* chainage_m,
                                 double max_off_m) const {
  chainage_m->assign(poses.size(), std::nan(""));
  std::string error;
  auto db = readers_->Take(&error);
  if (!db) return Fail(Outcome::kError, error);
  RunInfo run;
  Result r = RunLocked(*db, run_id, &run);
  if (!r) return r;
  LineInfo line;
  r = LineLocked(*db, run.line, &line);
  if (!r || line.reference_run == 0) return r;
  std::vector<CentrelinePoint> centreline;
  r = CentrelineLocked(*db, run.line, &centreline);
  if (!r) return r;
  const ChainageIndex index(std::move(centreline));
  for (size_t i = 0; i < poses.size(); ++i) {
    double along = 0.0;
    if (poses[i].georeferenced && poses[i].utm_zone == line.utm_zone &&
        index.Project(poses[i].p.head<2>(), max_off_m, &along, nullptr))
      (*chainage_m)[i] = along + line.chainage_offset_m;
  }
  return {};
}

StoreStats MapStore::stats() const {
  uint64_t lost = 0;
  std::string error;
  if (auto db = readers_->Take(&error)) {
    Statement q(*db, "SELECT COALESCE(SUM(submaps_lost), 0) FROM runs");
    if (q.Step()) lost = static_cast<uint64_t>(q.Int(0));
  }
  std::lock_guard<std::mutex> lock(mu_);
  StoreStats s = stats_;
  s.submaps_lost_stored = lost;
  s.hot_tiles = hot_.size();
  s.hot_points = hot_points_;
  return s;
}

}  // namespace raillomer::mapstore
