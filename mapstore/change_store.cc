#include "mapstore/change_store.h"

#include <algorithm>
#include <chrono>
#include <cmath>

#include <nlohmann/json.hpp>

#include "api/clock.h"
#include "mapstore/sqlite.h"

namespace raillomer::mapstore {
namespace {

using nlohmann::json;

Result Fail(Outcome outcome, std::string message) { return {outcome, std::move(message)}; }
Result DbError(const std::string& what, const std::string& message) {
  return Fail(Outcome::kError, what + ": " + message);
}

using api::NowNs;

/// Two reports lie this close (horizontally) when they are the same thing seen again.
constexpr double kSameChangeM = 2.0;

json Vec(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }
Eigen::Vector3d VecOf(const json& j) {
  return Eigen::Vector3d(j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>());
}
/// Infinity (nothing in a zone) has no JSON number: null.
json Finite(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }
double FiniteOf(const json& j) {
  return j.is_null() ? std::numeric_limits<double>::infinity() : j.get<double>();
}

/// What detection measured of a change, kept as one JSON text.
std::string PropertiesOf(const RunChange& c) {
  json footprint = json::array();
  for (const Eigen::Vector2d& p : c.footprint_utm) footprint.push_back({p.x(), p.y()});
  return json{{"size_m", Vec(c.size_m)},
              {"height_above_rail_m", {c.height_above_rail_min_m, c.height_above_rail_max_m}},
              {"margin_m", Finite(c.margin_m)},
              {"vegetation_margin_m", Finite(c.vegetation_margin_m)},
              {"lod_m", c.lod_m},
              {"confidence", c.confidence},
              {"seen_empty_share", c.seen_empty_share},
              {"voxels", c.voxels},
              {"points", {c.points_reference, c.points_later}},
              {"footprint_utm", footprint},
              {"moved_from_utm", Vec(c.moved_from_utm)},
              {"moved_m", c.moved_m},
              {"offset_range_m", {c.offset_from_m, c.offset_to_m}}}
      .dump();
}

void ReadProperties(const std::string& text, RunChange* c) {
  const json j = json::parse(text, nullptr, false);
  if (j.is_discarded()) return;
  c->size_m = VecOf(j.at("size_m"));
  c->height_above_rail_min_m = j.at("height_above_rail_m").at(0);
  c->height_above_rail_max_m = j.at("height_above_rail_m").at(1);
  c->margin_m = FiniteOf(j.at("margin_m"));
  c->vegetation_margin_m = FiniteOf(j.at("vegetation_margin_m"));
  c->lod_m = j.at("lod_m");
  c->confidence = j.at("confidence");
  c->seen_empty_share = j.at("seen_empty_share");
  c->voxels = j.at("voxels");
  c->points_reference = j.at("points").at(0);
  c->points_later = j.at("points").at(1);
  for (const json& p : j.at("footprint_utm"))
    c->footprint_utm.emplace_back(p.at(0).get<double>(), p.at(1).get<double>());
  c->moved_from_utm = VecOf(j.at("moved_from_utm"));
  c->moved_m = j.at("moved_m");
  // Changes stored before the range was kept: the size across, around the centre.
  const json range =
      j.value("offset_range_m",
              json::array({c->offset_m - 0.5 * c->size_m.y(), c->offset_m + 0.5 * c->size_m.y()}));
  c->offset_from_m = range.at(0);
  c->offset_to_m = range.at(1);
}

constexpr const char* kChangeColumns =
    "id, run_id, reference_run, stretch, line, kind, chainage_m, offset_m, utm_zone, x, y, z, "
    "properties, intrudes, status, note, IFNULL(closed_by_run, 0), created_ns, updated_ns, "
    "provisional, IFNULL(earlier_change, 0), IFNULL(first_seen_run, run_id)";

StoredChange ChangeOf(const Statement& q) {
  StoredChange s;
  s.id = q.Int(0);
  s.run_id = q.Int(1);
  s.reference_run = q.Int(2);
  s.change.stretch = static_cast<int>(q.Int(3));
  s.line = q.Text(4);
  ParseChangeKind(q.Text(5), &s.change.kind);
  s.change.chainage_m = q.Double(6);
  s.change.offset_m = q.Double(7);
  s.change.utm_zone = q.Text(8);
  s.change.centre_utm = Eigen::Vector3d(q.Double(9), q.Double(10), q.Double(11));
  ReadProperties(q.Text(12), &s.change);
  s.change.intrudes_envelope = q.Int(13) != 0;
  s.status = q.Text(14);
  s.note = q.Text(15);
  s.closed_by_run = q.Int(16);
  s.created_ns = q.Int(17);
  s.updated_ns = q.Int(18);
  s.provisional = q.Int(19) != 0;
  s.earlier_change = q.Int(20);
  s.first_seen_run = q.Int(21);
  return s;
}

std::string TransformText(const StretchOutcome& o) {
  json m = json::array();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) m.push_back(o.T_reference_later.matrix()(r, c));
  return json{{"origin", Vec(o.origin)}, {"T", m}}.dump();
}

/// Binds what detection measured of a change, from `first` on: chainage, offset, the centre's
/// x, y, z, the other properties, intrusion, largest size, provisional.
Statement& BindMeasured(Statement& q, int first, const StoredChange& s) {
  const RunChange& c = s.change;
  return q.Bind(first, c.chainage_m)
      .Bind(first + 1, c.offset_m)
      .Bind(first + 2, c.centre_utm.x())
      .Bind(first + 3, c.centre_utm.y())
      .Bind(first + 4, c.centre_utm.z())
      .Bind(first + 5, PropertiesOf(c))
      .Bind(first + 6, c.intrudes_envelope ? 1 : 0)
      .Bind(first + 7, c.size_m.maxCoeff())
      .Bind(first + 8, s.provisional ? 1 : 0);
}

}  // namespace

