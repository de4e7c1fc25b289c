// raillomer-registration-bias: how far the estimator's scan-to-map registration pulls a frame
// away from the truth when the frame and the local map are both placed exactly, on a simulated
// scenario (see estimator/eval/registration_bias.h). Prints the mean pull per time window and
// over the run, for all LiDARs together and each alone, and writes them as JSON with --json.
//
// Exit codes: 0 success; 1 the JSON could not be written; 2 unusable input (unknown scenario,
// bad config); CLI11's codes for usage errors.

#include <cmath>
#include <cstdio>
#include <iostream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "api/atomic_file.h"
#include "estimator/eval/registration_bias.h"
#include "estimator/pipeline/config.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace {

constexpr int kExitOutputError = 1;
constexpr int kExitInputError = 2;

nlohmann::json PullJson(const raillomer::eval::PullSummary& s) {
  const auto& m = s.mean;
  return {{"frames", s.frames},
          {"translation_mm",
           {1e3 * m.translation_m.x(), 1e3 * m.translation_m.y(), 1e3 * m.translation_m.z()}},
          {"rotation_urad",
           {1e6 * m.rotation_rad.x(), 1e6 * m.rotation_rad.y(), 1e6 * m.rotation_rad.z()}}};
}

void PrintRow(const std::string& label, const raillomer::eval::PullSummary& s) {
  const auto& m = s.mean;
  std::printf("  %-16s %6d  %7.2f %7.2f %7.2f   %8.1f %8.1f %8.1f\n",
              label.c_str(),
              s.frames,
              1e3 * m.translation_m.x(),
              1e3 * m.translation_m.y(),
              1e3 * m.translation_m.z(),
              1e6 * m.rotation_rad.x(),
              1e6 * m.rotation_rad.y(),
              1e6 * m.rotation_rad.z());
}

/// The command line.
struct Options {
  std::string scenario_name, config_path, json_path;
  unsigned seed = 0;
  bool has_seed = false;
  raillomer::eval::RegistrationBiasOptions bias;
  std::vector<double> offset;
  std::string matches = "all";
};

