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
#include "api/cli_checks.h"
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

/// The command line.
struct Options {
  std::string bag_path, sim_scenario, config_path, out_dir;
  double duration_s = -1.0;
  int64_t seed = -1;
  bool no_odometer = false, no_rail_plane = false, no_height = false, no_favour = false;
  bool lidar_only = false, lidar_inertial = false, no_keyframes = false, quiet = false;
  bool realtime = false;
  bool no_gnss = false, no_submaps = false, provisional_submaps = false;
  std::string map_path, map_box_text;
  double map_voxel_m = 0.1;
  bool map_voxel_given = false;
  std::string server_url, token, token_file, outbox_dir, line = "unnamed line",
                                                         vehicle = "unnamed vehicle";
  double server_wait_s = 120.0;
};

void AddSourceOptions(CLI::App* app, Options* o) {
  auto* source = app->add_option_group("source", "Where the sensor data comes from");
  source->add_option("--bag", o->bag_path, "ROS1 bag of the sensor data contract")
      ->check(api::NotEmpty());
  source
      ->add_option(
          "--sim", o->sim_scenario, "Run the simulator in-process: built-in scenario name or YAML")
      ->check(api::NotEmpty());
  source->require_option(1);
  app->add_option("--config",
                  o->config_path,
                  "Rig configuration YAML (required with --bag; --sim uses the scenario's rig)");
  app->add_option("--out", o->out_dir, "Output folder (created if missing)")->required();
  app->add_option("--duration", o->duration_s, "Process only the first N seconds of data")
      ->check(api::FinitePositive());
  app->add_option("--seed", o->seed, "With --sim: noise seed (the corridor keeps its world_seed)")
      ->check(CLI::Range(int64_t{0}, int64_t{4294967295}));
  app->add_flag("--realtime",
                o->realtime,
                "Feed the data at the rate it was recorded (as a train delivers it), not as fast "
                "as it can be processed");
  app->add_flag("--quiet",
                o->quiet,
                "No progress line, configuration log or milestones (warnings still print)");
}

void AddAblationOptions(CLI::App* app, Options* o) {
  app->add_flag("--no-odometer", o->no_odometer, "Ablation: ignore the wheel odometer");
  app->add_flag("--no-rail-plane", o->no_rail_plane, "Ablation: no rail-plane factor (eq. 28-30)");
  app->add_flag(
      "--no-height-descriptor", o->no_height, "Ablation: no height-descriptor factor (eq. 27)");
  app->add_flag("--no-favour-factors", o->no_favour, "Ablation: LiDAR weights of eq. (23) all 1");
  app->add_flag(
      "--lidar-inertial",
      o->lidar_inertial,
      "Ablation: the LiDAR-inertial subset (no odometer, rail plane or height descriptor)");
  app->add_flag("--lidar-only",
                o->lidar_only,
                "Ablation: LiDAR odometry alone (no IMU, odometer or rail factors)");
  app->add_flag(
      "--no-gnss",
      o->no_gnss,
      "Ablation: ignore GNSS (odometry only, in the local frame, as part 1 of the estimator)");
}

void AddOutputOptions(CLI::App* app, Options* o) {
  app->add_flag("--no-keyframes", o->no_keyframes, "Do not write keyframe clouds");
  app->add_flag("--no-submaps", o->no_submaps, "Do not write submaps (submaps/)");
  app->add_flag("--provisional-submaps",
                o->provisional_submaps,
                "Also write the provisional submaps (provisional/): what a server is sent ahead "
                "of the final output where the GNSS fusion holds poses back (a run's start, an "
                "outage)");
  app->add_option("--map",
                  o->map_path,
                  "Write the global map of the whole run to this .ply or .pcd file (double x y z: "
                  "UTM when georeferenced, float intensity) or .las file (LAS 1.2 at 1 mm, the "
                  "UTM zone as its EPSG code)");
  app->add_option(
         "--map-voxel", o->map_voxel_m, "With --map: one point per voxel of this size (0: all)")
      ->check(api::FiniteNonNegative());
  app->add_option("--map-box",
                  o->map_box_text,
                  "With --map: only points inside the horizontal box x0,y0,x1,y1 (UTM easting, "
                  "northing when georeferenced)");
}

