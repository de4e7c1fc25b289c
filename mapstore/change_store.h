#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "mapstore/run_comparison.h"

namespace raillomer::mapstore {

class Database;
class Statement;

/// The statuses engineers give a change; `closed` is set by a later run that no longer sees a
/// change marked `fixed`.
bool IsChangeStatus(const std::string& status, bool settable_only);

/// A change as stored: what detection found, and what engineers made of it.
struct StoredChange {
  int64_t id = 0;
  int64_t run_id = 0, reference_run = 0;
  std::string line;
  RunChange change;
  std::string status = "new", note;
  int64_t closed_by_run = 0;  ///< the run that no longer saw it (status `closed`)
  int64_t created_ns = 0, updated_ns = 0;
  /// Found on the run's provisional output: its stretch is compared again on the final one.
  bool provisional = false;
  /// The same change found by an earlier run of the line (0: none), and the run that found it
  /// first (this run when none did before).
  int64_t earlier_change = 0, first_seen_run = 0;
};

/// A run's comparison with its reference: requested, running (stretches stored as they are
/// compared), done (the run finished and every stretch stored) or failed (`error` says why).
struct DetectionState {
  int64_t run_id = 0, reference_run = 0;
  std::string status, error;
  int stretches_done = 0, stretches_compared = 0;
  int stretches_provisional = 0;    ///< of stretches_done, compared on provisional output
  double km = 0.0;                  ///< compared
  double registration_rms_m = 0.0;  ///< over the compared stretches
  /// The rail heads' height differences over the compared stretches (NaN: rails not seen).
  double rail_rms_m = std::numeric_limits<double>::quiet_NaN();
  double compared_to_m = -std::numeric_limits<double>::infinity();  ///< furthest stretch end
  double seconds = 0.0;                                             ///< spent comparing
  int64_t requested_ns = 0, updated_ns = 0;
};

/// Which changes of a run to list.
struct ChangeFilter {
  double from_m = -std::numeric_limits<double>::infinity();
  double to_m = std::numeric_limits<double>::infinity();
  std::optional<ChangeKind> kind;
  std::optional<bool> intrudes;
  double min_size_m = 0.0;            ///< the largest of along, across, height at least this
  std::vector<std::string> statuses;  ///< any of these (every status when empty)
};

/// A compared stretch's registration, for drawing the later run where the comparison put it.
struct StretchFrame {
  int stretch = 0;
  double from_m = 0.0, to_m = 0.0;  ///< chainage the stretch covers
  double rms_m = 0.0;               ///< the registration's RMS residual
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Isometry3d T_reference_later = Eigen::Isometry3d::Identity();
};

/// Change detection's records in the store's index (its own connection): each run's
/// detection state, its compared stretches and the changes found. A stretch and its changes
/// are stored in one transaction and a stretch stored once, so a detection interrupted
/// anywhere resumes at the first stretch without a row: no change is lost or stored twice.
class ChangeStore {
 public:
  /// Opens the index of an open store (its schema already migrated).
  static std::unique_ptr<ChangeStore> Open(const std::string& index_path, std::string* error);
  ~ChangeStore();
  ChangeStore(const ChangeStore&) = delete;
  ChangeStore& operator=(const ChangeStore&) = delete;

