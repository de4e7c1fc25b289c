#include "estimator/eval/map_sharpness.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <tuple>

#include <Eigen/Eigenvalues>

#include "estimator/eval/association.h"
#include "estimator/sim/world.h"

namespace raillomer::eval {
namespace {

using Vec3 = Eigen::Vector3d;

/// A 2-D grid cell or a patch key; std::map keeps the code free of hand-written hashes.
using Cell2 = std::pair<int64_t, int64_t>;
using PatchKey = std::tuple<int64_t, int64_t, int64_t, int64_t, int64_t, int64_t, int64_t>;

constexpr double kGridM = 2.0;  // triangle lookup grid

Cell2 GridCell(const Vec3& p) {
  return {static_cast<int64_t>(std::floor(p.x() / kGridM)),
          static_cast<int64_t>(std::floor(p.y() / kGridM))};
}

double Percentile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  const size_t k = std::min(values.size() - 1, static_cast<size_t>(q * (values.size() - 1) + 0.5));
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

/// How far `p` lies from the segment from..to (2-D or 3-D).
template <typename V>
double SegmentDistance(const V& from, const V& to, const V& p) {
  const V edge = to - from;
  const double t = std::clamp(edge.dot(p - from) / std::max(edge.squaredNorm(), 1e-18), 0.0, 1.0);
  return (from + t * edge - p).norm();
}

/// How far `p` lies from the triangle abc in plan (x, y): zero inside it.
double PlanDistance(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& p) {
  const Eigen::Vector2d q = p.head<2>();
  const Eigen::Vector2d corners[3] = {a.head<2>(), b.head<2>(), c.head<2>()};
  double sides[3], distance = 1e300;
  for (int e = 0; e < 3; ++e) {
    const Eigen::Vector2d& u = corners[e];
    const Eigen::Vector2d edge = corners[(e + 1) % 3] - u;
    sides[e] = edge.x() * (q.y() - u.y()) - edge.y() * (q.x() - u.x());
    distance = std::min(distance, SegmentDistance(u, corners[(e + 1) % 3], q));
  }
  const bool inside = (sides[0] >= 0.0 && sides[1] >= 0.0 && sides[2] >= 0.0) ||
                      (sides[0] <= 0.0 && sides[1] <= 0.0 && sides[2] <= 0.0);
  return inside ? 0.0 : distance;
}

/// A reference triangle ready for point tests: its plane and inward edge normals (edge e runs
/// from corner e to corner e + 1).
struct Surface {
  ReferenceTriangle::Kind kind;
  Vec3 corner[3], n;
  double d = 0.0;
  Vec3 edge_normal[3];
  /// An edge is inner when a triangle of the same surface continues beyond it (the other half
  /// of a quad, the next step of a rail); margins are kept from outer edges only.
  bool inner[3] = {false, false, false};
  int64_t plane_key[2];  ///< the plane, quantised, so coplanar triangles share patches
};

/// Sums for a plane fit, relative to the patch's first point (UTM is too large for raw sums).
struct PlaneSums {
  size_t count = 0;
  Vec3 sum = Vec3::Zero();
  Eigen::Matrix3d outer = Eigen::Matrix3d::Zero();

