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

/// The thresholds of the extraction, from its options.
struct Thresholds {
  explicit Thresholds(const LoamFeatureOptions& options)
      : k(options.curvature_half_window),
        plane_suppression(std::max(1, k / 2)),
        gap_angle(static_cast<float>(2.0 * std::sin(0.5 * options.gap_angle_deg * kDeg))),
        occlusion_ratio(static_cast<float>(options.occlusion_depth_ratio)),
        grazing_stretch(static_cast<float>(1.0 / std::cos(options.max_incidence_deg * kDeg))),
        edge_min(static_cast<float>(options.edge_curvature_min)),
        plane_max(static_cast<float>(options.plane_curvature_max)) {}

  int k;  ///< curvature half window
  int plane_suppression;
  float gap_angle;  ///< chord of gap_angle_deg
  float occlusion_ratio;
  float grazing_stretch;
  float edge_min, plane_max;
};

/// Per-line working arrays, reused from line to line. Step j joins points j and j + 1.
struct LineWork {
  std::vector<float> range, beam_angle, spacing, path, curvature;
  std::vector<uint8_t> broken;   ///< step j is a gap or an occlusion
  std::vector<uint8_t> blocked;  ///< point j is not selectable
  std::vector<uint8_t> picked;   ///< point j is taken or suppressed
  std::vector<Candidate> sector;
};

/// Ranges and steps along a line, and the gaps and occlusions no window may span. Within a few
/// microseconds the sensor barely moves, so the two returns and the sensor form a triangle even
/// after deskewing: the angle between the beams follows from the ranges and the distance.
void MeasureSteps(const std::vector<ScanPoint>& points,
                  const std::vector<uint32_t>& line,
                  const Thresholds& t,
                  LineWork* w) {
  const int m = static_cast<int>(line.size());
  const int k = t.k;
  w->range.resize(m);
  for (int j = 0; j < m; ++j) w->range[j] = std::max(Range(points[line[j]]), 1e-3f);
  w->beam_angle.assign(m - 1, 0.f);
  w->spacing.assign(m - 1, 0.f);
  w->path.assign(m, 0.f);  // cumulative beam angle along the line
  w->broken.assign(m - 1, 0);
  w->blocked.assign(m, 0);
  for (int j = 0; j + 1 < m; ++j) {
    w->spacing[j] = (points[line[j + 1]].p - points[line[j]].p).norm();
    w->beam_angle[j] = BeamChord(w->spacing[j], w->range[j], w->range[j + 1]);
    w->path[j + 1] = w->path[j] + w->beam_angle[j];
    const float dr = w->range[j + 1] - w->range[j];
    int from = 0, to = -1;
    if (w->beam_angle[j] > t.gap_angle) {
      from = j - k + 1;  // a gap: no window may span it
      to = j + k;
    } else if (std::fabs(dr) > t.occlusion_ratio * std::min(w->range[j], w->range[j + 1])) {
      // An occlusion: the far side's points are unstable (LOAM); the near side's outline is
      // a real edge.
      from = dr > 0.f ? j + 1 : j - k + 1;
      to = dr > 0.f ? j + k : j;
    } else {
      continue;
    }
    w->broken[j] = 1;
    for (int i = std::max(from, 0); i <= std::min(to, m - 1); ++i) w->blocked[i] = 1;
  }
}

