// The submap worker builds on its own thread exactly what the builder builds in the caller's:
// the same submaps, in order, the last one closed at Finish, none lost when the queue is full;
// its queue bounded by the time it spans; what waits long handed out once for provisional output.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>

#include "estimator/mapping/submap_builder.h"
#include "estimator/pipeline/submap_worker.h"

namespace raillomer {
namespace {

SubmapKeyframe Keyframe(int k) {
  SubmapKeyframe kf;
  kf.stamp_ns = 1'000'000'000LL + k * 100'000'000LL;
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(500000.0 + 2.0 * k, 4000000.0, 30.0);
  kf.T_world_body = T;
  kf.T_odom_body = T;
  kf.georeferenced = true;
  kf.utm_zone = "32N";
  for (int i = 0; i < 20; ++i) kf.points_body.emplace_back(2.0f, 0.1f * i, 1.0f);
  kf.intensities.assign(kf.points_body.size(), static_cast<float>(k));
  return kf;
}

SubmapOptions Plain() {
  SubmapOptions o;
  o.keyframes = 10;
  o.voxel_m = 0.0;
  o.icp = false;
  o.ndt = false;
  return o;
}

TEST(SubmapWorker, BuildsWhatTheBuilderBuildsInOrderAndClosesTheLastAtFinish) {
  std::vector<api::Submap> direct;
  SubmapBuilder builder(Plain());
  for (int k = 0; k < 45; ++k) {
    for (api::Submap& s : builder.Add(Keyframe(k))) direct.push_back(std::move(s));
  }
  for (api::Submap& s : builder.Flush()) direct.push_back(std::move(s));
  ASSERT_EQ(direct.size(), 5u);  // four of ten, the last of five

  // A queue spanning 0.15 s, two keyframes: Add has to wait for the worker most of the time.
  std::vector<api::Submap> emitted;
  SubmapWorker worker(
      Plain(), [&](api::Submap s) { emitted.push_back(std::move(s)); }, 0.15);
  for (int k = 0; k < 45; ++k) worker.Add(Keyframe(k));
  worker.Finish();
  ASSERT_EQ(emitted.size(), direct.size());
  for (size_t i = 0; i < direct.size(); ++i) {
    EXPECT_EQ(emitted[i].index, direct[i].index);
    EXPECT_EQ(emitted[i].first_stamp_ns, direct[i].first_stamp_ns);
    EXPECT_EQ(emitted[i].keyframes.size(), direct[i].keyframes.size());
    EXPECT_EQ(emitted[i].points, direct[i].points);
    EXPECT_EQ(emitted[i].intensities, direct[i].intensities);
  }
  EXPECT_EQ(worker.stats().submaps, 5u);
}

TEST(SubmapWorker, TheDestructorFinishesWhatWasQueued) {
  size_t emitted = 0;
  {
    SubmapWorker worker(Plain(), [&](api::Submap) { ++emitted; });
    for (int k = 0; k < 15; ++k) worker.Add(Keyframe(k));
  }
  EXPECT_EQ(emitted, 2u);
}

TEST(SubmapWorker, HandsOutWhatWaitsLongOnceForProvisionalOutput) {
  // The emit callback holds the worker on the first submap, so everything after it waits.
  std::mutex gate;
  gate.lock();
  size_t emitted = 0;
  SubmapWorker worker(Plain(), [&](api::Submap) {
    std::lock_guard<std::mutex> wait(gate);
    ++emitted;
  });
  for (int k = 0; k < 30; ++k) worker.Add(Keyframe(k), /*sent_provisionally=*/k >= 12 && k < 15);
  // Keyframes 0-9 went into the first submap; the worker may have taken a few more since.
  const int64_t before_ns = Keyframe(20).stamp_ns;
  const std::vector<SubmapKeyframe> taken = worker.TakeProvisional(before_ns);
  ASSERT_FALSE(taken.empty());
  int64_t last = 0;
  for (const SubmapKeyframe& k : taken) {
    EXPECT_LT(k.stamp_ns, before_ns);
    EXPECT_GT(k.stamp_ns, last);  // in order
    EXPECT_TRUE(k.stamp_ns < Keyframe(12).stamp_ns || k.stamp_ns >= Keyframe(15).stamp_ns)
        << "sent provisionally already";
    EXPECT_EQ(k.points_body.size(), 20u);  // a copy: the worker keeps its own
    last = k.stamp_ns;
  }
  EXPECT_EQ(taken.back().stamp_ns, Keyframe(19).stamp_ns);
  EXPECT_TRUE(worker.TakeProvisional(before_ns).empty()) << "each is handed out once";
  EXPECT_TRUE(worker.BehindProvisional());
  EXPECT_EQ(worker.TakeProvisional(Keyframe(30).stamp_ns).size(), 10u);
  gate.unlock();
  worker.Finish();
  EXPECT_EQ(emitted, 3u);
  EXPECT_FALSE(worker.BehindProvisional());
}

TEST(SubmapWorker, AddWaitsOnlyWhileTheQueueSpansMoreThanItsTime) {
  // The worker is held on its first submap (keyframes 0-9); with a 0.5 s span the queue takes
  // keyframes up to about 0.5 s after the oldest waiting, then Add waits for the worker.
  std::mutex gate;
  gate.lock();
  size_t emitted = 0;
  SubmapWorker worker(
      Plain(),
      [&](api::Submap) {
        std::lock_guard<std::mutex> wait(gate);
        ++emitted;
      },
      0.5);
  std::atomic<int> added{0};
  std::thread feeder([&] {
    for (int k = 0; k < 30; ++k) {
      worker.Add(Keyframe(k));
      ++added;
    }
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  EXPECT_GE(added.load(), 15);  // 0-9 in the builder, then about six 0.1 s apart
  EXPECT_LE(added.load(), 18);
  gate.unlock();
  feeder.join();
  worker.Finish();
  EXPECT_EQ(added.load(), 30);
  EXPECT_EQ(emitted, 3u);
}

}  // namespace
}  // namespace raillomer
