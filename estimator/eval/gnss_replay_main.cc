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

/// The command line.
struct Options {
  std::string odometry_path, fixes_path, bag_path, out_path, scenario_name, config_path;
  std::string options_path, json_path;
};

void AddOptions(CLI::App* app, Options* o) {
  app->add_option("--odometry", o->odometry_path, "odometry trajectory, local frame (TUM)")
      ->required();
  auto* fixes_option =
      app->add_option("--fixes",
                      o->fixes_path,
                      "receiver fixes in UTM (TUM with a '# utm_zone' line; orientations ignored)");
  app->add_option("--bag", o->bag_path, "or the fixes of this bag's GNSS topic (the rig's)")
      ->excludes(fixes_option);
  app->add_option("--out", o->out_path, "georeferenced trajectory to write (TUM, UTM)")->required();
  app->add_option("--sim", o->scenario_name, "take the rig (antenna, zone) from this scenario");
  app->add_option("--config",
                  o->config_path,
                  "estimator configuration (rig.yaml with an optional estimator: section)");
  app->add_option("--json",
                  o->json_path,
                  "also write the fusion's counts here (fixes, rejected, multipath, factors, "
                  "realignments)");
  app->add_option("--options",
                  o->options_path,
                  "with --sim: a file of estimator options (an estimator: section) for the "
                  "scenario's rig, e.g. gnss: settings to try")
      ->check(CLI::ExistingFile);
}

/// The scenario's rig (with the --options file's estimator section) or the --config file.
bool LoadConfig(const Options& o, raillomer::EstimatorConfig* config, std::string* error) {
  if (o.scenario_name.empty()) {
    if (!o.options_path.empty())
      return *error = "--options goes with --sim (--config carries its own)", false;
    return raillomer::LoadEstimatorConfig(o.config_path, config, error);
  }
  raillomer::sim::Scenario scenario;
  if (!raillomer::sim::LoadScenario(o.scenario_name, &scenario, error)) return false;
  raillomer::sim::SimOptions options;
  options.duration_s = 0.1;
  auto simulator = raillomer::sim::Simulator::Create(scenario, options, error);
  if (simulator == nullptr) return false;
  std::string text = simulator->RigYaml();
  if (!o.options_path.empty()) {
    std::ifstream in(o.options_path);
    std::ostringstream options_text;
    options_text << in.rdbuf();
    text += "\n" + options_text.str();
  }
  return raillomer::ParseEstimatorConfig(text, "rig.yaml + " + o.options_path, config, error);
}

/// The fixes of the rig's GNSS topic in a bag.
bool ReadBagFixes(const std::string& bag_path,
                  const std::string& topic,
                  std::vector<raillomer::io::GnssFix>* fixes,
                  std::string* error) {
  if (topic.empty()) return *error = "the rig has no GNSS topic", false;
  raillomer::io::BagTopics topics;
  topics.lidar.clear();
  topics.imu.clear();
  topics.odometer.clear();
  topics.gnss = topic;
  auto bag = raillomer::io::BagReader::Open(bag_path, topics, error);
  if (bag == nullptr) return false;
  raillomer::io::SensorMessage message;
  while (bag->Next(&message)) {
    if (const auto* fix = std::get_if<raillomer::io::GnssFix>(&message.data))
      fixes->push_back(*fix);
  }
  if (!bag->error().empty()) return *error = bag->error(), false;
  return true;
}

/// The fixes of a TUM file in UTM, as the receiver gives them (latitude, longitude).
bool ReadTumFixes(const std::string& path,
                  std::vector<raillomer::io::GnssFix>* fixes,
                  std::string* error) {
  raillomer::api::Trajectory utm;
  if (!raillomer::api::ReadTum(path, &utm, error)) return false;
  raillomer::geo::UtmZone zone;
  if (!raillomer::geo::ParseZone(utm.utm_zone, &zone))
    return *error = path + " has no '# utm_zone' line", false;
  for (const raillomer::api::StampedPose& f : utm.poses) {
    const Eigen::Vector2d ll = raillomer::geo::UtmToGeographic(zone, f.p_world.x(), f.p_world.y());
    raillomer::io::GnssFix fix;
    fix.stamp_ns = f.stamp_ns;
    fix.latitude_deg = ll.x();
    fix.longitude_deg = ll.y();
    fix.altitude_m = f.p_world.z();
    fixes->push_back(fix);
  }
  return true;
}

/// The odometry through the fusion, poses released as the estimator releases them
/// (Estimator::ReleaseHeld, the same GnssFusion policy).
class Replay {
 public:
  Replay(const raillomer::EstimatorOptions& o, raillomer::GnssFusion* fusion)
      : o_(o), fusion_(fusion) {}

  /// Every pose of `odometry` with the fixes; false if the run never aligned to UTM.
  bool Run(const raillomer::api::Trajectory& odometry,
           const std::vector<raillomer::io::GnssFix>& fixes) {
    // The estimator hands the fusion each fix as it arrives, long before the odometry (which
    // leaves its sliding window late) reaches the fix's epoch; so every fix up to a few
    // seconds past a pose goes in before it.
    size_t next_fix = 0;
    for (const raillomer::api::StampedPose& pose : odometry.poses) {
      if (gave_up_) break;
      for (; next_fix < fixes.size() &&
             Seconds(fixes[next_fix].stamp_ns) <= Seconds(pose.stamp_ns) + 2.0;
           ++next_fix)
        fusion_->AddFix(fixes[next_fix]);
      fusion_->AddOdometry(pose.stamp_ns, raillomer::eval::ToIsometry(pose));
      held_.push_back(pose);
      Release(false);
    }
    if (!gave_up_ && fusion_->aligned()) {
      fusion_->Finish();
      Release(true);
    }
    out_.utm_zone = fusion_->zone().Name();
    return !gave_up_ && fusion_->aligned();
  }

