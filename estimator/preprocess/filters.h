#pragma once

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "estimator/io/sensor_messages.h"
#include "estimator/preprocess/scan.h"

namespace raillomer {

/// Options of the per-LiDAR preprocessing (paper IV.C, Fig. 4-5).
struct PreprocessOptions {
  double min_range_m = 2.0;    ///< closer points are dropped (axial error, vehicle roof)
  double max_range_m = 200.0;  ///< farther points are dropped
  /// Sun flicker: occupancy grid (sensor frame); a cell with fewer points loses them all.
  double flicker_cell_size_m = 1.0;
  int flicker_min_points_per_cell = 3;
  /// Cells grow with range in half-octave shells so that each subtends about the same angle: the
  /// edge is flicker_cell_size_m at this range (0: one fixed-size grid, as in the paper).
  double flicker_reference_range_m = 35.0;
  /// Points in sparse cells at least this bright stay (flicker returns are dark; thin wires are
  /// bright but sparse). The default, above the 0..255 scale, exempts none.
  double flicker_exempt_intensity = 256.0;
  /// Boundary bleeding: the hidden sector around each beam axis (Fig. 5).
  double hidden_sector_angle_deg = 10.0;  ///< phi
  double hidden_sector_radius_m = 20.0;   ///< d
  /// Longer chains of points each in its neighbour's sector are a surface seen at grazing
  /// incidence, not bleeding, and are kept.
  int hidden_sector_max_chain = 3;
  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// How many points each stage removed.
struct PreprocessStats {
  size_t input = 0;
  size_t no_return = 0;  ///< zero points (no echo)
  size_t near_or_far = 0;
  size_t flicker = 0;
  size_t bleeding = 0;
  size_t output = 0;
};

/// A Livox frame as a Scan in the sensor frame; zero (no-return) points are dropped.
Scan ScanFromLidarFrame(const io::LidarFrame& frame, int lidar_index, double duration_s);
/// As above; `stats` (if given) gets the frame's point count as `input` and its zero points as
/// `no_return`, to be merged with Preprocess()'s counts.
Scan ScanFromLidarFrame(const io::LidarFrame& frame,
                        int lidar_index,
                        double duration_s,
                        PreprocessStats* stats);

/// Drops points closer than min_range_m or farther than max_range_m.
void RemoveNearAndFarPoints(const PreprocessOptions& options, Scan* scan, PreprocessStats* stats);

/// Drops every point of an occupancy-grid cell holding fewer than flicker_min_points_per_cell.
void RemoveSunFlicker(const PreprocessOptions& options, Scan* scan, PreprocessStats* stats);

/// Drops points inside the hidden sector of a neighbouring beam on the same laser line: a point
/// whose offset from its neighbour lies within hidden_sector_angle_deg of the neighbour's beam
/// axis and within hidden_sector_radius_m is a mixed (bleeding) return. Only points stretched
/// between both neighbours along the beam go (chains of up to hidden_sector_max_chain points):
/// the two real ends of a clean depth jump and long grazing-incidence runs stay.
void RemoveBoundaryBleeding(const PreprocessOptions& options, Scan* scan, PreprocessStats* stats);

/// All of the above in order (sensor frame: before Deskew), after dropping zero or non-finite
/// points (counted as no_return).
PreprocessStats Preprocess(const PreprocessOptions& options, Scan* scan);

/// Moves every point to the body frame at the frame end (start_s + duration_s).
///
/// T_end_start is the body motion over the frame (body at the end <- body at the start), from
/// the IMU/odometer increment; a point at time t is moved by the pose interpolated linearly
/// (slerp and lerp) between identity at the end and T_end_start at the start (paper IV.C). Points
/// stamped after duration_s extrapolate the same motion; with duration_s <= 0 only the extrinsic
/// is applied. range_m, line and time_s keep their values.
void Deskew(const Eigen::Isometry3d& T_body_lidar,
            const Eigen::Isometry3d& T_end_start,
            Scan* scan);

/// The body's motion over a frame, sampled: T_end_t (the body at the frame end <- the body at
/// time t) at times t_s (seconds from the frame start, strictly increasing).
struct FrameMotion {
  std::vector<double> t_s;
  std::vector<Eigen::Isometry3d> T_end_t;
};

/// As above, with the motion known finely (the gyro's rotation between the frame's ends: the
/// car body's pitch and roll on its suspension within a frame, which a single interpolation
/// from end to end misses). Between samples the pose is interpolated (slerp and lerp); before
/// the first and after the last it is extrapolated from the nearest pair. With one sample only
/// that pose is applied; with none, only the extrinsic.
void Deskew(const Eigen::Isometry3d& T_body_lidar, const FrameMotion& motion, Scan* scan);

}  // namespace raillomer
