#include "mapstore/schema.h"

#include <vector>

namespace raillomer::mapstore {
namespace {

// Migration N takes the index from version N-1 to N. Never edit a released migration: add one.
const std::vector<const char*>& Migrations() {
  static const std::vector<const char*> migrations = {
      // 1: runs, their submaps, poses and tiles. A submap's `tiled` is 0 until its points are in
      // written tiles (its payload waits in the incoming folder till then), 1 after, -1 if
      // its payload was lost before.
      R"sql(
CREATE TABLE runs (
  id INTEGER PRIMARY KEY,
  line TEXT NOT NULL,
  vehicle TEXT NOT NULL,
  status TEXT NOT NULL CHECK (status IN ('live', 'finished')),
  start_ns INTEGER NOT NULL,
  end_ns INTEGER,
  utm_zone TEXT,
  created_ns INTEGER NOT NULL,
  submaps INTEGER NOT NULL DEFAULT 0,
  points INTEGER NOT NULL DEFAULT 0,
  poses INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE submaps (
  run_id INTEGER NOT NULL REFERENCES runs(id),
  sequence INTEGER NOT NULL,
  idx INTEGER NOT NULL,
  first_stamp_ns INTEGER NOT NULL,
  last_stamp_ns INTEGER NOT NULL,
  utm_zone TEXT NOT NULL,
  origin_x REAL NOT NULL, origin_y REAL NOT NULL, origin_z REAL NOT NULL,
  min_x REAL NOT NULL, min_y REAL NOT NULL, max_x REAL NOT NULL, max_y REAL NOT NULL,
  points INTEGER NOT NULL,
  keyframes INTEGER NOT NULL,
  payload_hash TEXT NOT NULL,
  tiled INTEGER NOT NULL DEFAULT 0,
  received_ns INTEGER NOT NULL,
  PRIMARY KEY (run_id, sequence)
) WITHOUT ROWID;
CREATE INDEX submaps_untiled ON submaps (tiled) WHERE tiled = 0;
CREATE TABLE poses (
  run_id INTEGER NOT NULL REFERENCES runs(id),
  sequence INTEGER NOT NULL,
  stamp_ns INTEGER NOT NULL,
  georeferenced INTEGER NOT NULL,
  utm_zone TEXT NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL,
  qx REAL NOT NULL, qy REAL NOT NULL, qz REAL NOT NULL, qw REAL NOT NULL,
  PRIMARY KEY (run_id, sequence)
) WITHOUT ROWID;
CREATE TABLE tiles (
  run_id INTEGER NOT NULL REFERENCES runs(id),
  level INTEGER NOT NULL,
  ix INTEGER NOT NULL,
  iy INTEGER NOT NULL,
  utm_zone TEXT NOT NULL,
  origin_x REAL NOT NULL, origin_y REAL NOT NULL, origin_z REAL NOT NULL,
  points INTEGER NOT NULL,
  max_error_m REAL NOT NULL,
  version INTEGER NOT NULL,
  etag TEXT NOT NULL,
  updated_ns INTEGER NOT NULL,
  bytes BLOB NOT NULL,
  PRIMARY KEY (run_id, level, ix, iy)
) WITHOUT ROWID;
)sql",
      // 2: lines with their centreline and chainage, kilometre posts, points of interest.
      R"sql(
CREATE TABLE lines (
  name TEXT PRIMARY KEY,
  reference_run INTEGER REFERENCES runs(id),
  utm_zone TEXT,
  created_ns INTEGER NOT NULL
);
INSERT INTO lines (name, created_ns) SELECT line, MIN(created_ns) FROM runs GROUP BY line;
CREATE TABLE centreline (
  line TEXT NOT NULL REFERENCES lines(name),
  seq INTEGER NOT NULL,
  chainage_m REAL NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL,
  PRIMARY KEY (line, seq)
) WITHOUT ROWID;
CREATE TABLE km_posts (
  id INTEGER PRIMARY KEY,
  line TEXT NOT NULL REFERENCES lines(name),
  chainage_m REAL NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL,
  label TEXT NOT NULL,
  created_ns INTEGER NOT NULL
);
CREATE TABLE pois (
  id INTEGER PRIMARY KEY,
  line TEXT REFERENCES lines(name),
  kind TEXT NOT NULL,
  name TEXT NOT NULL,
  utm_zone TEXT NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL,
  properties TEXT NOT NULL DEFAULT '{}',
  created_ns INTEGER NOT NULL,
  updated_ns INTEGER NOT NULL
);
)sql",
      // 3: the centreline's cant, and a line's chainage offset (set by pinning km posts).
      R"sql(
ALTER TABLE centreline ADD COLUMN cant_m REAL NOT NULL DEFAULT 0;
ALTER TABLE lines ADD COLUMN chainage_offset_m REAL NOT NULL DEFAULT 0;
)sql",
      // 4: a run's submaps whose payload was lost before tiling are counted apart: its
      // submaps and points are what its tiles hold.
      R"sql(
ALTER TABLE runs ADD COLUMN submaps_lost INTEGER NOT NULL DEFAULT 0;
UPDATE runs SET
  submaps_lost = (SELECT count(*) FROM submaps WHERE run_id = runs.id AND tiled = -1),
  submaps = submaps - (SELECT count(*) FROM submaps WHERE run_id = runs.id AND tiled = -1),
  points = points -
    (SELECT COALESCE(SUM(points), 0) FROM submaps WHERE run_id = runs.id AND tiled = -1);
)sql",
      // 5: change detection: a run's comparison with its reference (one row per run), each
      // compared stretch (one transaction with its changes, so a restart resumes at the first
      // stretch without a row), and the changes found with the status engineers give them.
      R"sql(
CREATE TABLE change_detection (
  run_id INTEGER PRIMARY KEY REFERENCES runs(id),
  reference_run INTEGER NOT NULL REFERENCES runs(id),
  status TEXT NOT NULL CHECK (status IN ('pending', 'running', 'done', 'failed')),
  error TEXT NOT NULL DEFAULT '',
  requested_ns INTEGER NOT NULL,
  updated_ns INTEGER NOT NULL
);
CREATE TABLE change_stretches (
  run_id INTEGER NOT NULL REFERENCES runs(id),
  stretch INTEGER NOT NULL,
  reference_run INTEGER NOT NULL,
  from_m REAL NOT NULL, to_m REAL NOT NULL,
  compared INTEGER NOT NULL,
  rms_m REAL NOT NULL,
  rail_rms_m REAL,
  transform TEXT NOT NULL,
  seconds REAL NOT NULL,
  done_ns INTEGER NOT NULL,
  PRIMARY KEY (run_id, stretch)
) WITHOUT ROWID;
CREATE TABLE changes (
  id INTEGER PRIMARY KEY,
  run_id INTEGER NOT NULL REFERENCES runs(id),
  reference_run INTEGER NOT NULL,
  stretch INTEGER NOT NULL,
  line TEXT NOT NULL,
  kind TEXT NOT NULL,
  chainage_m REAL NOT NULL,
  offset_m REAL NOT NULL,
  utm_zone TEXT NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL,
  properties TEXT NOT NULL,
  intrudes INTEGER NOT NULL,
  size_max_m REAL NOT NULL,
  status TEXT NOT NULL DEFAULT 'new',
  note TEXT NOT NULL DEFAULT '',
  closed_by_run INTEGER,
  created_ns INTEGER NOT NULL,
  updated_ns INTEGER NOT NULL
);
CREATE INDEX changes_by_run ON changes (run_id, chainage_m);
CREATE INDEX changes_by_line ON changes (line, status);
)sql",
      // 6: stretches compared on a live run's provisional output, and their changes, until
      // the stretch is compared again on the final output.
      R"sql(
