#include "estimator/factors/imu_odometer_factor.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include "estimator/factors/pose_manifold.h"
#include "estimator/factors/preintegration.h"

namespace raillomer {
namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

constexpr double kGravity = 9.81;
constexpr int kBlockSizes[6] = {7, 9, 3, 7, 9, 3};
constexpr int kTangentSizes[6] = {6, 9, 3, 6, 9, 3};
constexpr int kRows = 21;

/// A 0.3 s preintegration of smooth synthetic IMU and odometer data (not a consistent
/// trajectory: the Jacobians do not need one).
/// sway_roll: the body's own roll over the interval, taken out of the lever arm's swing.
std::shared_ptr<Preintegration> MakePreintegration(bool odometer_valid = true,
                                                   double sway_roll = 0.0) {
  const Matrix3d R_body_odo =
      (Eigen::AngleAxisd(0.05, Vector3d::UnitZ()) * Eigen::AngleAxisd(-0.03, Vector3d::UnitY()))
          .toRotationMatrix();
  auto pre = std::make_shared<Preintegration>(Vector3d(0.02, -0.01, 0.03),
                                              Vector3d(0.001, 0.002, -0.001),
                                              1.0,
                                              R_body_odo,
                                              Vector3d(1.2, -0.3, -1.0),
                                              PreintegrationNoise(),
                                              kGravity);
  for (int k = 0; k <= 60; ++k) {
    const double t = 0.005 * k;
    const Vector3d gyro(0.05 * std::sin(1.1 * t), 0.03 * std::cos(0.7 * t), 0.1 + 0.05 * t);
    const Vector3d accel(
        0.5 * std::sin(t), 0.2 * std::cos(2.0 * t), kGravity + 0.1 * std::sin(3.0 * t));
    pre->Add(k == 0 ? 0.0 : 0.005, gyro, accel, 25.0 + std::sin(t), odometer_valid);
  }
  pre->set_sway_roll(sway_roll);
  return pre;
}

/// The six parameter blocks of one factor, three for each of its two states.
using Blocks = std::array<std::vector<double>, 6>;

/// The six parameter blocks at a non-trivial state: rotated poses, biases, scales and
/// misalignments away from the linearisation point, state j away from the prediction.
Blocks MakeParameters(const Preintegration& pre) {
  NavState i;
  i.p = Vector3d(10.0, -4.0, 2.0);
  i.q = Quaterniond(Eigen::AngleAxisd(0.7, Vector3d(0.2, -0.3, 1.0).normalized()));
  i.v = Vector3d(20.0, 8.0, -0.5);
  i.ba = pre.linearized_ba() + Vector3d(0.02, -0.01, 0.03);
  i.bg = pre.linearized_bg() + Vector3d(1e-3, -2e-3, 1.5e-3);
  i.c = 1.03;
  i.m = Eigen::Vector2d(2e-3, -1e-3);
  NavState j = pre.Predict(i);
  j.p += Vector3d(0.1, -0.2, 0.05);
  j.q = j.q * ExpQuaternion(Vector3d(0.02, -0.01, 0.03));
  j.v += Vector3d(-0.1, 0.05, 0.2);
  j.ba += Vector3d(0.001, 0.002, -0.003);
  j.bg += Vector3d(-1e-4, 2e-4, 1e-4);
  j.c = 1.05;
  j.m = Eigen::Vector2d(2.3e-3, -0.6e-3);
  Blocks blocks;
  for (int k = 0; k < 2; ++k) {
    const NavState& s = k == 0 ? i : j;
    blocks[3 * k] = {s.p.x(), s.p.y(), s.p.z(), s.q.x(), s.q.y(), s.q.z(), s.q.w()};
    blocks[3 * k + 1] = {
        s.v.x(), s.v.y(), s.v.z(), s.ba.x(), s.ba.y(), s.ba.z(), s.bg.x(), s.bg.y(), s.bg.z()};
    blocks[3 * k + 2] = {s.c, s.m.x(), s.m.y()};
  }
  return blocks;
}

NavState ToState(const Blocks& blocks, int k) {
  NavState s;
  const std::vector<double>& pose = blocks[3 * k];
  const std::vector<double>& sb = blocks[3 * k + 1];
  s.p = Vector3d(pose[0], pose[1], pose[2]);
  s.q = Quaterniond(pose[6], pose[3], pose[4], pose[5]);
  s.v = Vector3d(sb[0], sb[1], sb[2]);
  s.ba = Vector3d(sb[3], sb[4], sb[5]);
  s.bg = Vector3d(sb[6], sb[7], sb[8]);
  s.c = blocks[3 * k + 2][0];
  s.m = Eigen::Vector2d(blocks[3 * k + 2][1], blocks[3 * k + 2][2]);
  return s;
}

/// Tangent perturbation of one block: PoseManifold::Plus for poses, addition otherwise.
Blocks Perturb(const Blocks& blocks, int block, int dim, double h) {
  Blocks out = blocks;
  if (kBlockSizes[block] == 7) {
    double delta[6] = {0, 0, 0, 0, 0, 0};
    delta[dim] = h;
    PoseManifold().Plus(blocks[block].data(), delta, out[block].data());
  } else {
    out[block][dim] += h;
  }
  return out;
}

using Jacobian = Eigen::Matrix<double, kRows, Eigen::Dynamic>;
using Residual = Eigen::Matrix<double, kRows, 1>;

/// The factor's whole whitening: eq. (19)'s, then the misalignment walk's.
Eigen::Matrix<double, kRows, kRows> Whitening(const ImuOdometerFactor& factor,
                                              const Preintegration& pre) {
  Eigen::Matrix<double, kRows, kRows> L = Eigen::Matrix<double, kRows, kRows>::Zero();
  L.topLeftCorner<19, 19>() = pre.SqrtInformation();
  L.bottomRightCorner<2, 2>().diagonal().setConstant(factor.misalignment_weight());
  return L;
}

std::array<Jacobian, 6> AnalyticJacobians(const ImuOdometerFactor& factor,
                                          const Blocks& blocks,
                                          Residual* residual) {
  std::array<Eigen::Matrix<double, kRows, Eigen::Dynamic, Eigen::RowMajor>, 6> storage;
  double* jacobians[6];
  const double* parameters[6];
  for (int b = 0; b < 6; ++b) {
    storage[b].setConstant(kRows, kBlockSizes[b], std::nan(""));
    jacobians[b] = storage[b].data();
    parameters[b] = blocks[b].data();
  }
  EXPECT_TRUE(factor.Evaluate(parameters, residual->data(), jacobians));
  std::array<Jacobian, 6> out;
  for (int b = 0; b < 6; ++b) out[b] = storage[b];
  return out;
}

/// The factor's residual at `blocks` is the preintegration's current whitened residual.
template <typename Blocks>
void ExpectWhitenedResidual(const ImuOdometerFactor& factor,
                            const Preintegration& pre,
                            const Blocks& blocks) {
  const double* parameters[6];
  for (int b = 0; b < 6; ++b) parameters[b] = blocks[b].data();
  Residual r;
  ASSERT_TRUE(factor.Evaluate(parameters, r.data(), nullptr));
  const Residual expected =
      Whitening(factor, pre) * factor.Residual(ToState(blocks, 0), ToState(blocks, 1));
  EXPECT_LT((r - expected).norm(), 1e-9 * expected.norm());
}

TEST(ImuOdometerFactorTest, ResidualIsWhitenedPreintegrationResidual) {
  const auto pre = MakePreintegration();
  const ImuOdometerFactor factor(pre);
  const auto blocks = MakeParameters(*pre);
  ExpectWhitenedResidual(factor, *pre, blocks);
  EXPECT_EQ(factor.sqrt_information(), pre->SqrtInformation());
  EXPECT_NEAR(factor.misalignment_weight(),
              1.0 / (pre->noise().odometer_misalignment_walk * std::sqrt(pre->sum_dt())),
              1e-9);
}

// The misalignment m turns the wheels' path off the odometer's axis: phi moves by
// phi_misalignment() m, and the last two rows are its walk, m_j - m_i.
TEST(ImuOdometerFactorTest, MisalignmentTurnsThePathAndWalks) {
  const auto pre = MakePreintegration();
  const ImuOdometerFactor factor(pre);
  const auto blocks = MakeParameters(*pre);
  NavState i = ToState(blocks, 0);
  const NavState j = ToState(blocks, 1);
  const Residual r = factor.Residual(i, j);
  EXPECT_LT((r.tail<2>() - (j.m - i.m)).norm(), 1e-15);
  const Eigen::Vector2d m = i.m;
  i.m.setZero();
  const Eigen::Matrix<double, 19, 1> straight = pre->Evaluate(i, j);
  i.m = m;
  const Eigen::Matrix<double, 19, 1> turned = pre->Evaluate(i, j);
  const int phi = preintegration_index::kPhi;
  EXPECT_LT(((straight - turned).segment<3>(phi) - pre->phi_misalignment() * m).norm(), 1e-12);
  EXPECT_GT((pre->phi_misalignment() * m).norm(), 1e-3);  // 25 m/s for 0.3 s at 2 mrad
}

// The residual is eq. (19) but for the odometer-axis component of d_phi, which is in odometer
// units: c_lin / c_i times its length in metres. Pure odometer noise then costs the same at any
// scale estimate, so an unobserved scale is not shrunk.
TEST(ImuOdometerFactorTest, OdometerAxisRowIsInOdometerUnits) {
  const auto pre = MakePreintegration();
  const ImuOdometerFactor factor(pre);
  const auto blocks = MakeParameters(*pre);
  const NavState i = ToState(blocks, 0), j = ToState(blocks, 1);
  const Eigen::Matrix<double, 19, 1> metres = pre->Evaluate(i, j);
  const Residual r = factor.Residual(i, j);
  ASSERT_GT(std::abs(i.c - pre->linearized_c()), 1e-3);  // a state off the linearisation scale
  const int phi = preintegration_index::kPhi;
  const Vector3d axis = pre->R_body_odo().col(0);
  const Vector3d phi_metres = metres.segment<3>(phi), phi_r = r.segment<3>(phi);
  EXPECT_NEAR(axis.dot(phi_r), pre->linearized_c() / i.c * axis.dot(phi_metres), 1e-12);
  const Matrix3d across = Matrix3d::Identity() - axis * axis.transpose();
  EXPECT_LT((across * (phi_r - phi_metres)).norm(), 1e-12);
  for (int k = 0; k < 19; ++k) {
    if (k < phi || k >= phi + 3) {
      EXPECT_EQ(r(k), metres(k)) << "row " << k;
    }
  }
}

struct JacobianCase {
  bool odometer_valid;
  double sway_roll;
};

class ImuOdometerFactorJacobianTest : public ::testing::TestWithParam<JacobianCase> {};

/// The residual rows that carry information: the phi rows are zero without odometer data.
std::vector<int> InformedRows(bool odometer_valid) {
  std::vector<int> rows;
  for (int k = 0; k < kRows; ++k) {
    if (odometer_valid || k < 15 || k > 17) rows.push_back(k);
  }
  return rows;
}

struct NumericJacobian {
  Jacobian whitened;  // of the residual Evaluate returns
  Jacobian raw;       // of Preintegration's residual, before whitening
};

/// Central differences of the factor's residuals along block b's tangent directions.
NumericJacobian CentralDifferences(const ImuOdometerFactor& factor, const Blocks& blocks, int b) {
  auto whitened = [&](const Blocks& x) {
    const double* parameters[6];
    for (int i = 0; i < 6; ++i) parameters[i] = x[i].data();
    Residual r;
    factor.Evaluate(parameters, r.data(), nullptr);
    return r;
  };
  auto raw = [&](const Blocks& x) { return factor.Residual(ToState(x, 0), ToState(x, 1)); };
  const double h = 1e-6;
  const int m = kTangentSizes[b];
  NumericJacobian numeric{Jacobian(kRows, m), Jacobian(kRows, m)};
  for (int d = 0; d < m; ++d) {
    const Blocks plus = Perturb(blocks, b, d, h), minus = Perturb(blocks, b, d, -h);
    numeric.whitened.col(d) = (whitened(plus) - whitened(minus)) / (2 * h);
    numeric.raw.col(d) = (raw(plus) - raw(minus)) / (2 * h);
  }
  return numeric;
}

/// The analytic Jacobian unwhitened (L^-1 J on the informed rows) against the numeric one, row by
/// row, so that rows with small information are not hidden behind the large ones.
void ExpectUnwhitenedRowsMatch(const Jacobian& analytic,
                               const Jacobian& numeric_raw,
                               const Eigen::MatrixXd& L,
                               const std::vector<int>& rows,
                               int b) {
  const Eigen::MatrixXd L_sub = L(rows, rows);
  const Eigen::MatrixXd numeric = numeric_raw(rows, Eigen::all);
  const Eigen::MatrixXd unwhitened =
      L_sub.triangularView<Eigen::Upper>().solve(Eigen::MatrixXd(analytic(rows, Eigen::all)));
  for (size_t k = 0; k < rows.size(); ++k) {
    const double row_scale = std::max(numeric.row(k).cwiseAbs().maxCoeff(), 1e-2);
    EXPECT_LT((unwhitened.row(k) - numeric.row(k)).cwiseAbs().maxCoeff(), 1e-5 * row_scale)
        << "block " << b << " row " << rows[k] << "\nanalytic " << unwhitened.row(k)
        << "\nnumeric  " << numeric.row(k);
  }
}

// Every Jacobian against central differences through the manifold. Checked twice: whitened as
// returned (relative to each block's largest entry), and unwhitened (L^-1 J against numeric
// derivatives of Preintegration::Evaluate, row by row) so that rows with small information are
// not hidden behind the large ones.
TEST_P(ImuOdometerFactorJacobianTest, MatchesNumericDifferentiation) {
  const auto pre = MakePreintegration(GetParam().odometer_valid, GetParam().sway_roll);
  EXPECT_EQ(pre->odometer_used(), GetParam().odometer_valid);
  const ImuOdometerFactor factor(pre);
  const Blocks blocks = MakeParameters(*pre);
  Residual residual;
  const std::array<Jacobian, 6> analytic = AnalyticJacobians(factor, blocks, &residual);
  EXPECT_GT(residual.norm(), 1.0);  // a non-trivial state
  const Eigen::MatrixXd L = Whitening(factor, *pre);
  const std::vector<int> rows = InformedRows(GetParam().odometer_valid);

  for (int b = 0; b < 6; ++b) {
    const NumericJacobian numeric = CentralDifferences(factor, blocks, b);
    const Jacobian a = analytic[b].leftCols(kTangentSizes[b]);
    ASSERT_TRUE(a.allFinite()) << "block " << b;
    if (kBlockSizes[b] == 7) {
      EXPECT_EQ(analytic[b].col(6).cwiseAbs().maxCoeff(), 0.0);
    }
    const double scale = std::max(numeric.whitened.cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_LT((a - numeric.whitened).cwiseAbs().maxCoeff(), 1e-5 * scale) << "block " << b;
    ExpectUnwhitenedRowsMatch(a, numeric.raw, L, rows, b);
  }
}

INSTANTIATE_TEST_SUITE_P(Odometer,
                         ImuOdometerFactorJacobianTest,
                         ::testing::Values(JacobianCase{true, 0.0},
                                           JacobianCase{false, 0.0},
                                           JacobianCase{true, 0.004}));

TEST(ImuOdometerFactorTest, NoticesARepropagatedPreintegration) {
  const auto pre = MakePreintegration();
  const ImuOdometerFactor factor(pre);
  const auto blocks = MakeParameters(*pre);
  pre->Repropagate(pre->linearized_ba() + Vector3d(0.01, 0.0, 0.0), pre->linearized_bg(), 1.01);
  ExpectWhitenedResidual(factor, *pre, blocks);
}

}  // namespace
}  // namespace raillomer