void AddServerOptions(CLI::App* app, Options* o) {
  app->add_option("--server",
                  o->server_url,
                  "Stream poses and submaps to raillomer-server at this URL (http://host:port), "
                  "through a durable outbox: an outage loses nothing");
  app->add_option("--token", o->token, "With --server: the server's ingest token");
  app->add_option(
      "--token-file", o->token_file, "With --server: read the ingest token from this file");
  app->add_option(
      "--outbox", o->outbox_dir, "With --server: the outbox folder (default <out>/outbox)");
  app->add_option("--line", o->line, "With --server: the railway line's name");
  app->add_option("--vehicle", o->vehicle, "With --server: the vehicle's name");
  app->add_option("--server-wait",
                  o->server_wait_s,
                  "With --server: seconds to wait at the end for the backlog to drain (default "
                  "120)")
      ->check(api::FiniteNonNegative());
}

/// Where the sensor data comes from: a bag or the simulator, and the span of its data.
struct Source {
  std::unique_ptr<io::SensorSource> input;
  io::BagReader* bag = nullptr;
  sim::Simulator* simulator = nullptr;
  double start_s = 0.0, end_s = 0.0;
};

/// The simulator of --sim, with its scenario's rig as the configuration unless --config names
/// one.
bool OpenSimulator(const Options& o, EstimatorConfig* config, Source* source, std::string* error) {
  sim::Scenario scenario;
  if (!sim::LoadScenario(o.sim_scenario, &scenario, error)) return false;
  sim::SimOptions options;
  options.duration_s = o.duration_s;
  if (o.seed >= 0) options.seed = static_cast<uint32_t>(o.seed);
  auto s = sim::Simulator::Create(scenario, options, error);
  if (!s) return false;
  if (o.config_path.empty() &&
      !ParseEstimatorConfig(s->RigYaml(), "sim:" + o.sim_scenario + "/rig.yaml", config, error))
    return false;
  source->simulator = s.get();
  source->end_s = s->duration_s();
  source->input = std::move(s);
  return true;
}

/// The bag of --bag, reading the topics of the configuration's rig that the ablation uses.
bool OpenBag(const Options& o, const EstimatorConfig& config, Source* source, std::string* error) {
  if (o.config_path.empty())
    return *error = "--config is required with --bag (the rig.yaml of the recording)", false;
  io::BagTopics topics;
  topics.lidar.clear();
  for (const LidarRig& l : config.rig.lidars) topics.lidar.push_back(l.topic);
  topics.imu = config.rig.imu_topic;
  topics.odometer = config.rig.odometer_topic;
  topics.gnss = o.no_gnss ? std::string() : config.rig.gnss_topic;
  if (o.lidar_only) topics.imu.clear();
  if (o.lidar_only || o.lidar_inertial || o.no_odometer) topics.odometer.clear();
  auto reader = io::BagReader::Open(o.bag_path, topics, error);
  if (!reader) return false;
  source->bag = reader.get();
  source->start_s = static_cast<double>(reader->Summary().start_ns) * 1e-9;
  source->end_s = static_cast<double>(reader->Summary().end_ns) * 1e-9;
  source->input = std::move(reader);
  return true;
}

/// The sensor data's source and the rig configuration (--config over the scenario's rig).
bool OpenSource(const Options& o, EstimatorConfig* config, Source* source, std::string* error) {
  if (!o.sim_scenario.empty() && !OpenSimulator(o, config, source, error)) return false;
  if (!o.config_path.empty() && !LoadEstimatorConfig(o.config_path, config, error)) return false;
  return o.bag_path.empty() || OpenBag(o, *config, source, error);
}

