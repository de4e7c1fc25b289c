#include "mapstore/run_registration.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <unordered_map>

#include <Eigen/Eigenvalues>

#include "mapstore/grid_cell.h"

namespace raillomer::mapstore {
namespace {

/// The fixed cloud on a dense grid (compressed rows: each cell's points contiguous), so a
/// cell is found by arithmetic rather than hashing: the registration asks millions of times.
class Grid {
 public:
  Grid(const std::vector<Eigen::Vector3d>& points, double side) : side_(side) {
    if (points.empty()) return;
    std::vector<GridCell> cells(points.size());
    min_ = max_ = CellOf(points[0], side);
    for (size_t i = 0; i < points.size(); ++i) {
      cells[i] = CellOf(points[i], side);
      min_ = {
          std::min(min_.x, cells[i].x), std::min(min_.y, cells[i].y), std::min(min_.z, cells[i].z)};
      max_ = {
          std::max(max_.x, cells[i].x), std::max(max_.y, cells[i].y), std::max(max_.z, cells[i].z)};
    }
    nx_ = max_.x - min_.x + 1;
    ny_ = max_.y - min_.y + 1;
    const int64_t nz = max_.z - min_.z + 1;
    start_.assign(static_cast<size_t>(nx_ * ny_ * nz + 1), 0);
    for (const GridCell& c : cells) ++start_[Index(c) + 1];
    for (size_t k = 1; k < start_.size(); ++k) start_[k] += start_[k - 1];
    order_.resize(points.size());
    sorted_.resize(points.size());
    std::vector<uint32_t> next(start_.begin(), start_.end() - 1);
    for (size_t i = 0; i < points.size(); ++i) {
      const uint32_t j = next[Index(cells[i])]++;
      order_[j] = static_cast<uint32_t>(i);
      sorted_[j] = points[i];
    }
  }

  /// The indices of the points within `radius` (at most the grid's side) of `p`.
  void Near(const Eigen::Vector3d& p, double radius, std::vector<size_t>* out) const {
    out->clear();
    const GridCell c = CellOf(p, side_);
    for (int64_t dx = -1; dx <= 1; ++dx)
      for (int64_t dy = -1; dy <= 1; ++dy)
        for (int64_t dz = -1; dz <= 1; ++dz)
          ForCell({c.x + dx, c.y + dy, c.z + dz}, [&](const Eigen::Vector3d& q, size_t i) {
            if ((q - p).squaredNorm() <= radius * radius) out->push_back(i);
          });
  }

  /// The nearest point within `radius`; false if there is none. Shells of cells around
  /// `p`'s, nearest first, until the next shell lies beyond the best found or the radius.
  bool Nearest(const Eigen::Vector3d& p, double radius, size_t* index) const {
    const GridCell c = CellOf(p, side_);
    double best = radius * radius;
    bool found = false;
    auto keep = [&](const Eigen::Vector3d& q, size_t i) {
      const double d = (q - p).squaredNorm();
      if (d <= best) {
        best = d;
        *index = i;
        found = true;
      }
    };
    const int64_t shells = static_cast<int64_t>(std::ceil(radius / side_));
    for (int64_t k = 0; k <= shells; ++k) {
      // Shell k by rows along x: whole rows on its faces across y and z, else the two ends.
      for (int64_t dz = -k; dz <= k; ++dz)
        for (int64_t dy = -k; dy <= k; ++dy) {
          if (std::max(std::abs(dy), std::abs(dz)) == k) {
            ForRow(c.x - k, c.x + k, c.y + dy, c.z + dz, keep);
          } else {
            ForRow(c.x - k, c.x - k, c.y + dy, c.z + dz, keep);
            ForRow(c.x + k, c.x + k, c.y + dy, c.z + dz, keep);
          }
        }
      // Every point of shell k + 1 and beyond lies at least k sides away.
      if (found && best <= static_cast<double>(k * k) * side_ * side_) break;
    }
    return found;
  }

