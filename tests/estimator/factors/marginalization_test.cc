#include "estimator/factors/marginalization.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstdio>
#include <memory>
#include <random>
#include <unordered_set>
#include <vector>

#include <ceres/ceres.h>

#include <Eigen/Geometry>

#include "estimator/factors/lidar_factors.h"
#include "estimator/factors/pose_manifold.h"

namespace raillomer {
namespace {

using Pose = std::array<double, kPoseSize>;
using SpeedBias = std::array<double, kSpeedBiasSize>;
/// The synthetic window's states carry a scale alone (the estimator's odometer block also holds
/// the misalignment; marginalisation does not care what a Euclidean block means).
constexpr int kScaleSize = 1;
using Scale = std::array<double, kScaleSize>;
using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

int Tangent(int size) { return size == kPoseSize ? kPoseTangentSize : size; }

/// An automatically differentiated cost whose pose Jacobians follow the PoseManifold
/// convention (tangent in the first 6 columns, zero 7th), for the test's own factors.
template <typename Functor, int kNumResiduals, int... kBlockSizes>
class TangentAutoDiff final : public ceres::SizedCostFunction<kNumResiduals, kBlockSizes...> {
 public:
  explicit TangentAutoDiff(Functor* functor) : autodiff_(functor) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    if (jacobians == nullptr) return autodiff_.Evaluate(parameters, residuals, nullptr);
    constexpr int kNumBlocks = sizeof...(kBlockSizes);
    constexpr std::array<int, kNumBlocks> kSizes = {kBlockSizes...};
    std::array<std::array<double, kNumResiduals * kPoseSize>, kNumBlocks> ambient;
    std::array<double*, kNumBlocks> pointers;
    for (int k = 0; k < kNumBlocks; ++k) {
      pointers[k] =
          jacobians[k] != nullptr && kSizes[k] == kPoseSize ? ambient[k].data() : jacobians[k];
    }
    if (!autodiff_.Evaluate(parameters, residuals, pointers.data())) return false;
    using Jacobian = Eigen::Matrix<double, kNumResiduals, kPoseSize, Eigen::RowMajor>;
    for (int k = 0; k < kNumBlocks; ++k) {
      if (jacobians[k] == nullptr || kSizes[k] != kPoseSize) continue;
      // d(q * Exp(dtheta))/d(dtheta) at 0 in (x, y, z, w) order: 0.5 [w I + [v]x; -v^T].
      const Eigen::Map<const Eigen::Quaterniond> q(parameters[k] + 3);
      Eigen::Matrix<double, kPoseSize, kPoseTangentSize> plus = Eigen::Matrix<double, 7, 6>::Zero();
      plus.topLeftCorner<3, 3>().setIdentity();
      plus.block<3, 3>(3, 3) = 0.5 * (q.w() * Eigen::Matrix3d::Identity() + Skew(q.vec()));
      plus.block<1, 3>(6, 3) = -0.5 * q.vec().transpose();
      Eigen::Map<Jacobian> out(jacobians[k]);
      const Eigen::Map<const Jacobian> in(ambient[k].data());
      out.template leftCols<kPoseTangentSize>() = in * plus;
      out.col(6).setZero();
    }
    return true;
  }

