#include "api/ingest_client.h"

#include <algorithm>
#include <chrono>
#include <cinttypes>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>

#include <httplib.h>
#include <nlohmann/json.hpp>

#include "api/atomic_file.h"

namespace raillomer::api {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::string ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

/// Outbox files in sending order: "<order>.<kind>", order zero-padded.
std::vector<fs::path> Pending(const std::string& dir) {
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    // Exactly "<12 digits>.<kind>": never a file still being written ("....tmp-<pid>").
    const std::string kind = name.size() > 13 ? name.substr(13) : "";
    if (e.is_regular_file() && name.size() > 13 && name[12] == '.' &&
        std::all_of(name.begin(), name.begin() + 12, ::isdigit) &&
        (kind == "poses.json" || kind == "submap.pcd" || kind == "finish.json" ||
         kind == "provisional_poses.json" || kind == "provisional_submap.pcd"))
      files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

std::string KindOf(const fs::path& file) { return file.filename().string().substr(13); }

/// The highest sequence a poses.json or submap.pcd message holds (-1 if none).
int64_t MaxSequence(const std::string& kind, const std::string& bytes) {
  int64_t max = -1;
  if (kind == "poses.json") {
    const json j = json::parse(bytes, nullptr, false);
    if (j.is_object() && j.contains("poses") && j["poses"].is_array())
      for (const json& p : j["poses"])
        if (p.is_object() && p.contains("sequence") && p["sequence"].is_number_unsigned())
          max = std::max(max, p["sequence"].get<int64_t>());
  } else if (kind == "submap.pcd") {
    Submap s;
    std::string error;
    if (DecodeSubmapPcd(bytes, &s, &error)) max = static_cast<int64_t>(s.sequence);
  }
  return max;
}

}  // namespace

IngestClient::IngestClient(IngestClientOptions options) : options_(std::move(options)) {}

IngestClient::~IngestClient() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    FlushPosesLocked();
    stopping_ = true;
  }
  wake_.notify_all();
  if (sender_.joinable()) sender_.join();
}

void IngestClient::SetWarningHandler(std::function<void(const std::string&)> handler) {
  std::lock_guard<std::mutex> lock(mu_);
  warn_ = std::move(handler);
}

bool IngestClient::Start(std::string* error) {
  if (options_.server_url.rfind("http://", 0) != 0) {
    *error = "the server URL must start with http:// (got '" + options_.server_url + "')";
    return false;
  }
  if (options_.token.empty()) {
    *error = "streaming to a server needs its ingest token (--token)";
    return false;
  }
  std::error_code ec;
  fs::create_directories(fs::path(options_.outbox_dir) / "rejected", ec);
  if (ec) {
    *error = "cannot create the outbox " + options_.outbox_dir + ": " + ec.message();
    return false;
  }
  // Resume: a run begun by an earlier start goes on, after what its outbox still holds, and
  // skips what the outbox held before (acknowledged, or still pending).
  const fs::path run_file = fs::path(options_.outbox_dir) / "run.json";
  if (fs::exists(run_file)) {
    const json j = json::parse(ReadAll(run_file), nullptr, false);
    if (j.is_object() && j.value("server", "") == options_.server_url) {
      backlog_.run_id = j.value("run_id", int64_t{0});
      progress_pose_ = j.value("pose_sequence", int64_t{-1});
      progress_submap_ = j.value("submap_sequence", int64_t{-1});
    }
  }
  for (const fs::path& f : Pending(options_.outbox_dir)) {
    next_file_ =
        std::max<uint64_t>(next_file_, std::stoull(f.filename().string().substr(0, 12)) + 1);
    ++backlog_.messages;
    backlog_.bytes += fs::file_size(f, ec);
    const int64_t max = MaxSequence(KindOf(f), ReadAll(f));
    int64_t& progress = KindOf(f) == "poses.json" ? progress_pose_ : progress_submap_;
    progress = std::max(progress, max);
  }
  resume_pose_ = progress_pose_;
  resume_submap_ = progress_submap_;
  sender_ = std::thread([this] { SenderLoop(); });
  return true;
}

