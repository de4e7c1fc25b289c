#include "mapstore/chainage.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Geometry>

namespace raillomer::mapstore {
namespace {

double Roll(const Eigen::Quaterniond& q) {
  const Eigen::Matrix3d R = q.normalized().toRotationMatrix();
  return std::atan2(R(2, 1), R(2, 2));
}

double WrapAngle(double a) { return std::atan2(std::sin(a), std::cos(a)); }

}  // namespace

std::vector<CentrelinePoint> BuildCentreline(const std::vector<api::StreamPose>& poses,
                                             double spacing_m) {
  // The path: poses that make progress along the track.
  struct Node {
    Eigen::Vector3d p;
    double cant_m;
  };
  std::vector<Node> path;
  std::string zone;
  for (const api::StreamPose& pose : poses) {
    if (!pose.georeferenced || !pose.p.allFinite()) continue;
    if (zone.empty()) zone = pose.utm_zone;
    if (pose.utm_zone != zone) continue;
    const Node n{pose.p, kRailHeadSpacingM * std::sin(Roll(pose.q))};
    if (path.empty()) {
      path.push_back(n);
      continue;
    }
    const Eigen::Vector2d step = (n.p - path.back().p).head<2>();
    if (step.norm() < 0.5 * spacing_m) continue;
    if (path.size() >= 2) {
      const Eigen::Vector2d heading = (path.back().p - path[path.size() - 2].p).head<2>();
      if (step.dot(heading) <= 0.0) continue;  // reversing, or back over covered ground
    }
    path.push_back(n);
  }
  std::vector<CentrelinePoint> out;
  if (path.size() < 2) return out;
  // Resampled every spacing_m along the path.
  double along = 0.0, next = 0.0;
  for (size_t i = 1; i < path.size(); ++i) {
    const double length = (path[i].p - path[i - 1].p).norm();
    while (next <= along + length) {
      const double t = length > 0.0 ? (next - along) / length : 0.0;
      CentrelinePoint c;
      c.chainage_m = next;
      c.p = path[i - 1].p + t * (path[i].p - path[i - 1].p);
      c.cant_m = path[i - 1].cant_m + t * (path[i].cant_m - path[i - 1].cant_m);
      out.push_back(c);
      next += spacing_m;
    }
    along += length;
  }
  return out;
}

std::vector<TrackSample> TrackGeometry(const std::vector<CentrelinePoint>& c, double window_m) {
  std::vector<TrackSample> out(c.size());
  size_t lo = 0, hi = 0;
  for (size_t i = 0; i < c.size(); ++i) {
    out[i].point = c[i];
    while (c[i].chainage_m - c[lo].chainage_m > window_m) ++lo;
    while (hi + 1 < c.size() && c[hi + 1].chainage_m - c[i].chainage_m <= window_m) ++hi;
    if (hi <= lo) continue;
    const double ds = c[hi].chainage_m - c[lo].chainage_m;
    out[i].gradient = (c[hi].p.z() - c[lo].p.z()) / ds;
    if (lo < i && i < hi) {
      const Eigen::Vector2d a = (c[i].p - c[lo].p).head<2>(), b = (c[hi].p - c[i].p).head<2>();
      const double turn = WrapAngle(std::atan2(b.y(), b.x()) - std::atan2(a.y(), a.x()));
      // The heading turns by `turn` between the middles of the two halves.
      out[i].curvature_per_m = turn / (0.5 * ds);
    }
  }
  return out;
}

double ProjectChainage(const std::vector<CentrelinePoint>& c,
                       const Eigen::Vector2d& p,
                       double* distance_m) {
  double best = std::numeric_limits<double>::infinity(), chainage = 0.0;
  for (size_t i = 0; i + 1 < c.size(); ++i) {
    const Eigen::Vector2d a = c[i].p.head<2>(), b = c[i + 1].p.head<2>();
    const Eigen::Vector2d ab = b - a;
    const double t = std::clamp((p - a).dot(ab) / std::max(ab.squaredNorm(), 1e-12), 0.0, 1.0);
    const double d = (a + t * ab - p).norm();
    if (d < best) {
      best = d;
      chainage = c[i].chainage_m + t * (c[i + 1].chainage_m - c[i].chainage_m);
    }
  }
  if (c.size() == 1) {
    best = (c[0].p.head<2>() - p).norm();
    chainage = c[0].chainage_m;
  }
  if (distance_m) *distance_m = best;
  return chainage;
}

ChainageIndex::ChainageIndex(std::vector<CentrelinePoint> centreline, double cell_m)
    : c_(std::move(centreline)), cell_m_(cell_m) {
  for (size_t i = 0; i + 1 < c_.size(); ++i) {
    const Eigen::Vector2d a = c_[i].p.head<2>(), b = c_[i + 1].p.head<2>();
    const int64_t x0 = static_cast<int64_t>(std::floor(std::min(a.x(), b.x()) / cell_m_));
    const int64_t x1 = static_cast<int64_t>(std::floor(std::max(a.x(), b.x()) / cell_m_));
    const int64_t y0 = static_cast<int64_t>(std::floor(std::min(a.y(), b.y()) / cell_m_));
    const int64_t y1 = static_cast<int64_t>(std::floor(std::max(a.y(), b.y()) / cell_m_));
    for (int64_t x = x0; x <= x1; ++x)
      for (int64_t y = y0; y <= y1; ++y) cells_[Key(x, y)].push_back(static_cast<uint32_t>(i));
  }
}

bool ChainageIndex::Project(const Eigen::Vector2d& p,
                            double max_off_m,
                            double* chainage_m,
                            double* off_m) const {
  const int64_t cx = static_cast<int64_t>(std::floor(p.x() / cell_m_));
  const int64_t cy = static_cast<int64_t>(std::floor(p.y() / cell_m_));
  const int64_t reach = static_cast<int64_t>(std::ceil(max_off_m / cell_m_));
  double best = std::numeric_limits<double>::infinity();
  for (int64_t x = cx - reach; x <= cx + reach; ++x) {
    for (int64_t y = cy - reach; y <= cy + reach; ++y) {
      auto it = cells_.find(Key(x, y));
      if (it == cells_.end()) continue;
      for (uint32_t i : it->second) {
        const Eigen::Vector2d a = c_[i].p.head<2>(), ab = c_[i + 1].p.head<2>() - a;
        const double t = std::clamp((p - a).dot(ab) / std::max(ab.squaredNorm(), 1e-12), 0.0, 1.0);
        const double d = (a + t * ab - p).norm();
        if (d < best) {
          best = d;
          *chainage_m = c_[i].chainage_m + t * (c_[i + 1].chainage_m - c_[i].chainage_m);
        }
      }
    }
  }
  if (off_m) *off_m = best;
  return best <= max_off_m;
}

}  // namespace raillomer::mapstore
