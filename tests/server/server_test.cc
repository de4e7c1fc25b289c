// raillomer-server as a real process on loopback, driven by clients that are not ours: curl for
// REST, Debian's draco_decoder for a served tile, the sqlite3 tool for the index, and Python's
// websockets library for the live hub. Also: bad input answered with a 4xx JSON error and no
// change, and a kill -9 in the middle of ingest that loses nothing acknowledged.
#include <algorithm>
#include <cmath>
#include <fstream>
#include <set>

#include <gtest/gtest.h>
#include <yaml-cpp/yaml.h>
#include <nlohmann/json.hpp>

#include "api/las.h"
#include "api/stream.h"
#include "mapstore/tile_codec.h"
#include "tests/server/server_process.h"
#include "tests/support/corridor_submap.h"

namespace raillomer::test {
namespace {

/// Joins a thread that runs a child process when a failed assertion returns early, so that the
/// failure is reported instead of std::terminate aborting the test binary without a word (the
/// child must stop by itself).
struct JoinOnExit {
  std::thread& thread;
  ~JoinOnExit() {
    if (thread.joinable()) thread.join();
  }
};

using nlohmann::json;
namespace fs = std::filesystem;

/// Writes submap i's payload into `dir`; returns the file.
fs::path WriteSubmap(const fs::path& dir, const api::Submap& s, const std::string& name) {
  const fs::path path = dir / name;
  std::ofstream(path, std::ios::binary) << api::EncodeSubmapPcd(s);
  return path;
}

std::string PostFile(const fs::path& file) {
  return "-X POST -H 'Content-Type: application/octet-stream' --data-binary @" +
         ShellQuote(file.string()) + " ";
}

std::string PostJson(const json& body) {
  return "-X POST -H 'Content-Type: application/json' --data-binary " + ShellQuote(body.dump()) +
         " ";
}

int64_t CreateRun(const ServerProcess& server, const fs::path& scratch) {
  const CurlResult r =
      Curl(Bearer(server.token()) + PostJson({{"line", "Test line"}, {"vehicle", "RLM-1"}}) +
               ShellQuote(server.Url("/api/v1/runs")),
           scratch);
  EXPECT_EQ(r.status, 201) << r.body;
  const json j = json::parse(r.body, nullptr, false);
  return j.is_object() ? j.value("id", int64_t{0}) : 0;
}

/// Waits until the run's level-0 tiles hold `points` points (the flusher writes them).
json TilesWhenWritten(const ServerProcess& server,
                      int64_t run,
                      int64_t points,
                      const fs::path& scratch) {
  json index;
  for (int i = 0; i < 100; ++i) {
    const CurlResult r = Curl(
        ShellQuote(server.Url("/api/v1/runs/" + std::to_string(run) + "/tiles?level=0")), scratch);
    index = json::parse(r.body, nullptr, false);
    int64_t total = 0;
    if (index.is_object() && index.contains("tiles"))
      for (const auto& t : index["tiles"]) total += t["points"].get<int64_t>();
    if (total == points) return index;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ADD_FAILURE() << "the tiles never held " << points << " points: " << index.dump();
  return index;
}

/// One run through the REST API, step by step, on one server: each step checks a part of the
/// API with curl and the tools that read what the server wrote.
class RestApi : public ::testing::Test {
 protected:
  RestApi()
      : scratch_("raillomer_server_"), server_(scratch_.path() / "data"), dir_(scratch_.path()) {}

  /// The start-up log and /health.
  void CheckStartUp() {
    ASSERT_TRUE(server_.ok()) << server_.log();
    // The start-up log names every value in effect, never the token.
    EXPECT_NE(server_.log().find("store.tile_m"), std::string::npos);
    EXPECT_EQ(server_.log().find(server_.token()), std::string::npos);
    const CurlResult health = Curl(ShellQuote(server_.Url("/health")), dir_);
    EXPECT_EQ(health.status, 200);
    EXPECT_EQ(json::parse(health.body)["status"], "ok");
  }

  /// A run with two submaps; a repeated submap is a duplicate, a different one a conflict.
  void IngestSubmaps() {
    run_ = CreateRun(server_, dir_);
    ASSERT_GT(run_, 0);
    runs_ = server_.Url("/api/v1/runs/" + std::to_string(run_));
    const fs::path s0 = WriteSubmap(dir_, CorridorSubmap(0), "s0.pcd");
    const fs::path s1 = WriteSubmap(dir_, CorridorSubmap(1), "s1.pcd");
    CurlResult r = PostSubmap(s0);
    EXPECT_EQ(r.status, 201) << r.body;
    EXPECT_EQ(json::parse(r.body)["points"], CorridorSubmap(0).points.size());
    r = PostSubmap(s1);
    EXPECT_EQ(r.status, 201) << r.body;
    // The same submap again changes nothing; a different one under its sequence is a conflict.
    r = PostSubmap(s0);
    EXPECT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(json::parse(r.body)["duplicate"], true);
    api::Submap other = CorridorSubmap(0);
    other.points[0].z() += 1.0f;
    r = PostSubmap(WriteSubmap(dir_, other, "other.pcd"));
    EXPECT_EQ(r.status, 409) << r.body;
    EXPECT_EQ(json::parse(r.body)["error"]["code"], "conflict");
  }

  /// Poses, and the trajectory back as TUM and GeoJSON.
  void PostPosesAndReadTheTrajectory() {
    json poses = json::array();
    for (int i = 0; i < 5; ++i) {
      const Eigen::Vector3d p = CorridorStart() + Eigen::Vector3d(2.0 * i, 0.0, 2.0);
      poses.push_back({{"sequence", 20 + i},
                       {"stamp_ns", 1'600'000'000'000'000'000 + int64_t(i) * 100'000'000},
                       {"georeferenced", true},
                       {"utm_zone", "50N"},
                       {"p", {p.x(), p.y(), p.z()}},
                       {"q", {0.0, 0.0, 0.0, 1.0}}});
    }
    CurlResult r =
        Curl(Bearer(server_.token()) + PostJson({{"poses", poses}}) + ShellQuote(runs_ + "/poses"),
             dir_);
    EXPECT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(json::parse(r.body)["stored"], 5);
    r = Curl(ShellQuote(runs_ + "/trajectory?format=tum"), dir_);
    EXPECT_EQ(r.status, 200);
    EXPECT_EQ(r.body.rfind("# utm_zone 50N\n1600000000.000000000 432100.", 0), 0u) << r.body;
    r = Curl(ShellQuote(runs_ + "/trajectory"), dir_);
    const json geo = json::parse(r.body);
    const json& coords = geo["features"][0]["geometry"]["coordinates"];
    ASSERT_EQ(coords.size(), 5u);
    // UTM 50N (432100, 3585200) is near 32.4 N, 116.3 E (GeoConvert agrees).
    EXPECT_NEAR(coords[0][0].get<double>(), 116.28, 0.05);
    EXPECT_NEAR(coords[0][1].get<double>(), 32.40, 0.05);
  }

  /// The tiles: the index, then one tile's bytes with its ETag, read by Debian's draco_decoder.
  void ReadATile() {
    const int64_t expected_points = 400 * 110 * 3 / 2 * 1 + 0;  // 1.5 submaps' worth of voxels
    const json index = TilesWhenWritten(server_, run_, expected_points, dir_);
    ASSERT_FALSE(index["tiles"].empty());
    const json tile = index["tiles"][0];
    const CurlResult r = Curl(ShellQuote(server_.Url(tile["url"].get<std::string>())), dir_);
    ASSERT_EQ(r.status, 200);
    EXPECT_NE(r.headers.find("ETag: " + tile["etag"].get<std::string>()), std::string::npos)
        << r.headers;
    EXPECT_NE(r.headers.find("Cache-Control: no-cache"), std::string::npos);
    const CurlResult again =
        Curl("-H " + ShellQuote("If-None-Match: " + tile["etag"].get<std::string>()) + " " +
                 ShellQuote(server_.Url(tile["url"].get<std::string>())),
             dir_);
    EXPECT_EQ(again.status, 304);
    // draco_decoder reads the served tile; each point lies within the stated error of
    // a submap point.
    std::ofstream(dir_ / "tile.drc", std::ios::binary) << r.body;
    const CommandResult decoded =
        RunCommand("draco_decoder -i " + ShellQuote((dir_ / "tile.drc").string()) + " -o " +
                       ShellQuote((dir_ / "tile.ply").string()),
                   dir_);
    ASSERT_EQ(decoded.exit_code, 0) << decoded.out << decoded.err;
    std::ifstream ply(dir_ / "tile.ply", std::ios::binary);
    std::string line;
    size_t vertices = 0;
    while (std::getline(ply, line) && line != "end_header")
      if (line.rfind("element vertex ", 0) == 0) vertices = std::stoul(line.substr(15));
    ASSERT_EQ(static_cast<int64_t>(vertices), tile["points"].get<int64_t>());
    const Eigen::Vector3d origin(tile["origin"][0], tile["origin"][1], tile["origin"][2]);
    double worst = 0.0;
    for (size_t i = 0; i < vertices; ++i) {
      float p[3];
      ply.read(reinterpret_cast<char*>(p), sizeof(p));
      if (!ply) break;
      // The corridor's points lie on 0.1 m voxel centres (x.x5) relative to the start.
      const Eigen::Vector3d q = origin + Eigen::Vector3d(p[0], p[1], p[2]) - CorridorStart();
      for (int a = 0; a < 3; ++a)
        worst = std::max(worst, std::abs(q[a] - (std::floor(q[a] * 10.0) / 10.0 + 0.05)));
    }
    EXPECT_LE(worst, tile["max_error_m"].get<double>());
    EXPECT_LE(tile["max_error_m"].get<double>(), 0.005);
  }

  /// The sqlite3 tool reads the index.
  void ReadTheIndexWithSqlite() {
    const CommandResult sql = RunCommand(
        "sqlite3 " + ShellQuote((scratch_.path() / "data" / "index.sqlite").string()) +
            " 'PRAGMA integrity_check; SELECT count(*) FROM submaps; SELECT line FROM runs;'",
        dir_);
    EXPECT_EQ(sql.exit_code, 0) << sql.err;
    EXPECT_EQ(sql.out, "ok\n2\nTest line\n");
  }

  /// Finishing the run defines its line: centreline, segments by km, and km posts.
  void FinishAndQueryTheLine() {
    CurlResult r = Curl(
        Bearer(server_.token()) + PostJson(json::object()) + ShellQuote(runs_ + "/finish"), dir_);
    EXPECT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(json::parse(r.body)["status"], "finished");
    // The finished run defined its line's centreline: 8 m of poses, km 0.000 to 0.008.
    r = Curl(ShellQuote(server_.Url("/api/v1/lines/Test%20line")), dir_);
    EXPECT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(json::parse(r.body)["reference_run"], run_);
    EXPECT_NEAR(json::parse(r.body)["length_m"].get<double>(), 8.0, 0.01);
    r = Curl(ShellQuote(server_.Url("/api/v1/lines/Test%20line/segment?from_km=0.002&to_km=0.006")),
             dir_);
    ASSERT_EQ(r.status, 200) << r.body;
    const json segment = json::parse(r.body)["features"][0];
    EXPECT_EQ(segment["geometry"]["coordinates"].size(), 5u);
    EXPECT_EQ(segment["properties"]["profile"]["chainage_m"][0], 2.0);
    EXPECT_FALSE(segment["properties"]["tiles"].empty());
    // A km post at the line's start makes it km 12.
    r = Curl(Bearer(server_.token()) +
                 PostJson({{"km", 12.0},
                           {"easting", 432100.0},
                           {"northing", 3585200.0},
                           {"label", "km 12"}}) +
                 ShellQuote(server_.Url("/api/v1/lines/Test%20line/kmposts")),
             dir_);
    EXPECT_EQ(r.status, 200) << r.body;
    EXPECT_NEAR(json::parse(r.body)["chainage_offset_m"].get<double>(), 12000.0, 0.01);
    r = Curl(
        ShellQuote(server_.Url("/api/v1/lines/Test%20line/segment?from_km=12.002&to_km=12.006")),
        dir_);
    EXPECT_EQ(r.status, 200) << r.body;
    r = Curl(ShellQuote(server_.Url("/api/v1/lines/Test%20line/segment?from_km=abc&to_km=1")),
             dir_);
    EXPECT_EQ(r.status, 400) << r.body;
    r = Curl(ShellQuote(server_.Url("/api/v1/lines/Nowhere/segment?from_km=0&to_km=1")), dir_);
    EXPECT_EQ(r.status, 404) << r.body;
  }

  /// Exports: the run's points in a box as LAS and PLY, and along the line's first 8 m.
  void Export() {
    CurlResult r =
        Curl(ShellQuote(runs_ + "/export?format=las&bbox=432100,3585190,432110,3585210"), dir_);
    ASSERT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(r.body.compare(0, 4, "LASF"), 0);
    EXPECT_NE(r.headers.find("filename=\"run-" + std::to_string(run_) + ".las\""),
              std::string::npos);
    // 10 m of corridor: 100 columns of 110 voxels (ground and wall), 20 bytes each, after the
    // public header (227 bytes) and the zone's GeoTIFF key record (54 + 48), which names 50N.
    EXPECT_EQ(r.body.size(), 227u + 102u + 20u * 100u * 110u);
    api::las::Contents las;
    std::string las_error;
    ASSERT_TRUE(api::las::Decode(r.body, &las, &las_error)) << las_error;
    EXPECT_EQ(las.points.size(), 100u * 110u);
    EXPECT_EQ(las.epsg, 32650);
    // A box with no point of the run: an empty file that still names the run's zone.
    r = Curl(ShellQuote(runs_ + "/export?format=las&bbox=432000,3585000,432001,3585001"), dir_);
    ASSERT_EQ(r.status, 200) << r.body;
    ASSERT_TRUE(api::las::Decode(r.body, &las, &las_error)) << las_error;
    EXPECT_EQ(las.points.size(), 0u);
    EXPECT_EQ(las.epsg, 32650);
    r = Curl(ShellQuote(runs_ + "/export?format=ply&line=Test%20line&from_km=12.000&to_km=12.008"),
             dir_);
    EXPECT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(r.body.rfind("ply\n", 0), 0u);
    EXPECT_EQ(Curl(ShellQuote(runs_ + "/export?format=xyz&bbox=0,0,1,1"), dir_).status, 400);
    EXPECT_EQ(Curl(ShellQuote(runs_ + "/export"), dir_).status, 400);
  }

  /// Points of interest: create, read, list by line, update, delete.
  void EditPointsOfInterest() {
    const json mast = {{"kind", "mast"},
                       {"name", "M 7"},
                       {"line", "Test line"},
                       {"utm_zone", "50N"},
                       {"position", {432110.0, 3585203.2, 30.0}},
                       {"properties", {{"height_m", 8.5}}}};
    CurlResult r = Curl(
        Bearer(server_.token()) + PostJson(mast) + ShellQuote(server_.Url("/api/v1/pois")), dir_);
    ASSERT_EQ(r.status, 201) << r.body;
    const std::string poi =
        server_.Url("/api/v1/pois/" + std::to_string(json::parse(r.body)["id"].get<int>()));
    r = Curl(ShellQuote(poi), dir_);
    EXPECT_EQ(json::parse(r.body)["properties"]["height_m"], 8.5);
    r = Curl(ShellQuote(server_.Url("/api/v1/pois?line=Test%20line")), dir_);
    EXPECT_EQ(json::parse(r.body)["pois"].size(), 1u);
    json renamed = mast;
    renamed["name"] = "M 7a";
    r = Curl(Bearer(server_.token()) + "-X PUT -H 'Content-Type: application/json' --data-binary " +
                 ShellQuote(renamed.dump()) + " " + ShellQuote(poi),
             dir_);
    EXPECT_EQ(r.status, 200) << r.body;
    EXPECT_EQ(json::parse(r.body)["name"], "M 7a");
    EXPECT_EQ(Curl("-X DELETE " + ShellQuote(poi), dir_).status, 401);
    EXPECT_EQ(Curl(Bearer(server_.token()) + "-X DELETE " + ShellQuote(poi), dir_).status, 204);
    EXPECT_EQ(Curl(ShellQuote(poi), dir_).status, 404);
  }

  /// Metrics count what happened; the server stops on SIGTERM.
  void CheckMetricsAndStop() {
    const CurlResult r = Curl(ShellQuote(server_.Url("/metrics")), dir_);
    EXPECT_NE(r.body.find("raillomer_submaps_stored_total 2"), std::string::npos) << r.body;
    EXPECT_NE(
        r.body.find("raillomer_http_requests_total{route=\"ingest.submap\",status=\"409\"} 1"),
        std::string::npos);
    EXPECT_TRUE(server_.Stop(SIGTERM)) << server_.log();
  }

 private:
  CurlResult PostSubmap(const fs::path& file) const {
    return Curl(Bearer(server_.token()) + PostFile(file) + ShellQuote(runs_ + "/submaps"), dir_);
  }

  ScratchDir scratch_;
  ServerProcess server_;
  const fs::path dir_;
  int64_t run_ = 0;
  std::string runs_;  ///< the run's URL
};

TEST_F(RestApi, WithCurl) {
  ASSERT_NO_FATAL_FAILURE(CheckStartUp());
  ASSERT_NO_FATAL_FAILURE(IngestSubmaps());
  ASSERT_NO_FATAL_FAILURE(PostPosesAndReadTheTrajectory());
  ASSERT_NO_FATAL_FAILURE(ReadATile());
  ASSERT_NO_FATAL_FAILURE(ReadTheIndexWithSqlite());
  ASSERT_NO_FATAL_FAILURE(FinishAndQueryTheLine());
  ASSERT_NO_FATAL_FAILURE(Export());
  ASSERT_NO_FATAL_FAILURE(EditPointsOfInterest());
  CheckMetricsAndStop();
}

/// curl with `args` gets `status` and a JSON error with `code` and a message.
void ExpectJsonError(const std::string& args,
                     int status,
                     const std::string& code,
                     const fs::path& dir) {
  const CurlResult r = Curl(args, dir);
  EXPECT_EQ(r.status, status) << args << " -> " << r.body;
  const json j = json::parse(r.body, nullptr, false);
  ASSERT_TRUE(j.is_object() && j.contains("error")) << r.body;
  EXPECT_EQ(j["error"]["code"], code) << r.body;
  EXPECT_FALSE(j["error"]["message"].get<std::string>().empty());
}

/// A small submap that fits the body limit (written to ok.pcd), then broken versions of it, one
/// too large, one for an unknown run and ones without the token: each refused.
void ExpectBadSubmapsRefused(const ServerProcess& server,
                             const std::string& submaps,
                             const fs::path& dir) {
  api::Submap small = CorridorSubmap(0);
  small.points.resize(2000);
  small.intensities.resize(2000);
  const std::string good = api::EncodeSubmapPcd(small);
  const std::string token = Bearer(server.token());
  std::ofstream(dir / "truncated.pcd", std::ios::binary) << good.substr(0, good.size() - 7);
  ExpectJsonError(
      token + PostFile(dir / "truncated.pcd") + ShellQuote(submaps), 400, "invalid", dir);
  api::Submap nan = small;
  nan.points[5].x() = NAN;
  ExpectJsonError(token + PostFile(WriteSubmap(dir, nan, "nan.pcd")) + ShellQuote(submaps),
                  400,
                  "invalid",
                  dir);
  std::ofstream(dir / "garbage.pcd", std::ios::binary) << std::string(5000, '\x7f');
  ExpectJsonError(token + PostFile(dir / "garbage.pcd") + ShellQuote(submaps), 400, "invalid", dir);
  ExpectJsonError(token + PostFile(WriteSubmap(dir, small, "ok.pcd")) +
                      ShellQuote(server.Url("/api/v1/runs/999/submaps")),
                  404,
                  "not_found",
                  dir);
  ExpectJsonError(
      token + PostFile(WriteSubmap(dir, CorridorSubmap(1), "big.pcd")) + ShellQuote(submaps),
      413,
      "too_large",
      dir);
  ExpectJsonError(
      Bearer("wrong-token-wrong-token") + PostFile(dir / "ok.pcd") + ShellQuote(submaps),
      401,
      "unauthorized",
      dir);
  ExpectJsonError(PostFile(dir / "ok.pcd") + ShellQuote(submaps), 401, "unauthorized", dir);
}

/// Broken JSON, a NaN pose and an unknown tile: each refused.
void ExpectBadRequestsRefused(const ServerProcess& server, int64_t run, const fs::path& dir) {
  const std::string runs = server.Url("/api/v1/runs/" + std::to_string(run));
  ExpectJsonError(Bearer(server.token()) +
                      "-X POST -H 'Content-Type: application/json' --data-binary '{\"line\": 3' " +
                      ShellQuote(server.Url("/api/v1/runs")),
                  400,
                  "invalid",
                  dir);
  const json nan_pose = {{"sequence", 1}, {"stamp_ns", 5}, {"p", {NAN, 0, 0}}, {"q", {0, 0, 0, 1}}};
  ExpectJsonError(Bearer(server.token()) + PostJson({{"poses", json::array({nan_pose})}}) +
                      ShellQuote(runs + "/poses"),
                  400,
                  "invalid",
                  dir);
  ExpectJsonError(ShellQuote(runs + "/tiles/0/1/1"), 404, "not_found", dir);
}

/// Static files: the viewer is served, nothing outside its folder is.
void ExpectOnlyTheWebRootServed(const ServerProcess& server, const fs::path& dir) {
  const CurlResult page = Curl(ShellQuote(server.Url("/index.html")), dir);
  EXPECT_EQ(page.status, 200);
  EXPECT_EQ(page.body, "<html>viewer</html>");
  for (const char* path :
       {"/../secret.txt", "/..%2fsecret.txt", "/%2e%2e/secret.txt", "/../data/index.sqlite"}) {
    const CurlResult r = Curl("--path-as-is " + ShellQuote(server.Url(path)), dir);
    EXPECT_GE(r.status, 400) << path;
    EXPECT_LT(r.status, 500) << path;
    EXPECT_EQ(r.body.find("not for the web"), std::string::npos) << path;
  }
}

TEST(Server, BadInputGetsA4xxJsonErrorAndChangesNothing) {
  ScratchDir scratch("raillomer_server_");
  const fs::path dir = scratch.path();
  fs::create_directories(dir / "web");
  std::ofstream(dir / "web" / "index.html") << "<html>viewer</html>";
  std::ofstream(dir / "secret.txt") << "not for the web";
  std::ofstream(dir / "small.yaml") << "max_body_bytes: 200000\n";
  ServerProcess server(dir / "data",
                       "--config " + ShellQuote((dir / "small.yaml").string()) + " --web-root " +
                           ShellQuote((dir / "web").string()));
  ASSERT_TRUE(server.ok()) << server.log();
  const int64_t run = CreateRun(server, dir);
  const std::string submaps = server.Url("/api/v1/runs/" + std::to_string(run) + "/submaps");
  ExpectBadSubmapsRefused(server, submaps, dir);
  ExpectBadRequestsRefused(server, run, dir);
  ExpectOnlyTheWebRootServed(server, dir);
  // Nothing was stored.
  const CurlResult info = Curl(ShellQuote(server.Url("/api/v1/runs/" + std::to_string(run))), dir);
  EXPECT_EQ(json::parse(info.body)["submaps"], 0);
  EXPECT_EQ(json::parse(info.body)["poses"], 0);
  // And the good one goes in.
  EXPECT_EQ(
      Curl(Bearer(server.token()) + PostFile(dir / "ok.pcd") + ShellQuote(submaps), dir).status,
      201);
}

/// Sends submaps s0.pcd .. s<n-1>.pcd to the run one after another with curl, noting each answer
/// in answers.txt, and kills the server with SIGKILL once half of them are answered.
void SendSubmapsAndKillPartWay(ServerProcess& server, int64_t run, int n, const fs::path& dir) {
  const std::string url = server.Url("/api/v1/runs/" + std::to_string(run) + "/submaps");
  const std::string loop = "for i in $(seq 0 " + std::to_string(n - 1) +
                           "); do curl -s -o /dev/null -w \"$i %{http_code}\\n\" " +
                           Bearer(server.token()) +
                           "-X POST -H 'Content-Type: application/octet-stream' --data-binary @" +
                           ShellQuote(dir.string()) + "/s$i.pcd " + ShellQuote(url) + " >> " +
                           ShellQuote((dir / "answers.txt").string()) + "; done";
  std::thread sender([&] { std::system(("bash -c " + ShellQuote(loop)).c_str()); });
  for (int i = 0; i < 600; ++i) {
    std::ifstream answers(dir / "answers.txt");
    const auto answered =
        std::count(std::istreambuf_iterator<char>(answers), std::istreambuf_iterator<char>(), '\n');
    if (answered >= n / 2) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  server.Stop(SIGKILL);
  sender.join();
}

/// The submaps answered 201 Created in answers.txt.
std::set<int> AcknowledgedSubmaps(const fs::path& dir) {
  std::set<int> acknowledged;
  std::ifstream answers(dir / "answers.txt");
  int i = 0, code = 0;
  while (answers >> i >> code)
    if (code == 201) acknowledged.insert(i);
  return acknowledged;
}

TEST(Server, KillDashNineDuringIngestLosesNothingAcknowledged) {
  ScratchDir scratch("raillomer_server_");
  const fs::path dir = scratch.path();
  const int kSubmaps = 24;
  for (int i = 0; i < kSubmaps; ++i)
    WriteSubmap(dir, CorridorSubmap(i), "s" + std::to_string(i) + ".pcd");
  int64_t run = 0;
  std::string token;
  {
    ServerProcess server(dir / "data");
    ASSERT_TRUE(server.ok()) << server.log();
    run = CreateRun(server, dir);
    token = server.token();
    SendSubmapsAndKillPartWay(server, run, kSubmaps, dir);
  }
  const std::set<int> acknowledged = AcknowledgedSubmaps(dir);
  ASSERT_GE(acknowledged.size(), static_cast<size_t>(kSubmaps / 2));
  ASSERT_LT(acknowledged.size(), static_cast<size_t>(kSubmaps)) << "the kill came too late";

  ServerProcess server(dir / "data");
  ASSERT_TRUE(server.ok()) << server.log();
  // Every acknowledged submap is there with its payload: sending it again is a duplicate.
  for (int a : acknowledged) {
    const CurlResult r =
        Curl(Bearer(token) + PostFile(dir / ("s" + std::to_string(a) + ".pcd")) +
                 ShellQuote(server.Url("/api/v1/runs/" + std::to_string(run) + "/submaps")),
             dir);
    EXPECT_EQ(r.status, 200) << "submap " << a << ": " << r.body;
  }
  // Its points are in the tiles: submaps 0..n-1 cover (n + 1) half-lengths of corridor.
  const CurlResult info = Curl(ShellQuote(server.Url("/api/v1/runs/" + std::to_string(run))), dir);
  const int stored = json::parse(info.body)["submaps"];
  EXPECT_GE(stored, static_cast<int>(acknowledged.size()));
  const int last = *acknowledged.rbegin();
  EXPECT_EQ(*acknowledged.begin(), 0);
  EXPECT_EQ(static_cast<int>(acknowledged.size()), last + 1) << "acknowledged out of order";
  TilesWhenWritten(server, run, int64_t{400 * 110 / 2} * (stored + 1), dir);
  server.Stop(SIGTERM);
  const CommandResult check =
      RunCommand("sqlite3 " + ShellQuote((dir / "data" / "index.sqlite").string()) +
                     " 'PRAGMA integrity_check;'",
                 dir);
  EXPECT_EQ(check.out, "ok\n") << check.err;
}

TEST(Server, LiveHubStreamsPosesToPythonWebsocketClients) {
  ScratchDir scratch("raillomer_server_");
  const fs::path dir = scratch.path();
  std::ofstream(dir / "live.yaml") << "ws_queue_messages: 32\n";
  ServerProcess server(dir / "data", "--config " + ShellQuote((dir / "live.yaml").string()));
  ASSERT_TRUE(server.ok()) << server.log();
  const int64_t run = CreateRun(server, dir);
  const int kPoses = 1500;
  // Three clients read everything; a fourth subscribes and never reads (a tiny receive buffer),
  // so its queue overflows: the others must still get every pose. Batches of 10 poses, one
  // after another: far beyond the estimator's 10 Hz, in bursts the 32-message queues take.
  const std::string script = (SourceDir() / "tests" / "server" / "live_clients.py").string();
  const std::string command = "/usr/bin/python3 " + ShellQuote(script) + " --port " +
                              std::to_string(server.ws_port()) + " --run " + std::to_string(run) +
                              " --clients 3 --slow 1 --expect " + std::to_string(kPoses) +
                              " --timeout 60 > " + ShellQuote((dir / "live.json").string());
  std::thread clients([&] { std::system(command.c_str()); });
  const JoinOnExit join_on_exit{clients};  // they stop by themselves after --timeout
  for (int i = 0; i < 200 && !fs::exists(dir / "live.json.ready"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ASSERT_TRUE(fs::exists(dir / "live.json.ready")) << "the clients did not connect";
  const std::string poses_url = server.Url("/api/v1/runs/" + std::to_string(run) + "/poses");
  for (int batch = 0; batch < kPoses / 10; ++batch) {
    json poses = json::array();
    for (int i = 0; i < 10; ++i) {
      const int seq = batch * 10 + i;
      poses.push_back({{"sequence", seq},
                       {"stamp_ns", 1'600'000'000'000'000'000 + int64_t(seq) * 10'000'000},
                       {"georeferenced", true},
                       {"utm_zone", "50N"},
                       {"p", {432100.0 + seq * 0.1, 3585200.0, 30.0}},
                       {"q", {0.0, 0.0, 0.0, 1.0}}});
    }
    std::ofstream(dir / "batch.json") << json{{"poses", poses}}.dump();
    const CurlResult r = Curl(
        Bearer(server.token()) + "-X POST -H 'Content-Type: application/json' --data-binary @" +
            ShellQuote((dir / "batch.json").string()) + " " + ShellQuote(poses_url),
        dir);
    ASSERT_EQ(r.status, 200) << r.body;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  clients.join();
  const json result = json::parse(ReadText(dir / "live.json"), nullptr, false);
  ASSERT_TRUE(result.is_object()) << ReadText(dir / "live.json");
  for (const auto& c : result["clients"]) {
    EXPECT_EQ(c["poses"], kPoses) << result.dump();
    EXPECT_TRUE(c["in_order"].get<bool>()) << result.dump();
  }
  const CurlResult metrics = Curl(ShellQuote(server.Url("/metrics")), dir);
  const std::string name = "\nraillomer_live_messages_dropped_total ";
  const size_t at = metrics.body.find(name);
  ASSERT_NE(at, std::string::npos) << metrics.body;
  EXPECT_GT(std::stoll(metrics.body.substr(at + name.size())), 0)
      << "the slow client dropped nothing";
}

TEST(Server, ReadsCanNeedATokenAndTheLiveHubSendsTileNotices) {
  ScratchDir scratch("raillomer_server_");
  const fs::path dir = scratch.path();
  std::ofstream(dir / "closed.yaml")
      << "reads_need_token: true\nread_token: read-token-0123456789\n";
  ServerProcess server(dir / "data", "--config " + ShellQuote((dir / "closed.yaml").string()));
  ASSERT_TRUE(server.ok()) << server.log();
  const int64_t run = CreateRun(server, dir);
  const std::string runs = server.Url("/api/v1/runs");
  EXPECT_EQ(Curl(ShellQuote(runs), dir).status, 401);
  EXPECT_EQ(Curl(Bearer("read-token-0123456789") + ShellQuote(runs), dir).status, 200);
  EXPECT_EQ(Curl(Bearer(server.token()) + ShellQuote(runs), dir).status, 200);
  // The read token may read, not write.
  EXPECT_EQ(Curl(Bearer("read-token-0123456789") + PostJson({{"line", "x"}, {"vehicle", "y"}}) +
                     ShellQuote(runs),
                 dir)
                .status,
            401);
  EXPECT_EQ(server.log().find("read-token-0123456789"), std::string::npos);

  // The live hub refuses a client without the token; one with it hears of the tiles a submap
  // wrote.
  const std::string script = (SourceDir() / "tests" / "server" / "live_notice.py").string();
  const std::string base = "/usr/bin/python3 " + ShellQuote(script) + " --port " +
                           std::to_string(server.ws_port()) + " --run " + std::to_string(run) +
                           " --ready " + ShellQuote((dir / "ready").string());
  const CommandResult refused = RunCommand(base + " --timeout 5", dir);
  EXPECT_EQ(refused.exit_code, 2) << refused.out << refused.err;
  EXPECT_NE(refused.err.find("401"), std::string::npos) << refused.err;
  CommandResult notice;
  std::thread listener([&] { notice = RunCommand(base + " --token read-token-0123456789", dir); });
  for (int i = 0; i < 200 && !fs::exists(dir / "ready"); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const CurlResult r =
      Curl(Bearer(server.token()) + PostFile(WriteSubmap(dir, CorridorSubmap(0), "s0.pcd")) +
               ShellQuote(runs + "/" + std::to_string(run) + "/submaps"),
           dir);
  EXPECT_EQ(r.status, 201) << r.body;
  listener.join();
  ASSERT_EQ(notice.exit_code, 0) << notice.out << notice.err;
  const json m = json::parse(notice.out);
  EXPECT_EQ(m["run"], run);
  EXPECT_FALSE(m["tiles"].empty());
  EXPECT_EQ(m["tiles"][0]["version"], 1);
}

TEST(Server, ServesEveryRouteOfItsOpenApiDescription) {
  ScratchDir scratch("raillomer_server_");
  ServerProcess server(scratch.path() / "data");
  ASSERT_TRUE(server.ok()) << server.log();
  CreateRun(server, scratch.path());
  const YAML::Node doc = YAML::LoadFile((SourceDir() / "api" / "openapi.yaml").string());
  ASSERT_EQ(doc["openapi"].as<std::string>().rfind("3.", 0), 0u);
  int routes = 0;
  for (const auto& entry : doc["paths"]) {
    std::string path = entry.first.as<std::string>();
    for (const auto& [from, to] : std::vector<std::pair<std::string, std::string>>{{"{run}", "1"},
                                                                                   {"{level}", "0"},
                                                                                   {"{ix}", "0"},
                                                                                   {"{iy}", "0"},
                                                                                   {"{line}", "L"},
                                                                                   {"{id}", "1"}}) {
      const size_t at = path.find(from);
      if (at != std::string::npos) path.replace(at, from.size(), to);
    }
    for (const char* method : {"get", "post", "put", "patch", "delete"}) {
      if (!entry.second[method]) continue;
      ++routes;
      std::string upper = method;
      for (char& c : upper) c = static_cast<char>(std::toupper(c));
      const std::string body = upper == "GET" ? "" : "--data-binary '{}' ";
      const CurlResult r = Curl("-X " + upper + " -H 'Content-Type: application/json' " + body +
                                    Bearer(server.token()) + ShellQuote(server.Url(path)),
                                scratch.path());
      // Anything but the router's own "no resource": the route exists (a 404 for a missing
      // tile is the route answering).
      EXPECT_NE(r.status, 0) << upper << " " << path;
      EXPECT_EQ(r.body.find("no resource at"), std::string::npos) << upper << " " << path;
    }
  }
  EXPECT_GE(routes, 12);
}

/// The lines of a TUM file that are poses.
int TumPoses(const fs::path& file) {
  std::ifstream in(file);
  int poses = 0;
  for (std::string line; std::getline(in, line);)
    if (!line.empty() && line[0] != '#') ++poses;
  return poses;
}

/// The store in `dir`/data holds `poses` poses and `submaps` submaps, each numbered apart 0, 1,
/// 2, ... without a gap or a repeat (read with the sqlite3 tool).
void ExpectNumberedOnce(const fs::path& dir, int poses, int submaps) {
  const CommandResult sql =
      RunCommand("sqlite3 " + ShellQuote((dir / "data" / "index.sqlite").string()) +
                     " 'SELECT count(*), max(sequence) FROM poses; SELECT count(*), "
                     "max(sequence) FROM submaps;'",
                 dir);
  EXPECT_EQ(sql.out,
            std::to_string(poses) + "|" + std::to_string(poses - 1) + "\n" +
                std::to_string(submaps) + "|" + std::to_string(submaps - 1) + "\n")
      << sql.err;
}

TEST(Server, AnOutageWhileTheEstimatorStreamsLosesNothingAndDuplicatesNothing) {
  ScratchDir scratch("raillomer_server_");
  const fs::path dir = scratch.path();
  auto server = std::make_unique<ServerProcess>(dir / "data");
  ASSERT_TRUE(server->ok()) << server->log();
  const int port = server->port(), ws_port = server->ws_port();
  // The estimator streams the simulated demo run (30 s of data, about 12 s of work) while the
  // server is killed and comes back on the same port 3 s later.
  const std::string command =
      (BinDir() / "raillomer-estimator").string() + " --sim demo --quiet --no-keyframes --out " +
      ShellQuote((dir / "estimate").string()) + " --server " + ShellQuote(server->Url("")) +
      " --token " + server->token() + " --line Demo --vehicle RLM-1 > " +
      ShellQuote((dir / "estimator.log").string()) + " 2>&1";
  int exit_code = -1;
  std::thread estimator([&] { exit_code = WEXITSTATUS(std::system(command.c_str())); });
  const JoinOnExit join_on_exit{estimator};  // it gives up on the server after --server-wait
  // Once poses flow (GNSS aligned), the server is killed mid-run.
  for (int i = 0; i < 1200; ++i) {
    const CurlResult r = Curl(ShellQuote(server->Url("/api/v1/runs/1")), dir);
    const json j = json::parse(r.body, nullptr, false);
    if (r.status == 200 && j.is_object() && j["poses"].get<int>() >= 20) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  server->Stop(SIGKILL);
  std::this_thread::sleep_for(std::chrono::seconds(3));
  server = std::make_unique<ServerProcess>(dir / "data", "", port, ws_port);
  ASSERT_TRUE(server->ok()) << server->log();
  estimator.join();
  const std::string log = ReadText(dir / "estimator.log");
  ASSERT_EQ(exit_code, 0) << log;
  EXPECT_NE(log.find("buffering in"), std::string::npos) << "the outage was not noticed: " << log;

  // Every pose and submap the estimator wrote is on the server once: the sequence numbers run
  // without a gap, and the counts match what the estimator wrote itself.
  const json summary = json::parse(ReadText(dir / "estimate" / "summary.json"));
  const int poses = TumPoses(dir / "estimate" / "trajectory.tum");
  const CurlResult run = Curl(ShellQuote(server->Url("/api/v1/runs/1")), dir);
  const json r = json::parse(run.body);
  EXPECT_EQ(r["status"], "finished");
  EXPECT_EQ(r["poses"], poses);
  EXPECT_EQ(r["submaps"], summary["submaps"]["count"]);
  server->Stop(SIGTERM);
  ExpectNumberedOnce(dir, poses, summary["submaps"]["count"].get<int>());
}

/// The estimator streaming the first 20 s of the simulated demo run (7 submaps) into `server`
/// with the outbox in `out`.
std::string DemoEstimator(const ServerProcess& server,
                          const fs::path& out,
                          const fs::path& log,
                          const std::string& flags = "") {
  return (BinDir() / "raillomer-estimator").string() +
         " --sim demo --duration 20 --quiet --no-keyframes --out " + ShellQuote(out.string()) +
         " --server " + ShellQuote(server.Url("")) + " --token " + server.token() +
         " --line Demo --vehicle RLM-1" + flags + " > " + ShellQuote(log.string()) + " 2>&1";
}

/// A counter of the server's /metrics.
int64_t Metric(const ServerProcess& server, const std::string& name, const fs::path& scratch) {
  const std::string text = Curl(ShellQuote(server.Url("/metrics")), scratch).body;
  const size_t at = text.find("\n" + name + " ");
  return at == std::string::npos ? -1 : std::stoll(text.substr(at + name.size() + 2));
}

/// Run 1 as the server has it.
json RunOne(const ServerProcess& server, const fs::path& scratch) {
  return json::parse(Curl(ShellQuote(server.Url("/api/v1/runs/1")), scratch).body, nullptr, false);
}

/// Starts the demo estimator streaming to the server and kills it (kill -9) once run 1 holds 20
/// poses and at least `submaps` submaps.
void KillEstimatorOnceItSent(const ServerProcess& server,
                             int submaps,
                             const fs::path& out,
                             const fs::path& dir) {
  ChildProcess first(DemoEstimator(server, out, dir / "first.log"));
  for (int i = 0; i < 1200 && first.Running(); ++i) {
    const json run = RunOne(server, dir);
    if (run.is_object() && run.contains("poses") && run["poses"].get<int>() >= 20 &&
        run["submaps"].get<int>() >= submaps)
      break;
    std::this_thread::sleep_for(std::chrono::milliseconds(25));
  }
  ASSERT_TRUE(first.Running()) << "the first run ended before the kill";
  first.Signal(SIGKILL);
}

/// Run 1 is the one the first start began, finished, with every pose and submap the rerun wrote
/// and nothing the server had sent again, but for what the kill may have caught between the
/// server's answer and the outbox letting the message go: one batch or one submap.
void ExpectTheRunWholeAndOnce(const ServerProcess& server,
                              const fs::path& out,
                              const fs::path& dir) {
  const json summary = json::parse(ReadText(out / "summary.json"));
  const json run = RunOne(server, dir);
  EXPECT_EQ(run["status"], "finished");
  EXPECT_EQ(run["poses"], TumPoses(out / "trajectory.tum"));
  EXPECT_EQ(run["submaps"], summary["submaps"]["count"].get<int>());
  EXPECT_EQ(run["submaps_lost"], 0);
  EXPECT_EQ(Curl(ShellQuote(server.Url("/api/v1/runs")), dir).body.find("\"id\":2"),
            std::string::npos)
      << "a second run was created";
  EXPECT_TRUE(fs::is_empty(out / "outbox" / "rejected"));
  EXPECT_LE(Metric(server, "raillomer_submaps_duplicate_total", dir), 1);
  EXPECT_LE(Metric(server, "raillomer_poses_duplicate_total", dir), 10);
}

TEST(Server, AnEstimatorRestartedOnItsOutboxResumesTheRunWithoutADuplicate) {
  // Killed (kill -9) once poses flow, after 2 submaps, and after 4 submaps with the server
  // killed too; each time the estimator is started again on the same --out and finishes. The
  // second rerun has other sensor noise (--seed 2), as a rerun whose results differ in their
  // last digits would: what the server has must not be sent again, in any form.
  struct KillPoint {
    int submaps;
    bool server_too;
    const char* rerun_flags;
  };
  for (const KillPoint kill :
       {KillPoint{0, false, ""}, KillPoint{2, false, " --seed 2"}, KillPoint{4, true, ""}}) {
    SCOPED_TRACE("killed after " + std::to_string(kill.submaps) + " submaps" +
                 (kill.server_too ? ", the server too" : "") + kill.rerun_flags);
    ScratchDir scratch("raillomer_server_");
    const fs::path dir = scratch.path(), out = dir / "estimate";
    auto server = std::make_unique<ServerProcess>(dir / "data");
    ASSERT_TRUE(server->ok()) << server->log();
    const int port = server->port(), ws_port = server->ws_port();
    ASSERT_NO_FATAL_FAILURE(KillEstimatorOnceItSent(*server, kill.submaps, out, dir));
    if (kill.server_too) {
      server->Stop(SIGKILL);
      server = std::make_unique<ServerProcess>(dir / "data", "", port, ws_port);
      ASSERT_TRUE(server->ok()) << server->log();
    }
    const json before = RunOne(*server, dir);
    ChildProcess again(DemoEstimator(*server, out, dir / "again.log", kill.rerun_flags));
    const int exit_code = again.Wait();
    const std::string log = ReadText(dir / "again.log");
    ASSERT_EQ(exit_code, 0) << log;
    EXPECT_NE(log.find("resuming run 1 from the outbox"), std::string::npos) << log;
    EXPECT_GE(before["submaps"].get<int>(), kill.submaps);
    ExpectTheRunWholeAndOnce(*server, out, dir);
    server->Stop(SIGTERM);
    const int submaps = json::parse(ReadText(out / "summary.json"))["submaps"]["count"].get<int>();
    ExpectNumberedOnce(dir, TumPoses(out / "trajectory.tum"), submaps);
  }
}

}  // namespace
}  // namespace raillomer::test