void IngestClient::WriteMessage(const std::string& kind, const std::string& bytes) {
  char name[32];
  std::snprintf(name, sizeof(name), "%012" PRIu64 ".", next_file_++);
  std::string error;
  if (!WriteFileAtomically(
          (fs::path(options_.outbox_dir) / (name + kind)).string(), bytes, &error)) {
    // Told by the sender thread (never under this lock): the message is lost to the server.
    backlog_.last_error = "cannot write to the outbox, a message is lost: " + error;
    write_failed_ = true;
    wake_.notify_all();
    return;
  }
  ++backlog_.messages;
  backlog_.bytes += bytes.size();
  wake_.notify_all();
}

namespace {

/// A pose batch's body ({"poses": [...]}).
std::string PoseBatch(const std::vector<StreamPose>& poses) {
  json list = json::array();
  for (const StreamPose& p : poses) {
    list.push_back({{"sequence", p.sequence},
                    {"stamp_ns", p.stamp_ns},
                    {"georeferenced", p.georeferenced},
                    {"utm_zone", p.utm_zone},
                    {"p", {p.p.x(), p.p.y(), p.p.z()}},
                    {"q", {p.q.x(), p.q.y(), p.q.z(), p.q.w()}}});
  }
  return json{{"poses", list}}.dump();
}

}  // namespace

void IngestClient::FlushPosesLocked() {
  if (poses_.empty()) return;
  WriteMessage("poses.json", PoseBatch(poses_));
  poses_.clear();
}

void IngestClient::FlushProvisionalPosesLocked() {
  if (provisional_poses_.empty()) return;
  WriteMessage("provisional_poses.json", PoseBatch(provisional_poses_));
  provisional_poses_.clear();
}

void IngestClient::OnProvisionalPose(const StreamPose& pose) {
  std::lock_guard<std::mutex> lock(mu_);
  provisional_poses_.push_back(pose);
  if (provisional_poses_.size() >= std::max<size_t>(1, options_.poses_per_batch))
    FlushProvisionalPosesLocked();
}

void IngestClient::OnProvisionalSubmap(const Submap& submap) {
  const std::string bytes = EncodeSubmapPcd(submap);
  std::lock_guard<std::mutex> lock(mu_);
  FlushProvisionalPosesLocked();  // the poses before it go first
  WriteMessage("provisional_submap.pcd", bytes);
}

void IngestClient::OnPose(const StreamPose& pose) {
  std::lock_guard<std::mutex> lock(mu_);
  if (static_cast<int64_t>(pose.sequence) <= resume_pose_) {
    ++backlog_.skipped;
    return;
  }
  poses_.push_back(pose);
  if (poses_.size() >= std::max<size_t>(1, options_.poses_per_batch)) FlushPosesLocked();
}

void IngestClient::OnSubmap(const Submap& submap) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (static_cast<int64_t>(submap.sequence) <= resume_submap_) {
      ++backlog_.skipped;
      return;
    }
  }
  const std::string bytes = EncodeSubmapPcd(submap);
  std::lock_guard<std::mutex> lock(mu_);
  FlushPosesLocked();  // the poses before it go first
  WriteMessage("submap.pcd", bytes);
}

bool IngestClient::Finish(double wait_s, std::string* error) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    FlushPosesLocked();
    const int64_t end_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                               std::chrono::system_clock::now().time_since_epoch())
                               .count();
    WriteMessage("finish.json", json{{"end_ns", end_ns}}.dump());
    finishing_ = true;
  }
  std::unique_lock<std::mutex> lock(mu_);
  const bool drained = wake_.wait_for(lock,
                                      std::chrono::duration<double>(std::max(0.0, wait_s)),
                                      [this] { return backlog_.messages == 0; });
  if (!drained) {
    *error = std::to_string(backlog_.messages) + " messages (" +
             std::to_string(backlog_.bytes / 1024) + " KiB) are still in the outbox " +
             options_.outbox_dir +
             (backlog_.last_error.empty() ? "" : " (" + backlog_.last_error + ")") +
             ": the next start with this outbox sends them";
  }
  return drained;
}

