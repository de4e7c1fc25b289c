#pragma once

#include <cstdint>
#include <future>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "api/stream.h"
#include "estimator/mapping/submap_archive.h"
#include "estimator/mapping/submap_registration.h"

namespace raillomer {

/// Options of the two-stage submap mapping (paper IV.E).
struct SubmapOptions {
  int keyframes = 10;    ///< keyframes per submap
  double voxel_m = 0.1;  ///< one point (the centroid) per voxel; 0 keeps every point
  /// Only points within this range of their keyframe's body go into the submap (0: all). A
  /// Livox point's direction is good to 0.05 deg (0.9 mrad: 4.4 cm at 50 m, 15 cm at 170 m),
  /// and the submaps' headings, GNSS-corrected one by one, differ by up to 2 mrad over a few
  /// submaps; a wall 170 m ahead came out 54 cm thick over eight submaps
  /// (rich_low_yard_b seed 2). The train passes everything within 50 m of the line (the
  /// structure gauge, masts and vegetation clearance lie within 7 m) close enough to map it.
  double max_range_m = 50.0;
  /// Within a submap the keyframes' positions lose the sideways slip their steps share against
  /// their headings (WithoutSideSlip): the wheels roll along the rails, but the odometry's
  /// emitted positions can slide across the track where the LiDAR pulls the sliding window
  /// sideways a few millimetres a frame: 1.2-1.6 mrad for 5 s in poor_high_open_a's canted
  /// curve (GNSS off; the truth's within 0.2 mrad), and rail heads seen from two submaps came
  /// out 3.4 cm apart (docs/notebook/estimator-results.md: the sideways slip). Each step
  /// keeps the rest of its sideways part, the LiDAR's view of where the frame is: taking every
  /// step's sideways part out put the heading's own errors into the positions (imu_loss's rail
  /// heads 1.4 -> 2.3 cm). The body's swing as the cant rolls it about the rail (6 cm/s at 4 m
  /// in a transition) is no slip, hence the steps are the wheels'.
  bool remove_side_slip = true;
  /// ...and a step's sideways part beyond the shared slip goes too when above this (m): where
  /// the window jumps across as it takes a correction (long_20km at 558 s: 9 cm in one frame as
  /// a mast came into view). A car body sways by millimetres.
  double side_slip_max_jump_m = 0.02;
  /// The wheels (odometer) in the body frame, for remove_side_slip; the estimator sets the rig's.
  Eigen::Vector3d p_body_odometer = Eigen::Vector3d::Zero();
  /// Stage 1, scan-to-submap (paper: when the scan-to-map iterations hit their limit): a
  /// keyframe whose odometry solve hit its iteration limit is registered by ICP onto the
  /// submap built so far (about 0.3 s each), from its odometry pose and, if that fails too,
  /// from its GNSS pose.
  bool icp = true;
  IcpOptions icp_options;
  double icp_target_voxel_m = 0.2;
  /// Mean squared match distance (within icp_options.max_correspondence_m) to accept a result;
  /// a keyframe's new ground beyond the submap so far counts too (about 0.04 m^2 when right).
  double icp_max_fitness_m2 = 0.1;
  /// A result further than this from its guess is not trusted (m, deg).
  double icp_max_correction_m = 0.3;
  double icp_max_correction_deg = 1.0;
  /// Stage 2, submap-to-submap. A georeferenced submap is placed at the previous submap's
  /// position plus the odometry's motion since (turned into the world by the GNSS correction,
  /// its scale error taken out), with its GNSS-corrected orientation. If that lies more than
  /// `chain_reset_m` from its GNSS pose across the track, or twice that along it (a GNSS
  /// outage ended, or the alignment was re-solved), GNSS places it horizontally instead. NDT then
  /// registers it onto every earlier submap it overlaps: the previous ones and, where the train
  /// runs the same track again, those of the earlier pass (along the track only where that is
  /// observable); last it moves `gnss_pull` of the way towards its GNSS pose horizontally, so the
  /// chain follows GNSS without a large step at any seam.
  double gnss_pull = 0.05;
  /// The same pull in height; 0 by default. A height step at a seam shows as a step in the rail
  /// heads that both submaps see: 1 % of a single-point receiver's 2 m height error was 2 cm at
  /// every seam.
  double gnss_pull_vertical = 0.0;
  /// Instead the chain's height follows GNSS through its slope: the chain is tilted (its path
  /// and its orientation together, so each submap stays rigid and consecutive ones meet) by a
  /// critically damped loop on the anchor's height below its GNSS height, with this natural
  /// length (m). The tilt changes by hundredths of a milliradian from one submap to the next;
  /// an odometry that climbs too steeply is levelled out over a few kilometres. 0 leaves the
  /// height to the odometry (and gnss_pull_vertical).
  double gnss_height_length_m = 2000.0;
  /// The chain follows GNSS sideways the same way, through its heading: a critically damped
  /// loop on the anchor's offset to the right of its GNSS position turns the chain (path and
  /// orientation together) with this natural length (m), and gnss_pull then acts along the
  /// track only. A sideways pull moved each submap by a share of the GNSS error at its seam:
  /// 2-5 cm between submaps that see the same wall, a third of reverse_running's plane spread.
  /// 0 leaves the sideways correction to gnss_pull.
  double gnss_heading_length_m = 1000.0;
  /// The heading loop's angle turns by at most this per metre of path: faster than the height
  /// loop's, since the chain strays sideways by the GNSS graph's heading error and is torn
  /// back to GNSS (a chain reset) beyond chain_reset_m.
  double gnss_max_turn_rate_rad_per_m = 1e-5;
  /// With the heading loop the pull can still act sideways on the gap beyond 3/4 of
  /// chain_reset_m, taking this share of that excess each submap, so that where the GNSS
  /// graph's heading is off by more than the loop turns the chain comes back in centimetre
  /// steps instead of being torn back by metres at a reset. Off by default: at 0.2 it kept
  /// poor_high_open_a's rails within 2.6 cm (9.7 cm without), but long_20km still had 5 resets
  /// and one tore through a building wall (planes 4.35 cm against 2.4), and reverse_running's
  /// planes went from 2.0 to 2.7 cm.
  double gnss_pull_excess = 0.0;
  /// Along the track the pull also takes this share of the gap beyond 1/4 of chain_reset_m
  /// each submap. Where the odometry runs long for a while (1 % over 1.2 km in long_20km's
  /// feature-poor curve, the LiDAR blind along the track), the chain otherwise left GNSS by
  /// 0.3 m a submap and was reset every few submaps, each reset tearing the map by 2 m along
  /// the track (a building's walls 1 m apart). 0 leaves it to gnss_pull.
  double gnss_pull_along_excess = 0.5;
  double gnss_max_tilt_rad = 0.005;  ///< each loop's angle is held within this...
  /// ...and turns by at most this per metre of path (0.07 mrad over a 33 m submap, a
  /// millimetre at its seam), even when the GNSS position jumps.
  double gnss_max_tilt_rate_rad_per_m = 2e-6;
  /// A chained submap further than this from its GNSS pose across the track, or twice this
  /// along it, is placed by GNSS instead (a chain reset).
  double chain_reset_m = 2.0;
  bool ndt = true;
  NdtOptions ndt_options;
  double ndt_target_voxel_m = 0.2;  ///< earlier submaps, thinned (finer than NDT cells)
  /// An earlier submap is a target besides the previous one only where the train comes back
  /// over the same ground: where it has travelled at least this much further (by the
  /// odometry) than the straight distance between the two. Consecutive submaps along one pass
  /// overlap too, but registering onto those would hold the chain where it was and undo the
  /// GNSS pull, until a chain reset tore the map.
  double revisit_min_m = 20.0;
  double ndt_max_correction_m = 0.3;
  double ndt_max_correction_deg = 0.5;
  /// NDT's along-track correction is used only where the registration constrains that
  /// direction: its information along the track at least this share of the strongest (0.1-0.2
  /// past a station, under 0.01 on plain track with evenly spaced masts).
  double ndt_min_along_information = 0.05;
  /// The same where NDT's target holds an earlier pass's submaps. Each pass is placed along
  /// the track by its own odometry and GNSS, and only NDT ties them together there; the
  /// earlier pass holds the result, so it is not carried along the chain as a slide would be.
  /// reverse_running's later passes were 0.1-0.2 m off the first along the track (NDT saw the
  /// offset submap after submap at ratios of 0.005-0.06), and a wall facing along the track
  /// came out 3.2 cm RMS thick on seed 3 (2.5 with this; seed 2 2.4 -> 1.2 cm).
  double ndt_min_along_information_revisit = 0.005;
  /// NDT's turn about the vertical is used only where the registration constrains it: its
  /// information (the other directions free) at least that of the strongest translation at
  /// this lever arm (m). Mostly 5-15 m along built-up or mast-lined track, 1-2 m in a bare curve,
  /// where the placement's GNSS-corrected heading is kept instead. 0 always uses NDT's turn.
  double ndt_min_turn_arm_m = 3.0;
};

/// Body poses with the sideways slip of the point `p_body_wheel` (fixed in the body: the
/// wheels on the rail) taken out. Each step between neighbours k and k+1 is taken in the axes of
/// the pair's mean orientation (their slerp halfway: for a pair on a circular curve the chord
/// is that mean heading). The slip the steps share is the least-squares ratio of their y to
/// their x parts, fitted again without the steps whose y part lies more than `max_jump_m` off
/// it: those lose their whole y part (no car body steps sideways so far between two
/// keyframes), the others lose the shared slip times their x part and keep the rest. The pose
/// at `anchor` stays; the others are rebuilt outwards from it, orientations kept. Poses in any
/// one frame; fewer than two come back as they are.
std::vector<Eigen::Isometry3d> WithoutSideSlip(const std::vector<Eigen::Isometry3d>& poses,
                                               size_t anchor,
                                               const Eigen::Vector3d& p_body_wheel,
                                               double max_jump_m);

/// One keyframe for the submap builder.
struct SubmapKeyframe {
  int64_t stamp_ns = 0;
  /// Where GNSS puts it (GnssFusion::MapTarget), the pose the chain is pulled towards: UTM when
  /// georeferenced, else the local odometry frame.
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
  /// The odometry's own pose, without GNSS corrections: locally the most consistent.
  Eigen::Isometry3d T_odom_body = Eigen::Isometry3d::Identity();
  bool georeferenced = false;
  std::string utm_zone;
  /// The odometry's solve hit its iteration limit (stage 1 registers it).
  bool odometry_suspect = false;
  /// The odometry's scale error (true distance = scale x odometry), from the GNSS fusion.
  double odometry_scale = 1.0;
  std::vector<Eigen::Vector3f> points_body;  ///< deskewed cloud, body frame
  std::vector<float> intensities;
};

/// Counters of the two registration stages.
struct SubmapStats {
  uint64_t submaps = 0;
  uint64_t chained = 0;       ///< submaps placed by the odometry chain (pulled towards GNSS)
  uint64_t chain_resets = 0;  ///< ... placed by GNSS alone, the chain too far from it
  uint64_t icp_odometry = 0;  ///< keyframes registered from their odometry guess
  uint64_t icp_gnss = 0;      ///< ... from their GNSS guess, after the odometry one failed
  uint64_t icp_failed = 0;    ///< keyframes left at their odometry pose
  uint64_t ndt_applied = 0;
  uint64_t ndt_rejected = 0;   ///< not converged or beyond the trust region
  uint64_t ndt_turn_held = 0;  ///< registrations whose turn was held (poorly seen)
  uint64_t ndt_revisits = 0;   ///< registrations onto an earlier pass's submaps too
};

/// Groups consecutive keyframes into submaps (paper IV.E: 10 keyframes each) in two stages.
/// Within a submap the keyframes keep their odometry poses relative to the middle one (the
/// odometry is locally far better than GNSS), with stage 1's ICP where the odometry is suspect;
/// the submap is placed as a rigid body (stage 2, see SubmapOptions). A submap keeps float
/// offsets from a double-precision origin (its first keyframe's position rounded to whole
/// metres), so UTM coordinates are never stored in a float.
class SubmapBuilder {
 public:
  explicit SubmapBuilder(const SubmapOptions& options = {});
  ~SubmapBuilder();
  SubmapBuilder(const SubmapBuilder&) = delete;
  SubmapBuilder& operator=(const SubmapBuilder&) = delete;