  void Add(const Vec3& r) {
    ++count;
    sum += r;
    outer += r * r.transpose();
  }
  Vec3 Mean() const { return sum / static_cast<double>(count); }
  Eigen::Matrix3d Covariance() const {
    const Vec3 mean = Mean();
    return outer / static_cast<double>(count) - mean * mean.transpose();
  }
};

/// One plane patch: its points' sums, pooled and per submap.
struct PlanePatch {
  Vec3 reference = Vec3::Zero();
  PlaneSums all;
  struct Sample {
    size_t submap = 0;   ///< the order it was added in
    uint32_t index = 0;  ///< api::Submap::index
    PlaneSums sums;
  };
  std::vector<Sample> by_submap;
};

/// One submap's points on one rail-head segment: their heights along the head's normal.
struct RailSample {
  size_t submap = 0;   ///< the order it was added in
  uint32_t index = 0;  ///< api::Submap::index
  size_t count = 0;
  double sum = 0.0;
  double sum_squares = 0.0;
  double truth_sum = 0.0;  ///< distances from the true head, after the truth alignment
};

struct RailSegment {
  Vec3 where = Vec3::Zero();
  std::vector<RailSample> samples;
};

/// A mesh triangle in UTM with its unit normal and material.
struct Candidate {
  Vec3 a, b, c, n;
  sim::Material material;
};

/// Sorts the mesh's triangles, moved into UTM, into candidate planes and rail faces.
void SortCandidates(const sim::Mesh& mesh,
                    const Eigen::Vector3d& origin_utm,
                    std::vector<Candidate>* planes,
                    std::vector<Candidate>* rail_tops) {
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const Eigen::Vector3i& t = mesh.triangles[i];
    Candidate c{mesh.vertices[t[0]].cast<double>() + origin_utm,
                mesh.vertices[t[1]].cast<double>() + origin_utm,
                mesh.vertices[t[2]].cast<double>() + origin_utm,
                Vec3::Zero(),
                mesh.materials[i]};
    const Vec3 cross = (c.b - c.a).cross(c.c - c.a);
    if (cross.norm() < 1e-9) continue;
    c.n = cross.normalized();
    const double up = std::fabs(c.n.z());
    // Horizontal faces either way up: the corridor mesh's winding is not consistent (the ray
    // caster does not care), and a platform's underside is never seen anyway.
    if ((c.material == sim::Material::kPlatform && up > 0.95) ||
        (c.material == sim::Material::kBuilding && up < 0.05)) {
      planes->push_back(c);
    } else if (c.material == sim::Material::kRail && up > 0.9) {
      rail_tops->push_back(c);
    }
  }
}

// A rail's horizontal faces are its head top, the head's underside 5 cm below it and its foot
// 16 cm below (either way up, as above; the foot reaches 4 cm beyond the head on each side).
// The head top is the face with no face of its rail higher by more than a centimetre (a canted
// head tilts by millimetres across its width) within 10 cm in plan; the other rail of the
// track is 1.5 m away.
constexpr double kSameRailM = 0.1;

/// Rail faces by the grid cells within kSameRailM of them.
using RailFaceGrid = std::map<Cell2, std::vector<const Candidate*>>;

/// Puts every rail face into the grid cells its box, grown by kSameRailM, touches.
RailFaceGrid GridRailFaces(const std::vector<Candidate>& rail_tops) {
  RailFaceGrid grid;
  for (const Candidate& c : rail_tops) {
    const Eigen::AlignedBox3d box = Eigen::AlignedBox3d(c.a).extend(c.b).extend(c.c);
    const Cell2 lo = GridCell(box.min() - Vec3::Constant(kSameRailM));
    const Cell2 hi = GridCell(box.max() + Vec3::Constant(kSameRailM));
    for (int64_t x = lo.first; x <= hi.first; ++x) {
      for (int64_t y = lo.second; y <= hi.second; ++y) grid[{x, y}].push_back(&c);
    }
  }
  return grid;
}

/// Whether another face of the rail lies more than a centimetre above the face's centroid.
bool Covered(const Candidate& c, const RailFaceGrid& grid) {
  const Vec3 centroid = (c.a + c.b + c.c) / 3.0;
  const auto cell = grid.find(GridCell(centroid));  // its own face put it there
  for (const Candidate* other : cell->second) {
    if (other == &c || PlanDistance(other->a, other->b, other->c, centroid) > kSameRailM) continue;
    // The other face's height where the centroid is (faces are within 25 degrees of level;
    // the track's grade tilts them along its length).
    const double z = other->a.z() -
                     other->n.head<2>().dot(centroid.head<2>() - other->a.head<2>()) / other->n.z();
    if (z > centroid.z() + 0.01) return true;
  }
  return false;
}

}  // namespace

std::vector<ReferenceTriangle> SelectReferenceTriangles(const sim::Mesh& mesh,
                                                        const Eigen::Vector3d& origin_utm) {
  std::vector<Candidate> planes, rail_tops;
  SortCandidates(mesh, origin_utm, &planes, &rail_tops);
  const RailFaceGrid grid = GridRailFaces(rail_tops);
  std::vector<ReferenceTriangle> out;
  for (const Candidate& c : planes) {
    out.push_back({ReferenceTriangle::Kind::kPlane, c.a, c.b, c.c});
  }
  for (const Candidate& c : rail_tops) {
    if (!Covered(c, grid)) out.push_back({ReferenceTriangle::Kind::kRailHead, c.a, c.b, c.c});
  }
  return out;
}

