#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "api/stream.h"
#include "mapstore/chainage.h"
#include "mapstore/export.h"
#include "mapstore/store_lock.h"
#include "mapstore/tile_grid.h"

namespace raillomer::mapstore {

class Database;

/// What a store call came to. Everything but kOk and kDuplicate changed nothing.
enum class Outcome {
  kOk,
  kDuplicate,  ///< the same data was stored before: nothing changed
  kInvalid,    ///< the request's data is wrong (the message says what)
  kNotFound,   ///< no such run or tile
  kConflict,   ///< different data under a key already taken, or a finished run
  kError,      ///< the store itself failed (disk, database)
};
const char* ToString(Outcome outcome);

struct Result {
  Outcome outcome = Outcome::kOk;
  std::string message;
  bool ok() const { return outcome == Outcome::kOk || outcome == Outcome::kDuplicate; }
  explicit operator bool() const { return ok(); }
};

struct StoreOptions {
  TileGrid grid;
  size_t max_points_per_submap = 2'000'000;
  /// Points held in memory by tiles still being filled; beyond it every changed tile is
  /// written and the least recently touched are let go.
  size_t hot_points_budget = 6'000'000;
  /// Tiles held in memory (each costs its voxel table even when nearly empty): the same as
  /// hot_points_budget, counted in tiles.
  size_t hot_tiles_budget = 16384;
  /// A submap's points must lie within a square of this side (easting, northing): a real one
  /// spans its keyframes' path and the LiDARs' range, a few hundred metres.
  double max_submap_extent_m = 2000.0;
  /// Draco's encoding speed (0 smallest ... 9 fastest): 3 encodes as fast as 5 on corridor
  /// tiles and 15 % smaller (18 against 21 bits per point).
  int draco_speed = 3;
  int encode_threads = 2;  ///< tiles encoded in parallel on a flush
  /// A background thread writes the changed tiles this often (0: only Flush() writes them),
  /// and at once when this many new points wait.
  int flush_interval_ms = 1000;
  size_t flush_dirty_points = 1'000'000;
  bool IsValid(std::string* error) const;
};

struct NewRun {
  std::string line;     ///< the railway line's name; its first run defines its chainage
  std::string vehicle;  ///< the train or vehicle
  int64_t start_ns = 0;
};

struct RunInfo {
  int64_t id = 0;
  std::string line, vehicle, status, utm_zone;
  int64_t start_ns = 0, end_ns = 0, created_ns = 0;
  int64_t submaps = 0, points = 0, poses = 0;  ///< submaps and points in tiles (lost ones aside)
  int64_t submaps_lost = 0;  ///< acknowledged submaps whose payload was lost before tiling
};

struct TileInfo {
  int64_t run_id = 0;
  TileKey key;
  std::string utm_zone;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  int64_t points = 0, bytes = 0, version = 0, updated_ns = 0;
  double max_error_m = 0.0;
  std::string etag;  ///< quoted, for HTTP
};

struct LineInfo {
  std::string name;
  int64_t reference_run = 0;  ///< the run whose path is the centreline (0: none finished yet)
  std::string utm_zone;
  double length_m = 0.0;           ///< of the centreline
  double chainage_offset_m = 0.0;  ///< added to the distance along it (km posts set it)
  int64_t runs = 0;
  int64_t km_posts = 0;  ///< pinned (none: chainage counts from the reference run's start)
};

/// A stretch of a line by chainage: its centreline with the track geometry, and the reference
/// run's level-0 tiles that cover it.
struct TrackSegment {
  LineInfo line;
  std::vector<TrackSample> samples;  ///< chainage includes the line's offset
  std::vector<TileInfo> tiles;
};

/// A point of interest: a mast, a signal, a level crossing, a defect to watch.
struct Poi {
  int64_t id = 0;
  std::string line;  ///< may be empty
  std::string kind, name, utm_zone;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();  ///< UTM
  std::string properties_json = "{}";           ///< a JSON object, kept as given
  int64_t created_ns = 0, updated_ns = 0;
};

/// What to export: a run's points at a level, in a UTM box or along a line's km range.
struct ExportRequest {
  int64_t run_id = 0;
  int level = 0;
  bool has_box = false;
  Eigen::AlignedBox2d box;  ///< UTM easting/northing
  std::string line;         ///< with a km range: the points within half_width_m of its centreline
  double from_m = 0.0, to_m = 0.0;
  double half_width_m = 15.0;
  size_t max_points = 20'000'000;
};

struct IngestReceipt {
  uint64_t points = 0;           ///< the submap's points
  uint64_t points_new = 0;       ///< ... that filled a level-0 voxel no earlier point had
  uint64_t points_off_grid = 0;  ///< ... beyond a tile's height range, left out
  int64_t last_stamp_ns = 0;     ///< the submap's last keyframe stamp
};

/// Tiles written by a flush, for live notices.
struct TileUpdate {
  int64_t run_id = 0;
  TileKey key;
  int64_t version = 0;
};

struct StoreStats {
  uint64_t submaps_stored = 0, submaps_duplicate = 0, submaps_rejected = 0;
  uint64_t points_ingested = 0, points_off_grid = 0;
  uint64_t poses_stored = 0, poses_duplicate = 0;
  uint64_t tiles_written = 0, flushes = 0;
  uint64_t points_encoded = 0;       ///< tile points through Draco, over every flush
  uint64_t submaps_recovered = 0;    ///< merged again on opening, after a crash
  uint64_t submaps_lost = 0;         ///< acknowledged, but the payload was gone on opening
  uint64_t submaps_lost_stored = 0;  ///< lost submaps of every run not sent again since
  size_t hot_tiles = 0, hot_points = 0;
};

/// What opening the store found of submaps acknowledged before a crash but not yet in written
/// tiles: (run, sequence) of those merged again from their payloads, and of those whose
/// payload was gone (their points are not in the tiles until the submap is sent again).
struct RecoveryReport {
  std::vector<std::pair<int64_t, uint64_t>> recovered, lost;
};

class MapStore;

/// An export read tile by tile: what it holds is counted when it is made (one pass over the
/// tiles), then Next gives each tile's points in turn, so the points never all sit in memory.
/// Made by MapStore::PrepareExport; used while the store is open. A tile that a live run adds
/// to in between gives no more points than were counted.
class ExportCursor {
 public:
  ~ExportCursor();
  ExportCursor(const ExportCursor&) = delete;
  ExportCursor& operator=(const ExportCursor&) = delete;

