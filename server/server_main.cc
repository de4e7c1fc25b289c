// raillomer-server: stores runs streamed by raillomer-estimator as tiled, Draco-compressed maps
// with an SQLite index, and serves them over REST (/api/v1/), a live WebSocket hub and the
// browser viewer's static files.
#include <signal.h>
#include <sys/stat.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include <CLI/CLI.hpp>

#include "server/server.h"

using raillomer::server::ServerConfig;

namespace {

/// "run 3: 12, 13; run 4: 2" for (run, sequence) pairs in run order.
std::string ListSubmaps(const std::vector<std::pair<int64_t, uint64_t>>& submaps) {
  std::string out;
  int64_t run = -1;
  for (const auto& [r, sequence] : submaps) {
    out += r != run ? (out.empty() ? "" : "; ") + ("run " + std::to_string(r) + ": ") : ", ";
    out += std::to_string(sequence);
    run = r;
  }
  return out;
}

/// Tells what opening the store found of submaps acknowledged before a crash.
void PrintRecovery(const raillomer::mapstore::RecoveryReport& report) {
  if (!report.recovered.empty())
    std::printf("raillomer-server: recovered %zu submaps acknowledged before a crash (%s)\n",
                report.recovered.size(),
                ListSubmaps(report.recovered).c_str());
  if (!report.lost.empty())
    std::printf(
        "raillomer-server: LOST %zu acknowledged submaps whose payload is gone (%s): their "
        "points are not in the tiles; the same submaps sent again restore them\n",
        report.lost.size(),
        ListSubmaps(report.lost).c_str());
}

/// The viewer's files when neither flag nor config names them: the installed build
/// (<prefix>/share/raillomer/web beside <prefix>/bin), else the source tree's build (web/dist),
/// whichever holds an index.html; empty when neither does.
std::string DefaultWebRoot() {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  std::vector<fs::path> candidates;
  if (!ec) candidates.push_back(exe.parent_path().parent_path() / "share" / "raillomer" / "web");
  candidates.emplace_back(RAILLOMER_SOURCE_WEB_DIST);
  for (const fs::path& dir : candidates)
    if (fs::is_regular_file(dir / "index.html", ec)) return dir.string();
  return "";
}

/// The command line's flags; each given one overrides the config file's setting.
struct Flags {
  std::string config_path, data_dir, host, web_root;
  int port = -1, ws_port = -1;
};

void AddFlags(CLI::App* app, Flags* f) {
  app->add_option("--data", f->data_dir, "the store's folder (created if missing)");
  app->add_option("--port", f->port, "HTTP port (default 8470; 0 lets the OS pick)")
      ->check(CLI::Range(0, 65535));
  app->add_option("--ws-port", f->ws_port, "live WebSocket port (default: port + 1)")
      ->check(CLI::Range(0, 65535));
  app->add_option("--host", f->host, "address to listen on (default 127.0.0.1)");
  app->add_option("--web-root",
                  f->web_root,
                  "the viewer's static files, served at / (default: the installed viewer, or "
                  "web/dist of the source tree once built)");
  app->add_option("--config", f->config_path, "YAML config; flags override it");
}

/// The config file (if any) with the flags over it, checked.
bool ResolveConfig(const Flags& f, ServerConfig* config, std::string* error) {
  if (!f.config_path.empty() && !raillomer::server::LoadServerConfig(f.config_path, config, error))
    return false;
  if (!f.data_dir.empty()) config->data_dir = f.data_dir;
  if (f.port >= 0) config->port = f.port;
  if (f.ws_port >= 0) config->ws_port = f.ws_port;
  if (!f.host.empty()) config->host = f.host;
  if (!f.web_root.empty()) config->web_root = f.web_root;
  if (config->web_root.empty()) config->web_root = DefaultWebRoot();
  return config->IsValid(error);
}

/// The config in effect, what recovery found, where the server listens and its token.
void PrintServing(const raillomer::server::Server& server) {
  std::printf("raillomer-server: config in effect\n");
  for (const auto& [key, value] : raillomer::server::DescribeConfig(server.config()))
    std::printf("  %-28s %s\n", key.c_str(), value.c_str());
  PrintRecovery(server.recovery());
  const std::string& h = server.config().host;
  std::printf(
      "raillomer-server: serving http://%s:%d/ (REST /api/v1/, health /health, metrics "
      "/metrics; live ws://%s:%d/live)\n",
      h.c_str(),
      server.port(),
      h.c_str(),
      server.ws_port());
  if (server.token_path().empty()) {
    std::printf("raillomer-server: ingest token: set in the config\n");
  } else {
    std::printf("raillomer-server: ingest token: %s\n", server.token_path().c_str());
  }
  std::fflush(stdout);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-server: stores each run streamed by raillomer-estimator as a tiled, "
      "Draco-compressed map with an SQLite index, and serves it over REST (/api/v1/), a live "
      "WebSocket hub (/live) and the browser viewer.\n\n"
      "  raillomer-server --data <dir> [--port <n>] [--config <yaml>]\n\n"
      "The ingest token (for ingest and every write) is generated into <dir>/ingest.token on "
      "first start unless the config sets one; send it as 'Authorization: Bearer <token>'."};
  Flags flags;
  AddFlags(&app, &flags);
  CLI11_PARSE(app, argc, argv);

  ServerConfig config;
  std::string error;
  if (!ResolveConfig(flags, &config, &error)) {
    std::fprintf(stderr, "raillomer-server: %s\n", error.c_str());
    return 2;
  }
  // Signals are taken by this thread alone (sigwait), never by the serving threads.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  // The store's files (index, payloads, token) are readable by the server's user alone.
  umask(077);
  raillomer::server::Server server(config);
  if (!server.Start(&error)) {
    std::fprintf(stderr, "raillomer-server: %s\n", error.c_str());
    return 1;
  }
  PrintServing(server);
  int received = 0;
  sigwait(&signals, &received);
  std::printf("raillomer-server: %s, writing the last tiles and stopping\n",
              received == SIGINT ? "interrupted" : "terminated");
  std::fflush(stdout);
  server.Stop();
  return 0;
}