 private:
  ceres::AutoDiffCostFunction<Functor, kNumResiduals, kBlockSizes...> autodiff_;
};

/// r = [(p - p0) / sigma_p; 2 vec(q0^-1 q) / sigma_q].
struct PosePrior {
  Eigen::Vector3d p0;
  Eigen::Quaterniond q0;
  double sigma_p, sigma_q;
  template <typename T>
  bool operator()(const T* pose, T* r) const {
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> p(pose);
    const Eigen::Map<const Eigen::Quaternion<T>> q(pose + 3);
    Eigen::Map<Eigen::Matrix<T, 6, 1>> res(r);
    res.template head<3>() = (p - p0.cast<T>()) / T(sigma_p);
    res.template tail<3>() = T(2.0) * (q0.cast<T>().conjugate() * q).vec() / T(sigma_q);
    return true;
  }
};

/// r = (x - x0) / sigma.
template <int kSize>
struct EuclideanPrior {
  Eigen::Matrix<double, kSize, 1> x0;
  double sigma;
  template <typename T>
  bool operator()(const T* x, T* r) const {
    for (int k = 0; k < kSize; ++k) r[k] = (x[k] - T(x0(k))) / T(sigma);
    return true;
  }
};

/// An IMU/odometer-like factor between states i and j (pose, speed-bias, scale), nonlinear in
/// the rotation and in the odometer scale, coupling every block.
struct ImuLike {
  Eigen::Vector3d alpha, beta;
  Eigen::Quaterniond gamma;
  double odometer_m, dt_s;
  template <typename T>
  bool operator()(const T* pose_i,
                  const T* sb_i,
                  const T* scale_i,
                  const T* pose_j,
                  const T* sb_j,
                  const T* scale_j,
                  T* r) const {
    using Vec3 = Eigen::Matrix<T, 3, 1>;
    const Eigen::Map<const Vec3> p_i(pose_i), p_j(pose_j);
    const Eigen::Map<const Eigen::Quaternion<T>> q_i(pose_i + 3), q_j(pose_j + 3);
    const Eigen::Map<const Vec3> v_i(sb_i), ba_i(sb_i + 3), bg_i(sb_i + 6);
    const Eigen::Map<const Vec3> v_j(sb_j), ba_j(sb_j + 3), bg_j(sb_j + 6);
    const Eigen::Quaternion<T> q_i_inv = q_i.conjugate();
    const T dt(dt_s);
    Eigen::Map<Eigen::Matrix<T, 17, 1>> res(r);
    res.template segment<3>(0) =
        (q_i_inv * (p_j - p_i - v_i * dt) + T(0.5) * dt * dt * ba_i - alpha.cast<T>()) / T(0.05);
    res.template segment<3>(3) = (q_i_inv * (v_j - v_i) + dt * ba_i - beta.cast<T>()) / T(0.05);
    res.template segment<3>(6) = (ba_j - ba_i) / T(0.01);
    res.template segment<3>(9) = (bg_j - bg_i) / T(0.001);
    res.template segment<3>(12) =
        (T(2.0) * (gamma.cast<T>().conjugate() * q_i_inv * q_j).vec() - dt * bg_i) / T(0.002);
    res(15) = (scale_i[0] * T(odometer_m) - (q_i_inv * (p_j - p_i)).x()) / T(0.05);
    res(16) = (scale_j[0] - scale_i[0]) / T(0.001);
    return true;
  }
};

using PosePriorCost = TangentAutoDiff<PosePrior, 6, 7>;
using SpeedBiasPriorCost = TangentAutoDiff<EuclideanPrior<9>, 9, 9>;
using ScalePriorCost = TangentAutoDiff<EuclideanPrior<1>, 1, 1>;
using ImuLikeCost = TangentAutoDiff<ImuLike, 17, 7, 9, 1, 7, 9, 1>;

Eigen::Vector3d Position(const double* pose) { return Eigen::Map<const Eigen::Vector3d>(pose); }
Eigen::Quaterniond Orientation(const double* pose) {
  return Eigen::Map<const Eigen::Quaterniond>(pose + 3);
}

Pose MakePose(const Eigen::Vector3d& p, const Eigen::Vector3d& rotation_vector) {
  Pose pose;
  Eigen::Map<Eigen::Vector3d>(pose.data()) = p;
  Eigen::Map<Eigen::Quaterniond>(pose.data() + 3) = ExpQuaternion(rotation_vector);
  return pose;
}

/// Moves a block by a tangent step (PoseManifold::Plus for poses).
void Move(double* block, int size, const Eigen::VectorXd& delta) {
  if (size == kPoseSize) {
    Pose moved;
    PoseManifold().Plus(block, delta.data(), moved.data());
    std::copy(moved.begin(), moved.end(), block);
  } else {
    for (int k = 0; k < size; ++k) block[k] += delta(k);
  }
}

/// The tangent difference a [-] b.
Eigen::VectorXd Difference(const double* a, const double* b, int size) {
  Eigen::VectorXd d(Tangent(size));
  if (size == kPoseSize) {
    PoseManifold().Minus(a, b, d.data());
  } else {
    for (int k = 0; k < size; ++k) d(k) = a[k] - b[k];
  }
  return d;
}

/// One factor of the test problems.
struct Factor {
  std::shared_ptr<ceres::CostFunction> cost;
  std::shared_ptr<ceres::LossFunction> loss;
  std::vector<double*> blocks;
};

/// Tangent Jacobian of block `index` by central differences through PoseManifold::Plus.
Eigen::MatrixXd NumericJacobian(const ceres::CostFunction& cost,
                                const std::vector<double*>& blocks,
                                size_t index,
                                double step = 1e-6) {
  const int size = cost.parameter_block_sizes()[index];
  const int rows = cost.num_residuals();
  Eigen::MatrixXd jacobian(rows, Tangent(size));
  std::vector<const double*> values(blocks.begin(), blocks.end());
  Eigen::VectorXd plus(rows), minus(rows);
  for (int k = 0; k < Tangent(size); ++k) {
    for (double sign : {1.0, -1.0}) {
      std::vector<double> moved(blocks[index], blocks[index] + size);
      Eigen::VectorXd delta = Eigen::VectorXd::Zero(Tangent(size));
      delta(k) = sign * step;
      Move(moved.data(), size, delta);
      values[index] = moved.data();
      cost.Evaluate(values.data(), sign > 0 ? plus.data() : minus.data(), nullptr);
    }
    values[index] = blocks[index];
    jacobian.col(k) = (plus - minus) / (2.0 * step);
  }
  return jacobian;
}

/// Residual and tangent Jacobians of a cost (analytic).
void EvaluateTangent(const ceres::CostFunction& cost,
                     const std::vector<double*>& blocks,
                     Eigen::VectorXd* residual,
                     std::vector<Eigen::MatrixXd>* tangent_jacobians) {
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  std::vector<RowMatrix> ambient(blocks.size());
  std::vector<double*> pointers(blocks.size());
  for (size_t k = 0; k < blocks.size(); ++k) {
    ambient[k] = RowMatrix::Constant(cost.num_residuals(), sizes[k], 1e9);
    pointers[k] = ambient[k].data();
  }
  residual->resize(cost.num_residuals());
  std::vector<const double*> values(blocks.begin(), blocks.end());
  ASSERT_TRUE(cost.Evaluate(values.data(), residual->data(), pointers.data()));
  tangent_jacobians->clear();
  for (size_t k = 0; k < blocks.size(); ++k) {
    if (sizes[k] == kPoseSize) {
      EXPECT_EQ(ambient[k].col(6).cwiseAbs().maxCoeff(), 0.0);
    }
    tangent_jacobians->push_back(ambient[k].leftCols(Tangent(sizes[k])));
  }
}

/// A sliding window of five states with LiDAR, rail-plane, longitudinal-shift and IMU-like
/// factors plus priors on the first state, built from a known trajectory with noisy
/// measurements and one gross LiDAR outlier per state (Huber loss on every LiDAR term).
class WindowTest : public ::testing::Test {
 protected:
  static constexpr int kStates = 5;