  size_t points() const { return points_; }
  const Eigen::AlignedBox3d& bounds() const { return bounds_; }
  const std::string& utm_zone() const { return zone_; }
  bool done() const { return next_ >= tiles_.size(); }
  /// The points of the next tile (`points` is replaced).
  Result Next(std::vector<ExportPoint>* points);

 private:
  friend class MapStore;
  struct Filter;
  ExportCursor(const MapStore* store, int64_t run_id, std::unique_ptr<Filter> filter);
  /// A tile's points that the filter takes.
  Result Read(const TileKey& key, std::vector<ExportPoint>* points);

  const MapStore* store_;
  int64_t run_id_;
  std::unique_ptr<Filter> filter_;
  std::vector<TileKey> tiles_;
  std::vector<size_t> counts_;  ///< each tile's points when counted
  size_t next_ = 0, points_ = 0;
  Eigen::AlignedBox3d bounds_;
  std::string zone_;
};

/// A folder holding every run as Draco tiles on a UTM grid with a level-of-detail pyramid, and
/// an SQLite index (WAL) of runs, submaps, poses and tiles. A submap is acknowledged once its
/// payload is in the incoming folder and its row committed; its points go into tiles held in
/// memory, written (encoded) by a background flusher or Flush, after which the payload is let
/// go. Opening the folder after a crash merges the
/// payloads of submaps not yet in written tiles again, so nothing acknowledged is lost. Merging
/// keeps the first point of each voxel (level 0: the submaps' own 0.1 m voxels), so it is
/// incremental and a repeated merge changes nothing. Safe to call from several threads.
class MapStore {
 public:
  /// Opens or creates the store in `dir` (created if missing), migrating an older index.
  static std::unique_ptr<MapStore> Open(const std::string& dir,
                                        const StoreOptions& options,
                                        std::string* error);
  ~MapStore();
  MapStore(const MapStore&) = delete;
  MapStore& operator=(const MapStore&) = delete;

  Result CreateRun(const NewRun& run, RunInfo* out);
  Result GetRun(int64_t run_id, RunInfo* out) const;
  std::vector<RunInfo> ListRuns() const;
  /// Writes the run's tiles and marks it finished; a finished run takes no more data. The first
  /// finished run of a line with a usable path defines the line's centreline and chainage.
  Result FinishRun(int64_t run_id, int64_t end_ns, RunInfo* out);

