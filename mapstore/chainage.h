#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "api/stream.h"

namespace raillomer::mapstore {

/// A point of a line's centreline: chainage (metres along the line from the reference run's
/// start), position (UTM) and cant (the height of the outer rail over the inner, m).
struct CentrelinePoint {
  double chainage_m = 0.0;
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  double cant_m = 0.0;
};

/// A centreline point with the track geometry around it.
struct TrackSample {
  CentrelinePoint point;
  double curvature_per_m = 0.0;  ///< signed: positive turning left (1 / radius)
  double gradient = 0.0;         ///< rise over run (per mille / 1000)
};

/// The distance between the rail heads' centres: cant = this x sin(roll).
constexpr double kRailHeadSpacingM = 1.5;

/// The centreline a run's poses trace: georeferenced poses of its first zone, in sequence
/// order, kept only while they make progress along the track (a train reversing over ground it
/// has covered adds nothing), resampled every `spacing_m` along the path. The body rides above
/// the track centre, so the centreline is the body's path; cant comes from its roll.
std::vector<CentrelinePoint> BuildCentreline(const std::vector<api::StreamPose>& poses,
                                             double spacing_m = 1.0);

/// Curvature and gradient at each point, from the centreline `window_m` behind and ahead (the
/// ends use what there is).
std::vector<TrackSample> TrackGeometry(const std::vector<CentrelinePoint>& centreline,
                                       double window_m = 10.0);

/// The chainage of the centreline point nearest to `p` (horizontal), by projection onto the
/// nearest segment; `distance_m` (if given) gets how far off the line `p` is.
double ProjectChainage(const std::vector<CentrelinePoint>& centreline,
                       const Eigen::Vector2d& p,
                       double* distance_m = nullptr);

/// ProjectChainage for many points: the centreline's segments indexed on a grid.
class ChainageIndex {
 public:
  explicit ChainageIndex(std::vector<CentrelinePoint> centreline, double cell_m = 25.0);
  /// The chainage of the nearest point of the centreline within `max_off_m` (horizontal);
  /// false if there is none that near.
  bool Project(const Eigen::Vector2d& p, double max_off_m, double* chainage_m, double* off_m) const;

 private:
  uint64_t Key(int64_t x, int64_t y) const {
    return (static_cast<uint64_t>(x) << 32) ^ static_cast<uint32_t>(y);
  }
  std::vector<CentrelinePoint> c_;
  double cell_m_;
  std::unordered_map<uint64_t, std::vector<uint32_t>> cells_;  ///< segment i: c_[i] to c_[i+1]
};

}  // namespace raillomer::mapstore