IngestClient::Resume IngestClient::resume() const {
  std::lock_guard<std::mutex> lock(mu_);
  Resume r;
  r.run_id = backlog_.run_id;
  r.pose_sequence = resume_pose_;
  r.submap_sequence = resume_submap_;
  return r;
}

IngestClient::Backlog IngestClient::backlog() const {
  std::lock_guard<std::mutex> lock(mu_);
  return backlog_;
}

bool IngestClient::EnsureRun(std::string* error) {
  if (backlog_.run_id != 0) return true;
  httplib::Client client(options_.server_url);
  client.set_bearer_token_auth(options_.token);
  client.set_connection_timeout(2, 0);
  client.set_read_timeout(static_cast<time_t>(options_.request_timeout_s), 0);
  const json body = {
      {"line", options_.line}, {"vehicle", options_.vehicle}, {"start_ns", options_.start_ns}};
  const auto r = client.Post("/api/v1/runs", body.dump(), "application/json");
  if (!r) {
    *error = "cannot reach " + options_.server_url + ": " + httplib::to_string(r.error());
    return false;
  }
  if (r->status != 201) {
    *error = "the server refused to create the run (" + std::to_string(r->status) + "): " + r->body;
    return false;
  }
  const json j = json::parse(r->body, nullptr, false);
  const int64_t id = j.is_object() ? j.value("id", int64_t{0}) : 0;
  if (id <= 0) {
    *error = "the server's answer has no run id: " + r->body;
    return false;
  }
  {
    std::lock_guard<std::mutex> lock(mu_);
    backlog_.run_id = id;
  }
  WriteRunFile();
  return true;
}

void IngestClient::WriteRunFile() {
  std::string error;
  WriteFileAtomically((fs::path(options_.outbox_dir) / "run.json").string(),
                      json{{"run_id", backlog_.run_id},
                           {"server", options_.server_url},
                           {"pose_sequence", progress_pose_},
                           {"submap_sequence", progress_submap_}}
                          .dump(),
                      &error);
}

void IngestClient::RecordProgress(const std::string& kind, const std::string& bytes) {
  const int64_t max = MaxSequence(kind, bytes);
  int64_t& progress = kind == "poses.json" ? progress_pose_ : progress_submap_;
  if (max <= progress) return;
  progress = max;
  WriteRunFile();
}

bool IngestClient::SendOne(const std::string& path,
                           const std::string& bytes,
                           std::string* error,
                           bool* rejected) {
  *rejected = false;
  const std::string name = fs::path(path).filename().string();
  const std::string kind = name.substr(13);
  const std::string run = "/api/v1/runs/" + std::to_string(backlog_.run_id);
  std::string target, content_type = "application/json";
  if (kind == "poses.json") {
    target = run + "/poses";
  } else if (kind == "submap.pcd") {
    target = run + "/submaps";
    content_type = "application/octet-stream";
  } else if (kind == "provisional_poses.json") {
    target = run + "/provisional/poses";
  } else if (kind == "provisional_submap.pcd") {
    target = run + "/provisional/submaps";
    content_type = "application/octet-stream";
  } else if (kind == "finish.json") {
    target = run + "/finish";
  } else {
    *error = "unknown outbox file " + name;
    *rejected = true;
    return false;
  }
  httplib::Client client(options_.server_url);
  client.set_bearer_token_auth(options_.token);
  client.set_connection_timeout(2, 0);
  client.set_read_timeout(static_cast<time_t>(options_.request_timeout_s), 0);
  const auto r = client.Post(target, bytes, content_type);
  if (!r) {
    *error = "cannot reach " + options_.server_url + ": " + httplib::to_string(r.error());
    return false;
  }
  if (r->status >= 200 && r->status < 300) return true;
  *error = name + ": the server answered " + std::to_string(r->status) + ": " + r->body;
  // A bad message stays bad; a refused token or a failing server may be fixed: retry those.
  *rejected = r->status >= 400 && r->status < 500 && r->status != 401 && r->status != 408 &&
              r->status != 429;
  return false;
}

