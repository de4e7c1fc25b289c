#include "estimator/sim/scenario.h"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <set>
#include <sstream>
#include <stdexcept>

#include <yaml-cpp/yaml.h>

#include "api/yaml_map_reader.h"
#include "estimator/sim/alignment.h"
#include "estimator/sim/builtin_scenarios.h"
#include "estimator/sim/motion.h"

namespace raillomer::sim {

namespace {

using api::MapReader;
using ScenarioError = api::YamlError;
using api::ForEachMap;

constexpr double kKmh = 1.0 / 3.6;
/// The longest line simulated: the corridor's world is built for the whole alignment.
constexpr double kMaxLineM = 200000.0;

void Require(bool ok, MapReader& reader, const YAML::Node& at, const std::string& message) {
  if (!ok) reader.Fail(at, message);
}

void ParseAlignment(MapReader& root, Scenario* s) {
  if (!root.Has("alignment")) return;
  s->alignment.clear();
  ForEachMap(root, "alignment", [&](MapReader& r, const YAML::Node& node) {
    AlignmentSegment seg;
    std::string type;
    r.Read("type", &type);
    if (type == "straight") {
      seg.kind = AlignmentSegment::Kind::kStraight;
    } else if (type == "curve") {
      seg.kind = AlignmentSegment::Kind::kCurve;
      r.Read("radius_m", &seg.radius_m);
      seg.direction = r.ReadSide("direction", 1);
      r.Read("transition_m", &seg.transition_m);
      r.Read("cant_mm", &seg.cant_mm);
      Require(seg.radius_m >= 150.0, r, node, "curve radius_m must be at least 150");
      Require(seg.transition_m >= 0.0, r, node, "transition_m must not be negative");
      Require(seg.cant_mm >= 0.0 && seg.cant_mm <= 180.0, r, node, "cant_mm must be in [0, 180]");
    } else {
      r.Fail(node, "key '" + r.Path("type") + "' must be straight or curve, not '" + type + "'");
    }
    r.Read("length_m", &seg.length_m);
    r.Read("gradient_permille", &seg.gradient_permille);
    Require(seg.length_m > 0.0 && seg.length_m <= kMaxLineM,
            r,
            node,
            "length_m must be positive and at most 200 km");
    Require(std::fabs(seg.gradient_permille) <= 40.0, r, node, "gradient_permille beyond +-40");
    s->alignment.push_back(seg);
  });
}

void ParseTrack(MapReader& root, Scenario* s) {
  if (!root.Has("track")) return;
  MapReader r(root.Node("track"), "track", root.source());
  r.Read("sleeper_spacing_m", &s->sleeper_spacing_m);
  r.Read("rail_joint_spacing_m", &s->rail_joint_spacing_m);
  Require(s->sleeper_spacing_m >= 0.3, r, root.Node("track"), "sleeper_spacing_m below 0.3");
  if (r.Has("parallel_tracks")) s->parallel_tracks.clear();
  ForEachMap(r, "parallel_tracks", [&](MapReader& p, const YAML::Node& node) {
    ParallelTrack t;
    p.Read("from_m", &t.from_m);
    p.Read("to_m", &t.to_m);
    t.side = p.ReadSide("side", 1);
    p.Read("spacing_m", &t.spacing_m);
    p.Read("diverge_m", &t.diverge_m);
    Require(
        t.to_m > t.from_m + 2 * t.diverge_m, p, node, "parallel track shorter than 2 diverge_m");
    Require(t.spacing_m >= 3.5, p, node, "spacing_m below 3.5");
    s->parallel_tracks.push_back(t);
  });
  r.Finish();
}

void ParseCatenary(MapReader& root, Scenario* s) {
  if (!root.Has("catenary")) return;
  const YAML::Node node = root.Node("catenary");
  MapReader r(node, "catenary", root.source());
  r.Read("enabled", &s->catenary);
  r.ReadRange("mast_spacing_m", &s->mast_spacing_min_m, &s->mast_spacing_max_m);
  r.ReadRange("mast_offset_m", &s->mast_offset_min_m, &s->mast_offset_max_m);
  s->mast_side = r.ReadSide("mast_side", s->mast_side);
  r.Read("mast_height_m", &s->mast_height_m);
  r.Read("contact_wire_height_m", &s->contact_wire_height_m);
  r.Read("system_height_m", &s->system_height_m);
  r.Read("stagger_m", &s->stagger_m);
  Require(s->mast_spacing_min_m >= 20.0, r, node, "mast_spacing_m below 20");
  Require(s->mast_offset_min_m >= 2.0, r, node, "mast_offset_m closer than 2.0 m");
  Require(s->contact_wire_height_m + s->system_height_m < s->mast_height_m,
          r,
          node,
          "mast_height_m must exceed contact wire + system height");
  r.Finish();
}

void ParseDensity(MapReader& parent, const char* key, Density* d) {
  if (!parent.Has(key)) return;
  MapReader r(parent.Node(key), parent.Path(key), parent.source());
  r.Read("per_km", &d->per_km);
  r.ReadRange("offset_m", &d->min_offset_m, &d->max_offset_m);
  Require(d->per_km >= 0.0 && d->per_km <= 2000.0, r, parent.Node(key), "per_km out of [0, 2000]");
  Require(d->min_offset_m >= 2.0, r, parent.Node(key), "offset_m closer than 2 m to the track");
  r.Finish();
}

std::vector<ChainageRange> ParseRanges(MapReader& parent, const char* key) {
  std::vector<ChainageRange> ranges;
  ForEachMap(parent, key, [&](MapReader& r, const YAML::Node& node) {
    ChainageRange range;
    r.Read("from_m", &range.from_m);
    r.Read("to_m", &range.to_m);
    Require(range.to_m > range.from_m, r, node, "to_m must exceed from_m");
    ranges.push_back(range);
  });
  return ranges;
}

void ParseCorridor(MapReader& root, Scenario* s) {
  if (!root.Has("corridor")) return;
  MapReader r(root.Node("corridor"), "corridor", root.source());
  ParseDensity(r, "trees", &s->trees);
  ParseDensity(r, "bushes", &s->bushes);
  ParseDensity(r, "buildings", &s->buildings);
  r.Read("signal_spacing_m", &s->signal_spacing_m);
  r.Read("km_posts", &s->km_posts);
  r.Read("terrain_half_width_m", &s->terrain_half_width_m);
  r.Read("terrain_relief_m", &s->terrain_relief_m);
  if (r.Has("level_crossings_m")) r.Read("level_crossings_m", &s->level_crossings_m);
  if (r.Has("stations")) s->stations.clear();
  ForEachMap(r, "stations", [&](MapReader& p, const YAML::Node& node) {
    Station st;
    p.Read("at_m", &st.at_m);
    p.Read("length_m", &st.length_m);
    st.side = p.ReadSide("side", 1);
    p.Read("platform_height_m", &st.platform_height_m);
    Require(st.length_m >= 20.0, p, node, "station length_m below 20");
    Require(st.platform_height_m >= 0.2 && st.platform_height_m <= 1.3,
            p,
            node,
            "platform_height_m must be in [0.2, 1.3]");
    s->stations.push_back(st);
  });
  if (r.Has("tunnels")) s->tunnels = ParseRanges(r, "tunnels");
  if (r.Has("feature_poor")) s->feature_poor = ParseRanges(r, "feature_poor");
  Require(
      s->terrain_half_width_m >= 20.0, r, root.Node("corridor"), "terrain_half_width_m below 20");
  r.Finish();
}

void ParseMotion(MapReader& root, Scenario* s) {
  if (!root.Has("motion")) return;
  MapReader r(root.Node("motion"), "motion", root.source());
  r.Read("start_m", &s->start_m);
  if (r.Has("start_speed_kmh")) {
    double kmh = 0.0;
    r.Read("start_speed_kmh", &kmh);
    Require(std::fabs(kmh) <= 200.0, r, r.Node("start_speed_kmh"), "start_speed_kmh beyond +-200");
    s->start_speed_mps = kmh * kKmh;
  }
  r.Read("vibration_scale", &s->vibration_scale);
  r.Read("body_height_m", &s->body_height_m);
  for (const auto& [key, value] :
       {std::pair<const char*, double*>{"body_pitch_mrad", &s->body_pitch_rad},
        {"body_yaw_mrad", &s->body_yaw_rad}}) {
    if (!r.Has(key)) continue;
    double mrad = 0.0;
    r.Read(key, &mrad);
    Require(std::fabs(mrad) <= 50.0, r, r.Node(key), std::string(key) + " beyond +-50");
    *value = mrad * 1e-3;
  }
  if (r.Has("phases")) s->phases.clear();
  ForEachMap(r, "phases", [&](MapReader& p, const YAML::Node& node) {
    MotionPhase phase;
    int kinds = 0;
    if (p.Has("for_s")) {
      phase.kind = MotionPhase::Kind::kForSeconds;
      p.Read("for_s", &phase.value);
      Require(phase.value > 0.0, p, node, "for_s must be positive");
      ++kinds;
    }
    if (p.Has("for_m")) {
      phase.kind = MotionPhase::Kind::kForMetres;
      p.Read("for_m", &phase.value);
      Require(phase.value > 0.0, p, node, "for_m must be positive");
      ++kinds;
    }
    if (p.Has("to_kmh")) {
      phase.kind = MotionPhase::Kind::kToSpeed;
      double kmh = 0.0;
      p.Read("to_kmh", &kmh);
      Require(std::fabs(kmh) <= 200.0, p, node, "to_kmh beyond +-200");
      phase.value = kmh * kKmh;
      p.Read("accel_mps2", &phase.accel_mps2);
      Require(phase.accel_mps2 > 0.0 && phase.accel_mps2 <= 2.0,
              p,
              node,
              "accel_mps2 must be in (0, 2]");
      ++kinds;
    }
    Require(kinds == 1, p, node, "a phase needs exactly one of for_s, for_m, to_kmh");
    s->phases.push_back(phase);
  });
  r.Finish();
}

void ParseLidar(MapReader& root, Scenario* s) {
  if (!root.Has("lidar")) return;
  const YAML::Node node = root.Node("lidar");
  MapReader r(node, "lidar", root.source());
  r.Read("points_per_frame", &s->points_per_frame);
  r.Read("rate_hz", &s->lidar_rate_hz);
  r.Read("range_noise_m", &s->range_noise_m);
  r.Read("angular_noise_deg", &s->angular_noise_deg);
  r.Read("min_range_m", &s->min_range_m);
  r.Read("bleeding_probability", &s->bleeding_probability);
  r.Read("vehicle_body", &s->vehicle_body);
  if (r.Has("sun")) {
    MapReader sun(r.Node("sun"), "lidar.sun", root.source());
    sun.Read("azimuth_deg", &s->sun_azimuth_deg);
    sun.Read("elevation_deg", &s->sun_elevation_deg);
    sun.Read("flicker_probability", &s->sun_flicker_probability);
    sun.Read("cone_deg", &s->sun_cone_deg);
    sun.Finish();
  }
  if (r.Has("units")) s->lidars.clear();
  ForEachMap(r, "units", [&](MapReader& u, const YAML::Node& unit) {
    LidarConfig lidar;
    u.Read("name", &lidar.name);
    u.Read("topic", &lidar.topic);
    u.ReadArray("translation_m", &lidar.translation_m);
    u.ReadArray("rpy_deg", &lidar.rpy_deg);
    int id = static_cast<int>(s->lidars.size());
    u.Read("lidar_id", &id);
    Require(id >= 0 && id <= 255, u, unit, "lidar_id must be in [0, 255]");
    lidar.lidar_id = static_cast<uint8_t>(id);
    s->lidars.push_back(lidar);
  });
  Require(s->points_per_frame >= 600 && s->points_per_frame % 60 == 0,
          r,
          node,
          "points_per_frame must be a multiple of 60 (6 lasers x 10 sweeps) and at least 600");
  Require(s->lidar_rate_hz > 0.0 && s->lidar_rate_hz <= 50.0, r, node, "rate_hz out of (0, 50]");
  Require(s->range_noise_m >= 0.0 && s->angular_noise_deg >= 0.0, r, node, "negative noise");
  r.Finish();
}

void ParseImu(MapReader& root, Scenario* s) {
  if (!root.Has("imu")) return;
  const YAML::Node node = root.Node("imu");
  MapReader r(node, "imu", root.source());
  r.Read("rate_hz", &s->imu_rate_hz);
  r.Read("topic", &s->imu_topic);
  r.Read("gyro_noise_density", &s->gyro_noise_density);
  r.Read("gyro_bias_sigma", &s->gyro_bias_sigma);
  r.Read("gyro_bias_walk", &s->gyro_bias_walk);
  r.Read("accel_noise_density", &s->accel_noise_density);
  r.Read("accel_bias_sigma", &s->accel_bias_sigma);
  r.Read("accel_bias_walk", &s->accel_bias_walk);
  r.Read("gravity_mps2", &s->gravity_mps2);
  Require(s->imu_rate_hz >= 50.0 && s->imu_rate_hz <= 2000.0, r, node, "rate_hz out of [50, 2000]");
  r.Finish();
}

void ParseOdometer(MapReader& root, Scenario* s) {
  if (!root.Has("odometer")) return;
  const YAML::Node node = root.Node("odometer");
  MapReader r(node, "odometer", root.source());
  r.Read("rate_hz", &s->odometer_rate_hz);
  r.Read("topic", &s->odometer_topic);
  r.Read("wheel_diameter_m", &s->wheel_diameter_m);
  r.Read("pulses_per_rev", &s->pulses_per_rev);
  r.Read("scale_error", &s->odometer_scale_error);
  r.Read("creep_sigma", &s->creep_sigma);
  Require(s->wheel_diameter_m >= 0.5 && s->wheel_diameter_m <= 1.5,
          r,
          node,
          "wheel_diameter_m out of [0.5, 1.5]");
  Require(s->pulses_per_rev >= 1 && s->pulses_per_rev <= 10000,
          r,
          node,
          "pulses_per_rev out of [1, 10000]");
  Require(s->odometer_rate_hz > 0.0 && s->odometer_rate_hz <= 1000.0, r, node, "bad rate_hz");
  r.Finish();
}

void ParseGnss(MapReader& root, Scenario* s) {
  if (!root.Has("gnss")) return;
  const YAML::Node node = root.Node("gnss");
  MapReader r(node, "gnss", root.source());
  r.Read("rate_hz", &s->gnss_rate_hz);
  r.Read("topic", &s->gnss_topic);
  r.ReadArray("antenna_m", &s->gnss_antenna_m);
  r.Read("horizontal_sigma_m", &s->gnss_horizontal_sigma_m);
  r.Read("vertical_sigma_m", &s->gnss_vertical_sigma_m);
  r.Read("white_sigma_m", &s->gnss_white_sigma_m);
  r.Read("tau_s", &s->gnss_tau_s);
  r.Read("outlier_probability", &s->gnss_outlier_probability);
  r.Read("reported_sigma_m", &s->gnss_reported_sigma_m);
  Require(s->gnss_rate_hz > 0.0 && s->gnss_rate_hz <= 20.0, r, node, "rate_hz out of (0, 20]");
  Require(s->gnss_tau_s > 0.0, r, node, "tau_s must be positive");
  r.Finish();
}

void ParseEvents(MapReader& root, Scenario* s) {
  if (root.Has("events")) s->events.clear();
  ForEachMap(root, "events", [&](MapReader& r, const YAML::Node& node) {
    Event e;
    std::string type;
    r.Read("type", &type);
    r.Read("at_s", &e.at_s);
    r.Read("duration_s", &e.duration_s);
    if (type == "imu_dropout") {
      e.kind = Event::Kind::kImuDropout;
    } else if (type == "gnss_outage") {
      e.kind = Event::Kind::kGnssOutage;
    } else if (type == "wheel_slip") {
      e.kind = Event::Kind::kWheelSlip;
      r.Read("slip", &e.slip);
      Require(e.slip > -1.0 && e.slip < 2.0, r, node, "slip must be in (-1, 2)");
    } else if (type == "lidar_blackout") {
      e.kind = Event::Kind::kLidarBlackout;
      r.Read("lidar", &e.lidar);
      Require(!e.lidar.empty(), r, node, "lidar_blackout needs 'lidar' (a unit name)");
    } else {
      r.Fail(node,
             "event type must be imu_dropout, gnss_outage, wheel_slip or lidar_blackout, not '" +
                 type + "'");
    }
    Require(e.at_s >= 0.0 && e.duration_s > 0.0, r, node, "event needs at_s >= 0, duration_s > 0");
    s->events.push_back(e);
  });
}

void ParseChanges(MapReader& root, Scenario* s) {
  if (root.Has("changes")) s->changes.clear();
  ForEachMap(root, "changes", [&](MapReader& r, const YAML::Node& node) {
    Change c;
    std::string kind;
    r.Read("kind", &kind);
    r.Read("at_m", &c.at_m);
    if (kind == "object_added") {
      c.kind = Change::Kind::kObjectAdded;
      r.Read("offset_m", &c.offset_m);
      r.ReadArray("size_m", &c.size_m);
      Require(c.size_m[0] > 0 && c.size_m[1] > 0 && c.size_m[2] > 0, r, node, "size_m must be > 0");
    } else if (kind == "object_removed" || kind == "object_moved") {
      c.kind = kind == "object_removed" ? Change::Kind::kObjectRemoved : Change::Kind::kObjectMoved;
      r.Read("target", &c.target);
      Require(c.target == "mast" || c.target == "signal" || c.target == "building" ||
                  c.target == "tree",
              r,
              node,
              "target must be mast, signal, building or tree");
      if (c.kind == Change::Kind::kObjectMoved) r.ReadArray("move_m", &c.move_m);
    } else if (kind == "vegetation_growth") {
      c.kind = Change::Kind::kVegetationGrowth;
      c.side = r.ReadSide("side", 1);
      r.Read("intrusion_m", &c.intrusion_m);
      Require(c.intrusion_m > 0.0 && c.intrusion_m < 2.0, r, node, "intrusion_m out of (0, 2)");
    } else if (kind == "fallen_tree") {
      c.kind = Change::Kind::kFallenTree;
    } else {
      r.Fail(node,
             "change kind must be object_added, object_removed, object_moved, "
             "vegetation_growth or fallen_tree, not '" +
                 kind + "'");
    }
    s->changes.push_back(c);
  });
}

void DefaultLidars(Scenario* s) {
  LidarConfig up;
  up.name = "up";
  up.topic = "/livox/lidar_up";
  up.translation_m = {0.3, 0.0, 0.35};
  up.rpy_deg = {0.0, -12.7, 0.0};
  up.lidar_id = 0;
  LidarConfig down = up;
  down.name = "down";
  down.topic = "/livox/lidar_down";
  down.translation_m = {0.3, 0.0, 0.15};
  down.rpy_deg = {0.0, 12.7, 0.0};
  down.lidar_id = 1;
  s->lidars = {up, down};
}

void ParseInto(const YAML::Node& root_node, const std::string& source, Scenario* s, int depth);

void ParseBase(MapReader& root, Scenario* s, int depth) {
  if (!root.Has("base")) return;
  std::string base;
  root.Read("base", &base);
  if (depth > 4) root.Fail(root.Node("base"), "base scenarios nest too deeply");
  const std::string text = BuiltinScenarioText(base);
  if (text.empty()) root.Fail(root.Node("base"), "unknown base scenario '" + base + "'");
  ParseInto(YAML::Load(text), "builtin:" + base, s, depth + 1);
}

void ParseInto(const YAML::Node& root_node, const std::string& source, Scenario* s, int depth) {
  MapReader root(root_node, "", source);
  ParseBase(root, s, depth);
  root.Read("name", &s->name);
  root.Read("description", &s->description);
  root.Read("world_seed", &s->world_seed);
  root.Read("seed", &s->seed);
  if (root.Has("origin")) {
    MapReader o(root.Node("origin"), "origin", source);
    o.Read("latitude_deg", &s->origin_latitude_deg);
    o.Read("longitude_deg", &s->origin_longitude_deg);
    o.Read("height_m", &s->origin_height_m);
    Require(std::fabs(s->origin_latitude_deg) <= 80.0,
            o,
            root.Node("origin"),
            "latitude_deg outside the UTM range [-80, 80]");
    o.Finish();
  }
  root.Read("initial_azimuth_deg", &s->initial_azimuth_deg);
  root.Read("start_time_s", &s->start_time_s);
  root.Read("vertical_curve_m", &s->vertical_curve_m);
  ParseAlignment(root, s);
  ParseTrack(root, s);
  ParseCatenary(root, s);
  ParseCorridor(root, s);
  ParseMotion(root, s);
  ParseLidar(root, s);
  ParseImu(root, s);
  ParseOdometer(root, s);
  ParseGnss(root, s);
  ParseEvents(root, s);
  ParseChanges(root, s);
  root.Finish();
}

std::string Metres(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.1f m", value);
  return buffer;
}

void Validate(const std::string& source, Scenario* s) {
  auto fail = [&](const std::string& message) { throw ScenarioError(source + ": " + message); };
  if (s->lidars.empty()) DefaultLidars(s);
  if (s->alignment.empty()) fail("alignment is empty: list at least one straight or curve");
  if (s->phases.empty()) fail("motion.phases is empty: the train never moves");
  double v = s->start_speed_mps;
  for (size_t i = 0; i < s->phases.size(); ++i) {
    const MotionPhase& p = s->phases[i];
    if (p.kind == MotionPhase::Kind::kForMetres && std::fabs(v) < 1e-9) {
      fail("motion.phases[" + std::to_string(i) + "]: for_m while standing still never ends");
    }
    if (p.kind == MotionPhase::Kind::kToSpeed) v = p.value;
  }
  double min_s = 0.0, max_s = 0.0;
  SpeedProfile(*s).DistanceRange(&min_s, &max_s);
  const double length = Alignment(*s).length_m();
  if (length > kMaxLineM)
    fail("the alignment is " + Metres(length) +
         " long; a line is at most 200 km (the corridor's "
         "world is built for its whole length)");
  const double lookahead_m = 150.0;
  if (s->start_m + min_s < 0.0) {
    fail("motion runs back to chainage " + Metres(s->start_m + min_s) +
         ", before the line's start: raise motion.start_m");
  }
  if (s->start_m + max_s + lookahead_m > length) {
    fail("motion reaches chainage " + Metres(s->start_m + max_s) + " but the alignment is " +
         Metres(length) + " long; it must extend " + Metres(lookahead_m) +
         " beyond (LiDAR range): lengthen the alignment");
  }
  std::set<std::string> names;
  for (const LidarConfig& l : s->lidars) {
    if (!names.insert(l.name).second) fail("two lidar units are named '" + l.name + "'");
  }
  for (const Event& e : s->events) {
    if (e.kind == Event::Kind::kLidarBlackout && !names.count(e.lidar)) {
      fail("lidar_blackout names lidar '" + e.lidar + "', which is not one of the units");
    }
  }
  for (const ChainageRange& t : s->tunnels) {
    if (t.to_m > length) fail("a tunnel ends beyond the alignment's length");
  }
}

}  // namespace

double Scenario::ProfileDurationS() const { return SpeedProfile(*this).duration_s(); }

bool ParseScenario(const std::string& yaml_text,
                   const std::string& source_name,
                   Scenario* scenario,
                   std::string* error) {
  Scenario s;
  try {
    const YAML::Node root = YAML::Load(yaml_text);
    if (!root || root.IsNull()) throw ScenarioError(source_name + ": the scenario is empty");
    ParseInto(root, source_name, &s, 0);
    Validate(source_name, &s);
  } catch (const ScenarioError& e) {
    if (error) *error = e.what();
    return false;
  } catch (const YAML::Exception& e) {
    if (error) {
      *error = source_name + ":" + std::to_string(e.mark.line + 1) + ": YAML syntax: " + e.msg;
    }
    return false;
  }
  *scenario = std::move(s);
  return true;
}

bool LoadScenario(const std::string& name_or_path, Scenario* scenario, std::string* error) {
  const std::string builtin = BuiltinScenarioText(name_or_path);
  if (!builtin.empty()) return ParseScenario(builtin, "builtin:" + name_or_path, scenario, error);
  std::ifstream in(name_or_path);
  if (!in) {
    std::string names;
    for (const ScenarioInfo& info : ListScenarios()) names += " " + info.name;
    if (error) {
      *error = "'" + name_or_path + "' is neither a scenario file nor a built-in scenario (" +
               "built-ins:" + names + ")";
    }
    return false;
  }
  std::stringstream buffer;
  buffer << in.rdbuf();
  return ParseScenario(buffer.str(), name_or_path, scenario, error);
}

std::vector<ScenarioInfo> ListScenarios() {
  std::vector<ScenarioInfo> list;
  for (const BuiltinScenario& b : BuiltinScenarios()) {
    Scenario s;
    std::string error;
    ScenarioInfo info{b.name, "(invalid: see --scenario " + b.name + ")"};
    if (ParseScenario(b.yaml, "builtin:" + b.name, &s, &error)) info.description = s.description;
    list.push_back(info);
  }
  return list;
}

std::string BuiltinScenarioText(const std::string& name) {
  for (const BuiltinScenario& b : BuiltinScenarios()) {
    if (name == b.name) return b.yaml;
  }
  return {};
}

}  // namespace raillomer::sim
