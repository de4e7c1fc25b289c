// Change detection's records: a stretch and its changes stored once (a repeat is a duplicate,
// a detection re-requested against another reference refuses the old one's stretches and
// takes over the old changes it finds again), filters,
// an engineer's status and note, a later run closing a change marked fixed that it no longer
// sees and continuing the changes it finds again.
#include <gtest/gtest.h>

#include "mapstore/change_store.h"
#include "tests/mapstore/store_fixture.h"

namespace raillomer::mapstore {
namespace {

RunChange Change(ChangeKind kind, double chainage_m, const Eigen::Vector3d& centre, bool intrudes) {
  RunChange c;
  c.kind = kind;
  c.chainage_m = chainage_m;
  c.offset_m = -2.0;
  c.centre_utm = centre;
  c.utm_zone = "50N";
  c.size_m = Eigen::Vector3d(1.2, 0.8, 1.6);
  c.margin_m = intrudes ? -0.4 : 0.6;
  c.intrudes_envelope = intrudes;
  c.footprint_utm = {centre.head<2>(), centre.head<2>() + Eigen::Vector2d(1.0, 0.0)};
  return c;
}

StretchOutcome Stretch(int index, std::vector<RunChange> changes) {
  StretchOutcome o;
  o.range = {index, 80.0 * index, 80.0 * (index + 1)};
  o.compared = true;
  o.registration_rms_m = 0.02;
  o.origin = Eigen::Vector3d(500000.0, 4000000.0, 10.0);
  o.T_reference_later.translation() = Eigen::Vector3d(0.1, -0.2, 0.0);
  o.changes = std::move(changes);
  return o;
}

class ChangeStoreTest : public StoreTest {
 protected:
  void SetUp() override {
    StoreTest::SetUp();
    if (HasFatalFailure()) return;
    std::string error;
    for (int i = 0; i < 3; ++i) {
      RunInfo run;
      ASSERT_TRUE(store_->CreateRun({"Line", "RLM-1", 1'600'000'000'000'000'000 + i}, &run));
    }
    changes_ = ChangeStore::Open(store_->IndexPath(), &error);
    ASSERT_TRUE(changes_) << error;
  }

  /// Run 2's stretch 0 is stored on provisional output.
  void ExpectStretchZeroProvisional() {
    std::set<int> done, provisional;
    ASSERT_TRUE(changes_->StoredStretches(2, &done, &provisional));
    EXPECT_EQ(done, std::set<int>({0}));
    EXPECT_EQ(provisional, std::set<int>({0}));
    DetectionState state;
    ASSERT_TRUE(changes_->Detection(2, &state));
    EXPECT_EQ(state.stretches_provisional, 1);
  }

  /// Run 2's stretch 0 is stored on final output with its registration residual.
  void ExpectStretchZeroFinal(double registration_rms_m) {
    std::set<int> done, provisional;
    ASSERT_TRUE(changes_->StoredStretches(2, &done, &provisional));
    EXPECT_TRUE(provisional.empty());
    DetectionState state;
    ASSERT_TRUE(changes_->Detection(2, &state));
    EXPECT_EQ(state.stretches_done, 1);
    EXPECT_EQ(state.stretches_provisional, 0);
    EXPECT_NEAR(state.registration_rms_m, registration_rms_m, 1e-9);
  }

  /// The final output keeps the confirmed change (its note and status) where the final output
  /// places it, at km 0.0124, and drops the change the final output lacks.
  void ExpectTheKeptChangeMovedAndTheOtherGone(int64_t kept_id, int64_t gone_id) {
    std::vector<StoredChange> listed;
    ASSERT_TRUE(changes_->List(2, ChangeFilter(), &listed));
    ASSERT_EQ(listed.size(), 2u);
    StoredChange now;
    ASSERT_TRUE(changes_->Get(kept_id, &now));
    EXPECT_EQ(now.note, "seen from the cab");
    EXPECT_EQ(now.status, "confirmed");
    EXPECT_FALSE(now.provisional);
    EXPECT_NEAR(now.change.chainage_m, 12.4, 1e-9);
    EXPECT_EQ(changes_->Get(gone_id, &now).outcome, Outcome::kNotFound);
  }