/// Whether two triangles belong to one surface: the same kind, within 10 degrees of each other
/// (a rail's steps follow its curves and grades; a box's faces meet at right angles).
bool SameSurface(const Surface& a, const Surface& b) {
  static const double kCos = std::cos(10.0 * M_PI / 180.0);
  return a.kind == b.kind && std::fabs(a.n.dot(b.n)) > kCos;
}

/// Marks the edges two triangles of one surface share.
void MarkInnerEdges(std::vector<Surface>* surfaces) {
  using Corner = std::tuple<int64_t, int64_t, int64_t>;
  const auto corner = [](const Vec3& v) {
    return Corner{std::llround(v.x() * 1000.0),
                  std::llround(v.y() * 1000.0),
                  std::llround(v.z() * 1000.0)};  // to a millimetre
  };
  std::map<std::pair<Corner, Corner>, std::vector<std::pair<uint32_t, int>>> edges;
  for (uint32_t i = 0; i < surfaces->size(); ++i) {
    const Surface& s = (*surfaces)[i];
    for (int e = 0; e < 3; ++e) {
      Corner from = corner(s.corner[e]), to = corner(s.corner[(e + 1) % 3]);
      if (to < from) std::swap(from, to);
      edges[{from, to}].push_back({i, e});
    }
  }
  for (const auto& [key, sides] : edges) {
    for (const auto& [i, e] : sides) {
      Surface& s = (*surfaces)[i];
      for (const auto& [j, f] : sides) {
        if (j != i && SameSurface((*surfaces)[j], s)) s.inner[e] = true;
      }
    }
  }
}

struct MapSharpness::Impl {
  SharpnessOptions options;
  std::vector<Surface> surfaces;
  std::map<Cell2, std::vector<uint32_t>> grid;
  std::map<PatchKey, PlanePatch> planes;
  std::map<PatchKey, RailSegment> rails;
  size_t submaps = 0, points = 0, rail_points = 0;

  /// The surface a truth-aligned point lies on, or -1.
  int Find(const Vec3& p) const {
    const auto it = grid.find(GridCell(p));
    if (it == grid.end()) return -1;
    int best = -1;
    double best_inside = -1e9;
    for (uint32_t index : it->second) {
      const Surface& s = surfaces[index];
      const bool plane = s.kind == ReferenceTriangle::Kind::kPlane;
      const double distance = s.n.dot(p) - s.d;
      if (std::fabs(distance) > (plane ? options.plane_tolerance_m : options.rail_tolerance_m)) {
        continue;
      }
      const Vec3 q = p - distance * s.n;
      double inside = 1e9;
      for (int e = 0; e < 3; ++e) {
        inside = std::min(inside, s.edge_normal[e].dot(q - s.corner[e]));
      }
      constexpr double kSeamM = 1e-4;  // neighbours share their edges to float precision
      if (inside < -kSeamM) continue;
      if (FromOuterEdges(q, s, it->second) <
          (plane ? options.plane_margin_m : options.rail_margin_m)) {
        continue;
      }
      if (inside > best_inside) {
        best_inside = inside;
        best = static_cast<int>(index);
      }
    }
    return best;
  }

  /// How far `q`, on the surface of `s`, lies from the surface's outer edges: those of every
  /// triangle of it in `nearby` (a rail head's two sides belong to different halves of a quad).
  double FromOuterEdges(const Vec3& q,
                        const Surface& s,
                        const std::vector<uint32_t>& nearby) const {
    double nearest = 1e9;
    for (uint32_t index : nearby) {
      const Surface& o = surfaces[index];
      if (!SameSurface(o, s)) continue;
      for (int e = 0; e < 3; ++e) {
        if (!o.inner[e])
          nearest = std::min(nearest, SegmentDistance(o.corner[e], o.corner[(e + 1) % 3], q));
      }
    }
    return nearest;
  }
};

