// raillomer-estimator: the onboard state estimator (paper section IV) on a recorded bag or on
// the in-process simulator.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <thread>

#include <sys/resource.h>

#include <CLI/CLI.hpp>

#include "api/atomic_file.h"
#include "api/ingest_client.h"
#include "api/trajectory.h"
#include "estimator/io/bag_reader.h"
#include "estimator/mapping/map_export.h"
#include "estimator/pipeline/config.h"
#include "estimator/pipeline/estimator.h"
#include "estimator/pipeline/run_writer.h"
#include "estimator/sim/simulator.h"

using namespace raillomer;

namespace {

int Fail(const std::string& message) {
  std::cerr << "raillomer-estimator: error: " << message << "\n";
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-estimator: dual-LiDAR / IMU / wheel-odometer sliding-window odometry with rail "
      "constraints (RailLoMer section IV). Reads a ROS1 bag (or runs the built-in simulator) and "
      "writes trajectory.tum, timing.csv, keyframes, submaps and summary.json to --out."};
  std::string bag_path, sim_scenario, config_path, out_dir;
  double duration_s = -1.0;
  int64_t seed = -1;
  bool no_odometer = false, no_rail_plane = false, no_height = false, no_favour = false;
  bool lidar_only = false, lidar_inertial = false, no_keyframes = false, quiet = false;
  bool realtime = false;
  bool no_gnss = false, no_submaps = false, provisional_submaps = false;
  std::string map_path, map_box_text;
  std::string server_url, token, token_file, outbox_dir, line = "unnamed line",
                                                         vehicle = "unnamed vehicle";
  double server_wait_s = 120.0;
  double map_voxel_m = 0.1;
  auto* source = app.add_option_group("source", "Where the sensor data comes from");
  source->add_option("--bag", bag_path, "ROS1 bag of the sensor data contract");
  source->add_option(
      "--sim", sim_scenario, "Run the simulator in-process: built-in scenario name or YAML");
  source->require_option(1);
  app.add_option("--config",
                 config_path,
                 "Rig configuration YAML (required with --bag; --sim uses the scenario's rig)");
  app.add_option("--out", out_dir, "Output folder (created if missing)")->required();
  app.add_option("--duration", duration_s, "Process only the first N seconds of data")
      ->check(CLI::PositiveNumber);
  app.add_option("--seed", seed, "With --sim: noise seed (the corridor keeps its world_seed)")
      ->check(CLI::Range(int64_t{0}, int64_t{4294967295}));
  app.add_flag("--no-odometer", no_odometer, "Ablation: ignore the wheel odometer");
  app.add_flag("--no-rail-plane", no_rail_plane, "Ablation: no rail-plane factor (eq. 28-30)");
  app.add_flag(
      "--no-height-descriptor", no_height, "Ablation: no height-descriptor factor (eq. 27)");
  app.add_flag("--no-favour-factors", no_favour, "Ablation: LiDAR weights of eq. (23) all 1");
  app.add_flag(
      "--lidar-inertial",
      lidar_inertial,
      "Ablation: the LiDAR-inertial subset (no odometer, rail plane or height descriptor)");
  app.add_flag("--lidar-only",
               lidar_only,
               "Ablation: LiDAR odometry alone (no IMU, odometer or rail factors)");
  app.add_flag(
      "--no-gnss",
      no_gnss,
      "Ablation: ignore GNSS (odometry only, in the local frame, as part 1 of the estimator)");
  app.add_flag("--no-keyframes", no_keyframes, "Do not write keyframe clouds");
  app.add_flag("--no-submaps", no_submaps, "Do not write submaps (submaps/)");
  app.add_flag("--provisional-submaps",
               provisional_submaps,
               "Also write the provisional submaps (provisional/): what a server is sent ahead of "
               "the final output where the GNSS fusion holds poses back (a run's start, an "
               "outage)");
  app.add_option("--map",
                 map_path,
                 "Write the global map of the whole run to this .ply or .pcd file (double x y z: "
                 "UTM when georeferenced, float intensity) or .las file (LAS 1.2 at 1 mm, the "
                 "UTM zone as its EPSG code)");
  app.add_option(
         "--map-voxel", map_voxel_m, "With --map: one point per voxel of this size (0: all)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--map-box",
                 map_box_text,
                 "With --map: only points inside the horizontal box x0,y0,x1,y1 (UTM easting, "
                 "northing when georeferenced)");
  app.add_flag("--realtime",
               realtime,
               "Feed the data at the rate it was recorded (as a train delivers it), not as fast as "
               "it can be processed");
  app.add_flag(
      "--quiet", quiet, "No progress line, configuration log or milestones (warnings still print)");
  app.add_option("--server",
                 server_url,
                 "Stream poses and submaps to raillomer-server at this URL (http://host:port), "
                 "through a durable outbox: an outage loses nothing");
  app.add_option("--token", token, "With --server: the server's ingest token");
  app.add_option("--token-file", token_file, "With --server: read the ingest token from this file");
  app.add_option("--outbox", outbox_dir, "With --server: the outbox folder (default <out>/outbox)");
  app.add_option("--line", line, "With --server: the railway line's name");
  app.add_option("--vehicle", vehicle, "With --server: the vehicle's name");
  app.add_option("--server-wait",
                 server_wait_s,
                 "With --server: seconds to wait at the end for the backlog to drain (default 120)")
      ->check(CLI::NonNegativeNumber);
  CLI11_PARSE(app, argc, argv);

