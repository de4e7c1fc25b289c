#pragma once

#include <string>

#include "mapstore/sqlite.h"

namespace raillomer::mapstore {

/// The index's schema version this build writes (SQLite's user_version).
int LatestSchemaVersion();

/// Brings the index to the latest version, one migration per version in one transaction each:
/// a new file gets every migration, an older one the missing ones. An index written by a newer
/// build is refused (false, with a message naming both versions). `from` (if given) gets the
/// version found.
bool MigrateSchema(Database& db, std::string* error, int* from = nullptr);

/// Test support: migrates only up to `version` (a fixture of an older index).
bool MigrateSchemaTo(Database& db, int version, std::string* error);

}  // namespace raillomer::mapstore