bool IsChangeStatus(const std::string& status, bool settable_only) {
  for (const char* s : {"new", "confirmed", "dismissed", "fixed"})
    if (status == s) return true;
  return !settable_only && status == "closed";
}

ChangeStore::ChangeStore() : db_(std::make_unique<Database>()) {}
ChangeStore::~ChangeStore() = default;

std::unique_ptr<ChangeStore> ChangeStore::Open(const std::string& index_path, std::string* error) {
  std::unique_ptr<ChangeStore> store(new ChangeStore());
  if (!store->db_->Open(index_path, false, error)) return nullptr;
  return store;
}

Result ChangeStore::Request(int64_t run, int64_t reference, bool restart, DetectionState* out) {
  std::lock_guard<std::mutex> lock(mu_);
  DetectionState found;
  const Result r = DetectionLocked(run, &found);
  if (r && !restart && found.reference_run == reference) {
    if (out) *out = found;
    return {Outcome::kDuplicate, ""};
  }
  Transaction t(*db_);
  if (!t.ok()) return DbError("cannot begin", db_->Message());
  const int64_t now = NowNs();
  // The earlier comparison's changes stay, marked to be checked again: each stretch compared
  // anew on final output takes over those it finds again (their ids, statuses and notes) and
  // withdraws the rest; Finish withdraws those of stretches not compared again.
  Statement recheck_changes(*db_, "UPDATE changes SET rechecking = 1 WHERE run_id = ?");
  Statement drop_stretches(*db_, "DELETE FROM change_stretches WHERE run_id = ?");
  Statement set(*db_,
                "INSERT INTO change_detection (run_id, reference_run, status, error, "
                "requested_ns, updated_ns) VALUES (?, ?, 'pending', '', ?, ?) "
                "ON CONFLICT (run_id) DO UPDATE SET reference_run = excluded.reference_run, "
                "status = 'pending', error = '', requested_ns = excluded.requested_ns, "
                "updated_ns = excluded.updated_ns");
  std::string error;
  if (!recheck_changes.Bind(1, run).Run() || !drop_stretches.Bind(1, run).Run() ||
      !set.Bind(1, run).Bind(2, reference).Bind(3, now).Bind(4, now).Run() || !t.Commit(&error))
    return DbError("cannot store the detection request", db_->Message() + error);
  return out ? DetectionLocked(run, out) : Result{};
}