  static constexpr double kTrueScale = 1.02;
  static constexpr double kGroundD = 1.5;
  static constexpr double kLidarSigma = 0.02;

  void SetUp() override {
    MakeTruth();
    for (int k = 0; k < kStates; ++k) AddLidarFactors(k);
    for (int k = 0; k + 1 < kStates; ++k) AddFactorsBetween(k);
    AddPriorsOnTheFirstState();
    StartNearTheTruthAndSolve();
  }

  static Eigen::Vector3d GroundNormal() { return Eigen::Vector3d(0.01, 0.02, 1.0).normalized(); }

  double Noise(double sigma) { return sigma * normal_(rng_); }
  Eigen::Vector3d Noise3(double sigma) {
    return Eigen::Vector3d(Noise(sigma), Noise(sigma), Noise(sigma));
  }

  /// The true trajectory: a gentle curve with known speeds and biases.
  void MakeTruth() {
    for (int k = 0; k < kStates; ++k) {
      true_poses_[k] = MakePose({12.0 * k, 0.8 * std::sin(0.5 * k), 0.05 * k},
                                {0.01 * std::sin(1.0 * k), 0.02 * std::cos(1.0 * k), 0.1 * k});
      Eigen::Map<Eigen::Matrix<double, 9, 1>> sb(true_sb_[k].data());
      sb << 12.0, 0.4 * std::cos(0.5 * k), 0.05, 0.02, -0.01 + 0.001 * k, 0.03, 0.001, 0.002,
          -0.001;
    }
  }

  /// Measurements of state k: points on planes (ground, a wall on the left, a face ahead) and on
  /// lines (a pole, a wire), plus one outlier 0.3 m off the wall, all under a Huber loss.
  void AddLidarFactors(int k) {
    const std::shared_ptr<ceres::LossFunction> huber = std::make_shared<ceres::HuberLoss>(1.0);
    const Pose& truth = true_poses_[k];
    const Eigen::Vector3d t = Position(truth.data());
    const Eigen::Quaterniond q = Orientation(truth.data());
    auto to_body = [&](const Eigen::Vector3d& w) {
      return Eigen::Vector3d(q.conjugate() * (w - t) + Noise3(kLidarSigma / std::sqrt(3.0)));
    };
    const std::array<Eigen::Vector3d, 3> normals = {GroundNormal(),
                                                    Eigen::Vector3d(0.05, 1.0, 0.0).normalized(),
                                                    Eigen::Vector3d(1.0, 0.2, 0.1).normalized()};
    const std::array<Eigen::Vector3d, 3> anchors = {
        Eigen::Vector3d(0.0, 0.0, -kGroundD / GroundNormal().z()),
        t + Eigen::Vector3d(0.0, 6.0, 0.0),
        t + Eigen::Vector3d(15.0, 0.0, 0.0)};
    for (int f = 0; f < 3; ++f) {
      const double d = -normals[f].dot(anchors[f]);
      const Eigen::Vector3d e1 = normals[f].unitOrthogonal();
      const Eigen::Vector3d e2 = normals[f].cross(e1);
      // Points around the state's own position on the plane.
      const Eigen::Vector3d centre = t - (normals[f].dot(t) + d) * normals[f];
      for (int n = 0; n < 8; ++n) {
        const Eigen::Vector3d w = centre + (n - 3.5) * 1.3 * e1 + (n % 3 - 1) * 2.1 * e2;
        factors_.push_back(
            {std::make_shared<PointToPlaneFactor>(to_body(w), normals[f], d, 1.0 / kLidarSigma),
             huber,
             {poses_[k].data()}});
      }
      if (f == 1) {  // the outlier: 0.3 m off the wall
        const Eigen::Vector3d w = centre + 0.3 * normals[f] + 2.0 * e1;
        outlier_[k] = factors_.size();
        factors_.push_back(
            {std::make_shared<PointToPlaneFactor>(to_body(w), normals[f], d, 1.0 / kLidarSigma),
             huber,
             {poses_[k].data()}});
      }
    }
    const std::array<Eigen::Vector3d, 2> line_points = {t + Eigen::Vector3d(5.0, 4.0, 0.0),
                                                        t + Eigen::Vector3d(0.0, -1.0, 6.0)};
    const std::array<Eigen::Vector3d, 2> line_directions = {
        Eigen::Vector3d(0.0, 0.05, 1.0).normalized(), Eigen::Vector3d(1.0, 0.02, 0.0).normalized()};
    for (int f = 0; f < 2; ++f) {
      for (int n = 0; n < 5; ++n) {
        const Eigen::Vector3d w = line_points[f] + (n - 2.0) * 1.7 * line_directions[f];
        factors_.push_back({std::make_shared<PointToLineFactor>(
                                to_body(w), line_points[f], line_directions[f], 1.0 / kLidarSigma),
                            huber,
                            {poses_[k].data()}});
      }
    }
  }

