#include "estimator/preprocess/filters.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace raillomer {

namespace {

constexpr double kDegToRad = M_PI / 180.0;

/// Keeps the points whose flag is set, in order; returns how many went.
size_t Compact(const std::vector<uint8_t>& keep, std::vector<ScanPoint>* points) {
  size_t out = 0;
  for (size_t i = 0; i < points->size(); ++i) {
    if (keep[i]) (*points)[out++] = (*points)[i];
  }
  const size_t removed = points->size() - out;
  points->resize(out);
  return removed;
}

/// Points per cell of a sparse 3D grid: a counting hash set of 46-bit cell keys with open
/// addressing, key and count packed in one word so that the table stays small in the cache.
class CellCounter {
 public:
  explicit CellCounter(size_t points) {
    size_t capacity = 64;
    while (capacity < points + points / 2 + 1) capacity *= 2;  // never full
    slots_.assign(capacity, 0);
    mask_ = capacity - 1;
  }

  /// Adds one point to the cell `key` (< 2^48); returns the cell's slot.
  uint32_t Add(uint64_t key) {
    size_t slot = (key * 0x9E3779B97F4A7C15ULL) >> 40 & mask_;
    while (true) {
      uint64_t& entry = slots_[slot];
      if (entry == 0) {
        entry = key << 16 | 1;
        break;
      }
      if (entry >> 16 == key) {
        if ((entry & 0xFFFF) != 0xFFFF) ++entry;  // the count saturates
        break;
      }
      slot = (slot + 1) & mask_;
    }
    return static_cast<uint32_t>(slot);
  }

  uint32_t Count(uint32_t slot) const { return static_cast<uint32_t>(slots_[slot] & 0xFFFF); }

 private:
  std::vector<uint64_t> slots_;  ///< key << 16 | count; 0: empty
  size_t mask_ = 0;
};

/// Key of the cell of `p` on a grid of cells 1 / `inverse_size` wide shifted by `offset` cells,
/// within range shell `shell` (0..127).
uint64_t CellKey(const Eigen::Vector3f& p, float inverse_size, float offset, int shell) {
  constexpr int64_t kBias = int64_t{1} << 12;  // 13 bits per axis, 7 for the shell
  auto axis = [&](float v) {
    const int64_t c = static_cast<int64_t>(std::floor(v * inverse_size + offset)) + kBias;
    return static_cast<uint64_t>(std::clamp<int64_t>(c, 0, 2 * kBias - 1));
  };
  return static_cast<uint64_t>(shell & 0x7F) << 39 | axis(p.x()) << 26 | axis(p.y()) << 13 |
         axis(p.z());
}

}  // namespace

bool PreprocessOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (!(min_range_m >= 0.0)) return fail("min_range_m must be >= 0");
  if (!(max_range_m > min_range_m)) return fail("max_range_m must be > min_range_m");
  if (!(flicker_cell_size_m > 0.0)) return fail("flicker_cell_size_m must be > 0");
  if (flicker_min_points_per_cell < 1) return fail("flicker_min_points_per_cell must be >= 1");
  if (!(flicker_reference_range_m >= 0.0)) return fail("flicker_reference_range_m must be >= 0");
  if (!(hidden_sector_angle_deg > 0.0 && hidden_sector_angle_deg < 90.0)) {
    return fail("hidden_sector_angle_deg must be in (0, 90)");
  }
  if (!(hidden_sector_radius_m > 0.0)) return fail("hidden_sector_radius_m must be > 0");
  if (hidden_sector_max_chain < 1) return fail("hidden_sector_max_chain must be >= 1");
  return true;
}

Scan ScanFromLidarFrame(const io::LidarFrame& frame, int lidar_index, double duration_s) {
  return ScanFromLidarFrame(frame, lidar_index, duration_s, nullptr);
}

Scan ScanFromLidarFrame(const io::LidarFrame& frame,
                        int lidar_index,
                        double duration_s,
                        PreprocessStats* stats) {
  Scan scan;
  scan.lidar_index = lidar_index;
  scan.start_s = static_cast<double>(frame.timebase_ns) * 1e-9;
  scan.duration_s = duration_s;
  scan.points.reserve(frame.points.size());
  for (const io::LivoxPoint& in : frame.points) {
    if (in.x == 0.f && in.y == 0.f && in.z == 0.f) continue;
    ScanPoint out;
    out.p = Eigen::Vector3f(in.x, in.y, in.z);
    out.time_s = static_cast<float>(in.offset_time_ns * 1e-9);
    out.range_m = out.p.norm();
    out.intensity = in.reflectivity;
    out.line = in.line;
    scan.points.push_back(out);
  }
  if (stats) {
    stats->input = frame.points.size();
    stats->no_return = frame.points.size() - scan.points.size();
  }
  return scan;
}