Result ChangeStore::DetectionLocked(int64_t run, DetectionState* out) const {
  Statement q(*db_,
              "SELECT d.reference_run, d.status, d.error, d.requested_ns, d.updated_ns, "
              "(SELECT count(*) FROM change_stretches s WHERE s.run_id = d.run_id), "
              "(SELECT count(*) FROM change_stretches s WHERE s.run_id = d.run_id AND compared), "
              "(SELECT IFNULL(SUM(to_m - from_m), 0) FROM change_stretches s "
              " WHERE s.run_id = d.run_id AND compared), "
              "(SELECT IFNULL(AVG(rms_m * rms_m), 0) FROM change_stretches s "
              " WHERE s.run_id = d.run_id AND compared), "
              "(SELECT MAX(to_m) FROM change_stretches s WHERE s.run_id = d.run_id), "
              "(SELECT IFNULL(SUM(seconds), 0) FROM change_stretches s WHERE s.run_id = d.run_id), "
              "(SELECT AVG(rail_rms_m * rail_rms_m) FROM change_stretches s "
              " WHERE s.run_id = d.run_id AND compared AND rail_rms_m IS NOT NULL), "
              "(SELECT count(*) FROM change_stretches s WHERE s.run_id = d.run_id AND provisional) "
              "FROM change_detection d WHERE d.run_id = ?");
  q.Bind(1, run);
  if (!q.Step()) {
    if (!q.error().empty()) return DbError("cannot read the detection", q.error());
    return Fail(Outcome::kNotFound, "no change detection for run " + std::to_string(run));
  }
  out->run_id = run;
  out->reference_run = q.Int(0);
  out->status = q.Text(1);
  out->error = q.Text(2);
  out->requested_ns = q.Int(3);
  out->updated_ns = q.Int(4);
  out->stretches_done = static_cast<int>(q.Int(5));
  out->stretches_compared = static_cast<int>(q.Int(6));
  out->km = q.Double(7) / 1000.0;
  out->registration_rms_m = std::sqrt(q.Double(8));
  out->compared_to_m = q.IsNull(9) ? -std::numeric_limits<double>::infinity() : q.Double(9);
  out->seconds = q.Double(10);
  out->rail_rms_m =
      q.IsNull(11) ? std::numeric_limits<double>::quiet_NaN() : std::sqrt(q.Double(11));
  out->stretches_provisional = static_cast<int>(q.Int(12));
  return {};
}

Result ChangeStore::Detection(int64_t run, DetectionState* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  return DetectionLocked(run, out);
}

Result ChangeStore::Detections(std::vector<DetectionState>* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  out->clear();
  std::vector<int64_t> runs;
  {
    Statement q(*db_, "SELECT run_id FROM change_detection ORDER BY run_id");
    while (q.Step()) runs.push_back(q.Int(0));
    if (!q.error().empty()) return DbError("cannot list detections", q.error());
  }
  for (int64_t run : runs) {
    out->emplace_back();
    const Result r = DetectionLocked(run, &out->back());
    if (!r) return r;
  }
  return {};
}

Result ChangeStore::StoredStretches(int64_t run,
                                    std::set<int>* out,
                                    std::set<int>* provisional) const {
  std::lock_guard<std::mutex> lock(mu_);
  out->clear();
  if (provisional) provisional->clear();
  Statement q(*db_, "SELECT stretch, provisional FROM change_stretches WHERE run_id = ?");
  q.Bind(1, run);
  while (q.Step()) {
    out->insert(static_cast<int>(q.Int(0)));
    if (provisional && q.Int(1) != 0) provisional->insert(static_cast<int>(q.Int(0)));
  }
  if (!q.error().empty()) return DbError("cannot list stretches", q.error());
  return {};
}

Result ChangeStore::SaveStretch(int64_t run,
                                int64_t reference,
                                const StretchOutcome& o,
                                std::vector<StoredChange>* stored,
                                std::vector<StoredChange>* closed,
                                std::vector<StoredChange>* withdrawn) {
  std::lock_guard<std::mutex> lock(mu_);
  stored->clear();
  closed->clear();
  std::vector<StoredChange> provisional;
  Transaction t(*db_);
  if (!t.ok()) return DbError("cannot begin", db_->Message());
  DetectionState state;
  Result r = DetectionLocked(run, &state);
  if (!r) return r;
  if (state.reference_run != reference)
    return Fail(Outcome::kConflict, "the run is now compared with another reference");
  Statement seen(*db_, "SELECT provisional FROM change_stretches WHERE run_id = ? AND stretch = ?");
  if (seen.Bind(1, run).Bind(2, o.range.index).Step() && (seen.Int(0) == 0 || o.provisional))
    return {Outcome::kDuplicate, ""};
  r = TakeProvisionalLocked(run, o.range.index, !o.provisional, &provisional);
  if (!r) return r;
  StoredChange base;
  base.run_id = run;
  base.reference_run = reference;
  {
    Statement q(*db_, "SELECT line FROM runs WHERE id = ?");
    if (!q.Bind(1, run).Step()) return DbError("cannot read the run", q.error());
    base.line = q.Text(0);
  }
  base.created_ns = base.updated_ns = NowNs();
  r = InsertStretchLocked(run, reference, o, base.created_ns);
  if (r) r = StoreChangesLocked(base, o, &provisional, stored);
  if (r) r = WithdrawLocked(provisional);
  if (r && !o.provisional) r = CloseFixedLocked(run, o.range, *stored, closed);
  if (!r) return r;
  const int64_t now = base.created_ns;
  Statement touch(*db_,
                  "UPDATE change_detection SET status = 'running', updated_ns = ? "
                  "WHERE run_id = ? AND status = 'pending'");
  std::string error;
  if (!touch.Bind(1, now).Bind(2, run).Run() || !t.Commit(&error))
    return DbError("cannot commit the stretch", touch.error() + error);
  if (withdrawn) *withdrawn = std::move(provisional);
  return {};
}

