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

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-registration-bias: the pull of the scan-to-map registration at true poses on a "
      "simulated scenario (mean per frame, body axes: x forward, y left, z up; roll, pitch, yaw)"};
  std::string scenario_name, config_path, json_path;
  unsigned seed = 0;
  bool has_seed = false;
  raillomer::eval::RegistrationBiasOptions options;
  app.add_option("--scenario", scenario_name, "built-in scenario name or scenario YAML file")
      ->required();
  auto* seed_option = app.add_option("--seed", seed, "noise seed (the corridor keeps its own)");
  app.add_option("--config",
                 config_path,
                 "estimator configuration (rig.yaml with an optional estimator: section); "
                 "default: the scenario's rig with the estimator's defaults");
  app.add_option("--duration", options.duration_s, "seconds of the scenario (0: all of it)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--window", options.window_s, "length of the report's time windows (s)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--min-matches", options.min_matches, "fewer matches: the frame is not solved")
      ->check(CLI::Range(6, 1000000))
      ->capture_default_str();
  std::vector<double> offset;
  app.add_option("--start-offset",
                 offset,
                 "match and solve each frame from the truth moved by x,y,z (m) and roll,pitch,yaw "
                 "(mrad) in the body frame, to see how much of that error the registration takes "
                 "back")
      ->expected(6)
      ->delimiter(',');
  std::string matches = "all";
  app.add_option("--matches",
                 matches,
                 "solve with these matches only: all, planes or edges (whose pull is it)")
      ->check(CLI::IsMember({"all", "planes", "edges"}))
      ->capture_default_str();
  app.add_option("--json", json_path, "write the figures here as JSON");
  CLI11_PARSE(app, argc, argv);
  has_seed = seed_option->count() > 0;
  using Matches = raillomer::eval::RegistrationBiasOptions::Matches;
  options.matches = matches == "planes" ? Matches::kPlanes
                                        : (matches == "edges" ? Matches::kEdges : Matches::kAll);
  if (offset.size() == 6) {
    options.start_offset = Eigen::Translation3d(offset[0], offset[1], offset[2]) *
                           Eigen::AngleAxisd(1e-3 * offset[5], Eigen::Vector3d::UnitZ()) *
                           Eigen::AngleAxisd(1e-3 * offset[4], Eigen::Vector3d::UnitY()) *
                           Eigen::AngleAxisd(1e-3 * offset[3], Eigen::Vector3d::UnitX());
  }

  raillomer::sim::Scenario scenario;
  std::string error;
  if (!raillomer::sim::LoadScenario(scenario_name, &scenario, &error)) {
    std::cerr << "raillomer-registration-bias: " << error << "\n";
    return kExitInputError;
  }
  if (has_seed) scenario.seed = seed;
  auto simulator =
      raillomer::sim::Simulator::Create(scenario, raillomer::sim::SimOptions{}, &error);
  if (simulator == nullptr) {
    std::cerr << "raillomer-registration-bias: " << error << "\n";
    return kExitInputError;
  }
  raillomer::EstimatorConfig config;
  const bool parsed =
      config_path.empty()
          ? raillomer::ParseEstimatorConfig(simulator->RigYaml(), "rig.yaml", &config, &error)
          : raillomer::LoadEstimatorConfig(config_path, &config, &error);
  if (!parsed) {
    std::cerr << "raillomer-registration-bias: " << error << "\n";
    return kExitInputError;
  }

  raillomer::eval::RegistrationBiasReport report;
  const bool ok = raillomer::eval::MeasureRegistrationBias(
      simulator.get(), config, options, &report, &error, [](double t) {
        std::fprintf(stderr, "raillomer-registration-bias: %.0f s of the scenario\n", t);
      });
  if (!ok) {
    std::cerr << "raillomer-registration-bias: " << error << "\n";
    return kExitInputError;
  }

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

  if (!json_path.empty()) {
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
    if (!raillomer::api::WriteFileAtomically(json_path, j.dump(2) + "\n", &error)) {
      std::cerr << "raillomer-registration-bias: " << error << "\n";
      return kExitOutputError;
    }
  }
  return 0;
}