/// The ablation flags as the estimator's switches.
void ApplyAblations(const Options& o, EstimatorConfig* config) {
  AblationSwitches& sw = config->options.switches;
  if (o.no_odometer || o.lidar_inertial || o.lidar_only) sw.use_odometer = false;
  if (o.no_rail_plane || o.lidar_inertial || o.lidar_only) sw.use_rail_plane = false;
  if (o.no_height || o.lidar_inertial || o.lidar_only) sw.use_height_descriptor = false;
  if (o.no_favour || o.lidar_only) sw.use_favour_factors = false;
  if (o.lidar_only) sw.use_imu = false;
  if (o.no_gnss) sw.use_gnss = false;
  if (o.no_keyframes) config->options.write_keyframes = false;
}

/// The global map of --map, limited to --map-box; null without --map.
bool OpenMap(const Options& o, std::unique_ptr<MapExporter>* map, std::string* error) {
  MapExportOptions map_options;
  map_options.voxel_m = o.map_voxel_m;
  if (!o.map_box_text.empty()) {
    double v[4];
    char tail = 0;
    if (std::sscanf(
            o.map_box_text.c_str(), "%lf,%lf,%lf,%lf%c", &v[0], &v[1], &v[2], &v[3], &tail) != 4 ||
        !(v[0] < v[2] && v[1] < v[3])) {
      return *error =
                 "--map-box '" + o.map_box_text + "' is not x0,y0,x1,y1 with x0 < x1 and y0 < y1",
             false;
    }
    map_options.has_box = true;
    map_options.box_min = Eigen::Vector2d(v[0], v[1]);
    map_options.box_max = Eigen::Vector2d(v[2], v[3]);
  }
  if (o.map_path.empty() && (!o.map_box_text.empty() || o.map_voxel_given))
    return *error = "--map-voxel and --map-box need --map <file.ply|file.pcd|file.las>", false;
  if (o.map_path.empty()) return true;
  *map = MapExporter::Open(o.map_path, map_options, error);
  return *map != nullptr;
}

/// The client streaming to --server through the durable outbox, started; null without
/// --server.
bool StartIngest(const Options& o, std::unique_ptr<api::IngestClient>* ingest, std::string* error) {
  if (o.server_url.empty() && (!o.token.empty() || !o.token_file.empty() || !o.outbox_dir.empty()))
    return *error = "--token, --token-file and --outbox need --server <url>", false;
  if (o.server_url.empty()) return true;
  api::IngestClientOptions c;
  c.server_url = o.server_url;
  c.token = o.token;
  if (!o.token_file.empty()) {
    std::ifstream in(o.token_file);
    if (!in || !std::getline(in, c.token))
      return *error = "cannot read the token from " + o.token_file, false;
  }
  c.outbox_dir = o.outbox_dir.empty() ? o.out_dir + "/outbox" : o.outbox_dir;
  c.line = o.line;
  c.vehicle = o.vehicle;
  c.start_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                   std::chrono::system_clock::now().time_since_epoch())
                   .count();
  *ingest = std::make_unique<api::IngestClient>(c);
  const bool quiet = o.quiet;
  (*ingest)->SetWarningHandler([quiet](const std::string& m) {
    std::cerr << (quiet ? "" : "\r") << "raillomer-estimator: server: " << m << "\n";
  });
  if (!(*ingest)->Start(error)) return false;
  const api::IngestClient::Resume resume = (*ingest)->resume();
  if (resume.resuming())
    std::cerr << "raillomer-estimator: resuming "
              << (resume.run_id > 0 ? "run " + std::to_string(resume.run_id) : "the run")
              << " from the outbox " << c.outbox_dir << ": poses up to " << resume.pose_sequence
              << " and submaps up to " << resume.submap_sequence
              << " were sent or queued by an earlier start and are not sent again\n";
  return true;
}

