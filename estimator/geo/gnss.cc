#include "estimator/geo/gnss.h"

#include <algorithm>
#include <cmath>

namespace raillomer::geo {

std::string CheckFix(const io::GnssFix& fix,
                     const UtmZone& zone,
                     const FixCheckOptions& options,
                     Eigen::Vector3d* utm) {
  if (fix.status < 0)
    return "the receiver reports no fix (status " + std::to_string(fix.status) + ")";
  if (!std::isfinite(fix.latitude_deg) || !std::isfinite(fix.longitude_deg) ||
      !std::isfinite(fix.altitude_m)) {
    return "NaN or infinite coordinates";
  }
  if (fix.latitude_deg == 0.0 && fix.longitude_deg == 0.0) return "latitude and longitude both 0";
  if (std::abs(fix.latitude_deg) > 84.0) return "latitude outside the UTM band (|lat| > 84 deg)";
  if (std::abs(fix.longitude_deg) > 180.0) return "longitude outside [-180, 180] deg";
  if (fix.altitude_m < options.min_altitude_m || fix.altitude_m > options.max_altitude_m) {
    return "absurd height " + std::to_string(fix.altitude_m) + " m";
  }
  if ((fix.latitude_deg >= 0.0) != zone.north) {
    return std::string("in the ") + (zone.north ? "southern" : "northern") +
           " hemisphere, the run's zone is " + zone.Name();
  }
  // A line may run a little past its zone's edge (3 deg from the central meridian), but
  // GeographicLib refuses positions more than 9 deg off it: such a fix is in another zone.
  const double central_deg = -183.0 + 6.0 * zone.zone;
  const double off_deg = std::remainder(fix.longitude_deg - central_deg, 360.0);
  if (std::abs(off_deg) > 9.0) return "outside UTM zone " + zone.Name();
  const Eigen::Vector2d en = GeographicToUtm(zone, fix.latitude_deg, fix.longitude_deg);
  *utm = Eigen::Vector3d(en.x(), en.y(), fix.altitude_m);
  return "";
}

Eigen::Isometry3d FourDof::Isometry() const {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = t;
  return T;
}

Eigen::Vector3d FourDof::Apply(const Eigen::Vector3d& p) const {
  const double c = std::cos(yaw_rad), s = std::sin(yaw_rad);
  return Eigen::Vector3d(c * p.x() - s * p.y(), s * p.x() + c * p.y(), p.z()) + t;
}

FourDof FitFourDof(const std::vector<Eigen::Vector3d>& from,
                   const std::vector<Eigen::Vector3d>& to,
                   const std::vector<double>& weights,
                   bool* degenerate) {
  FourDof result;
  const size_t n = std::min(from.size(), to.size());
  auto weight = [&](size_t i) { return weights.empty() ? 1.0 : weights[i]; };
  double sum_w = 0.0;
  Eigen::Vector3d mean_from = Eigen::Vector3d::Zero(), mean_to = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    sum_w += weight(i);
    mean_from += weight(i) * from[i];
    mean_to += weight(i) * to[i];
  }
  if (!(sum_w > 0.0)) {
    if (degenerate) *degenerate = true;
    return result;
  }
  mean_from /= sum_w;
  mean_to /= sum_w;
  // The 2D Umeyama yaw: atan2(sum w (a x b), sum w (a . b)) on the centred xy.
  double dot = 0.0, cross = 0.0, scale = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector2d a = (from[i] - mean_from).head<2>();
    const Eigen::Vector2d b = (to[i] - mean_to).head<2>();
    dot += weight(i) * a.dot(b);
    cross += weight(i) * (a.x() * b.y() - a.y() * b.x());
    scale += weight(i) * a.norm() * b.norm();
  }
  const bool flat = !(scale > 0.0) || std::hypot(dot, cross) <= 1e-12 * scale;
  if (degenerate) *degenerate = flat;
  result.yaw_rad = flat ? 0.0 : std::atan2(cross, dot);
  result.t = mean_to - FourDof{result.yaw_rad, Eigen::Vector3d::Zero()}.Apply(mean_from);
  return result;
}