/// Smoothness (LOAM) of each selectable point: |sum of (p_j - p_i) over the window|^2 / range^2.
/// Points at grazing incidence or whose window turns back are blocked.
void MeasureCurvature(const std::vector<ScanPoint>& points,
                      const std::vector<uint32_t>& line,
                      const Thresholds& t,
                      LineWork* w) {
  const int m = static_cast<int>(line.size());
  const int k = t.k;
  w->curvature.assign(m, 0.f);
  for (int j = k; j < m - k; ++j) {
    if (w->blocked[j]) continue;
    // Grazing incidence: both neighbours much farther than the beam angle explains.
    const float face_on = w->range[j] * t.grazing_stretch;
    if (w->spacing[j - 1] > face_on * w->beam_angle[j - 1] &&
        w->spacing[j] > face_on * w->beam_angle[j]) {
      w->blocked[j] = 1;
      continue;
    }
    // The beams of the window must run on along the line, not turn back (the end of a sweep
    // of the scan pattern): the chord of the window falls short of its path.
    const int a = j - k, b = j + k;
    const float span =
        BeamChord((points[line[b]].p - points[line[a]].p).norm(), w->range[a], w->range[b]);
    if (span < kStraightWindow * (w->path[b] - w->path[a])) {
      w->blocked[j] = 1;
      continue;
    }
    const Eigen::Vector3f& c = points[line[j]].p;
    Eigen::Vector3f sum = -static_cast<float>(2 * k) * c;
    for (int i = a; i <= b; ++i) {
      if (i != j) sum += points[line[i]].p;
    }
    w->curvature[j] = sum.squaredNorm() / (w->range[j] * w->range[j]);
  }
}

/// Takes up to `max_count` of the sector [begin, end)'s points that pass `accept`, best first
/// under `better`, each suppressing `half` neighbours either side up to a broken step; appends
/// them (scan indices) to `out`.
template <typename Accept, typename Better>
void PickInSector(const std::vector<uint32_t>& line,
                  int begin,
                  int end,
                  int max_count,
                  int half,
                  Accept accept,
                  Better better,
                  LineWork* w,
                  std::vector<Candidate>* out) {
  const int m = static_cast<int>(line.size());
  w->sector.clear();
  for (int j = begin; j < end; ++j) {
    if (!w->blocked[j] && accept(w->curvature[j])) {
      w->sector.push_back({static_cast<uint32_t>(j), w->curvature[j]});
    }
  }
  std::sort(w->sector.begin(), w->sector.end(), better);
  int taken = 0;
  for (const Candidate& c : w->sector) {
    if (taken >= max_count) break;
    if (w->picked[c.index]) continue;
    const int j = static_cast<int>(c.index);
    w->picked[j] = 1;
    for (int i = 1; i <= half && j + i < m && !w->broken[j + i - 1]; ++i) w->picked[j + i] = 1;
    for (int i = 1; i <= half && j - i >= 0 && !w->broken[j - i]; ++i) w->picked[j - i] = 1;
    out->push_back({line[c.index], c.curvature});
    ++taken;
  }
}

bool Sharper(const Candidate& a, const Candidate& b) { return a.curvature > b.curvature; }
bool Flatter(const Candidate& a, const Candidate& b) { return a.curvature < b.curvature; }

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
  const Thresholds t(options);
  std::vector<Candidate> edges, planes;
  LineWork w;
  for (const std::vector<uint32_t>& line : PositionsByLine(points)) {
    const int m = static_cast<int>(line.size());
    if (m < 2 * t.k + 1) continue;
    MeasureSteps(points, line, t, &w);
    MeasureCurvature(points, line, t, &w);
    // Per sector: the sharpest edges and the flattest planes, each suppressing its neighbours.
    w.picked.assign(m, 0);
    const int usable = m - 2 * t.k;
    for (int s = 0; s < options.sectors_per_line; ++s) {
      const int begin = t.k + usable * s / options.sectors_per_line;
      const int end = t.k + usable * (s + 1) / options.sectors_per_line;
      PickInSector(
          line,
          begin,
          end,
          options.max_edges_per_sector,
          t.k,
          [&t](float curvature) { return curvature > t.edge_min; },
          Sharper,
          &w,
          &edges);
      PickInSector(
          line,
          begin,
          end,
          options.max_planes_per_sector,
          t.plane_suppression,
          [&t](float curvature) { return curvature < t.plane_max; },
          Flatter,
          &w,
          &planes);
    }
  }
  FeatureSet features;
  features.edges = VoxelThin(edges, points, options.edge_voxel_m, Sharper);
  features.planes = VoxelThin(planes, points, options.plane_voxel_m, Flatter);
  return features;
}

}  // namespace raillomer