  // Sensor source and configuration.
  EstimatorConfig config;
  std::string error;
  std::unique_ptr<io::SensorSource> input;
  io::BagReader* bag = nullptr;
  sim::Simulator* simulator = nullptr;
  double data_start_s = 0.0, data_end_s = 0.0;
  if (!sim_scenario.empty()) {
    sim::Scenario scenario;
    if (!sim::LoadScenario(sim_scenario, &scenario, &error)) return Fail(error);
    sim::SimOptions options;
    options.duration_s = duration_s;
    if (seed >= 0) options.seed = static_cast<uint32_t>(seed);
    auto s = sim::Simulator::Create(scenario, options, &error);
    if (!s) return Fail(error);
    simulator = s.get();
    if (config_path.empty()) {
      if (!ParseEstimatorConfig(s->RigYaml(), "sim:" + sim_scenario + "/rig.yaml", &config, &error))
        return Fail(error);
    }
    data_end_s = s->duration_s();
    input = std::move(s);
  }
  if (!config_path.empty() && !LoadEstimatorConfig(config_path, &config, &error))
    return Fail(error);
  if (!bag_path.empty()) {
    if (config_path.empty())
      return Fail("--config is required with --bag (the rig.yaml of the recording)");
    io::BagTopics topics;
    topics.lidar.clear();
    for (const LidarRig& l : config.rig.lidars) topics.lidar.push_back(l.topic);
    topics.imu = config.rig.imu_topic;
    topics.odometer = config.rig.odometer_topic;
    topics.gnss = no_gnss ? std::string() : config.rig.gnss_topic;
    if (lidar_only) topics.imu.clear();
    if (lidar_only || lidar_inertial || no_odometer) topics.odometer.clear();
    auto reader = io::BagReader::Open(bag_path, topics, &error);
    if (!reader) return Fail(error);
    bag = reader.get();
    data_start_s = static_cast<double>(reader->Summary().start_ns) * 1e-9;
    data_end_s = static_cast<double>(reader->Summary().end_ns) * 1e-9;
    input = std::move(reader);
  }
  AblationSwitches& sw = config.options.switches;
  if (no_odometer || lidar_inertial || lidar_only) sw.use_odometer = false;
  if (no_rail_plane || lidar_inertial || lidar_only) sw.use_rail_plane = false;
  if (no_height || lidar_inertial || lidar_only) sw.use_height_descriptor = false;
  if (no_favour || lidar_only) sw.use_favour_factors = false;
  if (lidar_only) sw.use_imu = false;
  if (no_gnss) sw.use_gnss = false;
  if (no_keyframes) config.options.write_keyframes = false;
  if (!quiet) {
    std::cerr << "raillomer-estimator: " << (bag ? "bag " + bag_path : "simulator " + sim_scenario)
              << " -> " << out_dir << "\n";
    std::istringstream lines(config.Describe());
    for (std::string text; std::getline(lines, text);) std::cerr << "  " << text << "\n";
  }

  RunWriter writer;
  std::ostringstream header;
  header << "# raillomer-estimator " << sw.Name()
         << ": body pose at every LiDAR frame, local frame "
         << "(first state at the origin, yaw 0, gravity-aligned), rig " << config.rig.rig << "\n";
  if (!writer.Open(out_dir, config.options.write_keyframes, header.str(), &error))
    return Fail(error);

