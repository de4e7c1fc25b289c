#include "estimator/sim/simulator.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <future>
#include <limits>

#include <yaml-cpp/yaml.h>
#include <nlohmann/json.hpp>

namespace raillomer::sim {

namespace {

constexpr double kImuBiasTrackHz = 10.0;

std::vector<double> Vec(const Eigen::Vector3d& v) { return {v.x(), v.y(), v.z()}; }

}  // namespace

Simulator::Simulator(const Scenario& scenario) : scenario_(scenario) {}

std::unique_ptr<Simulator> Simulator::Create(const Scenario& scenario,
                                             const SimOptions& options,
                                             std::string* error) {
  std::unique_ptr<Simulator> sim(new Simulator(scenario));
  Scenario& s = sim->scenario_;
  if (options.seed) s.seed = *options.seed;
  const double profile = s.ProfileDurationS();
  if (options.duration_s > profile + 1e-9) {
    if (error) {
      char text[160];
      std::snprintf(text,
                    sizeof(text),
                    "--duration %g s exceeds the scenario's motion profile of %.1f s",
                    options.duration_s,
                    profile);
      *error = text;
    }
    return nullptr;
  }
  if (options.duration_s == 0.0) {
    if (error) *error = "--duration must be positive";
    return nullptr;
  }
  sim->duration_s_ = options.duration_s > 0.0 ? options.duration_s : profile;

  sim->zone_ = geo::StandardZone(s.origin_latitude_deg, s.origin_longitude_deg);
  const Eigen::Vector2d en =
      geo::GeographicToUtm(sim->zone_, s.origin_latitude_deg, s.origin_longitude_deg);
  sim->origin_utm_ = Eigen::Vector3d(en.x(), en.y(), s.origin_height_m);
  sim->start_ns_ = static_cast<int64_t>(std::llround(s.start_time_s * 1e9));

  sim->alignment_ = std::make_unique<Alignment>(s);
  sim->world_ = std::make_unique<World>(s, *sim->alignment_);
  sim->truth_ = std::make_unique<TruthMotion>(s, *sim->alignment_, s.seed);
  if (options.lidar) {
    sim->caster_ = std::make_unique<RayCaster>(sim->world_->mesh());
    for (const LidarConfig& lidar : s.lidars) sim->lidars_.emplace_back(s, lidar, s.seed);
  }
  sim->imu_ = std::make_unique<ImuModel>(s, *sim->truth_, s.seed);
  sim->imu_samples_per_bias_entry_ =
      static_cast<uint64_t>(std::max<int64_t>(1, std::llround(s.imu_rate_hz / kImuBiasTrackHz)));
  sim->odometer_ = std::make_unique<OdometerModel>(s, *sim->truth_, s.seed);
  sim->gnss_ = std::make_unique<GnssModel>(
      s, *sim->world_, *sim->truth_, sim->zone_, sim->origin_utm_, s.seed);
  return sim;
}

int64_t Simulator::StampNs(double t) const {
  return start_ns_ + static_cast<int64_t>(std::llround(t * 1e9));
}

bool Simulator::Next(io::SensorMessage* message) {
  const double kNever = std::numeric_limits<double>::infinity();
  for (;;) {
    const double imu_t = imu_index_ / scenario_.imu_rate_hz;
    const double odo_t = odometer_index_ / scenario_.odometer_rate_hz;
    const double gnss_t = gnss_index_ / scenario_.gnss_rate_hz;
    const double period = 1.0 / scenario_.lidar_rate_hz;
    // A frame is received when its last point has been measured.
    const double frame_t = lidars_.empty() ? kNever : (frame_index_ + 1) * period;
    const double next = std::min({imu_t, odo_t, gnss_t, frame_t});
    if (next > duration_s_ + 1e-9) return false;
    last_time_s_ = next;

    if (frame_t <= next) {
      if (next_pending_ == 0) ScanFrames(frame_t);
      if (next_pending_ < pending_frames_.size()) {
        *message = std::move(pending_frames_[next_pending_++]);
        return true;
      }
      pending_frames_.clear();
      next_pending_ = 0;
      ++frame_index_;
      continue;
    }
    if (imu_t <= next) {
      if (imu_index_ % imu_samples_per_bias_entry_ == 0) {
        imu_bias_track_.push_back({StampNs(imu_t), imu_->gyro_bias(), imu_->accel_bias()});
      }
      ++imu_index_;
      io::ImuSample sample = imu_->Sample(imu_t, StampNs(imu_t));
      if (EventActive(scenario_, Event::Kind::kImuDropout, imu_t)) continue;
      message->topic = scenario_.imu_topic;
      message->receive_ns = sample.stamp_ns;
      message->data = sample;
      return true;
    }
    if (odo_t <= next) {
      ++odometer_index_;
      const io::WheelOdometry reading = odometer_->Sample(odo_t, StampNs(odo_t));
      message->topic = scenario_.odometer_topic;
      message->receive_ns = reading.stamp_ns;
      message->data = reading;
      return true;
    }
    ++gnss_index_;
    io::GnssFix fix;
    if (!gnss_->Sample(gnss_t, StampNs(gnss_t), &fix)) continue;
    message->topic = scenario_.gnss_topic;
    message->receive_ns = fix.stamp_ns;
    message->data = fix;
    return true;
  }
}

void Simulator::ScanFrames(double receive_t) {
  const double t0 = frame_index_ / scenario_.lidar_rate_hz;
  pending_frames_.clear();
  std::vector<const LivoxHorizonModel*> units;
  for (const LivoxHorizonModel& unit : lidars_) {
    if (EventActive(scenario_, Event::Kind::kLidarBlackout, t0, unit.config().name)) continue;
    io::SensorMessage message;
    message.topic = unit.config().topic;
    message.receive_ns = StampNs(receive_t);
    io::LidarFrame frame;
    frame.stamp_ns = StampNs(t0);
    frame.timebase_ns = static_cast<uint64_t>(frame.stamp_ns);
    frame.frame_id = "livox_" + unit.config().name;
    frame.lidar_id = unit.config().lidar_id;
    message.data = std::move(frame);
    pending_frames_.push_back(std::move(message));
    units.push_back(&unit);
  }
  // The units are independent: scan them concurrently, one thread each.
  const TruthMotion& truth = *truth_;
  auto scan = [this, &truth, &units, t0](size_t i) {
    auto& frame = std::get<io::LidarFrame>(pending_frames_[i].data);
    units[i]->Scan(
        frame_index_,
        t0,
        [&truth](double t) { return truth.Pose(t); },
        *caster_,
        &frame.points,
        nullptr);
  };
  std::vector<std::future<void>> workers;
  for (size_t i = 1; i < units.size(); ++i)
    workers.push_back(std::async(std::launch::async, scan, i));
  if (!units.empty()) scan(0);
  for (std::future<void>& worker : workers) worker.get();
}

api::StampedPose Simulator::TruthPose(double t) const {
  const Eigen::Isometry3d T = truth_->Pose(t);
  api::StampedPose pose;
  pose.stamp_ns = StampNs(t);
  pose.p_world = origin_utm_ + T.translation();
  pose.q_world_body = Eigen::Quaterniond(T.linear()).normalized();
  return pose;
}

api::StampedPose Simulator::FixInUtm(const io::GnssFix& fix) const {
  const Eigen::Vector2d en = geo::GeographicToUtm(zone_, fix.latitude_deg, fix.longitude_deg);
  api::StampedPose pose;
  pose.stamp_ns = fix.stamp_ns;
  pose.p_world = Eigen::Vector3d(en.x(), en.y(), fix.altitude_m);
  return pose;
}

api::Trajectory Simulator::TruthTrajectory(double rate_hz) const {
  api::Trajectory trajectory;
  trajectory.utm_zone = zone_.Name();
  const int64_t samples = static_cast<int64_t>(std::floor(duration_s_ * rate_hz + 1e-9));
  trajectory.poses.reserve(static_cast<size_t>(samples) + 1);
  for (int64_t k = 0; k <= samples; ++k) trajectory.poses.push_back(TruthPose(k / rate_hz));
  return trajectory;
}

std::string Simulator::ImuBiasCsv() const {
  std::string out =
      "stamp_s,gyro_bias_x,gyro_bias_y,gyro_bias_z,accel_bias_x,accel_bias_y,accel_bias_z\n";
  char line[256];
  for (const ImuBiasSample& b : imu_bias_track_) {
    std::snprintf(line,
                  sizeof(line),
                  ",%.6e,%.6e,%.6e,%.6e,%.6e,%.6e\n",
                  b.gyro.x(),
                  b.gyro.y(),
                  b.gyro.z(),
                  b.accel.x(),
                  b.accel.y(),
                  b.accel.z());
    out += api::FormatStampSeconds(b.stamp_ns);
    out += line;
  }
  return out;
}

std::string Simulator::RigYaml() const {
  const Scenario& s = scenario_;
  YAML::Emitter out;
  out.SetDoublePrecision(12);
  out << YAML::Comment("RailLoMer rig configuration, written by raillomer-sim for scenario '" +
                       s.name + "'. Frames: body = IMU (x forward, y left, z up).");
  out << YAML::BeginMap;
  out << YAML::Key << "rig" << YAML::Value << s.name;
  out << YAML::Key << "utm_zone" << YAML::Value << zone_.Name();
  out << YAML::Key << "lidars" << YAML::Value << YAML::BeginSeq;
  for (const LidarConfig& l : s.lidars) {
    out << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << l.name;
    out << YAML::Key << "topic" << YAML::Value << l.topic;
    out << YAML::Key << "type" << YAML::Value << "livox_ros_driver/CustomMsg";
    out << YAML::Key << "model" << YAML::Value << "livox_horizon";
    out << YAML::Key << "lidar_id" << YAML::Value << static_cast<int>(l.lidar_id);
    out << YAML::Key << "translation_m" << YAML::Value << YAML::Flow
        << std::vector<double>(l.translation_m.begin(), l.translation_m.end());
    out << YAML::Key << "rpy_deg" << YAML::Value << YAML::Flow
        << std::vector<double>(l.rpy_deg.begin(), l.rpy_deg.end());
    out << YAML::Key << "points_per_frame" << YAML::Value << s.points_per_frame;
    out << YAML::Key << "rate_hz" << YAML::Value << s.lidar_rate_hz;
    out << YAML::Key << "range_noise_m" << YAML::Value << s.range_noise_m;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::Key << "imu" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "topic" << YAML::Value << s.imu_topic;
  out << YAML::Key << "rate_hz" << YAML::Value << s.imu_rate_hz;
  out << YAML::Key << "gyro_noise_density" << YAML::Value << s.gyro_noise_density;
  out << YAML::Key << "gyro_bias_walk" << YAML::Value << s.gyro_bias_walk;
  out << YAML::Key << "accel_noise_density" << YAML::Value << s.accel_noise_density;
  out << YAML::Key << "accel_bias_walk" << YAML::Value << s.accel_bias_walk;
  out << YAML::Key << "gravity_mps2" << YAML::Value << s.gravity_mps2;
  out << YAML::EndMap;
  out << YAML::Key << "odometer" << YAML::Value << YAML::BeginMap;
  // The wheel meets the rail at the track's centre line, below the body origin: the body, high
  // above it, swings sideways over it when the track cants.
  out << YAML::Key << "translation_m" << YAML::Value << YAML::Flow
      << std::vector<double>{0.0, 0.0, -s.body_height_m};
  out << YAML::Key << "topic" << YAML::Value << s.odometer_topic;
  out << YAML::Key << "joint_name" << YAML::Value << "wheel";
  out << YAML::Key << "wheel_diameter_m" << YAML::Value << s.wheel_diameter_m;
  out << YAML::Key << "pulses_per_rev" << YAML::Value << s.pulses_per_rev;
  out << YAML::Key << "rate_hz" << YAML::Value << s.odometer_rate_hz;
  out << YAML::EndMap;
  out << YAML::Key << "gnss" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "topic" << YAML::Value << s.gnss_topic;
  out << YAML::Key << "antenna_m" << YAML::Value << YAML::Flow
      << std::vector<double>(s.gnss_antenna_m.begin(), s.gnss_antenna_m.end());
  out << YAML::Key << "rate_hz" << YAML::Value << s.gnss_rate_hz;
  out << YAML::EndMap;
  out << YAML::Key << "vehicle" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "body_above_rail_top_m" << YAML::Value << s.body_height_m;
  out << YAML::Key << "gauge_m" << YAML::Value << 1.435;
  out << YAML::EndMap;
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

std::string Simulator::ChangesJson() const {
  nlohmann::json changes = nlohmann::json::array();
  for (const ChangeRecord& r : world_->changes()) {
    const Eigen::Vector3d centre = origin_utm_ + r.centre_world;
    const Eigen::Vector2d latlon = geo::UtmToGeographic(zone_, centre.x(), centre.y());
    nlohmann::json c = {{"id", r.id},
                        {"kind", r.kind},
                        {"object", r.object},
                        {"chainage_m", r.chainage_m},
                        {"lateral_m", r.lateral_m},
                        {"centre_utm", Vec(centre)},
                        {"centre_wgs84", {latlon.x(), latlon.y()}},
                        {"extent_m", Vec(r.extent_m)},
                        {"intrudes_clearance", r.intrudes_clearance}};
    if (r.kind == "object_moved") c["from_utm"] = Vec(origin_utm_ + r.from_world);
    changes.push_back(c);
  }
  const nlohmann::json doc = {{"scenario", scenario_.name},
                              {"world_seed", scenario_.world_seed},
                              {"utm_zone", zone_.Name()},
                              {"changes", changes}};
  return doc.dump(2) + "\n";
}

}  // namespace raillomer::sim
