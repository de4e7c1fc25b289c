#pragma once

// raillomer-server as a child process on loopback ports the OS picks, and curl (not our code)
// as its client.

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <thread>

#include "tests/support/process.h"

namespace raillomer::test {

class ServerProcess {
 public:
  /// Starts the server on `data` (on `port` and `ws_port`, 0 for both: the OS picks; extra
  /// flags appended) and waits until it serves. A restart on the same port passes the first
  /// server's WebSocket port too: with ws_port 0 and a port given, the hub takes port + 1,
  /// which another process may hold.
  ServerProcess(const std::filesystem::path& data,
                const std::string& flags = "",
                int port = 0,
                int ws_port = 0)
      : data_(data),
        log_(data.string() + ".log"),
        process_((BinDir() / "raillomer-server").string() + " --data " + ShellQuote(data.string()) +
                 " --port " + std::to_string(port) + " --ws-port " + std::to_string(ws_port) + " " +
                 flags + " >" + ShellQuote(log_) + " 2>&1") {
    const std::regex serving(R"(serving http://127\.0\.0\.1:(\d+)/.*ws://127\.0\.0\.1:(\d+)/live)");
    for (int i = 0; i < 400 && port_ == 0 && process_.Running(); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
      std::smatch m;
      const std::string log = ReadText(log_);
      if (std::regex_search(log, m, serving)) {
        port_ = std::stoi(m[1]);
        ws_port_ = std::stoi(m[2]);
      }
    }
    std::ifstream token(data / "ingest.token");
    std::getline(token, token_);
  }
  ~ServerProcess() { Stop(SIGTERM); }

  /// Sends a signal and waits for the process to end; true if it exited with 0.
  bool Stop(int signal) {
    if (!process_.Running()) return false;
    process_.Signal(signal);
    return process_.Wait() == 0;
  }
  bool ok() { return port_ > 0 && process_.Running(); }
  int port() const { return port_; }
  int ws_port() const { return ws_port_; }
  const std::string& token() const { return token_; }
  std::string log() const { return ReadText(log_); }
  std::string Url(const std::string& path) const {
    return "http://127.0.0.1:" + std::to_string(port_) + path;
  }

 private:
  std::filesystem::path data_;
  std::string log_;
  ChildProcess process_;
  int port_ = 0, ws_port_ = 0;
  std::string token_;
};

/// An HTTP answer as curl saw it.
struct CurlResult {
  int status = 0;  ///< 0 if curl got no answer
  std::string body;
  std::string headers;
};

/// Runs curl with `args` (already quoted); the body goes to a file in `scratch`.
inline CurlResult Curl(const std::string& args, const std::filesystem::path& scratch) {
  const std::filesystem::path body = scratch / "curl_body", headers = scratch / "curl_headers";
  const CommandResult r =
      RunCommand("curl -s -o " + ShellQuote(body.string()) + " -D " + ShellQuote(headers.string()) +
                     " -w '%{http_code}' --max-time 30 " + args,
                 scratch);
  CurlResult c;
  try {
    c.status = std::stoi(r.out);
  } catch (const std::exception&) {
    c.status = 0;
  }
  c.body = ReadText(body);
  c.headers = ReadText(headers);
  std::filesystem::remove(body);
  std::filesystem::remove(headers);
  return c;
}

inline std::string Bearer(const std::string& token) {
  return "-H " + ShellQuote("Authorization: Bearer " + token) + " ";
}

}  // namespace raillomer::test
