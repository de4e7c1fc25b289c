#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>

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

  /// `max_queued`: Add blocks while this many keyframes wait (each holds its cloud).
  SubmapWorker(const SubmapOptions& options, Emit emit, size_t max_queued = 300);
  /// Finishes first, if Finish was not called: nothing accepted is lost.
  ~SubmapWorker();
  SubmapWorker(const SubmapWorker&) = delete;
  SubmapWorker& operator=(const SubmapWorker&) = delete;

  /// Queues a keyframe.
  void Add(SubmapKeyframe keyframe);
  /// Builds everything queued, closes the last submap and stops the thread; every submap has
  /// been emitted when it returns. Add must not be called after it.
  void Finish();
  /// The builder's counters as of the last keyframe it took.
  SubmapStats stats() const;

 private:
  void Run();

  SubmapBuilder builder_;
  Emit emit_;
  size_t max_queued_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<SubmapKeyframe> queue_;
  bool finishing_ = false;
  SubmapStats stats_;
  std::thread thread_;  ///< last: started once the rest is set up
};

}  // namespace raillomer