  // Submaps go to submaps/ and, with --map, into the global map as they complete.
  MapExportOptions map_options;
  map_options.voxel_m = map_voxel_m;
  if (!map_box_text.empty()) {
    double v[4];
    char tail = 0;
    if (std::sscanf(map_box_text.c_str(), "%lf,%lf,%lf,%lf%c", &v[0], &v[1], &v[2], &v[3], &tail) !=
            4 ||
        !(v[0] < v[2] && v[1] < v[3])) {
      return Fail("--map-box '" + map_box_text + "' is not x0,y0,x1,y1 with x0 < x1 and y0 < y1");
    }
    map_options.has_box = true;
    map_options.box_min = Eigen::Vector2d(v[0], v[1]);
    map_options.box_max = Eigen::Vector2d(v[2], v[3]);
  }
  if (map_path.empty() && (!map_box_text.empty() || app.count("--map-voxel") > 0))
    return Fail("--map-voxel and --map-box need --map <file.ply|file.pcd|file.las>");
  std::unique_ptr<MapExporter> map;
  if (!map_path.empty()) {
    map = MapExporter::Open(map_path, map_options, &error);
    if (!map) return Fail(error);
  }
  if (!no_submaps && !writer.OpenSubmaps(&error)) return Fail(error);
  if (provisional_submaps && !writer.OpenProvisional(&error)) return Fail(error);
  // Streaming to the server, through the durable outbox.
  std::unique_ptr<api::IngestClient> ingest;
  if (server_url.empty() && (!token.empty() || !token_file.empty() || !outbox_dir.empty()))
    return Fail("--token, --token-file and --outbox need --server <url>");
  if (!server_url.empty()) {
    if (!token_file.empty()) {
      std::ifstream in(token_file);
      if (!in || !std::getline(in, token)) return Fail("cannot read the token from " + token_file);
    }
    api::IngestClientOptions o;
    o.server_url = server_url;
    o.token = token;
    o.outbox_dir = outbox_dir.empty() ? out_dir + "/outbox" : outbox_dir;
    o.line = line;
    o.vehicle = vehicle;
    o.start_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                     std::chrono::system_clock::now().time_since_epoch())
                     .count();
    ingest = std::make_unique<api::IngestClient>(o);
    ingest->SetWarningHandler([quiet](const std::string& m) {
      std::cerr << (quiet ? "" : "\r") << "raillomer-estimator: server: " << m << "\n";
    });
    if (!ingest->Start(&error)) return Fail(error);
    const api::IngestClient::Resume resume = ingest->resume();
    if (resume.resuming())
      std::cerr << "raillomer-estimator: resuming "
                << (resume.run_id > 0 ? "run " + std::to_string(resume.run_id) : "the run")
                << " from the outbox " << o.outbox_dir << ": poses up to " << resume.pose_sequence
                << " and submaps up to " << resume.submap_sequence
                << " were sent or queued by an earlier start and are not sent again\n";
  }
  struct Stream : api::StreamSink {
    RunWriter* writer;
    MapExporter* map;
    api::IngestClient* ingest;
    bool write_submaps, write_provisional;
    void OnPose(const api::StreamPose& p) override {
      if (ingest) ingest->OnPose(p);
    }
    void OnSubmap(const api::Submap& s) override {
      if (write_submaps) writer->WriteSubmap(s);
      if (map) map->Add(s);
      if (ingest) ingest->OnSubmap(s);
    }
    void OnProvisionalPose(const api::StreamPose& p) override {
      if (ingest) ingest->OnProvisionalPose(p);
    }
    void OnProvisionalSubmap(const api::Submap& s) override {
      if (write_provisional) writer->WriteProvisionalSubmap(s);
      if (ingest) ingest->OnProvisionalSubmap(s);
    }
  } stream;
  stream.writer = &writer;
  stream.map = map.get();
  stream.ingest = ingest.get();
  stream.write_submaps = !no_submaps;
  stream.write_provisional = provisional_submaps;

  EstimatorSinks sinks;
  if (!no_submaps || provisional_submaps || map || ingest) sinks.stream = &stream;
  sinks.on_frame = [&](const FrameResult& f) { writer.WriteFrame(f); };
  if (config.options.write_keyframes)
    sinks.on_keyframe = [&](const Keyframe& k) { writer.WriteKeyframe(k); };
  sinks.on_warning = [&](const std::string& m) {
    std::cerr << (quiet ? "" : "\r") << "raillomer-estimator: warning: " << m << "\n";
  };
  sinks.on_info = [&](const std::string& m) {
    if (!quiet) std::cerr << "\rraillomer-estimator: " << m << "\n";
  };
  Estimator estimator(config, sinks);

  const auto wall_start = std::chrono::steady_clock::now();
  auto last_report = wall_start;
  io::SensorMessage message;
  double first_s = -1.0, last_s = 0.0;
  api::Trajectory sim_fixes;  // --sim: the receiver's fixes in UTM, written beside the truth
  while (input->Next(&message)) {
    if (simulator) {
      if (const auto* fix = std::get_if<io::GnssFix>(&message.data))
        sim_fixes.poses.push_back(simulator->FixInUtm(*fix));
    }
    const double t = static_cast<double>(message.receive_ns) * 1e-9;
    if (first_s < 0.0) first_s = t;
    if (bag && duration_s > 0.0 && t - first_s > duration_s) break;
    last_s = std::max(last_s, t);
    if (realtime)
      std::this_thread::sleep_until(wall_start +
                                    std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::duration<double>(t - first_s)));
    estimator.Add(message);
    const auto now = std::chrono::steady_clock::now();
    if (!quiet && now - last_report > std::chrono::seconds(5)) {
      last_report = now;
      const double wall = std::chrono::duration<double>(now - wall_start).count();
      const double total = bag ? data_end_s - data_start_s : data_end_s;
      std::fprintf(stderr,
                   "\r  %6.1f / %.1f s of data, %llu frames, %.2f km, %.1fx real time, median %.1f "
                   "ms/frame%s   ",
                   last_s - first_s,
                   total,
                   static_cast<unsigned long long>(estimator.stats().frames),
                   estimator.stats().distance_m / 1000.0,
                   (last_s - first_s) / wall,
                   writer.MedianFrameMs(),
                   ingest ? (", server backlog " + std::to_string(ingest->backlog().messages) +
                             (ingest->backlog().connected || ingest->backlog().retries == 0
                                  ? ""
                                  : " (server away)"))
                                .c_str()
                          : "");
      std::fflush(stderr);
    }
  }
  estimator.Finish();
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  const double data_s = std::max(0.0, last_s - first_s);

  std::string input_error;
  if (bag && !bag->error().empty()) input_error = bag->error();
  if (simulator) {
    // The truth beside the estimate, for raillomer-eval, the receiver's fixes (UTM) and the
    // IMU's true biases.
    const api::Trajectory truth = simulator->TruthTrajectory(100.0);
    sim_fixes.utm_zone = truth.utm_zone;
    std::string truth_error;
    if (!api::WriteFileAtomically(out_dir + "/truth.tum", api::FormatTum(truth), &truth_error) ||
        !api::WriteFileAtomically(out_dir + "/gnss.tum", api::FormatTum(sim_fixes), &truth_error) ||
        !api::WriteFileAtomically(
            out_dir + "/imu_bias.csv", simulator->ImuBiasCsv(), &truth_error)) {
      return Fail(truth_error);
    }
  }
  std::ostringstream extra;
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  extra << "\"ablation\": \"" << sw.Name() << "\",\n  \"source\": \"" << (bag ? "bag" : "sim")
        << "\",\n  \"peak_rss_mb\": " << static_cast<double>(usage.ru_maxrss) / 1024.0;
  if (!writer.Close(estimator.stats(), data_s, wall_s, extra.str(), &error)) return Fail(error);
  if (map) {
    if (!map->Close(&error)) return Fail(error);
    if (map->skipped_submaps() > 0) {
      std::cerr << "raillomer-estimator: warning: " << map->skipped_submaps()
                << " submaps in another frame than the first were left out of " << map_path << "\n";
    }
    if (!quiet) std::cerr << "  map: " << map->points() << " points -> " << map_path << "\n";
  }
  if (!quiet) {
    std::fprintf(stderr,
                 "\r  done: %zu frames, %.2f km in %.1f s (%.2fx real time), median %.1f ms/frame, "
                 "p95 %.1f ms\n",
                 writer.frames(),
                 estimator.stats().distance_m / 1000.0,
                 wall_s,
                 wall_s > 0 ? data_s / wall_s : 0.0,
                 writer.MedianFrameMs(),
                 writer.PercentileFrameMs(0.95));
  }
  if (ingest) {
    if (!quiet)
      std::cerr << "  server: sending the last " << ingest->backlog().messages
                << " messages and finishing the run ...\n";
    std::string drain_error;
    const bool drained = ingest->Finish(server_wait_s, &drain_error);
    const api::IngestClient::Backlog b = ingest->backlog();
    if (!quiet || !drained) {
      std::cerr << "  server: run " << b.run_id << ", " << b.sent << " messages acknowledged, "
                << b.retries << " failed attempts, " << b.rejected << " rejected, " << b.messages
                << " left in the outbox";
      if (b.skipped > 0)
        std::cerr << "; resumed: " << b.skipped
                  << " poses and submaps skipped (the outbox had them from an earlier start)";
      std::cerr << "\n";
    }
    if (!drained) return Fail("the server did not take everything: " + drain_error);
    if (b.rejected > 0)
      return Fail(std::to_string(b.rejected) +
                  " messages were rejected by the server (kept in "
                  "the outbox's rejected/ folder)");
  }
  if (!input_error.empty()) {
    return Fail("the input stopped early: " + input_error + " (the " +
                std::to_string(writer.frames()) + " frames before it are written)");
  }
  if (writer.frames() == 0)
    return Fail("no frame was processed: check the LiDAR and IMU topics of the config");
  return 0;
}
