#include "estimator/factors/lidar_factors.h"

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <memory>
#include <random>
#include <vector>

#include <ceres/ceres.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "estimator/factors/heading_factor.h"
#include "estimator/factors/pose_manifold.h"

namespace raillomer {
namespace {

using Pose = std::array<double, kPoseSize>;
using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

Pose MakePose(const Eigen::Vector3d& p, const Eigen::Vector3d& rotation_vector) {
  Pose pose;
  Eigen::Map<Eigen::Vector3d>(pose.data()) = p;
  Eigen::Map<Eigen::Quaterniond>(pose.data() + 3) = ExpQuaternion(rotation_vector);
  return pose;
}

Eigen::Vector3d Position(const Pose& pose) {
  return Eigen::Map<const Eigen::Vector3d>(pose.data());
}

Eigen::Matrix3d Rotation(const Pose& pose) {
  return Eigen::Map<const Eigen::Quaterniond>(pose.data() + 3).toRotationMatrix();
}

/// A world point expressed in the body frame of `pose` (T_world_body).
Eigen::Vector3d ToBody(const Pose& pose, const Eigen::Vector3d& world) {
  return Rotation(pose).transpose() * (world - Position(pose));
}

/// Tangent Jacobian of block `index` by central differences through PoseManifold::Plus.
Eigen::MatrixXd NumericJacobian(const ceres::CostFunction& cost,
                                const std::vector<double*>& blocks,
                                size_t index,
                                double step = 1e-6) {
  const int size = cost.parameter_block_sizes()[index];
  const int tangent = size == kPoseSize ? kPoseTangentSize : size;
  const int rows = cost.num_residuals();
  Eigen::MatrixXd jacobian(rows, tangent);
  std::vector<const double*> values(blocks.begin(), blocks.end());
  std::vector<double> moved(size);
  Eigen::VectorXd plus(rows), minus(rows);
  const PoseManifold manifold;
  for (int k = 0; k < tangent; ++k) {
    for (double sign : {1.0, -1.0}) {
      Eigen::VectorXd delta = Eigen::VectorXd::Zero(tangent);
      delta(k) = sign * step;
      if (size == kPoseSize) {
        manifold.Plus(blocks[index], delta.data(), moved.data());
      } else {
        for (int e = 0; e < size; ++e) moved[e] = blocks[index][e] + delta(e);
      }
      values[index] = moved.data();
      cost.Evaluate(values.data(), sign > 0 ? plus.data() : minus.data(), nullptr);
    }
    values[index] = blocks[index];
    jacobian.col(k) = (plus - minus) / (2.0 * step);
  }
  return jacobian;
}

/// The analytic Jacobians of every block: the tangent part must match central differences and
/// the 7th column of a pose block must be zero. Returns the tangent Jacobians.
std::vector<Eigen::MatrixXd> ExpectJacobiansMatch(const ceres::CostFunction& cost,
                                                  const std::vector<double*>& blocks,
                                                  double tolerance = 1e-7) {
  const int rows = cost.num_residuals();
  const std::vector<int32_t>& sizes = cost.parameter_block_sizes();
  std::vector<RowMatrix> analytic(blocks.size());
  std::vector<double*> pointers(blocks.size());
  for (size_t k = 0; k < blocks.size(); ++k) {
    analytic[k] = RowMatrix::Constant(rows, sizes[k], 1e9);  // every entry must be written
    pointers[k] = analytic[k].data();
  }
  Eigen::VectorXd residual(rows);
  std::vector<const double*> values(blocks.begin(), blocks.end());
  EXPECT_TRUE(cost.Evaluate(values.data(), residual.data(), pointers.data()));
  std::vector<Eigen::MatrixXd> tangent_jacobians;
  for (size_t k = 0; k < blocks.size(); ++k) {
    const Eigen::MatrixXd numeric = NumericJacobian(cost, blocks, k);
    const Eigen::MatrixXd tangent = analytic[k].leftCols(numeric.cols());
    const double scale = std::max(1.0, numeric.cwiseAbs().maxCoeff());
    EXPECT_LT((tangent - numeric).cwiseAbs().maxCoeff(), tolerance * scale)
        << "block " << k << "\nanalytic\n"
        << tangent << "\nnumeric\n"
        << numeric;
    if (sizes[k] == kPoseSize) {
      EXPECT_EQ(analytic[k].col(6).cwiseAbs().maxCoeff(), 0.0) << "block " << k;
    }
    tangent_jacobians.push_back(tangent);
  }
  return tangent_jacobians;
}

double EvaluateScalar(const ceres::CostFunction& cost, const std::vector<double*>& blocks) {
  std::vector<const double*> values(blocks.begin(), blocks.end());
  double residual = 0.0;
  cost.Evaluate(values.data(), &residual, nullptr);
  return residual;
}

Eigen::VectorXd EvaluateVector(const ceres::CostFunction& cost,
                               const std::vector<double*>& blocks) {
  std::vector<const double*> values(blocks.begin(), blocks.end());
  Eigen::VectorXd residual(cost.num_residuals());
  cost.Evaluate(values.data(), residual.data(), nullptr);
  return residual;
}

/// Pose error as (position m, rotation rad).
std::pair<double, double> PoseError(const Pose& a, const Pose& b) {
  const Eigen::Map<const Eigen::Quaterniond> qa(a.data() + 3), qb(b.data() + 3);
  return {(Position(a) - Position(b)).norm(), LogQuaternion(qa.conjugate() * qb).norm()};
}

const Pose kTruePose = MakePose({3.0, -1.0, 0.5}, {0.1, -0.2, 0.7});

TEST(PointToPlaneFactor, ResidualIsSignedDistance) {
  Pose pose = kTruePose;
  const Eigen::Vector3d normal = Eigen::Vector3d(1.0, 2.0, 2.0) / 3.0;
  const double d = -4.0;
  const Eigen::Vector3d on_plane = 4.0 * normal + Eigen::Vector3d(2.0, -1.0, 0.0);
  ASSERT_NEAR(normal.dot(on_plane) + d, 0.0, 1e-12);
  const PointToPlaneFactor on(ToBody(pose, on_plane), normal, d, 2.0);
  EXPECT_NEAR(EvaluateScalar(on, {pose.data()}), 0.0, 1e-12);
  const PointToPlaneFactor off(ToBody(pose, on_plane + 0.25 * normal), normal, d, 2.0);
  EXPECT_NEAR(EvaluateScalar(off, {pose.data()}), 0.5, 1e-12);
  const PointToPlaneFactor below(ToBody(pose, on_plane - 0.1 * normal), normal, d, 1.0);
  EXPECT_NEAR(EvaluateScalar(below, {pose.data()}), -0.1, 1e-12);
}

TEST(PointToPlaneFactor, JacobianMatchesNumeric) {
  for (const Pose& start : {kTruePose, MakePose({-20.0, 5.0, 1.0}, {2.0, 0.5, -1.0})}) {
    Pose pose = start;
    const Eigen::Vector3d normal = Eigen::Vector3d(0.3, -0.4, 0.8).normalized();
    const PointToPlaneFactor factor({4.0, -2.0, 1.5}, normal, 1.7, 3.0);
    ExpectJacobiansMatch(factor, {pose.data()});
  }
}

TEST(PointToLineFactor, ResidualIsPerpendicularOffset) {
  Pose pose = kTruePose;
  const Eigen::Vector3d a(1.0, 2.0, 3.0);
  const Eigen::Vector3d u = Eigen::Vector3d(1.0, 1.0, 0.0).normalized();
  const Eigen::Vector3d perpendicular = Eigen::Vector3d(0.0, 0.0, 1.0);
  const PointToLineFactor on(ToBody(pose, a + 7.0 * u), a, u, 2.0);
  EXPECT_NEAR(EvaluateVector(on, {pose.data()}).norm(), 0.0, 1e-12);
  const PointToLineFactor off(ToBody(pose, a - 3.0 * u + 0.4 * perpendicular), a, u, 2.0);
  const Eigen::Vector3d r = EvaluateVector(off, {pose.data()});
  EXPECT_NEAR(r.norm(), 0.8, 1e-12);
  EXPECT_NEAR((r - 0.8 * perpendicular).norm(), 0.0, 1e-12);
  // An unnormalised direction is normalised by the factor.
  const PointToLineFactor scaled(ToBody(pose, a + 0.4 * perpendicular), a, 5.0 * u, 1.0);
  EXPECT_NEAR(EvaluateVector(scaled, {pose.data()}).norm(), 0.4, 1e-12);
}

TEST(PointToLineFactor, JacobianMatchesNumeric) {
  for (const Pose& start : {kTruePose, MakePose({-20.0, 5.0, 1.0}, {2.0, 0.5, -1.0})}) {
    Pose pose = start;
    const PointToLineFactor factor({4.0, -2.0, 1.5}, {1.0, 0.0, -1.0}, {0.2, 0.9, 0.1}, 2.5);
    ExpectJacobiansMatch(factor, {pose.data()});
  }
}

/// Remapping of the translation along `direction` away from p0 only.
PoseRemapping TranslationRemapping(const Eigen::Vector3d& p0, const Eigen::Vector3d& direction) {
  PoseRemapping remapping;
  remapping.p0 = p0;
  remapping.direction = direction;
  return remapping;
}

/// Remapping of the heading away from q0 only.
PoseRemapping HeadingRemapping(const Eigen::Quaterniond& q0) {
  PoseRemapping remapping;
  remapping.q0 = q0;
  return remapping;
}

TEST(RemappedPoseCost, TranslationJacobianMatchesNumeric) {
  Pose pose = kTruePose;
  const Eigen::Vector3d p0 = Position(pose) + Eigen::Vector3d(0.3, -0.2, 0.1);
  const RemappedPoseCost plane(std::make_shared<PointToLineFactor>(Eigen::Vector3d(4.0, -2.0, 1.5),
                                                                   Eigen::Vector3d(1.0, 0.0, -1.0),
                                                                   Eigen::Vector3d(0.2, 0.9, 0.1),
                                                                   2.5),
                               TranslationRemapping(p0, Eigen::Vector3d(1.0, 1.0, 0.2)));
  ExpectJacobiansMatch(plane, {pose.data()});
}

// The wrapped cost does not change with the translation along the projected direction, and
// changes as before across it.
TEST(RemappedPoseCost, IgnoresTranslationAlongTheDirection) {
  Pose pose = kTruePose;
  const Eigen::Vector3d u = Eigen::Vector3d(1.0, 0.5, 0.0).normalized();
  // A plane whose normal has a component along u: it would pull the pose along u.
  const Eigen::Vector3d normal = Eigen::Vector3d(0.6, 0.0, 0.8);
  auto inner =
      std::make_shared<PointToPlaneFactor>(Eigen::Vector3d(2.0, 1.0, -1.0), normal, 0.3, 1.0);
  const RemappedPoseCost projected(inner, TranslationRemapping(Position(pose), u));
  const double r0 = EvaluateScalar(projected, {pose.data()});
  EXPECT_NEAR(r0, EvaluateScalar(*inner, {pose.data()}), 1e-12);
  Pose moved = pose;
  for (int k = 0; k < 3; ++k) moved[k] += 0.7 * u[k];
  EXPECT_NEAR(EvaluateScalar(projected, {moved.data()}), r0, 1e-12);
  EXPECT_GT(std::abs(EvaluateScalar(*inner, {moved.data()}) - r0), 0.1);
  const Eigen::Vector3d across = u.cross(Eigen::Vector3d::UnitZ()).normalized();
  Pose sideways = pose;
  for (int k = 0; k < 3; ++k) sideways[k] += 0.5 * across[k] + 0.2 * (k == 2);
  EXPECT_NEAR(EvaluateScalar(projected, {sideways.data()}),
              EvaluateScalar(*inner, {sideways.data()}),
              1e-12);
}

// At the reference rotation the wrapped Jacobian is exact; a few milliradians away (a solve's
// step) it still matches to first order.
TEST(RemappedPoseCost, HeadingJacobianMatchesNumeric) {
  const auto line = std::make_shared<PointToLineFactor>(Eigen::Vector3d(4.0, -2.0, 1.5),
                                                        Eigen::Vector3d(1.0, 0.0, -1.0),
                                                        Eigen::Vector3d(0.2, 0.9, 0.1),
                                                        2.5);
  Pose pose = kTruePose;
  const Eigen::Quaterniond q(Rotation(pose));
  ExpectJacobiansMatch(RemappedPoseCost(line, HeadingRemapping(q)), {pose.data()});
  const Eigen::Quaterniond q_near = ExpQuaternion(Eigen::Vector3d(0.002, -0.001, 0.003)) * q;
  ExpectJacobiansMatch(RemappedPoseCost(line, HeadingRemapping(q_near)), {pose.data()}, 2e-3);
  // Both at once, as a degenerate frame with a weakly held heading has them.
  PoseRemapping both = HeadingRemapping(q);
  both.p0 = Position(pose) + Eigen::Vector3d(0.3, -0.2, 0.1);
  both.direction = Eigen::Vector3d(1.0, 1.0, 0.2);
  ExpectJacobiansMatch(RemappedPoseCost(line, both), {pose.data()});
  // With the heading's profile the turn about z follows the position and the level turns; the
  // remapped rotation is then milliradians from q0, so first order again.
  PoseRemapping profiled = HeadingRemapping(q);
  profiled.heading_z0 = 0.004;
  profiled.heading_gain << 0.01, -0.02, 0.005, 0.3, -0.2;
  profiled.heading_p_ref = Position(pose) + Eigen::Vector3d(0.2, 0.1, -0.1);
  ExpectJacobiansMatch(RemappedPoseCost(line, profiled), {pose.data()}, 2e-3);
  profiled.p0 = both.p0;
  profiled.direction = both.direction;
  ExpectJacobiansMatch(RemappedPoseCost(line, profiled), {pose.data()}, 2e-3);
}

// With a profile the wrapped cost is still blind to the turn about the vertical, and it
// evaluates the inner cost at the profile's heading.
TEST(RemappedPoseCost, TheProfileSetsTheHeading) {
  Pose pose = kTruePose;
  const Eigen::Quaterniond q(Rotation(pose));
  auto inner = std::make_shared<PointToPlaneFactor>(
      Eigen::Vector3d(20.0, 5.0, -1.0), Eigen::Vector3d(0.0, 1.0, 0.2).normalized(), 0.3, 1.0);
  PoseRemapping profiled = HeadingRemapping(q);
  profiled.heading_z0 = 0.01;
  profiled.heading_gain << 0.0, 0.05, 0.0, 0.0, 0.0;
  profiled.heading_p_ref = Position(pose);
  const RemappedPoseCost projected(inner, profiled);
  auto turned = [&](const Pose& from, double yaw) {
    Pose out = from;
    Eigen::Map<Eigen::Quaterniond>(out.data() + 3) =
        (Eigen::Quaterniond(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ())) *
         Eigen::Quaterniond(Rotation(from)))
            .normalized();
    return out;
  };
  Pose at_z0 = turned(pose, 0.01);
  EXPECT_NEAR(
      EvaluateScalar(projected, {pose.data()}), EvaluateScalar(*inner, {at_z0.data()}), 1e-9);
  Pose yawed = turned(pose, -0.04);
  EXPECT_NEAR(
      EvaluateScalar(projected, {yawed.data()}), EvaluateScalar(*inner, {at_z0.data()}), 1e-9);
  // 0.2 m along world y adds 0.05 * 0.2 = 0.01 rad to the heading the inner cost sees.
  Pose moved = pose;
  moved[1] += 0.2;
  Pose moved_at = turned(moved, 0.02);
  EXPECT_NEAR(
      EvaluateScalar(projected, {moved.data()}), EvaluateScalar(*inner, {moved_at.data()}), 1e-9);
}

// The wrapped cost does not change with a turn about the vertical, and changes as before with a
// turn about a level axis.
TEST(RemappedPoseCost, IgnoresTurnsAboutTheVertical) {
  Pose pose = kTruePose;
  // A plane seen 20 m to the side: a turn about z swings the point across it.
  const Eigen::Vector3d normal = Eigen::Vector3d(0.0, 1.0, 0.2).normalized();
  auto inner =
      std::make_shared<PointToPlaneFactor>(Eigen::Vector3d(20.0, 5.0, -1.0), normal, 0.3, 1.0);
  const RemappedPoseCost projected(inner, HeadingRemapping(Eigen::Quaterniond(Rotation(pose))));
  const double r0 = EvaluateScalar(projected, {pose.data()});
  EXPECT_NEAR(r0, EvaluateScalar(*inner, {pose.data()}), 1e-12);
  auto turned = [&](const Eigen::Vector3d& world_axis, double angle) {
    Pose out = pose;
    Eigen::Map<Eigen::Quaterniond>(out.data() + 3) =
        (Eigen::Quaterniond(Eigen::AngleAxisd(angle, world_axis)) *
         Eigen::Quaterniond(Rotation(pose)))
            .normalized();
    return out;
  };
  Pose yawed = turned(Eigen::Vector3d::UnitZ(), 0.05);
  EXPECT_NEAR(EvaluateScalar(projected, {yawed.data()}), r0, 1e-9);
  EXPECT_GT(std::abs(EvaluateScalar(*inner, {yawed.data()}) - r0), 0.1);
  Pose rolled = turned(Eigen::Vector3d::UnitX(), 0.05);
  EXPECT_NEAR(
      EvaluateScalar(projected, {rolled.data()}), EvaluateScalar(*inner, {rolled.data()}), 1e-9);
  EXPECT_GT(std::abs(EvaluateScalar(*inner, {rolled.data()}) - r0), 0.01);
}

/// The plane n_w . x + d_w = 0 expressed in the body frame of `pose`.
std::pair<Eigen::Vector3d, double> PlaneInBody(const Pose& pose,
                                               const Eigen::Vector3d& n_world,
                                               double d_world) {
  return {Rotation(pose).transpose() * n_world, d_world + n_world.dot(Position(pose))};
}

struct RailPlaneSetup {
  Pose pose_i = MakePose({10.0, -2.0, 0.3}, {0.02, -0.03, 0.6});
  Pose pose_j = MakePose({18.0, 3.0, 0.5}, {-0.01, 0.04, 0.75});
  Eigen::Vector3d n_world = Eigen::Vector3d(0.03, -0.02, 1.0).normalized();
  double d_world = 1.2;
};

TEST(RailPlaneFactor, ConsistentPlanesGiveZeroResidual) {
  RailPlaneSetup s;
  const auto [n_i, d_i] = PlaneInBody(s.pose_i, s.n_world, s.d_world);
  const auto [n_j, d_j] = PlaneInBody(s.pose_j, s.n_world, s.d_world);
  const RailPlaneFactor factor(n_i, d_i, n_j, d_j, 10.0, 5.0);
  EXPECT_LT(EvaluateVector(factor, {s.pose_i.data(), s.pose_j.data()}).norm(), 1e-12);
  // Raising the plane measured in frame j by 0.1 m gives a distance residual of 5 * 0.1.
  const RailPlaneFactor raised(n_i, d_i, n_j, d_j + 0.1, 10.0, 5.0);
  const Eigen::Vector4d r = EvaluateVector(raised, {s.pose_i.data(), s.pose_j.data()});
  EXPECT_NEAR(r(3), -0.5, 1e-12);
  EXPECT_LT(r.head<3>().norm(), 1e-12);
}

TEST(RailPlaneFactor, JacobianMatchesNumeric) {
  RailPlaneSetup s;
  // Planes that do not agree, so the residual is not zero.
  const RailPlaneFactor factor(Eigen::Vector3d(0.1, 0.05, 1.0).normalized(),
                               1.3,
                               Eigen::Vector3d(-0.05, 0.02, 1.0).normalized(),
                               0.9,
                               20.0,
                               8.0);
  ExpectJacobiansMatch(factor, {s.pose_i.data(), s.pose_j.data()});
}

TEST(RailPlaneFactor, ConstrainsRollPitchAndHeightOnly) {
  RailPlaneSetup s;
  const auto [n_i, d_i] = PlaneInBody(s.pose_i, s.n_world, s.d_world);
  const auto [n_j, d_j] = PlaneInBody(s.pose_j, s.n_world, s.d_world);
  const RailPlaneFactor factor(n_i, d_i, n_j, d_j, 10.0, 5.0);
  const std::vector<Eigen::MatrixXd> jacobians =
      ExpectJacobiansMatch(factor, {s.pose_i.data(), s.pose_j.data()});
  Eigen::Matrix<double, 4, 12> full;
  full << jacobians[0], jacobians[1];
  // Only the relative pose matters and the plane fixes 3 of its 6 degrees of freedom.
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd_full(full);
  EXPECT_EQ((svd_full.singularValues().array() > 1e-9).count(), 3);
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd_j(jacobians[1]);
  EXPECT_EQ((svd_j.singularValues().array() > 1e-9).count(), 3);

  // Null directions of pose j: yaw about the plane normal, translation within the plane.
  const Eigen::MatrixXd& jac_j = jacobians[1];
  Eigen::Matrix<double, 6, 1> yaw, along_1, along_2, roll, pitch, height;
  const Eigen::Vector3d in_plane_1 = s.n_world.unitOrthogonal();
  const Eigen::Vector3d in_plane_2 = s.n_world.cross(in_plane_1);
  yaw << Eigen::Vector3d::Zero(), n_j;
  along_1 << in_plane_1, Eigen::Vector3d::Zero();
  along_2 << in_plane_2, Eigen::Vector3d::Zero();
  EXPECT_LT((jac_j * yaw).norm(), 1e-12);
  EXPECT_LT((jac_j * along_1).norm(), 1e-12);
  EXPECT_LT((jac_j * along_2).norm(), 1e-12);
  // Roll and pitch (body axes perpendicular to the normal) and height are observed.
  roll << Eigen::Vector3d::Zero(), n_j.unitOrthogonal();
  pitch << Eigen::Vector3d::Zero(), n_j.cross(n_j.unitOrthogonal());
  height << s.n_world, Eigen::Vector3d::Zero();
  EXPECT_NEAR((jac_j * roll).norm(), 10.0, 1e-9);
  EXPECT_NEAR((jac_j * pitch).norm(), 10.0, 1e-9);
  EXPECT_NEAR((jac_j * height).norm(), 5.0, 1e-9);
}

TEST(HeadingHoldFactor, ResidualIsTheHeadingErrorWrapped) {
  // Heading 0.3 rad with roll and pitch: the body's x axis still points 0.3 rad from world x.
  const Eigen::Quaterniond q = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd(-0.05, Eigen::Vector3d::UnitY()) *
                               Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX());
  EXPECT_NEAR(HeadingOf(q), 0.3, 1e-12);
  Pose pose;
  Eigen::Map<Eigen::Vector3d>(pose.data()) = Eigen::Vector3d(5.0, -2.0, 1.0);
  Eigen::Map<Eigen::Quaterniond>(pose.data() + 3) = q;
  EXPECT_NEAR(EvaluateScalar(HeadingHoldFactor(0.29, 1e-3), {pose.data()}), 10.0, 1e-9);
  // Across +-pi: 3.1 rad held to -3.1 rad is 0.083 rad off, not 6.2.
  Pose back = MakePose(Eigen::Vector3d::Zero(), Eigen::Vector3d(0.0, 0.0, 3.1));
  EXPECT_NEAR(EvaluateScalar(HeadingHoldFactor(-3.1, 1.0), {back.data()}), 6.2 - 2.0 * M_PI, 1e-12);
}