  /// Every line with its centreline's extent.
  Result ListLines(std::vector<LineInfo>* lines) const;
  Result GetLine(const std::string& name, LineInfo* line) const;
  /// The stretch of `line` from `from_m` to `to_m` of chainage (metres).
  Result Segment(const std::string& line, double from_m, double to_m, TrackSegment* out) const;
  /// Pins a kilometre post: the centreline point nearest to `p_utm` gets chainage
  /// `chainage_m`; every chainage of the line moves by the same offset.
  Result PinKmPost(const std::string& line,
                   const std::string& label,
                   double chainage_m,
                   const Eigen::Vector2d& p_utm,
                   LineInfo* out);

  /// The points of a run in a box or along a km range (tile points, within their stated
  /// error), counted; refused if they would be more than request.max_points.
  Result PrepareExport(const ExportRequest& request, std::unique_ptr<ExportCursor>* cursor) const;
  /// PrepareExport's points all at once.
  Result Export(const ExportRequest& request,
                std::vector<ExportPoint>* points,
                std::string* utm_zone) const;

  /// Points of interest: create (the id is assigned), read, list (of a line, or all when
  /// `line` is empty, optionally in a UTM box), update (all fields but the id) and delete.
  Result CreatePoi(Poi* poi);
  Result GetPoi(int64_t id, Poi* poi) const;
  Result ListPois(const std::string& line,
                  const Eigen::AlignedBox2d* box,
                  std::vector<Poi>* pois) const;
  Result UpdatePoi(Poi* poi);
  Result DeletePoi(int64_t id);

  /// Stores a submap (EncodeSubmapPcd bytes) under its run and sequence number. The same bytes
  /// again are a duplicate; different bytes under a stored sequence are a conflict.
  Result IngestSubmap(int64_t run_id, const std::string& payload, IngestReceipt* receipt);
  /// Stores poses by sequence number: stored ones again are skipped, different values under a
  /// stored sequence are a conflict (and nothing of the batch is stored).
  /// `added` (if given) gets, per pose, whether this call stored it.
  Result IngestPoses(int64_t run_id,
                     const std::vector<api::StreamPose>& poses,
                     int* stored,
                     std::vector<bool>* added = nullptr);

  /// Encodes every changed tile and writes them in one transaction, ingest going on meanwhile;
  /// `updated` gets them. The background flusher calls it too.
  Result Flush(std::vector<TileUpdate>* updated = nullptr);
  /// Called (on the flushing thread) with the tiles each flush wrote: for live notices.
  void SetTileListener(std::function<void(const std::vector<TileUpdate>&)> listener);

  /// The written tiles of a run at `level` that meet the box (UTM easting/northing).
  Result TilesInBox(int64_t run_id,
                    int level,
                    const Eigen::AlignedBox2d& box,
                    std::vector<TileInfo>* tiles) const;
  /// One written tile's Draco bytes.
  Result Tile(int64_t run_id, const TileKey& key, TileInfo* info, std::string* bytes) const;
  /// The run's poses in sequence order.
  Result Trajectory(int64_t run_id, std::vector<api::StreamPose>* poses) const;
  /// Each pose's chainage on its run's line (offset included), NaN where the pose lies more
  /// than `max_off_m` from the centreline or the line has none yet: every run of a line is
  /// referenced to the centreline its first run defined.
  Result ChainageOfPoses(int64_t run_id,
                         const std::vector<api::StreamPose>& poses,
                         std::vector<double>* chainage_m,
                         double max_off_m = 10.0) const;

  StoreStats stats() const;
  /// What opening the store recovered and found lost.
  const RecoveryReport& recovery() const { return recovery_; }
  const StoreOptions& options() const { return options_; }
  const std::string& dir() const { return dir_; }
  std::string IndexPath() const { return dir_ + "/index.sqlite"; }

 private:
  struct HotTile;
  using HotKey = std::tuple<int64_t, int, int64_t, int64_t>;  // run, level, ix, iy
  class Readers;

