#include "estimator/eval/registration_bias.h"

#include <algorithm>
#include <map>
#include <utility>
#include <variant>

#include "estimator/backend/local_map.h"
#include "estimator/features/loam_features.h"
#include "estimator/io/sensor_messages.h"
#include "estimator/pipeline/config.h"
#include "estimator/preprocess/filters.h"
#include "estimator/sim/motion.h"
#include "estimator/sim/simulator.h"

namespace raillomer::eval {
namespace {

/// Running sums of pulls.
struct PullSum {
  int frames = 0;
  Eigen::Matrix<double, 6, 1> sum = Eigen::Matrix<double, 6, 1>::Zero();
  void Add(const PosePull& p) {
    sum.head<3>() += p.translation_m;
    sum.tail<3>() += p.rotation_rad;
    ++frames;
  }
  PullSummary Mean() const {
    PullSummary out;
    out.frames = frames;
    if (frames > 0) {
      out.mean.translation_m = sum.head<3>() / frames;
      out.mean.rotation_rad = sum.tail<3>() / frames;
    }
    return out;
  }
};

std::vector<Eigen::Vector3d> ToWorld(const std::vector<Eigen::Vector3f>& body,
                                     const Eigen::Isometry3d& T_world_body) {
  std::vector<Eigen::Vector3d> world;
  world.reserve(body.size());
  for (const Eigen::Vector3f& p : body) world.push_back(T_world_body * p.cast<double>());
  return world;
}

/// Scenario time (s) of a simulator stamp, from the stamp of the scenario's start.
double ScenarioTime(uint64_t stamp_ns, int64_t start_ns) {
  return static_cast<double>(static_cast<int64_t>(stamp_ns) - start_ns) * 1e-9;
}

/// Checks the rig and the options; maps LiDAR topics to units and names them in the report.
bool CheckInputs(const RigConfig& rig,
                 const RegistrationBiasOptions& options,
                 std::map<std::string, int>* unit_of_topic,
                 RegistrationBiasReport* report,
                 std::string* error) {
  if (rig.lidars.empty()) {
    *error = "the rig has no LiDARs";
    return false;
  }
  for (size_t i = 0; i < rig.lidars.size(); ++i) {
    (*unit_of_topic)[rig.lidars[i].topic] = static_cast<int>(i);
    report->lidar_names.push_back(rig.lidars[i].name);
  }
  if (!(options.window_s > 0.0) || options.min_matches < 6 || options.iterations < 1) {
    *error = "window_s must be > 0, min_matches >= 6 and iterations >= 1";
    return false;
  }
  return true;
}

/// One frame group's features, each LiDAR's frame deskewed with the true motion.
struct GroupFeatures {
  std::vector<FeatureSet> features;  ///< one per LiDAR; empty for a unit that sent nothing
  /// The true pose at the end of the group's last non-empty frame.
  Eigen::Isometry3d T_end = Eigen::Isometry3d::Identity();
  bool any = false;  ///< at least one frame has points
};

/// The pulls of one measurement: each frame group is matched at the truth against local maps of
/// the earlier groups' features placed at their true poses, solved, then mapped.
class BiasMeasurement {
 public:
  BiasMeasurement(sim::Simulator* simulator,
                  const EstimatorConfig& config,
                  const RegistrationBiasOptions& options,
                  RegistrationBiasReport* report,
                  const std::function<void(double)>& progress)
      : simulator_(simulator),
        rig_(config.rig),
        o_(config.options),
        options_(options),
        report_(report),
        progress_(progress),
        edge_map_(o_.map_voxel_m, o_.map_points_per_voxel),
        plane_map_(o_.map_voxel_m, o_.map_points_per_voxel),
        per_lidar_(rig_.lidars.size()),
        start_ns_(simulator->StampNs(0.0)) {}

  /// The stamp of the scenario's start.
  int64_t start_ns() const { return start_ns_; }