TEST(HeadingHoldFactor, JacobianMatchesNumeric) {
  for (const Eigen::Vector3d& rv : {Eigen::Vector3d(0.0, 0.0, 0.0),
                                    Eigen::Vector3d(0.02, -0.01, 1.2),
                                    Eigen::Vector3d(0.1, 0.2, -2.0),
                                    Eigen::Vector3d(0.03, 0.01, 3.1)}) {
    Pose pose = MakePose(Eigen::Vector3d(1.0, 2.0, 3.0), rv);
    const HeadingHoldFactor factor(0.5, 2e-3);
    ExpectJacobiansMatch(factor, {pose.data()}, 1e-6);
  }
}

TEST(HeadingHoldFactor, LeavesPositionAndRollFree) {
  // A tilted pose: moving it, or turning it about its own x axis (roll), leaves the heading.
  Pose pose = MakePose(Eigen::Vector3d(1.0, 2.0, 3.0), Eigen::Vector3d(0.05, -0.03, 0.7));
  const HeadingHoldFactor factor(0.6, 1e-3);
  const double r0 = EvaluateScalar(factor, {pose.data()});
  const PoseManifold manifold;
  for (int k : {0, 1, 2, 3}) {
    Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
    delta(k) = 0.01;
    Pose moved;
    manifold.Plus(pose.data(), delta.data(), moved.data());
    EXPECT_NEAR(EvaluateScalar(factor, {moved.data()}), r0, 1e-9) << "tangent " << k;
  }
}