  /// Rail plane, longitudinal shift and IMU-like factors between states k and k + 1.
  void AddFactorsBetween(int k) {
    const Pose& ti = true_poses_[k];
    const Pose& tj = true_poses_[k + 1];
    const Eigen::Quaterniond qi = Orientation(ti.data()), qj = Orientation(tj.data());
    const Eigen::Vector3d pi = Position(ti.data()), pj = Position(tj.data());
    // Rail plane (the ground) measured in both body frames.
    const Eigen::Vector3d n_i = (qi.conjugate() * GroundNormal() + Noise3(0.002)).normalized();
    const Eigen::Vector3d n_j = (qj.conjugate() * GroundNormal() + Noise3(0.002)).normalized();
    const double d_i = kGroundD + GroundNormal().dot(pi) + Noise(0.01);
    const double d_j = kGroundD + GroundNormal().dot(pj) + Noise(0.01);
    factors_.push_back({std::make_shared<RailPlaneFactor>(n_i, d_i, n_j, d_j, 500.0, 100.0),
                        nullptr,
                        {poses_[k].data(), poses_[k + 1].data()}});
    const double dx = (qi.conjugate() * (pj - pi)).x();
    factors_.push_back({std::make_shared<LongitudinalShiftFactor>(dx + Noise(0.05), 0.05),
                        nullptr,
                        {poses_[k].data(), poses_[k + 1].data()}});
    const Eigen::Map<const Eigen::Vector3d> v_i(true_sb_[k].data()), ba_i(true_sb_[k].data() + 3),
        bg_i(true_sb_[k].data() + 6), v_j(true_sb_[k + 1].data());
    const double dt = 1.0;
    auto* imu =
        new ImuLike{qi.conjugate() * (pj - pi - v_i * dt) + 0.5 * dt * dt * ba_i + Noise3(0.05),
                    qi.conjugate() * (v_j - v_i) + dt * ba_i + Noise3(0.05),
                    qi.conjugate() * qj * ExpQuaternion(-dt * bg_i + Noise3(0.002)),
                    dx / kTrueScale + Noise(0.05),
                    dt};
    factors_.push_back({std::make_shared<ImuLikeCost>(imu),
                        nullptr,
                        {poses_[k].data(),
                         speed_biases_[k].data(),
                         scales_[k].data(),
                         poses_[k + 1].data(),
                         speed_biases_[k + 1].data(),
                         scales_[k + 1].data()}});
  }

  /// Priors on the first state's pose, speed and biases, and scale.
  void AddPriorsOnTheFirstState() {
    factors_.push_back({std::make_shared<PosePriorCost>(
                            new PosePrior{Position(true_poses_[0].data()) + Noise3(0.1),
                                          Orientation(true_poses_[0].data()),
                                          0.1,
                                          0.01}),
                        nullptr,
                        {poses_[0].data()}});
    Eigen::Matrix<double, 9, 1> sb0 =
        Eigen::Map<const Eigen::Matrix<double, 9, 1>>(true_sb_[0].data());
    sb0.head<3>() += Noise3(0.1);
    factors_.push_back({std::make_shared<SpeedBiasPriorCost>(new EuclideanPrior<9>{sb0, 0.1}),
                        nullptr,
                        {speed_biases_[0].data()}});
    factors_.push_back({std::make_shared<ScalePriorCost>(new EuclideanPrior<1>{
                            Eigen::Matrix<double, 1, 1>(kTrueScale + Noise(0.05)), 0.05}),
                        nullptr,
                        {scales_[0].data()}});
  }

  /// Starts near the truth and solves the whole window: x*.
  void StartNearTheTruthAndSolve() {
    for (int k = 0; k < kStates; ++k) {
      poses_[k] = true_poses_[k];
      speed_biases_[k] = true_sb_[k];
      scales_[k] = {kTrueScale};
      Eigen::Matrix<double, 6, 1> step;
      step << Noise3(0.2), Noise3(0.02);
      Move(poses_[k].data(), kPoseSize, step);
      Move(speed_biases_[k].data(), kSpeedBiasSize, Eigen::Matrix<double, 9, 1>::Constant(0.1));
      Move(scales_[k].data(), kScaleSize, Eigen::Matrix<double, 1, 1>(0.03));
    }
    std::vector<const Factor*> all;
    for (const Factor& f : factors_) all.push_back(&f);
    Solve(all);
    optimum_poses_ = poses_;
    optimum_speed_biases_ = speed_biases_;
    optimum_scales_ = scales_;
  }

  std::vector<double*> StateBlocks(int k) {
    return {poses_[k].data(), speed_biases_[k].data(), scales_[k].data()};
  }

  /// Factors touching any of `blocks` (touching = true) or none of them (touching = false).
  std::vector<const Factor*> Select(const std::unordered_set<double*>& blocks,
                                    bool touching) const {
    std::vector<const Factor*> selected;
    for (const Factor& f : factors_) {
      const bool touches = std::any_of(
          f.blocks.begin(), f.blocks.end(), [&](double* b) { return blocks.count(b) > 0; });
      if (touches == touching) selected.push_back(&f);
    }
    return selected;
  }

