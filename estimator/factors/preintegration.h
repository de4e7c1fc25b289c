#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace raillomer {

/// Continuous-time noise densities of the IMU and the odometer (Q of eq. 17).
struct PreintegrationNoise {
  double gyro_noise_density = 1.22e-4;   ///< rad/s/sqrt(Hz)
  double accel_noise_density = 5.9e-4;   ///< m/s^2/sqrt(Hz)
  double gyro_bias_walk = 1.0e-6;        ///< rad/s^2/sqrt(Hz)
  double accel_bias_walk = 1.0e-5;       ///< m/s^3/sqrt(Hz)
  double odometer_speed_density = 0.02;  ///< m/s/sqrt(Hz), white speed noise eta_sO
  /// 1/sqrt(s), random walk of c^O: 0.18 % in an hour. Wheel wear moves the scale over months;
  /// a looser walk lets gravity leaking through a small pitch error drag the scale along on
  /// long stretches at constant speed, where nothing else observes it.
  double odometer_scale_walk = 3.0e-5;
  /// rad/sqrt(s): random walk of the odometer's misalignment (NavState::m). The car body's pitch
  /// against the track shifts with load, speed and traction, and a wheel's path is never
  /// exactly the IMU's x axis.
  double odometer_misalignment_walk = 1.0e-5;
  /// m/s/sqrt(Hz): velocity of the body across the odometer's axis, sideways. The car body
  /// sways on its suspension while the wheel rolls along the rail, so the body does not move
  /// exactly along its x axis; without this term phi would pin the attitude to the suspension's
  /// motion.
  double odometer_lateral_density = 0.01;
  /// m/s/sqrt(Hz): the same, vertically (a car body may bounce more than it sways). At 0.03
  /// rich_high_mixed_b's 3.0 m of vertical drift over 2.7 km falls to 0.4 m, but long_20km's
  /// pitch and heading then wander through its feature-poor stretches until it diverges at
  /// 15 km (docs/notebook/estimator-results.md), so it stays at the sideways figure.
  double odometer_vertical_density = 0.01;
  /// m: distance of one encoder pulse. Each end of an interval is quantised to it, a bounded
  /// error (variance resolution^2 / 12 per end) that does not grow with the interval.
  double odometer_resolution_m = 0.0;
  /// s: the IMU's sample period (0: unknown; the Estimator sets it from the rig's IMU rate). A
  /// longer step bridges missing samples by interpolating between the two around the gap; their
  /// noise is not averaged down over the step but held through it, so a step's white-noise variance
  /// is density^2 / min(dt, period) rather than density^2 / dt, and a 0.5 s dropout is not trusted
  /// like 100 real samples.
  double imu_period_s = 0.0;
  /// rad/s and m/s^2: how far the body's turn rate and acceleration may stray from the straight
  /// line between the samples around a bridged step (one of more than 1.5 sample periods). The
  /// car body pitches and rolls on its suspension at about 1.4 Hz by up to 10 mrad/s, which no
  /// interpolation across a dropout follows. Each adds (sigma dt)^2 to the step's rotation and
  /// velocity variance, so the LiDARs and the odometer carry the motion across the gap.
  double gap_rate_sigma_radps = 0.02;
  double gap_accel_sigma_mps2 = 0.3;
};

/// Offsets of the blocks of the 19-row preintegration residual and error state (eq. 19).
namespace preintegration_index {
constexpr int kAlpha = 0;
constexpr int kBeta = 3;
constexpr int kTheta = 6;
constexpr int kBa = 9;
constexpr int kBg = 12;
constexpr int kPhi = 15;
constexpr int kC = 18;
}  // namespace preintegration_index