TEST(LongitudinalShiftFactor, ResidualIsForwardMotion) {
  // Body i faces +y (yaw 90 deg); moving 2 m along world +y is 2 m forward.
  Pose pose_i = MakePose({1.0, 1.0, 0.0}, {0.0, 0.0, M_PI / 2.0});
  Pose pose_j = MakePose({1.0, 3.0, 0.0}, {0.0, 0.0, 1.0});
  const LongitudinalShiftFactor factor(1.5, 0.25);
  EXPECT_NEAR(EvaluateScalar(factor, {pose_i.data(), pose_j.data()}), 2.0, 1e-12);
  // Sideways motion does not count.
  Pose pose_k = MakePose({4.0, 1.0, 0.0}, {0.0, 0.0, 0.0});
  EXPECT_NEAR(EvaluateScalar(factor, {pose_i.data(), pose_k.data()}), -6.0, 1e-12);
}

TEST(LongitudinalShiftFactor, JacobianMatchesNumeric) {
  Pose pose_i = MakePose({10.0, -2.0, 0.3}, {0.1, -0.3, 0.6});
  Pose pose_j = MakePose({18.0, 3.0, 0.5}, {-0.2, 0.4, 0.75});
  const LongitudinalShiftFactor factor(7.0, 0.1);
  ExpectJacobiansMatch(factor, {pose_i.data(), pose_j.data()});
}

