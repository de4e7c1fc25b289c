#include "server/change_worker.h"

#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#include <chrono>

#include <algorithm>
#include <cstdio>
#include <limits>
#include <map>
#include <set>

namespace raillomer::server {

using mapstore::DetectionState;
using mapstore::Outcome;
using mapstore::Result;

ChangeWorker::ChangeWorker(mapstore::MapStore* store,
                           mapstore::ChangeStore* changes,
                           mapstore::ProvisionalMap* provisional,
                           ChangeWorkerOptions options,
                           Announce announce)
    : store_(store),
      changes_(changes),
      provisional_(provisional),
      options_(std::move(options)),
      announce_(announce) {}

ChangeWorker::~ChangeWorker() { Stop(); }

void ChangeWorker::Start() {
  if (!options_.enabled || threads_[0].joinable()) return;
  for (Work work : {Work::kNew, Work::kAgain})
    threads_[static_cast<int>(work)] = std::thread([this, work] { Loop(work); });
}

void ChangeWorker::Stop() {
  stopping_ = true;
  Notify();
  for (std::thread& t : threads_)
    if (t.joinable()) t.join();
}

void ChangeWorker::Notify() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    woken_[0] = woken_[1] = true;
  }
  wake_.notify_all();
}

void ChangeWorker::Loop(Work work) {
  LowerPriority(work, false);
  bool& woken = woken_[static_cast<int>(work)];
  while (!stopping()) {
    if (Pass(work)) continue;  // more to do at once
    std::unique_lock<std::mutex> lock(mu_);
    wake_.wait_for(
        lock, std::chrono::milliseconds(options_.poll_ms), [&] { return woken || stopping(); });
    woken = false;
  }
}

Result ChangeWorker::Recompute(int64_t run, int64_t reference, DetectionState* out) {
  mapstore::RunInfo info;
  Result r = store_->GetRun(run, &info);
  if (!r) return r;
  if (reference == 0) {
    mapstore::LineInfo line;
    r = store_->GetLine(info.line, &line);
    if (!r) return r;
    if (line.reference_run == 0 || line.reference_run == run)
      return {Outcome::kConflict,
              "line '" + info.line + "' has no other finished run to compare run " +
                  std::to_string(run) + " with: name one with ?reference="};
    reference = line.reference_run;
  }
  std::unique_ptr<mapstore::RunComparison> comparison;
  r = mapstore::RunComparison::Prepare(*store_, reference, run, options_.comparison, &comparison);
  if (!r) return r;
  r = changes_->Request(run, reference, true, out);
  Notify();
  return r;
}

Result ChangeWorker::State(int64_t run, DetectionState* out, std::string* reason) const {
  reason->clear();
  Result r = changes_->Detection(run, out);
  if (r || r.outcome != Outcome::kNotFound) return r;
  mapstore::RunInfo info;
  mapstore::LineInfo line;
  r = store_->GetRun(run, &info);
  if (r) r = store_->GetLine(info.line, &line);
  if (!r) return r;
  *out = DetectionState();
  out->run_id = run;
  out->status = "pending";
  if (line.reference_run == run)
    *reason = "run " + std::to_string(run) + " is line '" + line.name +
              "''s reference: later runs are compared with it";
  else if (line.reference_run == 0)
    *reason = "line '" + line.name + "' has no finished run to compare with yet";
  else if (!options_.enabled)
    *reason = "this server does not detect changes (changes.enabled is false)";
  else
    out->reference_run = line.reference_run;
  return {};
}