/// A state of the sliding window (eq. 1) in plain form.
struct NavState {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();            ///< p_world_body
  Eigen::Quaterniond q = Eigen::Quaterniond::Identity();  ///< q_world_body
  Eigen::Vector3d v = Eigen::Vector3d::Zero();            ///< v_world
  Eigen::Vector3d ba = Eigen::Vector3d::Zero();
  Eigen::Vector3d bg = Eigen::Vector3d::Zero();
  double c = 1.0;  ///< odometer scale factor
  /// rad: the wheels' path against the odometer's x axis, pitch and yaw (about the odometer's y
  /// and z axes): the path runs along R_body_odo Exp((0, m0, m1)) x. A car body sitting 1.6 mrad
  /// nose-up on its suspension, taken to move along its x axis, drove the pitch 12 mrad off
  /// and the distance 0.9 % long (docs/notebook/estimator-results.md: the odometer's pitch).
  Eigen::Vector2d m = Eigen::Vector2d::Zero();
};

/// IMU / odometer preintegration between two window states (eq. 11-18).
///
/// Residual order (eq. 19), 19 rows: [d_alpha(3), d_beta(3), d_theta(3), d_ba(3), d_bg(3),
/// d_phi(3), d_c(1)]. The odometer frame O has rotation R_body_odo and lever arm p_body_odo;
/// the odometer measures speed along its x axis. An interval with any sample lacking odometer
/// data carries no phi information (odometer_used() is false).
///
/// The error state has the same order; rotation errors are right perturbations
/// gamma_true = gamma * Exp(d_theta). The first Add() only records the start measurement when
/// its dt is zero; later ones each integrate one step from the previous measurement.
class Preintegration {
 public:
  Preintegration(const Eigen::Vector3d& ba,
                 const Eigen::Vector3d& bg,
                 double c,
                 const Eigen::Matrix3d& R_body_odo,
                 const Eigen::Vector3d& p_body_odo,
                 const PreintegrationNoise& noise,
                 double gravity_mps2);

  /// One step of dt seconds with the measurements at its start and end (midpoint integration).
  /// speed_mps is the odometer's raw speed (before the scale factor); odometer_valid false marks
  /// a step without an odometer reading.
  ///
  /// The start measurement is the one of the previous call. A first call with dt <= 0 only
  /// records it; a first call with dt > 0 uses its own measurement at both ends. Later calls
  /// with dt <= 0 replace the recorded measurement without integrating. A step carries odometer
  /// data only when the readings at both of its ends are valid.
  ///
  /// sway_rad is the car body's own rotation on its suspension at the measurement (the gyro's
  /// angles high-passed, InertialBuffer::SwayAt): the wheels run along the track, which is the
  /// odometer's x axis turned back by it. Zero by default.
  void Add(double dt,
           const Eigen::Vector3d& gyro_radps,
           const Eigen::Vector3d& accel_mps2,
           double speed_mps,
           bool odometer_valid,
           const Eigen::Vector3d& sway_rad = Eigen::Vector3d::Zero());

  /// Integrates all steps again about new linearisation points.
  void Repropagate(const Eigen::Vector3d& ba, const Eigen::Vector3d& bg, double c);

  /// Appends the raw steps of `next` (which starts where this one ends) and repropagates.
  void Append(const Preintegration& next);

  /// Eq. (19) at the given states, bias/scale corrections applied to first order (eq. 18).
  Eigen::Matrix<double, 19, 1> Evaluate(const NavState& i, const NavState& j) const;

  /// State at the end of the interval from state i (biases and scale carried over).
  NavState Predict(const NavState& i) const;

  /// Body pose at time `t_s` after the start (0..sum_dt), relative to the body at the start,
  /// integrated from the raw steps with the linearisation biases; for deskewing.
  ///
  /// Rotation: gamma(t). Translation: when odometer_used(), the odometer path with its lever
  /// arm, phi(t) - LeverTerm(gamma(t)) (v_start_body is not used); otherwise
  /// v_start_body * t + alpha(t) - 0.5 t^2 g_start, with gravity g_start = (0, 0, g) assumed
  /// along the start body's z axis (a level start; prefer the overload below). Within a step
  /// the measurements are interpolated linearly; t_s is clamped to [0, sum_dt].
  Eigen::Isometry3d RelativePoseAt(double t_s, const Eigen::Vector3d& v_start_body) const;

