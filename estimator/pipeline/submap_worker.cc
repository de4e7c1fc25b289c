#include "estimator/pipeline/submap_worker.h"

#include <utility>
#include <vector>

namespace raillomer {

SubmapWorker::SubmapWorker(const SubmapOptions& options, Emit emit, size_t max_queued)
    : builder_(options),
      emit_(std::move(emit)),
      max_queued_(max_queued > 0 ? max_queued : 1),
      thread_([this] { Run(); }) {}

SubmapWorker::~SubmapWorker() { Finish(); }

void SubmapWorker::Add(SubmapKeyframe keyframe) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [&] { return queue_.size() < max_queued_; });
  queue_.push_back(std::move(keyframe));
  changed_.notify_all();
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
    SubmapKeyframe keyframe;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [&] { return !queue_.empty() || finishing_; });
      if (queue_.empty()) break;  // finishing, and nothing left
      keyframe = std::move(queue_.front());
      queue_.pop_front();
    }
    changed_.notify_all();  // room in the queue
    emit(builder_.Add(std::move(keyframe)));
  }
  emit(builder_.Flush());
}

}  // namespace raillomer
