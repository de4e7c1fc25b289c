// raillomer-eval: scores an estimated trajectory against ground truth as the paper's Table III
// (ATE after alignment, relative error per 100 m, end-point drift). A thin wrapper: reads the two
// TUM files, calls raillomer::eval::Evaluate, prints a table and writes JSON and SVG atomically.
// With --scenario and --submaps it also scores the map's sharpness against the simulated
// corridor's planes and rail heads.
//
// Exit codes: 0 success; 1 an output could not be written; 2 unusable input (unreadable or
// malformed TUM, different UTM zones, fewer than two matched poses); CLI11's codes for usage.

#include <cstdio>
#include <iostream>
#include <string>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "api/atomic_file.h"
#include "api/trajectory.h"
#include "estimator/eval/evaluation.h"
#include "estimator/eval/map_sharpness.h"
#include "estimator/eval/report.h"
#include "estimator/eval/svg_plot.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace {

namespace eval = raillomer::eval;

constexpr int kExitOutputError = 1;
constexpr int kExitInputError = 2;

/// The command line.
struct Options {
  std::string estimate_path, truth_path, align_text = "none", json_path, plot_path;
  eval::EvalOptions eval;
  std::string scenario_name, submap_folder, rail_csv_path, plane_csv_path;
};

void AddTrajectoryOptions(CLI::App* app, Options* o) {
  app->add_option("--estimate", o->estimate_path, "estimated trajectory, TUM")->required();
  app->add_option("--truth", o->truth_path, "ground-truth trajectory, TUM")->required();
  app->add_option("--align", o->align_text, "alignment before the ATE: none, se3 or 4dof")
      ->check(CLI::IsMember({"none", "se3", "4dof"}))
      ->capture_default_str();
  app->add_option("--max-gap", o->eval.max_gap_s, "largest truth gap to interpolate across (s)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app->add_option("--segment-m", o->eval.segment_length_m, "relative error segment length (m)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app->add_option("--json", o->json_path, "write the JSON summary here");
  app->add_option("--plot", o->plot_path, "write the plot here (.svg)")
      ->check(CLI::Validator(
          [](std::string& path) {
            std::string error;
            return eval::IsSupportedPlotPath(path, &error) ? std::string() : error;
          },
          "FILE.svg"));
}

void AddMapOptions(CLI::App* app, Options* o) {
  auto* scenario_option =
      app->add_option("--scenario",
                      o->scenario_name,
                      "simulated scenario of the run, for --submaps (name or YAML)");
  auto* submaps_option =
      app->add_option("--submaps",
                      o->submap_folder,
                      "score the sharpness of this run's submap folder (needs --scenario)");
  app->add_option("--rail-csv",
                  o->rail_csv_path,
                  "with --submaps: write every rail-head segment seen by two or more submaps "
                  "here (CSV: x,y,z,spread_m,submap,points,height_m,rms_m,truth_offset_m), to "
                  "find where they disagree")
      ->needs(submaps_option);
  app->add_option("--plane-csv",
                  o->plane_csv_path,
                  "with --submaps: write every scored plane patch here, one row per submap on "
                  "it (CSV: x,y,z,patch_rms_m,patch_points,submap,points,offset_m,rms_m), to tell "
                  "submaps that disagree from blur within one")
      ->needs(submaps_option);
  scenario_option->needs(submaps_option);
  submaps_option->needs(scenario_option);
}

/// The sharpness of the run's submaps against the simulated corridor's planes and rail heads:
/// printed, the CSVs asked for written, and its JSON.
bool ScoreMap(const Options& o,
              const raillomer::api::Trajectory& truth,
              nlohmann::json* map_json,
              std::string* error) {
  raillomer::sim::Scenario scenario;
  raillomer::sim::SimOptions sim_options;
  sim_options.lidar = false;
  std::unique_ptr<raillomer::sim::Simulator> simulator;
  if (raillomer::sim::LoadScenario(o.scenario_name, &scenario, error))
    simulator = raillomer::sim::Simulator::Create(scenario, sim_options, error);
  if (!simulator) return *error = "scenario " + o.scenario_name + ": " + *error, false;
  eval::MapSharpness sharpness(
      eval::SelectReferenceTriangles(simulator->world().mesh(), simulator->origin_utm()));
  size_t skipped = 0;
  if (!eval::ScoreSubmapFolder(o.submap_folder, truth, &sharpness, &skipped, error)) return false;
  if (skipped > 0) {
    std::cerr << "raillomer-eval: warning: " << skipped
              << " submaps lie outside the truth's span and were not scored\n";
  }
  const eval::SharpnessResult map = sharpness.Result();
  std::cout << eval::FormatSharpness(map) << std::flush;
  if (!o.rail_csv_path.empty() &&
      !raillomer::api::WriteFileAtomically(
          o.rail_csv_path, eval::RailSegmentsCsv(sharpness.RailSegments()), error))
    return false;
  if (!o.plane_csv_path.empty() &&
      !raillomer::api::WriteFileAtomically(
          o.plane_csv_path, eval::PlanePatchesCsv(sharpness.PlanePatches()), error))
    return false;
  *map_json = eval::ToJson(map);
  return true;
}

/// The JSON summary and the plot, where asked for; the exit code.
int WriteOutputs(const Options& o, const eval::EvalResult& result, const nlohmann::json& map_json) {
  int exit_code = 0;
  std::string error;
  if (!o.json_path.empty()) {
    nlohmann::json json = eval::ToJson(result);
    json["estimate_file"] = o.estimate_path;
    json["truth_file"] = o.truth_path;
    if (!map_json.is_null()) json["map"] = map_json;
    if (!raillomer::api::WriteFileAtomically(o.json_path, json.dump(2) + "\n", &error)) {
      std::cerr << "raillomer-eval: error: " << error << "\n";
      exit_code = kExitOutputError;
    }
  }
  if (!o.plot_path.empty()) {
    const std::string svg = eval::RenderSvgPlot(eval::MakePlotData(result), eval::SvgPlotOptions{});
    if (!raillomer::api::WriteFileAtomically(o.plot_path, svg, &error)) {
      std::cerr << "raillomer-eval: error: " << error << "\n";
      exit_code = kExitOutputError;
    }
  }
  return exit_code;
}

int InputError(const std::string& error) {
  std::cerr << "raillomer-eval: error: " << error << "\n";
  return kExitInputError;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"raillomer-eval: score a trajectory against ground truth (TUM files)"};
  Options o;
  AddTrajectoryOptions(&app, &o);
  AddMapOptions(&app, &o);
  CLI11_PARSE(app, argc, argv);
  eval::ParseAlignmentMode(o.align_text, &o.eval.align);  // IsMember checked it.

  std::cerr << "raillomer-eval: estimate=" << o.estimate_path << " truth=" << o.truth_path
            << " align=" << eval::ToString(o.eval.align) << " max_gap_s=" << o.eval.max_gap_s
            << " segment_m=" << o.eval.segment_length_m
            << " rpe_start_step_m=" << o.eval.rpe_start_step_m
            << " json=" << (o.json_path.empty() ? "(none)" : o.json_path)
            << " plot=" << (o.plot_path.empty() ? "(none)" : o.plot_path) << "\n";

  std::string error;
  raillomer::api::Trajectory estimate, truth;
  if (!raillomer::api::ReadTum(o.estimate_path, &estimate, &error) ||
      !raillomer::api::ReadTum(o.truth_path, &truth, &error))
    return InputError(error);
  const eval::EvalResult result = eval::Evaluate(estimate, truth, o.eval);
  for (const std::string& warning : result.warnings) {
    std::cerr << "raillomer-eval: warning: " << warning << "\n";
  }
  if (!result.ok) return InputError(result.error);
  std::cout << eval::FormatTable(result) << std::flush;

  nlohmann::json map_json;
  if (!o.submap_folder.empty() && !ScoreMap(o, truth, &map_json, &error)) return InputError(error);
  return WriteOutputs(o, result, map_json);
}
