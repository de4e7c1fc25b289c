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

constexpr int kExitOutputError = 1;
constexpr int kExitInputError = 2;

}  // namespace

int main(int argc, char** argv) {
  using raillomer::eval::AlignmentMode;
  CLI::App app{"raillomer-eval: score a trajectory against ground truth (TUM files)"};
  std::string estimate_path, truth_path, align_text = "none", json_path, plot_path;
  raillomer::eval::EvalOptions options;
  app.add_option("--estimate", estimate_path, "estimated trajectory, TUM")->required();
  app.add_option("--truth", truth_path, "ground-truth trajectory, TUM")->required();
  app.add_option("--align", align_text, "alignment before the ATE: none, se3 or 4dof")
      ->check(CLI::IsMember({"none", "se3", "4dof"}))
      ->capture_default_str();
  app.add_option("--max-gap", options.max_gap_s, "largest truth gap to interpolate across (s)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--segment-m", options.segment_length_m, "relative error segment length (m)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--json", json_path, "write the JSON summary here");
  app.add_option("--plot", plot_path, "write the plot here (.svg)")
      ->check(CLI::Validator(
          [](std::string& path) {
            std::string error;
            return raillomer::eval::IsSupportedPlotPath(path, &error) ? std::string() : error;
          },
          "FILE.svg"));
  std::string scenario_name, submap_folder;
  auto* scenario_option = app.add_option(
      "--scenario", scenario_name, "simulated scenario of the run, for --submaps (name or YAML)");
  auto* submaps_option =
      app.add_option("--submaps",
                     submap_folder,
                     "score the sharpness of this run's submap folder (needs --scenario)");
  std::string rail_csv_path;
  app.add_option("--rail-csv",
                 rail_csv_path,
                 "with --submaps: write every rail-head segment seen by two or more submaps here "
                 "(CSV: x,y,z,spread_m,submap,points,height_m,rms_m,truth_offset_m), to find where "
                 "they disagree")
      ->needs(submaps_option);
  std::string plane_csv_path;
  app.add_option("--plane-csv",
                 plane_csv_path,
                 "with --submaps: write every scored plane patch here, one row per submap on it "
                 "(CSV: x,y,z,patch_rms_m,patch_points,submap,points,offset_m,rms_m), to tell "
                 "submaps that disagree from blur within one")
      ->needs(submaps_option);
  scenario_option->needs(submaps_option);
  submaps_option->needs(scenario_option);
  CLI11_PARSE(app, argc, argv);
  raillomer::eval::ParseAlignmentMode(align_text, &options.align);  // IsMember checked it.

  std::cerr << "raillomer-eval: estimate=" << estimate_path << " truth=" << truth_path
            << " align=" << raillomer::eval::ToString(options.align)
            << " max_gap_s=" << options.max_gap_s << " segment_m=" << options.segment_length_m
            << " rpe_start_step_m=" << options.rpe_start_step_m
            << " json=" << (json_path.empty() ? "(none)" : json_path)
            << " plot=" << (plot_path.empty() ? "(none)" : plot_path) << "\n";

  std::string error;
  raillomer::api::Trajectory estimate, truth;
  if (!raillomer::api::ReadTum(estimate_path, &estimate, &error) ||
      !raillomer::api::ReadTum(truth_path, &truth, &error)) {
    std::cerr << "raillomer-eval: error: " << error << "\n";
    return kExitInputError;
  }

  const raillomer::eval::EvalResult result = raillomer::eval::Evaluate(estimate, truth, options);
  for (const std::string& warning : result.warnings) {
    std::cerr << "raillomer-eval: warning: " << warning << "\n";
  }
  if (!result.ok) {
    std::cerr << "raillomer-eval: error: " << result.error << "\n";
    return kExitInputError;
  }
  std::cout << raillomer::eval::FormatTable(result) << std::flush;

  nlohmann::json map_json;
  if (!submap_folder.empty()) {
    raillomer::sim::Scenario scenario;
    raillomer::sim::SimOptions sim_options;
    sim_options.lidar = false;
    std::unique_ptr<raillomer::sim::Simulator> simulator;
    if (raillomer::sim::LoadScenario(scenario_name, &scenario, &error)) {
      simulator = raillomer::sim::Simulator::Create(scenario, sim_options, &error);
    }
    if (!simulator) {
      std::cerr << "raillomer-eval: error: scenario " << scenario_name << ": " << error << "\n";
      return kExitInputError;
    }
    raillomer::eval::MapSharpness sharpness(raillomer::eval::SelectReferenceTriangles(
        simulator->world().mesh(), simulator->origin_utm()));
    size_t skipped = 0;
    if (!raillomer::eval::ScoreSubmapFolder(submap_folder, truth, &sharpness, &skipped, &error)) {
      std::cerr << "raillomer-eval: error: " << error << "\n";
      return kExitInputError;
    }
    if (skipped > 0) {
      std::cerr << "raillomer-eval: warning: " << skipped
                << " submaps lie outside the truth's span and were not scored\n";
    }
    const raillomer::eval::SharpnessResult map = sharpness.Result();
    std::cout << raillomer::eval::FormatSharpness(map) << std::flush;
    if (!rail_csv_path.empty() &&
        !raillomer::api::WriteFileAtomically(
            rail_csv_path, raillomer::eval::RailSegmentsCsv(sharpness.RailSegments()), &error)) {
      std::cerr << "raillomer-eval: error: " << error << "\n";
      return kExitInputError;
    }
    if (!plane_csv_path.empty() &&
        !raillomer::api::WriteFileAtomically(
            plane_csv_path, raillomer::eval::PlanePatchesCsv(sharpness.PlanePatches()), &error)) {
      std::cerr << "raillomer-eval: error: " << error << "\n";
      return kExitInputError;
    }
    map_json = raillomer::eval::ToJson(map);
  }

  int exit_code = 0;
  if (!json_path.empty()) {
    nlohmann::json json = raillomer::eval::ToJson(result);
    json["estimate_file"] = estimate_path;
    json["truth_file"] = truth_path;
    if (!map_json.is_null()) json["map"] = map_json;
    if (!raillomer::api::WriteFileAtomically(json_path, json.dump(2) + "\n", &error)) {
      std::cerr << "raillomer-eval: error: " << error << "\n";
      exit_code = kExitOutputError;
    }
  }
  if (!plot_path.empty()) {
    const std::string svg = raillomer::eval::RenderSvgPlot(raillomer::eval::MakePlotData(result),
                                                           raillomer::eval::SvgPlotOptions{});
    if (!raillomer::api::WriteFileAtomically(plot_path, svg, &error)) {
      std::cerr << "raillomer-eval: error: " << error << "\n";
      exit_code = kExitOutputError;
    }
  }
  return exit_code;
}
