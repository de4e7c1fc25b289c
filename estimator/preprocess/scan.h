#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace raillomer {

/// One LiDAR return through preprocessing and feature extraction.
///
/// Until deskewing, `p` is in the sensor (LiDAR) frame; after Deskew() it is in the body frame
/// at the frame's reference time (the frame end). `range_m` and `line` stay those of the sensor.
struct ScanPoint {
  Eigen::Vector3f p = Eigen::Vector3f::Zero();
  float time_s = 0.f;     ///< since the frame's first point (offset_time), seconds
  float range_m = 0.f;    ///< distance from the sensor origin when measured
  float intensity = 0.f;  ///< reflectivity, 0..255
  uint8_t line = 0;       ///< laser line (Livox Horizon: 0..5)
};

/// One LiDAR frame's points in acquisition order (time ascending within each line).
struct Scan {
  int lidar_index = 0;      ///< position of the LiDAR in the rig config
  double start_s = 0.0;     ///< absolute time of the first point (the frame's timebase)
  double duration_s = 0.1;  ///< nominal frame period
  std::vector<ScanPoint> points;
};

/// Feature points of one LiDAR frame, in the body frame at the frame's reference time.
struct FeatureSet {
  std::vector<Eigen::Vector3f> edges;   ///< high curvature (LOAM "sharp")
  std::vector<Eigen::Vector3f> planes;  ///< low curvature (LOAM "flat")
};

/// Positions of the points of each laser line in the scan, in acquisition order.
inline std::vector<std::vector<uint32_t>> PositionsByLine(const std::vector<ScanPoint>& points) {
  std::vector<size_t> counts;
  for (const ScanPoint& p : points) {
    if (p.line >= counts.size()) counts.resize(p.line + 1, 0);
    ++counts[p.line];
  }
  std::vector<std::vector<uint32_t>> lines(counts.size());
  for (size_t l = 0; l < counts.size(); ++l) lines[l].reserve(counts[l]);
  for (size_t i = 0; i < points.size(); ++i)
    lines[points[i].line].push_back(static_cast<uint32_t>(i));
  return lines;
}

}  // namespace raillomer
