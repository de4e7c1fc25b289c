#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <nlohmann/json.hpp>

#include "api/stream.h"
#include "api/trajectory.h"

namespace raillomer::sim {
struct Mesh;
}

namespace raillomer::eval {

/// A surface of the simulated corridor whose map points the sharpness check scores (UTM).
struct ReferenceTriangle {
  enum class Kind { kPlane, kRailHead };
  Kind kind = Kind::kPlane;
  Eigen::Vector3d a = Eigen::Vector3d::Zero(), b = Eigen::Vector3d::Zero(),
                  c = Eigen::Vector3d::Zero();
};

/// The planar surfaces (platform tops, building walls) and rail-head tops of a simulated
/// corridor, moved into UTM by `origin_utm` (the world frame's origin).
std::vector<ReferenceTriangle> SelectReferenceTriangles(const sim::Mesh& mesh,
                                                        const Eigen::Vector3d& origin_utm);

struct SharpnessOptions {
  /// A point belongs to a plane when, after its submap's truth alignment, it lies within this
  /// distance of the plane...
  double plane_tolerance_m = 0.15;
  /// ...and at least this far inside the plane's outer edges, where voxels mix two surfaces.
  double plane_margin_m = 0.2;
  /// A point belongs to a rail head within this distance of its top and at least this far inside
  /// its edges. The head's sides drop 5 cm from its edges, so a point near an edge may be on a
  /// side: in long_20km's map, 38 % of the points up to 2 cm beyond an edge, 25 % of those within
  /// 5 mm inside one and 5.5 % of those 5-10 mm inside lie more than 2 cm from the top, against
  /// 1.7 % of those 1-3 cm inside.
  double rail_tolerance_m = 0.05;
  double rail_margin_m = 0.01;
  /// Planes are scored in patches of at most this size, so a map bent gently by GNSS
  /// corrections over a 100 m platform is not mistaken for blur.
  double patch_m = 10.0;
  /// Rail heads are compared in segments of this length.
  double rail_segment_m = 2.0;
  int min_plane_points = 20;
  int min_rail_points = 3;
};

/// How sharp a map is: the point spread normal to known planes, and how well rail-head heights
/// from different submaps agree.
struct SharpnessResult {
  size_t submaps = 0;
  size_t points = 0;
  size_t plane_points = 0;   ///< points in scored plane patches
  size_t plane_patches = 0;  ///< patches with at least min_plane_points
  double plane_rms_m = 0.0;  ///< RMS distance to each patch's fitted plane, pooled over patches
  double plane_patch_p95_m = 0.0;
  double plane_patch_max_m = 0.0;
  Eigen::Vector3d worst_patch_utm = Eigen::Vector3d::Zero();
  size_t rail_points = 0;
  size_t rail_segments = 0;  ///< rail-head segments seen by at least two submaps
  /// Per segment: the largest difference between two submaps' mean rail-head heights.
  double rail_spread_median_m = 0.0;
  double rail_spread_p95_m = 0.0;
  double rail_spread_max_m = 0.0;
  Eigen::Vector3d worst_rail_utm = Eigen::Vector3d::Zero();
};

/// One scored plane patch, for finding where a map is blurred and whether by submaps that
/// disagree or within one.
struct PlanePatchReport {
  Eigen::Vector3d utm = Eigen::Vector3d::Zero();  ///< the centroid of the patch's points
  size_t points = 0;
  double rms_m = 0.0;  ///< spread normal to the patch's fitted plane
  struct Sample {
    uint32_t submap = 0;  ///< api::Submap::index
    size_t points = 0;
    double offset_m = 0.0;  ///< the submap's mean distance from the fitted plane
    double rms_m = 0.0;     ///< its points' spread about that mean, normal to the plane
  };
  std::vector<Sample> samples;  ///< every submap with points on the patch
};

/// One rail-head segment seen by at least two submaps, for finding where a map disagrees.
struct RailSegmentReport {
  Eigen::Vector3d utm = Eigen::Vector3d::Zero();  ///< the segment's first mapped point
  double spread_m = 0.0;  ///< largest difference between two submaps' mean heights
  struct Sample {
    uint32_t submap = 0;  ///< api::Submap::index
    size_t points = 0;
    double height_m = 0.0;  ///< mean height along the head's normal, relative to `utm`
    double rms_m = 0.0;     ///< the points' spread about that mean
    /// Mean distance from the true head top once the submap is aligned to the truth at its
    /// middle keyframe: the submap's own error there, its placement taken out.
    double truth_offset_m = 0.0;
  };
  std::vector<Sample> samples;  ///< submaps with at least min_rail_points points on it
};

/// Scores a map submap by submap; memory grows with the number of surface patches, not points.
class MapSharpness {
 public:
  explicit MapSharpness(std::vector<ReferenceTriangle> triangles,
                        const SharpnessOptions& options = {});
  ~MapSharpness();
  MapSharpness(const MapSharpness&) = delete;
  MapSharpness& operator=(const MapSharpness&) = delete;

  /// Scores one submap. `T_truth_est` moves the estimate onto the truth near the submap; it only
  /// decides which surface a point belongs to. The spread is measured on the points as mapped.
  void AddSubmap(const api::Submap& submap, const Eigen::Isometry3d& T_truth_est);

  SharpnessResult Result() const;
  /// Every plane patch that Result() scores, in no particular order.
  std::vector<PlanePatchReport> PlanePatches() const;
  /// Every rail-head segment that Result() scores, in no particular order.
  std::vector<RailSegmentReport> RailSegments() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Scores every submap file (`*.pcd`) of a run's submap folder in index order, each aligned by
/// the truth at its middle keyframe. False with a message if the folder or a file is unusable;
/// `skipped` counts submaps outside the truth's span.
bool ScoreSubmapFolder(const std::string& folder,
                       const api::Trajectory& truth,
                       MapSharpness* sharpness,
                       size_t* skipped,
                       std::string* error);

/// The segments as CSV, one row per submap's sample:
/// x,y,z,spread_m,submap,points,height_m,rms_m,truth_offset_m.
std::string RailSegmentsCsv(const std::vector<RailSegmentReport>& segments);

/// The patches as CSV, one row per submap's sample:
/// x,y,z,patch_rms_m,patch_points,submap,points,offset_m,rms_m.
std::string PlanePatchesCsv(const std::vector<PlanePatchReport>& patches);

/// The figures as text lines for a terminal, and as JSON (units in the keys).
std::string FormatSharpness(const SharpnessResult& result);
nlohmann::json ToJson(const SharpnessResult& result);

}  // namespace raillomer::eval