MapSharpness::MapSharpness(std::vector<ReferenceTriangle> triangles,
                           const SharpnessOptions& options)
    : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  for (const ReferenceTriangle& t : triangles) {
    Surface s;
    s.kind = t.kind;
    s.corner[0] = t.a;
    s.corner[1] = t.b;
    s.corner[2] = t.c;
    s.n = (t.b - t.a).cross(t.c - t.a).normalized();
    if (!s.n.allFinite()) continue;
    s.d = s.n.dot(t.a);
    for (int e = 0; e < 3; ++e) {
      const Vec3& from = s.corner[e];
      const Vec3& to = s.corner[(e + 1) % 3];
      const Vec3& opposite = s.corner[(e + 2) % 3];
      Vec3 m = s.n.cross(to - from).normalized();
      if (m.dot(opposite - from) < 0.0) m = -m;
      s.edge_normal[e] = m;
    }
    // Coplanar triangles (the two halves of a quad) share a key: the normal to 1e-3 and the
    // offset to 1 cm.
    s.plane_key[0] = std::llround(s.n.x() * 1000.0) * 4001 * 4001 +
                     std::llround(s.n.y() * 1000.0) * 4001 + std::llround(s.n.z() * 1000.0);
    s.plane_key[1] = std::llround(s.d * 100.0);
    const uint32_t index = static_cast<uint32_t>(impl_->surfaces.size());
    impl_->surfaces.push_back(s);
    const Eigen::AlignedBox3d box = Eigen::AlignedBox3d(t.a).extend(t.b).extend(t.c);
    const Cell2 lo = GridCell(box.min() - Vec3::Constant(0.1));
    const Cell2 hi = GridCell(box.max() + Vec3::Constant(0.1));
    for (int64_t x = lo.first; x <= hi.first; ++x) {
      for (int64_t y = lo.second; y <= hi.second; ++y) impl_->grid[{x, y}].push_back(index);
    }
  }
  MarkInnerEdges(&impl_->surfaces);
}

MapSharpness::~MapSharpness() = default;

void MapSharpness::AddSubmap(const api::Submap& submap, const Eigen::Isometry3d& T_truth_est) {
  Impl& m = *impl_;
  const size_t submap_index = m.submaps++;
  m.points += submap.points.size();
  for (const Eigen::Vector3f& offset : submap.points) {
    const Vec3 mapped = submap.origin + offset.cast<double>();
    const Vec3 aligned = T_truth_est * mapped;
    const int found = m.Find(aligned);
    if (found < 0) continue;
    const Surface& s = m.surfaces[static_cast<size_t>(found)];
    if (s.kind == ReferenceTriangle::Kind::kPlane) {
      const double cell = m.options.patch_m;
      const PatchKey key{s.plane_key[0],
                         s.plane_key[1],
                         static_cast<int64_t>(std::floor(aligned.x() / cell)),
                         static_cast<int64_t>(std::floor(aligned.y() / cell)),
                         static_cast<int64_t>(std::floor(aligned.z() / cell)),
                         0,
                         0};
      PlanePatch& patch = m.planes[key];
      if (patch.all.count == 0) patch.reference = mapped;
      const Vec3 r = mapped - patch.reference;
      patch.all.Add(r);
      if (patch.by_submap.empty() || patch.by_submap.back().submap != submap_index) {
        patch.by_submap.push_back({submap_index, submap.index, PlaneSums{}});
      }
      patch.by_submap.back().sums.Add(r);
    } else {
      ++m.rail_points;
      const double cell = m.options.rail_segment_m;
      const PatchKey key{s.plane_key[0],
                         s.plane_key[1],
                         static_cast<int64_t>(std::floor(aligned.x() / cell)),
                         static_cast<int64_t>(std::floor(aligned.y() / cell)),
                         0,
                         0,
                         1};
      RailSegment& segment = m.rails[key];
      if (segment.samples.empty()) segment.where = mapped;
      if (segment.samples.empty() || segment.samples.back().submap != submap_index) {
        segment.samples.push_back({submap_index, submap.index, 0, 0.0, 0.0, 0.0});
      }
      RailSample& sample = segment.samples.back();
      ++sample.count;
      // Heights relative to the segment's first point keep the sum exact at UTM magnitudes.
      const double height = s.n.dot(mapped - segment.where);
      sample.sum += height;
      sample.sum_squares += height * height;
      sample.truth_sum += s.n.dot(aligned) - s.d;
    }
  }
}