  std::unique_ptr<ChangeStore> changes_;
  const Eigen::Vector3d at_{500010.0, 4000002.0, 11.0};
};

TEST_F(ChangeStoreTest, StoresAStretchOnceWithItsChanges) {
  DetectionState state;
  ASSERT_TRUE(changes_->Request(2, 1, false, &state));
  EXPECT_EQ(state.status, "pending");
  std::vector<StoredChange> stored, closed;
  const StretchOutcome o = Stretch(0, {Change(ChangeKind::kAdded, 12.0, at_, true)});
  ASSERT_TRUE(changes_->SaveStretch(2, 1, o, &stored, &closed));
  ASSERT_EQ(stored.size(), 1u);
  EXPECT_GT(stored[0].id, 0);
  // Again (a restart that compared it before its row was read): nothing more.
  const Result again = changes_->SaveStretch(2, 1, o, &stored, &closed);
  EXPECT_EQ(again.outcome, Outcome::kDuplicate);
  std::vector<StoredChange> listed;
  ASSERT_TRUE(changes_->List(2, ChangeFilter(), &listed));
  ASSERT_EQ(listed.size(), 1u);
  const RunChange& c = listed[0].change;
  EXPECT_EQ(c.kind, ChangeKind::kAdded);
  EXPECT_TRUE(c.intrudes_envelope);
  EXPECT_DOUBLE_EQ(c.margin_m, -0.4);
  EXPECT_EQ(c.footprint_utm.size(), 2u);
  EXPECT_EQ(listed[0].status, "new");
  ASSERT_TRUE(changes_->Detection(2, &state));
  EXPECT_EQ(state.status, "running");
  EXPECT_EQ(state.stretches_done, 1);
  EXPECT_NEAR(state.km, 0.08, 1e-9);
  EXPECT_NEAR(state.registration_rms_m, 0.02, 1e-9);
  StretchFrame frame;
  ASSERT_TRUE(changes_->Frame(2, 0, &frame));
  EXPECT_TRUE(frame.T_reference_later.isApprox(o.T_reference_later));
  EXPECT_TRUE(frame.origin.isApprox(o.origin));
  // Every compared stretch's registration, with its chainage (what the viewer draws with).
  std::vector<StretchFrame> frames;
  ASSERT_TRUE(changes_->Frames(2, &frames));
  ASSERT_EQ(frames.size(), 1u);
  EXPECT_EQ(frames[0].stretch, 0);
  EXPECT_DOUBLE_EQ(frames[0].from_m, o.range.from_m);
  EXPECT_DOUBLE_EQ(frames[0].to_m, o.range.to_m);
  EXPECT_NEAR(frames[0].rms_m, 0.02, 1e-9);
  EXPECT_TRUE(frames[0].T_reference_later.isApprox(o.T_reference_later));
}

TEST_F(ChangeStoreTest, ARequestAgainstAnotherReferenceChecksTheOldResultsAgain) {
  // Run 3 against run 1: two changes in stretch 0 (one confirmed with a note), one in stretch 1.
  ASSERT_TRUE(changes_->Request(3, 1, false, nullptr));
  std::vector<StoredChange> stored, closed, withdrawn;
  const Eigen::Vector3d east(30.0, 0.0, 0.0);
  ASSERT_TRUE(changes_->SaveStretch(3,
                                    1,
                                    Stretch(0,
                                            {Change(ChangeKind::kRemoved, 5.0, at_, false),
                                             Change(ChangeKind::kAdded, 35.0, at_ + east, false)}),
                                    &stored,
                                    &closed));
  const int64_t kept = stored[0].id, gone = stored[1].id;
  ASSERT_TRUE(
      changes_->SaveStretch(3,
                            1,
                            Stretch(1, {Change(ChangeKind::kAdded, 95.0, at_ + 3 * east, false)}),
                            &stored,
                            &closed));
  const int64_t unchecked = stored[0].id;
  StoredChange set;
  ASSERT_TRUE(
      changes_->Update(kept, std::string("confirmed"), std::string("seen from the cab"), &set));

  // Against run 2 now: the changes stand as they were until their stretches are compared
  // again; a stretch compared against the old reference is refused.
  ASSERT_TRUE(changes_->Request(3, 2, false, nullptr));
  std::vector<StoredChange> listed;
  ASSERT_TRUE(changes_->List(3, ChangeFilter(), &listed));
  ASSERT_EQ(listed.size(), 3u);
  for (const StoredChange& c : listed) EXPECT_FALSE(c.provisional) << c.id;
  EXPECT_EQ(changes_->SaveStretch(3, 1, Stretch(1, {}), &stored, &closed).outcome,
            Outcome::kConflict);
  std::set<int> done;
  ASSERT_TRUE(changes_->StoredStretches(3, &done));
  EXPECT_TRUE(done.empty());

  // Stretch 0 finds the removed object again, 0.5 m off: it keeps its id, status and note.
  ASSERT_TRUE(changes_->SaveStretch(
      3,
      2,
      Stretch(0, {Change(ChangeKind::kRemoved, 5.5, at_ + Eigen::Vector3d(0.5, 0.0, 0.0), false)}),
      &stored,
      &closed,
      &withdrawn));
  ASSERT_EQ(stored.size(), 1u);
  EXPECT_EQ(stored[0].id, kept);
  ASSERT_EQ(withdrawn.size(), 1u);
  EXPECT_EQ(withdrawn[0].id, gone);
  StoredChange now;
  ASSERT_TRUE(changes_->Get(kept, &now));
  EXPECT_EQ(now.status, "confirmed");
  EXPECT_EQ(now.note, "seen from the cab");
  EXPECT_EQ(now.reference_run, 2);
  EXPECT_FALSE(now.provisional);
  EXPECT_NEAR(now.change.chainage_m, 5.5, 1e-9);

  // Finishing withdraws what no stretch compared again found; not if the detection was
  // requested again meanwhile.
  DetectionState state;
  ASSERT_TRUE(changes_->Detection(3, &state));
  EXPECT_EQ(changes_->Finish(3, state.requested_ns - 1, &withdrawn).outcome, Outcome::kConflict);
  ASSERT_TRUE(changes_->Finish(3, state.requested_ns, &withdrawn));
  ASSERT_EQ(withdrawn.size(), 1u);
  EXPECT_EQ(withdrawn[0].id, unchecked);
  ASSERT_TRUE(changes_->List(3, ChangeFilter(), &listed));
  EXPECT_EQ(listed.size(), 1u);
  ASSERT_TRUE(changes_->Detection(3, &state));
  EXPECT_EQ(state.status, "done");
  // An id is never given again, not even the latest one withdrawn.
  ASSERT_TRUE(
      changes_->SaveStretch(3,
                            2,
                            Stretch(1, {Change(ChangeKind::kAdded, 95.0, at_ + 3 * east, false)}),
                            &stored,
                            &closed));
  EXPECT_GT(stored[0].id, unchecked);
}

TEST_F(ChangeStoreTest, ALiveRunComparedAgainKeepsItsChangesUntilTheFinalOutput) {
  // Run 2's change, confirmed; then the run is compared again while its output is provisional.
  ASSERT_TRUE(changes_->Request(2, 1, false, nullptr));
  std::vector<StoredChange> stored, closed, withdrawn;
  ASSERT_TRUE(changes_->SaveStretch(
      2, 1, Stretch(0, {Change(ChangeKind::kAdded, 12.0, at_, true)}), &stored, &closed));
  const int64_t kept = stored[0].id;
  StoredChange set;
  ASSERT_TRUE(changes_->Update(kept, std::string("confirmed"), std::string("cab"), &set));
  ASSERT_TRUE(changes_->Request(2, 1, true, nullptr));
  // The provisional output misses it: it stays, for the final output to check.
  StretchOutcome early = Stretch(0, {});
  early.provisional = true;
  ASSERT_TRUE(changes_->SaveStretch(2, 1, early, &stored, &closed, &withdrawn));
  EXPECT_TRUE(withdrawn.empty());
  // The final output finds it: the same change, still confirmed.
  ASSERT_TRUE(changes_->SaveStretch(2,
                                    1,
                                    Stretch(0, {Change(ChangeKind::kAdded, 12.3, at_, true)}),
                                    &stored,
                                    &closed,
                                    &withdrawn));
  ASSERT_EQ(stored.size(), 1u);
  EXPECT_EQ(stored[0].id, kept);
  EXPECT_EQ(stored[0].status, "confirmed");
  EXPECT_EQ(stored[0].note, "cab");
  EXPECT_TRUE(withdrawn.empty());
}

TEST_F(ChangeStoreTest, AWithdrawnChangeHandsOnWhatItContinuedToTheChangeThatContinuedIt) {
  std::vector<StoredChange> stored, closed, withdrawn;
  ASSERT_TRUE(changes_->Request(2, 1, false, nullptr));
  ASSERT_TRUE(changes_->SaveStretch(
      2, 1, Stretch(0, {Change(ChangeKind::kAdded, 12.0, at_, false)}), &stored, &closed));
  const int64_t week2 = stored[0].id;
  ASSERT_TRUE(changes_->Request(3, 1, false, nullptr));
  ASSERT_TRUE(changes_->SaveStretch(
      3, 1, Stretch(0, {Change(ChangeKind::kAdded, 12.0, at_, false)}), &stored, &closed));
  const int64_t week3 = stored[0].id;
  ASSERT_EQ(stored[0].earlier_change, week2);
  // Run 2 compared again no longer has it: run 3's change continues nothing, first seen in 2.
  ASSERT_TRUE(changes_->Request(2, 1, true, nullptr));
  ASSERT_TRUE(changes_->SaveStretch(2, 1, Stretch(0, {}), &stored, &closed, &withdrawn));
  ASSERT_EQ(withdrawn.size(), 1u);
  StoredChange now;
  ASSERT_TRUE(changes_->Get(week3, &now));
  EXPECT_EQ(now.earlier_change, 0);
  EXPECT_EQ(now.first_seen_run, 2);
}

TEST_F(ChangeStoreTest, FiltersByKilometreKindIntrusionSizeAndStatus) {
  ASSERT_TRUE(changes_->Request(2, 1, false, nullptr));
  std::vector<StoredChange> stored, closed;
  RunChange small = Change(ChangeKind::kAdded, 150.0, at_, false);
  small.size_m = Eigen::Vector3d(0.2, 0.2, 0.25);
  ASSERT_TRUE(changes_->SaveStretch(2,
                                    1,
                                    Stretch(1,
                                            {Change(ChangeKind::kAdded, 90.0, at_, true),
                                             Change(ChangeKind::kRemoved, 120.0, at_, false),
                                             small}),
                                    &stored,
                                    &closed));
  const auto count = [&](ChangeFilter f) {
    std::vector<StoredChange> listed;
    EXPECT_TRUE(changes_->List(2, f, &listed));
    return listed.size();
  };
  ChangeFilter f;
  EXPECT_EQ(count(f), 3u);
  f.from_m = 100.0;
  EXPECT_EQ(count(f), 2u);
  f.to_m = 130.0;
  EXPECT_EQ(count(f), 1u);
  f = ChangeFilter();
  f.kind = ChangeKind::kRemoved;
  EXPECT_EQ(count(f), 1u);
  f = ChangeFilter();
  f.intrudes = true;
  EXPECT_EQ(count(f), 1u);
  f = ChangeFilter();
  f.min_size_m = 0.3;
  EXPECT_EQ(count(f), 2u);
  StoredChange set;
  ASSERT_TRUE(changes_->Update(stored[0].id, std::string("dismissed"), std::nullopt, &set));
  ASSERT_TRUE(changes_->Update(stored[1].id, std::string("confirmed"), std::nullopt, &set));
  f = ChangeFilter();
  f.statuses = {"new", "confirmed"};
  EXPECT_EQ(count(f), 2u);
  f.statuses = {"dismissed"};
  EXPECT_EQ(count(f), 1u);
  f.statuses = {"closed"};
  EXPECT_EQ(count(f), 0u);
}

TEST_F(ChangeStoreTest, AFixedChangeALaterRunNoLongerSeesIsClosed) {
  ASSERT_TRUE(changes_->Request(2, 1, false, nullptr));
  std::vector<StoredChange> stored, closed;
  ASSERT_TRUE(changes_->SaveStretch(
      2, 1, Stretch(0, {Change(ChangeKind::kAdded, 12.0, at_, true)}), &stored, &closed));
  StoredChange updated;
  EXPECT_EQ(changes_->Update(stored[0].id, std::string("closed"), std::nullopt, &updated).outcome,
            Outcome::kInvalid);
  ASSERT_TRUE(
      changes_->Update(stored[0].id, std::string("fixed"), std::string("tree cut"), &updated));
  EXPECT_EQ(updated.status, "fixed");
  EXPECT_EQ(updated.note, "tree cut");
  // Run 3 sees the same stretch without it.
  ASSERT_TRUE(changes_->Request(3, 1, false, nullptr));
  ASSERT_TRUE(changes_->SaveStretch(3, 1, Stretch(0, {}), &stored, &closed));
  ASSERT_EQ(closed.size(), 1u);
  StoredChange now;
  ASSERT_TRUE(changes_->Get(updated.id, &now));
  EXPECT_EQ(now.status, "closed");
  EXPECT_EQ(now.closed_by_run, 3);
  EXPECT_EQ(now.note, "tree cut");
  // A note alone leaves it closed.
  ASSERT_TRUE(changes_->Update(updated.id, std::nullopt, std::string("cut on Monday"), &now));
  EXPECT_EQ(now.status, "closed");
  EXPECT_EQ(now.closed_by_run, 3);
  EXPECT_EQ(now.note, "cut on Monday");
  EXPECT_EQ(changes_->Update(123456, std::string("new"), std::nullopt, &now).outcome,
            Outcome::kNotFound);
}

TEST_F(ChangeStoreTest, AChangeFoundAgainByALaterRunContinuesTheEarlierOne) {
  // Run 2 finds three changes; engineers confirm one, dismiss one and mark one fixed.
  ASSERT_TRUE(changes_->Request(2, 1, false, nullptr));
  std::vector<StoredChange> stored, closed;
  const Eigen::Vector3d east(20.0, 0.0, 0.0);
  ASSERT_TRUE(
      changes_->SaveStretch(2,
                            1,
                            Stretch(0,
                                    {Change(ChangeKind::kAdded, 12.0, at_, true),
                                     Change(ChangeKind::kAdded, 32.0, at_ + east, false),
                                     Change(ChangeKind::kAdded, 52.0, at_ + 2 * east, false)}),
                            &stored,
                            &closed));
  ASSERT_EQ(stored.size(), 3u);
  EXPECT_EQ(stored[0].earlier_change, 0);
  EXPECT_EQ(stored[0].first_seen_run, 2);
  StoredChange set;
  ASSERT_TRUE(
      changes_->Update(stored[0].id, std::string("confirmed"), std::string("tree to cut"), &set));
  ASSERT_TRUE(
      changes_->Update(stored[1].id, std::string("dismissed"), std::string("a shadow"), &set));
  ASSERT_TRUE(changes_->Update(stored[2].id, std::string("fixed"), std::string("removed"), &set));
  const std::vector<StoredChange> week2 = stored;

  // Run 3 finds each again within 2 m, a removed object where the first was, and something
  // 3 m from the second.
  ASSERT_TRUE(changes_->Request(3, 1, false, nullptr));
  const Eigen::Vector3d nudge(0.6, -0.4, 0.0);
  ASSERT_TRUE(changes_->SaveStretch(
      3,
      1,
      Stretch(0,
              {Change(ChangeKind::kAdded, 12.6, at_ + nudge, true),
               Change(ChangeKind::kRemoved, 12.0, at_, false),
               Change(ChangeKind::kAdded, 32.6, at_ + east + nudge, false),
               Change(ChangeKind::kAdded, 35.0, at_ + east + Eigen::Vector3d(3.0, 0.0, 0.0), false),
               Change(ChangeKind::kAdded, 52.6, at_ + 2 * east + nudge, false)}),
      &stored,
      &closed));
  ASSERT_EQ(stored.size(), 5u);
  const std::vector<int64_t> continues = {week2[0].id, 0, week2[1].id, 0, week2[2].id};
  const std::vector<std::string> status = {"confirmed", "new", "dismissed", "new", "new"};
  const std::vector<std::string> note = {"tree to cut", "", "a shadow", "", "removed"};
  for (size_t i = 0; i < stored.size(); ++i) {
    SCOPED_TRACE("change " + std::to_string(i));
    StoredChange now;
    ASSERT_TRUE(changes_->Get(stored[i].id, &now));
    EXPECT_EQ(now.earlier_change, continues[i]);
    EXPECT_EQ(now.first_seen_run, continues[i] != 0 ? 2 : 3);
    EXPECT_EQ(now.status, status[i]);  // a change marked fixed and found again is new again
    EXPECT_EQ(now.note, note[i]);
    EXPECT_EQ(stored[i].earlier_change, now.earlier_change);
  }
  // Seen again, the fixed one is not closed.
  EXPECT_TRUE(closed.empty());
}

TEST_F(ChangeStoreTest, AStretchComparedOnProvisionalOutputIsReplacedByTheFinalOne) {
  ASSERT_TRUE(changes_->Request(2, 1, false, nullptr));
  std::vector<StoredChange> stored, closed, withdrawn;
  const Eigen::Vector3d elsewhere = at_ + Eigen::Vector3d(30.0, 0.0, 0.0);
  StretchOutcome early = Stretch(0,
                                 {Change(ChangeKind::kAdded, 12.0, at_, true),
                                  Change(ChangeKind::kRemoved, 40.0, elsewhere, false)});
  early.provisional = true;
  ASSERT_TRUE(changes_->SaveStretch(2, 1, early, &stored, &closed, &withdrawn));
  ASSERT_EQ(stored.size(), 2u);
  EXPECT_TRUE(stored[0].provisional);
  const int64_t kept_id = stored[0].id, gone_id = stored[1].id;
  StoredChange confirmed;
  ASSERT_TRUE(changes_->Update(
      kept_id, std::string("confirmed"), std::string("seen from the cab"), &confirmed));
  ASSERT_NO_FATAL_FAILURE(ExpectStretchZeroProvisional());
  // Provisional again: nothing changes.
  EXPECT_EQ(changes_->SaveStretch(2, 1, early, &stored, &closed, &withdrawn).outcome,
            Outcome::kDuplicate);

  // The final output: the added object 0.4 m from where it was, the removed one not found, a
  // new one.
  StretchOutcome final_outcome =
      Stretch(0,
              {Change(ChangeKind::kAdded, 12.4, at_ + Eigen::Vector3d(0.4, 0.0, 0.0), true),
               Change(ChangeKind::kAdded, 60.0, at_ + Eigen::Vector3d(50.0, 0.0, 0.0), false)});
  final_outcome.registration_rms_m = 0.015;
  ASSERT_TRUE(changes_->SaveStretch(2, 1, final_outcome, &stored, &closed, &withdrawn));
  ASSERT_EQ(stored.size(), 2u);
  EXPECT_EQ(stored[0].id, kept_id);
  EXPECT_EQ(stored[0].status, "confirmed");
  EXPECT_FALSE(stored[0].provisional);
  EXPECT_NE(stored[1].id, gone_id);
  ASSERT_EQ(withdrawn.size(), 1u);
  EXPECT_EQ(withdrawn[0].id, gone_id);
  ASSERT_NO_FATAL_FAILURE(ExpectTheKeptChangeMovedAndTheOtherGone(kept_id, gone_id));
  ASSERT_NO_FATAL_FAILURE(ExpectStretchZeroFinal(0.015));
  // Final once: a provisional or final outcome after it changes nothing.
  EXPECT_EQ(changes_->SaveStretch(2, 1, early, &stored, &closed, &withdrawn).outcome,
            Outcome::kDuplicate);
  EXPECT_EQ(changes_->SaveStretch(2, 1, final_outcome, &stored, &closed, &withdrawn).outcome,
            Outcome::kDuplicate);
}

TEST_F(ChangeStoreTest, OnlyAFinalStretchClosesAFixedChange) {
  ASSERT_TRUE(changes_->Request(2, 1, false, nullptr));
  std::vector<StoredChange> stored, closed, withdrawn;
  ASSERT_TRUE(changes_->SaveStretch(
      2, 1, Stretch(0, {Change(ChangeKind::kAdded, 12.0, at_, true)}), &stored, &closed));
  StoredChange updated;
  ASSERT_TRUE(changes_->Update(stored[0].id, std::string("fixed"), std::nullopt, &updated));
  ASSERT_TRUE(changes_->Request(3, 1, false, nullptr));
  StretchOutcome early = Stretch(0, {});
  early.provisional = true;
  ASSERT_TRUE(changes_->SaveStretch(3, 1, early, &stored, &closed, &withdrawn));
  EXPECT_TRUE(closed.empty());
  ASSERT_TRUE(changes_->SaveStretch(3, 1, Stretch(0, {}), &stored, &closed, &withdrawn));
  ASSERT_EQ(closed.size(), 1u);
  EXPECT_EQ(closed[0].id, updated.id);
}

}  // namespace
}  // namespace raillomer::mapstore
