#include "estimator/mapping/submap_archive.h"

namespace raillomer {

SubmapArchive::SubmapArchive() : file_(std::tmpfile()) {}

SubmapArchive::~SubmapArchive() {
  if (file_) std::fclose(file_);
}

void SubmapArchive::Put(uint32_t id,
                        const std::string& utm_zone,
                        const Eigen::Vector3d& origin,
                        const std::vector<Eigen::Vector3f>& points) {
  if (points.empty()) return;
  Entry e;
  e.id = id;
  e.utm_zone = utm_zone;
  e.origin = origin;
  for (const Eigen::Vector3f& p : points) e.box.extend(p.cast<double>() + origin);
  e.offset = stored_;
  e.count = points.size();
  if (file_) {
    const long at = static_cast<long>(stored_ * sizeof(Eigen::Vector3f));
    if (std::fseek(file_, at, SEEK_SET) != 0 ||
        std::fwrite(points.data(), sizeof(Eigen::Vector3f), points.size(), file_) !=
            points.size()) {
      // The disk is full or gone: what is stored moves into memory, and the rest follows.
      memory_.resize(stored_);
      const bool read =
          std::fseek(file_, 0, SEEK_SET) == 0 &&
          std::fread(memory_.data(), sizeof(Eigen::Vector3f), stored_, file_) == stored_;
      std::fclose(file_);
      file_ = nullptr;
      if (!read) {  // lost: later submaps register onto what comes after
        memory_.clear();
        entries_.clear();
        stored_ = 0;
        e.offset = 0;
      }
    }
  }
  if (!file_) memory_.insert(memory_.end(), points.begin(), points.end());
  stored_ += points.size();
  entries_.push_back(std::move(e));
}

std::vector<Eigen::Vector3f> SubmapArchive::Within(const std::string& utm_zone,
                                                   const Eigen::Vector3d& origin,
                                                   const Eigen::AlignedBox3f& box,
                                                   const std::function<bool(uint32_t id)>& take,
                                                   std::vector<uint32_t>* ids) const {
  std::vector<Eigen::Vector3f> out;
  if (ids) ids->clear();
  if (box.isEmpty()) return out;
  const Eigen::AlignedBox3d world(box.min().cast<double>() + origin,
                                  box.max().cast<double>() + origin);
  std::vector<Eigen::Vector3f> buffer;
  for (const Entry& e : entries_) {
    if (e.utm_zone != utm_zone || !e.box.intersects(world) || (take && !take(e.id))) continue;
    const Eigen::Vector3f* points = nullptr;
    if (file_) {
      buffer.resize(e.count);
      if (std::fseek(file_, static_cast<long>(e.offset * sizeof(Eigen::Vector3f)), SEEK_SET) != 0 ||
          std::fread(buffer.data(), sizeof(Eigen::Vector3f), e.count, file_) != e.count) {
        continue;  // unreadable: this submap is no target
      }
      points = buffer.data();
    } else {
      points = memory_.data() + e.offset;
    }
    // Offsets between origins are whole metres at most a few kilometres: exact in float.
    const Eigen::Vector3f shift = (e.origin - origin).cast<float>();
    size_t kept = 0;
    for (uint64_t i = 0; i < e.count; ++i) {
      const Eigen::Vector3f p = points[i] + shift;
      if (!box.contains(p)) continue;
      out.push_back(p);
      ++kept;
    }
    if (ids && kept > 0) ids->push_back(e.id);
  }
  return out;
}

}  // namespace raillomer