SharpnessResult MapSharpness::Result() const {
  const Impl& m = *impl_;
  SharpnessResult r;
  r.submaps = m.submaps;
  r.points = m.points;
  r.rail_points = m.rail_points;
  double weighted = 0.0;
  std::vector<double> patch_rms;
  for (const PlanePatchReport& patch : PlanePatches()) {
    weighted += patch.rms_m * patch.rms_m * static_cast<double>(patch.points);
    r.plane_points += patch.points;
    patch_rms.push_back(patch.rms_m);
    if (patch.rms_m > r.plane_patch_max_m) {
      r.plane_patch_max_m = patch.rms_m;
      r.worst_patch_utm = patch.utm;
    }
  }
  r.plane_patches = patch_rms.size();
  if (r.plane_points > 0) r.plane_rms_m = std::sqrt(weighted / static_cast<double>(r.plane_points));
  r.plane_patch_p95_m = Percentile(patch_rms, 0.95);

  std::vector<double> spreads;
  for (const RailSegmentReport& segment : RailSegments()) {
    spreads.push_back(segment.spread_m);
    if (segment.spread_m > r.rail_spread_max_m) {
      r.rail_spread_max_m = segment.spread_m;
      r.worst_rail_utm = segment.utm;
    }
  }
  r.rail_segments = spreads.size();
  r.rail_spread_median_m = Percentile(spreads, 0.5);
  r.rail_spread_p95_m = Percentile(spreads, 0.95);
  return r;
}

std::vector<PlanePatchReport> MapSharpness::PlanePatches() const {
  const Impl& m = *impl_;
  std::vector<PlanePatchReport> out;
  for (const auto& [key, patch] : m.planes) {
    if (patch.all.count < static_cast<size_t>(m.options.min_plane_points)) continue;
    const Vec3 mean = patch.all.Mean();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(patch.all.Covariance());
    const Vec3 normal = eig.eigenvectors().col(0);
    PlanePatchReport report;
    report.utm = patch.reference + mean;
    report.points = patch.all.count;
    report.rms_m = std::sqrt(std::max(0.0, eig.eigenvalues()(0)));
    for (const PlanePatch::Sample& sample : patch.by_submap) {
      const PlaneSums& sums = sample.sums;
      const double spread = std::max(0.0, normal.dot(sums.Covariance() * normal));
      report.samples.push_back(
          {sample.index, sums.count, normal.dot(sums.Mean() - mean), std::sqrt(spread)});
    }
    out.push_back(std::move(report));
  }
  return out;
}

std::string PlanePatchesCsv(const std::vector<PlanePatchReport>& patches) {
  std::string out = "x,y,z,patch_rms_m,patch_points,submap,points,offset_m,rms_m\n";
  char line[192];
  for (const PlanePatchReport& patch : patches) {
    for (const PlanePatchReport::Sample& sample : patch.samples) {
      std::snprintf(line,
                    sizeof(line),
                    "%.3f,%.3f,%.3f,%.4f,%zu,%u,%zu,%.4f,%.4f\n",
                    patch.utm.x(),
                    patch.utm.y(),
                    patch.utm.z(),
                    patch.rms_m,
                    patch.points,
                    sample.submap,
                    sample.points,
                    sample.offset_m,
                    sample.rms_m);
      out += line;
    }
  }
  return out;
}

std::vector<RailSegmentReport> MapSharpness::RailSegments() const {
  const Impl& m = *impl_;
  std::vector<RailSegmentReport> out;
  for (const auto& [key, segment] : m.rails) {
    RailSegmentReport report;
    report.utm = segment.where;
    double lo = 1e9, hi = -1e9;
    for (const RailSample& sample : segment.samples) {
      if (sample.count < static_cast<size_t>(m.options.min_rail_points)) continue;
      const double n = static_cast<double>(sample.count);
      const double mean = sample.sum / n;
      const double rms = std::sqrt(std::max(0.0, sample.sum_squares / n - mean * mean));
      report.samples.push_back({sample.index, sample.count, mean, rms, sample.truth_sum / n});
      lo = std::min(lo, mean);
      hi = std::max(hi, mean);
    }
    if (report.samples.size() < 2) continue;
    report.spread_m = hi - lo;
    out.push_back(std::move(report));
  }
  return out;
}