void RemoveNearAndFarPoints(const PreprocessOptions& options, Scan* scan, PreprocessStats* stats) {
  const float min2 = static_cast<float>(options.min_range_m * options.min_range_m);
  const float max2 = static_cast<float>(options.max_range_m * options.max_range_m);
  std::vector<uint8_t> keep(scan->points.size());
  for (size_t i = 0; i < scan->points.size(); ++i) {
    const float r2 = scan->points[i].p.squaredNorm();
    keep[i] = r2 >= min2 && r2 <= max2;
  }
  const size_t removed = Compact(keep, &scan->points);
  if (stats) stats->near_or_far += removed;
}

void RemoveSunFlicker(const PreprocessOptions& options, Scan* scan, PreprocessStats* stats) {
  // Paper IV.C: an occupancy grid in the sensor frame; all points of a sparse cell go. Flicker
  // returns spread along the rays towards the sun at random ranges, so near the sensor they
  // crowd into a few metres while true surfaces far away thin out; cells that grow with range
  // (half-octave shells) treat both alike. A second grid, shifted by half a cell and a quarter
  // octave, keeps surface points that a cell boundary cut off from their neighbours.
  std::vector<ScanPoint>& points = scan->points;
  const size_t n = points.size();
  if (n == 0) return;
  const bool scaled = options.flicker_reference_range_m > 0.0;
  // Shell s (r in [2^(s/2), 2^((s+1)/2)) for grid 0, a quarter octave lower for grid 1) has
  // cells alpha 2^(s/2) wide, about alpha r.
  constexpr int kShells = 128, kShellBias = kShells / 2;
  float inverse_size[kShells];
  const double alpha = options.flicker_cell_size_m / options.flicker_reference_range_m;
  for (int s = 0; s < kShells; ++s) {
    inverse_size[s] = static_cast<float>(1.0 / (alpha * std::exp2(0.5 * (s - kShellBias))));
  }
  const float fixed_inverse_size = static_cast<float>(1.0 / options.flicker_cell_size_m);
  CellCounter grids[2] = {CellCounter(n), CellCounter(n)};
  std::vector<uint32_t> slots[2] = {std::vector<uint32_t>(n), std::vector<uint32_t>(n)};
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f& p = points[i].p;
    const float octaves = scaled ? 2.f * std::log2(std::max(p.norm(), 1e-3f)) : 0.f;
    for (int g = 0; g < 2; ++g) {
      int shell = 0;
      float inverse = fixed_inverse_size;
      if (scaled) {
        shell = std::clamp(
            static_cast<int>(std::floor(octaves + 0.5f * g)) + kShellBias, 0, kShells - 1);
        inverse = inverse_size[shell];
      }
      slots[g][i] = grids[g].Add(CellKey(p, inverse, 0.5f * g, shell));
    }
  }
  const uint32_t min_points = static_cast<uint32_t>(options.flicker_min_points_per_cell);
  std::vector<uint8_t> keep(n);
  for (size_t i = 0; i < n; ++i) {
    keep[i] = grids[0].Count(slots[0][i]) >= min_points ||
              grids[1].Count(slots[1][i]) >= min_points ||
              points[i].intensity >= options.flicker_exempt_intensity;
  }
  const size_t removed = Compact(keep, &points);
  if (stats) stats->flicker += removed;
}

void RemoveBoundaryBleeding(const PreprocessOptions& options, Scan* scan, PreprocessStats* stats) {
  // Paper IV.C, Fig. 5. A mixed return lies on its beam between a foreground and a background
  // surface: it and its neighbours along the line form a chain in which each step runs within
  // phi of the beam axis. The chain's inner points (at least one of their steps within d) are
  // stretched points; the chain's ends are the real surfaces. A chain longer than
  // hidden_sector_max_chain inner points is a surface at grazing incidence and stays.
  std::vector<ScanPoint>& points = scan->points;
  const float cos_phi = static_cast<float>(std::cos(options.hidden_sector_angle_deg * kDegToRad));
  const float d = static_cast<float>(options.hidden_sector_radius_m);
  const int max_chain = options.hidden_sector_max_chain;
  std::vector<uint8_t> keep(points.size(), 1);
  std::vector<uint8_t> axial;
  std::vector<float> step_m;
  for (const std::vector<uint32_t>& line : PositionsByLine(points)) {
    const int m = static_cast<int>(line.size());
    if (m < 3) continue;
    // Step j joins line[j] and line[j + 1].
    axial.assign(m - 1, 0);
    step_m.assign(m - 1, 0.f);
    for (int j = 0; j + 1 < m; ++j) {
      const Eigen::Vector3f& a = points[line[j]].p;
      const Eigen::Vector3f& b = points[line[j + 1]].p;
      const Eigen::Vector3f v = b - a;
      const float length = v.norm();
      step_m[j] = length;
      if (length <= 0.f) continue;
      const float ra = a.norm(), rb = b.norm();
      if (ra <= 0.f || rb <= 0.f) continue;
      const float along = std::max(std::fabs(v.dot(a)) / ra, std::fabs(v.dot(b)) / rb);
      axial[j] = along >= cos_phi * length;
    }
    // Maximal chains of axial steps [first, last]; their inner points are line[first + 1 ..
    // last].
    int j = 0;
    while (j < m - 1) {
      if (!axial[j]) {
        ++j;
        continue;
      }
      const int first = j;
      while (j < m - 1 && axial[j]) ++j;
      const int last = j - 1;
      const int inner = last - first;
      if (inner < 1 || inner > max_chain) continue;
      // Stretched points lie between the ends: the range changes monotonically.
      bool monotonic = true;
      const float sign = points[line[last + 1]].p.norm() - points[line[first]].p.norm();
      for (int k = first; k <= last && monotonic; ++k) {
        const float dr = points[line[k + 1]].p.norm() - points[line[k]].p.norm();
        monotonic = dr * sign > 0.f;
      }
      if (!monotonic) continue;
      for (int k = first + 1; k <= last; ++k) {
        if (std::min(step_m[k - 1], step_m[k]) <= d) keep[line[k]] = 0;
      }
    }
  }
  const size_t removed = Compact(keep, &points);
  if (stats) stats->bleeding += removed;
}

