// LOAM edge and planar features (paper IV.C, after Zhang and Singh) on a constructed scan of
// known geometry: edges along the corner lines and silhouettes, planes on the faces, nothing on a
// surface seen at grazing incidence, and at most the configured number per sector.

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/features/loam_features.h"

namespace raillomer {
namespace {

constexpr double kDeg = M_PI / 180.0;

/// A vertical face between two points of the ground plan (x, y), from z = -20 to 20 m.
struct Face {
  Eigen::Vector2d a, b;
};

/// The scene, seen from the origin (x forward, y left):
///  - a back wall at x = 30;
///  - a wedge with its apex (a convex corner, 103 deg) at (17, 4) and its ends at (21, -1) and
///    (21, 9), standing out before the wall;
///  - a box front at x = 14 from y = 10 on (a step of 16 m);
///  - a side wall at y = -3 from x = 6 to 25, seen at grazing incidence beyond x = 11.2 m.
std::vector<Face> Scene() {
  return {{{30, -40}, {30, 40}},
          {{21, -1}, {17, 4}},
          {{17, 4}, {21, 9}},
          {{14, 10}, {14, 14}},
          {{6, -3}, {25, -3}}};
}

/// Vertical edges where an edge feature belongs: the apex, the outlines of the wedge, the box
/// and the near end of the side wall.
const std::vector<Eigen::Vector2d> kCorners = {{17, 4}, {21, -1}, {21, 9}, {14, 10}, {6, -3}};

double Cast(const std::vector<Face>& faces, const Eigen::Vector3d& dir) {
  double best = -1.0;
  const Eigen::Vector2d d = dir.head<2>();
  for (const Face& face : faces) {
    const Eigen::Vector2d e = face.b - face.a;
    const double det = d.x() * -e.y() - d.y() * -e.x();
    if (std::fabs(det) < 1e-12) continue;
    // origin + t d = a + u e
    const double t = (face.a.x() * -e.y() - face.a.y() * -e.x()) / det;
    const double u = (d.x() * face.a.y() - d.y() * face.a.x()) / det;
    if (t <= 0.0 || u < 0.0 || u > 1.0) continue;
    const double range = t * dir.norm();
    if (best < 0.0 || range < best) best = range;
  }
  return best;
}

double DistanceToFaces(const std::vector<Face>& faces, const Eigen::Vector3f& p) {
  double best = 1e9;
  const Eigen::Vector2d q = p.head<2>().cast<double>();
  for (const Face& face : faces) {
    const Eigen::Vector2d e = face.b - face.a;
    const double u = std::clamp((q - face.a).dot(e) / e.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (face.a + u * e - q).norm());
  }
  return best;
}

double DistanceToCorners(const Eigen::Vector3f& p) {
  double best = 1e9;
  for (const Eigen::Vector2d& c : kCorners)
    best = std::min(best, (p.head<2>().cast<double>() - c).norm());
  return best;
}

/// A Horizon-like deskewed scan of the scene: 6 lines, each sweeping +-40 deg in 0.2 deg steps
/// and back again one band step higher (the turn of the pattern must not make edges).
Scan SceneScan(const std::vector<Face>& faces) {
  Scan scan;
  const int per_sweep = 400;
  for (int sweep = 0; sweep < 2; ++sweep) {
    for (int i = 0; i < per_sweep; ++i) {
      const double u = (i + 0.5) / per_sweep;
      const double azimuth = ((sweep == 0 ? u : 1.0 - u) - 0.5) * 80.0 * kDeg;
      for (int line = 0; line < 6; ++line) {
        const double elevation = (-6.0 + 2.0 * line + 0.4 * sweep) * kDeg;
        const Eigen::Vector3d dir(std::cos(elevation) * std::cos(azimuth),
                                  std::cos(elevation) * std::sin(azimuth),
                                  std::sin(elevation));
        const double range = Cast(faces, dir);
        if (range <= 0.0) continue;
        ScanPoint point;
        point.p = (range * dir).cast<float>();
        point.range_m = static_cast<float>(range);
        point.line = static_cast<uint8_t>(line);
        point.time_s = static_cast<float>(0.1 * (sweep * per_sweep + i) / (2 * per_sweep));
        scan.points.push_back(point);
      }
    }
  }
  return scan;
}

TEST(LoamFeatureOptions, DefaultsAreValidAndBadFieldsAreNamed) {
  std::string error;
  EXPECT_TRUE(LoamFeatureOptions().IsValid(&error)) << error;
  LoamFeatureOptions options;
  options.plane_curvature_max = options.edge_curvature_min;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("plane_curvature_max"), std::string::npos) << error;
  options = LoamFeatureOptions();
  options.curvature_half_window = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("curvature_half_window"), std::string::npos) << error;
}

