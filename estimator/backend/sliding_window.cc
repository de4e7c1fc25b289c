#include "estimator/backend/sliding_window.h"

#include <ceres/ceres.h>
#include <ceres/normal_prior.h>

#include "estimator/factors/imu_odometer_factor.h"
#include "estimator/factors/marginalization.h"
#include "estimator/factors/pose_manifold.h"

namespace raillomer {

namespace {

/// A Gaussian prior on a pose: r = [p - p0; Log(q0^-1 q)] / sigma (Jacobian of Log taken as I),
/// with its own sigma for roll and pitch (observable through gravity) and for yaw (not).
class PosePriorFactor : public ceres::SizedCostFunction<6, 7> {
 public:
  PosePriorFactor(const double* pose, double sigma_p, double sigma_roll_pitch, double sigma_yaw)
      : p0_(pose[0], pose[1], pose[2]),
        q0_(pose[6], pose[3], pose[4], pose[5]),
        wp_(1.0 / sigma_p),
        wq_(1.0 / sigma_roll_pitch, 1.0 / sigma_roll_pitch, 1.0 / sigma_yaw) {}

  bool Evaluate(double const* const* parameters,
                double* residuals,
                double** jacobians) const override {
    Eigen::Map<const Eigen::Vector3d> p(parameters[0]);
    Eigen::Map<const Eigen::Quaterniond> q(parameters[0] + 3);
    Eigen::Map<Eigen::Matrix<double, 6, 1>> r(residuals);
    r.head<3>() = wp_ * (p - p0_);
    r.tail<3>() = wq_.cwiseProduct(LogQuaternion(q0_.conjugate() * q));
    if (jacobians && jacobians[0]) {
      Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>> j(jacobians[0]);
      j.setZero();
      j.block<3, 3>(0, 0) = wp_ * Eigen::Matrix3d::Identity();
      j.block<3, 3>(3, 3) = wq_.asDiagonal();
    }
    return true;
  }