  /// A marginalisation term for `f`, dropping those of its blocks that are in `dropped`.
  static MarginalizationTerm Term(const Factor& f, const std::unordered_set<double*>& dropped) {
    MarginalizationTerm term{f.cost, f.loss, f.blocks, {}};
    for (size_t k = 0; k < f.blocks.size(); ++k) {
      if (dropped.count(f.blocks[k]) > 0) term.drop_indices.push_back(static_cast<int>(k));
    }
    return term;
  }

  ceres::Solver::Summary Solve(const std::vector<const Factor*>& factors) {
    ceres::Problem::Options problem_options;
    problem_options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(problem_options);
    for (const Factor* f : factors) {
      problem.AddResidualBlock(f->cost.get(), f->loss.get(), f->blocks);
    }
    for (Pose& pose : poses_) {
      if (problem.HasParameterBlock(pose.data())) problem.SetManifold(pose.data(), &manifold_);
    }
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = 100;
    options.function_tolerance = 1e-18;
    options.gradient_tolerance = 1e-18;
    options.parameter_tolerance = 1e-18;
    ceres::Solver::Summary summary;
    ceres::Solve(options, &problem, &summary);
    EXPECT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
    return summary;
  }

  /// Moves every block of states [first, kStates) away from its value.
  void Perturb(int first) {
    for (int k = first; k < kStates; ++k) {
      Eigen::Matrix<double, 6, 1> step;
      step << 0.1, -0.2, 0.05, 0.02, -0.01, 0.03;
      Move(poses_[k].data(), kPoseSize, step);
      Move(speed_biases_[k].data(), kSpeedBiasSize, Eigen::Matrix<double, 9, 1>::Constant(0.05));
      Move(scales_[k].data(), kScaleSize, Eigen::Matrix<double, 1, 1>(-0.02));
    }
  }

  /// States [first, kStates) are back at the batch optimum x*.
  void ExpectAtOptimum(int first, double tolerance) {
    for (int k = first; k < kStates; ++k) {
      EXPECT_LT(Difference(poses_[k].data(), optimum_poses_[k].data(), kPoseSize).norm(), tolerance)
          << "pose " << k;
      EXPECT_LT(Difference(speed_biases_[k].data(), optimum_speed_biases_[k].data(), kSpeedBiasSize)
                    .norm(),
                tolerance)
          << "speed-bias " << k;
      EXPECT_LT(std::abs(scales_[k][0] - optimum_scales_[k][0]), tolerance) << "scale " << k;
    }
  }

