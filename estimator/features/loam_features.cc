#include "estimator/features/loam_features.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <unordered_map>
#include <vector>

namespace raillomer {

namespace {

constexpr double kDeg = M_PI / 180.0;
/// A window whose beams' chord is shorter than this fraction of their path along the line turns
/// back on itself.
constexpr float kStraightWindow = 0.8f;

/// A selectable point: its position in the scan and its smoothness.
struct Candidate {
  uint32_t index;
  float curvature;
};

float Range(const ScanPoint& point) { return point.range_m > 0.f ? point.range_m : point.p.norm(); }

/// Chord 2 sin(angle / 2) between the beams of two returns `distance` apart at ranges ra, rb
/// from one origin: distance^2 = (ra - rb)^2 + ra rb chord^2.
float BeamChord(float distance, float ra, float rb) {
  const float dr = ra - rb;
  return std::sqrt(std::max(distance * distance - dr * dr, 0.f) / (ra * rb));
}

/// Keeps one candidate per voxel: the one that compares best under `better`.
template <typename Better>
std::vector<Eigen::Vector3f> VoxelThin(const std::vector<Candidate>& candidates,
                                       const std::vector<ScanPoint>& points,
                                       double voxel_m,
                                       Better better) {
  std::vector<Eigen::Vector3f> out;
  if (voxel_m <= 0.0) {
    out.reserve(candidates.size());
    for (const Candidate& c : candidates) out.push_back(points[c.index].p);
    return out;
  }
  const float voxel = static_cast<float>(voxel_m);
  std::unordered_map<uint64_t, size_t> best;  // voxel -> position in candidates
  best.reserve(2 * candidates.size());
  std::vector<size_t> order;
  order.reserve(candidates.size());
  for (size_t i = 0; i < candidates.size(); ++i) {
    const Eigen::Vector3f& p = points[candidates[i].index].p;
    auto axis = [voxel](float v) {
      return static_cast<uint64_t>(static_cast<int64_t>(std::floor(v / voxel)) + (1 << 20)) &
             0x1FFFFF;
    };
    const uint64_t key = axis(p.x()) << 42 | axis(p.y()) << 21 | axis(p.z());
    auto [it, inserted] = best.emplace(key, i);
    if (inserted) {
      order.push_back(key);
    } else if (better(candidates[i], candidates[it->second])) {
      it->second = i;
    }
  }
  out.reserve(order.size());
  for (uint64_t key : order) out.push_back(points[candidates[best[key]].index].p);
  return out;
}

}  // namespace

bool LoamFeatureOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (curvature_half_window < 1) return fail("curvature_half_window must be >= 1");
  if (sectors_per_line < 1) return fail("sectors_per_line must be >= 1");
  if (max_edges_per_sector < 0) return fail("max_edges_per_sector must be >= 0");
  if (max_planes_per_sector < 0) return fail("max_planes_per_sector must be >= 0");
  if (!(edge_curvature_min > 0.0)) return fail("edge_curvature_min must be > 0");
  if (!(plane_curvature_max > 0.0)) return fail("plane_curvature_max must be > 0");
  if (!(plane_curvature_max < edge_curvature_min)) {
    return fail("plane_curvature_max must be < edge_curvature_min");
  }
  if (!(plane_voxel_m >= 0.0)) return fail("plane_voxel_m must be >= 0");
  if (!(edge_voxel_m >= 0.0)) return fail("edge_voxel_m must be >= 0");
  if (!(gap_angle_deg > 0.0)) return fail("gap_angle_deg must be > 0");
  if (!(occlusion_depth_ratio > 0.0)) return fail("occlusion_depth_ratio must be > 0");
  if (!(max_incidence_deg > 0.0 && max_incidence_deg < 90.0)) {
    return fail("max_incidence_deg must be in (0, 90)");
  }
  return true;
}