Result ChangeStore::TakeProvisionalLocked(int64_t run,
                                          int stretch,
                                          bool rechecked,
                                          std::vector<StoredChange>* provisional) {
  // Oldest first: where two would match a change found again, the older one (an earlier
  // comparison's, with what engineers set) is taken over.
  Result r = ListWhere(
      std::string("run_id = ? AND stretch = ? AND ((provisional = 1 AND rechecking = 0)") +
          (rechecked ? " OR rechecking = 1" : "") + ") ORDER BY id",
      [&](Statement& q) { q.Bind(1, run).Bind(2, stretch); },
      provisional);
  if (!r) return r;
  Statement drop(*db_, "DELETE FROM change_stretches WHERE run_id = ? AND stretch = ?");
  if (!drop.Bind(1, run).Bind(2, stretch).Run())
    return DbError("cannot replace a provisional stretch", drop.error());
  return {};
}

Result ChangeStore::StoreChangesLocked(const StoredChange& base,
                                       const StretchOutcome& o,
                                       std::vector<StoredChange>* provisional,
                                       std::vector<StoredChange>* stored) {
  for (const RunChange& found : o.changes) {
    StoredChange c = base;
    c.change = found;
    c.change.stretch = o.range.index;
    c.provisional = o.provisional;
    auto same = std::find_if(provisional->begin(), provisional->end(), [&](const StoredChange& p) {
      return p.change.kind == found.kind &&
             (p.change.centre_utm - found.centre_utm).head<2>().norm() < kSameChangeM;
    });
    Result r;
    if (same != provisional->end()) {
      c.id = same->id;
      c.status = same->status;
      c.note = same->note;
      c.created_ns = same->created_ns;
      c.earlier_change = same->earlier_change;
      c.first_seen_run = same->first_seen_run;
      provisional->erase(same);
      r = UpdateChangeLocked(c);
    } else {
      r = ContinueEarlierLocked(&c);
      if (r) r = InsertChangeLocked(&c);
    }
    if (!r) return r;
    stored->push_back(std::move(c));
  }
  return {};
}

Result ChangeStore::UpdateChangeLocked(const StoredChange& s) {
  Statement set(*db_,
                "UPDATE changes SET chainage_m = ?, offset_m = ?, x = ?, y = ?, z = ?, "
                "properties = ?, intrudes = ?, size_max_m = ?, provisional = ?, updated_ns = ?, "
                "reference_run = ?, rechecking = 0 WHERE id = ?");
  if (!BindMeasured(set, 1, s)
           .Bind(10, s.updated_ns)
           .Bind(11, s.reference_run)
           .Bind(12, s.id)
           .Run())
    return DbError("cannot store a change again", set.error());
  return {};
}

