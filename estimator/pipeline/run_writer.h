#pragma once

#include <cstdint>
#include <cstdio>
#include <mutex>
#include <string>
#include <vector>

#include "api/stream.h"
#include "estimator/pipeline/estimator.h"

namespace raillomer {

/// Writes an estimator run to a folder as it goes, so that whatever was written stays valid if
/// the run stops early:
///   trajectory.tum  body pose at every LiDAR frame (TUM, flushed every frame)
///   timing.csv      per-frame frontend / backend milliseconds and diagnostics
///   keyframes.tum   keyframe poses; keyframes/<stamp>.pcd their deskewed clouds (body frame,
///                   binary PCD, the pose also in VIEWPOINT)
///   submaps/<index>.pcd, submaps/index.csv  submaps as they complete (OpenSubmaps): float
///                   offsets from a double origin, the origin in the index and the PCD header
///   provisional/<n>.pcd, provisional/index.csv  provisional submaps (OpenProvisional), the same
///                   way, numbered as they go out
///   summary.json    counts, timing percentiles and the real-time factor (at Close)
class RunWriter {
 public:
  ~RunWriter();
  /// Creates the folder and the files; false with a message naming the path on failure. The
  /// trajectory's header goes in with the first frame: `header` for a local frame, or, for a
  /// georeferenced run, `# utm_zone <zone>` and a line saying the poses are in UTM.
  bool Open(const std::string& out_dir,
            bool write_keyframes,
            const std::string& header,
            std::string* error);
  /// Creates submaps/ and its index; false with a message on failure.
  bool OpenSubmaps(std::string* error);
  void WriteSubmap(const api::Submap& submap);
  /// Creates provisional/ and its index, likewise.
  bool OpenProvisional(std::string* error);
  /// Writes a provisional submap; called from one thread at a time, as the estimator does.
  void WriteProvisionalSubmap(const api::Submap& submap);
  void WriteFrame(const FrameResult& frame);
  /// Keyframes after their frame (a georeferenced keyframe takes that frame's UTM origin).
  void WriteKeyframe(const Keyframe& keyframe);
  /// Writes summary.json; `extra_json` members (without braces) are added to it.
  bool Close(const EstimatorStats& stats,
             double data_duration_s,
             double wall_s,
             const std::string& extra_json,
             std::string* error);

  size_t frames() const { return frame_ms_.size(); }
  /// Median and 95th percentile of frontend + backend time per frame.
  double MedianFrameMs() const;
  double PercentileFrameMs(double q) const;
  bool failed() const;
  std::string failure() const;

 private:
  std::string out_dir_;
  std::FILE* trajectory_ = nullptr;
  std::FILE* timing_ = nullptr;
  std::FILE* keyframes_ = nullptr;
  std::FILE* submap_index_ = nullptr;
  std::FILE* provisional_index_ = nullptr;
  uint32_t provisional_written_ = 0;
  bool write_keyframes_ = false;
  std::string header_;
  bool header_written_ = false;
  void WriteHeader(const FrameResult* first);
  /// Creates out_dir/folder and its index.csv with the header line.
  bool OpenSubmapIndex(const std::string& folder, std::FILE** index, std::string* error);
  /// Writes `s` as folder/<number>.pcd and its index line.
  void WriteSubmapTo(const std::string& folder,
                     std::FILE* index,
                     uint32_t number,
                     const api::Submap& s);
  std::vector<double> frame_ms_, frontend_ms_, backend_ms_;
  /// A write that failed: WriteSubmap runs on the submap worker's thread, the rest on the
  /// caller's.
  void Failed(const std::string& error);
  mutable std::mutex failure_mutex_;
  bool failed_ = false;
  std::string failure_;
};

}  // namespace raillomer