/// Declares the options; returns the --seed option, to tell whether it was given.
CLI::Option* AddOptions(CLI::App* app, Options* o) {
  app->add_option("--scenario", o->scenario_name, "built-in scenario name or scenario YAML file")
      ->required();
  auto* seed_option = app->add_option("--seed", o->seed, "noise seed (the corridor keeps its own)");
  app->add_option("--config",
                  o->config_path,
                  "estimator configuration (rig.yaml with an optional estimator: section); "
                  "default: the scenario's rig with the estimator's defaults");
  app->add_option("--duration", o->bias.duration_s, "seconds of the scenario (0: all of it)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app->add_option("--window", o->bias.window_s, "length of the report's time windows (s)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app->add_option("--min-matches", o->bias.min_matches, "fewer matches: the frame is not solved")
      ->check(CLI::Range(6, 1000000))
      ->capture_default_str();
  app->add_option("--start-offset",
                  o->offset,
                  "match and solve each frame from the truth moved by x,y,z (m) and "
                  "roll,pitch,yaw (mrad) in the body frame, to see how much of that error the "
                  "registration takes back")
      ->expected(6)
      ->delimiter(',');
  app->add_option("--matches",
                  o->matches,
                  "solve with these matches only: all, planes or edges (whose pull is it)")
      ->check(CLI::IsMember({"all", "planes", "edges"}))
      ->capture_default_str();
  app->add_option("--json", o->json_path, "write the figures here as JSON");
  return seed_option;
}

/// --matches and --start-offset into the measurement's options.
void ApplyParsed(Options* o) {
  using Matches = raillomer::eval::RegistrationBiasOptions::Matches;
  o->bias.matches = o->matches == "planes"
                        ? Matches::kPlanes
                        : (o->matches == "edges" ? Matches::kEdges : Matches::kAll);
  if (o->offset.size() == 6) {
    const std::vector<double>& v = o->offset;
    o->bias.start_offset = Eigen::Translation3d(v[0], v[1], v[2]) *
                           Eigen::AngleAxisd(1e-3 * v[5], Eigen::Vector3d::UnitZ()) *
                           Eigen::AngleAxisd(1e-3 * v[4], Eigen::Vector3d::UnitY()) *
                           Eigen::AngleAxisd(1e-3 * v[3], Eigen::Vector3d::UnitX());
  }
}

/// The simulator of the scenario (with --seed) and the estimator configuration: --config, or
/// the scenario's rig with the estimator's defaults.
bool Prepare(const Options& o,
             raillomer::sim::Scenario* scenario,
             std::unique_ptr<raillomer::sim::Simulator>* simulator,
             raillomer::EstimatorConfig* config,
             std::string* error) {
  if (!raillomer::sim::LoadScenario(o.scenario_name, scenario, error)) return false;
  if (o.has_seed) scenario->seed = o.seed;
  *simulator = raillomer::sim::Simulator::Create(*scenario, raillomer::sim::SimOptions{}, error);
  if (*simulator == nullptr) return false;
  return o.config_path.empty()
             ? raillomer::ParseEstimatorConfig((*simulator)->RigYaml(), "rig.yaml", config, error)
             : raillomer::LoadEstimatorConfig(o.config_path, config, error);
}

/// The table: the mean pull per window, over the run, and of each LiDAR alone.
void PrintReport(const raillomer::sim::Scenario& scenario,
                 const std::string& matches,
                 const raillomer::eval::RegistrationBiasReport& report) {
  std::printf("raillomer-registration-bias  scenario %s  seed %u  frames %d  matches %s\n",
              scenario.name.c_str(),
              scenario.seed,
              report.frames,
              matches.c_str());
  std::printf(
      "  mean pull per frame   frames    x mm    y mm    z mm   roll urad pitch urad  yaw urad\n");
  for (const auto& w : report.windows) {
    char label[40];
    std::snprintf(label, sizeof(label), "%.0f-%.0f s", w.t_from_s, w.t_to_s);
    PrintRow(label, w.both);
  }
  PrintRow("whole run", report.both);
  for (size_t i = 0; i < report.per_lidar.size(); ++i) {
    PrintRow(report.lidar_names[i] + " alone", report.per_lidar[i]);
  }
}

/// The same figures as JSON, for --json.
std::string ReportJson(const raillomer::sim::Scenario& scenario,
                       const std::string& matches,
                       const raillomer::eval::RegistrationBiasReport& report) {
  nlohmann::json j;
  j["scenario"] = scenario.name;
  j["seed"] = scenario.seed;
  j["matches"] = matches;
  j["frames"] = report.frames;
  j["both"] = PullJson(report.both);
  for (size_t i = 0; i < report.per_lidar.size(); ++i) {
    j["per_lidar"][report.lidar_names[i]] = PullJson(report.per_lidar[i]);
  }
  j["windows"] = nlohmann::json::array();
  for (const auto& w : report.windows) {
    nlohmann::json row = PullJson(w.both);
    row["from_s"] = w.t_from_s;
    row["to_s"] = w.t_to_s;
    j["windows"].push_back(row);
  }
  return j.dump(2) + "\n";
}

int Fail(int code, const std::string& error) {
  std::cerr << "raillomer-registration-bias: " << error << "\n";
  return code;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-registration-bias: the pull of the scan-to-map registration at true poses on a "
      "simulated scenario (mean per frame, body axes: x forward, y left, z up; roll, pitch, yaw)"};
  Options o;
  CLI::Option* seed_option = AddOptions(&app, &o);
  CLI11_PARSE(app, argc, argv);
  o.has_seed = seed_option->count() > 0;
  ApplyParsed(&o);

  raillomer::sim::Scenario scenario;
  std::unique_ptr<raillomer::sim::Simulator> simulator;
  raillomer::EstimatorConfig config;
  std::string error;
  if (!Prepare(o, &scenario, &simulator, &config, &error)) return Fail(kExitInputError, error);
  raillomer::eval::RegistrationBiasReport report;
  const bool ok = raillomer::eval::MeasureRegistrationBias(
      simulator.get(), config, o.bias, &report, &error, [](double t) {
        std::fprintf(stderr, "raillomer-registration-bias: %.0f s of the scenario\n", t);
      });
  if (!ok) return Fail(kExitInputError, error);
  PrintReport(scenario, o.matches, report);
  if (!o.json_path.empty() && !raillomer::api::WriteFileAtomically(
                                  o.json_path, ReportJson(scenario, o.matches, report), &error))
    return Fail(kExitOutputError, error);
  return 0;
}