Result ChangeStore::InsertStretchLocked(int64_t run,
                                        int64_t reference,
                                        const StretchOutcome& o,
                                        int64_t now) {
  Statement add(*db_,
                "INSERT INTO change_stretches (run_id, stretch, reference_run, from_m, to_m, "
                "compared, rms_m, rail_rms_m, transform, seconds, done_ns, provisional) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  add.Bind(1, run)
      .Bind(2, o.range.index)
      .Bind(3, reference)
      .Bind(4, o.range.from_m)
      .Bind(5, o.range.to_m)
      .Bind(6, o.compared ? 1 : 0)
      .Bind(7, o.registration_rms_m);
  if (std::isnan(o.rail_rms_m))
    add.BindNull(8);
  else
    add.Bind(8, o.rail_rms_m);
  if (!add.Bind(9, TransformText(o))
           .Bind(10, o.seconds)
           .Bind(11, now)
           .Bind(12, o.provisional ? 1 : 0)
           .Run())
    return DbError("cannot store the stretch", add.error());
  return {};
}

Result ChangeStore::EarlierChangeLocked(const StoredChange& c, StoredChange* out) const {
  *out = StoredChange();
  const Eigen::Vector3d& at = c.change.centre_utm;
  Statement q(*db_,
              std::string("SELECT ") + kChangeColumns +
                  " FROM changes WHERE line = ? AND kind = ? AND utm_zone = ? AND run_id < ? AND "
                  "status != 'closed' AND provisional = 0 AND x BETWEEN ? AND ? AND "
                  "y BETWEEN ? AND ? ORDER BY run_id DESC, id");
  q.Bind(1, c.line)
      .Bind(2, ToString(c.change.kind))
      .Bind(3, c.change.utm_zone)
      .Bind(4, c.run_id)
      .Bind(5, at.x() - kSameChangeM)
      .Bind(6, at.x() + kSameChangeM)
      .Bind(7, at.y() - kSameChangeM)
      .Bind(8, at.y() + kSameChangeM);
  double nearest = kSameChangeM;
  while (q.Step()) {
    StoredChange e = ChangeOf(q);
    if (out->id != 0 && e.run_id != out->run_id) break;  // the latest run's only
    const double d = (e.change.centre_utm - at).head<2>().norm();
    if (d < nearest) nearest = d, *out = std::move(e);
  }
  if (!q.error().empty()) return DbError("cannot read earlier changes", q.error());
  return {};
}

Result ChangeStore::ContinueEarlierLocked(StoredChange* c) const {
  c->first_seen_run = c->run_id;
  StoredChange earlier;
  const Result r = EarlierChangeLocked(*c, &earlier);
  if (!r || earlier.id == 0) return r;
  c->earlier_change = earlier.id;
  c->first_seen_run = earlier.first_seen_run;
  c->status = earlier.status == "fixed" ? "new" : earlier.status;
  c->note = earlier.note;
  return {};
}

Result ChangeStore::InsertChangeLocked(StoredChange* s) {
  Statement add(*db_,
                "INSERT INTO changes (run_id, reference_run, stretch, line, kind, utm_zone, "
                "chainage_m, offset_m, x, y, z, properties, intrudes, size_max_m, provisional, "
                "created_ns, updated_ns, status, note, earlier_change, first_seen_run) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  BindMeasured(add.Bind(1, s->run_id)
                   .Bind(2, s->reference_run)
                   .Bind(3, s->change.stretch)
                   .Bind(4, s->line)
                   .Bind(5, ToString(s->change.kind))
                   .Bind(6, s->change.utm_zone),
               7,
               *s)
      .Bind(16, s->created_ns)
      .Bind(17, s->updated_ns)
      .Bind(18, s->status)
      .Bind(19, s->note)
      .Bind(21, s->first_seen_run);
  if (s->earlier_change != 0)
    add.Bind(20, s->earlier_change);
  else
    add.BindNull(20);
  if (!add.Run()) return DbError("cannot store a change", add.error());
  s->id = db_->LastInsertId();
  return {};
}

Result ChangeStore::CloseFixedLocked(int64_t run,
                                     const StretchRange& range,
                                     const std::vector<StoredChange>& seen,
                                     std::vector<StoredChange>* closed) {
  std::vector<StoredChange> fixed;
  Statement q(*db_,
              std::string("SELECT ") + kChangeColumns +
                  " FROM changes WHERE status = 'fixed' AND run_id < ? AND chainage_m >= ? AND "
                  "chainage_m < ? AND line = (SELECT line FROM runs WHERE id = ?)");
  q.Bind(1, run).Bind(2, range.from_m).Bind(3, range.to_m).Bind(4, run);
  while (q.Step()) fixed.push_back(ChangeOf(q));
  if (!q.error().empty()) return DbError("cannot read fixed changes", q.error());
  Statement close(*db_,
                  "UPDATE changes SET status = 'closed', closed_by_run = ?, updated_ns = ? "
                  "WHERE id = ?");
  for (StoredChange& f : fixed) {
    const bool again = std::any_of(seen.begin(), seen.end(), [&](const StoredChange& s) {
      return (s.change.centre_utm - f.change.centre_utm).head<2>().norm() < kSameChangeM;
    });
    if (again) continue;
    f.status = "closed";
    f.closed_by_run = run;
    f.updated_ns = NowNs();
    close.Reset();
    if (!close.Bind(1, run).Bind(2, f.updated_ns).Bind(3, f.id).Run())
      return DbError("cannot close a fixed change", close.error());
    closed->push_back(std::move(f));
  }
  return {};
}

Result ChangeStore::WithdrawLocked(const std::vector<StoredChange>& gone) {
  Statement drop(*db_, "DELETE FROM changes WHERE id = ?");
  Statement relink(*db_, "UPDATE changes SET earlier_change = ? WHERE earlier_change = ?");
  for (const StoredChange& c : gone) {
    drop.Reset();
    relink.Reset();
    // A later change that continued it continues what it continued (its first run stays).
    if (c.earlier_change != 0)
      relink.Bind(1, c.earlier_change);
    else
      relink.BindNull(1);
    if (!drop.Bind(1, c.id).Run() || !relink.Bind(2, c.id).Run())
      return DbError("cannot withdraw a change", drop.error() + relink.error());
  }
  return {};
}

Result ChangeStore::Finish(int64_t run,
                           int64_t requested_ns,
                           std::vector<StoredChange>* withdrawn) {
  std::lock_guard<std::mutex> lock(mu_);
  Transaction t(*db_);
  if (!t.ok()) return DbError("cannot begin", db_->Message());
  // Requested again since the caller looked (its stretches dropped): not this one's to finish.
  DetectionState state;
  Result r = DetectionLocked(run, &state);
  if (!r) return r;
  if (state.requested_ns != requested_ns || state.stretches_provisional > 0)
    return Fail(Outcome::kConflict, "the detection was requested again, or is not final yet");
  std::vector<StoredChange> stale;
  r = ListWhere(
      "run_id = ? AND rechecking = 1", [&](Statement& q) { q.Bind(1, run); }, &stale);
  if (r) r = WithdrawLocked(stale);
  if (!r) return r;
  Statement done(*db_,
                 "UPDATE change_detection SET status = 'done', error = '', updated_ns = ? "
                 "WHERE run_id = ?");
  std::string error;
  if (!done.Bind(1, NowNs()).Bind(2, run).Run() || !t.Commit(&error))
    return DbError("cannot finish the detection", done.error() + error);
  if (withdrawn) *withdrawn = std::move(stale);
  return {};
}

Result ChangeStore::SetStatus(int64_t run, const std::string& status, const std::string& error) {
  std::lock_guard<std::mutex> lock(mu_);
  Statement q(*db_,
              "UPDATE change_detection SET status = ?, error = ?, updated_ns = ? WHERE run_id = ?");
  if (!q.Bind(1, status).Bind(2, error).Bind(3, NowNs()).Bind(4, run).Run())
    return DbError("cannot set the detection's status", q.error());
  return {};
}

Result ChangeStore::ListWhere(const std::string& where,
                              const std::function<void(Statement&)>& bind,
                              std::vector<StoredChange>* out) const {
  out->clear();
  Statement q(*db_, std::string("SELECT ") + kChangeColumns + " FROM changes WHERE " + where);
  bind(q);
  while (q.Step()) out->push_back(ChangeOf(q));
  if (!q.error().empty()) return DbError("cannot list changes", q.error());
  return {};
}

Result ChangeStore::List(int64_t run, const ChangeFilter& f, std::vector<StoredChange>* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  std::string where = "run_id = ? AND chainage_m >= ? AND chainage_m <= ? AND size_max_m >= ?";
  if (f.kind) where += " AND kind = ?";
  if (f.intrudes) where += " AND intrudes = ?";
  if (!f.statuses.empty()) {
    where += " AND status IN (?";
    for (size_t i = 1; i < f.statuses.size(); ++i) where += ", ?";
    where += ")";
  }
  where += " ORDER BY chainage_m, id";
  // SQLite binds no infinities: the line's chainage is far inside these.
  const double far = 1e12;
  return ListWhere(
      where,
      [&](Statement& q) {
        q.Bind(1, run)
            .Bind(2, std::max(f.from_m, -far))
            .Bind(3, std::min(f.to_m, far))
            .Bind(4, f.min_size_m);
        int next = 5;
        if (f.kind) q.Bind(next++, ToString(*f.kind));
        if (f.intrudes) q.Bind(next++, *f.intrudes ? 1 : 0);
        for (const std::string& status : f.statuses) q.Bind(next++, status);
      },
      out);
}

Result ChangeStore::Get(int64_t id, StoredChange* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<StoredChange> found;
  const Result r = ListWhere(
      "id = ?", [&](Statement& q) { q.Bind(1, id); }, &found);
  if (!r) return r;
  if (found.empty()) return Fail(Outcome::kNotFound, "no change " + std::to_string(id));
  *out = std::move(found.front());
  return {};
}

Result ChangeStore::Update(int64_t id,
                           const std::optional<std::string>& status,
                           const std::optional<std::string>& note,
                           StoredChange* out) {
  if (status && !IsChangeStatus(*status, true))
    return Fail(Outcome::kInvalid,
                "status must be new, confirmed, dismissed or fixed (got '" + *status + "')");
  {
    // One statement: a note alone leaves the status (closed too) as it is then.
    std::lock_guard<std::mutex> lock(mu_);
    Statement q(*db_,
                "UPDATE changes SET status = IFNULL(?1, status), note = IFNULL(?2, note), "
                "closed_by_run = CASE WHEN ?1 IS NULL THEN closed_by_run END, updated_ns = ?3 "
                "WHERE id = ?4");
    if (status)
      q.Bind(1, *status);
    else
      q.BindNull(1);
    if (note)
      q.Bind(2, *note);
    else
      q.BindNull(2);
    if (!q.Bind(3, NowNs()).Bind(4, id).Run()) return DbError("cannot update", q.error());
    if (db_->Changes() == 0) return Fail(Outcome::kNotFound, "no change " + std::to_string(id));
  }
  return Get(id, out);
}

Result ChangeStore::MappedUntil(int64_t run, int64_t* stamp_ns) const {
  std::lock_guard<std::mutex> lock(mu_);
  Statement q(*db_, "SELECT IFNULL(MAX(last_stamp_ns), 0) FROM submaps WHERE run_id = ?");
  if (!q.Bind(1, run).Step()) return DbError("cannot read the run's submaps", q.error());
  *stamp_ns = q.Int(0);
  return {};
}

namespace {

/// A stretch's stored transform (JSON: origin, T row-major 3x4) into `out`.
bool ReadTransform(const std::string& text, StretchFrame* out) {
  const json j = json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.contains("origin") || !j.contains("T") || j.at("T").size() != 12)
    return false;
  out->origin = VecOf(j.at("origin"));
  out->T_reference_later.setIdentity();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) out->T_reference_later.matrix()(r, c) = j.at("T").at(r * 4 + c);
  return true;
}

}  // namespace