  /// As above, from the IMU alone with the start attitude known: rotation gamma(t), translation
  /// v_start_body * t + alpha(t) - 0.5 t^2 R(q_world_start)^T (0, 0, g).
  Eigen::Isometry3d RelativePoseAt(double t_s,
                                   const Eigen::Vector3d& v_start_body,
                                   const Eigen::Quaterniond& q_world_start) const;

  double sum_dt() const { return sum_dt_; }
  bool odometer_used() const { return odometer_used_; }
  const Eigen::Vector3d& alpha() const { return alpha_; }
  const Eigen::Vector3d& beta() const { return beta_; }
  const Eigen::Quaterniond& gamma() const { return gamma_; }
  const Eigen::Vector3d& phi() const { return phi_; }
  /// d phi / d m (3 x 2), at the linearisation scale: phi is integrated with m = 0 and
  /// corrected to first order (Evaluate).
  const Eigen::Matrix<double, 3, 2>& phi_misalignment() const { return phi_m_; }
  const Eigen::Vector3d& linearized_ba() const { return ba_; }
  const Eigen::Vector3d& linearized_bg() const { return bg_; }
  double linearized_c() const { return c_; }
  /// Error-state Jacobian and covariance, 19 x 19 in the residual order above (eq. 16-17).
  const Eigen::Matrix<double, 19, 19>& jacobian() const { return jacobian_; }
  const Eigen::Matrix<double, 19, 19>& covariance() const { return covariance_; }
  /// The covariance the factor whitens with: covariance() plus the odometer's pulse
  /// quantisation at both ends of the interval.
  Eigen::Matrix<double, 19, 19> FactorCovariance() const;
  /// Upper-triangular L with L^T L = covariance^-1 (phi rows zero when !odometer_used()).
  Eigen::Matrix<double, 19, 19> SqrtInformation() const;
  double gravity_mps2() const { return gravity_mps2_; }
  const PreintegrationNoise& noise() const { return noise_; }
  const Eigen::Matrix3d& R_body_odo() const { return R_body_odo_; }
  const Eigen::Vector3d& p_body_odo() const { return p_body_odo_; }
  /// The lever-arm term of the phi residual for the relative rotation R_ij = R_i^T R_j: the
  /// odometer point moves by R_ij p - p in the start body frame. Across the odometer axis the
  /// whole arm counts: a body high above the rail swings sideways over it when the track cants.
  /// Along the axis the arm's height (its component along the odometer's z) is left out: the
  /// body pitching on its suspension does not turn the wheels.
  ///
  /// The whole arm swings with the track's roll only: the roll the car body makes on its
  /// suspension, about itself, over the interval (sway_roll(), measured by the caller) is taken
  /// out of R_ij first, as R_ij * Exp(-sway_roll * x_odo).
  Eigen::Vector3d LeverTerm(const Eigen::Matrix3d& R_ij) const;
  /// d LeverTerm / d delta for R_ij * Exp(delta) (perturbing j) and for Exp(-delta) * R_ij
  /// (perturbing i, right perturbation of R_i).
  Eigen::Matrix3d LeverTermJacobianJ(const Eigen::Matrix3d& R_ij) const;
  Eigen::Matrix3d LeverTermJacobianI(const Eigen::Matrix3d& R_ij) const;
  /// rad: the car body's roll on its suspension over the interval, about the odometer axis (the
  /// fast part of the gyro's roll, InertialBuffer::SwayAt); 0 by default. Append() adds up.
  void set_sway_roll(double rad);
  double sway_roll() const { return sway_roll_; }
  /// Number of integrated steps.
  int num_steps() const { return static_cast<int>(steps_.size()); }
  /// Incremented by every Add(), Repropagate() and Append(); lets factors spot stale caches.
  std::uint64_t revision() const { return revision_; }