 private:
  size_t Index(const GridCell& c) const {
    return static_cast<size_t>((c.x - min_.x) + nx_ * ((c.y - min_.y) + ny_ * (c.z - min_.z)));
  }

  template <typename Fn>
  void ForCell(const GridCell& c, Fn fn) const {
    ForRow(c.x, c.x, c.y, c.z, fn);
  }

  /// Calls `fn` on the points of the cells x0..x1 of row (y, z), which lie one after another.
  template <typename Fn>
  void ForRow(int64_t x0, int64_t x1, int64_t y, int64_t z, Fn fn) const {
    if (start_.empty() || y < min_.y || z < min_.z || y > max_.y || z > max_.z) return;
    x0 = std::max(x0, min_.x);
    x1 = std::min(x1, max_.x);
    if (x0 > x1) return;
    const uint32_t end = start_[Index({x1, y, z}) + 1];
    for (uint32_t j = start_[Index({x0, y, z})]; j < end; ++j) fn(sorted_[j], order_[j]);
  }

  double side_;
  GridCell min_, max_;
  int64_t nx_ = 0, ny_ = 0;
  std::vector<uint32_t> start_;  ///< each cell's first entry in order_, and one past the last
  std::vector<uint32_t> order_;  ///< point indices, cell by cell
  std::vector<Eigen::Vector3d> sorted_;  ///< the points in that order
};

/// Each fixed point's surface normal where its neighbourhood is a plane (zero elsewhere),
/// worked out when first asked for: a stage pairs a small part of the fixed cloud.
class Normals {
 public:
  Normals(const std::vector<Eigen::Vector3d>& points, const RegistrationOptions& o)
      : points_(points),
        o_(o),
        grid_(points, o.normal_radius_m),
        normals_(points.size()),
        known_(points.size(), false) {}

  const Eigen::Vector3d& operator[](size_t i) {
    if (!known_[i]) {
      normals_[i] = Compute(points_[i]);
      known_[i] = true;
    }
    return normals_[i];
  }

 private:
  Eigen::Vector3d Compute(const Eigen::Vector3d& p) {
    grid_.Near(p, o_.normal_radius_m, &near_);
    if (near_.size() < 5) return Eigen::Vector3d::Zero();
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (size_t k : near_) mean += points_[k];
    mean /= static_cast<double>(near_.size());
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    for (size_t k : near_) cov += (points_[k] - mean) * (points_[k] - mean).transpose();
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
    const Eigen::Vector3d values = eig.eigenvalues();  // ascending
    if (values.sum() > 0.0 && values(0) <= o_.planarity * values.sum())
      return eig.eigenvectors().col(0);
    return Eigen::Vector3d::Zero();
  }