/// Solves `problem` to convergence with tight tolerances.
void SolveToConvergence(ceres::Problem* problem) {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::DENSE_QR;
  options.max_num_iterations = 50;
  options.function_tolerance = 1e-16;
  options.gradient_tolerance = 1e-16;
  options.parameter_tolerance = 1e-16;
  ceres::Solver::Summary summary;
  ceres::Solve(options, problem, &summary);
  EXPECT_TRUE(summary.IsSolutionUsable()) << summary.BriefReport();
}

/// Solves for one pose from `factors` starting at `start`; Ceres takes the factors.
Pose SolvePose(const Pose& start, std::vector<ceres::CostFunction*> factors) {
  Pose pose = start;
  ceres::Problem problem;
  problem.AddParameterBlock(pose.data(), kPoseSize, new PoseManifold);
  for (ceres::CostFunction* factor : factors) {
    problem.AddResidualBlock(factor, nullptr, pose.data());
  }
  SolveToConvergence(&problem);
  return pose;
}

const Pose kPerturbedStart = MakePose({3.4, -1.3, 0.2}, {0.25, -0.05, 0.55});

TEST(PointToPlaneFactor, RecoversPoseFromThreePlanes) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uniform(-8.0, 8.0);
  const std::array<Eigen::Vector3d, 3> normals = {Eigen::Vector3d(0.0, 0.0, 1.0),
                                                  Eigen::Vector3d(0.1, 1.0, 0.0).normalized(),
                                                  Eigen::Vector3d(1.0, -0.2, 0.3).normalized()};
  const std::array<double, 3> distances = {0.5, -6.0, -15.0};
  std::vector<ceres::CostFunction*> factors;
  for (size_t k = 0; k < normals.size(); ++k) {
    const Eigen::Vector3d e1 = normals[k].unitOrthogonal();
    const Eigen::Vector3d e2 = normals[k].cross(e1);
    for (int n = 0; n < 20; ++n) {
      const Eigen::Vector3d world =
          -distances[k] * normals[k] + uniform(rng) * e1 + uniform(rng) * e2;
      factors.push_back(
          new PointToPlaneFactor(ToBody(kTruePose, world), normals[k], distances[k], 1.0));
    }
  }
  const Pose solved = SolvePose(kPerturbedStart, factors);
  const auto [position_error, rotation_error] = PoseError(solved, kTruePose);
  EXPECT_LT(position_error, 1e-6);
  EXPECT_LT(rotation_error, 1e-6);
}