  std::array<Pose, kStates> poses_;
  std::array<SpeedBias, kStates> speed_biases_;
  std::array<Scale, kStates> scales_;
  std::array<Pose, kStates> optimum_poses_;
  std::array<SpeedBias, kStates> optimum_speed_biases_;
  std::array<Scale, kStates> optimum_scales_;
  std::vector<Factor> factors_;
  std::array<size_t, kStates> outlier_{};
  PoseManifold manifold_;
  std::mt19937 rng_{42};
  std::normal_distribution<double> normal_{0.0, 1.0};
  std::array<Pose, kStates> true_poses_;
  std::array<SpeedBias, kStates> true_sb_;
};

/// Dense reference: H and b over [dropped..., kept...] in tangent coordinates, with the
/// robustified residual and Jacobian (Huber: rho'' <= 0, so both scale by sqrt(rho')).
void DenseSystem(const std::vector<const Factor*>& factors,
                 const std::vector<double*>& order,
                 const std::vector<int>& sizes,
                 Eigen::MatrixXd* hessian,
                 Eigen::VectorXd* gradient) {
  std::vector<int> offsets;
  int n = 0;
  for (int size : sizes) {
    offsets.push_back(n);
    n += Tangent(size);
  }
  int rows = 0;
  for (const Factor* f : factors) rows += f->cost->num_residuals();
  Eigen::MatrixXd jacobian = Eigen::MatrixXd::Zero(rows, n);
  Eigen::VectorXd residual(rows);
  int row = 0;
  for (const Factor* f : factors) {
    Eigen::VectorXd r;
    std::vector<Eigen::MatrixXd> jacobians;
    EvaluateTangent(*f->cost, f->blocks, &r, &jacobians);
    double scale = 1.0;
    if (f->loss != nullptr) {
      double rho[3];
      f->loss->Evaluate(r.squaredNorm(), rho);
      ASSERT_LE(rho[2], 0.0);
      scale = std::sqrt(rho[1]);
    }
    const int m = static_cast<int>(r.size());
    residual.segment(row, m) = scale * r;
    for (size_t k = 0; k < f->blocks.size(); ++k) {
      const auto it = std::find(order.begin(), order.end(), f->blocks[k]);
      ASSERT_NE(it, order.end());
      const int col = offsets[it - order.begin()];
      jacobian.block(row, col, m, jacobians[k].cols()) += scale * jacobians[k];
    }
    row += m;
  }
  *hessian = jacobian.transpose() * jacobian;
  *gradient = jacobian.transpose() * residual;
}

/// H and b of the kept blocks once the first m tangent coordinates are eliminated.
struct ReducedSystem {
  Eigen::MatrixXd h;
  Eigen::VectorXd b;
};

ReducedSystem SchurComplement(const Eigen::MatrixXd& h, const Eigen::VectorXd& b, int m) {
  const int k = static_cast<int>(h.rows()) - m;
  const Eigen::MatrixXd hmm_inverse = h.topLeftCorner(m, m).inverse();
  return {
      h.bottomRightCorner(k, k) - h.bottomLeftCorner(k, m) * hmm_inverse * h.topRightCorner(m, k),
      b.tail(k) - h.bottomLeftCorner(k, m) * hmm_inverse * b.head(m)};
}

/// The factor reproduces the quadratic model exactly along a random tangent step:
/// 0.5 |r|^2 - 0.5 |r0|^2 = b'^T dx + 0.5 dx^T H' dx.
void ExpectQuadraticModel(const std::shared_ptr<MarginalizationInfo>& info,
                          const ReducedSystem& schur) {
  const MarginalizationFactor factor(info);
  const int k = static_cast<int>(schur.b.size());
  std::mt19937 rng(3);
  std::normal_distribution<double> normal(0.0, 0.3);
  std::vector<std::vector<double>> moved_values = info->kept_values();
  Eigen::VectorXd dx(k);
  for (int e = 0; e < k; ++e) dx(e) = normal(rng);
  std::vector<const double*> moved;
  for (size_t n = 0; n < moved_values.size(); ++n) {
    Move(moved_values[n].data(),
         info->kept_sizes()[n],
         dx.segment(info->kept_offsets()[n], Tangent(info->kept_sizes()[n])));
    moved.push_back(moved_values[n].data());
  }
  Eigen::VectorXd residual(k);
  ASSERT_TRUE(factor.Evaluate(moved.data(), residual.data(), nullptr));
  const double model = schur.b.dot(dx) + 0.5 * dx.dot(schur.h * dx);
  const double r0_sq = info->linearized_residual().squaredNorm();
  EXPECT_NEAR(0.5 * residual.squaredNorm() - 0.5 * r0_sq, model, 1e-8 * std::abs(model));
}

TEST_F(WindowTest, PriorMatchesDenseSchurComplement) {
  const std::unordered_set<double*> dropped = {
      poses_[0].data(), speed_biases_[0].data(), scales_[0].data()};
  const std::vector<const Factor*> marginalised = Select(dropped, true);
  // The outlier on the dropped pose is in Huber's linear region, so the loss matters.
  double rho[3];
  const Factor& outlier = factors_[outlier_[0]];
  Eigen::VectorXd r;
  std::vector<Eigen::MatrixXd> unused;
  EvaluateTangent(*outlier.cost, outlier.blocks, &r, &unused);
  outlier.loss->Evaluate(r.squaredNorm(), rho);
  EXPECT_LT(rho[1], 0.2);

  auto info = std::make_shared<MarginalizationInfo>();
  for (const Factor* f : marginalised) info->AddTerm(Term(*f, dropped));
  ASSERT_TRUE(info->Marginalize());
  const std::vector<double*> kept = info->KeptBlocks({});
  const std::vector<double*> expected_kept = StateBlocks(1);
  EXPECT_EQ(std::unordered_set<double*>(kept.begin(), kept.end()),
            std::unordered_set<double*>(expected_kept.begin(), expected_kept.end()));
  EXPECT_EQ(info->kept_tangent_size(), 16);

  std::vector<double*> order = {poses_[0].data(), speed_biases_[0].data(), scales_[0].data()};
  std::vector<int> sizes = {kPoseSize, kSpeedBiasSize, kScaleSize};
  order.insert(order.end(), kept.begin(), kept.end());
  sizes.insert(sizes.end(), info->kept_sizes().begin(), info->kept_sizes().end());
  Eigen::MatrixXd h;
  Eigen::VectorXd b;
  DenseSystem(marginalised, order, sizes, &h, &b);
  const int m = 16;
  const int k = static_cast<int>(h.rows()) - m;
  ASSERT_EQ(k, 16);
  // x* is a minimum: the gradient along the dropped blocks vanishes.
  EXPECT_LT(b.head(m).cwiseAbs().maxCoeff(), 1e-6 * b.tail(k).cwiseAbs().maxCoeff());
  const ReducedSystem schur = SchurComplement(h, b, m);
  const Eigen::MatrixXd& jp = info->linearized_jacobian();
  const Eigen::VectorXd& r0 = info->linearized_residual();
  EXPECT_LT((jp.transpose() * jp - schur.h).cwiseAbs().maxCoeff(),
            1e-9 * schur.h.cwiseAbs().maxCoeff());
  EXPECT_LT((jp.transpose() * r0 - schur.b).cwiseAbs().maxCoeff(),
            1e-9 * schur.b.cwiseAbs().maxCoeff());
  EXPECT_GT(schur.b.norm(), 1.0);  // the remaining factors pull on the kept blocks

  // The kept values are the linearisation point.
  for (size_t n = 0; n < kept.size(); ++n) {
    EXPECT_EQ(info->kept_values()[n],
              std::vector<double>(kept[n], kept[n] + info->kept_sizes()[n]));
  }
  ExpectQuadraticModel(info, schur);
}

TEST_F(WindowTest, ReducedProblemReturnsToBatchOptimum) {
  const std::unordered_set<double*> dropped = {
      poses_[0].data(), speed_biases_[0].data(), scales_[0].data()};
  auto info = std::make_shared<MarginalizationInfo>();
  for (const Factor* f : Select(dropped, true)) info->AddTerm(Term(*f, dropped));
  ASSERT_TRUE(info->Marginalize());
  Factor prior{std::make_shared<MarginalizationFactor>(info), nullptr, info->KeptBlocks({})};

  std::vector<const Factor*> reduced = Select(dropped, false);
  reduced.push_back(&prior);
  Perturb(1);
  const ceres::Solver::Summary summary = Solve(reduced);
  EXPECT_GT(summary.iterations.size(), 2u);
  ExpectAtOptimum(1, 2e-9);

  // Marginalise the next state too, with the first prior as one of the terms, and solve again.
  const std::unordered_set<double*> dropped_2 = {
      poses_[1].data(), speed_biases_[1].data(), scales_[1].data()};
  auto info_2 = std::make_shared<MarginalizationInfo>();
  for (const Factor* f : reduced) {
    const bool touches = std::any_of(
        f->blocks.begin(), f->blocks.end(), [&](double* b) { return dropped_2.count(b) > 0; });
    if (touches) info_2->AddTerm(Term(*f, dropped_2));
  }
  ASSERT_TRUE(info_2->Marginalize());
  EXPECT_EQ(info_2->kept_tangent_size(), 16);
  Factor prior_2{std::make_shared<MarginalizationFactor>(info_2), nullptr, info_2->KeptBlocks({})};
  std::unordered_set<double*> gone = dropped;
  gone.insert(dropped_2.begin(), dropped_2.end());
  std::vector<const Factor*> reduced_2 = Select(gone, false);
  reduced_2.push_back(&prior_2);
  Perturb(2);
  Solve(reduced_2);
  ExpectAtOptimum(2, 2e-9);
}

TEST_F(WindowTest, FactorJacobianMatchesNumeric) {
  const std::unordered_set<double*> dropped = {
      poses_[0].data(), speed_biases_[0].data(), scales_[0].data()};
  auto info = std::make_shared<MarginalizationInfo>();
  for (const Factor* f : Select(dropped, true)) info->AddTerm(Term(*f, dropped));
  ASSERT_TRUE(info->Marginalize());
  const MarginalizationFactor factor(info);
  EXPECT_EQ(factor.num_residuals(), 16);
  EXPECT_EQ(std::vector<int32_t>(factor.parameter_block_sizes()),
            std::vector<int32_t>(info->kept_sizes().begin(), info->kept_sizes().end()));

  // At the linearisation point the residual is r0.
  std::vector<std::vector<double>> values = info->kept_values();
  std::vector<double*> blocks;
  for (std::vector<double>& v : values) blocks.push_back(v.data());
  Eigen::VectorXd r0(16);
  std::vector<const double*> const_blocks(blocks.begin(), blocks.end());
  ASSERT_TRUE(factor.Evaluate(const_blocks.data(), r0.data(), nullptr));
  EXPECT_LT((r0 - info->linearized_residual()).norm(), 1e-12);

  // Far from it (0.5 rad), the analytic Jacobian still matches central differences.
  for (size_t n = 0; n < blocks.size(); ++n) {
    const int size = info->kept_sizes()[n];
    Eigen::VectorXd step = Eigen::VectorXd::LinSpaced(Tangent(size), 0.1, 0.3);
    Move(blocks[n], size, step);
  }
  Eigen::VectorXd residual;
  std::vector<Eigen::MatrixXd> analytic;
  EvaluateTangent(factor, blocks, &residual, &analytic);
  for (size_t n = 0; n < blocks.size(); ++n) {
    const Eigen::MatrixXd numeric = NumericJacobian(factor, blocks, n);
    EXPECT_LT((analytic[n] - numeric).cwiseAbs().maxCoeff(), 1e-6 * numeric.cwiseAbs().maxCoeff())
        << "block " << n;
  }
}

/// rho(s) = s + s^2 / (2 c): a loss with rho'' > 0, which takes Ceres's full corrector path.
class StiffeningLoss : public ceres::LossFunction {
 public:
  explicit StiffeningLoss(double c) : c_(c) {}
  void Evaluate(double s, double rho[3]) const override {
    rho[0] = s + s * s / (2.0 * c_);
    rho[1] = 1.0 + s / c_;
    rho[2] = 1.0 / c_;
  }

