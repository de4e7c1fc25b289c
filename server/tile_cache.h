#pragma once

#include <cstdint>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>
#include <vector>

#include "mapstore/map_store.h"

namespace raillomer::server {

/// Served tiles kept in memory, least recently used first out, within a byte budget. A tile
/// written again (the store's flush listener) is dropped; an older read arriving after that
/// is not cached.
class TileCache {
 public:
  struct Entry {
    mapstore::TileInfo info;
    std::string bytes;
  };
  explicit TileCache(size_t budget_bytes) : budget_(budget_bytes) {}

  std::shared_ptr<const Entry> Get(int64_t run_id, const mapstore::TileKey& key) {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = map_.find({run_id, key.level, key.ix, key.iy});
    if (it == map_.end()) return nullptr;
    lru_.splice(lru_.begin(), lru_, it->second.second);
    return it->second.first;
  }

  void Put(std::shared_ptr<const Entry> entry) {
    const Key k{entry->info.run_id, entry->info.key.level, entry->info.key.ix, entry->info.key.iy};
    std::lock_guard<std::mutex> lock(mu_);
    auto latest = latest_.find(k);
    if (latest != latest_.end() && entry->info.version < latest->second) return;  // stale read
    if (map_.count(k)) return;
    used_ += entry->bytes.size();
    lru_.push_front(k);
    map_[k] = {std::move(entry), lru_.begin()};
    while (used_ > budget_ && !lru_.empty()) {
      auto victim = map_.find(lru_.back());
      used_ -= victim->second.first->bytes.size();
      map_.erase(victim);
      lru_.pop_back();
    }
  }

  void Invalidate(const std::vector<mapstore::TileUpdate>& updates) {
    std::lock_guard<std::mutex> lock(mu_);
    for (const mapstore::TileUpdate& u : updates) {
      const Key k{u.run_id, u.key.level, u.key.ix, u.key.iy};
      latest_[k] = std::max(latest_[k], u.version);
      auto it = map_.find(k);
      if (it == map_.end()) continue;
      used_ -= it->second.first->bytes.size();
      lru_.erase(it->second.second);
      map_.erase(it);
    }
  }

 private:
  using Key = std::tuple<int64_t, int, int64_t, int64_t>;
  size_t budget_;
  size_t used_ = 0;
  std::mutex mu_;
  std::list<Key> lru_;
  std::map<Key, std::pair<std::shared_ptr<const Entry>, std::list<Key>::iterator>> map_;
  std::map<Key, int64_t> latest_;  ///< the newest written version of each tile seen
};

}  // namespace raillomer::server
