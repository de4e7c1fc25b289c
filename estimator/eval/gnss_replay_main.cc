// raillomer-gnss-replay: georeferences an odometry trajectory again with a receiver's fixes,
// through the estimator's GNSS fusion (estimator/mapping/gnss_fusion.h), without running the
// odometry. The estimator's odometry does not depend on GNSS, so the trajectory of a --no-gnss
// run replayed with the run's fixes is the trajectory the estimator publishes with GNSS (poses
// are released as the estimator releases them: once a graph node follows them, or after
// gnss_max_latency_s). A fusion setting is then tried on a whole suite in seconds instead of
// rerunning every scenario (tests/tools/gnss_suite.py --replay).
//
// Exit codes: 0 success; 1 the output could not be written; 2 unusable input; 3 the run never
// aligned to UTM (nothing written); CLI11's codes for usage errors.

#include <cstdint>
#include <cstdio>
#include <deque>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <variant>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "api/atomic_file.h"
#include "api/trajectory.h"
#include "estimator/eval/association.h"
#include "estimator/geo/utm.h"
#include "estimator/io/bag_reader.h"
#include "estimator/mapping/gnss_fusion.h"
#include "estimator/pipeline/config.h"
#include "estimator/sim/scenario.h"
#include "estimator/sim/simulator.h"

