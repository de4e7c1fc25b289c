#include "estimator/backend/scan_matching.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "estimator/factors/pose_manifold.h"

namespace raillomer {

namespace {

/// Plane through the neighbours by least squares on n . x = -1 (LOAM), checked point by point.
bool FitPlane(
    const Eigen::Vector3d* pts, int n, double max_residual, Eigen::Vector3d* normal, double* d) {
  Eigen::MatrixXd A(n, 3);
  for (int i = 0; i < n; ++i) A.row(i) = pts[i].transpose();
  // Centre the points first so the fit works at any distance from the origin.
  const Eigen::Vector3d centroid = A.colwise().mean().transpose();
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d e = pts[i] - centroid;
    cov += e * e.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  *normal = eig.eigenvectors().col(0);
  *d = -normal->dot(centroid);
  for (int i = 0; i < n; ++i) {
    if (std::abs(normal->dot(pts[i]) + *d) > max_residual) return false;
  }
  // A plane needs spread in two directions.
  return eig.eigenvalues()(1) > 4.0 * eig.eigenvalues()(0) + 1e-6;
}

bool FitLine(const Eigen::Vector3d* pts,
             int n,
             double min_ratio,
             double max_spread,
             Eigen::Vector3d* point,
             Eigen::Vector3d* direction,
             double* spread) {
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (int i = 0; i < n; ++i) centroid += pts[i];
  centroid /= n;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d e = pts[i] - centroid;
    cov += e * e.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  if (eig.eigenvalues()(2) < min_ratio * eig.eigenvalues()(1)) return false;
  // Spread about the line: eigenvalues are sums of squares over the n points.
  const double spread_sq = (eig.eigenvalues()(0) + eig.eigenvalues()(1)) / n;
  if (max_spread > 0.0 && spread_sq > max_spread * max_spread) return false;
  *point = centroid;
  *direction = eig.eigenvectors().col(2);
  *spread = std::sqrt(std::max(0.0, spread_sq));
  return true;
}

}  // namespace

LidarMatches MatchFeatures(const MatchOptions& options,
                           const FeatureSet& features,
                           const Eigen::Isometry3d& T_world_body,
                           const LocalMap& edge_map,
                           const LocalMap& plane_map) {
  LidarMatches matches;
  Eigen::Vector3d nn[16];
  const int k = std::min(options.neighbours, 16);
  matches.planes.reserve(features.planes.size());
  for (const Eigen::Vector3f& pf : features.planes) {
    const Eigen::Vector3d p_body = pf.cast<double>();
    const Eigen::Vector3d p_world = T_world_body * p_body;
    if (plane_map.KNearest(p_world, k, options.max_distance_m, nn) < k) continue;
    PlaneMatch m;
    if (!FitPlane(nn, k, options.plane_max_residual_m, &m.normal, &m.d)) continue;
    m.p_body = p_body;
    matches.planes.push_back(m);
  }
  matches.lines.reserve(features.edges.size());
  for (const Eigen::Vector3f& pf : features.edges) {
    const Eigen::Vector3d p_body = pf.cast<double>();
    const Eigen::Vector3d p_world = T_world_body * p_body;
    if (edge_map.KNearest(p_world, k, options.max_distance_m, nn) < k) continue;
    LineMatch m;
    double spread = 0.0;
    if (!FitLine(nn,
                 k,
                 options.line_min_ratio,
                 options.line_max_spread_m,
                 &m.point,
                 &m.direction,
                 &spread))
      continue;
    m.p_body = p_body;
    m.soft = options.line_soft_spread_m > 0.0 && spread > options.line_soft_spread_m;
    matches.lines.push_back(m);
  }
  return matches;
}

namespace {

using Mat6 = Eigen::Matrix<double, 6, 6>;
using Vec6 = Eigen::Matrix<double, 6, 1>;

/// The Huber-weighted normal equations H, b of the matches at pose T. Residual r(x) with
/// x = [dp (world), dtheta (body)]: dr/dp = a^T, dr/dtheta = -a^T R [p]x.
void NormalEquations(const LidarMatches& matches, const Eigen::Isometry3d& T, Mat6* H, Vec6* b) {
  H->setZero();
  b->setZero();
  const Eigen::Matrix3d R = T.linear();
  const Eigen::Vector3d t = T.translation();
  auto accumulate = [&](const Eigen::Vector3d& a, double r, const Eigen::Vector3d& p_body) {
    const double w = std::abs(r) < 0.1 ? 1.0 : 0.1 / std::abs(r);  // Huber
    Vec6 J;
    J.head<3>() = a;
    J.tail<3>() = -(a.transpose() * R * Skew(p_body)).transpose();
    *H += w * J * J.transpose();
    *b += w * J * r;
  };
  for (const PlaneMatch& m : matches.planes) {
    const Eigen::Vector3d pw = R * m.p_body + t;
    accumulate(m.normal, m.normal.dot(pw) + m.d, m.p_body);
  }
  for (const LineMatch& m : matches.lines) {
    const Eigen::Vector3d pw = R * m.p_body + t;
    const Eigen::Vector3d e = pw - m.point;
    const Eigen::Vector3d perp = e - m.direction.dot(e) * m.direction;
    const double dist = perp.norm();
    if (dist < 1e-9) continue;
    accumulate(perp / dist, dist, m.p_body);
  }
}

/// Degeneracy: the translation block of H / n with the rotation eliminated; its smallest
/// eigenvalue and direction.
void MeasureDegeneracy(const Mat6& H, double n, LidarOnlySolution* out) {
  const Eigen::Matrix3d Htt = H.topLeftCorner<3, 3>() / n;
  const Eigen::Matrix3d Htr = H.topRightCorner<3, 3>() / n;
  const Eigen::Matrix3d Hrr = H.bottomRightCorner<3, 3>() / n;
  const Eigen::Matrix3d S =
      Htt - Htr * (Hrr + 1e-9 * Eigen::Matrix3d::Identity()).inverse() * Htr.transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(S);
  out->degeneracy = std::max(0.0, eig.eigenvalues()(0));
  out->weakest_direction = eig.eigenvectors().col(0);
}

/// The heading's information and its profile at the linearisation pose.
void MeasureHeading(const Mat6& H, const Vec6& b, double n, LidarOnlySolution* out) {
  // The tangent direction u of a turn about world z (body-frame rotation R^T z); its marginal
  // information 1 / (u^T H^-1 u).
  Vec6 u = Vec6::Zero();
  u.tail<3>() = out->T_world_body.linear().transpose() * Eigen::Vector3d::UnitZ();
  const double variance = u.dot((H / n + 1e-12 * Mat6::Identity()).ldlt().solve(u));
  out->heading_information = variance > 0.0 ? 1.0 / variance : 0.0;
  // The heading's profile, in world-frame rotations phi = R dtheta: the normal equations
  // become T^T H T and T^T b with T = diag(I, R^T); minimising over phi_z alone gives
  // phi_z = -(b_z + H_z,o o) / H_zz for the other five directions o.
  const Eigen::Matrix3d R_lin = out->T_linearized.linear();
  Mat6 T = Mat6::Identity();
  T.bottomRightCorner<3, 3>() = R_lin.transpose();
  const Mat6 H_world = T.transpose() * H * T;
  const Vec6 b_world = T.transpose() * b;
  const double h_zz = H_world(5, 5);
  if (h_zz > 1e-9 * std::max(1.0, H_world.trace())) {
    out->heading_z0 = -b_world(5) / h_zz;
    out->heading_gain = -H_world.block<1, 5>(5, 0).transpose() / h_zz;
  }
}

}  // namespace

LidarOnlySolution SolveLidarOnly(const LidarMatches& matches,
                                 const Eigen::Isometry3d& T_init,
                                 int max_iterations) {
  LidarOnlySolution out;
  out.T_world_body = T_init;
  if (matches.size() < 6) return out;
  Mat6 H = Mat6::Zero();
  Vec6 b = Vec6::Zero();
  for (int it = 0; it < max_iterations; ++it) {
    out.T_linearized = out.T_world_body;
    NormalEquations(matches, out.T_world_body, &H, &b);
    const Vec6 dx = (H + 1e-6 * Mat6::Identity()).ldlt().solve(-b);
    out.T_world_body.translation() += dx.head<3>();
    out.T_world_body.linear() =
        (Eigen::Quaterniond(out.T_world_body.linear()) * ExpQuaternion(dx.tail<3>()))
            .normalized()
            .toRotationMatrix();
    out.iterations = it + 1;
    if (dx.head<3>().norm() < 1e-4 && dx.tail<3>().norm() < 1e-5) {
      out.converged = true;
      break;
    }
  }
  const double n = static_cast<double>(matches.size());
  MeasureDegeneracy(H, n, &out);
  MeasureHeading(H, b, n, &out);
  return out;
}

}  // namespace raillomer