FeatureSet ExtractLoamFeatures(const LoamFeatureOptions& options, const Scan& scan) {
  const std::vector<ScanPoint>& points = scan.points;
  const int k = options.curvature_half_window;
  const int plane_suppression = std::max(1, k / 2);
  const float gap_angle = static_cast<float>(2.0 * std::sin(0.5 * options.gap_angle_deg * kDeg));
  const float occlusion_ratio = static_cast<float>(options.occlusion_depth_ratio);
  const float grazing_stretch =
      static_cast<float>(1.0 / std::cos(options.max_incidence_deg * kDeg));
  const float edge_min = static_cast<float>(options.edge_curvature_min);
  const float plane_max = static_cast<float>(options.plane_curvature_max);

  std::vector<Candidate> edges, planes, sector;
  std::vector<float> range, beam_angle, spacing, path, curvature;
  std::vector<uint8_t> broken, blocked, picked;
  for (const std::vector<uint32_t>& line : PositionsByLine(points)) {
    const int m = static_cast<int>(line.size());
    if (m < 2 * k + 1) continue;
    range.resize(m);
    for (int j = 0; j < m; ++j) range[j] = std::max(Range(points[line[j]]), 1e-3f);
    // Steps between neighbours (step j joins j and j + 1). Within a few microseconds the sensor
    // barely moves, so the two returns and the sensor form a triangle even after deskewing: the
    // angle between the beams follows from the ranges and the distance.
    beam_angle.assign(m - 1, 0.f);
    spacing.assign(m - 1, 0.f);
    path.assign(m, 0.f);  // cumulative beam angle along the line
    broken.assign(m - 1, 0);
    blocked.assign(m, 0);
    for (int j = 0; j + 1 < m; ++j) {
      spacing[j] = (points[line[j + 1]].p - points[line[j]].p).norm();
      beam_angle[j] = BeamChord(spacing[j], range[j], range[j + 1]);
      path[j + 1] = path[j] + beam_angle[j];
      const float dr = range[j + 1] - range[j];
      int from = 0, to = -1;
      if (beam_angle[j] > gap_angle) {
        from = j - k + 1;  // a gap: no window may span it
        to = j + k;
      } else if (std::fabs(dr) > occlusion_ratio * std::min(range[j], range[j + 1])) {
        // An occlusion: the far side's points are unstable (LOAM); the near side's outline is
        // a real edge.
        from = dr > 0.f ? j + 1 : j - k + 1;
        to = dr > 0.f ? j + k : j;
      } else {
        continue;
      }
      broken[j] = 1;
      for (int i = std::max(from, 0); i <= std::min(to, m - 1); ++i) blocked[i] = 1;
    }
    // Smoothness (LOAM): |sum of (p_j - p_i) over the window|^2 / range^2.
    curvature.assign(m, 0.f);
    for (int j = k; j < m - k; ++j) {
      if (blocked[j]) continue;
      // Grazing incidence: both neighbours much farther than the beam angle explains.
      const float face_on = range[j] * grazing_stretch;
      if (spacing[j - 1] > face_on * beam_angle[j - 1] && spacing[j] > face_on * beam_angle[j]) {
        blocked[j] = 1;
        continue;
      }
      // The beams of the window must run on along the line, not turn back (the end of a sweep
      // of the scan pattern): the chord of the window falls short of its path.
      const int a = j - k, b = j + k;
      const float span =
          BeamChord((points[line[b]].p - points[line[a]].p).norm(), range[a], range[b]);
      if (span < kStraightWindow * (path[b] - path[a])) {
        blocked[j] = 1;
        continue;
      }
      const Eigen::Vector3f& c = points[line[j]].p;
      Eigen::Vector3f sum = -static_cast<float>(2 * k) * c;
      for (int i = a; i <= b; ++i) {
        if (i != j) sum += points[line[i]].p;
      }
      curvature[j] = sum.squaredNorm() / (range[j] * range[j]);
    }
    // Per sector: the sharpest edges and the flattest planes, each suppressing its neighbours.
    picked.assign(m, 0);
    auto suppress = [&](int j, int half) {
      for (int i = 1; i <= half && j + i < m && !broken[j + i - 1]; ++i) picked[j + i] = 1;
      for (int i = 1; i <= half && j - i >= 0 && !broken[j - i]; ++i) picked[j - i] = 1;
    };
    const int usable = m - 2 * k;
    for (int s = 0; s < options.sectors_per_line; ++s) {
      const int begin = k + usable * s / options.sectors_per_line;
      const int end = k + usable * (s + 1) / options.sectors_per_line;
      sector.clear();
      for (int j = begin; j < end; ++j) {
        if (!blocked[j] && curvature[j] > edge_min) {
          sector.push_back({static_cast<uint32_t>(j), curvature[j]});
        }
      }
      std::sort(sector.begin(), sector.end(), [](const Candidate& a, const Candidate& b) {
        return a.curvature > b.curvature;
      });
      int taken = 0;
      for (const Candidate& c : sector) {
        if (taken >= options.max_edges_per_sector) break;
        if (picked[c.index]) continue;
        picked[c.index] = 1;
        suppress(c.index, k);
        edges.push_back({line[c.index], c.curvature});
        ++taken;
      }
      sector.clear();
      for (int j = begin; j < end; ++j) {
        if (!blocked[j] && curvature[j] < plane_max) {
          sector.push_back({static_cast<uint32_t>(j), curvature[j]});
        }
      }
      std::sort(sector.begin(), sector.end(), [](const Candidate& a, const Candidate& b) {
        return a.curvature < b.curvature;
      });
      taken = 0;
      for (const Candidate& c : sector) {
        if (taken >= options.max_planes_per_sector) break;
        if (picked[c.index]) continue;
        picked[c.index] = 1;
        suppress(c.index, plane_suppression);
        planes.push_back({line[c.index], c.curvature});
        ++taken;
      }
    }
  }
  FeatureSet features;
  features.edges =
      VoxelThin(edges, points, options.edge_voxel_m, [](const Candidate& a, const Candidate& b) {
        return a.curvature > b.curvature;
      });
  features.planes =
      VoxelThin(planes, points, options.plane_voxel_m, [](const Candidate& a, const Candidate& b) {
        return a.curvature < b.curvature;
      });
  return features;
}

}  // namespace raillomer