  /// One frame of every LiDAR with the same timebase, matched at the truth, then mapped.
  /// A unit that sent nothing for a timebase has an empty frame in its group.
  void Process(uint64_t timebase_ns, const std::vector<io::LidarFrame>& frames) {
    const double t_start = ScenarioTime(timebase_ns, start_ns_);
    const GroupFeatures group = ExtractFeatures(t_start, frames);
    if (!group.any) return;
    ++report_->frames;
    last_t_ = t_start;
    if (!plane_map_.empty()) AddPulls(frames, group);
    AddToMaps(group);
    CloseWindowAndReportProgress(t_start);
  }

  /// Closes the last window and writes the whole run's means into the report.
  void Finish() {
    if (window_.frames > 0) report_->windows.push_back({window_from_, last_t_, window_.Mean()});
    report_->both = both_.Mean();
    for (const PullSum& p : per_lidar_) report_->per_lidar.push_back(p.Mean());
  }

 private:
  /// Deskews each non-empty frame with the true motion over its period and extracts features.
  GroupFeatures ExtractFeatures(double t_start, const std::vector<io::LidarFrame>& frames) const {
    GroupFeatures group;
    group.features.resize(rig_.lidars.size());
    for (size_t i = 0; i < frames.size(); ++i) {
      if (frames[i].points.empty()) continue;
      const LidarRig& lidar = rig_.lidars[i];
      const double period = 1.0 / lidar.rate_hz;
      group.T_end = simulator_->truth().Pose(t_start + period);
      const Eigen::Isometry3d T_start = simulator_->truth().Pose(t_start);
      Scan scan = ScanFromLidarFrame(frames[i], static_cast<int>(i), period);
      Preprocess(o_.preprocess, &scan);
      Deskew(lidar.T_body_lidar, group.T_end.inverse() * T_start, &scan);
      group.features[i] = ExtractLoamFeatures(o_.loam, scan);
      group.any = true;
    }
    return group;
  }

  /// Matches the group at truth * start_offset; adds each LiDAR's pull and their joint pull.
  void AddPulls(const std::vector<io::LidarFrame>& frames, const GroupFeatures& group) {
    const Eigen::Isometry3d T_match = group.T_end * options_.start_offset;
    LidarMatches all;
    for (size_t i = 0; i < frames.size(); ++i) {
      if (frames[i].points.empty()) continue;
      LidarMatches m = MatchFeatures(LidarMatchOptions(o_, rig_.lidars[i].looks_down()),
                                     group.features[i],
                                     T_match,
                                     edge_map_,
                                     plane_map_);
      if (options_.matches == RegistrationBiasOptions::Matches::kPlanes) m.lines.clear();
      if (options_.matches == RegistrationBiasOptions::Matches::kEdges) m.planes.clear();
      if (static_cast<int>(m.size()) >= options_.min_matches) {
        per_lidar_[i].Add(RegistrationPull(m, T_match, group.T_end, options_.iterations));
      }
      all.planes.insert(all.planes.end(), m.planes.begin(), m.planes.end());
      all.lines.insert(all.lines.end(), m.lines.begin(), m.lines.end());
    }
    if (static_cast<int>(all.size()) >= options_.min_matches) {
      const PosePull pull = RegistrationPull(all, T_match, group.T_end, options_.iterations);
      both_.Add(pull);
      window_.Add(pull);
    }
  }

  /// Maps the group's features at the true pose; every 10th group drops the far map points.
  void AddToMaps(const GroupFeatures& group) {
    for (const FeatureSet& f : group.features) {
      edge_map_.Add(ToWorld(f.edges, group.T_end));
      plane_map_.Add(ToWorld(f.planes, group.T_end));
    }
    if (++solved_frames_ % 10 == 0) {
      edge_map_.RemoveFar(group.T_end.translation(), o_.map_radius_m);
      plane_map_.RemoveFar(group.T_end.translation(), o_.map_radius_m);
    }
  }

