#include "estimator/eval/report.h"

#include <cstdio>

#include "api/trajectory.h"

namespace raillomer::eval {

namespace {

nlohmann::json Matrix(const Eigen::Matrix3d& R) {
  nlohmann::json rows = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) rows.push_back({R(r, 0), R(r, 1), R(r, 2)});
  return rows;
}

nlohmann::json Vector(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

nlohmann::json Transform(const Eigen::Isometry3d& T) {
  return {{"rotation", Matrix(T.linear())},
          {"translation_m", Vector(T.translation())},
          {"yaw_deg", BestYaw(T.linear()) * 180.0 / 3.14159265358979323846},
          {"angle_deg", RotationAngle(T.linear()) * 180.0 / 3.14159265358979323846}};
}

nlohmann::json OrNull(bool valid, double value) {
  return valid ? nlohmann::json(value) : nlohmann::json(nullptr);
}

std::string Line(const std::string& label, const std::string& value, const std::string& unit) {
  char buffer[192];
  std::snprintf(buffer, sizeof(buffer), "  %-32s %20s", label.c_str(), value.c_str());
  return std::string(buffer) + (unit.empty() ? "" : " " + unit) + "\n";
}

std::string Fixed(double value, int decimals) {
  char buffer[48];
  std::snprintf(buffer, sizeof(buffer), "%.*f", decimals, value);
  return buffer;
}

}  // namespace

nlohmann::json ToJson(const EvalResult& result) {
  const Association& a = result.association;
  nlohmann::json j;
  j["ok"] = result.ok;
  if (!result.ok) j["error"] = result.error;
  j["warnings"] = result.warnings;
  j["align"] = ToString(result.options.align);
  j["max_gap_s"] = result.options.max_gap_s;
  j["utm_zone"] =
      result.utm_zone.empty() ? nlohmann::json(nullptr) : nlohmann::json(result.utm_zone);
  j["estimate_poses"] = a.num_estimate_poses;
  j["truth_poses"] = a.num_truth_poses;
  j["matched_poses"] = a.pairs.size();
  j["skipped_poses"] = a.num_skipped();
  j["skipped_outside_truth_poses"] = a.num_skipped_outside;
  j["skipped_truth_gap_poses"] = a.num_skipped_gap;
  if (!result.ok) return j;

  j["first_stamp_ns"] = result.first_stamp_ns;
  j["last_stamp_ns"] = result.last_stamp_ns;
  j["first_stamp_s"] = static_cast<double>(result.first_stamp_ns) * 1e-9;
  j["last_stamp_s"] = static_cast<double>(result.last_stamp_ns) * 1e-9;
  j["duration_s"] = result.duration_s;
  j["distance_m"] = result.distance_m;

  nlohmann::json alignment = Transform(result.alignment.T_truth_est);
  alignment["frame"] = "T_truth_est: p_truth = rotation * p_est + translation_m";
  alignment["num_points"] = result.alignment.num_points;
  alignment["degenerate"] = result.alignment.degenerate;
  alignment["rmse_before_m"] = result.alignment.rmse_before_m;
  alignment["rmse_after_m"] = result.alignment.rmse_after_m;
  j["alignment"] = alignment;

  const AteStats& ate = result.ate;
  j["ate_rmse_m"] = ate.rmse_m;
  j["ate_mean_m"] = ate.mean_m;
  j["ate_median_m"] = ate.median_m;
  j["ate_max_m"] = ate.max_m;
  j["ate_max_stamp_ns"] = ate.max_stamp_ns;
  j["ate_max_stamp_s"] = static_cast<double>(ate.max_stamp_ns) * 1e-9;
  j["ate_max_distance_m"] = ate.max_distance_m;

  const RpeStats& rpe = result.rpe;
  j["rpe_segment_m"] = rpe.segment_length_m;
  j["rpe_start_step_m"] = result.options.rpe_start_step_m;
  j["rpe_segments"] = rpe.num_segments;
  j["rpe_trans_mean_m"] = OrNull(rpe.valid, rpe.trans_mean_m);
  j["rpe_trans_rmse_m"] = OrNull(rpe.valid, rpe.trans_rmse_m);
  j["rpe_trans_mean_pct"] = OrNull(rpe.valid, rpe.trans_mean_pct);
  j["rpe_trans_rmse_pct"] = OrNull(rpe.valid, rpe.trans_rmse_pct);
  j["rpe_rot_mean_deg"] = OrNull(rpe.valid && rpe.has_rotation, rpe.rot_mean_deg);
  j["rpe_rot_rmse_deg"] = OrNull(rpe.valid && rpe.has_rotation, rpe.rot_rmse_deg);

  const DriftStats& drift = result.drift;
  j["end_error_m"] = OrNull(drift.valid, drift.end_error_m);
  j["end_drift_pct"] = OrNull(drift.valid && drift.has_drift_pct, drift.end_drift_pct);
  j["end_alignment"] = Transform(drift.T_truth_est);
  return j;
}

std::string FormatTable(const EvalResult& result) {
  const Association& a = result.association;
  std::string out;
  out += "raillomer-eval  align " + std::string(ToString(result.options.align)) +
         (result.utm_zone.empty() ? "" : "  utm_zone " + result.utm_zone) + "\n";
  out += Line("estimate poses", std::to_string(a.num_estimate_poses), "");
  out += Line("truth poses", std::to_string(a.num_truth_poses), "");
  out += Line("matched poses", std::to_string(a.pairs.size()), "");
  out += Line("skipped poses", std::to_string(a.num_skipped()), "");
  out += Line("  outside truth span", std::to_string(a.num_skipped_outside), "");
  out += Line("  across truth gaps", std::to_string(a.num_skipped_gap), "");
  if (!result.ok) return out;
  out += Line("distance", Fixed(result.distance_m, 3), "m");
  out += Line("duration", Fixed(result.duration_s, 3), "s");
  out += Line("ATE RMSE", Fixed(result.ate.rmse_m, 4), "m");
  out += Line("ATE mean", Fixed(result.ate.mean_m, 4), "m");
  out += Line("ATE median", Fixed(result.ate.median_m, 4), "m");
  out += Line("ATE max", Fixed(result.ate.max_m, 4), "m");
  out += Line("  at stamp", api::FormatStampSeconds(result.ate.max_stamp_ns), "s");
  out += Line("  at distance", Fixed(result.ate.max_distance_m, 3), "m");
  const RpeStats& rpe = result.rpe;
  const std::string per = "per " + Fixed(rpe.segment_length_m, 0) + " m";
  if (rpe.valid) {
    out += Line("RPE trans mean " + per, Fixed(rpe.trans_mean_m, 4), "m");
    out += Line("RPE trans RMSE " + per, Fixed(rpe.trans_rmse_m, 4), "m");
    out += Line("RPE trans mean / segment length", Fixed(rpe.trans_mean_pct, 4), "%");
    out += Line("RPE trans RMSE / segment length", Fixed(rpe.trans_rmse_pct, 4), "%");
    if (rpe.has_rotation) {
      out += Line("RPE rot mean " + per, Fixed(rpe.rot_mean_deg, 4), "deg");
      out += Line("RPE rot RMSE " + per, Fixed(rpe.rot_rmse_deg, 4), "deg");
    } else {
      out += Line("RPE rot " + per, "n/a", "(positions only)");
    }
    out += Line("RPE segments", std::to_string(rpe.num_segments), "");
  } else {
    out += Line("RPE " + per, "n/a", "(run shorter than one segment)");
  }
  out += Line("end error (first-pose aligned)", Fixed(result.drift.end_error_m, 4), "m");
  out += Line("end drift",
              result.drift.has_drift_pct ? Fixed(result.drift.end_drift_pct, 4) : "n/a",
              "% of distance");
  return out;
}

PlotData MakePlotData(const EvalResult& result) {
  PlotData data;
  const std::vector<PosePair>& pairs = result.association.pairs;
  char title[160];
  std::snprintf(title,
                sizeof(title),
                "raillomer-eval: align %s, ATE RMSE %.3f m, max %.3f m, %zu poses",
                ToString(result.options.align),
                result.ate.rmse_m,
                result.ate.max_m,
                pairs.size());
  data.title = title;
  if (pairs.empty()) return data;
  const Eigen::Vector3d origin = pairs.front().T_world_truth.translation();
  char label[160];
  std::snprintf(label, sizeof(label), "first truth pose (%.3f, %.3f)", origin.x(), origin.y());
  data.origin_label = label;
  if (!result.utm_zone.empty()) data.origin_label += " UTM " + result.utm_zone;
  data.xy_truth_m.reserve(pairs.size());
  data.xy_est_m.reserve(pairs.size());
  for (const PosePair& pair : pairs) {
    data.xy_truth_m.push_back((pair.T_world_truth.translation() - origin).head<2>());
    data.xy_est_m.push_back(
        (result.alignment.T_truth_est * pair.T_world_est.translation() - origin).head<2>());
    data.distance_m.push_back(pair.distance_m);
  }
  data.error_m = result.ate.errors_m;
  return data;
}

}  // namespace raillomer::eval