TEST(PointToLineFactor, RecoversPoseFromThreeLines) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> uniform(-6.0, 6.0);
  const std::array<Eigen::Vector3d, 3> points = {Eigen::Vector3d(0.0, 3.0, 2.0),
                                                 Eigen::Vector3d(10.0, -3.0, 1.0),
                                                 Eigen::Vector3d(5.0, 0.0, 4.0)};
  const std::array<Eigen::Vector3d, 3> directions = {Eigen::Vector3d(1.0, 0.1, 0.0).normalized(),
                                                     Eigen::Vector3d(0.0, 0.0, 1.0),
                                                     Eigen::Vector3d(0.2, 1.0, 0.1).normalized()};
  std::vector<ceres::CostFunction*> factors;
  for (size_t k = 0; k < points.size(); ++k) {
    for (int n = 0; n < 10; ++n) {
      const Eigen::Vector3d world = points[k] + uniform(rng) * directions[k];
      // The line is given by another point on it, so `a` is not the sample's foot point.
      factors.push_back(new PointToLineFactor(
          ToBody(kTruePose, world), points[k] + 2.0 * directions[k], directions[k], 1.0));
    }
  }
  const Pose solved = SolvePose(kPerturbedStart, factors);
  const auto [position_error, rotation_error] = PoseError(solved, kTruePose);
  EXPECT_LT(position_error, 1e-6);
  EXPECT_LT(rotation_error, 1e-6);
}