namespace {

/// Horizontal span (the bounding box's diagonal) of the first n positions; 0 for none.
double HorizontalExtent(const std::vector<Eigen::Vector3d>& p, size_t n) {
  Eigen::Vector2d lo(1e300, 1e300), hi(-1e300, -1e300);
  for (size_t i = 0; i < n; ++i) {
    lo = lo.cwiseMin(p[i].head<2>());
    hi = hi.cwiseMax(p[i].head<2>());
  }
  return n > 0 ? (hi - lo).norm() : 0.0;
}

/// Why n pairs spanning extent_m are too few or too short to align on; empty if they will do.
std::string Insufficient(size_t n, double extent_m, const GnssAlignmentOptions& options) {
  if (static_cast<int>(n) < options.min_inliers)
    return std::to_string(n) + " fixes, " + std::to_string(options.min_inliers) + " needed";
  if (extent_m < options.min_extent_m) {
    return "the train has moved " + std::to_string(static_cast<int>(extent_m)) + " m of the " +
           std::to_string(static_cast<int>(options.min_extent_m)) + " m needed";
  }
  return "";
}

/// Weights each pair 1 within one round's gate of the fit's horizontal residuals, else 0.
void GateRound(const FourDof& fit,
               const std::vector<Eigen::Vector3d>& p_odom,
               const std::vector<Eigen::Vector3d>& p_enu,
               double min_gate_m,
               bool last,
               std::vector<double>* w) {
  const size_t n = w->size();
  std::vector<double> residuals(n);
  for (size_t i = 0; i < n; ++i) residuals[i] = (fit.Apply(p_odom[i]) - p_enu[i]).head<2>().norm();
  std::vector<double> sorted = residuals;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(n / 2), sorted.end());
  const double median = sorted[n / 2];
  const double gate = last ? min_gate_m : std::max(min_gate_m, 3.0 * median);
  for (size_t i = 0; i < n; ++i) (*w)[i] = residuals[i] <= gate ? 1.0 : 0.0;
}

/// Fits and gates `rounds` times; false when a fit's heading is not determined.
bool GateOutliers(const std::vector<Eigen::Vector3d>& p_odom,
                  const std::vector<Eigen::Vector3d>& p_enu,
                  const GnssAlignmentOptions& options,
                  std::vector<double>* w) {
  for (int round = 0; round < options.rounds; ++round) {
    bool degenerate = false;
    const FourDof fit = FitFourDof(p_odom, p_enu, *w, &degenerate);
    if (degenerate) return false;
    GateRound(fit, p_odom, p_enu, options.inlier_gate_m, round + 1 == options.rounds, w);
  }
  return true;
}

/// Counts the inliers (weight > 0) and outliers, and the inliers' horizontal RMS residual.
void Score(const FourDof& fit,
           const std::vector<Eigen::Vector3d>& p_odom,
           const std::vector<Eigen::Vector3d>& p_enu,
           const std::vector<double>& w,
           GnssAlignment* out) {
  double sum_sq = 0.0;
  for (size_t i = 0; i < w.size(); ++i) {
    if (w[i] > 0.0) {
      ++out->inliers;
      sum_sq += (fit.Apply(p_odom[i]) - p_enu[i]).head<2>().squaredNorm();
    } else {
      ++out->outliers;
    }
  }
  out->rms_m = out->inliers > 0 ? std::sqrt(sum_sq / out->inliers) : 0.0;
}

}  // namespace

GnssAlignment AlignToGnss(const std::vector<Eigen::Vector3d>& p_odom,
                          const std::vector<Eigen::Vector3d>& p_enu,
                          const GnssAlignmentOptions& options) {
  GnssAlignment out;
  const size_t n = std::min(p_odom.size(), p_enu.size());
  out.extent_m = HorizontalExtent(p_odom, n);
  out.reason = Insufficient(n, out.extent_m, options);
  if (!out.reason.empty()) return out;
  // First fit on all pairs, then on those within the gate: a gate that starts at the median
  // residual's scale keeps a 30 m multipath jump from dragging the first fit far enough to
  // make the good pairs look bad.
  std::vector<double> w(n, 1.0);
  if (!GateOutliers(p_odom, p_enu, options, &w)) {
    out.reason = "the odometry positions do not fix a heading";
    return out;
  }
  bool degenerate = false;
  const FourDof fit = FitFourDof(p_odom, p_enu, w, &degenerate);
  Score(fit, p_odom, p_enu, w, &out);
  out.T_enu_odom = fit;
  if (degenerate || out.inliers < options.min_inliers) {
    out.reason = std::to_string(out.inliers) + " fixes agree with each other within " +
                 std::to_string(options.inlier_gate_m) + " m, " +
                 std::to_string(options.min_inliers) + " needed";
    return out;
  }
  out.ok = true;
  return out;
}

}  // namespace raillomer::geo