  const std::vector<Eigen::Vector3d>& points_;
  RegistrationOptions o_;
  Grid grid_;
  std::vector<Eigen::Vector3d> normals_;
  std::vector<bool> known_;
  std::vector<size_t> near_;
};

/// A correspondence: the moved point, its partner and the partner's normal (zero: point to
/// point).
struct Pair {
  Eigen::Vector3d p, q, n;
};

double Residual(const Pair& c) {
  return c.n.isZero() ? (c.p - c.q).norm() : std::abs(c.n.dot(c.p - c.q));
}

}  // namespace

bool RegistrationOptions::IsValid(std::string* error) const {
  if (!(voxel_m > 0.0 && max_correspondence_m > 0.0 && normal_radius_m > 0.0))
    return *error = "voxel_m, max_correspondence_m and normal_radius_m must be positive", false;
  if (!(initial_correspondence_m >= max_correspondence_m))
    return *error = "initial_correspondence_m must be at least max_correspondence_m", false;
  if (!(planarity > 0.0 && planarity < 1.0 / 3.0))
    return *error = "planarity must be in (0, 1/3)", false;
  if (max_iterations < 1) return *error = "max_iterations must be at least 1", false;
  if (max_moving_points < 100 || coarse_moving_points < 100)
    return *error = "max_moving_points and coarse_moving_points must be at least 100", false;
  if (!(kernel_floor_m > 0.0)) return *error = "kernel_floor_m must be positive", false;
  if (!(coarse_converged_share >= 0.0 && coarse_converged_share < 1.0))
    return *error = "coarse_converged_share must be in [0, 1)", false;
  return true;
}

std::vector<Eigen::Vector3d> VoxelCentroids(const std::vector<Eigen::Vector3d>& points,
                                            double voxel_m) {
  std::unordered_map<GridCell, std::pair<Eigen::Vector3d, int>, GridCellHash> sums;
  for (const Eigen::Vector3d& p : points) {
    auto& [sum, n] = sums.try_emplace(CellOf(p, voxel_m), Eigen::Vector3d::Zero(), 0).first->second;
    sum += p;
    ++n;
  }
  std::vector<Eigen::Vector3d> out;
  out.reserve(sums.size());
  for (const auto& [cell, s] : sums) out.push_back(s.first / s.second);
  return out;
}

namespace {

/// Correspondences: each moved point (moved by `T_fixed_moving`) and the nearest fixed one
/// within `correspondence_m`.
void FindPairs(const std::vector<Eigen::Vector3d>& fixed,
               const Grid& grid,
               Normals* normals,
               const std::vector<Eigen::Vector3d>& moving,
               const Eigen::Isometry3d& T_fixed_moving,
               double correspondence_m,
               std::vector<Pair>* pairs) {
  pairs->clear();
  for (const Eigen::Vector3d& m : moving) {
    const Eigen::Vector3d p = T_fixed_moving * m;
    size_t k = 0;
    if (grid.Nearest(p, correspondence_m, &k)) pairs->push_back({p, fixed[k], (*normals)[k]});
  }
}

/// The robust kernel's scale from the pairs' residuals: 1.5 times their median, at least
/// kernel_floor_m and half the stage's correspondence distance.
double KernelScale(const std::vector<double>& residuals,
                   double correspondence_m,
                   const RegistrationOptions& o) {
  std::vector<double> sorted = residuals;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
  // The ground agrees at once (its median residual is soon near zero): the scale keeps room
  // for the few structures (masts, walls) that still disagree by up to the stage's distance.
  return std::max({o.kernel_floor_m, 1.5 * sorted[sorted.size() / 2], 0.5 * correspondence_m});
}

/// Adds the weighted pairs to the Gauss-Newton system `H`, `b` on a left perturbation
/// [dt, dtheta]: d(R p + t) = dt + dtheta x (R p + t). `result` gets the inliers (residual
/// within `scale`) and their RMS.
void AddPairs(const std::vector<Pair>& pairs,
              const std::vector<double>& residuals,
              double scale,
              Eigen::Matrix<double, 6, 6>* H,
              Eigen::Matrix<double, 6, 1>* b,
              RegistrationResult* result) {
  double inlier_sq = 0.0;
  result->inliers = 0;
  for (size_t i = 0; i < pairs.size(); ++i) {
    const Pair& c = pairs[i];
    // Geman-McClure weight: residuals well beyond the scale (what changed) count for little.
    const double u = residuals[i] / scale;
    const double w = 1.0 / ((1.0 + u * u) * (1.0 + u * u));
    if (residuals[i] <= scale) {
      ++result->inliers;
      inlier_sq += residuals[i] * residuals[i];
    }
    auto add = [&](const Eigen::Vector3d& n, double r) {
      Eigen::Matrix<double, 6, 1> J;
      J << n, c.p.cross(n);
      *H += w * J * J.transpose();
      *b += w * J * r;
    };
    if (!c.n.isZero()) {
      add(c.n, c.n.dot(c.p - c.q));
    } else {
      for (int a = 0; a < 3; ++a) add(Eigen::Vector3d::Unit(a), c.p[a] - c.q[a]);
    }
  }
  result->rms_m = result->inliers > 0 ? std::sqrt(inlier_sq / result->inliers) : 0.0;
}

/// The translation block's smallest eigenvalue over its largest (0 where it is empty): how
/// well the pairs hold the translation in every direction.
double TranslationConditioning(const Eigen::Matrix<double, 6, 6>& H) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> translation(H.topLeftCorner<3, 3>());
  return translation.eigenvalues()(2) > 0.0
             ? translation.eigenvalues()(0) / translation.eigenvalues()(2)
             : 0.0;
}

/// The step [dt, dtheta] that solves the system.
Eigen::Matrix<double, 6, 1> SolveStep(const Eigen::Matrix<double, 6, 6>& H,
                                      const Eigen::Matrix<double, 6, 1>& b) {
  // A little damping keeps a direction the stretch cannot see (along a bare straight) still.
  return -(H + 1e-9 * H.trace() * Eigen::Matrix<double, 6, 6>::Identity()).ldlt().solve(b);
}

/// The rigid motion of a step [dt, dtheta].
Eigen::Isometry3d StepMotion(const Eigen::Vector3d& dt, const Eigen::Vector3d& dtheta) {
  Eigen::Isometry3d delta = Eigen::Isometry3d::Identity();
  if (dtheta.norm() > 0.0)
    delta.linear() = Eigen::AngleAxisd(dtheta.norm(), dtheta.normalized()).toRotationMatrix();
  delta.translation() = dt;
  return delta;
}

/// One stage of the registration at a correspondence distance, from `result`'s transform;
/// `grid` holds the fixed cloud, `normals` are its, worked out as pairs ask for them.
void RegisterStage(const std::vector<Eigen::Vector3d>& fixed,
                   const Grid& grid,
                   Normals* normals,
                   const std::vector<Eigen::Vector3d>& moving,
                   double correspondence_m,
                   const RegistrationOptions& o,
                   RegistrationResult* result) {
  std::vector<Pair> pairs;
  std::vector<double> residuals;
  result->converged = false;
  for (int iteration = 0; iteration < o.max_iterations; ++iteration) {
    ++result->iterations;
    FindPairs(fixed, grid, normals, moving, result->T_fixed_moving, correspondence_m, &pairs);
    result->pairs = pairs.size();
    if (pairs.size() < 6) return;
    residuals.resize(pairs.size());
    for (size_t i = 0; i < pairs.size(); ++i) residuals[i] = Residual(pairs[i]);
    const double scale = KernelScale(residuals, correspondence_m, o);
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> b = Eigen::Matrix<double, 6, 1>::Zero();
    AddPairs(pairs, residuals, scale, &H, &b, result);
    result->translation_conditioning = TranslationConditioning(H);
    const Eigen::Matrix<double, 6, 1> step = SolveStep(H, b);
    const Eigen::Vector3d dtheta = step.tail<3>();
    result->T_fixed_moving = StepMotion(step.head<3>(), dtheta) * result->T_fixed_moving;
    // How far the step moved the cloud: its translation and the rotation at 50 m.
    if (step.head<3>().norm() + 50.0 * dtheta.norm() < o.converged_step_m) {
      result->converged = true;
      return;
    }
  }
}

/// At most `n` of the points, every k-th (the centroids come in hash order: spread over the
/// cloud).
std::vector<Eigen::Vector3d> EvenSample(const std::vector<Eigen::Vector3d>& points, size_t n) {
  if (points.size() <= n) return points;
  const double step = static_cast<double>(points.size()) / static_cast<double>(n);
  std::vector<Eigen::Vector3d> out;
  out.reserve(n);
  for (size_t i = 0; i < n; ++i) out.push_back(points[static_cast<size_t>(i * step)]);
  return out;
}

/// The voxel side of a stage pairing points up to `distance` apart: coarser for the wide
/// first stages, which need only the shapes.
double StageVoxel(const RegistrationOptions& o, double distance) {
  return std::max(o.voxel_m, distance / 5.0);
}

}  // namespace

