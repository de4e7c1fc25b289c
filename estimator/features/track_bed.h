#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

namespace raillomer {

struct RailExtraction;

/// Options of the track-bed match: the sleepers as a measure of distance along the track.
/// Between the rails the down LiDAR sees a comb: sleeper tops and the faces of the sleepers
/// that the ballast in each gap hides behind (sleepers every 0.6 m stand 0.19 m above the
/// ballast; seen from 4 m up at under 25 deg the gap is in the shadow of the sleeper in front).
/// Matched against the same comb seen in the frames before, it gives the distance travelled
/// without the odometer's wheel size or creep.
struct TrackBedOptions {
  /// Standard deviation of one frame's along-track measurement; 0 switches the match off.
  double sigma_m = 0.01;
  double min_forward_m = 6.0;  ///< the bed ahead of the body origin, along body x
  double max_forward_m = 22.0;
  double half_width_m = 0.55;  ///< either side of the track centre (rail feet are at 0.68 m)
  double min_depth_m = 0.1;    ///< below the rail plane: the rails themselves are above this
  double max_depth_m = 0.55;
  double bin_m = 0.01;         ///< along the track
  double depth_bin_m = 0.02;   ///< below the rail plane
  double blur_m = 0.015;       ///< Gaussian smoothing of the reference along the track
  double max_search_m = 0.12;  ///< around the predicted displacement
  int history_frames = 10;     ///< earlier frames whose bed points form the reference
  int min_points = 150;        ///< in the frame and in the reference over their overlap
  /// The best shift must raise the mean log-density this much above the search's mean: a bed
  /// without sleepers (snow, slab track, a level crossing) gives nothing.
  double min_gain = 0.15;
  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// The down LiDAR's points on the track bed between the rails (body frame): within
/// half_width_m of the centre line of the extracted rails, min/max_depth_m below their plane,
/// min/max_forward_m ahead. Empty when the rails were not extracted.
std::vector<Eigen::Vector3f> SelectTrackBed(const TrackBedOptions& options,
                                            const RailExtraction& rails,
                                            const std::vector<Eigen::Vector3f>& points_body);

struct TrackBedShift {
  bool ok = false;
  double shift_m = 0.0;  ///< move the current points this far along x to fit the reference
  double sigma_m = 0.0;  ///< from the curvature of the score at the optimum (one frame)
  double gain = 0.0;     ///< mean log-density at the optimum above the search's mean
  int points = 0;        ///< current points within the reference's span
  std::string failure;   ///< why not ok
};

/// Finds the shift along x (of the reference frame) that best lays `current` onto the comb of
/// `reference`, both in the reference frame (the current points moved there by the predicted
/// motion), depths taken below the plane n . x + d = 0. No measurement (ok false, `failure`
/// says why) when either holds too few points, the best shift is at the search's edge, or the
/// score is too flat (no sleepers).
TrackBedShift EstimateTrackBedShift(const TrackBedOptions& options,
                                    const std::vector<Eigen::Vector3d>& reference,
                                    const std::vector<Eigen::Vector3d>& current,
                                    const Eigen::Vector3d& plane_normal,
                                    double plane_distance);

}  // namespace raillomer
