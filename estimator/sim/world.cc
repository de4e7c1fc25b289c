#include "estimator/sim/world.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>

namespace raillomer::sim {

namespace {

/// A trackside object of `kind` at a chainage and lateral offset, its mesh still empty.
WorldObject Object(const std::string& kind, double chainage_m, double lateral_m) {
  WorldObject object;
  object.kind = kind;
  object.chainage_m = chainage_m;
  object.lateral_m = lateral_m;
  return object;
}

constexpr double kRailHeadCentreM = 0.7535;  // half gauge (0.7175) + half head width (0.036)
constexpr double kBallastTopM = -0.36;       // below the rail-top plane
constexpr double kBallastShoulderM = 1.75;   // half width of the ballast top
constexpr double kFormationM = -0.9;         // ground level beside the track
constexpr double kBallastToeM = 2.7;
constexpr double kClearanceHalfWidthM = 2.44;
constexpr double kClearanceHeightM = 6.55;
constexpr double kTunnelHalfWidthM = 4.5;
constexpr double kTunnelSpringM = 4.5;  // wall height where the arch starts

using Vec3 = Eigen::Vector3d;

double Uniform(std::mt19937& rng, double lo, double hi) {
  return std::uniform_real_distribution<double>(lo, hi)(rng);
}

/// The track frame at chainage s shifted sideways by `offset_m`: maps (lateral, height) to world.
struct TrackSection {
  Vec3 origin;
  Eigen::Matrix3d R;
  Vec3 At(double lateral, double height, double along = 0.0) const {
    return origin + R * Vec3(along, lateral, height);
  }
};

TrackSection SectionAt(const Alignment& a, double s, double offset_m) {
  const TrackPoint p = a.At(s);
  TrackSection section;
  section.R = p.Rotation();
  section.origin = p.position + section.R * Vec3(0.0, offset_m, 0.0);
  return section;
}

/// Extrudes a polyline profile (lateral, height) along the line between chainages.
void Extrude(const std::vector<Eigen::Vector2d>& profile,
             bool closed,
             double from,
             double to,
             double step,
             const std::function<TrackSection(double)>& section_at,
             Material m,
             Mesh* mesh) {
  if (to <= from) return;
  const int n = std::max(1, static_cast<int>(std::ceil((to - from) / step)));
  std::vector<Vec3> previous;
  for (int i = 0; i <= n; ++i) {
    const double s = from + (to - from) * i / n;
    const TrackSection section = section_at(s);
    std::vector<Vec3> ring;
    ring.reserve(profile.size());
    for (const Eigen::Vector2d& q : profile) ring.push_back(section.At(q.x(), q.y()));
    if (i > 0) {
      const size_t edges = closed ? profile.size() : profile.size() - 1;
      for (size_t k = 0; k < edges; ++k) {
        const size_t k1 = (k + 1) % profile.size();
        mesh->AddQuad(previous[k], previous[k1], ring[k1], ring[k], m);
      }
    }
    previous.swap(ring);
  }
}

std::vector<Eigen::Vector2d> RailProfile(double centre) {
  const double c = centre;
  return {{c - 0.036, 0.0},
          {c + 0.036, 0.0},
          {c + 0.036, -0.05},
          {c + 0.0083, -0.05},
          {c + 0.0083, -0.16},
          {c + 0.075, -0.16},
          {c + 0.075, -0.172},
          {c - 0.075, -0.172},
          {c - 0.075, -0.16},
          {c - 0.0083, -0.16},
          {c - 0.0083, -0.05},
          {c - 0.036, -0.05}};
}

std::vector<Eigen::Vector2d> TunnelProfile() {
  std::vector<Eigen::Vector2d> profile;
  profile.emplace_back(-kTunnelHalfWidthM, kFormationM);
  const int arch = 16;
  for (int i = 0; i <= arch; ++i) {
    const double a = M_PI - M_PI * i / arch;
    profile.emplace_back(kTunnelHalfWidthM * std::cos(a),
                         kTunnelSpringM + kTunnelHalfWidthM * std::sin(a));
  }
  profile.emplace_back(kTunnelHalfWidthM, kFormationM);
  return profile;
}

/// One catenary span: the contact wire straight, the messenger sagging by `sag`, droppers.
void AddSpanWires(
    const Vec3& c0, const Vec3& c1, const Vec3& m0, const Vec3& m1, double sag, Mesh* wires) {
  wires->AddCylinder(c0, c1, 0.0065, 4, Material::kWire);
  const double span = (c1 - c0).norm();
  const int pieces = std::max(2, static_cast<int>(span / 5.0));
  auto messenger_at = [&](double u) -> Vec3 {
    return m0 + u * (m1 - m0) - Vec3(0, 0, sag * 4.0 * u * (1.0 - u));
  };
  for (int k = 0; k < pieces; ++k) {
    wires->AddCylinder(messenger_at(double(k) / pieces),
                       messenger_at(double(k + 1) / pieces),
                       0.006,
                       4,
                       Material::kWire);
  }
  const int droppers = std::max(1, static_cast<int>(span / 9.0));
  for (int k = 1; k < droppers; ++k) {
    const double u = double(k) / droppers;
    wires->AddCylinder(c0 + u * (c1 - c0), messenger_at(u), 0.003, 3, Material::kWire);
  }
}

/// A station's platform in 10 m blocks, each with its canopy pillar, roof and lamp post.
WorldObject Platform(const Alignment& alignment, const Station& st) {
  const double side = st.side;
  WorldObject platform = Object("platform", st.at_m + 0.5 * st.length_m, side * 4.75);
  for (double s = st.at_m; s < st.at_m + st.length_m; s += 10.0) {
    const double mid = s + 5.0;
    const TrackPoint p = alignment.At(mid);
    const Eigen::Matrix3d R = Eigen::AngleAxisd(p.heading_rad, Vec3::UnitZ()).toRotationMatrix();
    const double bottom = kFormationM, top = st.platform_height_m;
    platform.mesh.AddBox(alignment.Beside(mid, side * 4.75, 0.5 * (top + bottom)),
                         R,
                         Vec3(5.0, 3.0, 0.5 * (top - bottom)),
                         Material::kPlatform);
    // Canopy pillars and roof, lamp posts.
    platform.mesh.AddCylinder(alignment.Beside(mid, side * 5.6, top),
                              alignment.Beside(mid, side * 5.6, top + 4.4),
                              0.15,
                              6,
                              Material::kMast);
    platform.mesh.AddBox(
        alignment.Beside(mid, side * 5.6, top + 4.5), R, Vec3(5.0, 2.0, 0.1), Material::kRoof);
    platform.mesh.AddCylinder(alignment.Beside(s, side * 7.4, top),
                              alignment.Beside(s, side * 7.4, top + 5.0),
                              0.06,
                              4,
                              Material::kMast);
  }
  return platform;
}

/// A level crossing at chainage `at`: road panel, barrier posts and booms, cross-buck signs.
WorldObject LevelCrossing(const Alignment& alignment, double at) {
  WorldObject crossing;
  crossing.kind = "level_crossing";
  crossing.chainage_m = at;
  const TrackPoint p = alignment.At(at);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(p.heading_rad, Vec3::UnitZ()).toRotationMatrix();
  crossing.mesh.AddBox(alignment.Beside(at, 0.0, 0.5 * (-0.01 + kFormationM)),
                       R,
                       Vec3(3.0, 20.0, 0.5 * (kFormationM + 0.01) * -1.0),
                       Material::kRoad);
  for (double side : {1.0, -1.0}) {
    const double along = side * 5.0;
    const Vec3 post = alignment.Beside(at + along, side * 4.5, kFormationM);
    crossing.mesh.AddCylinder(post, post + Vec3(0, 0, 1.3), 0.12, 6, Material::kMast);
    crossing.mesh.AddCylinder(post + Vec3(0, 0, 1.1),
                              alignment.Beside(at + along, side * 10.0, kFormationM + 1.1),
                              0.05,
                              4,
                              Material::kSign);
    const Vec3 sign = alignment.Beside(at - along, side * 4.0, kFormationM);
    crossing.mesh.AddCylinder(sign, sign + Vec3(0, 0, 2.8), 0.05, 4, Material::kMast);
    crossing.mesh.AddBox(sign + Vec3(0, 0, 2.6), R, Vec3(0.03, 0.6, 0.1), Material::kSign);
  }
  return crossing;
}

}  // namespace

double MaterialReflectivity(Material material) {
  switch (material) {
    case Material::kGround:
      return 15.0;
    case Material::kBallast:
      return 22.0;
    case Material::kSleeper:
      return 35.0;
    case Material::kRail:
      return 30.0;
    case Material::kMast:
      return 40.0;
    case Material::kWire:
      return 45.0;
    case Material::kVegetation:
      return 45.0;
    case Material::kBuilding:
      return 35.0;
    case Material::kRoof:
      return 20.0;
    case Material::kPlatform:
      return 30.0;
    case Material::kSignal:
      return 150.0;  // retro-reflective plate
    case Material::kRoad:
      return 10.0;
    case Material::kTunnel:
      return 30.0;
    case Material::kSign:
      return 140.0;
    case Material::kVehicle:
      return 60.0;
    case Material::kCount:
      break;
  }
  return 20.0;
}

void Mesh::Append(const Mesh& other) {
  const int base = static_cast<int>(vertices.size());
  vertices.insert(vertices.end(), other.vertices.begin(), other.vertices.end());
  for (const Eigen::Vector3i& t : other.triangles) triangles.push_back(t.array() + base);
  materials.insert(materials.end(), other.materials.begin(), other.materials.end());
}

void Mesh::AddTriangle(const Vec3& a, const Vec3& b, const Vec3& c, Material m) {
  const int base = static_cast<int>(vertices.size());
  vertices.push_back(a.cast<float>());
  vertices.push_back(b.cast<float>());
  vertices.push_back(c.cast<float>());
  triangles.emplace_back(base, base + 1, base + 2);
  materials.push_back(m);
}

void Mesh::AddQuad(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& d, Material m) {
  const int base = static_cast<int>(vertices.size());
  for (const Vec3* v : {&a, &b, &c, &d}) vertices.push_back(v->cast<float>());
  triangles.emplace_back(base, base + 1, base + 2);
  triangles.emplace_back(base, base + 2, base + 3);
  materials.push_back(m);
  materials.push_back(m);
}

void Mesh::AddBox(const Vec3& centre, const Eigen::Matrix3d& R, const Vec3& half, Material m) {
  Vec3 corner[8];
  for (int i = 0; i < 8; ++i) {
    const Vec3 sign((i & 1) ? 1 : -1, (i & 2) ? 1 : -1, (i & 4) ? 1 : -1);
    corner[i] = centre + R * sign.cwiseProduct(half);
  }
  static const int kFaces[6][4] = {
      {0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
  for (const auto& f : kFaces) AddQuad(corner[f[0]], corner[f[1]], corner[f[2]], corner[f[3]], m);
}

void Mesh::AddCylinder(const Vec3& a, const Vec3& b, double radius, int sides, Material m) {
  const Vec3 axis = (b - a).normalized();
  const Vec3 helper = std::fabs(axis.z()) < 0.9 ? Vec3::UnitZ() : Vec3::UnitX();
  const Vec3 u = axis.cross(helper).normalized();
  const Vec3 v = axis.cross(u);
  std::vector<Vec3> ring(sides);
  for (int i = 0; i < sides; ++i) {
    const double angle = 2.0 * M_PI * i / sides;
    ring[i] = radius * (std::cos(angle) * u + std::sin(angle) * v);
  }
  for (int i = 0; i < sides; ++i) {
    const int j = (i + 1) % sides;
    AddQuad(a + ring[i], a + ring[j], b + ring[j], b + ring[i], m);
    AddTriangle(a, a + ring[j], a + ring[i], m);
    AddTriangle(b, b + ring[i], b + ring[j], m);
  }
}

void Mesh::AddBlob(
    const Vec3& centre, const Vec3& radii, double jitter, std::mt19937& rng, Material m) {
  // Icosahedron subdivided once: 80 faces.
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Vec3> v = {{-1, t, 0},
                         {1, t, 0},
                         {-1, -t, 0},
                         {1, -t, 0},
                         {0, -1, t},
                         {0, 1, t},
                         {0, -1, -t},
                         {0, 1, -t},
                         {t, 0, -1},
                         {t, 0, 1},
                         {-t, 0, -1},
                         {-t, 0, 1}};
  std::vector<Eigen::Vector3i> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                    {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                    {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                    {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (Vec3& p : v) p.normalize();
  std::map<std::pair<int, int>, int> midpoints;
  auto mid = [&](int a, int b) {
    const auto key = std::minmax(a, b);
    auto it = midpoints.find(key);
    if (it != midpoints.end()) return it->second;
    v.push_back((v[a] + v[b]).normalized());
    return midpoints[key] = static_cast<int>(v.size()) - 1;
  };
  std::vector<Eigen::Vector3i> faces;
  for (const Eigen::Vector3i& tri : f) {
    const int a = mid(tri[0], tri[1]), b = mid(tri[1], tri[2]), c = mid(tri[2], tri[0]);
    faces.insert(faces.end(), {{tri[0], a, c}, {tri[1], b, a}, {tri[2], c, b}, {a, b, c}});
  }
  std::vector<Vec3> world(v.size());
  for (size_t i = 0; i < v.size(); ++i) {
    const double scale = 1.0 + Uniform(rng, -jitter, jitter);
    world[i] = centre + scale * v[i].cwiseProduct(radii);
  }
  for (const Eigen::Vector3i& tri : faces)
    AddTriangle(world[tri[0]], world[tri[1]], world[tri[2]], m);
}

void Mesh::Translate(const Vec3& delta) {
  const Eigen::Vector3f d = delta.cast<float>();
  for (Eigen::Vector3f& p : vertices) p += d;
}

Eigen::AlignedBox3d Mesh::Bounds() const {
  Eigen::AlignedBox3d box;
  for (const Eigen::Vector3f& p : vertices) box.extend(p.cast<double>());
  return box;
}

World::World(const Scenario& scenario, const Alignment& alignment, const WorldOptions& options)
    : scenario_(scenario), alignment_(alignment), options_(options) {
  std::mt19937 rng(scenario.world_seed * 2654435761u + 1u);
  Mesh infrastructure;
  BuildTrack(&infrastructure);
  BuildTerrain(&infrastructure);
  BuildTunnels(&infrastructure);
  mesh_ = std::move(infrastructure);
  BuildCatenary(rng);
  BuildStations();
  BuildCorridor(rng);
  ApplyChanges(rng);
  for (const WorldObject& object : objects_) mesh_.Append(object.mesh);
}

bool World::InTunnel(double s, double margin_m) const {
  for (const ChainageRange& t : scenario_.tunnels) {
    if (s >= t.from_m - margin_m && s <= t.to_m + margin_m) return true;
  }
  return false;
}

bool World::FeaturePoor(double s) const {
  for (const ChainageRange& r : scenario_.feature_poor) {
    if (s >= r.from_m && s <= r.to_m) return true;
  }
  return false;
}

bool World::NearStructure(double s, double lateral_m) const {
  for (const Station& st : scenario_.stations) {
    if (s > st.at_m - 30.0 && s < st.at_m + st.length_m + 30.0 && lateral_m * st.side > 0.0 &&
        std::fabs(lateral_m) < 40.0) {
      return true;
    }
  }
  for (double at : scenario_.level_crossings_m) {
    if (std::fabs(s - at) < 15.0) return true;
  }
  for (const ParallelTrack& p : scenario_.parallel_tracks) {
    if (s > p.from_m && s < p.to_m && lateral_m * p.side > 0.0 &&
        std::fabs(lateral_m) < p.spacing_m + 6.0) {
      return true;
    }
  }
  return InTunnel(s, 40.0);
}

double World::GroundHeight(double s, double lateral_m) const {
  const double l = std::fabs(lateral_m);
  if (l <= kBallastShoulderM) return kBallastTopM;
  if (l <= kBallastToeM) {
    return kBallastTopM + (kFormationM - kBallastTopM) * (l - kBallastShoulderM) /
                              (kBallastToeM - kBallastShoulderM);
  }
  const double ramp = std::clamp((l - 6.0) / 20.0, 0.0, 1.0);
  const double seed_phase = 0.37 * scenario_.world_seed;
  const double relief = 0.6 * std::sin(s / 97.0 + lateral_m / 23.0 + seed_phase) +
                        0.4 * std::sin(s / 41.0 - lateral_m / 17.0 + 2.0 * seed_phase);
  return kFormationM + scenario_.terrain_relief_m * ramp * relief;
}

void World::BuildTrack(Mesh* mesh) {
  const Alignment& a = alignment_;
  const double length = a.length_m();
  auto main_section = [&](double s) { return SectionAt(a, s, 0.0); };
  const std::vector<Eigen::Vector2d> ballast = {{-kBallastToeM, kFormationM},
                                                {-kBallastShoulderM, kBallastTopM},
                                                {kBallastShoulderM, kBallastTopM},
                                                {kBallastToeM, kFormationM}};
  const double step = options_.rail_step_m;
  Extrude(ballast, false, 0.0, length, step, main_section, Material::kBallast, mesh);
  Extrude(
      RailProfile(kRailHeadCentreM), true, 0.0, length, step, main_section, Material::kRail, mesh);
  Extrude(
      RailProfile(-kRailHeadCentreM), true, 0.0, length, step, main_section, Material::kRail, mesh);
  const Vec3 sleeper_half(0.125, 1.3, 0.11);
  for (double s = 0.3; s < length; s += scenario_.sleeper_spacing_m) {
    const TrackSection section = main_section(s);
    mesh->AddBox(section.At(0.0, -0.172 - 0.11), section.R, sleeper_half, Material::kSleeper);
  }

  // Parallel tracks: a turnout eases the offset from 0 to the spacing and back.
  for (const ParallelTrack& p : scenario_.parallel_tracks) {
    auto offset = [&p](double s) {
      auto smooth = [](double u) {
        u = std::clamp(u, 0.0, 1.0);
        return u * u * (3.0 - 2.0 * u);
      };
      const double in = smooth((s - p.from_m) / p.diverge_m);
      const double out = smooth((p.to_m - s) / p.diverge_m);
      return p.side * p.spacing_m * std::min(in, out);
    };
    auto section = [&](double s) { return SectionAt(a, s, offset(s)); };
    Extrude(
        RailProfile(kRailHeadCentreM), true, p.from_m, p.to_m, 1.0, section, Material::kRail, mesh);
    Extrude(RailProfile(-kRailHeadCentreM),
            true,
            p.from_m,
            p.to_m,
            1.0,
            section,
            Material::kRail,
            mesh);
    const double full_from = p.from_m + p.diverge_m, full_to = p.to_m - p.diverge_m;
    Extrude(ballast, false, full_from, full_to, step, section, Material::kBallast, mesh);
    for (double s = p.from_m + 0.3; s < p.to_m; s += scenario_.sleeper_spacing_m) {
      if (std::fabs(offset(s)) < 2.9) continue;  // the switch panel shares the main sleepers
      const TrackSection sec = section(s);
      mesh->AddBox(sec.At(0.0, -0.172 - 0.11), sec.R, sleeper_half, Material::kSleeper);
    }
  }
}

void World::BuildTerrain(Mesh* mesh) {
  std::vector<double> lateral = {2.4, 3.5, 5.0, 7.0, 10.0, 14.0, 19.0, 25.0, 32.0, 40.0};
  for (double l = 50.0; l < scenario_.terrain_half_width_m; l += 12.0) lateral.push_back(l);
  lateral.push_back(scenario_.terrain_half_width_m);
  const double length = alignment_.length_m();
  const int n = static_cast<int>(std::ceil(length / options_.terrain_step_m));
  for (int side : {1, -1}) {
    std::vector<Vec3> previous;
    for (int i = 0; i <= n; ++i) {
      const double s = length * i / n;
      std::vector<Vec3> row;
      for (double l : lateral) {
        row.push_back(alignment_.Beside(s, side * l, GroundHeight(s, side * l)));
      }
      if (i > 0) {
        for (size_t k = 0; k + 1 < row.size(); ++k) {
          mesh->AddQuad(previous[k], previous[k + 1], row[k + 1], row[k], Material::kGround);
        }
      }
      previous.swap(row);
    }
  }
}

void World::BuildTunnels(Mesh* mesh) {
  const std::vector<Eigen::Vector2d> tube = TunnelProfile();
  auto flat = [&](double s) {
    const TrackPoint p = alignment_.At(s);
    TrackSection section;
    section.origin = p.position;
    section.R = Eigen::AngleAxisd(p.heading_rad, Vec3::UnitZ()).toRotationMatrix();
    return section;
  };
  for (const ChainageRange& t : scenario_.tunnels) {
    Extrude(tube, false, t.from_m, t.to_m, options_.rail_step_m, flat, Material::kTunnel, mesh);
    // Portal headwalls: a 30 m x 13 m face around the opening.
    for (double s : {t.from_m, t.to_m}) {
      const TrackSection sec = flat(s);
      const double top = 12.0, half = 15.0;
      mesh->AddQuad(sec.At(-half, kFormationM),
                    sec.At(-kTunnelHalfWidthM, kFormationM),
                    sec.At(-kTunnelHalfWidthM, top),
                    sec.At(-half, top),
                    Material::kTunnel);
      mesh->AddQuad(sec.At(kTunnelHalfWidthM, kFormationM),
                    sec.At(half, kFormationM),
                    sec.At(half, top),
                    sec.At(kTunnelHalfWidthM, top),
                    Material::kTunnel);
      for (size_t k = 1; k + 2 < tube.size(); ++k) {
        const Eigen::Vector2d& p = tube[k];
        const Eigen::Vector2d& q = tube[k + 1];
        mesh->AddQuad(sec.At(p.x(), p.y()),
                      sec.At(q.x(), q.y()),
                      sec.At(q.x(), top),
                      sec.At(p.x(), top),
                      Material::kTunnel);
      }
    }
    // Lamps every 25 m (alternating walls) and refuge pilasters every 50 m.
    int k = 0;
    for (double s = t.from_m + 12.5; s < t.to_m; s += 25.0, ++k) {
      const TrackSection sec = flat(s);
      const double side = (k % 2) ? 1.0 : -1.0;
      mesh->AddBox(sec.At(side * (kTunnelHalfWidthM - 0.1), 3.5),
                   sec.R,
                   Vec3(0.15, 0.1, 0.1),
                   Material::kSign);
      if (k % 2 == 0) {
        mesh->AddBox(sec.At(side * (kTunnelHalfWidthM - 0.2), 1.0),
                     sec.R,
                     Vec3(0.5, 0.2, 1.9),
                     Material::kTunnel);
      }
    }
  }
}

void World::BuildCatenary(std::mt19937& rng) {
  if (!scenario_.catenary) return;
  std::vector<Vec3> contact_supports, messenger_supports;
  Mesh wires;
  PlaceMasts(rng, &contact_supports, &messenger_supports, &wires);
  // Contact wire: straight between supports. Messenger: parabolic sag, with droppers.
  for (size_t i = 0; i + 1 < contact_supports.size(); ++i) {
    AddSpanWires(contact_supports[i],
                 contact_supports[i + 1],
                 messenger_supports[i],
                 messenger_supports[i + 1],
                 scenario_.system_height_m - 0.5,
                 &wires);
  }
  mesh_.Append(wires);
}

void World::PlaceMasts(std::mt19937& rng,
                       std::vector<Vec3>* contact_supports,
                       std::vector<Vec3>* messenger_supports,
                       Mesh* wires) {
  const double length = alignment_.length_m();
  const double contact = scenario_.contact_wire_height_m;
  const double messenger = contact + scenario_.system_height_m;
  std::vector<Vec3> feeder_supports;
  int index = 0;
  for (double s = Uniform(rng, 5.0, 30.0); s < length;
       s += Uniform(rng, scenario_.mast_spacing_min_m, scenario_.mast_spacing_max_m), ++index) {
    const double stagger = (index % 2 ? 1.0 : -1.0) * scenario_.stagger_m;
    const Vec3 contact_point = alignment_.Beside(s, stagger, contact);
    const Vec3 messenger_point = alignment_.Beside(s, 0.0, messenger);
    contact_supports->push_back(contact_point);
    messenger_supports->push_back(messenger_point);
    if (InTunnel(s, 2.0)) {
      // Drop bracket from the tunnel crown.
      wires->AddCylinder(alignment_.Beside(s, 0.0, kTunnelSpringM + kTunnelHalfWidthM - 0.05),
                         contact_point,
                         0.04,
                         4,
                         Material::kMast);
      feeder_supports.clear();
      continue;
    }
    const double offset = scenario_.mast_side *
                          Uniform(rng, scenario_.mast_offset_min_m, scenario_.mast_offset_max_m);
    objects_.push_back(Mast(s, offset, stagger, contact_point, messenger_point));
    const Vec3 feeder = alignment_.Beside(s, offset, scenario_.mast_height_m - 0.3);
    if (!feeder_supports.empty()) {
      wires->AddCylinder(feeder_supports.back(), feeder, 0.01, 4, Material::kWire);
    }
    feeder_supports.push_back(feeder);
  }
}

WorldObject World::Mast(double s,
                        double offset,
                        double stagger,
                        const Vec3& contact_point,
                        const Vec3& messenger_point) const {
  const double contact = scenario_.contact_wire_height_m;
  const double messenger = contact + scenario_.system_height_m;
  WorldObject mast = Object("mast", s, offset);
  const Vec3 base = alignment_.Beside(s, offset, GroundHeight(s, offset));
  const Vec3 top = alignment_.Beside(s, offset, scenario_.mast_height_m);
  mast.mesh.AddCylinder(base, top, 0.17, 8, Material::kMast);
  const double inner = offset - scenario_.mast_side * 0.2;
  mast.mesh.AddCylinder(
      alignment_.Beside(s, inner, messenger + 0.3), messenger_point, 0.03, 4, Material::kMast);
  mast.mesh.AddCylinder(alignment_.Beside(s, inner, contact + 0.2),
                        alignment_.Beside(s, stagger, contact + 0.15),
                        0.03,
                        4,
                        Material::kMast);
  mast.mesh.AddCylinder(
      contact_point + Vec3(0, 0, 0.15), messenger_point, 0.02, 4, Material::kMast);
  return mast;
}

void World::BuildStations() {
  for (const Station& st : scenario_.stations) {
    objects_.push_back(Platform(alignment_, st));
    objects_.push_back(StationBuilding(st));
  }
  // Level crossings: road panel, barrier posts and booms, cross-buck signs.
  for (double at : scenario_.level_crossings_m) objects_.push_back(LevelCrossing(alignment_, at));
}

WorldObject World::StationBuilding(const Station& st) const {
  const double side = st.side;
  WorldObject building;
  building.kind = "station_building";
  const double mid = st.at_m + 0.5 * st.length_m;
  building.chainage_m = mid;
  building.lateral_m = side * 16.0;
  const TrackPoint p = alignment_.At(mid);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(p.heading_rad, Vec3::UnitZ()).toRotationMatrix();
  const double ground = GroundHeight(mid, side * 16.0);
  building.mesh.AddBox(alignment_.Beside(mid, side * 16.0, ground + 4.0),
                       R,
                       Vec3(std::min(30.0, 0.2 * st.length_m), 5.0, 4.0),
                       Material::kBuilding);
  return building;
}

void World::BuildCorridor(std::mt19937& rng) {
  // Signals and kilometre posts first: their layout does not depend on densities.
  if (scenario_.signal_spacing_m > 0.0) PlaceSignals();
  if (scenario_.km_posts) PlaceKmPosts();
  PlaceRandomly(
      scenario_.trees, rng, [&](double s, double lateral) { return Tree(s, lateral, rng); });
  PlaceRandomly(
      scenario_.bushes, rng, [&](double s, double lateral) { return Bush(s, lateral, rng); });
  PlaceRandomly(scenario_.buildings, rng, [&](double s, double lateral) {
    return Building(s, lateral, rng);
  });
}

void World::PlaceSignals() {
  const double length = alignment_.length_m();
  for (double s = 300.0; s < length - 50.0; s += scenario_.signal_spacing_m) {
    if (InTunnel(s, 5.0)) continue;
    const double lateral = -scenario_.mast_side * 3.2;
    WorldObject signal = Object("signal", s, lateral);
    const TrackPoint p = alignment_.At(s);
    const Eigen::Matrix3d R = Eigen::AngleAxisd(p.heading_rad, Vec3::UnitZ()).toRotationMatrix();
    const Vec3 base = alignment_.Beside(s, lateral, GroundHeight(s, lateral));
    signal.mesh.AddCylinder(base, base + Vec3(0, 0, 4.6), 0.08, 6, Material::kMast);
    signal.mesh.AddBox(base + Vec3(0, 0, 4.5), R, Vec3(0.12, 0.18, 0.5), Material::kSignal);
    signal.mesh.AddBox(base + Vec3(0, 0, 0.3), R, Vec3(0.3, 0.3, 0.3), Material::kMast);
    objects_.push_back(std::move(signal));
  }
}

void World::PlaceKmPosts() {
  for (double s = 1000.0; s < alignment_.length_m(); s += 1000.0) {
    if (InTunnel(s, 5.0)) continue;
    WorldObject post = Object("km_post", s, 3.6);
    const Vec3 base = alignment_.Beside(s, 3.6, GroundHeight(s, 3.6));
    post.mesh.AddBox(base + Vec3(0, 0, 0.65),
                     Eigen::Matrix3d::Identity(),
                     Vec3(0.08, 0.08, 0.65),
                     Material::kSign);
    objects_.push_back(std::move(post));
  }
}

void World::PlaceRandomly(const Density& density,
                          std::mt19937& rng,
                          const std::function<WorldObject(double, double)>& build) {
  const double length = alignment_.length_m();
  std::poisson_distribution<int> count(std::max(1e-9, density.per_km));
  for (double km = 0.0; km < length; km += 1000.0) {
    const double span = std::min(1000.0, length - km);
    for (int side : {1, -1}) {
      const int n = density.per_km > 0.0 ? count(rng) : 0;
      for (int i = 0; i < n; ++i) {
        const double s = km + Uniform(rng, 0.0, span);
        const double lateral = side * Uniform(rng, density.min_offset_m, density.max_offset_m);
        if (FeaturePoor(s) || NearStructure(s, lateral)) continue;
        objects_.push_back(build(s, lateral));
      }
    }
  }
}

WorldObject World::Tree(double s, double lateral, std::mt19937& rng) const {
  WorldObject tree = Object("tree", s, lateral);
  const double trunk = Uniform(rng, 1.5, 4.0);
  const double crown = std::min(Uniform(rng, 1.5, 4.0), std::fabs(lateral) - 3.0);
  const Vec3 base = alignment_.Beside(s, lateral, GroundHeight(s, lateral));
  tree.mesh.AddCylinder(
      base, base + Vec3(0, 0, trunk + crown), 0.15 + 0.03 * crown, 6, Material::kVegetation);
  const int blobs = 3 + static_cast<int>(rng() % 3);
  for (int b = 0; b < blobs; ++b) {
    const Vec3 c = base + Vec3(Uniform(rng, -0.4, 0.4) * crown,
                               Uniform(rng, -0.4, 0.4) * crown,
                               trunk + crown * Uniform(rng, 0.6, 1.4));
    const double r = crown * Uniform(rng, 0.5, 0.8);
    tree.mesh.AddBlob(c, Vec3(r, r, r * 0.9), 0.25, rng, Material::kVegetation);
  }
  return tree;
}

WorldObject World::Bush(double s, double lateral, std::mt19937& rng) const {
  WorldObject bush = Object("bush", s, lateral);
  const int blobs = 1 + static_cast<int>(rng() % 3);
  const double side = lateral > 0.0 ? 1.0 : -1.0;
  for (int b = 0; b < blobs; ++b) {
    // Blobs spread along the line and away from it; with their jitter (x1.3) they stay out of
    // the structure gauge (2.44 m) with 0.15 m to spare.
    const double away = Uniform(rng, 0.0, 1.0);
    const double r_max = (std::fabs(lateral) + away - kClearanceHalfWidthM - 0.15) / 1.3;
    const double r = std::min(Uniform(rng, 0.5, 1.4), std::max(0.2, r_max));
    const double s_blob = s + Uniform(rng, -1.0, 1.0);
    const Vec3 centre =
        alignment_.Beside(s_blob, lateral + side * away, GroundHeight(s_blob, lateral) + 0.6 * r);
    bush.mesh.AddBlob(centre, Vec3(r, r, 0.8 * r), 0.3, rng, Material::kVegetation);
  }
  return bush;
}

WorldObject World::Building(double s, double lateral, std::mt19937& rng) const {
  WorldObject building = Object("building", s, lateral);
  const TrackPoint p = alignment_.At(s);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(p.heading_rad + Uniform(rng, -0.3, 0.3), Vec3::UnitZ()).toRotationMatrix();
  const Vec3 half(Uniform(rng, 3.0, 12.0), Uniform(rng, 3.0, 7.0), Uniform(rng, 1.5, 6.0));
  const Vec3 base = alignment_.Beside(s, lateral, GroundHeight(s, lateral) - 0.3);
  const Vec3 centre = base + Vec3(0, 0, half.z());
  building.mesh.AddBox(centre, R, half, Material::kBuilding);
  // Gable roof along the long axis.
  const double ridge = 0.6 * half.y();
  const Vec3 e0 = centre + R * Vec3(-half.x(), -half.y(), half.z());
  const Vec3 e1 = centre + R * Vec3(half.x(), -half.y(), half.z());
  const Vec3 e2 = centre + R * Vec3(half.x(), half.y(), half.z());
  const Vec3 e3 = centre + R * Vec3(-half.x(), half.y(), half.z());
  const Vec3 r0 = centre + R * Vec3(-half.x(), 0.0, half.z() + ridge);
  const Vec3 r1 = centre + R * Vec3(half.x(), 0.0, half.z() + ridge);
  building.mesh.AddQuad(e0, e1, r1, r0, Material::kRoof);
  building.mesh.AddQuad(e2, e3, r0, r1, Material::kRoof);
  building.mesh.AddTriangle(e0, r0, e3, Material::kBuilding);
  building.mesh.AddTriangle(e1, e2, r1, Material::kBuilding);
  return building;
}

void World::ApplyChanges(std::mt19937& rng) {
  for (const Change& c : scenario_.changes) {
    switch (c.kind) {
      case Change::Kind::kObjectAdded:
        AddObject(c);
        break;
      case Change::Kind::kObjectRemoved:
      case Change::Kind::kObjectMoved:
        RemoveOrMoveObject(c);
        break;
      case Change::Kind::kVegetationGrowth:
        GrowTree(c, rng);
        break;
      case Change::Kind::kFallenTree:
        FellTree(c, rng);
        break;
    }
  }
}

bool World::IntrudesClearance(const WorldObject& object) const {
  // Sample the triangle edges every 0.25 m: long members (a trunk) cross the envelope between
  // their vertices.
  const TrackPoint p = alignment_.At(object.chainage_m);
  const Vec3 t(std::cos(p.heading_rad), std::sin(p.heading_rad), 0.0);
  const Mesh& mesh = object.mesh;
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    for (int e = 0; e < 3; ++e) {
      const Vec3 a = mesh.vertices[mesh.triangles[i][e]].cast<double>();
      const Vec3 b = mesh.vertices[mesh.triangles[i][(e + 1) % 3]].cast<double>();
      const int steps = 1 + static_cast<int>((b - a).norm() / 0.25);
      for (int k = 0; k <= steps; ++k) {
        const Vec3 d = a + (b - a) * (double(k) / steps) - p.position;
        const double along = d.dot(t);
        const double lateral = d.dot(p.Left());
        const double height = d.z() - p.grade * along;
        if (std::fabs(along) < 50.0 && std::fabs(lateral) < kClearanceHalfWidthM && height > 0.0 &&
            height < kClearanceHeightM) {
          return true;
        }
      }
    }
  }
  return false;
}

ChangeRecord World::Record(const std::string& kind, const WorldObject& object) const {
  ChangeRecord r;
  r.id = static_cast<int>(changes_.size()) + 1;
  r.kind = kind;
  r.object = object.kind;
  r.chainage_m = object.chainage_m;
  r.lateral_m = object.lateral_m;
  const Eigen::AlignedBox3d box = object.mesh.Bounds();
  r.centre_world = box.center();
  r.extent_m = box.sizes();
  // What is gone cannot be in the way.
  r.intrudes_clearance = kind != "object_removed" && IntrudesClearance(object);
  return r;
}

void World::AddObject(const Change& c) {
  WorldObject box = Object("box", c.at_m, c.offset_m);
  const TrackPoint p = alignment_.At(c.at_m);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(p.heading_rad, Vec3::UnitZ()).toRotationMatrix();
  const double ground =
      std::fabs(c.offset_m) < kBallastShoulderM ? 0.0 : GroundHeight(c.at_m, c.offset_m);
  box.mesh.AddBox(alignment_.Beside(c.at_m, c.offset_m, ground + 0.5 * c.size_m[2]),
                  R,
                  0.5 * Vec3(c.size_m[0], c.size_m[1], c.size_m[2]),
                  Material::kBuilding);
  changes_.push_back(Record("object_added", box));
  objects_.push_back(std::move(box));
}

void World::RemoveOrMoveObject(const Change& c) {
  auto best = objects_.end();
  for (auto it = objects_.begin(); it != objects_.end(); ++it) {
    if (it->kind != c.target) continue;
    if (best == objects_.end() ||
        std::fabs(it->chainage_m - c.at_m) < std::fabs(best->chainage_m - c.at_m)) {
      best = it;
    }
  }
  if (best == objects_.end()) return;  // nothing of that kind: recorded as no change
  if (c.kind == Change::Kind::kObjectRemoved) {
    changes_.push_back(Record("object_removed", *best));
    objects_.erase(best);
    return;
  }
  const Vec3 from = best->mesh.Bounds().center();
  const TrackPoint p = alignment_.At(best->chainage_m);
  const Vec3 t(std::cos(p.heading_rad), std::sin(p.heading_rad), 0.0);
  best->mesh.Translate(c.move_m[0] * t + c.move_m[1] * p.Left());
  best->chainage_m += c.move_m[0];
  best->lateral_m += c.move_m[1];
  ChangeRecord r = Record("object_moved", *best);
  r.from_world = from;
  changes_.push_back(r);
}

void World::GrowTree(const Change& c, std::mt19937& rng) {
  WorldObject tree;
  tree.kind = "tree";
  const double crown = 2.0;
  const double lateral = c.side * (kClearanceHalfWidthM - c.intrusion_m + crown);
  tree.chainage_m = c.at_m;
  tree.lateral_m = lateral;
  const Vec3 base = alignment_.Beside(c.at_m, lateral, GroundHeight(c.at_m, lateral));
  tree.mesh.AddCylinder(
      base, alignment_.Beside(c.at_m, lateral, 4.0), 0.2, 6, Material::kVegetation);
  tree.mesh.AddBlob(alignment_.Beside(c.at_m, lateral, 4.0),
                    Vec3(crown, crown, 1.8),
                    0.0,
                    rng,
                    Material::kVegetation);
  changes_.push_back(Record("vegetation_growth", tree));
  objects_.push_back(std::move(tree));
}

void World::FellTree(const Change& c, std::mt19937& rng) {
  WorldObject tree;
  tree.kind = "fallen_tree";
  tree.chainage_m = c.at_m;
  const TrackPoint p = alignment_.At(c.at_m);
  const double angle = p.heading_rad + 70.0 * M_PI / 180.0;
  const Vec3 dir(std::cos(angle), std::sin(angle), 0.0);
  const Vec3 centre = alignment_.Beside(c.at_m, 0.0, 0.25);
  tree.mesh.AddCylinder(centre - 6.0 * dir, centre + 6.0 * dir, 0.22, 8, Material::kVegetation);
  for (int b = 0; b < 3; ++b) {
    tree.mesh.AddBlob(centre + (7.0 + 1.2 * b) * dir + Vec3(0, 0, 0.8),
                      Vec3(1.4, 1.4, 1.0),
                      0.25,
                      rng,
                      Material::kVegetation);
  }
  changes_.push_back(Record("fallen_tree", tree));
  objects_.push_back(std::move(tree));
}

}  // namespace raillomer::sim