/// The fixed cloud thinned to one stage's voxels, its normals and its grids by side.
struct RegistrationTarget::Level {
  std::vector<Eigen::Vector3d> fixed;
  std::unique_ptr<Normals> normals;
  std::vector<std::pair<double, std::unique_ptr<Grid>>> grids;

  /// The grid of cells of `side`, made on first use.
  const Grid& GridOf(double side) {
    for (const auto& [s, grid] : grids)
      if (s == side) return *grid;
    grids.emplace_back(side, std::make_unique<Grid>(fixed, side));
    return *grids.back().second;
  }
};

RegistrationTarget::RegistrationTarget(const std::vector<Eigen::Vector3d>& fixed,
                                       const RegistrationOptions& o)
    : points_(fixed), o_(o) {}

RegistrationTarget::~RegistrationTarget() = default;

RegistrationTarget::Level& RegistrationTarget::LevelFor(double voxel_m) {
  for (auto& [side, level] : levels_)
    if (side == voxel_m) return *level;
  auto level = std::make_unique<Level>();
  level->fixed = VoxelCentroids(points_, voxel_m);
  RegistrationOptions normal = o_;
  normal.normal_radius_m = std::max(o_.normal_radius_m, 2.5 * voxel_m);
  level->normals = std::make_unique<Normals>(level->fixed, normal);
  levels_.emplace_back(voxel_m, std::move(level));
  return *levels_.back().second;
}