std::string RailSegmentsCsv(const std::vector<RailSegmentReport>& segments) {
  std::string out = "x,y,z,spread_m,submap,points,height_m,rms_m,truth_offset_m\n";
  char line[192];
  for (const RailSegmentReport& segment : segments) {
    for (const RailSegmentReport::Sample& sample : segment.samples) {
      std::snprintf(line,
                    sizeof(line),
                    "%.3f,%.3f,%.3f,%.4f,%u,%zu,%.4f,%.4f,%.4f\n",
                    segment.utm.x(),
                    segment.utm.y(),
                    segment.utm.z(),
                    segment.spread_m,
                    sample.submap,
                    sample.points,
                    sample.height_m,
                    sample.rms_m,
                    sample.truth_offset_m);
      out += line;
    }
  }
  return out;
}

bool ScoreSubmapFolder(const std::string& folder,
                       const api::Trajectory& truth,
                       MapSharpness* sharpness,
                       size_t* skipped,
                       std::string* error) {
  namespace fs = std::filesystem;
  std::error_code ec;
  std::vector<std::string> files;
  for (const fs::directory_entry& entry : fs::directory_iterator(folder, ec)) {
    if (entry.path().extension() == ".pcd") files.push_back(entry.path().string());
  }
  if (ec) {
    *error = "cannot list " + folder + ": " + ec.message();
    return false;
  }
  if (files.empty()) {
    *error = folder + " holds no submap (.pcd) files";
    return false;
  }
  std::sort(files.begin(), files.end());  // zero-padded indices: name order is index order
  *skipped = 0;
  for (const std::string& file : files) {
    api::Submap submap;
    if (!api::ReadSubmapFile(file, &submap, error)) return false;
    if (submap.keyframes.empty()) {
      *error = file + ": the submap lists no keyframe poses";
      return false;
    }
    api::Trajectory middle;
    middle.poses.push_back(submap.keyframes[submap.keyframes.size() / 2]);
    const Association association = AssociatePoses(middle, truth, AssociationOptions{});
    if (!association.ok) {
      *error = file + ": " + association.error;
      return false;
    }
    if (association.pairs.empty()) {
      ++*skipped;
      continue;
    }
    const PosePair& pair = association.pairs.front();
    sharpness->AddSubmap(submap, pair.T_world_truth * pair.T_world_est.inverse());
  }
  return true;
}

std::string FormatSharpness(const SharpnessResult& r) {
  char text[1024];
  std::snprintf(text,
                sizeof(text),
                "map sharpness (%zu submaps, %zu points)\n"
                "  planes: %zu patches, %zu points; spread normal to the plane RMS %.4f m, "
                "patch p95 %.4f m, worst %.4f m at %.1f %.1f %.1f\n"
                "  rail heads: %zu segments seen by two or more submaps (%zu points); height "
                "difference between submaps median %.4f m, p95 %.4f m, max %.4f m at %.1f %.1f "
                "%.1f\n",
                r.submaps,
                r.points,
                r.plane_patches,
                r.plane_points,
                r.plane_rms_m,
                r.plane_patch_p95_m,
                r.plane_patch_max_m,
                r.worst_patch_utm.x(),
                r.worst_patch_utm.y(),
                r.worst_patch_utm.z(),
                r.rail_segments,
                r.rail_points,
                r.rail_spread_median_m,
                r.rail_spread_p95_m,
                r.rail_spread_max_m,
                r.worst_rail_utm.x(),
                r.worst_rail_utm.y(),
                r.worst_rail_utm.z());
  return text;
}

nlohmann::json ToJson(const SharpnessResult& r) {
  auto vec = [](const Vec3& v) { return nlohmann::json::array({v.x(), v.y(), v.z()}); };
  return {{"submaps", r.submaps},
          {"points", r.points},
          {"plane_patches", r.plane_patches},
          {"plane_points", r.plane_points},
          {"plane_rms_m", r.plane_rms_m},
          {"plane_patch_p95_m", r.plane_patch_p95_m},
          {"plane_patch_max_m", r.plane_patch_max_m},
          {"worst_patch_utm", vec(r.worst_patch_utm)},
          {"rail_segments", r.rail_segments},
          {"rail_points", r.rail_points},
          {"rail_spread_median_m", r.rail_spread_median_m},
          {"rail_spread_p95_m", r.rail_spread_p95_m},
          {"rail_spread_max_m", r.rail_spread_max_m},
          {"worst_rail_utm", vec(r.worst_rail_utm)}};
}

}  // namespace raillomer::eval