/// The estimator's stream: submaps to submaps/ (and provisional/), into the global map, and
/// everything to the server.
struct Stream : api::StreamSink {
  RunWriter* writer = nullptr;
  MapExporter* map = nullptr;
  api::IngestClient* ingest = nullptr;
  bool write_submaps = false, write_provisional = false;
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
};

/// Where the estimator's results go: frames and keyframes to the writer, the stream when
/// anything takes it, warnings always and milestones unless quiet.
EstimatorSinks MakeSinks(const Options& o,
                         const EstimatorConfig& config,
                         RunWriter* writer,
                         Stream* stream) {
  EstimatorSinks sinks;
  if (stream->write_submaps || stream->write_provisional || stream->map || stream->ingest)
    sinks.stream = stream;
  sinks.on_frame = [writer](const FrameResult& f) { writer->WriteFrame(f); };
  if (config.options.write_keyframes)
    sinks.on_keyframe = [writer](const Keyframe& k) { writer->WriteKeyframe(k); };
  const bool quiet = o.quiet;
  sinks.on_warning = [quiet](const std::string& m) {
    std::cerr << (quiet ? "" : "\r") << "raillomer-estimator: warning: " << m << "\n";
  };
  sinks.on_info = [quiet](const std::string& m) {
    if (!quiet) std::cerr << "\rraillomer-estimator: " << m << "\n";
  };
  return sinks;
}

/// What feeding the data to the estimator saw.
struct Fed {
  double first_s = -1.0, last_s = 0.0;  ///< receive times of the first and last message
  double wall_s = 0.0;
  api::Trajectory sim_fixes;  ///< --sim: the receiver's fixes in UTM, written beside the truth
};

/// The progress line: data time, frames, distance, speed, and the server's backlog.
void PrintProgress(const Source& source,
                   const Estimator& estimator,
                   const RunWriter& writer,
                   const api::IngestClient* ingest,
                   const Fed& fed,
                   double wall_s) {
  const double total = source.bag ? source.end_s - source.start_s : source.end_s;
  std::string backlog;
  if (ingest) {
    const api::IngestClient::Backlog b = ingest->backlog();
    backlog = ", server backlog " + std::to_string(b.messages) +
              (b.connected || b.retries == 0 ? "" : " (server away)");
  }
  std::fprintf(stderr,
               "\r  %6.1f / %.1f s of data, %llu frames, %.2f km, %.1fx real time, median %.1f "
               "ms/frame%s   ",
               fed.last_s - fed.first_s,
               total,
               static_cast<unsigned long long>(estimator.stats().frames),
               estimator.stats().distance_m / 1000.0,
               (fed.last_s - fed.first_s) / wall_s,
               writer.MedianFrameMs(),
               backlog.c_str());
  std::fflush(stderr);
}

/// Every message of the source to the estimator (at the recorded rate with --realtime), then
/// the estimator finished.
Fed Feed(const Options& o,
         const Source& source,
         Estimator* estimator,
         const RunWriter& writer,
         const api::IngestClient* ingest) {
  Fed fed;
  const auto wall_start = std::chrono::steady_clock::now();
  auto last_report = wall_start;
  io::SensorMessage message;
  while (source.input->Next(&message)) {
    if (source.simulator) {
      if (const auto* fix = std::get_if<io::GnssFix>(&message.data))
        fed.sim_fixes.poses.push_back(source.simulator->FixInUtm(*fix));
    }
    const double t = static_cast<double>(message.receive_ns) * 1e-9;
    if (fed.first_s < 0.0) fed.first_s = t;
    if (source.bag && o.duration_s > 0.0 && t - fed.first_s > o.duration_s) break;
    fed.last_s = std::max(fed.last_s, t);
    if (o.realtime)
      std::this_thread::sleep_until(wall_start +
                                    std::chrono::duration_cast<std::chrono::nanoseconds>(
                                        std::chrono::duration<double>(t - fed.first_s)));
    estimator->Add(message);
    const auto now = std::chrono::steady_clock::now();
    if (!o.quiet && now - last_report > std::chrono::seconds(5)) {
      last_report = now;
      PrintProgress(source,
                    *estimator,
                    writer,
                    ingest,
                    fed,
                    std::chrono::duration<double>(now - wall_start).count());
    }
  }
  estimator->Finish();
  fed.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  return fed;
}

