// The only translation unit that includes PCL's registration templates (they compile slowly).
#include "estimator/mapping/submap_registration.h"

#include <cmath>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/gicp.h>
#include <pcl/registration/ndt.h>

#include "estimator/factors/pose_manifold.h"
#include "estimator/mapping/voxel_centroids.h"

namespace raillomer {
namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;

Cloud::Ptr ToCloud(const std::vector<Eigen::Vector3f>& points, double voxel_m) {
  auto cloud = std::make_shared<Cloud>();
  if (voxel_m > 0.0) {
    VoxelCentroids grid(voxel_m);
    for (const Eigen::Vector3f& p : points) grid.Add(p.cast<double>(), 0.f);
    grid.ForEach([&](uint64_t, const Eigen::Vector3d& p, float) {
      cloud->push_back(pcl::PointXYZ(
          static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())));
    });
  } else {
    cloud->reserve(points.size());
    for (const Eigen::Vector3f& p : points) cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  }
  return cloud;
}

/// PCL's NDT with its Hessian (protected there) exposed.
class Ndt : public pcl::NormalDistributionsTransform<pcl::PointXYZ, pcl::PointXYZ> {
 public:
  Eigen::Matrix<double, 6, 6> HessianAt(const Cloud& aligned) {
    Eigen::Matrix<double, 6, 6> h;
    computeHessian(h, aligned);
    return h;
  }
};

Eigen::Isometry3d ToIsometry(const Eigen::Matrix4f& m) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  // Re-orthonormalise: PCL works in float.
  T.linear() = Eigen::Quaterniond(m.topLeftCorner<3, 3>().cast<double>()).normalized().matrix();
  T.translation() = m.topRightCorner<3, 1>().cast<double>();
  return T;
}

}  // namespace

Registration IcpRegister(const std::vector<Eigen::Vector3f>& source,
                         const std::vector<Eigen::Vector3f>& target,
                         const Eigen::Isometry3d& guess,
                         const IcpOptions& options) {
  Registration r;
  r.T_target_source = guess;
  if (source.size() < 10 || target.size() < 10) return r;
  pcl::GeneralizedIterativeClosestPoint<pcl::PointXYZ, pcl::PointXYZ> icp;
  icp.setInputSource(ToCloud(source, options.source_voxel_m));
  icp.setInputTarget(ToCloud(target, 0.0));
  icp.setMaximumIterations(options.max_iterations);
  icp.setMaxCorrespondenceDistance(options.max_correspondence_m);
  icp.setTransformationEpsilon(options.transformation_epsilon);
  icp.setEuclideanFitnessEpsilon(1e-8);
  Cloud aligned;
  icp.align(aligned, guess.matrix().cast<float>());
  const auto criteria = icp.getConvergeCriteria();
  const bool hit_limit =
      criteria &&
      criteria->getConvergenceState() ==
          pcl::registration::DefaultConvergenceCriteria<float>::CONVERGENCE_CRITERIA_ITERATIONS;
  r.converged = icp.hasConverged() && !hit_limit;
  r.fitness_m2 = icp.getFitnessScore(options.max_correspondence_m);
  r.T_target_source = ToIsometry(icp.getFinalTransformation());
  return r;
}

Registration NdtRegister(const std::vector<Eigen::Vector3f>& source,
                         const std::vector<Eigen::Vector3f>& target,
                         const Eigen::Isometry3d& guess,
                         const NdtOptions& options) {
  Registration r;
  r.T_target_source = guess;
  if (source.size() < 10 || target.size() < 10) return r;
  // Coarse to fine: a pass at twice the resolution widens the capture range, the fine pass
  // gives the accuracy.
  const Cloud::Ptr target_cloud = ToCloud(target, 0.0);
  Cloud::Ptr source_cloud = ToCloud(source, options.source_voxel_m);
  if (options.max_source_points > 0 && source_cloud->size() > options.max_source_points) {
    auto kept = std::make_shared<Cloud>();
    const double stride =
        static_cast<double>(source_cloud->size()) / static_cast<double>(options.max_source_points);
    for (size_t i = 0; i < options.max_source_points; ++i) {
      kept->push_back((*source_cloud)[static_cast<size_t>(static_cast<double>(i) * stride)]);
    }
    source_cloud = kept;
  }
  Eigen::Matrix4f start = guess.matrix().cast<float>();
  std::vector<double> passes = {options.resolution_m};
  if (options.coarse_pass) passes.insert(passes.begin(), 2.0 * options.resolution_m);
  for (const double resolution : passes) {
    Ndt ndt;
    ndt.setResolution(static_cast<float>(resolution));
    ndt.setStepSize(options.step_size_m);
    ndt.setTransformationEpsilon(options.transformation_epsilon);
    ndt.setMaximumIterations(options.max_iterations);
    ndt.setInputTarget(target_cloud);
    ndt.setInputSource(source_cloud);
    Cloud aligned;
    ndt.align(aligned, start);
    r.iterations = ndt.getFinalNumIteration();
    r.converged = ndt.hasConverged() && r.iterations < options.max_iterations;
    if (!r.converged) return r;
    start = ndt.getFinalTransformation();
    r.fitness_m2 = ndt.getFitnessScore(2.0 * resolution);
    r.information = -ndt.HessianAt(aligned);
  }
  r.T_target_source = ToIsometry(start);
  return r;
}

void CorrectionSize(const Eigen::Isometry3d& guess,
                    const Eigen::Isometry3d& result,
                    double* translation_m,
                    double* rotation_rad) {
  const Eigen::Isometry3d delta = guess.inverse() * result;
  *translation_m = (result.translation() - guess.translation()).norm();
  *rotation_rad = Eigen::AngleAxisd(delta.linear()).angle();
}

bool HoldPoorlySeenTurn(const Eigen::Matrix<double, 6, 6>& information,
                        const Eigen::Vector3d& pivot,
                        double min_arm_m,
                        Eigen::Isometry3d* delta) {
  // The information about the pivot: a correction (t_p, w) there is (t_p + pivot x w, w) about
  // the origin.
  Eigen::Matrix<double, 6, 6> J = Eigen::Matrix<double, 6, 6>::Identity();
  J.topRightCorner<3, 3>() = Skew(pivot);
  const Eigen::Matrix<double, 6, 6> I = J.transpose() * information * J;
  const double strongest = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(I.topLeftCorner<3, 3>())
                               .eigenvalues()
                               .maxCoeff();
  const Eigen::FullPivLU<Eigen::Matrix<double, 6, 6>> lu(I);
  if (!(strongest > 0.0) || !lu.isInvertible()) return false;
  const double covariance_turn = lu.solve(Eigen::Matrix<double, 6, 1>::Unit(5))(5);
  if (covariance_turn > 0.0 && 1.0 / covariance_turn >= min_arm_m * min_arm_m * strongest) {
    return false;
  }
  const Eigen::AngleAxisd turn(delta->linear());
  Eigen::Matrix<double, 6, 1> d;
  d << *delta * pivot - pivot, turn.angle() * turn.axis();
  // Minimise (x - d)' I (x - d) with x(5) = 0.
  Eigen::Matrix<double, 5, 1> x =
      d.head<5>() + I.topLeftCorner<5, 5>().ldlt().solve(I.block<5, 1>(0, 5) * d(5));
  const Eigen::Vector3d w(x(3), x(4), 0.0);
  delta->linear() = w.norm() > 0.0 ? Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix()
                                   : Eigen::Matrix3d::Identity();
  delta->translation() = pivot + x.head<3>() - delta->linear() * pivot;
  return true;
}

}  // namespace raillomer
