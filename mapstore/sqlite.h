#pragma once

#include <cstdint>
#include <string>
#include <string_view>

struct sqlite3;
struct sqlite3_stmt;

namespace raillomer::mapstore {

/// One SQLite connection. Every call reports failure as false with SQLite's message.
class Database {
 public:
  Database() = default;
  ~Database();
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;
  Database(Database&& other) noexcept;
  Database& operator=(Database&& other) noexcept;

  /// Opens (creating if asked) the file, with WAL journaling, foreign keys and a busy timeout.
  bool Open(const std::string& path, bool create, std::string* error);
  /// Runs one or more statements without results.
  bool Exec(const std::string& sql, std::string* error);
  int64_t LastInsertId() const;
  /// Rows changed by the last statement.
  int Changes() const;
  sqlite3* handle() const { return db_; }
  std::string Message() const;

 private:
  sqlite3* db_ = nullptr;
};

/// A prepared statement: bind by 1-based index, Step() through the rows, read columns 0-based.
class Statement {
 public:
  Statement(const Database& db, std::string_view sql);
  ~Statement();
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  bool ok() const { return stmt_ != nullptr; }
  const std::string& error() const { return error_; }

  Statement& Bind(int index, int64_t value);
  Statement& Bind(int index, int value) { return Bind(index, static_cast<int64_t>(value)); }
  Statement& Bind(int index, uint32_t value) { return Bind(index, static_cast<int64_t>(value)); }
  Statement& Bind(int index, double value);
  Statement& Bind(int index, std::string_view text);
  Statement& BindBlob(int index, std::string_view bytes);
  Statement& BindNull(int index);

  /// True while a row is ready; false when done or failed (then error() says why).
  bool Step();
  /// Runs a statement that returns no rows; false with error() set if it failed.
  bool Run();
  void Reset();

  int64_t Int(int column) const;
  double Double(int column) const;
  std::string Text(int column) const;
  std::string Blob(int column) const;
  bool IsNull(int column) const;

 private:
  sqlite3* db_ = nullptr;
  sqlite3_stmt* stmt_ = nullptr;
  std::string error_;
};

/// BEGIN IMMEDIATE ... COMMIT; rolled back unless committed.
class Transaction {
 public:
  explicit Transaction(Database& db);
  ~Transaction();
  bool ok() const { return ok_; }
  bool Commit(std::string* error);

 private:
  Database& db_;
  bool ok_ = false;
  bool done_ = false;
};

}  // namespace raillomer::mapstore