  /// Adds a keyframe. Returns the submaps completed since the last call (without their
  /// sequence numbers), in index order: a submap's NDT runs on a worker thread while the
  /// caller goes on, and the submap comes out of a later call once it is done.
  std::vector<api::Submap> Add(SubmapKeyframe keyframe);
  /// The end of the run: every submap still open or registering.
  std::vector<api::Submap> Flush();
  const SubmapStats& stats() const { return stats_; }

 private:
  /// A closed submap whose NDT runs on a worker thread.
  struct Pending {
    api::Submap submap;
    std::vector<Eigen::Isometry3d> P;  ///< keyframe poses, local (world minus origin)
    Eigen::Isometry3d T_odom_anchor = Eigen::Isometry3d::Identity();
    /// Absolute; its orientation tilted by the height loop (where the pull takes the submap).
    Eigen::Isometry3d T_gnss_anchor = Eigen::Isometry3d::Identity();
    bool chained = false;
    size_t anchor = 0;
    double travel_anchor_m = 0.0;  ///< the odometry's path length at the anchor
    bool revisit = false;          ///< NDT's target holds an earlier pass's submaps
    std::future<Registration> ndt;
  };

  /// Closes the open submap into `done`, or into pending_ while its NDT runs.
  void Close(std::vector<api::Submap>* done);
  /// The open keyframes' local poses (world minus origin): the anchor placed, the others by the
  /// odometry relative to it, refined by ICP.
  void PlaceKeyframes(Pending* p);
  /// The open keyframes' points within max_range_m at their poses, voxel-thinned.
  void GatherPoints(Pending* p) const;
  /// Waits for the pending submap's NDT, applies it and hands the submap over.
  void FinishPending(std::vector<api::Submap>* done);
  /// Pulls a chained submap towards GNSS, writes the keyframe poses and remembers the submap
  /// for the next one's chain and NDT.
  api::Submap Finalize(Pending p);
  /// Where a chained submap's anchor goes (local): gnss_pull of the way to its GNSS pose.
  Eigen::Isometry3d PullTarget(const Pending& p) const;
  /// Keeps a georeferenced submap for the next one's chain and for NDT.
  void Remember(const Pending& p);
  /// Stage 1: refines the local keyframe poses P (world minus origin) by ICP.
  void RegisterKeyframes(const Eigen::Vector3d& origin, std::vector<Eigen::Isometry3d>* P);
  /// Stage 2: where the middle keyframe goes (absolute), by the chain or by GNSS; `chained`
  /// tells which.
  /// `tilt` is the height and heading loops' rotation (where the GNSS pull takes the
  /// orientation); the chain's path and orientation are tilted by it and by the previous
  /// submap's roll and pitch against its own.
  Eigen::Isometry3d PlaceAnchor(const SubmapKeyframe& anchor, bool* chained, Eigen::Matrix3d* tilt);
  /// The rotation that raises the nose of `R_world_body` by the height loop's slope and turns
  /// its heading left by the heading loop's angle.
  Eigen::Matrix3d Tilt(const Eigen::Matrix3d& R_world_body) const;
  /// The anchor's pose carried from the previous submap's by the odometry and tilted;
  /// `travel_m`: the distance carried.
  Eigen::Isometry3d Chain(const SubmapKeyframe& anchor,
                          const Eigen::Matrix3d& tilt,
                          double* travel_m) const;
  /// A critically damped loop of natural length `length_m` on a distance along the path.
  struct Loop {
    double angle_rad = 0.0;
    double integral_m2 = 0.0;  ///< of the distance over the path
  };
  /// Feeds `loop` the distance `error_m` (positive: the angle should grow) `travel_m` after
  /// the previous anchor; its angle turns by at most `rate_rad_per_m` per metre.
  void Steer(
      Loop* loop, double length_m, double rate_rad_per_m, double error_m, double travel_m) const;
  /// Stage 2: starts the NDT of the submap onto the earlier submaps it overlaps; false if
  /// there is no overlap to register.
  bool StartNdt(Pending* p, bool chained);

