#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "api/stream.h"

namespace raillomer::api {

struct IngestClientOptions {
  std::string server_url;  ///< http://host:port
  std::string token;       ///< the server's ingest token
  std::string outbox_dir;  ///< the durable outbox (created if missing)
  std::string line = "unnamed line";
  std::string vehicle = "unnamed vehicle";
  int64_t start_ns = 0;
  size_t poses_per_batch = 10;  ///< 10 Hz poses go out about once a second
  double retry_max_s = 2.0;     ///< back-off between attempts while the server is away
  double request_timeout_s = 30.0;
};

/// Streams the estimator's poses and submaps to raillomer-server through a durable on-disk
/// outbox: each pose batch and each submap is written to the outbox before it is sent, and let
/// go only when the server has acknowledged it (a duplicate counts: the server had it). A
/// server outage or a cut link loses nothing: a sender thread keeps retrying. The server
/// de-duplicates by sequence number, so a message sent twice (acknowledgement lost) is stored
/// once.
///
/// A restarted estimator with the same outbox resumes the same run: what the outbox holds goes
/// first, and poses and submaps up to the highest sequences the outbox has held (pending, or
/// acknowledged and recorded in progress.json before the file went) are skipped, since the
/// estimator numbers them by the data alone and regenerates them on a rerun.
class IngestClient : public StreamSink {
 public:
  explicit IngestClient(IngestClientOptions options);
  ~IngestClient() override;
  IngestClient(const IngestClient&) = delete;
  IngestClient& operator=(const IngestClient&) = delete;

  /// Creates the outbox and starts the sender; false with a message if the outbox is unusable.
  bool Start(std::string* error);
  void OnPose(const StreamPose& pose) override;
  void OnSubmap(const Submap& submap) override;
  /// Provisional output goes through the outbox in order with the rest, to the server's
  /// provisional routes; a refusal (the run finished meanwhile) is logged like any other.
  void OnProvisionalPose(const StreamPose& pose) override;
  void OnProvisionalSubmap(const Submap& submap) override;
  /// Sends what is left and finishes the run on the server, waiting up to `wait_s`; false if
  /// the backlog did not drain (it stays in the outbox for a later start).
  bool Finish(double wait_s, std::string* error);

  struct Backlog {
    size_t messages = 0;  ///< in the outbox, not yet acknowledged
    uint64_t bytes = 0;
    uint64_t sent = 0;      ///< acknowledged since start
    uint64_t retries = 0;   ///< failed attempts (server away or erroring)
    uint64_t rejected = 0;  ///< refused by the server (4xx): kept in outbox/rejected/
    uint64_t skipped = 0;   ///< poses and submaps a resumed run had sent or queued before
    bool connected = false;
    int64_t run_id = 0;
    std::string last_error;
  };
  Backlog backlog() const;
  /// What Start found in the outbox of an earlier start: the run to go on with (0: none yet)
  /// and the highest pose and submap sequences it held, which are skipped (-1: none).
  struct Resume {
    int64_t run_id = 0;
    int64_t pose_sequence = -1, submap_sequence = -1;
    bool resuming() const { return pose_sequence >= 0 || submap_sequence >= 0; }
  };
  Resume resume() const;
  /// Called from the sender thread with each problem worth a warning (rejections, outages).
  void SetWarningHandler(std::function<void(const std::string&)> handler);

 private:
  bool EnsureRun(std::string* error);
  void WriteMessage(const std::string& name, const std::string& bytes);
  void FlushPosesLocked();
  void FlushProvisionalPosesLocked();
  /// Sends the outbox's messages in order, each until the server takes or rejects it, with
  /// exponential backoff while it cannot be reached.
  void SenderLoop();
  /// Keeps `message` as the last error and passes it to the warning callback.
  void SenderWarn(const std::string& message);
  /// Warns once of a message the outbox refused to hold.
  void WarnOfLostWrite();
  /// The outbox's files: provisional output first, each group in outbox order.
  std::vector<std::string> OutboxInSendingOrder() const;
  /// Lets a sent (or rejected, kept aside) message go from the outbox and the backlog.
  void Delivered(const std::string& file,
                 const std::string& bytes,
                 bool rejected,
                 const std::string& error);
  bool SendOne(const std::string& name,
               const std::string& bytes,
               std::string* error,
               bool* rejected);
  /// Records, before a sent or rejected message leaves the outbox, the highest sequences the
  /// outbox has held (progress.json), so a resumed run skips them.
  void RecordProgress(const std::string& kind, const std::string& bytes);
  /// run.json: the run's id, the server and the progress, written atomically.
  void WriteRunFile();

  IngestClientOptions options_;
  mutable std::mutex mu_;
  std::condition_variable wake_;
  std::vector<StreamPose> poses_, provisional_poses_;
  uint64_t next_file_ = 0;  ///< outbox order
  bool stopping_ = false;
  bool finishing_ = false;
  bool write_failed_ = false;  ///< the outbox refused a message: the sender warns
  /// Highest pose and submap sequences the outbox has held (-1: none); from Start, then the
  /// sender's alone.
  int64_t progress_pose_ = -1, progress_submap_ = -1;
  /// What a resumed run skips: sequences up to these (set by Start).
  int64_t resume_pose_ = -1, resume_submap_ = -1;
  Backlog backlog_;
  std::function<void(const std::string&)> warn_;
  std::thread sender_;
};

}  // namespace raillomer::api