PreprocessStats Preprocess(const PreprocessOptions& options, Scan* scan) {
  PreprocessStats stats;
  stats.input = scan->points.size();
  std::vector<uint8_t> keep(scan->points.size());
  for (size_t i = 0; i < scan->points.size(); ++i) {
    const Eigen::Vector3f& p = scan->points[i].p;
    keep[i] = p.allFinite() && !p.isZero(0.f);
  }
  stats.no_return = Compact(keep, &scan->points);
  RemoveNearAndFarPoints(options, scan, &stats);
  RemoveSunFlicker(options, scan, &stats);
  RemoveBoundaryBleeding(options, scan, &stats);
  stats.output = scan->points.size();
  return stats;
}

void Deskew(const Eigen::Isometry3d& T_body_lidar,
            const Eigen::Isometry3d& T_end_start,
            Scan* scan) {
  // Paper IV.C, the IMU/odometer increment with linear interpolation: T_end_t runs from
  // T_end_start (t = 0) to identity (t = duration), the rotation turning about its fixed axis at
  // a constant rate (slerp) and the translation lerped.
  FrameMotion motion;
  if (scan->duration_s > 0.0) {
    motion.t_s = {0.0, scan->duration_s};
    motion.T_end_t = {T_end_start, Eigen::Isometry3d::Identity()};
  }
  Deskew(T_body_lidar, motion, scan);
}

void Deskew(const Eigen::Isometry3d& T_body_lidar, const FrameMotion& motion, Scan* scan) {
  const Eigen::Matrix3d R_body_lidar = T_body_lidar.linear();
  const Eigen::Vector3d t_body_lidar = T_body_lidar.translation();
  const size_t n = std::min(motion.t_s.size(), motion.T_end_t.size());
  if (n < 2) {
    const Eigen::Isometry3d T =
        (n == 1 ? motion.T_end_t[0] : Eigen::Isometry3d::Identity()) * T_body_lidar;
    for (ScanPoint& point : scan->points) point.p = (T * point.p.cast<double>()).cast<float>();
    return;
  }
  // Each segment: its start pose, and the rotation and translation on to its end.
  struct Segment {
    double t0, rate;
    Eigen::Quaterniond q0;
    Eigen::Vector3d axis, p0, dp;
    double angle;
  };
  std::vector<Segment> segments(n - 1);
  for (size_t k = 0; k + 1 < n; ++k) {
    const Eigen::Isometry3d& a = motion.T_end_t[k];
    const Eigen::Isometry3d& b = motion.T_end_t[k + 1];
    const Eigen::AngleAxisd turn(a.linear().transpose() * b.linear());
    const double dt = motion.t_s[k + 1] - motion.t_s[k];
    segments[k] = {motion.t_s[k],
                   dt > 0.0 ? 1.0 / dt : 0.0,
                   Eigen::Quaterniond(a.linear()),
                   turn.axis(),
                   a.translation(),
                   b.translation() - a.translation(),
                   turn.angle()};
  }
  for (ScanPoint& point : scan->points) {
    // The segment holding the point's time; the first and last extend beyond the samples.
    const auto it = std::upper_bound(
        motion.t_s.begin() + 1, motion.t_s.begin() + (n - 1), static_cast<double>(point.time_s));
    const Segment& seg = segments[static_cast<size_t>(it - (motion.t_s.begin() + 1))];
    const double f = (point.time_s - seg.t0) * seg.rate;
    const double half = 0.5 * f * seg.angle;
    const double s = std::sin(half);
    const Eigen::Quaterniond q =
        seg.q0 *
        Eigen::Quaterniond(std::cos(half), s * seg.axis.x(), s * seg.axis.y(), s * seg.axis.z());
    const Eigen::Vector3d p_body = R_body_lidar * point.p.cast<double>() + t_body_lidar;
    point.p = (q * p_body + seg.p0 + f * seg.dp).cast<float>();
  }
}

}  // namespace raillomer