TEST(ExtractLoamFeatures, EdgesOnCornersAndPlanesOnFaces) {
  const std::vector<Face> faces = Scene();
  const Scan scan = SceneScan(faces);
  ASSERT_GT(scan.points.size(), 4000u);
  LoamFeatureOptions options;
  options.edge_voxel_m = 0.0;  // every selected point, to check the selection itself
  options.plane_voxel_m = 0.0;
  const FeatureSet features = ExtractLoamFeatures(options, scan);

  // Edges: only on the corner lines (within the half window, 5 steps of ~6 cm), and each
  // corner line found on most of the 12 line passes.
  ASSERT_FALSE(features.edges.empty());
  std::map<size_t, int> per_corner;
  for (const Eigen::Vector3f& e : features.edges) {
    EXPECT_LT(DistanceToCorners(e), 0.4) << e.transpose();
    for (size_t c = 0; c < kCorners.size(); ++c) {
      per_corner[c] += (e.head<2>().cast<double>() - kCorners[c]).norm() < 0.4;
    }
  }
  for (size_t c = 0; c < kCorners.size(); ++c) {
    EXPECT_GE(per_corner[c], 9) << "corner " << kCorners[c].transpose();
  }

  // Planes: on the faces, off the corners, none where the side wall is seen at more than 75 deg
  // incidence (beyond x = 3 / tan 15 deg = 11.2 m).
  ASSERT_GT(features.planes.size(), 300u);
  for (const Eigen::Vector3f& p : features.planes) {
    EXPECT_LT(DistanceToFaces(faces, p), 1e-3) << p.transpose();
    EXPECT_GT(DistanceToCorners(p), 0.05) << p.transpose();
    const bool grazing = std::fabs(p.y() + 3.0) < 1e-3 && p.x() > 11.5;
    EXPECT_FALSE(grazing) << p.transpose();
  }
  // Every face seen at a fair angle contributes planes.
  auto planes_near = [&features](double x, double y) {
    return std::count_if(features.planes.begin(), features.planes.end(), [&](const auto& p) {
      return std::hypot(p.x() - x, p.y() - y) < 3.0;
    });
  };
  EXPECT_GT(planes_near(30, -15), 20);  // back wall
  EXPECT_GT(planes_near(19, 1.5), 10);  // wedge faces
  EXPECT_GT(planes_near(19, 6.5), 10);
  EXPECT_GT(planes_near(14, 11), 10);  // box front

  // No edge at the turns of the pattern (|azimuth| near 40 deg) nor on the side wall.
  for (const Eigen::Vector3f& e : features.edges) {
    EXPECT_LT(std::fabs(std::atan2(e.y(), e.x())), 38.0 * kDeg);
  }
}

TEST(ExtractLoamFeatures, CountsPerSectorAreBounded) {
  const Scan scan = SceneScan(Scene());
  LoamFeatureOptions options;
  options.edge_voxel_m = 0.0;
  options.plane_voxel_m = 0.0;
  options.sectors_per_line = 4;
  options.max_edges_per_sector = 2;
  options.max_planes_per_sector = 7;
  const FeatureSet features = ExtractLoamFeatures(options, scan);
  // Sector of each point: its position among its line's points.
  std::map<std::tuple<float, float, float>, std::pair<int, int>> where;  // p -> (line, sector)
  std::vector<std::vector<size_t>> lines(6);
  for (size_t i = 0; i < scan.points.size(); ++i) lines[scan.points[i].line].push_back(i);
  const int k = options.curvature_half_window;
  for (int l = 0; l < 6; ++l) {
    const int m = static_cast<int>(lines[l].size());
    for (int j = k; j < m - k; ++j) {
      const int sector = (j - k) * options.sectors_per_line / (m - 2 * k);
      const Eigen::Vector3f& p = scan.points[lines[l][j]].p;
      where[{p.x(), p.y(), p.z()}] = {l, sector};
    }
  }
  std::map<std::pair<int, int>, int> edges, planes;
  for (const Eigen::Vector3f& e : features.edges) ++edges[where.at({e.x(), e.y(), e.z()})];
  for (const Eigen::Vector3f& p : features.planes) ++planes[where.at({p.x(), p.y(), p.z()})];
  for (const auto& [sector, n] : edges) EXPECT_LE(n, options.max_edges_per_sector);
  for (const auto& [sector, n] : planes) EXPECT_LE(n, options.max_planes_per_sector);
  EXPECT_LE(features.edges.size(), 6u * 4u * 2u);
  EXPECT_LE(features.planes.size(), 6u * 4u * 7u);
  // The plane-rich sectors fill up.
  EXPECT_GE(features.planes.size(), 6u * 4u * 7u / 2);
}

TEST(ExtractLoamFeatures, VoxelThinningAndEmptyInput) {
  const Scan scan = SceneScan(Scene());
  LoamFeatureOptions raw;
  raw.plane_voxel_m = 0.0;
  raw.edge_voxel_m = 0.0;
  const FeatureSet all = ExtractLoamFeatures(raw, scan);
  const FeatureSet thinned = ExtractLoamFeatures(LoamFeatureOptions(), scan);
  EXPECT_LT(thinned.planes.size(), all.planes.size());
  EXPECT_LE(thinned.edges.size(), all.edges.size());
  // At most one planar point per 0.6 m voxel.
  std::map<std::tuple<int, int, int>, int> voxels;
  for (const Eigen::Vector3f& p : thinned.planes) {
    const Eigen::Vector3i v = (p / 0.6f).array().floor().cast<int>();
    const int seen = ++voxels[std::make_tuple(v.x(), v.y(), v.z())];
    EXPECT_EQ(seen, 1);
  }
  EXPECT_TRUE(ExtractLoamFeatures(LoamFeatureOptions(), Scan()).edges.empty());
  Scan tiny;
  tiny.points.resize(3);
  EXPECT_TRUE(ExtractLoamFeatures(LoamFeatureOptions(), tiny).planes.empty());
}

}  // namespace
}  // namespace raillomer