/// A frame's terms seen from kTruePose: points on three planes and along two lines, with a
/// fraction pushed off their feature (outliers, beyond the Huber scale), or, when `degenerate`,
/// on the ground plane only (nothing observes x, y or yaw).
struct FrameTerms {
  std::vector<PlaneTerm> planes;
  std::vector<LineTerm> lines;
  std::vector<Eigen::Vector3d> line_directions;  ///< of each line term, for PointToLineFactor
};

FrameTerms MakeFrameTerms(bool degenerate, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(-8.0, 8.0);
  std::normal_distribution<double> noise(0.0, 0.05);
  std::bernoulli_distribution outlier(0.15), upward(0.5);
  const std::array<Eigen::Vector3d, 3> normals = {Eigen::Vector3d(0.0, 0.0, 1.0),
                                                  Eigen::Vector3d(0.1, 1.0, 0.0).normalized(),
                                                  Eigen::Vector3d(1.0, -0.2, 0.3).normalized()};
  const std::array<double, 3> distances = {0.5, -6.0, -15.0};
  FrameTerms terms;
  for (size_t k = 0; k < (degenerate ? 1 : normals.size()); ++k) {
    const Eigen::Vector3d e1 = normals[k].unitOrthogonal();
    const Eigen::Vector3d e2 = normals[k].cross(e1);
    for (int n = 0; n < 40; ++n) {
      const double off = noise(rng) + (outlier(rng) ? (upward(rng) ? 2.5 : -2.5) : 0.0);
      const Eigen::Vector3d world =
          (off - distances[k]) * normals[k] + uniform(rng) * e1 + uniform(rng) * e2;
      terms.planes.push_back({ToBody(kTruePose, world), normals[k], distances[k], 3.0});
    }
  }
  if (degenerate) return terms;
  const std::array<Eigen::Vector3d, 2> points = {Eigen::Vector3d(0.0, 3.0, 2.0),
                                                 Eigen::Vector3d(10.0, -3.0, 1.0)};
  const std::array<Eigen::Vector3d, 2> directions = {Eigen::Vector3d(1.0, 0.1, 0.0).normalized(),
                                                     Eigen::Vector3d(0.0, 0.0, 1.0)};
  for (size_t k = 0; k < points.size(); ++k) {
    const Eigen::Vector3d side = directions[k].unitOrthogonal();
    for (int n = 0; n < 15; ++n) {
      const double off = noise(rng) + (outlier(rng) ? (upward(rng) ? 1.5 : -1.5) : 0.0);
      const Eigen::Vector3d world = points[k] + uniform(rng) * directions[k] + off * side;
      terms.lines.emplace_back(ToBody(kTruePose, world), points[k], directions[k], 2.0);
      terms.line_directions.push_back(directions[k]);
    }
  }
  return terms;
}

