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
  const RigConfig& rig = config.rig;
  const EstimatorOptions& o = config.options;
  if (rig.lidars.empty()) {
    *error = "the rig has no LiDARs";
    return false;
  }
  std::map<std::string, int> unit_of_topic;
  for (size_t i = 0; i < rig.lidars.size(); ++i) {
    unit_of_topic[rig.lidars[i].topic] = static_cast<int>(i);
    report->lidar_names.push_back(rig.lidars[i].name);
  }
  if (!(options.window_s > 0.0) || options.min_matches < 6 || options.iterations < 1) {
    *error = "window_s must be > 0, min_matches >= 6 and iterations >= 1";
    return false;
  }

  LocalMap edge_map(o.map_voxel_m, o.map_points_per_voxel);
  LocalMap plane_map(o.map_voxel_m, o.map_points_per_voxel);
  PullSum both, window;
  std::vector<PullSum> per_lidar(rig.lidars.size());
  const int64_t start_ns = simulator->StampNs(0.0);
  double window_from = 0.0, last_t = 0.0;
  double last_progress = 0.0;
  int solved_frames = 0;

  // One frame of every LiDAR with the same timebase, matched at the truth, then mapped.
  // A unit that sent nothing for a timebase has an empty frame in its group.
  auto process = [&](uint64_t timebase_ns, const std::vector<io::LidarFrame>& frames) {
    const double t_start = static_cast<double>(static_cast<int64_t>(timebase_ns) - start_ns) * 1e-9;
    std::vector<FeatureSet> features(rig.lidars.size());
    Eigen::Isometry3d T_end = Eigen::Isometry3d::Identity();
    bool any = false;
    for (size_t i = 0; i < frames.size(); ++i) {
      if (frames[i].points.empty()) continue;
      const LidarRig& lidar = rig.lidars[i];
      const double period = 1.0 / lidar.rate_hz;
      T_end = simulator->truth().Pose(t_start + period);
      const Eigen::Isometry3d T_start = simulator->truth().Pose(t_start);
      Scan scan = ScanFromLidarFrame(frames[i], static_cast<int>(i), period);
      Preprocess(o.preprocess, &scan);
      Deskew(lidar.T_body_lidar, T_end.inverse() * T_start, &scan);
      features[i] = ExtractLoamFeatures(o.loam, scan);
      any = true;
    }
    if (!any) return;
    ++report->frames;
    last_t = t_start;
    if (!plane_map.empty()) {
      const Eigen::Isometry3d T_match = T_end * options.start_offset;
      LidarMatches all;
      for (size_t i = 0; i < frames.size(); ++i) {
        if (frames[i].points.empty()) continue;
        LidarMatches m = MatchFeatures(LidarMatchOptions(o, rig.lidars[i].looks_down()),
                                       features[i],
                                       T_match,
                                       edge_map,
                                       plane_map);
        if (options.matches == RegistrationBiasOptions::Matches::kPlanes) m.lines.clear();
        if (options.matches == RegistrationBiasOptions::Matches::kEdges) m.planes.clear();
        if (static_cast<int>(m.size()) >= options.min_matches) {
          per_lidar[i].Add(RegistrationPull(m, T_match, T_end, options.iterations));
        }
        all.planes.insert(all.planes.end(), m.planes.begin(), m.planes.end());
        all.lines.insert(all.lines.end(), m.lines.begin(), m.lines.end());
      }
      if (static_cast<int>(all.size()) >= options.min_matches) {
        const PosePull pull = RegistrationPull(all, T_match, T_end, options.iterations);
        both.Add(pull);
        window.Add(pull);
      }
    }
    for (const FeatureSet& f : features) {
      edge_map.Add(ToWorld(f.edges, T_end));
      plane_map.Add(ToWorld(f.planes, T_end));
    }
    if (++solved_frames % 10 == 0) {
      edge_map.RemoveFar(T_end.translation(), o.map_radius_m);
      plane_map.RemoveFar(T_end.translation(), o.map_radius_m);
    }
    if (t_start - window_from >= options.window_s) {
      report->windows.push_back({window_from, t_start, window.Mean()});
      window = PullSum();
      window_from = t_start;
    }
    if (progress && t_start - last_progress >= 10.0) {
      progress(t_start);
      last_progress = t_start;
    }
  };

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
    const double t =
        static_cast<double>(static_cast<int64_t>(frame->timebase_ns) - start_ns) * 1e-9;
    if (options.duration_s > 0.0 && t > options.duration_s) break;
    std::vector<io::LidarFrame>& group = held[frame->timebase_ns];
    group.resize(rig.lidars.size());
    group[static_cast<size_t>(unit->second)] = std::move(*frame);
    // A newer frame closes every older group.
    while (held.size() > 1) {
      process(held.begin()->first, held.begin()->second);
      held.erase(held.begin());
    }
  }
  for (const auto& [timebase, group] : held) process(timebase, group);
  if (!seen_lidar) {
    *error = "the simulator produced no LiDAR frames";
    return false;
  }
  if (window.frames > 0) report->windows.push_back({window_from, last_t, window.Mean()});
  report->both = both.Mean();
  for (const PullSum& p : per_lidar) report->per_lidar.push_back(p.Mean());
  return true;
}

}  // namespace raillomer::eval
