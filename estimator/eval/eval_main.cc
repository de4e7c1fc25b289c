// raillomer-eval: scores an estimated trajectory against ground truth as the paper's Table III
// (ATE after alignment, relative error per 100 m, end-point drift). A thin wrapper: reads the two
// TUM files, calls raillomer::eval::Evaluate, prints a table and writes JSON and SVG atomically.
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
#include "estimator/eval/report.h"
#include "estimator/eval/svg_plot.h"

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

  int exit_code = 0;
  if (!json_path.empty()) {
    nlohmann::json json = raillomer::eval::ToJson(result);
    json["estimate_file"] = estimate_path;
    json["truth_file"] = truth_path;
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