 private:
  Eigen::Vector3d p0_;
  Eigen::Quaterniond q0_;
  double wp_;
  Eigen::Vector3d wq_;
};

void ToBlocks(const NavState& s, double* pose, double* speed_bias, double* odometer) {
  const Eigen::Quaterniond q = s.q.normalized();
  for (int k = 0; k < 3; ++k) {
    pose[k] = s.p[k];
    speed_bias[k] = s.v[k];
    speed_bias[3 + k] = s.ba[k];
    speed_bias[6 + k] = s.bg[k];
  }
  pose[3] = q.x();
  pose[4] = q.y();
  pose[5] = q.z();
  pose[6] = q.w();
  odometer[0] = s.c;
  odometer[1] = s.m.x();
  odometer[2] = s.m.y();
}

std::shared_ptr<ceres::CostFunction> DiagonalPrior(const double* values,
                                                   int n,
                                                   const Eigen::VectorXd& sigma) {
  Eigen::MatrixXd A = sigma.cwiseInverse().asDiagonal();
  Eigen::VectorXd b = Eigen::Map<const Eigen::VectorXd>(values, n);
  return std::make_shared<ceres::NormalPrior>(A, b);
}

}  // namespace

struct SlidingWindow::Node {
  double t_s = 0.0;
  double pose[kPoseSize];
  double speed_bias[kSpeedBiasSize];
  double odometer[kOdometerBlockSize];
  std::shared_ptr<Preintegration> preintegration;  ///< from the previous state to this one
  std::vector<WindowTerm> lidar;                   ///< unary, on pose: none or one
  std::vector<WindowTerm> unary;                   ///< other factors on pose alone
  std::vector<WindowTerm> links;   ///< with the previous state: IMU and pair factors
  std::vector<WindowTerm> priors;  ///< initial priors of the first state
};

SlidingWindow::SlidingWindow(const SlidingWindowOptions& options) : options_(options) {
  if (!options_.estimate_scale) odometer_held_.push_back(0);
  for (int k = 0; k < 2; ++k) {
    if (!(options_.initial_misalignment_sigma_rad[k] > 0.0)) odometer_held_.push_back(1 + k);
  }
  if (!odometer_held_.empty() && static_cast<int>(odometer_held_.size()) < kOdometerBlockSize) {
    odometer_manifold_ =
        std::make_unique<ceres::SubsetManifold>(kOdometerBlockSize, odometer_held_);
  }
}
SlidingWindow::~SlidingWindow() = default;

void SlidingWindow::Push(double t_s,
                         const NavState& state,
                         std::shared_ptr<Preintegration> preintegration) {
  auto node = std::make_unique<Node>();
  node->t_s = t_s;
  ToBlocks(state, node->pose, node->speed_bias, node->odometer);
  if (nodes_.empty() && !has_prior_) {
    AddAnchorPriors(node.get(), options_.initial_accel_bias_sigma);
  } else if (options_.use_imu && preintegration && !nodes_.empty()) {
    Node& prev = *nodes_.back();
    node->preintegration = preintegration;
    node->links.push_back({std::make_shared<ImuOdometerFactor>(preintegration),
                           nullptr,
                           {prev.pose,
                            prev.speed_bias,
                            prev.odometer,
                            node->pose,
                            node->speed_bias,
                            node->odometer}});
  }
  nodes_.push_back(std::move(node));
}

void SlidingWindow::SetNewestLidarFactor(std::shared_ptr<ceres::CostFunction> cost) {
  Node& node = *nodes_.back();
  node.lidar.clear();
  if (cost) node.lidar.push_back({std::move(cost), nullptr, {node.pose}});
}

void SlidingWindow::AddNewestPairFactor(std::shared_ptr<ceres::CostFunction> cost,
                                        std::shared_ptr<ceres::LossFunction> loss) {
  if (nodes_.size() < 2) return;
  Node& prev = *nodes_[nodes_.size() - 2];
  Node& node = *nodes_.back();
  node.links.push_back({std::move(cost), std::move(loss), {prev.pose, node.pose}});
}

void SlidingWindow::AddNewestUnaryFactor(std::shared_ptr<ceres::CostFunction> cost) {
  Node& node = *nodes_.back();
  node.unary.push_back({std::move(cost), nullptr, {node.pose}});
}

void SlidingWindow::ClearUnaryFactors() {
  for (auto& n : nodes_) n->unary.clear();
}

void SlidingWindow::AddAnchorPriors(Node* node, double accel_bias_sigma) const {
  // The anchor state holds the frame: its pose tightly (roll and pitch loosely when the IMU
  // observes them through gravity), velocity and biases loosely.
  node->priors.push_back(
      {std::make_shared<PosePriorFactor>(node->pose, 1e-4, options_.use_imu ? 0.02 : 1e-5, 1e-5),
       nullptr,
       {node->pose}});
  if (!options_.use_imu) return;
  Eigen::VectorXd sigma(9);
  sigma << Eigen::Vector3d::Constant(options_.initial_velocity_sigma_mps),
      Eigen::Vector3d::Constant(accel_bias_sigma),
      Eigen::Vector3d::Constant(options_.initial_gyro_bias_sigma);
  node->priors.push_back({DiagonalPrior(node->speed_bias, 9, sigma), nullptr, {node->speed_bias}});
  // The scale, and each misalignment component that is estimated (the manifold holds the
  // others).
  const Eigen::Vector2d& sigma_m = options_.initial_misalignment_sigma_rad;
  Eigen::MatrixXd A =
      Eigen::MatrixXd::Zero(1 + (sigma_m.array() > 0.0).count(), kOdometerBlockSize);
  A(0, 0) = 1.0 / options_.initial_scale_sigma;
  for (int k = 0, row = 1; k < 2; ++k) {
    if (sigma_m[k] > 0.0) A(row++, 1 + k) = 1.0 / sigma_m[k];
  }
  node->priors.push_back(
      {std::make_shared<ceres::NormalPrior>(
           A, Eigen::Map<const Eigen::VectorXd>(node->odometer, kOdometerBlockSize)),
       nullptr,
       {node->odometer}});
}

void SlidingWindow::RotateWorld(const Eigen::Matrix3d& R_new_old, bool forget_tilt_gyro_bias) {
  const Eigen::Quaterniond q_rot(R_new_old);
  for (auto& n : nodes_) {
    Eigen::Map<Eigen::Vector3d> p(n->pose), v(n->speed_bias), ba(n->speed_bias + 3),
        bg(n->speed_bias + 6);
    Eigen::Map<Eigen::Quaterniond> q(n->pose + 3);
    p = R_new_old * p;
    q = (q_rot * q).normalized();
    v = R_new_old * v;
    ba.setZero();
    if (forget_tilt_gyro_bias) bg.head<2>().setZero();
    n->lidar.clear();
    n->unary.clear();
    n->priors.clear();
  }
  has_prior_ = false;
  prior_term_ = WindowTerm();
  if (!nodes_.empty()) AddAnchorPriors(nodes_.front().get(), options_.relevelled_accel_bias_sigma);
}

std::vector<WindowTerm> SlidingWindow::AllTerms() const {
  std::vector<WindowTerm> terms;
  if (has_prior_) terms.push_back(prior_term_);
  for (size_t i = 0; i < nodes_.size(); ++i) {
    const Node& n = *nodes_[i];
    terms.insert(terms.end(), n.priors.begin(), n.priors.end());
    terms.insert(terms.end(), n.lidar.begin(), n.lidar.end());
    terms.insert(terms.end(), n.unary.begin(), n.unary.end());
    if (i > 0) terms.insert(terms.end(), n.links.begin(), n.links.end());
  }
  return terms;
}

WindowSummary SlidingWindow::Optimize() {
  WindowSummary summary;
  if (nodes_.empty()) return summary;
  RelinearizeDrifted();
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.enable_fast_removal = false;
  ceres::Problem problem(problem_options);
  AddParameterBlocks(&problem);
  for (const WindowTerm& t : AllTerms()) {
    problem.AddResidualBlock(t.cost.get(), t.loss.get(), t.blocks);
    ++summary.residual_blocks;
  }
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  solver_options.max_num_iterations = options_.max_iterations;
  solver_options.num_threads = options_.num_threads;
  solver_options.minimizer_progress_to_stdout = false;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(solver_options, &problem, &ceres_summary);
  summary.iterations = static_cast<int>(ceres_summary.iterations.size());
  summary.initial_cost = ceres_summary.initial_cost;
  summary.final_cost = ceres_summary.final_cost;
  summary.converged = ceres_summary.termination_type == ceres::CONVERGENCE;
  return summary;
}

void SlidingWindow::RelinearizeDrifted() {
  for (size_t i = 1; i < nodes_.size(); ++i) {
    Node& n = *nodes_[i];
    if (!n.preintegration || n.links.empty()) continue;
    const Node& prev = *nodes_[i - 1];
    Eigen::Map<const Eigen::Vector3d> ba(prev.speed_bias + 3), bg(prev.speed_bias + 6);
    if ((ba - n.preintegration->linearized_ba()).norm() > 0.05 ||
        (bg - n.preintegration->linearized_bg()).norm() > 2e-3 ||
        std::abs(prev.odometer[0] - n.preintegration->linearized_c()) > 0.01) {
      n.preintegration->Repropagate(ba, bg, prev.odometer[0]);
      n.links.front().cost = std::make_shared<ImuOdometerFactor>(n.preintegration);
    }
  }
}

void SlidingWindow::AddParameterBlocks(ceres::Problem* problem) const {
  static PoseManifold manifold;
  for (const auto& n : nodes_) {
    problem->AddParameterBlock(n->pose, kPoseSize, &manifold);
    if (options_.use_imu) {
      problem->AddParameterBlock(n->speed_bias, kSpeedBiasSize);
      problem->AddParameterBlock(n->odometer, kOdometerBlockSize, odometer_manifold_.get());
      if (static_cast<int>(odometer_held_.size()) == kOdometerBlockSize)
        problem->SetParameterBlockConstant(n->odometer);
    }
  }
  if (!options_.use_imu) {
    // Without the IMU the states are independent: only the newest is solved.
    for (size_t i = 0; i + 1 < nodes_.size(); ++i)
      problem->SetParameterBlockConstant(nodes_[i]->pose);
  }
}

bool SlidingWindow::Full() const { return static_cast<int>(nodes_.size()) > options_.size; }

NavState SlidingWindow::PopOldest(double* t_s) {
  Node& oldest = *nodes_.front();
  const NavState final_state = State(0);
  if (t_s) *t_s = oldest.t_s;
  if (nodes_.size() >= 2 && options_.use_imu) {
    auto info = std::make_shared<MarginalizationInfo>();
    const std::vector<double*> dropped = {oldest.pose, oldest.speed_bias, oldest.odometer};
    auto add = [&](const WindowTerm& t) {
      MarginalizationTerm m;
      m.cost_function = t.cost;
      m.loss_function = t.loss;
      m.parameter_blocks = t.blocks;
      for (size_t k = 0; k < t.blocks.size(); ++k) {
        if (std::find(dropped.begin(), dropped.end(), t.blocks[k]) != dropped.end()) {
          m.drop_indices.push_back(static_cast<int>(k));
        }
      }
      if (!m.drop_indices.empty()) info->AddTerm(std::move(m));
    };
    if (has_prior_) add(prior_term_);
    for (const WindowTerm& t : oldest.priors) add(t);
    for (const WindowTerm& t : oldest.lidar) add(t);
    for (const WindowTerm& t : oldest.unary) add(t);
    for (const WindowTerm& t : nodes_[1]->links) add(t);
    if (info->Marginalize()) {
      prior_term_ = {std::make_shared<MarginalizationFactor>(info), nullptr, info->KeptBlocks({})};
      has_prior_ = true;
    }
  } else if (nodes_.size() >= 2) {
    // Poses only: the next state becomes the anchor.
    Node& next = *nodes_[1];
    next.priors.push_back(
        {std::make_shared<PosePriorFactor>(next.pose, 1e-4, 1e-5, 1e-5), nullptr, {next.pose}});
  }
  nodes_.pop_front();
  if (!nodes_.empty()) nodes_.front()->links.clear();
  return final_state;
}

NavState SlidingWindow::State(int index) const {
  const Node& n = *nodes_.at(static_cast<size_t>(index));
  NavState s;
  s.p = Eigen::Map<const Eigen::Vector3d>(n.pose);
  s.q = Eigen::Map<const Eigen::Quaterniond>(n.pose + 3).normalized();
  s.v = Eigen::Map<const Eigen::Vector3d>(n.speed_bias);
  s.ba = Eigen::Map<const Eigen::Vector3d>(n.speed_bias + 3);
  s.bg = Eigen::Map<const Eigen::Vector3d>(n.speed_bias + 6);
  s.c = n.odometer[0];
  s.m = Eigen::Vector2d(n.odometer[1], n.odometer[2]);
  return s;
}

double SlidingWindow::Time(int index) const { return nodes_.at(static_cast<size_t>(index))->t_s; }

double* SlidingWindow::NewestPose() { return nodes_.back()->pose; }

}  // namespace raillomer