/// --sim: the truth beside the estimate, for raillomer-eval, the receiver's fixes (UTM) and
/// the IMU's true biases.
bool WriteSimTruth(const sim::Simulator& simulator,
                   api::Trajectory fixes,
                   const std::string& out_dir,
                   std::string* error) {
  const api::Trajectory truth = simulator.TruthTrajectory(100.0);
  fixes.utm_zone = truth.utm_zone;
  return api::WriteFileAtomically(out_dir + "/truth.tum", api::FormatTum(truth), error) &&
         api::WriteFileAtomically(out_dir + "/gnss.tum", api::FormatTum(fixes), error) &&
         api::WriteFileAtomically(out_dir + "/imu_bias.csv", simulator.ImuBiasCsv(), error);
}

/// summary.json (with the ablation, the source and the peak memory) and the global map
/// closed, and the run's figures printed.
bool CloseOutputs(const Options& o,
                  const std::string& ablation,
                  const Source& source,
                  const Estimator& estimator,
                  const Fed& fed,
                  RunWriter* writer,
                  MapExporter* map,
                  std::string* error) {
  const double data_s = std::max(0.0, fed.last_s - fed.first_s);
  std::ostringstream extra;
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  extra << "\"ablation\": \"" << ablation << "\",\n  \"source\": \"" << (source.bag ? "bag" : "sim")
        << "\",\n  \"peak_rss_mb\": " << static_cast<double>(usage.ru_maxrss) / 1024.0;
  if (!writer->Close(estimator.stats(), data_s, fed.wall_s, extra.str(), error)) return false;
  if (map) {
    if (!map->Close(error)) return false;
    if (map->skipped_submaps() > 0) {
      std::cerr << "raillomer-estimator: warning: " << map->skipped_submaps()
                << " submaps in another frame than the first were left out of " << o.map_path
                << "\n";
    }
    if (!o.quiet) std::cerr << "  map: " << map->points() << " points -> " << o.map_path << "\n";
  }
  if (!o.quiet) {
    std::fprintf(stderr,
                 "\r  done: %zu frames, %.2f km in %.1f s (%.2fx real time), median %.1f "
                 "ms/frame, p95 %.1f ms\n",
                 writer->frames(),
                 estimator.stats().distance_m / 1000.0,
                 fed.wall_s,
                 fed.wall_s > 0 ? data_s / fed.wall_s : 0.0,
                 writer->MedianFrameMs(),
                 writer->PercentileFrameMs(0.95));
  }
  return true;
}

/// The outbox drained to the server (waiting up to --server-wait) and the run finished there;
/// false if it kept something or rejected something.
bool FinishIngest(const Options& o, api::IngestClient* ingest, std::string* error) {
  if (!o.quiet)
    std::cerr << "  server: sending the last " << ingest->backlog().messages
              << " messages and finishing the run ...\n";
  std::string drain_error;
  const bool drained = ingest->Finish(o.server_wait_s, &drain_error);
  const api::IngestClient::Backlog b = ingest->backlog();
  if (!o.quiet || !drained) {
    std::cerr << "  server: run " << b.run_id << ", " << b.sent << " messages acknowledged, "
              << b.retries << " failed attempts, " << b.rejected << " rejected, " << b.messages
              << " left in the outbox";
    if (b.skipped > 0)
      std::cerr << "; resumed: " << b.skipped
                << " poses and submaps skipped (the outbox had them from an earlier start)";
    std::cerr << "\n";
  }
  if (!drained) return *error = "the server did not take everything: " + drain_error, false;
  if (b.rejected > 0)
    return *error = std::to_string(b.rejected) +
                    " messages were rejected by the server (kept in the outbox's rejected/ "
                    "folder)",
           false;
  return true;
}

