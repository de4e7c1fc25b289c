#pragma once

#include <string>

#include <nlohmann/json.hpp>

#include "estimator/eval/evaluation.h"
#include "estimator/eval/svg_plot.h"

namespace raillomer::eval {

/// The JSON summary of an evaluation: every figure with its unit in the key, null where a figure
/// does not exist (e.g. the relative error of a run shorter than one segment).
nlohmann::json ToJson(const EvalResult& result);

/// The figures as a readable text table for a terminal.
std::string FormatTable(const EvalResult& result);

/// The plot series of an evaluation: matched truth and aligned estimate relative to the first
/// truth pose, and the ATE error along distance.
PlotData MakePlotData(const EvalResult& result);

}  // namespace raillomer::eval