bool RegistrationTarget::RunStage(const std::vector<Eigen::Vector3d>& moving,
                                  double distance,
                                  const RegistrationOptions& stage,
                                  RegistrationResult* result) {
  Level& level = LevelFor(stage.voxel_m);
  if (level.fixed.size() < 10 || moving.size() < 10) return false;
  RegisterStage(level.fixed,
                level.GridOf(std::max(2.0 * stage.voxel_m, distance / 4.0)),
                level.normals.get(),
                moving,
                distance,
                stage,
                result);
  return true;
}

RegistrationResult RegistrationTarget::Check(const std::vector<Eigen::Vector3d>& moving_points,
                                             const Eigen::Isometry3d& T_fixed_moving) {
  RegistrationOptions stage = o_;
  stage.max_iterations = 1;
  const double distance = o_.max_correspondence_m;
  stage.voxel_m = StageVoxel(o_, distance);
  RegistrationResult result;
  result.T_fixed_moving = T_fixed_moving;
  RunStage(EvenSample(VoxelCentroids(moving_points, stage.voxel_m), o_.max_moving_points),
           distance,
           stage,
           &result);
  // One step was taken: the figures are those of the transform asked about.
  result.T_fixed_moving = T_fixed_moving;
  result.converged = false;
  return result;
}

RegistrationResult RegistrationTarget::Register(const std::vector<Eigen::Vector3d>& moving_points,
                                                const Eigen::Isometry3d& initial) {
  const RegistrationOptions& o = o_;
  RegistrationResult result;
  result.T_fixed_moving = initial;
  double distance = std::max(o.initial_correspondence_m, o.max_correspondence_m);
  // Stages on voxels of the same side (the last two, with the defaults) share the centroids.
  double voxel_m = 0.0;
  std::vector<Eigen::Vector3d> moving_centroids;
  while (true) {
    RegistrationOptions stage = o;
    stage.voxel_m = StageVoxel(o, distance);
    const bool last = distance <= o.max_correspondence_m;
    if (!last)
      stage.converged_step_m = std::max(o.converged_step_m, o.coarse_converged_share * distance);
    if (stage.voxel_m != voxel_m) {
      voxel_m = stage.voxel_m;
      moving_centroids = VoxelCentroids(moving_points, voxel_m);
    }
    if (!RunStage(EvenSample(moving_centroids, last ? o.max_moving_points : o.coarse_moving_points),
                  distance,
                  stage,
                  &result))
      return result;
    if (last) break;
    distance = std::max(o.max_correspondence_m, 0.5 * distance);
  }
  return result;
}

RegistrationResult RegisterClouds(const std::vector<Eigen::Vector3d>& fixed_points,
                                  const std::vector<Eigen::Vector3d>& moving_points,
                                  const Eigen::Isometry3d& initial,
                                  const RegistrationOptions& o) {
  RegistrationTarget target(fixed_points, o);
  return target.Register(moving_points, initial);
}

}  // namespace raillomer::mapstore