 private:
  double c_;
};

TEST(MarginalizationInfo, LossFollowsCeresCorrector) {
  // Nothing dropped, so the prior is the robustified term itself: H = J^T (rho' I + 2 rho''
  // r r^T) J and b = rho' J^T r (Ceres's second-order correction of the Gauss-Newton model).
  Pose pose = MakePose({3.0, -1.0, 0.5}, {0.1, -0.2, 0.7});
  auto line = std::make_shared<PointToLineFactor>(Eigen::Vector3d(4.0, -2.0, 1.5),
                                                  Eigen::Vector3d(1.0, 0.0, -1.0),
                                                  Eigen::Vector3d(0.2, 0.9, 0.1),
                                                  2.5);
  auto loss = std::make_shared<StiffeningLoss>(3.0);
  Eigen::VectorXd r;
  std::vector<Eigen::MatrixXd> jacobians;
  EvaluateTangent(*line, {pose.data()}, &r, &jacobians);
  ASSERT_GT(r.squaredNorm(), 1.0);
  double rho[3];
  loss->Evaluate(r.squaredNorm(), rho);
  const Eigen::MatrixXd& j = jacobians[0];
  const Eigen::MatrixXd expected_h =
      j.transpose() *
      (rho[1] * Eigen::MatrixXd::Identity(3, 3) + 2.0 * rho[2] * r * r.transpose()) * j;
  const Eigen::VectorXd expected_b = rho[1] * j.transpose() * r;

  MarginalizationInfo info;
  info.AddTerm({line, loss, {pose.data()}, {}});
  ASSERT_TRUE(info.Marginalize());
  const Eigen::MatrixXd& jp = info.linearized_jacobian();
  EXPECT_LT((jp.transpose() * jp - expected_h).cwiseAbs().maxCoeff(),
            1e-10 * expected_h.cwiseAbs().maxCoeff());
  EXPECT_LT((jp.transpose() * info.linearized_residual() - expected_b).cwiseAbs().maxCoeff(),
            1e-10 * expected_b.cwiseAbs().maxCoeff());
}

TEST(MarginalizationInfo, RejectsNothingKeptAndBadIndices) {
  Pose pose = MakePose({1.0, 2.0, 3.0}, {0.1, 0.2, 0.3});
  Pose other = MakePose({2.0, 2.0, 3.0}, {0.1, 0.2, 0.3});
  auto prior = std::make_shared<PosePriorCost>(
      new PosePrior{Eigen::Vector3d::Zero(), Eigen::Quaterniond::Identity(), 1.0, 1.0});
  MarginalizationInfo nothing_kept;
  nothing_kept.AddTerm({prior, nullptr, {pose.data()}, {0}});
  EXPECT_FALSE(nothing_kept.Marginalize());
  MarginalizationInfo bad_index;
  bad_index.AddTerm({std::make_shared<LongitudinalShiftFactor>(1.0, 0.1),
                     nullptr,
                     {pose.data(), other.data()},
                     {2}});
  EXPECT_FALSE(bad_index.Marginalize());
}

TEST(MarginalizationInfo, KeptBlocksAreRenamedThroughTheAddressMap) {
  Pose a = MakePose({0.0, 0.0, 0.0}, {0.0, 0.0, 0.1});
  Pose b = MakePose({10.0, 0.5, 0.0}, {0.0, 0.0, 0.2});
  SpeedBias sb{};
  Scale c = {1.01};
  Scale c_a = {1.0};
  auto info = std::make_shared<MarginalizationInfo>();
  info->AddTerm({std::make_shared<PosePriorCost>(
                     new PosePrior{Eigen::Vector3d::Zero(), Orientation(a.data()), 0.1, 0.01}),
                 nullptr,
                 {a.data()},
                 {0}});
  info->AddTerm(
      {std::make_shared<LongitudinalShiftFactor>(9.9, 0.1), nullptr, {a.data(), b.data()}, {0}});
  info->AddTerm({std::make_shared<SpeedBiasPriorCost>(
                     new EuclideanPrior<9>{Eigen::Matrix<double, 9, 1>::Zero(), 1.0}),
                 nullptr,
                 {sb.data()},
                 {}});
  info->AddTerm({std::make_shared<TangentAutoDiff<EuclideanPrior<1>, 1, 1>>(
                     new EuclideanPrior<1>{Eigen::Matrix<double, 1, 1>(1.0), 0.01}),
                 nullptr,
                 {c_a.data()},
                 {0}});
  info->AddTerm(
      {std::make_shared<LongitudinalShiftFactor>(0.0, 1.0), nullptr, {b.data(), a.data()}, {1}});
  info->AddTerm({std::make_shared<ScalePriorCost>(
                     new EuclideanPrior<1>{Eigen::Matrix<double, 1, 1>(1.0), 0.01}),
                 nullptr,
                 {c.data()},
                 {}});
  ASSERT_TRUE(info->Marginalize());
  // Kept in order of first appearance: b, sb, c; the dropped a and c_a are gone.
  EXPECT_EQ(info->KeptBlocks({}), (std::vector<double*>{b.data(), sb.data(), c.data()}));
  EXPECT_EQ(info->kept_sizes(), (std::vector<int>{7, 9, 1}));
  EXPECT_EQ(info->kept_offsets(), (std::vector<int>{0, 6, 15}));
  EXPECT_EQ(info->kept_tangent_size(), 16);

  // The window shifts: b moves to another slot, the others stay.
  Pose b_moved = b;
  Pose unrelated{};
  const std::unordered_map<double*, double*> shift = {{b.data(), b_moved.data()},
                                                      {a.data(), unrelated.data()}};
  const std::vector<double*> renamed = info->KeptBlocks(shift);
  EXPECT_EQ(renamed, (std::vector<double*>{b_moved.data(), sb.data(), c.data()}));
  // The prior evaluated on the renamed blocks is at its linearisation point: r = r0.
  const MarginalizationFactor factor(info);
  std::vector<const double*> values(renamed.begin(), renamed.end());
  Eigen::VectorXd r(16);
  ASSERT_TRUE(factor.Evaluate(values.data(), r.data(), nullptr));
  EXPECT_LT((r - info->linearized_residual()).norm(), 1e-12);
}

}  // namespace
}  // namespace raillomer
