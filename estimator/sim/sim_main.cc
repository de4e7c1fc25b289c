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

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-sim: simulates a railway corridor and the RailLoMer sensor rig (two Livox "
      "Horizon, IMU, wheel odometer, GNSS) and writes run.bag, truth.tum, rig.yaml, gnss.tum, "
      "imu_bias.csv (the IMU's true biases) and, for changed runs, changes.json."};
  bool list = false;
  std::string scenario_name, out_dir;
  double duration_s = -1.0;
  int64_t seed = -1;
  bool lz4 = false;
  bool print_scenario = false;
  app.add_flag("--list", list, "List the built-in scenarios and exit");
  app.add_option("--scenario", scenario_name, "Built-in scenario name or scenario YAML file");
  app.add_option("--out", out_dir, "Output folder (created if missing)");
  app.add_option("--duration", duration_s, "Simulate only the first N seconds")
      ->check(CLI::PositiveNumber);
  app.add_option("--seed", seed, "Noise and vibration seed (the corridor keeps its world_seed)")
      ->check(CLI::Range(int64_t{0}, int64_t{4294967295}));
  app.add_flag("--lz4", lz4, "Compress bag chunks with LZ4");
  app.add_flag("--print-scenario",
               print_scenario,
               "Print the built-in scenario's YAML (with --scenario) and exit");
  CLI11_PARSE(app, argc, argv);

  if (list) {
    for (const sim::ScenarioInfo& info : sim::ListScenarios()) {
      std::printf("%-28s %s\n", info.name.c_str(), info.description.c_str());
    }
    return 0;
  }
  if (scenario_name.empty()) return Fail("--scenario is required (see --list)");
  if (print_scenario) {
    const std::string text = sim::BuiltinScenarioText(scenario_name);
    if (text.empty()) return Fail("no built-in scenario named '" + scenario_name + "'");
    std::cout << text;
    return 0;
  }
  if (out_dir.empty()) return Fail("--out is required");

  sim::Scenario scenario;
  std::string error;
  if (!sim::LoadScenario(scenario_name, &scenario, &error)) return Fail(error);
  sim::SimOptions options;
  options.duration_s = duration_s;
  if (seed >= 0) options.seed = static_cast<uint32_t>(seed);

  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) return Fail("cannot create " + out_dir + ": " + ec.message());

  const auto wall_start = std::chrono::steady_clock::now();
  std::cerr << "raillomer-sim: scenario " << scenario.name << " (" << scenario.description << ")\n";
  std::unique_ptr<sim::Simulator> simulator = sim::Simulator::Create(scenario, options, &error);
  if (!simulator) return Fail(error);
  const sim::Scenario& s = simulator->scenario();
  const double build_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  std::cerr << "  seed " << s.seed << ", world_seed " << s.world_seed << ", duration "
            << simulator->duration_s() << " s, line " << simulator->alignment().length_m()
            << " m, utm zone " << simulator->utm_zone().Name() << "\n"
            << "  corridor: " << simulator->world().mesh().triangles.size() << " triangles, "
            << simulator->world().objects().size() << " objects, built in " << build_s << " s\n"
            << "  lidars: " << s.lidars.size() << " x " << s.points_per_frame << " points at "
            << s.lidar_rate_hz << " Hz; imu " << s.imu_rate_hz << " Hz; odometer "
            << s.odometer_rate_hz << " Hz; gnss " << s.gnss_rate_hz << " Hz\n";

  const std::string bag_path = out_dir + "/run.bag";
  io::BagWriterOptions bag_options;
  bag_options.lz4_compression = lz4;
  std::unique_ptr<io::BagWriter> bag = io::BagWriter::Open(bag_path, bag_options, &error);
  if (!bag) return Fail(error);

  raillomer::api::Trajectory gnss;
  gnss.utm_zone = simulator->utm_zone().Name();
  io::SensorMessage message;
  auto last_report = std::chrono::steady_clock::now();
  while (simulator->Next(&message)) {
    if (const auto* fix = std::get_if<io::GnssFix>(&message.data)) {
      gnss.poses.push_back(simulator->FixInUtm(*fix));
    }
    if (!bag->Write(message, &error)) return Fail(error);
    const auto now = std::chrono::steady_clock::now();
    if (now - last_report > std::chrono::seconds(5)) {
      last_report = now;
      const double wall = std::chrono::duration<double>(now - wall_start).count();
      std::fprintf(stderr,
                   "  %.1f / %.1f s simulated (%.0f%%), %.2fx real time\n",
                   simulator->last_time_s(),
                   simulator->duration_s(),
                   100.0 * simulator->last_time_s() / simulator->duration_s(),
                   simulator->last_time_s() / wall);
    }
  }
  if (!bag->Close(&error)) return Fail(error);

  if (!raillomer::api::WriteTum(
          out_dir + "/truth.tum", simulator->TruthTrajectory(100.0), &error) ||
      !raillomer::api::WriteTum(out_dir + "/gnss.tum", gnss, &error) ||
      !WriteFileAtomically(out_dir + "/imu_bias.csv", simulator->ImuBiasCsv(), &error) ||
      !WriteFileAtomically(out_dir + "/rig.yaml", simulator->RigYaml(), &error)) {
    return Fail(error);
  }
  if (!s.changes.empty() &&
      !WriteFileAtomically(out_dir + "/changes.json", simulator->ChangesJson(), &error)) {
    return Fail(error);
  }
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  std::cerr << "raillomer-sim: wrote " << bag_path << " (";
  bool first = true;
  for (const auto& [topic, count] : bag->message_counts()) {
    std::cerr << (first ? "" : ", ") << topic << " " << count;
    first = false;
  }
  std::fprintf(stderr,
               "), truth.tum, gnss.tum, imu_bias.csv, rig.yaml%s in %.1f s (%.2fx real time)\n",
               s.changes.empty() ? "" : ", changes.json",
               wall,
               simulator->duration_s() / wall);
  return 0;
}
