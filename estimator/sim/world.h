#pragma once

#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/sim/alignment.h"
#include "estimator/sim/scenario.h"

namespace raillomer::sim {

/// Surface materials; each has a reflectivity for the LiDAR model.
enum class Material : uint8_t {
  kGround,
  kBallast,
  kSleeper,
  kRail,
  kMast,
  kWire,
  kVegetation,
  kBuilding,
  kRoof,
  kPlatform,
  kSignal,
  kRoad,
  kTunnel,
  kSign,
  kVehicle,
  kCount
};

/// Diffuse reflectivity in percent (>100 marks retro-reflectors).
double MaterialReflectivity(Material material);

/// A triangle soup with one material per triangle (world frame, metres).
struct Mesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3i> triangles;
  std::vector<Material> materials;

  void Append(const Mesh& other);
  void AddTriangle(const Eigen::Vector3d& a,
                   const Eigen::Vector3d& b,
                   const Eigen::Vector3d& c,
                   Material m);
  void AddQuad(const Eigen::Vector3d& a,
               const Eigen::Vector3d& b,
               const Eigen::Vector3d& c,
               const Eigen::Vector3d& d,
               Material m);
  /// A box with the given centre, orientation and half extents.
  void AddBox(const Eigen::Vector3d& centre,
              const Eigen::Matrix3d& R,
              const Eigen::Vector3d& half,
              Material m);
  /// A capped prism of `sides` faces around the segment a-b.
  void AddCylinder(
      const Eigen::Vector3d& a, const Eigen::Vector3d& b, double radius, int sides, Material m);
  /// An irregular ellipsoid (subdivided icosahedron with jittered radii).
  void AddBlob(const Eigen::Vector3d& centre,
               const Eigen::Vector3d& radii,
               double jitter,
               std::mt19937& rng,
               Material m);
  void Translate(const Eigen::Vector3d& delta);
  Eigen::AlignedBox3d Bounds() const;
};

/// A discrete trackside object that change scenarios can add, remove or move.
struct WorldObject {
  std::string kind;  ///< mast, signal, building, tree, bush, km_post, added, ...
  double chainage_m = 0.0;
  double lateral_m = 0.0;
  Mesh mesh;
};

/// The ground truth of one corridor edit, in the world frame (UTM offsets from the origin).
struct ChangeRecord {
  int id = 0;
  std::string kind;    ///< object_added, object_removed, object_moved, vegetation_growth, ...
  std::string object;  ///< what was edited: mast, signal, building, tree, box, fallen_tree
  double chainage_m = 0.0;
  double lateral_m = 0.0;
  Eigen::Vector3d centre_world = Eigen::Vector3d::Zero();  ///< after the change (before if removed)
  Eigen::Vector3d extent_m = Eigen::Vector3d::Zero();      ///< box size, world axes
  Eigen::Vector3d from_world = Eigen::Vector3d::Zero();    ///< object_moved: where it was
  bool intrudes_clearance = false;  ///< inside the structure gauge (|y| < 2.44 m, 0-6.55 m)
};

/// Options of the corridor geometry that are not scenario keys.
struct WorldOptions {
  double rail_step_m = 2.0;     ///< extrusion step of rails and ballast
  double terrain_step_m = 4.0;  ///< terrain grid spacing along the line
};

/// The whole corridor: track, catenary, trackside objects and terrain, as one triangle mesh.
class World {
 public:
  World(const Scenario& scenario, const Alignment& alignment, const WorldOptions& options = {});

  const Mesh& mesh() const { return mesh_; }
  const std::vector<WorldObject>& objects() const { return objects_; }
  const std::vector<ChangeRecord>& changes() const { return changes_; }
  /// Height of the ground surface above the rail-top plane at (chainage, lateral).
  double GroundHeight(double s, double lateral_m) const;
  /// Whether a chainage lies inside a tunnel (with `margin_m` either side).
  bool InTunnel(double s, double margin_m = 0.0) const;

 private:
  void BuildTrack(Mesh* mesh);
  void BuildTerrain(Mesh* mesh);
  void BuildCatenary(std::mt19937& rng);
  /// Places masts (drop brackets in tunnels) and the feeder wire; collects the wire supports.
  void PlaceMasts(std::mt19937& rng,
                  std::vector<Eigen::Vector3d>* contact_supports,
                  std::vector<Eigen::Vector3d>* messenger_supports,
                  Mesh* wires);
  /// A mast at (s, offset): its pole and the arms that hold the wires at their supports.
  WorldObject Mast(double s,
                   double offset,
                   double stagger,
                   const Eigen::Vector3d& contact_point,
                   const Eigen::Vector3d& messenger_point) const;
  void BuildCorridor(std::mt19937& rng);
  void BuildStations();
  /// The station building behind a station's platform.
  WorldObject StationBuilding(const Station& st) const;
  void BuildTunnels(Mesh* mesh);
  void PlaceSignals();
  void PlaceKmPosts();
  /// Places objects at random by a density (Poisson per km and side, uniform offsets), skipping
  /// feature-poor stretches and places near structures; `build` makes each.
  void PlaceRandomly(const Density& density,
                     std::mt19937& rng,
                     const std::function<WorldObject(double, double)>& build);
  WorldObject Tree(double s, double lateral, std::mt19937& rng) const;
  WorldObject Bush(double s, double lateral, std::mt19937& rng) const;
  WorldObject Building(double s, double lateral, std::mt19937& rng) const;
  /// Edits the corridor by the scenario's changes and records each (changes_).
  void ApplyChanges(std::mt19937& rng);
  void AddObject(const Change& c);
  void RemoveOrMoveObject(const Change& c);
  void GrowTree(const Change& c, std::mt19937& rng);
  void FellTree(const Change& c, std::mt19937& rng);
  /// The ground truth of an edit to `object`.
  ChangeRecord Record(const std::string& kind, const WorldObject& object) const;
  /// Whether any part of the object lies inside the structure gauge near its chainage.
  bool IntrudesClearance(const WorldObject& object) const;
  bool FeaturePoor(double s) const;
  bool NearStructure(double s, double lateral_m) const;

  const Scenario& scenario_;
  const Alignment& alignment_;
  WorldOptions options_;
  Mesh mesh_;
  std::vector<WorldObject> objects_;
  std::vector<ChangeRecord> changes_;
};

}  // namespace raillomer::sim