  MapStore(const std::string& dir, const StoreOptions& options);
  bool Recover(std::string* error);
  std::string IncomingPath(int64_t run_id, uint64_t sequence) const;
  /// Merges a submap's points into the hot tiles of every level.
  void Merge(int64_t run_id, const api::Submap& submap, IngestReceipt* receipt);
  /// Merges the submap's `points` that fall in tile `key` into its hot tile's voxels (of side
  /// 1 / inverse_voxel); `next` gets those new there.
  void MergeTile(int64_t run_id,
                 const api::Submap& submap,
                 const TileKey& key,
                 const std::vector<uint32_t>& points,
                 float inverse_voxel,
                 IngestReceipt* receipt,
                 std::vector<uint32_t>* next);
  HotTile* Hot(int64_t run_id, const std::string& zone, const TileKey& key, double z_m);
  /// Hot tiles beyond hot_points_budget or hot_tiles_budget.
  bool OverBudgetLocked() const;
  void EvictLocked();
  void FlushLoop();
  struct FlushTile;
  struct FlushSnapshot;
  /// Copies the changed tiles (marked in flight) and takes the submaps they hold.
  FlushSnapshot TakeSnapshot();
  /// Encodes the snapshot's tiles on encode_threads threads, without the lock.
  void EncodeSnapshot(FlushSnapshot* snapshot) const;
  /// Writes the encoded tiles and, unless `poisoned`, marks the submaps tiled: one transaction.
  Result WriteSnapshotLocked(const FlushSnapshot& snapshot,
                             bool poisoned,
                             std::vector<TileUpdate>* done);
  /// Puts a failed flush's tiles and submaps back for the next one; returns the error.
  Result UndoFlushLocked(const FlushSnapshot& snapshot, const std::string& message);
  /// Lets the unreadable hot tiles go that no flush holds.
  void DropUnreadableLocked();
  /// Decodes and checks an ingested submap; counts a rejection.
  Result DecodeIngested(const std::string& payload, api::Submap* s);
  /// The answer to a submap whose sequence the run has already: restored (its payload was
  /// lost), a duplicate or a conflict; nullopt for a new one.
  std::optional<Result> ResentSubmapLocked(int64_t run_id,
                                           const api::Submap& s,
                                           const std::string& payload,
                                           const std::string& hash,
                                           IngestReceipt* receipt);
  Result RestoreSubmapLocked(int64_t run_id,
                             const api::Submap& s,
                             const std::string& payload,
                             IngestReceipt* receipt);
  /// Keeps a new submap's payload in the incoming folder and commits its row (with the points'
  /// bounding `box`, computed before the lock) and counts.
  Result StoreSubmapLocked(int64_t run_id,
                           const api::Submap& s,
                           const std::string& payload,
                           const std::string& hash,
                           const Eigen::AlignedBox3d& box);
  /// Inserts the poses the run has not stored yet (`fresh` marks them, `added` counts them);
  /// kConflict for a stored sequence with other values or a new pose of a finished run.
  Result InsertPosesLocked(int64_t run_id,
                           const RunInfo& run,
                           const std::vector<api::StreamPose>& poses,
                           std::vector<bool>* fresh,
                           int* added);
  Result RunLocked(const Database& db, int64_t run_id, RunInfo* out) const;
  /// Marks an acknowledged submap whose payload is gone as lost, and takes it out of its run's
  /// counts.
  bool MarkLostLocked(int64_t run_id, uint64_t sequence, std::string* error);
  Result LineLocked(const Database& db, const std::string& name, LineInfo* out) const;
  Result CentrelineLocked(const Database& db,
                          const std::string& name,
                          std::vector<CentrelinePoint>* out) const;
  /// Makes the run's path the centreline of its line if the line has none yet.
  Result DefineCentrelineLocked(const RunInfo& run);

  std::string dir_;
  StoreOptions options_;
  std::unique_ptr<StoreLock> lock_;  ///< first taken, last let go: after the final flush
  mutable std::mutex mu_;            ///< the writer connection, the hot tiles, the stats
  std::unique_ptr<Database> writer_;
  std::unique_ptr<Readers> readers_;
  std::map<HotKey, std::unique_ptr<HotTile>> hot_;
  size_t hot_points_ = 0;
  uint64_t touch_ = 0;
  /// Submaps merged into hot tiles that are not all written yet.
  std::vector<std::pair<int64_t, uint64_t>> unflushed_;
  StoreStats stats_;
  RecoveryReport recovery_;
  size_t dirty_points_ = 0;  ///< new points since the last snapshot
  std::function<void(const std::vector<TileUpdate>&)> listener_;
  std::mutex flush_mu_;  ///< one flush at a time
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread flusher_;
};

}  // namespace raillomer::mapstore