namespace {

constexpr int kExitOutputError = 1;
constexpr int kExitInputError = 2;
constexpr int kExitNotAligned = 3;

int Fail(int code, const std::string& message) {
  std::cerr << "raillomer-gnss-replay: " << message << "\n";
  return code;
}

double Seconds(int64_t stamp_ns) { return static_cast<double>(stamp_ns) * 1e-9; }

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-gnss-replay: the estimator's GNSS fusion on a recorded odometry trajectory "
      "(a --no-gnss run's trajectory.tum) and the receiver's fixes (a simulated run's gnss.tum, "
      "or a bag's GNSS topic), "
      "written as the UTM trajectory the estimator would publish"};
  std::string odometry_path, fixes_path, out_path, scenario_name, config_path;
  app.add_option("--odometry", odometry_path, "odometry trajectory, local frame (TUM)")->required();
  std::string bag_path;
  auto* fixes_option =
      app.add_option("--fixes",
                     fixes_path,
                     "receiver fixes in UTM (TUM with a '# utm_zone' line; orientations ignored)");
  app.add_option("--bag", bag_path, "or the fixes of this bag's GNSS topic (the rig's)")
      ->excludes(fixes_option);
  app.add_option("--out", out_path, "georeferenced trajectory to write (TUM, UTM)")->required();
  app.add_option("--sim", scenario_name, "take the rig (antenna, zone) from this scenario");
  app.add_option("--config",
                 config_path,
                 "estimator configuration (rig.yaml with an optional estimator: section)");
  std::string options_path, json_path;
  app.add_option("--json",
                 json_path,
                 "also write the fusion's counts here (fixes, rejected, multipath, factors, "
                 "realignments)");
  app.add_option("--options",
                 options_path,
                 "with --sim: a file of estimator options (an estimator: section) for the "
                 "scenario's rig, e.g. gnss: settings to try")
      ->check(CLI::ExistingFile);
  CLI11_PARSE(app, argc, argv);
  if (scenario_name.empty() == config_path.empty())
    return Fail(kExitInputError, "give exactly one of --sim and --config");
  if (fixes_path.empty() && bag_path.empty())
    return Fail(kExitInputError, "give the fixes: --fixes <tum> or --bag <bag>");

  std::string error;
  raillomer::EstimatorConfig config;
  if (!scenario_name.empty()) {
    raillomer::sim::Scenario scenario;
    if (!raillomer::sim::LoadScenario(scenario_name, &scenario, &error))
      return Fail(kExitInputError, error);
    raillomer::sim::SimOptions options;
    options.duration_s = 0.1;
    auto simulator = raillomer::sim::Simulator::Create(scenario, options, &error);
    if (simulator == nullptr) return Fail(kExitInputError, error);
    std::string text = simulator->RigYaml();
    if (!options_path.empty()) {
      std::ifstream in(options_path);
      std::ostringstream options_text;
      options_text << in.rdbuf();
      text += "\n" + options_text.str();
    }
    if (!raillomer::ParseEstimatorConfig(text, "rig.yaml + " + options_path, &config, &error))
      return Fail(kExitInputError, error);
  } else if (!options_path.empty()) {
    return Fail(kExitInputError, "--options goes with --sim (--config carries its own)");
  } else if (!raillomer::LoadEstimatorConfig(config_path, &config, &error)) {
    return Fail(kExitInputError, error);
  }

  raillomer::api::Trajectory odometry;
  if (!raillomer::api::ReadTum(odometry_path, &odometry, &error))
    return Fail(kExitInputError, error);
  if (!odometry.utm_zone.empty())
    return Fail(kExitInputError,
                odometry_path + " is in UTM zone " + odometry.utm_zone +
                    ": replay needs the local odometry (a --no-gnss run)");
  std::vector<raillomer::io::GnssFix> fixes;
  if (!bag_path.empty()) {
    if (config.rig.gnss_topic.empty()) return Fail(kExitInputError, "the rig has no GNSS topic");
    raillomer::io::BagTopics topics;
    topics.lidar.clear();
    topics.imu.clear();
    topics.odometer.clear();
    topics.gnss = config.rig.gnss_topic;
    auto bag = raillomer::io::BagReader::Open(bag_path, topics, &error);
    if (bag == nullptr) return Fail(kExitInputError, error);
    raillomer::io::SensorMessage message;
    while (bag->Next(&message)) {
      if (const auto* fix = std::get_if<raillomer::io::GnssFix>(&message.data))
        fixes.push_back(*fix);
    }
    if (!bag->error().empty()) return Fail(kExitInputError, bag->error());
  } else {
    raillomer::api::Trajectory utm;
    if (!raillomer::api::ReadTum(fixes_path, &utm, &error)) return Fail(kExitInputError, error);
    raillomer::geo::UtmZone zone;
    if (!raillomer::geo::ParseZone(utm.utm_zone, &zone))
      return Fail(kExitInputError, fixes_path + " has no '# utm_zone' line");
    for (const raillomer::api::StampedPose& f : utm.poses) {
      const Eigen::Vector2d ll =
          raillomer::geo::UtmToGeographic(zone, f.p_world.x(), f.p_world.y());
      raillomer::io::GnssFix fix;
      fix.stamp_ns = f.stamp_ns;
      fix.latitude_deg = ll.x();
      fix.longitude_deg = ll.y();
      fix.altitude_m = f.p_world.z();
      fixes.push_back(fix);
    }
  }

  const raillomer::EstimatorOptions& o = config.options;
  raillomer::GnssFusion fusion(
      o.gnss,
      [](const std::string& m) { std::cerr << "raillomer-gnss-replay: warning: " << m << "\n"; },
      [](const std::string& m) { std::cerr << "raillomer-gnss-replay: " << m << "\n"; });

  // The estimator hands the fusion each fix as it arrives, long before the odometry (which
  // leaves its sliding window late) reaches the fix's epoch; so every fix up to a few seconds
  // past a pose goes in before it.
  size_t next_fix = 0;
  auto add_fixes_until = [&](double t_s) {
    for (; next_fix < fixes.size() && Seconds(fixes[next_fix].stamp_ns) <= t_s; ++next_fix)
      fusion.AddFix(fixes[next_fix]);
  };

  // Release as the estimator does (Estimator::ReleaseHeld, the same GnssFusion policy).
  raillomer::api::Trajectory out;
  std::deque<raillomer::api::StampedPose> held;
  bool gave_up = false;
  auto release = [&](bool flush) {
    if (held.empty() || gave_up) return;
    const double newest_s = Seconds(held.back().stamp_ns);
    if (!fusion.aligned()) {
      gave_up = flush || fusion.AlignmentOverdue(newest_s - Seconds(held.front().stamp_ns),
                                                 o.gnss_max_hold_s);
      return;
    }
    while (!held.empty()) {
      const double t = Seconds(held.front().stamp_ns);
      if (!flush && !fusion.Releases(t, newest_s, o.gnss_prompt_latency_s, o.gnss_max_latency_s))
        break;
      const Eigen::Isometry3d T = fusion.Publish(raillomer::eval::ToIsometry(held.front()), t);
      raillomer::api::StampedPose p;
      p.stamp_ns = held.front().stamp_ns;
      p.p_world = T.translation() + fusion.origin_utm();
      p.q_world_body = Eigen::Quaterniond(T.linear()).normalized();
      out.poses.push_back(p);
      held.pop_front();
    }
  };
  for (const raillomer::api::StampedPose& pose : odometry.poses) {
    if (gave_up) break;
    add_fixes_until(Seconds(pose.stamp_ns) + 2.0);
    fusion.AddOdometry(pose.stamp_ns, raillomer::eval::ToIsometry(pose));
    held.push_back(pose);
    release(false);
  }
  if (!gave_up && fusion.aligned()) {
    fusion.Finish();
    release(true);
  }
  if (gave_up || !fusion.aligned())
    return Fail(kExitNotAligned, "not georeferenced: " + fusion.pending_reason());
  out.utm_zone = fusion.zone().Name();
  if (!raillomer::api::WriteTum(out_path, out, &error)) return Fail(kExitOutputError, error);
  const raillomer::GnssFusionStats& s = fusion.stats();
  if (!json_path.empty()) {
    const nlohmann::json j = {{"poses", out.poses.size()},
                              {"utm_zone", out.utm_zone},
                              {"fixes", s.fixes},
                              {"rejected", s.rejected},
                              {"outliers", s.outliers},
                              {"factors", s.factors},
                              {"realignments", s.realignments}};
    if (!raillomer::api::WriteFileAtomically(json_path, j.dump(2) + "\n", &error))
      return Fail(kExitOutputError, error);
  }
  std::fprintf(stderr,
               "raillomer-gnss-replay: %zu poses -> %s (%llu fixes, %llu multipath, %llu factors, "
               "%llu re-alignments)\n",
               out.poses.size(),
               out_path.c_str(),
               static_cast<unsigned long long>(s.fixes),
               static_cast<unsigned long long>(s.outliers),
               static_cast<unsigned long long>(s.factors),
               static_cast<unsigned long long>(s.realignments));
  return 0;
}
