#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <set>
#include <thread>
#include <vector>

#include "mapstore/change_store.h"
#include "mapstore/map_store.h"
#include "mapstore/provisional_map.h"

namespace raillomer::server {

/// Settings of the server's own change detection.
struct ChangeWorkerOptions {
  bool enabled = true;
  /// A stretch of a live run is compared once the train is this far past the stretch's end
  /// and the run's map (its stored submaps) reaches mapped_past_m past it: everything its
  /// LiDARs (which look ahead) saw of the stretch and its overlap is in.
  double past_m = 100.0;
  double mapped_past_m = 30.0;
  int poll_ms = 500;  ///< how often the worker looks for work without being woken
  int threads = 2;    ///< stretches compared side by side
  mapstore::RunComparisonOptions comparison;
};

/// Compares every run of a line with the line's reference run (or the one an operator chose)
/// on a background thread, stretch by stretch as the run's tiles arrive: a stretch of a live
/// run once the train is past it, the rest when the run finishes. Where the run's final output
/// does not hold a stretch yet but its provisional output (ProvisionalMap) does, the stretch
/// is compared on that, and again once the final output holds it, on a second thread at a
/// lower priority, so that a stretch not compared yet never waits behind one compared already.
/// Each stretch's changes are stored at once (ChangeStore) and handed to
/// `announce`; a restarted server resumes where the stored stretches end.
class ChangeWorker {
 public:
  /// Called on a worker's thread with each stretch's changes (new, or found again when a
  /// provisional stretch is compared on the final output), changes of earlier runs it closed,
  /// provisional changes not found again, and the run's detection state after it.
  using Announce = std::function<void(const std::vector<mapstore::StoredChange>& found,
                                      const std::vector<mapstore::StoredChange>& closed,
                                      const std::vector<mapstore::StoredChange>& withdrawn,
                                      const mapstore::DetectionState& state)>;

  /// `provisional` (may be null) holds the live runs' provisional output.
  ChangeWorker(mapstore::MapStore* store,
               mapstore::ChangeStore* changes,
               mapstore::ProvisionalMap* provisional,
               ChangeWorkerOptions options,
               Announce announce);
  ~ChangeWorker();
  ChangeWorker(const ChangeWorker&) = delete;
  ChangeWorker& operator=(const ChangeWorker&) = delete;

  void Start();
  /// Finishes the stretch under way and stops.
  void Stop();
  /// Something arrived (poses, a finished run): look for work now.
  void Notify();

  /// Asks for `run` to be compared again from the start with `reference` (0: the line's
  /// reference run). Checks first that the two can be compared: a run of another line or zone,
  /// an unknown or live reference, runs that do not overlap get an error naming the reason and
  /// change nothing.
  mapstore::Result Recompute(int64_t run, int64_t reference, mapstore::DetectionState* out);

  /// The run's detection state; for a run never requested, what it waits for (`pending`
  /// against the line's reference once there is one, `reason` otherwise).
  mapstore::Result State(int64_t run, mapstore::DetectionState* out, std::string* reason) const;

  /// Stretches compared since start, and seconds spent comparing.
  uint64_t stretches_compared() const { return stretches_compared_; }

 private:
  /// The two threads' work: stretches not compared yet (`Work::kNew`), or those compared on
  /// provisional output that the final output now holds (`Work::kAgain`).
  enum class Work { kNew = 0, kAgain = 1 };
  void Loop(Work work);
  /// One look over every run: requests detection of new runs (kNew), advances each running
  /// one; true if there is more to do at once.
  bool Pass(Work work);
  /// Compares the stretches of `state.run_id` that are ready for `work` (of kAgain, one batch:
  /// new ones may have come meanwhile; true if more wait); marks the run done when it finished
  /// and every stretch is stored final.
  bool Advance(const mapstore::RunInfo& run, const mapstore::DetectionState& state, Work work);
  /// Marks a finished run's detection done once every stretch is stored on the final output;
  /// either thread may find it so, one announces it.
  void FinishIfDone(const mapstore::RunInfo& run, size_t stretches);
  /// A stretch to compare, on provisional output or not.
  struct Job {
    mapstore::StretchRange range;
    bool provisional = false;
  };
  /// The run's stretches that can be compared now: `ready` those not stored yet, in order
  /// (on provisional output where the final does not hold them yet), `again` those stored
  /// provisional that the final output now holds; false if the store could not say.
  bool Ready(const mapstore::RunInfo& run,
             const mapstore::RunComparison& comparison,
             const std::set<int>& stored,
             const std::set<int>& provisional,
             std::vector<Job>* ready,
             std::vector<Job>* again) const;
  /// The comparison of `run` with `reference`, on its provisional output too while it is live.
  mapstore::Result PrepareComparison(const mapstore::RunInfo& run,
                                     int64_t reference,
                                     std::unique_ptr<mapstore::RunComparison>* out) const;
  /// Compares a batch of stretches on a thread each (the first on this one).
  static void CompareSideBySide(const mapstore::RunComparison& comparison,
                                Work work,
                                bool live,
                                const std::vector<Job>& batch,
                                std::vector<mapstore::StretchOutcome>* outcomes,
                                std::vector<mapstore::Result>* results);
  /// Stores a compared stretch and announces its changes; false (logged) on an error.
  bool Store(int64_t run,
             int64_t reference,
             mapstore::Result r,
             const mapstore::StretchOutcome& outcome);
  /// The calling thread yields to ingest and the API (nice 5), and a stretch compared again
  /// to everything else (nice 10): it has been compared once already. `idle`: it takes only
  /// CPU that nothing else wants (SCHED_IDLE), as a live run's stretch compared again does:
  /// the first comparisons of the stretches the train is passing never wait on it.
  static void LowerPriority(Work work, bool idle);
  bool stopping() const { return stopping_; }

  mapstore::MapStore* store_;
  mapstore::ChangeStore* changes_;
  mapstore::ProvisionalMap* provisional_;
  ChangeWorkerOptions options_;
  Announce announce_;
  std::mutex mu_;
  std::condition_variable wake_;
  bool woken_[2] = {false, false};  ///< by Work
  std::mutex done_mu_;              ///< FinishIfDone's check and mark
  std::atomic<bool> stopping_{false};
  std::atomic<uint64_t> stretches_compared_{0};
  std::thread threads_[2];  ///< by Work
};

}  // namespace raillomer::server