bool ChangeWorker::Pass(Work work) {
  std::vector<DetectionState> states;
  if (!changes_->Detections(&states)) return false;
  bool more = false;
  std::map<int64_t, DetectionState> by_run;
  for (const DetectionState& s : states) by_run[s.run_id] = s;
  for (const mapstore::RunInfo& run : store_->ListRuns()) {
    if (stopping()) return false;
    auto found = by_run.find(run.id);
    if (found == by_run.end()) {
      if (work == Work::kAgain) continue;
      mapstore::LineInfo line;
      if (!store_->GetLine(run.line, &line) || line.reference_run == 0 ||
          line.reference_run == run.id)
        continue;
      DetectionState requested;
      if (!changes_->Request(run.id, line.reference_run, false, &requested)) continue;
      found = by_run.emplace(run.id, requested).first;
    }
    if (found->second.status == "done" || found->second.status == "failed") continue;
    more = Advance(run, found->second, work) || more;
  }
  return more;
}

bool ChangeWorker::Ready(const mapstore::RunInfo& run,
                         const mapstore::RunComparison& comparison,
                         const std::set<int>& stored,
                         const std::set<int>& provisional,
                         std::vector<Job>* ready,
                         std::vector<Job>* again) const {
  // A live run's stretch waits for the train to be past it and for its map (the stored
  // submaps, which trail the poses) to hold all its LiDARs saw of it: in its final output, or
  // failing that in its provisional output.
  const bool finished = run.status == "finished";
  int64_t mapped_ns = 0;
  if (!finished && !changes_->MappedUntil(run.id, &mapped_ns)) return false;
  // How far the train and the map reach: [0] on the final output, [1] with the provisional.
  const double infinity = std::numeric_limits<double>::infinity();
  double train[2] = {infinity, infinity}, mapped[2] = {infinity, infinity};
  if (!finished) {
    const int64_t until = std::max(mapped_ns, comparison.provisional_mapped_until());
    for (int p = 0; p < 2; ++p) {
      train[p] = comparison.later_reach_m(p == 1);
      mapped[p] = comparison.ReachUntil(p == 1 ? until : mapped_ns, p == 1);
    }
  }
  auto holds = [&](const mapstore::StretchRange& range, bool with_provisional) {
    return train[with_provisional] >= range.to_m + options_.past_m &&
           mapped[with_provisional] >= range.to_m + options_.mapped_past_m;
  };
  ready->clear();
  again->clear();
  bool waiting = false;
  for (const mapstore::StretchRange& range : comparison.stretches()) {
    const bool final = holds(range, false);
    if (stored.count(range.index)) {
      if (provisional.count(range.index) && final) again->push_back({range, false});
      continue;
    }
    if (waiting) continue;
    if (final || holds(range, true))
      ready->push_back({range, !final});
    else
      waiting = true;  // in order: the next stretch cannot be further along
  }
  return true;
}

Result ChangeWorker::PrepareComparison(const mapstore::RunInfo& run,
                                       int64_t reference,
                                       std::unique_ptr<mapstore::RunComparison>* out) const {
  mapstore::ProvisionalRun provisional;
  const bool live = run.status != "finished";
  const bool have = provisional_ && live && provisional_->Get(run.id, &provisional);
  return mapstore::RunComparison::Prepare(
      *store_, reference, run.id, options_.comparison, out, have ? &provisional : nullptr);
}

void ChangeWorker::CompareSideBySide(const mapstore::RunComparison& comparison,
                                     Work work,
                                     bool live,
                                     const std::vector<Job>& batch,
                                     std::vector<mapstore::StretchOutcome>* outcomes,
                                     std::vector<Result>* results) {
  outcomes->assign(batch.size(), mapstore::StretchOutcome());
  results->assign(batch.size(), Result());
  // Only the comparing itself may wait for idle CPU: flushing and storing take locks that
  // ingest and the API wait on.
  const bool idle = work == Work::kAgain && live;
  auto compare = [&](size_t i) {
    LowerPriority(work, idle);
    (*results)[i] = comparison.Compare(batch[i].range, &(*outcomes)[i], batch[i].provisional);
    LowerPriority(work, false);
  };
  std::vector<std::thread> workers;
  for (size_t i = 1; i < batch.size(); ++i) workers.emplace_back(compare, i);
  compare(0);
  for (std::thread& t : workers) t.join();
}

