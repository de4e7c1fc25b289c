#pragma once

#include <cstdint>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer {

/// The finished submaps of a run, thinned, for registering a later submap onto every earlier
/// one it overlaps (the train runs the same track again: reversing, shunting, a second pass).
/// The points go to an anonymous temporary file and only a small index stays in memory, so
/// memory does not grow with the length of the run. If no temporary file can be created the
/// points stay in memory instead.
class SubmapArchive {
 public:
  SubmapArchive();
  ~SubmapArchive();
  SubmapArchive(const SubmapArchive&) = delete;
  SubmapArchive& operator=(const SubmapArchive&) = delete;

  /// Stores submap `id`'s points, offsets from `origin` (UTM, metres) in zone `utm_zone`.
  void Put(uint32_t id,
           const std::string& utm_zone,
           const Eigen::Vector3d& origin,
           const std::vector<Eigen::Vector3f>& points);
  /// The stored points of `utm_zone` inside `box` (offsets from `origin`), as offsets from
  /// `origin`, of the submaps `take` accepts (every one if it is empty); `ids` (if given) gets
  /// the ids of the submaps they came from.
  std::vector<Eigen::Vector3f> Within(const std::string& utm_zone,
                                      const Eigen::Vector3d& origin,
                                      const Eigen::AlignedBox3f& box,
                                      const std::function<bool(uint32_t id)>& take = {},
                                      std::vector<uint32_t>* ids = nullptr) const;
  size_t size() const { return entries_.size(); }
  /// False when the points are held in memory (no temporary file could be made).
  bool on_disk() const { return file_ != nullptr; }

 private:
  struct Entry {
    uint32_t id = 0;
    std::string utm_zone;
    Eigen::Vector3d origin;
    Eigen::AlignedBox3d box;  ///< absolute
    uint64_t offset = 0;      ///< first point, in points
    uint64_t count = 0;
  };
  std::FILE* file_ = nullptr;
  std::vector<Eigen::Vector3f> memory_;  ///< the points when there is no file
  uint64_t stored_ = 0;
  std::vector<Entry> entries_;
};

}  // namespace raillomer
