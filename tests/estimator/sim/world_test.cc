// The corridor: a sound mesh, a changed run that differs from its base by exactly the listed
// edits, change records with the right clearance flags, the ground profile and tunnels.

#include "estimator/sim/world.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <string>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

namespace raillomer::sim {
namespace {

/// A scenario with its alignment and world, kept together (World holds references to both).
struct Built {
  Scenario scenario;
  std::unique_ptr<Alignment> alignment;
  std::unique_ptr<World> world;
};

std::unique_ptr<Built> Build(const Scenario& scenario) {
  auto built = std::make_unique<Built>();
  built->scenario = scenario;
  built->alignment = std::make_unique<Alignment>(built->scenario);
  built->world = std::make_unique<World>(built->scenario, *built->alignment);
  return built;
}

const Built& Builtin(const std::string& name) {
  static std::map<std::string, std::unique_ptr<Built>> cache;
  auto it = cache.find(name);
  if (it == cache.end()) {
    Scenario s;
    std::string error;
    EXPECT_TRUE(LoadScenario(name, &s, &error)) << error;
    it = cache.emplace(name, Build(s)).first;
  }
  return *it->second;
}

std::map<std::string, int> CountByKind(const World& world) {
  std::map<std::string, int> counts;
  for (const WorldObject& o : world.objects()) ++counts[o.kind];
  return counts;
}

using ObjectKey = std::tuple<std::string, double, double, size_t>;

ObjectKey Key(const WorldObject& o) {
  return {o.kind, o.chainage_m, o.lateral_m, o.mesh.triangles.size()};
}

const ChangeRecord* FindChange(const World& world, const std::string& kind) {
  for (const ChangeRecord& r : world.changes()) {
    if (r.kind == kind) return &r;
  }
  return nullptr;
}

/// Whether any part of `o` lies inside the structure gauge (|y| < 2.44 m, 0-6.55 m above the
/// rail top, within 50 m along the line of the object's chainage), found by sampling every
/// triangle's surface at 0.1 m or finer: a thin object lying across the track intrudes although
/// all its vertices are outside.
bool Intrudes(const Alignment& a, const WorldObject& o) {
  const TrackPoint p = a.At(o.chainage_m);
  const Eigen::Vector3d t(std::cos(p.heading_rad), std::sin(p.heading_rad), 0.0);
  auto inside = [&](const Eigen::Vector3d& x) {
    const Eigen::Vector3d d = x - p.position;
    const double along = d.dot(t), lateral = d.dot(p.Left()), height = d.z() - p.grade * along;
    return std::fabs(along) < 50.0 && std::fabs(lateral) < 2.44 && height > 0.0 && height < 6.55;
  };
  for (const Eigen::Vector3i& tri : o.mesh.triangles) {
    const Eigen::Vector3d v0 = o.mesh.vertices[tri[0]].cast<double>();
    const Eigen::Vector3d e1 = o.mesh.vertices[tri[1]].cast<double>() - v0;
    const Eigen::Vector3d e2 = o.mesh.vertices[tri[2]].cast<double>() - v0;
    const double longest = std::max({e1.norm(), e2.norm(), (e2 - e1).norm()});
    const int n = std::max(1, static_cast<int>(std::ceil(longest / 0.1)));
    for (int i = 0; i <= n; ++i) {
      for (int j = 0; i + j <= n; ++j) {
        if (inside(v0 + (double(i) / n) * e1 + (double(j) / n) * e2)) return true;
      }
    }
  }
  return false;
}

TEST(World, MeshIsNonEmptyFiniteAndConsistent) {
  const Built& demo = Builtin("demo");
  const Mesh& mesh = demo.world->mesh();
  ASSERT_GT(mesh.triangles.size(), 10000u);
  ASSERT_EQ(mesh.materials.size(), mesh.triangles.size());
  const int n = static_cast<int>(mesh.vertices.size());
  for (const Eigen::Vector3f& v : mesh.vertices) ASSERT_TRUE(v.allFinite());
  std::vector<int> per_material(static_cast<size_t>(Material::kCount), 0);
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const Eigen::Vector3i& t = mesh.triangles[i];
    ASSERT_TRUE(t.minCoeff() >= 0 && t.maxCoeff() < n) << "triangle " << i;
    ASSERT_LT(static_cast<size_t>(mesh.materials[i]), per_material.size());
    ++per_material[static_cast<size_t>(mesh.materials[i])];
  }
  for (Material m : {Material::kGround,
                     Material::kBallast,
                     Material::kSleeper,
                     Material::kRail,
                     Material::kMast,
                     Material::kWire,
                     Material::kVegetation,
                     Material::kBuilding,
                     Material::kPlatform,
                     Material::kRoad}) {
    EXPECT_GT(per_material[static_cast<size_t>(m)], 0) << "material " << static_cast<int>(m);
  }
  EXPECT_EQ(per_material[static_cast<size_t>(Material::kTunnel)], 0);  // the demo has none
  // The corridor stays within the terrain strip along the line, a few metres up or down.
  const Eigen::AlignedBox3d box = mesh.Bounds();
  const double reach = demo.alignment->length_m() + demo.scenario.terrain_half_width_m + 1.0;
  EXPECT_LT(box.max().head<2>().norm(), reach);
  EXPECT_LT(box.min().head<2>().norm(), reach);
  EXPECT_GT(box.min().z(), -10.0);
  EXPECT_LT(box.max().z(), 30.0);
  // Every object's mesh is in the world mesh.
  size_t object_triangles = 0;
  for (const WorldObject& o : demo.world->objects()) object_triangles += o.mesh.triangles.size();
  EXPECT_LT(object_triangles, mesh.triangles.size());
  EXPECT_TRUE(demo.world->changes().empty());
}

TEST(World, CatenaryMastsFollowTheScenario) {
  const Built& demo = Builtin("demo");
  const Scenario& s = demo.scenario;
  std::vector<double> chainages;
  for (const WorldObject& o : demo.world->objects()) {
    if (o.kind != "mast") continue;
    chainages.push_back(o.chainage_m);
    EXPECT_GE(o.lateral_m * s.mast_side, s.mast_offset_min_m - 1e-9);
    EXPECT_LE(o.lateral_m * s.mast_side, s.mast_offset_max_m + 1e-9);
  }
  ASSERT_GE(chainages.size(), 10u);
  EXPECT_LE(chainages.front(), 30.0);
  for (size_t i = 1; i < chainages.size(); ++i) {
    const double spacing = chainages[i] - chainages[i - 1];
    EXPECT_GE(spacing, s.mast_spacing_min_m - 1e-9);
    EXPECT_LE(spacing, s.mast_spacing_max_m + 1e-9);
  }
  EXPECT_GT(chainages.back(), demo.alignment->length_m() - s.mast_spacing_max_m);
}

TEST(World, SameSeedSameWorld) {
  const Built& demo = Builtin("demo");
  const std::unique_ptr<Built> again = Build(demo.scenario);
  ASSERT_EQ(again->world->mesh().vertices.size(), demo.world->mesh().vertices.size());
  ASSERT_EQ(again->world->objects().size(), demo.world->objects().size());
  EXPECT_TRUE(again->world->mesh().vertices == demo.world->mesh().vertices);
  Scenario other = demo.scenario;
  other.world_seed += 1;
  const std::unique_ptr<Built> different = Build(other);
  EXPECT_NE(CountByKind(*different->world), CountByKind(*demo.world));
}

/// The base world's objects that the edits of a changed run took away or moved, and the changed
/// world's objects left once each unchanged one is matched to its base (same key, same mesh).
struct EditedObjects {
  const WorldObject* removed_mast = nullptr;
  const WorldObject* moved_building = nullptr;
  std::multimap<ObjectKey, const WorldObject*> remaining;
};

EditedObjects MatchUnchangedObjects(const World& base,
                                    const World& changed,
                                    const ChangeRecord& removed,
                                    const ChangeRecord& moved) {
  EditedObjects out;
  for (const WorldObject& o : changed.objects()) out.remaining.emplace(Key(o), &o);
  for (const WorldObject& o : base.objects()) {
    if (o.kind == "mast" && o.chainage_m == removed.chainage_m) {
      out.removed_mast = &o;
      continue;
    }
    if (o.kind == "building" && std::fabs(o.chainage_m + 4.0 - moved.chainage_m) < 1e-9 &&
        std::fabs(o.lateral_m + 2.0 - moved.lateral_m) < 1e-9) {
      out.moved_building = &o;
      continue;
    }
    auto it = out.remaining.find(Key(o));
    if (it == out.remaining.end()) {
      ADD_FAILURE() << o.kind << " at " << o.chainage_m << " is missing";
      continue;
    }
    EXPECT_TRUE(it->second->mesh.vertices == o.mesh.vertices) << o.kind << " at " << o.chainage_m;
    out.remaining.erase(it);
  }
  return out;
}

TEST(World, ChangedRunDiffersFromItsBaseByTheEditsOnly) {
  const Built& base = Builtin("rich_low_station_a");
  const Built& changed = Builtin("rich_low_station_a_changed");
  ASSERT_EQ(changed.scenario.world_seed, base.scenario.world_seed);
  ASSERT_EQ(changed.world->changes().size(), 5u);

  // Counts per kind: one mast fewer; a grown tree, a fallen tree and a box more.
  std::map<std::string, int> expected = CountByKind(*base.world);
  ASSERT_GT(expected["mast"], 15);
  ASSERT_GT(expected["building"], 0);
  expected["mast"] -= 1;
  expected["tree"] += 1;
  expected["fallen_tree"] += 1;
  expected["box"] += 1;
  EXPECT_EQ(CountByKind(*changed.world), expected);
  EXPECT_EQ(changed.world->objects().size(), base.world->objects().size() - 1 + 3);

  // Every other object is where it was, with the same mesh.
  const ChangeRecord* removed = FindChange(*changed.world, "object_removed");
  const ChangeRecord* moved = FindChange(*changed.world, "object_moved");
  ASSERT_NE(removed, nullptr);
  ASSERT_NE(moved, nullptr);
  const EditedObjects edited = MatchUnchangedObjects(*base.world, *changed.world, *removed, *moved);
  const WorldObject* removed_mast = edited.removed_mast;
  const auto& remaining = edited.remaining;
  ASSERT_NE(removed_mast, nullptr);
  ASSERT_NE(edited.moved_building, nullptr);
  // Left over: the moved building and the three added objects.
  std::map<std::string, int> left;
  for (const auto& entry : remaining) ++left[std::get<0>(entry.first)];
  EXPECT_EQ(
      left,
      (std::map<std::string, int>{{"box", 1}, {"building", 1}, {"fallen_tree", 1}, {"tree", 1}}));

  // The mast nearest 850 m went; no mast is left at its chainage.
  EXPECT_NEAR(removed_mast->chainage_m, 850.0, 0.5 * base.scenario.mast_spacing_max_m);
  for (const WorldObject& o : base.world->objects()) {
    if (o.kind == "mast" && &o != removed_mast) {
      EXPECT_GE(std::fabs(o.chainage_m - 850.0), std::fabs(removed_mast->chainage_m - 850.0));
    }
  }
  for (const WorldObject& o : changed.world->objects()) {
    EXPECT_FALSE(o.kind == "mast" && o.chainage_m == removed_mast->chainage_m);
  }

  // The whole mesh: minus the mast, plus the additions, same size otherwise.
  size_t added = 0;
  for (const auto& entry : remaining) {
    if (std::get<0>(entry.first) != "building") added += std::get<3>(entry.first);
  }
  EXPECT_EQ(changed.world->mesh().triangles.size(),
            base.world->mesh().triangles.size() - removed_mast->mesh.triangles.size() + added);
}

/// The moved building's record: the building nearest 600 m, moved by 4 m along and 2 m left of
/// the line at its original chainage, from where the base world has it.
void ExpectMovedBuildingRecord(const Built& base, const Built& changed, const ChangeRecord& moved) {
  EXPECT_EQ(moved.object, "building");
  const TrackPoint p = changed.alignment->At(moved.chainage_m - 4.0);
  const Eigen::Vector3d along(std::cos(p.heading_rad), std::sin(p.heading_rad), 0.0);
  const Eigen::Vector3d expected_shift = 4.0 * along + 2.0 * p.Left();
  EXPECT_LT((moved.centre_world - moved.from_world - expected_shift).norm(), 1e-3);
  bool found = false;
  for (const WorldObject& o : base.world->objects()) {
    if (o.kind != "building" || std::fabs(o.chainage_m + 4.0 - moved.chainage_m) > 1e-9) continue;
    EXPECT_LT((o.mesh.Bounds().center() - moved.from_world).norm(), 1e-6);
    found = true;
  }
  EXPECT_TRUE(found);
  for (const WorldObject& o : base.world->objects()) {
    if (o.kind == "building") {
      EXPECT_GE(std::fabs(o.chainage_m - 600.0) + 1e-9, std::fabs(moved.chainage_m - 4.0 - 600.0));
    }
  }
}

TEST(World, ChangeRecordsDescribeTheEdits) {
  const Built& base = Builtin("rich_low_station_a");
  const Built& changed = Builtin("rich_low_station_a_changed");
  const std::vector<ChangeRecord>& changes = changed.world->changes();
  ASSERT_EQ(changes.size(), 5u);
  const std::vector<std::string> kinds = {
      "fallen_tree", "vegetation_growth", "object_removed", "object_moved", "object_added"};
  for (size_t i = 0; i < changes.size(); ++i) {
    EXPECT_EQ(changes[i].id, static_cast<int>(i) + 1);
    EXPECT_EQ(changes[i].kind, kinds[i]);
    EXPECT_TRUE(changes[i].centre_world.allFinite());
    EXPECT_GT(changes[i].extent_m.minCoeff(), 0.0);
  }
  EXPECT_EQ(changes[0].object, "fallen_tree");
  EXPECT_DOUBLE_EQ(changes[0].chainage_m, 700.0);

  const ChangeRecord& growth = changes[1];
  EXPECT_EQ(growth.object, "tree");
  EXPECT_DOUBLE_EQ(growth.chainage_m, 560.0);
  EXPECT_NEAR(growth.lateral_m, 2.44 - 0.6 + 2.0, 1e-12);  // left, crown 0.6 m into the gauge
  EXPECT_TRUE(growth.intrudes_clearance);

  const ChangeRecord& removed = changes[2];
  EXPECT_EQ(removed.object, "mast");
  EXPECT_FALSE(removed.intrudes_clearance);

  ExpectMovedBuildingRecord(base, changed, changes[3]);

  const ChangeRecord& added = changes[4];
  EXPECT_EQ(added.object, "box");
  EXPECT_DOUBLE_EQ(added.chainage_m, 1000.0);
  EXPECT_DOUBLE_EQ(added.lateral_m, 3.2);
  EXPECT_FALSE(added.intrudes_clearance);  // inner face at 2.8 m, outside the 2.44 m gauge
  EXPECT_NEAR(added.extent_m.z(), 1.6, 1e-3);

  // The flags agree with the geometry of the objects in the changed world.
  for (const WorldObject& o : changed.world->objects()) {
    if (o.kind == "box") {
      EXPECT_FALSE(Intrudes(*changed.alignment, o));
    }
    if (o.kind == "tree" && o.chainage_m == 560.0) {
      EXPECT_TRUE(Intrudes(*changed.alignment, o));
    }
  }
}

TEST(World, FallenTreeAcrossTheTrackIntrudesTheGauge) {
  // The trunk, a 12 m prism with vertices only at its ends 5.6 m either side of the track,
  // crosses the gauge between its vertices: the record tests the faces, not just the vertices.
  const Built& changed = Builtin("rich_low_station_a_changed");
  const ChangeRecord* fallen = FindChange(*changed.world, "fallen_tree");
  ASSERT_NE(fallen, nullptr);
  EXPECT_GT(fallen->extent_m.head<2>().norm(), 10.0);  // a 12 m trunk across the line
  const WorldObject* tree = nullptr;
  for (const WorldObject& o : changed.world->objects()) {
    if (o.kind == "fallen_tree") tree = &o;
  }
  ASSERT_NE(tree, nullptr);
  // It spans the track: parts of it on both sides, beyond the gauge.
  const TrackPoint p = changed.alignment->At(700.0);
  double min_lateral = 0.0, max_lateral = 0.0;
  for (const Eigen::Vector3f& v : tree->mesh.vertices) {
    const double lateral = (v.cast<double>() - p.position).dot(p.Left());
    min_lateral = std::min(min_lateral, lateral);
    max_lateral = std::max(max_lateral, lateral);
  }
  EXPECT_LT(min_lateral, -2.44);
  EXPECT_GT(max_lateral, 2.44);
  EXPECT_TRUE(Intrudes(*changed.alignment, *tree));
  EXPECT_TRUE(fallen->intrudes_clearance);
}

TEST(World, BaseCorridorKeepsTheGaugeClear) {
  // Trees, bushes and buildings of a generated corridor stay outside the structure gauge, so a
  // change detector's intrusions come from the edits alone. Bushes stand closest, at the
  // minimum offset of 4 m: their crowns must stay clear too.
  for (const char* name : {"rich_low_station_a", "demo"}) {
    const Built& built = Builtin(name);
    int intruding = 0, checked = 0;
    for (const WorldObject& o : built.world->objects()) {
      if (o.kind != "tree" && o.kind != "bush" && o.kind != "building") continue;
      ++checked;
      if (Intrudes(*built.alignment, o)) {
        ++intruding;
        ADD_FAILURE() << name << ": " << o.kind << " at chainage " << o.chainage_m << ", lateral "
                      << o.lateral_m << " reaches into the structure gauge";
      }
    }
    EXPECT_GT(checked, 50) << name;
    EXPECT_EQ(intruding, 0) << name;
  }
}

/// A 1.5 km line with a tunnel and a feature-poor stretch in a dense corridor.
Scenario TunnelScenario() {
  Scenario s;
  AlignmentSegment straight;
  straight.length_m = 1500.0;
  s.alignment = {straight};
  s.tunnels = {{600.0, 900.0}};
  s.feature_poor = {{200.0, 400.0}};
  s.trees.per_km = 200.0;
  s.bushes.per_km = 100.0;
  s.buildings.per_km = 20.0;
  s.signal_spacing_m = 100.0;
  s.world_seed = 9;
  return s;
}

TEST(World, GroundProfile) {
  const std::unique_ptr<Built> built = Build(TunnelScenario());
  const World& w = *built->world;
  for (double s : {10.0, 333.3, 1200.0}) {
    for (double side : {1.0, -1.0}) {
      EXPECT_DOUBLE_EQ(w.GroundHeight(s, 0.0), -0.36);  // ballast top
      EXPECT_DOUBLE_EQ(w.GroundHeight(s, side * 1.0), -0.36);
      EXPECT_DOUBLE_EQ(w.GroundHeight(s, side * 1.75), -0.36);     // shoulder
      EXPECT_NEAR(w.GroundHeight(s, side * 2.225), -0.63, 1e-12);  // halfway down the slope
      EXPECT_DOUBLE_EQ(w.GroundHeight(s, side * 2.7), -0.9);       // toe: formation level
      EXPECT_DOUBLE_EQ(w.GroundHeight(s, side * 3.0), -0.9);
      EXPECT_DOUBLE_EQ(w.GroundHeight(s, side * 6.0), -0.9);
      // Terrain relief beyond 6 m, within the scenario's relief.
      for (double l = 7.0; l <= 80.0; l += 7.0) {
        EXPECT_LE(std::fabs(w.GroundHeight(s, side * l) + 0.9),
                  built->scenario.terrain_relief_m + 1e-12);
      }
    }
  }
  double spread = 0.0;
  for (double s = 0.0; s < 1500.0; s += 10.0) {
    spread = std::max(spread, std::fabs(w.GroundHeight(s, 40.0) + 0.9));
  }
  EXPECT_GT(spread, 0.5);  // the relief is there
}

TEST(World, TunnelsAndFeaturePoorStretches) {
  const std::unique_ptr<Built> built = Build(TunnelScenario());
  const World& w = *built->world;
  EXPECT_FALSE(w.InTunnel(599.0));
  EXPECT_TRUE(w.InTunnel(600.0));
  EXPECT_TRUE(w.InTunnel(750.0));
  EXPECT_TRUE(w.InTunnel(900.0));
  EXPECT_FALSE(w.InTunnel(901.0));
  EXPECT_TRUE(w.InTunnel(571.0, 30.0));
  EXPECT_FALSE(w.InTunnel(569.0, 30.0));
  EXPECT_TRUE(w.InTunnel(929.0, 30.0));
  EXPECT_FALSE(w.InTunnel(931.0, 30.0));
  EXPECT_FALSE(w.InTunnel(100.0, 30.0));

  int tunnel_triangles = 0;
  for (Material m : w.mesh().materials) tunnel_triangles += m == Material::kTunnel;
  EXPECT_GT(tunnel_triangles, 100);

  std::map<std::string, int> counts;
  for (const WorldObject& o : w.objects()) {
    ++counts[o.kind];
    const bool vegetation_or_building =
        o.kind == "tree" || o.kind == "bush" || o.kind == "building";
    if (vegetation_or_building) {
      EXPECT_FALSE(o.chainage_m >= 200.0 && o.chainage_m <= 400.0)
          << o.kind << " in the feature-poor stretch at " << o.chainage_m;
      EXPECT_FALSE(w.InTunnel(o.chainage_m, 40.0)) << o.kind << " at the tunnel, " << o.chainage_m;
    }
    // Masts give way to drop brackets from the tunnel crown; no signals inside.
    if (o.kind == "mast") {
      EXPECT_FALSE(w.InTunnel(o.chainage_m, 2.0)) << o.chainage_m;
    }
    if (o.kind == "signal") {
      EXPECT_FALSE(w.InTunnel(o.chainage_m, 5.0)) << o.chainage_m;
    }
  }
  EXPECT_GT(counts["tree"], 200);  // dense elsewhere
  EXPECT_GT(counts["signal"], 5);
  EXPECT_GT(counts["mast"], 10);
  EXPECT_EQ(counts["km_post"], 1);
}

}  // namespace
}  // namespace raillomer::sim