  SubmapOptions options_;
  SubmapStats stats_;
  uint32_t next_index_ = 0;
  std::vector<SubmapKeyframe> open_;
  std::vector<double> open_travel_m_;  ///< the odometry's path length at each open keyframe
  double travel_m_ = 0.0;
  std::optional<Eigen::Vector3d> last_odom_;
  std::optional<Pending> pending_;
  /// The height loop (the chain's slope, nose up, on its height below GNSS) and the heading
  /// loop (its turn to the left, on its offset to the right of GNSS).
  Loop height_;
  Loop heading_;
  /// The previous georeferenced submap's placement, for the chain.
  struct Previous {
    std::string utm_zone;
    Eigen::Isometry3d T_world_anchor = Eigen::Isometry3d::Identity();  ///< absolute, final
    Eigen::Isometry3d T_odom_anchor = Eigen::Isometry3d::Identity();
    /// Its GNSS orientation tilted by the height loop: where the pull took its orientation.
    Eigen::Matrix3d R_level_anchor = Eigen::Matrix3d::Identity();
  };
  std::optional<Previous> previous_;
  /// Every finished georeferenced submap, thinned: NDT's targets. By submap index, where its
  /// anchor ended up and the path length there, to tell an earlier pass from this one.
  SubmapArchive archive_;
  struct Placed {
    Eigen::Vector3d anchor = Eigen::Vector3d::Zero();
    double travel_m = 0.0;
  };
  std::vector<Placed> placed_;
};

}  // namespace raillomer