  const raillomer::api::Trajectory& out() const { return out_; }

 private:
  /// The held poses the fusion lets go (all of them with `flush`), in UTM.
  void Release(bool flush) {
    if (held_.empty() || gave_up_) return;
    const double newest_s = Seconds(held_.back().stamp_ns);
    if (!fusion_->aligned()) {
      gave_up_ = flush || fusion_->AlignmentOverdue(newest_s - Seconds(held_.front().stamp_ns),
                                                    o_.gnss_max_hold_s);
      return;
    }
    while (!held_.empty()) {
      const double t = Seconds(held_.front().stamp_ns);
      if (!flush &&
          !fusion_->Releases(t, newest_s, o_.gnss_prompt_latency_s, o_.gnss_max_latency_s))
        break;
      const Eigen::Isometry3d T = fusion_->Publish(raillomer::eval::ToIsometry(held_.front()), t);
      raillomer::api::StampedPose p;
      p.stamp_ns = held_.front().stamp_ns;
      p.p_world = T.translation() + fusion_->origin_utm();
      p.q_world_body = Eigen::Quaterniond(T.linear()).normalized();
      out_.poses.push_back(p);
      held_.pop_front();
    }
  }

  const raillomer::EstimatorOptions& o_;
  raillomer::GnssFusion* fusion_;
  std::deque<raillomer::api::StampedPose> held_;
  bool gave_up_ = false;
  raillomer::api::Trajectory out_;
};

/// The fusion's counts as JSON, for --json.
std::string SummaryJson(const raillomer::api::Trajectory& out,
                        const raillomer::GnssFusionStats& s) {
  const nlohmann::json j = {{"poses", out.poses.size()},
                            {"utm_zone", out.utm_zone},
                            {"fixes", s.fixes},
                            {"rejected", s.rejected},
                            {"outliers", s.outliers},
                            {"factors", s.factors},
                            {"realignments", s.realignments}};
  return j.dump(2) + "\n";
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "raillomer-gnss-replay: the estimator's GNSS fusion on a recorded odometry trajectory "
      "(a --no-gnss run's trajectory.tum) and the receiver's fixes (a simulated run's gnss.tum, "
      "or a bag's GNSS topic), "
      "written as the UTM trajectory the estimator would publish"};
  Options o;
  AddOptions(&app, &o);
  CLI11_PARSE(app, argc, argv);
  if (o.scenario_name.empty() == o.config_path.empty())
    return Fail(kExitInputError, "give exactly one of --sim and --config");
  if (o.fixes_path.empty() && o.bag_path.empty())
    return Fail(kExitInputError, "give the fixes: --fixes <tum> or --bag <bag>");

  std::string error;
  raillomer::EstimatorConfig config;
  if (!LoadConfig(o, &config, &error)) return Fail(kExitInputError, error);
  raillomer::api::Trajectory odometry;
  if (!raillomer::api::ReadTum(o.odometry_path, &odometry, &error))
    return Fail(kExitInputError, error);
  if (!odometry.utm_zone.empty())
    return Fail(kExitInputError,
                o.odometry_path + " is in UTM zone " + odometry.utm_zone +
                    ": replay needs the local odometry (a --no-gnss run)");
  std::vector<raillomer::io::GnssFix> fixes;
  if (!(o.bag_path.empty() ? ReadTumFixes(o.fixes_path, &fixes, &error)
                           : ReadBagFixes(o.bag_path, config.rig.gnss_topic, &fixes, &error)))
    return Fail(kExitInputError, error);

  raillomer::GnssFusion fusion(
      config.options.gnss,
      [](const std::string& m) { std::cerr << "raillomer-gnss-replay: warning: " << m << "\n"; },
      [](const std::string& m) { std::cerr << "raillomer-gnss-replay: " << m << "\n"; });
  Replay replay(config.options, &fusion);
  if (!replay.Run(odometry, fixes))
    return Fail(kExitNotAligned, "not georeferenced: " + fusion.pending_reason());
  const raillomer::api::Trajectory& out = replay.out();
  if (!raillomer::api::WriteTum(o.out_path, out, &error)) return Fail(kExitOutputError, error);
  const raillomer::GnssFusionStats& s = fusion.stats();
  if (!o.json_path.empty() &&
      !raillomer::api::WriteFileAtomically(o.json_path, SummaryJson(out, s), &error))
    return Fail(kExitOutputError, error);
  std::fprintf(stderr,
               "raillomer-gnss-replay: %zu poses -> %s (%llu fixes, %llu multipath, %llu factors, "
               "%llu re-alignments)\n",
               out.poses.size(),
               o.out_path.c_str(),
               static_cast<unsigned long long>(s.fixes),
               static_cast<unsigned long long>(s.outliers),
               static_cast<unsigned long long>(s.factors),
               static_cast<unsigned long long>(s.realignments));
  return 0;
}