ALTER TABLE change_stretches ADD COLUMN provisional INTEGER NOT NULL DEFAULT 0;
ALTER TABLE changes ADD COLUMN provisional INTEGER NOT NULL DEFAULT 0;
)sql",
      // 7: a change found again by a later run of the line: the earlier change it continues
      // and the run that first found it.
      R"sql(
ALTER TABLE changes ADD COLUMN earlier_change INTEGER;
ALTER TABLE changes ADD COLUMN first_seen_run INTEGER;
)sql",
      // 8: a change's id is never given again, even after the change is withdrawn: reports
      // and links name changes by it.
      R"sql(
CREATE TABLE changes_v8 (
  id INTEGER PRIMARY KEY AUTOINCREMENT,
  run_id INTEGER NOT NULL REFERENCES runs(id),
  reference_run INTEGER NOT NULL,
  stretch INTEGER NOT NULL,
  line TEXT NOT NULL,
  kind TEXT NOT NULL,
  chainage_m REAL NOT NULL,
  offset_m REAL NOT NULL,
  utm_zone TEXT NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL,
  properties TEXT NOT NULL,
  intrudes INTEGER NOT NULL,
  size_max_m REAL NOT NULL,
  status TEXT NOT NULL DEFAULT 'new',
  note TEXT NOT NULL DEFAULT '',
  closed_by_run INTEGER,
  created_ns INTEGER NOT NULL,
  updated_ns INTEGER NOT NULL,
  provisional INTEGER NOT NULL DEFAULT 0,
  earlier_change INTEGER,
  first_seen_run INTEGER
);
INSERT INTO changes_v8 SELECT * FROM changes;
DROP TABLE changes;
ALTER TABLE changes_v8 RENAME TO changes;
CREATE INDEX changes_by_run ON changes (run_id, chainage_m);
CREATE INDEX changes_by_line ON changes (line, status);
)sql",
      // 9: a run's changes under a comparison requested again, each until its stretch is
      // compared again (rechecking); the changes that continue one, found when it is withdrawn.
      R"sql(
ALTER TABLE changes ADD COLUMN rechecking INTEGER NOT NULL DEFAULT 0;
CREATE INDEX changes_by_earlier ON changes (earlier_change);
)sql",
  };
  return migrations;
}

int UserVersion(Database& db) {
  Statement s(db, "PRAGMA user_version");
  return s.Step() ? static_cast<int>(s.Int(0)) : -1;
}

}  // namespace

int LatestSchemaVersion() { return static_cast<int>(Migrations().size()); }

bool MigrateSchemaTo(Database& db, int version, std::string* error) {
  const int found = UserVersion(db);
  if (found < 0) {
    *error = "cannot read the index's schema version: " + db.Message();
    return false;
  }
  if (found > LatestSchemaVersion()) {
    *error = "the index has schema version " + std::to_string(found) +
             ", newer than this build's " + std::to_string(LatestSchemaVersion()) +
             ": use a newer raillomer-server";
    return false;
  }
  for (int v = found + 1; v <= version; ++v) {
    Transaction t(db);
    if (!t.ok()) {
      *error = "cannot begin migration " + std::to_string(v) + ": " + db.Message();
      return false;
    }
    std::string message;
    if (!db.Exec(Migrations()[v - 1], &message) ||
        !db.Exec("PRAGMA user_version = " + std::to_string(v), &message) || !t.Commit(&message)) {
      *error = "schema migration to version " + std::to_string(v) + " failed: " + message;
      return false;
    }
  }
  return true;
}

bool MigrateSchema(Database& db, std::string* error, int* from) {
  if (from) *from = UserVersion(db);
  return MigrateSchemaTo(db, LatestSchemaVersion(), error);
}

}  // namespace raillomer::mapstore
