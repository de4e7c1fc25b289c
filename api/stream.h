#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "api/trajectory.h"

namespace raillomer::api {

/// A pose as the estimator streams it, once it is final.
struct StreamPose {
  /// 0, 1, 2, ... over the run's poses (submaps count apart): the server stores each
  /// sequence once, so a message sent again is a duplicate.
  uint64_t sequence = 0;
  int64_t stamp_ns = 0;
  bool georeferenced = false;  ///< false: the estimator's local odometry frame
  std::string utm_zone;        ///< "50N" when georeferenced
  /// Body position: UTM easting, northing, ellipsoidal height when georeferenced.
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();  ///< body to world (UTM grid axes)
};

/// A submap: the deskewed clouds of consecutive keyframes in one frame. Positions are float
/// offsets from a double-precision origin (UTM coordinates never go into a float).
struct Submap {
  uint64_t sequence = 0;  ///< 0, 1, 2, ... over the run's submaps (the estimator: its index)
  uint32_t index = 0;     ///< 0, 1, 2, ... within the run
  int64_t first_stamp_ns = 0, last_stamp_ns = 0;
  bool georeferenced = false;
  std::string utm_zone;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  ///< UTM when georeferenced
  std::vector<Eigen::Vector3f> points;               ///< offsets from origin, world axes
  std::vector<float> intensities;                    ///< one per point
  std::vector<StampedPose> keyframes;                ///< body poses, absolute (double)
  /// Provisional submaps: which placement of the GNSS fusion their keyframes come from
  /// (1, 2, ...; 0: none given). Submaps of one placement fit one another; where the fusion's
  /// graph moves, a new placement starts and its submaps can lie a little off the older ones.
  uint32_t placement = 0;
};

/// Receives what the estimator produces, in order: each pose as it becomes final and each
/// submap as it completes. The server's ingest client implements it.
class StreamSink {
 public:
  virtual ~StreamSink() = default;
  virtual void OnPose(const StreamPose& pose) = 0;
  virtual void OnSubmap(const Submap& submap) = 0;
  /// Output ahead of the final one where the GNSS fusion holds poses back (a run's start, an
  /// outage): where they lie for now, replaced by the final poses and submaps as they come.
  /// Ignored unless a sink has a use for it.
  virtual void OnProvisionalPose(const StreamPose&) {}
  virtual void OnProvisionalSubmap(const Submap&) {}
};

/// A submap as a binary PCD file (fields x y z intensity, float offsets from the origin), with
/// the origin, zone, sequence and stamps in `# raillomer` header comments; PCL and CloudCompare
/// read it as a local cloud.
std::string EncodeSubmapPcd(const Submap& submap);
/// Parses EncodeSubmapPcd's output; false with a message naming what is wrong.
bool DecodeSubmapPcd(const std::string& bytes, Submap* submap, std::string* error);
/// Reads and decodes one submap file; false with a message naming the file.
bool ReadSubmapFile(const std::string& path, Submap* submap, std::string* error);

}  // namespace raillomer::api