 private:
  struct Step {
    double dt;
    Eigen::Vector3d gyro0, accel0, gyro1, accel1;
    double speed0, speed1;
    bool odometer_valid;
    Eigen::Vector3d sway0, sway1;
  };
  /// The preintegrated quantities at one instant (eq. 14).
  struct Delta {
    Eigen::Vector3d alpha = Eigen::Vector3d::Zero();
    Eigen::Vector3d beta = Eigen::Vector3d::Zero();
    Eigen::Quaterniond gamma = Eigen::Quaterniond::Identity();
    Eigen::Vector3d phi = Eigen::Vector3d::Zero();
  };
  struct StepTransition;
  /// Appends one step: the deltas at its end, their Jacobian and covariance.
  void Integrate(const Step& step);
  /// The inertial rows of one step's transition, from the deltas at its start and end.
  StepTransition InertialTransition(const Step& s, const Delta& start, const Delta& end) const;
  /// The odometer's rows of the transition, and the step's share of phi's misalignment Jacobian.
  void AddOdometerStep(const Step& s, StepTransition* t);
  /// J = F J and P = F P F^T + G Q G^T over one step of dt, with the random walks (eq. 17).
  void PropagateCovariance(const StepTransition& t, double dt);
  /// LeverTerm with the sway roll already applied to the arm and its level part.
  Eigen::Vector3d LeverTerm(const Eigen::Matrix3d& R_ij,
                            const Eigen::Vector3d& swayed_p,
                            const Eigen::Vector3d& swayed_p_level) const;
  /// Midpoint step from `in` over the share f of step s (its end measurements interpolated).
  Delta Propagate(const Delta& in, const Step& s, double f) const;
  /// The odometer axis turned back by the body's sway (to first order): the track's direction.
  Eigen::Vector3d TrackAxis(const Eigen::Vector3d& sway) const;
  /// The preintegrated quantities at t_s (see RelativePoseAt).
  Delta DeltaAt(double t_s) const;
  /// alpha, beta, gamma, phi corrected to first order for the given biases and scale (eq. 18).
  Delta Corrected(const Eigen::Vector3d& ba, const Eigen::Vector3d& bg, double c) const;

  Eigen::Vector3d ba_, bg_;
  double c_;
  Eigen::Matrix3d R_body_odo_;
  Eigen::Vector3d p_body_odo_;
  Eigen::Vector3d p_body_odo_level_;  ///< p_body_odo_ without its height (see LeverTerm)
  Eigen::Matrix3d along_odo_;         ///< projector onto the odometer axis
  double sway_roll_ = 0.0;
  /// Exp(-sway_roll_ x_odo) applied to the lever arm and its level part (see LeverTerm).
  Eigen::Vector3d sway_p_body_odo_, sway_p_body_odo_level_;
  PreintegrationNoise noise_;
  double gravity_mps2_;

  double sum_dt_ = 0.0;
  bool odometer_used_ = true;
  Eigen::Vector3d alpha_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d beta_ = Eigen::Vector3d::Zero();
  Eigen::Quaterniond gamma_ = Eigen::Quaterniond::Identity();
  Eigen::Vector3d phi_ = Eigen::Vector3d::Zero();
  Eigen::Matrix<double, 3, 2> phi_m_ = Eigen::Matrix<double, 3, 2>::Zero();
  Eigen::Matrix<double, 19, 19> jacobian_ = Eigen::Matrix<double, 19, 19>::Identity();
  Eigen::Matrix<double, 19, 19> covariance_ = Eigen::Matrix<double, 19, 19>::Zero();
  std::vector<Step> steps_;
  /// Preintegrated quantities at the start of each step, and the start times, for DeltaAt().
  std::vector<Delta> step_start_deltas_;
  std::vector<double> step_start_times_;

  // The last measurement, the start of the next step.
  bool has_last_ = false;
  Eigen::Vector3d last_gyro_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d last_accel_ = Eigen::Vector3d::Zero();
  double last_speed_ = 0.0;
  bool last_odometer_valid_ = true;
  Eigen::Vector3d last_sway_ = Eigen::Vector3d::Zero();
  std::uint64_t revision_ = 0;
};

}  // namespace raillomer