/// Cost, tangent gradient and Gauss-Newton matrix J^T J of a problem on one pose at `pose`.
struct Linearisation {
  double cost = 0.0;
  Eigen::VectorXd gradient;
  Eigen::MatrixXd hessian;
};

Linearisation Linearise(ceres::Problem* problem) {
  Linearisation out;
  std::vector<double> gradient;
  ceres::CRSMatrix crs;
  problem->Evaluate(ceres::Problem::EvaluateOptions(), &out.cost, nullptr, &gradient, &crs);
  out.gradient = Eigen::Map<Eigen::VectorXd>(gradient.data(), gradient.size());
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int row = 0; row < crs.num_rows; ++row) {
    for (int k = crs.rows[row]; k < crs.rows[row + 1]; ++k) J(row, crs.cols[k]) = crs.values[k];
  }
  out.hessian = J.transpose() * J;
  return out;
}

/// The frame's terms as one LidarFrameCost, or as one Huber-robustified block per term.
void AddFrame(const FrameTerms& terms, bool folded, ceres::Problem* problem, double* pose) {
  problem->AddParameterBlock(pose, kPoseSize, new PoseManifold);
  if (folded) {
    problem->AddResidualBlock(new LidarFrameCost(terms.planes, terms.lines, 1.0), nullptr, pose);
    return;
  }
  for (const PlaneTerm& m : terms.planes) {
    problem->AddResidualBlock(
        new PointToPlaneFactor(m.p_body, m.normal, m.d, m.weight), new ceres::HuberLoss(1.0), pose);
  }
  for (size_t k = 0; k < terms.lines.size(); ++k) {
    const LineTerm& m = terms.lines[k];
    problem->AddResidualBlock(
        new PointToLineFactor(m.p_body, m.point, terms.line_directions[k], m.weight),
        new ceres::HuberLoss(1.0),
        pose);
  }
}

TEST(LidarFrameCost, HasTheSameCostGradientAndNormalEquationsAsOneBlockPerTerm) {
  for (const bool degenerate : {false, true}) {
    SCOPED_TRACE(degenerate ? "degenerate frame" : "full frame");
    const FrameTerms terms = MakeFrameTerms(degenerate, 5);
    for (const Pose& at : {kTruePose, kPerturbedStart}) {
      Pose pose_folded = at, pose_blocks = at;
      ceres::Problem folded, blocks;
      AddFrame(terms, true, &folded, pose_folded.data());
      AddFrame(terms, false, &blocks, pose_blocks.data());
      const Linearisation a = Linearise(&folded);
      const Linearisation b = Linearise(&blocks);
      ASSERT_GT(b.cost, 1.0);  // the outliers are beyond the Huber scale
      EXPECT_NEAR(a.cost, b.cost, 1e-9 * b.cost);
      EXPECT_LT((a.gradient - b.gradient).norm(), 1e-9 * b.gradient.norm() + 1e-12);
      EXPECT_LT((a.hessian - b.hessian).norm(), 1e-9 * b.hessian.norm());
    }
  }
}

