// raillomer-sim: simulates a railway corridor and the RailLoMer sensor rig, and writes a ROS1
// bag, the ground truth and the rig configuration.

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <string>

#include <CLI/CLI.hpp>

#include "api/atomic_file.h"
#include "api/cli_checks.h"
#include "api/trajectory.h"
#include "estimator/io/bag_writer.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace {

using raillomer::api::WriteFileAtomically;
namespace sim = raillomer::sim;
namespace io = raillomer::io;

int Fail(const std::string& message) {
  std::cerr << "raillomer-sim: error: " << message << "\n";
  return 2;
}

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

/// The command line.
struct Options {
  bool list = false;
  std::string scenario_name, out_dir;
  double duration_s = -1.0;
  int64_t seed = -1;
  bool lz4 = false;
  bool print_scenario = false;
};

void AddOptions(CLI::App* app, Options* o) {
  app->add_flag("--list", o->list, "List the built-in scenarios and exit");
  app->add_option("--scenario", o->scenario_name, "Built-in scenario name or scenario YAML file");
  app->add_option("--out", o->out_dir, "Output folder (created if missing)");
  app->add_option("--duration", o->duration_s, "Simulate only the first N seconds")
      ->check(raillomer::api::FinitePositive());
  app->add_option("--seed", o->seed, "Noise and vibration seed (the corridor keeps its world_seed)")
      ->check(CLI::Range(int64_t{0}, int64_t{4294967295}));
  app->add_flag("--lz4", o->lz4, "Compress bag chunks with LZ4");
  app->add_flag("--print-scenario",
                o->print_scenario,
                "Print the built-in scenario's YAML (with --scenario) and exit");
}

/// The scenario, its seed and the corridor built from it.
void PrintSetup(const sim::Simulator& simulator, double build_s) {
  const sim::Scenario& s = simulator.scenario();
  std::cerr << "  seed " << s.seed << ", world_seed " << s.world_seed << ", duration "
            << simulator.duration_s() << " s, line " << simulator.alignment().length_m()
            << " m, utm zone " << simulator.utm_zone().Name() << "\n"
            << "  corridor: " << simulator.world().mesh().triangles.size() << " triangles, "
            << simulator.world().objects().size() << " objects, built in " << build_s << " s\n"
            << "  lidars: " << s.lidars.size() << " x " << s.points_per_frame << " points at "
            << s.lidar_rate_hz << " Hz; imu " << s.imu_rate_hz << " Hz; odometer "
            << s.odometer_rate_hz << " Hz; gnss " << s.gnss_rate_hz << " Hz\n";
}

/// Every simulated message into the bag, with a progress line every 5 s; the receiver's
/// fixes in UTM into `gnss`.
bool WriteMessages(sim::Simulator* simulator,
                   io::BagWriter* bag,
                   Clock::time_point wall_start,
                   raillomer::api::Trajectory* gnss,
                   std::string* error) {
  gnss->utm_zone = simulator->utm_zone().Name();
  io::SensorMessage message;
  auto last_report = Clock::now();
  while (simulator->Next(&message)) {
    if (const auto* fix = std::get_if<io::GnssFix>(&message.data)) {
      gnss->poses.push_back(simulator->FixInUtm(*fix));
    }
    if (!bag->Write(message, error)) return false;
    if (Clock::now() - last_report > std::chrono::seconds(5)) {
      last_report = Clock::now();
      std::fprintf(stderr,
                   "  %.1f / %.1f s simulated (%.0f%%), %.2fx real time\n",
                   simulator->last_time_s(),
                   simulator->duration_s(),
                   100.0 * simulator->last_time_s() / simulator->duration_s(),
                   simulator->last_time_s() / SecondsSince(wall_start));
    }
  }
  return bag->Close(error);
}