void IngestClient::SenderLoop() {
  double backoff_s = 0.05;
  bool was_connected = true;
  while (true) {
    WarnOfLostWrite();
    const std::vector<std::string> files = OutboxInSendingOrder();
    if (files.empty()) {
      std::unique_lock<std::mutex> lock(mu_);
      if (stopping_) return;
      wake_.wait_for(lock, std::chrono::milliseconds(200));
      continue;
    }
    std::string error;
    bool rejected = false;
    const std::string bytes = ReadAll(files.front());
    bool ok = EnsureRun(&error);
    if (ok) ok = SendOne(files.front(), bytes, &error, &rejected);
    if (ok || rejected) {
      Delivered(files.front(), bytes, rejected, error);
      if (!was_connected) SenderWarn("the server is back; sending the backlog");
      was_connected = true;
      backoff_s = 0.05;
      continue;
    }
    {
      std::lock_guard<std::mutex> lock(mu_);
      ++backlog_.retries;
      backlog_.connected = false;
      if (stopping_ && !finishing_) return;  // the outbox keeps the rest for the next start
    }
    if (was_connected) {
      SenderWarn(error + "; buffering in " + options_.outbox_dir + " and retrying");
    }
    was_connected = false;
    {
      std::unique_lock<std::mutex> lock(mu_);
      wake_.wait_for(lock, std::chrono::duration<double>(backoff_s), [this] { return stopping_; });
      if (stopping_) return;
    }
    backoff_s = std::min(options_.retry_max_s, backoff_s * 2.0);
  }
}

void IngestClient::SenderWarn(const std::string& message) {
  std::function<void(const std::string&)> w;
  {
    std::lock_guard<std::mutex> lock(mu_);
    backlog_.last_error = message;
    w = warn_;
  }
  if (w) w(message);
}

void IngestClient::WarnOfLostWrite() {
  std::string lost;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (write_failed_) lost = backlog_.last_error;
    write_failed_ = false;
  }
  if (!lost.empty()) SenderWarn(lost);
}

std::vector<std::string> IngestClient::OutboxInSendingOrder() const {
  std::vector<fs::path> files = Pending(options_.outbox_dir);
  // Provisional output is worth something only while it is new: it goes ahead of a backlog
  // of final output (which the server prunes it by, whatever the order).
  std::stable_partition(files.begin(), files.end(), [](const fs::path& f) {
    return KindOf(f).rfind("provisional_", 0) == 0;
  });
  return std::vector<std::string>(files.begin(), files.end());
}

void IngestClient::Delivered(const std::string& file,
                             const std::string& bytes,
                             bool rejected,
                             const std::string& error) {
  const fs::path path(file);
  std::error_code ec;
  RecordProgress(KindOf(path), bytes);  // before the file goes
  if (rejected) {
    fs::rename(path, fs::path(options_.outbox_dir) / "rejected" / path.filename(), ec);
    SenderWarn("rejected, kept in " + options_.outbox_dir + "/rejected: " + error);
  } else {
    fs::remove(path, ec);
    if (KindOf(path) == "finish.json")
      fs::remove(fs::path(options_.outbox_dir) / "run.json", ec);  // the run is complete
  }
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (backlog_.messages > 0) --backlog_.messages;
    backlog_.bytes -= std::min<uint64_t>(backlog_.bytes, bytes.size());
    ++(rejected ? backlog_.rejected : backlog_.sent);
    backlog_.connected = true;
  }
  wake_.notify_all();
}

}  // namespace raillomer::api
