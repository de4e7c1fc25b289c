#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "estimator/geo/utm.h"
#include "estimator/io/sensor_messages.h"

namespace raillomer::geo {

/// Bounds a GNSS fix must meet before it is used.
struct FixCheckOptions {
  double min_altitude_m = -500.0;  ///< below the Dead Sea shore: absurd
  double max_altitude_m = 9000.0;  ///< above any railway
};

/// Checks a NavSatFix against the run's UTM zone and converts it. Returns an empty string and
/// sets `utm` (easting, northing, ellipsoidal height) when the fix is usable; otherwise a short
/// reason, naming what is wrong: no fix status, NaN or infinite coordinates, (0, 0), a latitude
/// or longitude out of range, an absurd height, the other hemisphere, or a position more than 9 deg
/// of longitude from the zone's central meridian (3 deg beyond its edge, as far as UTM
/// conversion goes).
std::string CheckFix(const io::GnssFix& fix,
                     const UtmZone& zone,
                     const FixCheckOptions& options,
                     Eigen::Vector3d* utm);

/// A 4-DoF rigid transform (yaw about z and a 3D translation): p_to = R_z(yaw) p_from + t.
struct FourDof {
  double yaw_rad = 0.0;
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  Eigen::Isometry3d Isometry() const;
  Eigen::Vector3d Apply(const Eigen::Vector3d& p) const;
};

/// Least-squares 4-DoF fit of `from` onto `to` (same length, weights >= 0 or empty for all 1):
/// the 2D Umeyama yaw on the weighted-centred xy (paper eq. 5 over all pairs at once) and the
/// weighted mean offset (eq. 6). `degenerate` is set when the yaw is not determined (all
/// points at one place).
FourDof FitFourDof(const std::vector<Eigen::Vector3d>& from,
                   const std::vector<Eigen::Vector3d>& to,
                   const std::vector<double>& weights,
                   bool* degenerate);

/// Options of the robust GNSS alignment.
struct GnssAlignmentOptions {
  double min_extent_m = 100.0;  ///< horizontal span of the odometry positions needed
  int min_inliers = 10;
  double inlier_gate_m = 3.0;  ///< a pair whose horizontal residual exceeds this is an outlier
  int rounds = 4;
};

/// The result of AlignToGnss.
struct GnssAlignment {
  bool ok = false;
  FourDof T_enu_odom;  ///< odometry frame -> local ENU (UTM minus the origin)
  int inliers = 0, outliers = 0;
  double rms_m = 0.0;     ///< horizontal RMS residual of the inliers
  double extent_m = 0.0;  ///< horizontal span of the odometry positions
  std::string reason;     ///< why not ok
};

/// Paper eq. (3-6): aligns odometry antenna positions to GNSS positions (local ENU) in 4-DoF,
/// dropping multipath outliers by re-fitting on the pairs within the gate.
GnssAlignment AlignToGnss(const std::vector<Eigen::Vector3d>& p_odom,
                          const std::vector<Eigen::Vector3d>& p_enu,
                          const GnssAlignmentOptions& options);

}  // namespace raillomer::geo