void ChangeWorker::LowerPriority(Work work, bool idle) {
  // Ingest and the API come first: comparing waits for the CPU they leave.
  const auto tid = static_cast<pid_t>(syscall(SYS_gettid));
  const sched_param none{};
  sched_setscheduler(tid, idle ? SCHED_IDLE : SCHED_OTHER, &none);
  setpriority(PRIO_PROCESS, static_cast<id_t>(tid), work == Work::kNew ? 5 : 10);
}

bool ChangeWorker::Store(int64_t run,
                         int64_t reference,
                         Result r,
                         const mapstore::StretchOutcome& outcome) {
  std::vector<mapstore::StoredChange> found, closed, withdrawn;
  if (r) r = changes_->SaveStretch(run, reference, outcome, &found, &closed, &withdrawn);
  if (!r) {
    std::fprintf(stderr,
                 "raillomer-server: change detection of run %lld, stretch %d: %s\n",
                 static_cast<long long>(run),
                 outcome.range.index,
                 r.message.c_str());
    return false;
  }
  if (r.outcome == Outcome::kDuplicate) return true;
  ++stretches_compared_;
  DetectionState now;
  if (changes_->Detection(run, &now)) announce_(found, closed, withdrawn, now);
  return true;
}

bool ChangeWorker::Advance(const mapstore::RunInfo& run, const DetectionState& state, Work work) {
  std::unique_ptr<mapstore::RunComparison> comparison;
  Result r = PrepareComparison(run, state.reference_run, &comparison);
  if (!r) {
    // A reference still live may finish; anything else will not mend itself.
    if (work == Work::kNew && r.outcome != Outcome::kConflict)
      changes_->SetStatus(run.id, "failed", r.message);
    return false;
  }
  std::set<int> stored, provisional;
  if (!changes_->StoredStretches(run.id, &stored, &provisional)) return false;
  std::vector<Job> ready, again;
  if (!Ready(run, *comparison, stored, provisional, &ready, &again)) return false;
  const size_t threads = static_cast<size_t>(std::max(1, options_.threads));
  bool more = false;
  if (work == Work::kAgain) {
    // One batch, then a fresh look: the final output may reach further by then.
    more = again.size() > threads;
    if (more) again.resize(threads);
    ready.swap(again);
  }
  if (!ready.empty()) store_->Flush();  // the stretches' tiles as received so far
  const bool live = run.status != "finished";
  for (size_t first = 0; first < ready.size() && !stopping(); first += threads) {
    const std::vector<Job> batch(ready.begin() + first,
                                 ready.begin() + std::min(ready.size(), first + threads));
    std::vector<mapstore::StretchOutcome> outcomes;
    std::vector<Result> results;
    CompareSideBySide(*comparison, work, live, batch, &outcomes, &results);
    for (size_t i = 0; i < batch.size(); ++i)
      if (!Store(run.id, state.reference_run, results[i], outcomes[i])) return false;
  }
  if (run.status == "finished") FinishIfDone(run, comparison->stretches().size());
  return more;
}

void ChangeWorker::FinishIfDone(const mapstore::RunInfo& run, size_t stretches) {
  std::lock_guard<std::mutex> lock(done_mu_);
  DetectionState now;
  std::set<int> stored, provisional;
  if (!changes_->Detection(run.id, &now) || now.status == "done" || now.status == "failed" ||
      !changes_->StoredStretches(run.id, &stored, &provisional))
    return;
  if (!provisional.empty() || stored.size() < stretches) return;
  std::vector<mapstore::StoredChange> withdrawn;
  if (!changes_->Finish(run.id, now.requested_ns, &withdrawn)) return;
  if (changes_->Detection(run.id, &now)) announce_({}, {}, withdrawn, now);
}

}  // namespace raillomer::server