/// The files beside the bag: truth.tum, gnss.tum, imu_bias.csv, rig.yaml and, for a changed
/// run, changes.json.
bool WriteTruth(const sim::Simulator& simulator,
                const raillomer::api::Trajectory& gnss,
                const std::string& out_dir,
                std::string* error) {
  return raillomer::api::WriteTum(
             out_dir + "/truth.tum", simulator.TruthTrajectory(100.0), error) &&
         raillomer::api::WriteTum(out_dir + "/gnss.tum", gnss, error) &&
         WriteFileAtomically(out_dir + "/imu_bias.csv", simulator.ImuBiasCsv(), error) &&
         WriteFileAtomically(out_dir + "/rig.yaml", simulator.RigYaml(), error) &&
         (simulator.scenario().changes.empty() ||
          WriteFileAtomically(out_dir + "/changes.json", simulator.ChangesJson(), error));
}

/// What was written: the bag's messages by topic, the other files, and the speed.
void PrintWritten(const sim::Simulator& simulator,
                  const io::BagWriter& bag,
                  const std::string& bag_path,
                  double wall_s) {
  std::cerr << "raillomer-sim: wrote " << bag_path << " (";
  bool first = true;
  for (const auto& [topic, count] : bag.message_counts()) {
    std::cerr << (first ? "" : ", ") << topic << " " << count;
    first = false;
  }
  std::fprintf(stderr,
               "), truth.tum, gnss.tum, imu_bias.csv, rig.yaml%s in %.1f s (%.2fx real time)\n",
               simulator.scenario().changes.empty() ? "" : ", changes.json",
               wall_s,
               simulator.duration_s() / wall_s);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-sim: simulates a railway corridor and the RailLoMer sensor rig (two Livox "
      "Horizon, IMU, wheel odometer, GNSS) and writes run.bag, truth.tum, rig.yaml, gnss.tum, "
      "imu_bias.csv (the IMU's true biases) and, for changed runs, changes.json."};
  Options o;
  AddOptions(&app, &o);
  CLI11_PARSE(app, argc, argv);

  if (o.list) {
    for (const sim::ScenarioInfo& info : sim::ListScenarios()) {
      std::printf("%-28s %s\n", info.name.c_str(), info.description.c_str());
    }
    return 0;
  }
  if (o.scenario_name.empty()) return Fail("--scenario is required (see --list)");
  if (o.print_scenario) {
    const std::string text = sim::BuiltinScenarioText(o.scenario_name);
    if (text.empty()) return Fail("no built-in scenario named '" + o.scenario_name + "'");
    std::cout << text;
    return 0;
  }
  if (o.out_dir.empty()) return Fail("--out is required");

  sim::Scenario scenario;
  std::string error;
  if (!sim::LoadScenario(o.scenario_name, &scenario, &error)) return Fail(error);
  sim::SimOptions options;
  options.duration_s = o.duration_s;
  if (o.seed >= 0) options.seed = static_cast<uint32_t>(o.seed);

  std::error_code ec;
  std::filesystem::create_directories(o.out_dir, ec);
  if (ec) return Fail("cannot create " + o.out_dir + ": " + ec.message());

  const auto wall_start = Clock::now();
  std::cerr << "raillomer-sim: scenario " << scenario.name << " (" << scenario.description << ")\n";
  std::unique_ptr<sim::Simulator> simulator = sim::Simulator::Create(scenario, options, &error);
  if (!simulator) return Fail(error);
  PrintSetup(*simulator, SecondsSince(wall_start));

  const std::string bag_path = o.out_dir + "/run.bag";
  io::BagWriterOptions bag_options;
  bag_options.lz4_compression = o.lz4;
  std::unique_ptr<io::BagWriter> bag = io::BagWriter::Open(bag_path, bag_options, &error);
  if (!bag) return Fail(error);
  raillomer::api::Trajectory gnss;
  if (!WriteMessages(simulator.get(), bag.get(), wall_start, &gnss, &error) ||
      !WriteTruth(*simulator, gnss, o.out_dir, &error))
    return Fail(error);
  PrintWritten(*simulator, *bag, bag_path, SecondsSince(wall_start));
  return 0;
}
