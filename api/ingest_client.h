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
/// server outage or a cut link loses nothing: a sender thread keeps retrying, and a restarted
/// estimator with the same outbox resumes the same run. The server de-duplicates by sequence
/// number, so a message sent twice (acknowledgement lost) is stored once.
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
  /// Sends what is left and finishes the run on the server, waiting up to `wait_s`; false if
  /// the backlog did not drain (it stays in the outbox for a later start).
  bool Finish(double wait_s, std::string* error);

  struct Backlog {
    size_t messages = 0;  ///< in the outbox, not yet acknowledged
    uint64_t bytes = 0;
    uint64_t sent = 0;      ///< acknowledged since start
    uint64_t retries = 0;   ///< failed attempts (server away or erroring)
    uint64_t rejected = 0;  ///< refused by the server (4xx): kept in outbox/rejected/
    bool connected = false;
    int64_t run_id = 0;
    std::string last_error;
  };
  Backlog backlog() const;
  /// Called from the sender thread with each problem worth a warning (rejections, outages).
  void SetWarningHandler(std::function<void(const std::string&)> handler);

 private:
  bool EnsureRun(std::string* error);
  void WriteMessage(const std::string& name, const std::string& bytes);
  void FlushPosesLocked();
  void SenderLoop();
  bool SendOne(const std::string& name, std::string* error, bool* rejected);

  IngestClientOptions options_;
  mutable std::mutex mu_;
  std::condition_variable wake_;
  std::vector<StreamPose> poses_;
  uint64_t next_file_ = 0;  ///< outbox order
  bool stopping_ = false;
  bool finishing_ = false;
  bool write_failed_ = false;  ///< the outbox refused a message: the sender warns
  Backlog backlog_;
  std::function<void(const std::string&)> warn_;
  std::thread sender_;
};

}  // namespace raillomer::api