TEST(LidarFrameCost, CostWithoutJacobiansIsTheSame) {
  const FrameTerms terms = MakeFrameTerms(false, 9);
  const LidarFrameCost cost(terms.planes, terms.lines, 1.0);
  Pose pose = kPerturbedStart;
  const double* parameters[1] = {pose.data()};
  Eigen::Matrix<double, 7, 1> with, without;
  double jacobian[49];
  double* jacobians[1] = {jacobian};
  ASSERT_TRUE(cost.Evaluate(parameters, with.data(), jacobians));
  ASSERT_TRUE(cost.Evaluate(parameters, without.data(), nullptr));
  EXPECT_NEAR(with.squaredNorm(), without.squaredNorm(), 1e-9 * with.squaredNorm());
  EXPECT_EQ(cost.size(), terms.planes.size() + terms.lines.size());
}

// A soft edge's term that ignores one axis: its cost is the offset across that axis alone, and
// moving the pose along the axis costs nothing.
TEST(LidarFrameCost, ALineTermIgnoresTheAxisItIsTold) {
  const Eigen::Vector3d a(1.0, 2.0, 3.0), u = Eigen::Vector3d::UnitX();
  const Eigen::Vector3d y = Eigen::Vector3d::UnitY(), z = Eigen::Vector3d::UnitZ();
  Pose pose = kTruePose;
  const Eigen::Vector3d p_body = ToBody(pose, a + 4.0 * u + 0.2 * y + 0.1 * z);
  LineTerm full(p_body, a, u, 1.0);
  LineTerm blind = full;
  blind.Ignore(y);
  const auto cost_at = [](const LineTerm& term, Pose at) {
    const LidarFrameCost cost({}, {term}, 10.0);  // the quadratic part of the Huber loss
    return EvaluateVector(cost, {at.data()}).squaredNorm();
  };
  EXPECT_NEAR(cost_at(full, pose), 0.05, 1e-9);
  EXPECT_NEAR(cost_at(blind, pose), 0.01, 1e-9);
  Pose moved = pose;
  moved[1] += 0.3;  // along world y
  EXPECT_NEAR(cost_at(blind, moved), 0.01, 1e-9);
  EXPECT_GT(cost_at(full, moved), 0.2);
}

TEST(LidarFrameCost, SolvesToTheSamePoseAsOneBlockPerTerm) {
  const FrameTerms terms = MakeFrameTerms(false, 13);
  Pose folded_pose = kPerturbedStart, blocks_pose = kPerturbedStart;
  for (const bool folded : {true, false}) {
    Pose* pose = folded ? &folded_pose : &blocks_pose;
    ceres::Problem problem;
    AddFrame(terms, folded, &problem, pose->data());
    SolveToConvergence(&problem);
  }
  const auto [position_gap, rotation_gap] = PoseError(folded_pose, blocks_pose);
  EXPECT_LT(position_gap, 1e-6);
  EXPECT_LT(rotation_gap, 1e-7);
  // And it has come from 0.6 m and 0.25 rad away to near the truth despite the outliers.
  const auto [position_error, rotation_error] = PoseError(folded_pose, kTruePose);
  EXPECT_LT(position_error, 0.1);
  EXPECT_LT(rotation_error, 0.02);
}

TEST(RailPlaneFactor, RecoversRollPitchAndHeightOfSecondPose) {
  // Pose i is held fixed and pose j starts with wrong roll, pitch and height.
  Pose pose_i = MakePose({10.0, -2.0, 0.3}, {0.02, -0.03, 0.6});
  const Pose truth_j = MakePose({18.0, 3.0, 0.5}, {-0.01, 0.04, 0.75});
  Pose pose_j = MakePose({18.0, 3.0, 0.9}, {0.1, -0.08, 0.75});
  ceres::Problem problem;
  problem.AddParameterBlock(pose_i.data(), kPoseSize, new PoseManifold);
  problem.AddParameterBlock(pose_j.data(), kPoseSize, new PoseManifold);
  problem.SetParameterBlockConstant(pose_i.data());
  const auto [n_i, d_i] = PlaneInBody(pose_i, Eigen::Vector3d(0.03, -0.02, 1.0).normalized(), 1.2);
  const auto [n_j, d_j] = PlaneInBody(truth_j, Eigen::Vector3d(0.03, -0.02, 1.0).normalized(), 1.2);
  problem.AddResidualBlock(
      new RailPlaneFactor(n_i, d_i, n_j, d_j, 10.0, 10.0), nullptr, pose_i.data(), pose_j.data());
  ceres::Solver::Options options;
  options.function_tolerance = 1e-16;
  options.gradient_tolerance = 1e-16;
  options.parameter_tolerance = 1e-16;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  // Roll/pitch relative to the plane and the height above it return; yaw and in-plane position
  // are not observed (they stay where they started).
  const Eigen::Vector3d n_world = Eigen::Vector3d(0.03, -0.02, 1.0).normalized();
  EXPECT_NEAR(n_world.dot(Position(pose_j) - Position(truth_j)), 0.0, 1e-9);
  EXPECT_LT(
      (Rotation(pose_j).transpose() * n_world - Rotation(truth_j).transpose() * n_world).norm(),
      1e-9);
}

}  // namespace
}  // namespace raillomer
