// The scenario loader: every built-in scenario is valid; user mistakes become messages that name
// the key and the line; `base:` inheritance; the motion profile's duration.

#include "estimator/sim/scenario.h"

#include <cmath>
#include <regex>
#include <set>
#include <string>

#include <gtest/gtest.h>

namespace raillomer::sim {
namespace {

/// A minimal valid scenario; the comments give the line numbers the tests rely on.
const std::string kMinimal =
    "name: t\n"                               // 1
    "alignment:\n"                            // 2
    "  - {type: straight, length_m: 1000}\n"  // 3
    "motion:\n"                               // 4
    "  start_m: 10\n"                         // 5
    "  phases:\n"                             // 6
    "    - {for_s: 1}\n";                     // 7

/// Parses `yaml` as "test.yaml"; returns the error message, or "" when it parsed.
std::string ParseError(const std::string& yaml) {
  Scenario s;
  std::string error;
  if (ParseScenario(yaml, "test.yaml", &s, &error)) return "";
  EXPECT_FALSE(error.empty());
  return error;
}

/// Replaces the first `from` in `text` with `to`; fails the test if `from` is absent.
std::string Replace(std::string text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

::testing::AssertionResult Contains(const std::string& text, const std::string& part) {
  if (text.find(part) != std::string::npos) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "'" << text << "' does not contain '" << part << "'";
}

TEST(Scenario, MinimalScenarioParses) {
  Scenario s;
  std::string error;
  ASSERT_TRUE(ParseScenario(kMinimal, "test.yaml", &s, &error)) << error;
  EXPECT_EQ(s.name, "t");
  ASSERT_EQ(s.alignment.size(), 1u);
  EXPECT_DOUBLE_EQ(s.alignment[0].length_m, 1000.0);
  EXPECT_DOUBLE_EQ(s.start_m, 10.0);
  ASSERT_EQ(s.phases.size(), 1u);
  EXPECT_EQ(s.phases[0].kind, MotionPhase::Kind::kForSeconds);
  // The default rig: two LiDARs, up and down.
  ASSERT_EQ(s.lidars.size(), 2u);
  EXPECT_EQ(s.lidars[0].name, "up");
  EXPECT_EQ(s.lidars[1].name, "down");
}

TEST(Scenario, EveryBuiltinScenarioParsesAndValidates) {
  const std::vector<ScenarioInfo> list = ListScenarios();
  ASSERT_GE(list.size(), 10u);
  std::set<std::string> names;
  for (const ScenarioInfo& info : list) {
    SCOPED_TRACE(info.name);
    EXPECT_TRUE(names.insert(info.name).second) << "listed twice";
    EXPECT_FALSE(info.description.empty());
    EXPECT_EQ(info.description.find("(invalid"), std::string::npos) << info.description;
    EXPECT_FALSE(BuiltinScenarioText(info.name).empty());
    Scenario s;
    std::string error;
    ASSERT_TRUE(LoadScenario(info.name, &s, &error)) << error;
    EXPECT_EQ(s.name, info.name);
    EXPECT_EQ(s.description, info.description);
    EXPECT_FALSE(s.alignment.empty());
    EXPECT_FALSE(s.phases.empty());
    EXPECT_GT(s.ProfileDurationS(), 0.0);
    EXPECT_FALSE(s.lidars.empty());
  }
  for (const char* expected : {"demo",
                               "rich_low_station_a",
                               "rich_low_station_a_changed",
                               "demo_changed",
                               "tunnel_gnss_outage",
                               "winter_wheel_slip",
                               "reverse_running"}) {
    EXPECT_TRUE(names.count(expected)) << expected;
  }
}

TEST(Scenario, UnknownNameIsRejectedWithTheBuiltinList) {
  EXPECT_TRUE(BuiltinScenarioText("no_such_scenario").empty());
  Scenario s;
  std::string error;
  EXPECT_FALSE(LoadScenario("no_such_scenario", &s, &error));
  EXPECT_TRUE(Contains(error, "no_such_scenario"));
  EXPECT_TRUE(Contains(error, "demo"));
}

TEST(Scenario, UnknownTopLevelKeyNamesKeyAndLine) {
  const std::string error = ParseError(kMinimal + "treez: 3\n");  // line 8
  EXPECT_TRUE(Contains(error, "test.yaml:8:"));
  EXPECT_TRUE(Contains(error, "unknown key 'treez'"));
}

TEST(Scenario, UnknownNestedKeyNamesKeyPathAndLine) {
  const std::string corridor = kMinimal +
                               "corridor:\n"              // 8
                               "  trees: {per_km: 5}\n"   // 9
                               "  treez: {per_km: 5}\n";  // 10
  std::string error = ParseError(corridor);
  EXPECT_TRUE(Contains(error, "test.yaml:10:"));
  EXPECT_TRUE(Contains(error, "unknown key 'corridor.treez'"));

  // Two levels down, in a flow map.
  error = ParseError(kMinimal +
                     "corridor:\n"                                   // 8
                     "  trees: {per_km: 5, offset_mm: [6, 30]}\n");  // 9
  EXPECT_TRUE(Contains(error, "test.yaml:9:"));
  EXPECT_TRUE(Contains(error, "unknown key 'corridor.trees.offset_mm'"));

  // Inside a list item.
  error = ParseError(Replace(kMinimal, "length_m: 1000}", "length_m: 1000, radius: 3}"));
  EXPECT_TRUE(Contains(error, "test.yaml:3:"));
  EXPECT_TRUE(Contains(error, "unknown key 'alignment[0].radius'"));

  // A misspelt sensor key.
  error = ParseError(kMinimal +
                     "imu:\n"                  // 8
                     "  rate_hz: 200\n"        // 9
                     "  gyro_noise: 1e-4\n");  // 10
  EXPECT_TRUE(Contains(error, "test.yaml:10:"));
  EXPECT_TRUE(Contains(error, "unknown key 'imu.gyro_noise'"));
}

TEST(Scenario, WrongTypeNamesKeyAndLine) {
  std::string error = ParseError(Replace(kMinimal, "start_m: 10", "start_m: abc"));
  EXPECT_TRUE(Contains(error, "test.yaml:5:"));
  EXPECT_TRUE(Contains(error, "'motion.start_m'"));
  EXPECT_TRUE(Contains(error, "wrong type"));

  error = ParseError(Replace(kMinimal, "start_m: 10", "start_m: [1, 2]"));
  EXPECT_TRUE(Contains(error, "test.yaml:5:"));
  EXPECT_TRUE(Contains(error, "'motion.start_m'"));

  error = ParseError(Replace(kMinimal, "length_m: 1000", "length_m: long"));
  EXPECT_TRUE(Contains(error, "test.yaml:3:"));
  EXPECT_TRUE(Contains(error, "'alignment[0].length_m'"));
}

TEST(Scenario, BadEnumsAreRejected) {
  // Curve direction.
  std::string error = ParseError(
      Replace(kMinimal,
              "  - {type: straight, length_m: 1000}\n",
              "  - {type: straight, length_m: 1000}\n"
              "  - {type: curve, length_m: 100, radius_m: 800, direction: up}\n"));  // line 4
  EXPECT_TRUE(Contains(error, "test.yaml:4:"));
  EXPECT_TRUE(Contains(error, "alignment[1].direction"));
  EXPECT_TRUE(Contains(error, "'up'"));

  // Segment type.
  error = ParseError(Replace(kMinimal, "type: straight", "type: spiral"));
  EXPECT_TRUE(Contains(error, "test.yaml:3:"));
  EXPECT_TRUE(Contains(error, "alignment[0].type"));
  EXPECT_TRUE(Contains(error, "'spiral'"));

  // Event type.
  error = ParseError(kMinimal +
                     "events:\n"                                             // 8
                     "  - {type: imu_loss, at_s: 0.5, duration_s: 0.2}\n");  // 9
  EXPECT_TRUE(Contains(error, "test.yaml:9:"));
  EXPECT_TRUE(Contains(error, "'imu_loss'"));

  // Change kind and side.
  error = ParseError(kMinimal +
                     "changes:\n"                              // 8
                     "  - {kind: object_stolen, at_m: 5}\n");  // 9
  EXPECT_TRUE(Contains(error, "test.yaml:9:"));
  EXPECT_TRUE(Contains(error, "'object_stolen'"));
  error = ParseError(kMinimal + "catenary: {mast_side: middle}\n");  // 8
  EXPECT_TRUE(Contains(error, "test.yaml:8:"));
  EXPECT_TRUE(Contains(error, "catenary.mast_side"));
}

TEST(Scenario, ImpossibleValuesAreRejected) {
  EXPECT_TRUE(Contains(ParseError(Replace(kMinimal,
                                          "type: straight, length_m: 1000",
                                          "type: curve, length_m: 1000, radius_m: 100")),
                       "radius_m"));
  EXPECT_TRUE(Contains(ParseError(Replace(kMinimal, "{for_s: 1}", "{for_s: 1, for_m: 3}")),
                       "exactly one of"));
  // for_m while standing still would never end.
  EXPECT_TRUE(
      Contains(ParseError(Replace(kMinimal, "{for_s: 1}", "{for_m: 3}")), "standing still"));
  // A blackout of a unit that does not exist.
  EXPECT_TRUE(Contains(ParseError(kMinimal + "events: [{type: lidar_blackout, at_s: 0, "
                                             "duration_s: 1, lidar: left}]\n"),
                       "'left'"));
  EXPECT_TRUE(Contains(ParseError(""), "empty"));
  // The corridor's world is built for the whole alignment: a line of 10 000 km would take
  // gigabytes before the first scan; one segment, or many, beyond 200 km are refused.
  EXPECT_TRUE(
      Contains(ParseError(Replace(
                   kMinimal, "type: straight, length_m: 1000", "type: straight, length_m: 1e7")),
               "at most 200 km"));
  EXPECT_TRUE(Contains(ParseError(Replace(kMinimal,
                                          "  - {type: straight, length_m: 1000}\n",
                                          "  - {type: straight, length_m: 150000}\n"
                                          "  - {type: straight, length_m: 150000}\n")),
                       "at most 200 km"));
}

TEST(Scenario, AlignmentTooShortForTheMotion) {
  const std::string yaml =
      "alignment: [{type: straight, length_m: 300}]\n"
      "motion:\n"
      "  start_m: 10\n"
      "  phases: [{to_kmh: 36, accel_mps2: 0.5}, {for_m: 100}]\n";
  const std::string error = ParseError(yaml);
  EXPECT_TRUE(Contains(error, "test.yaml:"));
  EXPECT_TRUE(Contains(error, "lengthen the alignment"));
  // 10 + 200 m of motion + 150 m of LiDAR range fits in 360 m.
  EXPECT_EQ(ParseError(Replace(yaml, "length_m: 300", "length_m: 360")), "");

  // Running back past the start of the line.
  const std::string back =
      "alignment: [{type: straight, length_m: 1000}]\n"
      "motion: {start_m: 10, start_speed_kmh: -36, phases: [{for_s: 2}]}\n";
  EXPECT_TRUE(Contains(ParseError(back), "raise motion.start_m"));
}

TEST(Scenario, YamlSyntaxErrorReportsALine) {
  const std::string yaml =
      "name: t\n"                              // 1
      "alignment:\n"                           // 2
      "  - {type: straight, length_m: 1000\n"  // 3: unclosed
      "motion:\n"                              // 4
      "  phases: [{for_s: 1}]\n";              // 5
  const std::string error = ParseError(yaml);
  std::smatch match;
  ASSERT_TRUE(std::regex_search(error, match, std::regex("^test\\.yaml:([0-9]+): YAML syntax")))
      << error;
  const int line = std::stoi(match[1].str());
  EXPECT_GE(line, 3);
  EXPECT_LE(line, 5);

  const std::string tab_error = ParseError("name: t\nalignment: [\n");
  EXPECT_TRUE(std::regex_search(tab_error, std::regex("^test\\.yaml:[0-9]+: YAML syntax")))
      << tab_error;
}

TEST(Scenario, BaseInheritsAndOverrides) {
  Scenario base, changed;
  std::string error;
  ASSERT_TRUE(LoadScenario("rich_low_station_a", &base, &error)) << error;
  ASSERT_TRUE(LoadScenario("rich_low_station_a_changed", &changed, &error)) << error;
  EXPECT_EQ(changed.name, "rich_low_station_a_changed");
  EXPECT_NE(changed.description, base.description);
  EXPECT_EQ(changed.seed, 2u);
  EXPECT_EQ(base.seed, 1u);
  EXPECT_EQ(changed.world_seed, base.world_seed);
  EXPECT_EQ(changed.world_seed, 101u);
  ASSERT_EQ(changed.changes.size(), 5u);
  EXPECT_TRUE(base.changes.empty());
  EXPECT_EQ(changed.changes[0].kind, Change::Kind::kFallenTree);
  EXPECT_EQ(changed.changes[2].kind, Change::Kind::kObjectRemoved);
  EXPECT_EQ(changed.changes[2].target, "mast");
  EXPECT_DOUBLE_EQ(changed.changes[3].move_m[0], 4.0);
  EXPECT_DOUBLE_EQ(changed.changes[3].move_m[1], 2.0);

  // Alignment, track and corridor come from the base.
  ASSERT_EQ(changed.alignment.size(), base.alignment.size());
  for (size_t i = 0; i < base.alignment.size(); ++i) {
    EXPECT_EQ(changed.alignment[i].kind, base.alignment[i].kind);
    EXPECT_DOUBLE_EQ(changed.alignment[i].length_m, base.alignment[i].length_m);
    EXPECT_DOUBLE_EQ(changed.alignment[i].radius_m, base.alignment[i].radius_m);
    EXPECT_EQ(changed.alignment[i].direction, base.alignment[i].direction);
    EXPECT_DOUBLE_EQ(changed.alignment[i].transition_m, base.alignment[i].transition_m);
    EXPECT_DOUBLE_EQ(changed.alignment[i].cant_mm, base.alignment[i].cant_mm);
    EXPECT_DOUBLE_EQ(changed.alignment[i].gradient_permille, base.alignment[i].gradient_permille);
  }
  EXPECT_EQ(changed.alignment[1].direction, -1);  // "right" in the base
  EXPECT_DOUBLE_EQ(changed.rail_joint_spacing_m, 25.0);
  EXPECT_DOUBLE_EQ(changed.trees.per_km, base.trees.per_km);
  EXPECT_DOUBLE_EQ(changed.trees.per_km, 70.0);
  EXPECT_DOUBLE_EQ(changed.buildings.min_offset_m, base.buildings.min_offset_m);
  EXPECT_EQ(changed.level_crossings_m, base.level_crossings_m);
  ASSERT_EQ(changed.stations.size(), 1u);
  EXPECT_DOUBLE_EQ(changed.stations[0].length_m, base.stations[0].length_m);
  EXPECT_EQ(changed.phases.size(), base.phases.size());
  EXPECT_DOUBLE_EQ(changed.ProfileDurationS(), base.ProfileDurationS());
}

TEST(Scenario, UnknownBaseIsRejected) {
  const std::string error = ParseError("base: nowhere\n" + kMinimal);
  EXPECT_TRUE(Contains(error, "test.yaml:1:"));
  EXPECT_TRUE(Contains(error, "'nowhere'"));
}

TEST(Scenario, ProfileDurationOfASimpleProfile) {
  // 0 -> 36 km/h at 0.5 m/s^2: 20 s over 100 m; then 100 m at 10 m/s: 10 s.
  const std::string yaml =
      "alignment: [{type: straight, length_m: 1000}]\n"
      "motion:\n"
      "  phases: [{to_kmh: 36, accel_mps2: 0.5}, {for_m: 100}]\n";
  Scenario s;
  std::string error;
  ASSERT_TRUE(ParseScenario(yaml, "test.yaml", &s, &error)) << error;
  ASSERT_EQ(s.phases.size(), 2u);
  EXPECT_EQ(s.phases[0].kind, MotionPhase::Kind::kToSpeed);
  EXPECT_NEAR(s.phases[0].value, 10.0, 1e-12);
  EXPECT_EQ(s.phases[1].kind, MotionPhase::Kind::kForMetres);
  EXPECT_NEAR(s.ProfileDurationS(), 30.0, 1e-9);

  // Adding a 5 s stand and a stop at 1 m/s^2 (10 s).
  s.phases.push_back({MotionPhase::Kind::kToSpeed, 0.0, 1.0});
  s.phases.push_back({MotionPhase::Kind::kForSeconds, 5.0, 0.5});
  EXPECT_NEAR(s.ProfileDurationS(), 45.0, 1e-9);
}

TEST(Scenario, StartSpeedIsRespected) {
  const std::string yaml =
      "alignment: [{type: straight, length_m: 1000}]\n"
      "motion:\n"
      "  start_speed_kmh: 36\n"
      "  phases: [{for_m: 100}, {to_kmh: 0, accel_mps2: 0.5}]\n";
  Scenario s;
  std::string error;
  ASSERT_TRUE(ParseScenario(yaml, "test.yaml", &s, &error)) << error;
  EXPECT_NEAR(s.start_speed_mps, 10.0, 1e-12);
  // 100 m at 10 m/s, then 20 s to stop.
  EXPECT_NEAR(s.ProfileDurationS(), 30.0, 1e-9);
  s.start_speed_mps = 0.0;  // without the start speed the first phase would never end
  EXPECT_NEAR(s.ProfileDurationS(), 0.0, 1e-9);
}

}  // namespace
}  // namespace raillomer::sim
