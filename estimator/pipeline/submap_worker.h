#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

#include "api/stream.h"
#include "estimator/mapping/submap_builder.h"

namespace raillomer {

/// Runs a SubmapBuilder on a thread of its own, so that the submaps (scan-to-submap ICP, then
/// NDT) are built while the frames go on. With GNSS the keyframes come in bursts: each is held
/// until the GNSS graph has a node after it, and a node comes every factor period (10 s), so
/// 100 keyframes and 10 submaps arrive together; built in the frame loop, that stalled one frame
/// in a hundred by 1-3 s.
class SubmapWorker {
 public:
  /// Called on the worker's thread with each submap as it completes, in order.
  using Emit = std::function<void(api::Submap)>;

  /// `max_queued_s`: Add blocks while the keyframes waiting span more than this much time
  /// (each holds its cloud). The GNSS fusion releases what it held through an outage at once
  /// (up to its gnss_max_latency_s); those clouds are in memory already, and blocking then
  /// would only stall the frames, so the span covers that.
  SubmapWorker(const SubmapOptions& options, Emit emit, double max_queued_s = 90.0);
  /// Finishes first, if Finish was not called: nothing accepted is lost.
  ~SubmapWorker();
  SubmapWorker(const SubmapWorker&) = delete;
  SubmapWorker& operator=(const SubmapWorker&) = delete;

  /// Queues a keyframe; `sent_provisionally`: it went out as provisional output already.
  void Add(SubmapKeyframe keyframe, bool sent_provisionally = false);
  /// Copies of the keyframes waiting that are stamped before `before_ns` and were not sent
  /// provisionally yet, in order; each is returned once (the caller sends it provisionally).
  std::vector<SubmapKeyframe> TakeProvisional(int64_t before_ns);
  /// Whether the oldest keyframe waiting went out provisionally: the final map is behind.
  bool BehindProvisional() const;
  /// Builds everything queued, closes the last submap and stops the thread; every submap has
  /// been emitted when it returns. Add must not be called after it.
  void Finish();
  /// The builder's counters as of the last keyframe it took.
  SubmapStats stats() const;

 private:
  void Run();

  SubmapBuilder builder_;
  Emit emit_;
  struct Waiting {
    SubmapKeyframe keyframe;
    bool sent_provisionally = false;
  };

  int64_t max_queued_ns_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Waiting> queue_;
  bool finishing_ = false;
  SubmapStats stats_;
  std::thread thread_;  ///< last: started once the rest is set up
};

}  // namespace raillomer
