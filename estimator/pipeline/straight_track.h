#pragma once

#include <deque>
#include <string>
#include <utility>

namespace raillomer {

/// A train on straight track does not turn: its car body's heading is the track's, give or
/// take a hunting sway of tenths of a milliradian about it. The heading hold pins every state on
/// a straight stretch to the heading it had when the straight was recognised, so neither a
/// registration's small steady pull nor a gyro bias error can turn it there, and the yaw gyro
/// bias becomes observable (the gyro's mean yaw rate on a straight is its bias).
///
/// A stretch is straight when the gyro's raw heading (integrated about the world vertical, bias
/// and all) has followed a line for `detect_s`: within `tolerance_rad` of it, turning at most
/// `max_rate_rps` once the estimated bias is taken off (what is left is a bias error). On the
/// straight the line is fitted to up to a minute of it, and the newest second must lie on its
/// extrapolation: a transition's heading grows with the square of the distance into it and
/// shows within a few tens of metres. The raw heading, not the bias-corrected one, because the
/// hold itself moves the bias estimate, which would bend a corrected heading's line.
struct StraightTrackOptions {
  /// Noise of a state's heading about the straight's (hunting sway); 0 switches the hold off.
  double sigma_rad = 1.0e-3;
  double detect_s = 5.0;          ///< the gyro's heading history that must be straight
  double tolerance_rad = 1.0e-3;  ///< its largest distance from the fitted line
  double max_rate_rps = 3.0e-4;   ///< the fitted line's largest slope
  /// False with a message naming the bad field.
  bool IsValid(std::string* error) const;
};

/// Recognises straight track from the gyro's heading, one frame at a time.
class StraightTrackDetector {
 public:
  explicit StraightTrackDetector(const StraightTrackOptions& options) : options_(options) {}

  /// The gyro's raw heading change (rad, about the world vertical, bias not taken off) from
  /// the previous call to time t_s, and the estimated bias about the vertical (rad/s). Times
  /// must increase.
  void Add(double t_s, double raw_heading_change_rad, double bias_rps);
  /// Forgets the history (a re-levelled world, a gap in the data).
  void Reset();

  /// The last `detect_s` of heading lie on a line within the tolerance.
  bool straight() const { return straight_; }
  /// The last Add() began a straight stretch, or ended one (the train began to turn).
  bool started() const { return started_; }
  bool ended() const { return ended_; }
  /// The fitted line's slope less the bias at the last Add() (rad/s).
  double rate_rps() const { return rate_; }
  /// How far the gyro's heading at time t_s (a time given to Add(), within the span) lay from
  /// the fitted line: the car body's sway about the track's heading, or 0 when t_s is not in
  /// the span.
  double DeviationAt(double t_s) const;

 private:
  StraightTrackOptions options_;
  std::deque<std::pair<double, double>> samples_;  ///< (t, integrated heading)
  double heading_ = 0.0;
  bool straight_ = false, started_ = false, ended_ = false;
  double rate_ = 0.0;
  double fit_t_ = 0.0, fit_h_ = 0.0, fit_slope_ = 0.0;  ///< the line: h = fit_h + slope (t - fit_t)
};

}  // namespace raillomer
