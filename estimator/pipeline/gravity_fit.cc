#include "estimator/pipeline/gravity_fit.h"

namespace raillomer {

void GravityFit::AddOpenLine(double* sxx, Eigen::Vector3d* sxy) const {
  if (n_ < 2) return;
  *sxx += sum_tt_ - sum_t_ * sum_t_ / n_;
  *sxy += sum_ty_ - sum_t_ * sum_y_ / n_;
}

void GravityFit::CloseLine() {
  AddOpenLine(&sxx_, &sxy_);
  n_ = 0;
  sum_t_ = sum_tt_ = 0.0;
  c_.setZero();
  sum_y_.setZero();
  sum_ty_.setZero();
}

void GravityFit::Start(const Eigen::Vector3d& v) {
  CloseLine();
  t_ = 0.0;
  n_ = 1;
  sum_y_ = -v;
}

void GravityFit::Add(double dt_s,
                     const Eigen::Vector3d& world_increment,
                     const Eigen::Vector3d& v) {
  if (n_ == 0) {
    Start(v);
    return;
  }
  t_ += dt_s;
  duration_s_ += dt_s;
  c_ += world_increment;
  const Eigen::Vector3d y = c_ - v;
  ++n_;
  sum_t_ += t_;
  sum_tt_ += t_ * t_;
  sum_y_ += y;
  sum_ty_ += t_ * y;
}

bool GravityFit::Gravity(Eigen::Vector3d* g) const {
  double sxx = sxx_;
  Eigen::Vector3d sxy = sxy_;
  AddOpenLine(&sxx, &sxy);
  if (!(sxx > 0.0)) return false;
  *g = sxy / sxx;
  return true;
}

}  // namespace raillomer
