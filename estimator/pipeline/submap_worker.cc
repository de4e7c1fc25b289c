#include "estimator/pipeline/submap_worker.h"

#include <algorithm>
#include <utility>
#include <vector>

namespace raillomer {

SubmapWorker::SubmapWorker(const SubmapOptions& options, Emit emit, double max_queued_s)
    : builder_(options),
      emit_(std::move(emit)),
      max_queued_ns_(static_cast<int64_t>(std::max(0.0, max_queued_s) * 1e9)),
      thread_([this] { Run(); }) {}

SubmapWorker::~SubmapWorker() { Finish(); }

void SubmapWorker::Add(SubmapKeyframe keyframe, bool sent_provisionally) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [&] {
    return queue_.empty() || keyframe.stamp_ns - queue_.front().keyframe.stamp_ns <= max_queued_ns_;
  });
  queue_.push_back({std::move(keyframe), sent_provisionally});
  changed_.notify_all();
}

std::vector<SubmapKeyframe> SubmapWorker::TakeProvisional(int64_t before_ns) {
  std::vector<SubmapKeyframe> out;
  std::lock_guard<std::mutex> lock(mutex_);
  for (Waiting& w : queue_) {
    if (w.keyframe.stamp_ns >= before_ns) break;
    if (w.sent_provisionally) continue;
    w.sent_provisionally = true;
    out.push_back(w.keyframe);
  }
  return out;
}

bool SubmapWorker::BehindProvisional() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return !queue_.empty() && queue_.front().sent_provisionally;
}

void SubmapWorker::Finish() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    finishing_ = true;
  }
  changed_.notify_all();
  if (thread_.joinable()) thread_.join();
}

SubmapStats SubmapWorker::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

void SubmapWorker::Run() {
  const auto emit = [this](std::vector<api::Submap> built) {
    for (api::Submap& s : built) emit_(std::move(s));
    std::lock_guard<std::mutex> lock(mutex_);
    stats_ = builder_.stats();
  };
  for (;;) {
    Waiting next;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [&] { return !queue_.empty() || finishing_; });
      if (queue_.empty()) break;  // finishing, and nothing left
      next = std::move(queue_.front());
      queue_.pop_front();
    }
    changed_.notify_all();  // room in the queue
    emit(builder_.Add(std::move(next.keyframe)));
  }
  emit(builder_.Flush());
}

}  // namespace raillomer