  /// Closes the report's window once window_s has passed, and reports progress every 10 s.
  void CloseWindowAndReportProgress(double t_start) {
    if (t_start - window_from_ >= options_.window_s) {
      report_->windows.push_back({window_from_, t_start, window_.Mean()});
      window_ = PullSum();
      window_from_ = t_start;
    }
    if (progress_ && t_start - last_progress_ >= 10.0) {
      progress_(t_start);
      last_progress_ = t_start;
    }
  }

  sim::Simulator* simulator_;
  const RigConfig& rig_;
  const EstimatorOptions& o_;
  const RegistrationBiasOptions& options_;
  RegistrationBiasReport* report_;
  const std::function<void(double)>& progress_;
  LocalMap edge_map_;
  LocalMap plane_map_;
  PullSum both_, window_;
  std::vector<PullSum> per_lidar_;
  const int64_t start_ns_;
  double window_from_ = 0.0, last_t_ = 0.0;
  double last_progress_ = 0.0;
  int solved_frames_ = 0;
};

/// Groups the simulator's LiDAR frames by timebase and processes each group once it closes.
bool RunFrameGroups(sim::Simulator* simulator,
                    const RigConfig& rig,
                    const std::map<std::string, int>& unit_of_topic,
                    const RegistrationBiasOptions& options,
                    BiasMeasurement* measurement,
                    std::string* error) {
  std::map<uint64_t, std::vector<io::LidarFrame>> held;  // frames by timebase, not yet solved
  io::SensorMessage message;
  bool seen_lidar = false;
  while (simulator->Next(&message)) {
    auto* frame = std::get_if<io::LidarFrame>(&message.data);
    if (frame == nullptr) continue;
    const auto unit = unit_of_topic.find(message.topic);
    if (unit == unit_of_topic.end()) {
      *error = "the simulator's LiDAR topic " + message.topic + " is not in the rig";
      return false;
    }
    seen_lidar = true;
    const double t = ScenarioTime(frame->timebase_ns, measurement->start_ns());
    if (options.duration_s > 0.0 && t > options.duration_s) break;
    std::vector<io::LidarFrame>& group = held[frame->timebase_ns];
    group.resize(rig.lidars.size());
    group[static_cast<size_t>(unit->second)] = std::move(*frame);
    // A newer frame closes every older group.
    while (held.size() > 1) {
      measurement->Process(held.begin()->first, held.begin()->second);
      held.erase(held.begin());
    }
  }
  for (const auto& [timebase, group] : held) measurement->Process(timebase, group);
  if (!seen_lidar) {
    *error = "the simulator produced no LiDAR frames";
    return false;
  }
  return true;
}

}  // namespace

PosePull RegistrationPull(const LidarMatches& matches,
                          const Eigen::Isometry3d& T_world_body_start,
                          const Eigen::Isometry3d& T_world_body_true,
                          int iterations) {
  const LidarOnlySolution solution = SolveLidarOnly(matches, T_world_body_start, iterations);
  const Eigen::Isometry3d delta = T_world_body_true.inverse() * solution.T_world_body;
  const Eigen::AngleAxisd rotation(delta.linear());
  PosePull pull;
  pull.translation_m = delta.translation();
  pull.rotation_rad = rotation.angle() * rotation.axis();
  return pull;
}

bool MeasureRegistrationBias(sim::Simulator* simulator,
                             const EstimatorConfig& config,
                             const RegistrationBiasOptions& options,
                             RegistrationBiasReport* report,
                             std::string* error,
                             const std::function<void(double)>& progress) {
  *report = RegistrationBiasReport();
  std::map<std::string, int> unit_of_topic;
  if (!CheckInputs(config.rig, options, &unit_of_topic, report, error)) return false;
  BiasMeasurement measurement(simulator, config, options, report, progress);
  if (!RunFrameGroups(simulator, config.rig, unit_of_topic, options, &measurement, error)) {
    return false;
  }
  measurement.Finish();
  return true;
}

}  // namespace raillomer::eval