Result ChangeStore::Frame(int64_t run, int stretch, StretchFrame* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  Statement q(*db_,
              "SELECT transform, from_m, to_m, rms_m FROM change_stretches "
              "WHERE run_id = ? AND stretch = ?");
  if (!q.Bind(1, run).Bind(2, stretch).Step())
    return Fail(Outcome::kNotFound, "stretch " + std::to_string(stretch) + " not compared");
  if (!ReadTransform(q.Text(0), out))
    return Fail(Outcome::kError, "a stretch's transform is unreadable");
  out->stretch = stretch;
  out->from_m = q.Double(1);
  out->to_m = q.Double(2);
  out->rms_m = q.Double(3);
  return {};
}

Result ChangeStore::Frames(int64_t run, std::vector<StretchFrame>* out) const {
  std::lock_guard<std::mutex> lock(mu_);
  out->clear();
  Statement q(*db_,
              "SELECT stretch, transform, from_m, to_m, rms_m FROM change_stretches "
              "WHERE run_id = ? AND compared = 1 ORDER BY from_m");
  q.Bind(1, run);
  while (q.Step()) {
    StretchFrame f;
    if (!ReadTransform(q.Text(1), &f))
      return Fail(Outcome::kError, "a stretch's transform is unreadable");
    f.stretch = static_cast<int>(q.Int(0));
    f.from_m = q.Double(2);
    f.to_m = q.Double(3);
    f.rms_m = q.Double(4);
    out->push_back(f);
  }
  return {};
}

}  // namespace raillomer::mapstore