/// Prints what runs from where, and the config.
void PrintStart(const Options& o, const EstimatorConfig& config, const Source& source) {
  std::cerr << "raillomer-estimator: "
            << (source.bag ? "bag " + o.bag_path : "simulator " + o.sim_scenario) << " -> "
            << o.out_dir << "\n";
  std::istringstream lines(config.Describe());
  for (std::string text; std::getline(lines, text);) std::cerr << "  " << text << "\n";
}

/// Opens the run's files (trajectory, timing, keyframes, submaps), the map and the ingest client.
bool OpenOutputs(const Options& o,
                 const EstimatorConfig& config,
                 RunWriter* writer,
                 std::unique_ptr<MapExporter>* map,
                 std::unique_ptr<api::IngestClient>* ingest,
                 std::string* error) {
  std::ostringstream header;
  header << "# raillomer-estimator " << config.options.switches.Name()
         << ": body pose at every LiDAR frame, local frame "
         << "(first state at the origin, yaw 0, gravity-aligned), rig " << config.rig.rig << "\n";
  if (!writer->Open(o.out_dir, config.options.write_keyframes, header.str(), error)) return false;
  if (!OpenMap(o, map, error)) return false;
  if (!o.no_submaps && !writer->OpenSubmaps(error)) return false;
  if (o.provisional_submaps && !writer->OpenProvisional(error)) return false;
  return StartIngest(o, ingest, error);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-estimator: dual-LiDAR / IMU / wheel-odometer sliding-window odometry with rail "
      "constraints (RailLoMer section IV). Reads a ROS1 bag (or runs the built-in simulator) and "
      "writes trajectory.tum, timing.csv, keyframes, submaps and summary.json to --out."};
  Options o;
  AddSourceOptions(&app, &o);
  AddAblationOptions(&app, &o);
  AddOutputOptions(&app, &o);
  AddServerOptions(&app, &o);
  CLI11_PARSE(app, argc, argv);
  o.map_voxel_given = app.count("--map-voxel") > 0;

  EstimatorConfig config;
  Source source;
  std::string error;
  if (!OpenSource(o, &config, &source, &error)) return Fail(error);
  ApplyAblations(o, &config);
  if (!o.quiet) PrintStart(o, config, source);
  RunWriter writer;
  std::unique_ptr<MapExporter> map;
  std::unique_ptr<api::IngestClient> ingest;
  if (!OpenOutputs(o, config, &writer, &map, &ingest, &error)) return Fail(error);

  Stream stream;
  stream.writer = &writer;
  stream.map = map.get();
  stream.ingest = ingest.get();
  stream.write_submaps = !o.no_submaps;
  stream.write_provisional = o.provisional_submaps;
  Estimator estimator(config, MakeSinks(o, config, &writer, &stream));
  const Fed fed = Feed(o, source, &estimator, writer, ingest.get());

  const std::string input_error = source.bag ? source.bag->error() : std::string();
  if (source.simulator && !WriteSimTruth(*source.simulator, fed.sim_fixes, o.out_dir, &error))
    return Fail(error);
  if (!CloseOutputs(
          o, config.options.switches.Name(), source, estimator, fed, &writer, map.get(), &error))
    return Fail(error);
  if (ingest && !FinishIngest(o, ingest.get(), &error)) return Fail(error);
  if (!input_error.empty()) {
    return Fail("the input stopped early: " + input_error + " (the " +
                std::to_string(writer.frames()) + " frames before it are written)");
  }
  if (writer.frames() == 0)
    return Fail("no frame was processed: check the LiDAR and IMU topics of the config");
  return 0;
}