  /// Asks for `run` to be compared with `reference`: a new detection, or (`restart`, or another
  /// reference than the stored one) the run's stored stretches dropped and its changes marked
  /// to be checked again: a stretch compared on final output takes over those it finds again
  /// (SaveStretch) and withdraws the rest; they are listed as they were meanwhile.
  Result Request(int64_t run, int64_t reference, bool restart, DetectionState* out);
  Result Detection(int64_t run, DetectionState* out) const;  ///< kNotFound if never requested
  Result Detections(std::vector<DetectionState>* out) const;
  /// The run's stored stretches; `provisional` (if given) gets those compared on provisional
  /// output.
  Result StoredStretches(int64_t run,
                         std::set<int>* out,
                         std::set<int>* provisional = nullptr) const;
  /// Stores a compared (or skipped) stretch with its changes; `stored` gets them with their
  /// ids. A stretch already stored is a kDuplicate (nothing stored), unless it was stored
  /// provisional and this outcome is not: then the outcome replaces it. A change of the same
  /// kind within 2 m keeps its id, status and note; the provisional changes not found again,
  /// and on a final outcome the earlier comparison's left to be checked again (Request), are
  /// deleted (`withdrawn` gets them). A
  /// detection requested meanwhile against another reference is a kConflict. A final outcome closes
  /// changes of earlier runs of the line marked `fixed` in the stretch and not seen again within 2
  /// m (`closed` gets them). A new change of the kind of an earlier run's (not closed) within 2 m
  /// continues it: it takes its note and status (`new` again if it was `fixed`) and its first run.
  Result SaveStretch(int64_t run,
                     int64_t reference,
                     const StretchOutcome& outcome,
                     std::vector<StoredChange>* stored,
                     std::vector<StoredChange>* closed,
                     std::vector<StoredChange>* withdrawn = nullptr);
  Result SetStatus(int64_t run, const std::string& status, const std::string& error);
  /// Marks the run's detection done, withdrawing the changes of an earlier comparison that no
  /// stretch of this one checked again (`withdrawn` gets them). A kConflict, changing nothing,
  /// if the detection was requested again since `requested_ns` (DetectionState) or still has
  /// stretches compared on provisional output only.
  Result Finish(int64_t run, int64_t requested_ns, std::vector<StoredChange>* withdrawn);

  Result List(int64_t run, const ChangeFilter& filter, std::vector<StoredChange>* out) const;
  Result Get(int64_t id, StoredChange* out) const;
  /// Sets a change's status (IsChangeStatus settable), its note, or both; what is not given
  /// stays as it is (a closed change keeps its status under a new note).
  Result Update(int64_t id,
                const std::optional<std::string>& status,
                const std::optional<std::string>& note,
                StoredChange* out);
  Result Frame(int64_t run, int stretch, StretchFrame* out) const;
  /// Every compared stretch's registration of the run, in chainage order.
  Result Frames(int64_t run, std::vector<StretchFrame>* out) const;
  /// The last stamp of the run's stored submaps (what its map holds up to); 0 with none.
  Result MappedUntil(int64_t run, int64_t* stamp_ns) const;

 private:
  ChangeStore();
  Result DetectionLocked(int64_t run, DetectionState* out) const;
  Result InsertStretchLocked(int64_t run,
                             int64_t reference,
                             const StretchOutcome& outcome,
                             int64_t now);
  /// Inserts a change (its run, reference, line and stamps set); its id is set.
  Result InsertChangeLocked(StoredChange* change);
  /// Stores what detection measured of a change again, under its id.
  Result UpdateChangeLocked(const StoredChange& change);
  /// Deletes the stretch's row (the caller knows it is absent or provisional); `provisional`
  /// gets, oldest first, the stretch's provisional changes and, if `rechecked` (a final
  /// outcome), the changes an earlier comparison left to be checked again (Request).
  Result TakeProvisionalLocked(int64_t run,
                               int stretch,
                               bool rechecked,
                               std::vector<StoredChange>* provisional);
  /// Deletes the changes; one that a later change continued hands that on to what it continued.
  Result WithdrawLocked(const std::vector<StoredChange>& gone);
  /// Stores each change of the outcome: as an update of a provisional one of its kind within
  /// 2 m (which leaves `provisional`), else as a new one, continuing an earlier run's.
  Result StoreChangesLocked(const StoredChange& base,
                            const StretchOutcome& outcome,
                            std::vector<StoredChange>* provisional,
                            std::vector<StoredChange>* stored);
  /// The latest change of an earlier run of the line (final, not closed) of `c`'s kind within
  /// 2 m of it; its id is 0 if there is none.
  Result EarlierChangeLocked(const StoredChange& c, StoredChange* out) const;
  /// Makes `c` continue an earlier run's change of the same place, if there is one.
  Result ContinueEarlierLocked(StoredChange* c) const;
  Result CloseFixedLocked(int64_t run,
                          const StretchRange& range,
                          const std::vector<StoredChange>& seen,
                          std::vector<StoredChange>* closed);
  Result ListWhere(const std::string& where,
                   const std::function<void(Statement&)>& bind,
                   std::vector<StoredChange>* out) const;

  mutable std::mutex mu_;
  std::unique_ptr<Database> db_;
};

}  // namespace raillomer::mapstore
