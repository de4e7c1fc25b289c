#include "estimator/features/rail_extraction.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <random>
#include <string>

#include <Eigen/Eigenvalues>

namespace raillomer {

namespace {

constexpr double kRailHeadHalfWidthM = 0.036;  // 60E1 head: 72 mm wide
constexpr double kSliceM = 0.25;               // along-track slice of the local-maximum search
constexpr double kLocalMaxToleranceM = 0.05;   // candidates: this close to the local highest
constexpr int kLocalMaxHalfWindow = 2;         // the local maximum spans +-2 slices
constexpr int kSeedRobustCount = 3;            // the seed starts at the 3rd nearest bed return
constexpr double kChunkM = 1.0;                // region growing proceeds in steps of this length
constexpr double kQuadraticMinSpanM = 8.0;     // rails bend: a quadratic once this long
constexpr double kMinCurveRadiusM = 100.0;     // bounds the fitted curvature
constexpr double kMaxSeedSlope = 0.2;          // seed line: |dy/dx|, |dz/dx| at most this
constexpr double kMaxGapM = 6.0;               // a rail stops growing after a gap this long
constexpr double kGaugeToleranceM = 0.06;      // rail separation check while growing
constexpr double kMaxCrossLevelM = 0.3;        // rail heights differ at most this (body rolls)
constexpr double kPlaneInlierM = 0.03;         // RANSAC plane threshold
constexpr double kRailTopBelowM = 0.015;       // final plane: rail-top points reach this low
constexpr double kMaxPlaneTiltRad = 0.2;       // rail plane normal within ~11 deg of body z

struct Point {
  float x, y, z;
};

/// A rail seed as a line y = a + b u, z = d + e u with u = x - x0; least squares on the points
/// added.
class SeedLine {
 public:
  explicit SeedLine(double x0) : x0_(x0) {}

  void Add(const Point& p) {
    const double u = p.x - x0_;
    A_ += Eigen::Vector2d(1.0, u) * Eigen::RowVector2d(1.0, u);
    y_ += Eigen::Vector2d(1.0, u) * p.y;
    z_ += Eigen::Vector2d(1.0, u) * p.z;
    u_min_ = std::min(u_min_, u);
    u_max_ = std::max(u_max_, u);
  }

  /// Refits from the points added; false if they do not determine a line.
  bool Fit() {
    if (A_(0, 0) < 2.0 || u_max_ - u_min_ < 0.3) return false;
    const Eigen::Matrix2d inverse = A_.inverse();
    const Eigen::Vector2d y = inverse * y_, z = inverse * z_;
    if (!y.allFinite() || !z.allFinite()) return false;
    Set(y[0], y[1], z[0], z[1]);
    return true;
  }

  void Set(double a, double b, double d, double e) {
    a_ = a;
    b_ = b;
    d_ = d;
    e_ = e;
  }

  double Y(double x) const { return a_ + b_ * (x - x0_); }
  double Z(double x) const { return d_ + e_ * (x - x0_); }
  double y_slope() const { return b_; }
  double z_slope() const { return e_; }

  /// Distance of p to the line.
  double Distance(const Point& p) const {
    const Eigen::Vector3d dir = Eigen::Vector3d(1.0, b_, e_).normalized();
    const Eigen::Vector3d v(0.0, p.y - Y(p.x), p.z - Z(p.x));
    return (v - v.dot(dir) * dir).norm();
  }

 private:
  double x0_;
  Eigen::Matrix2d A_ = Eigen::Matrix2d::Zero();
  Eigen::Vector2d y_ = Eigen::Vector2d::Zero(), z_ = Eigen::Vector2d::Zero();
  double u_min_ = std::numeric_limits<double>::infinity();
  double u_max_ = -std::numeric_limits<double>::infinity();
  double a_ = 0.0, b_ = 0.0, d_ = 0.0, e_ = 0.0;
};

/// The track as seen while growing: a common centre line y = a + b u + c u^2 (u = x - x0) with
/// the rails W either side of it, measured perpendicular to the line, and a height line
/// z = d_r + e_r u per rail (cant may change along a transition). Refitted from the grown points;
/// the rails share the direction and curvature, so a sparse rail cannot wander off.
class TrackModel {
 public:
  TrackModel(double x0, double a, double b, double half_separation)
      : x0_(x0), a_(a), b_(b), w_(half_separation) {}

  void SetHeight(int r, double d, double e) {
    d_[r] = d;
    e_[r] = e;
  }

  double Slope(double x) const { return b_ + 2.0 * c_ * (x - x0_); }
  double Y(int r, double x) const {
    const double u = x - x0_, slope = Slope(x);
    return a_ + b_ * u + c_ * u * u + Side(r) * w_ * std::sqrt(1.0 + slope * slope);
  }
  double Z(int r, double x) const { return d_[r] + e_[r] * (x - x0_); }
  double z_slope(int r) const { return e_[r]; }
  double half_separation() const { return w_; }

  /// Distance of p to rail r's centre line, perpendicular to the local direction.
  double Distance(int r, const Point& p) const {
    const double dy = p.y - Y(r, p.x), dz = p.z - Z(r, p.x);
    const Eigen::Vector3d dir = Eigen::Vector3d(1.0, Slope(p.x), e_[r]).normalized();
    const Eigen::Vector3d v(0.0, dy, dz);
    return (v - v.dot(dir) * dir).norm();
  }

  /// Least squares on both rails' points; the factor sqrt(1 + slope^2) of the separation is
  /// taken from the current model (it changes slowly). False if the points do not suffice.
  bool Fit(const std::array<std::vector<Point>, 2>& rails) {
    double u_min = std::numeric_limits<double>::infinity(), u_max = -u_min;
    for (const std::vector<Point>& rail : rails) {
      for (const Point& p : rail) {
        u_min = std::min(u_min, p.x - x0_);
        u_max = std::max(u_max, p.x - x0_);
      }
    }
    const size_t n = rails[0].size() + rails[1].size();
    if (rails[0].size() < 2 || rails[1].size() < 2 || u_max - u_min < 0.3) return false;
    const bool quadratic = u_max - u_min >= kQuadraticMinSpanM && n >= 10;
    // Columns: a, b, W, c.
    Eigen::Matrix4d A = Eigen::Matrix4d::Zero();
    Eigen::Vector4d rhs = Eigen::Vector4d::Zero();
    for (int r = 0; r < 2; ++r) {
      for (const Point& p : rails[r]) {
        const double u = p.x - x0_, slope = Slope(p.x);
        const Eigen::Vector4d row(1.0, u, Side(r) * std::sqrt(1.0 + slope * slope), u * u);
        A += row * row.transpose();
        rhs += row * p.y;
      }
    }
    const double c_max = 0.5 / kMinCurveRadiusM;
    Eigen::Vector4d q = Eigen::Vector4d::Zero();
    bool solved = false;
    if (quadratic) {
      q = A.ldlt().solve(rhs);
      solved = q.allFinite() && std::fabs(q[3]) <= c_max;
      if (q.allFinite() && !solved) q[3] = std::copysign(c_max, q[3]);  // bounded curvature
    }
    if (!solved) {
      const double c = q[3];
      const Eigen::Vector3d l =
          A.topLeftCorner<3, 3>().ldlt().solve(rhs.head<3>() - c * A.block<3, 1>(0, 3));
      if (!l.allFinite()) return false;
      q.head<3>() = l;
    }
    a_ = q[0];
    b_ = q[1];
    w_ = q[2];
    c_ = q[3];
    for (int r = 0; r < 2; ++r) {
      Eigen::Matrix2d Az = Eigen::Matrix2d::Zero();
      Eigen::Vector2d bz = Eigen::Vector2d::Zero();
      for (const Point& p : rails[r]) {
        const Eigen::Vector2d row(1.0, p.x - x0_);
        Az += row * row.transpose();
        bz += row * p.z;
      }
      if (std::fabs(Az.determinant()) < 1e-6) continue;  // keep the previous height line
      const Eigen::Vector2d z = Az.inverse() * bz;
      d_[r] = z[0];
      e_[r] = z[1];
    }
    return true;
  }

 private:
  static double Side(int r) { return r == 0 ? 1.0 : -1.0; }

  double x0_;
  double a_, b_, c_ = 0.0, w_;
  std::array<double, 2> d_{}, e_{};
};

/// The track-bed points sorted into along-track slices (a counting sort on x).
struct Slices {
  double x_min = 0.0;
  std::vector<int> begin;  ///< slice k holds points[begin[k], begin[k + 1])
  std::vector<Point> points;

  int count() const { return static_cast<int>(begin.size()) - 1; }
  int SliceOf(double x) const {
    return std::clamp(static_cast<int>(std::floor((x - x_min) / kSliceM)), 0, count());
  }
};

/// The seed lines of both rails: y = a + b u, z = d + e u with u = x - x0.
struct Seeds {
  bool ok = false;
  std::string failure;
  double x0 = 0.0;
  std::array<double, 2> a{}, b{}, d{}, e{};
  int first_slice = 0, end_slice = 0;  ///< the seed area
};

std::string SideName(int r) { return r == 0 ? "left rail" : "right rail"; }

/// The bands around both nominal rails in which the seeds are sought.
struct RailBands {
  std::array<double, 2> nominal;  ///< y of the left and right rail
  double half;                    ///< half-width of each band

  /// The rail (0 left, 1 right) whose band holds p, or -1.
  int Of(const Point& p) const {
    for (int r = 0; r < 2; ++r) {
      if (std::fabs(p.y - nominal[r]) <= half) return r;
    }
    return -1;
  }
};

/// The slice of the kSeedRobustCount-th nearest track-bed return in a rail band, or -1.
int FirstBedSlice(const Slices& slices, const RailBands& bands) {
  int seen = 0;
  for (int k = 0; k < slices.count(); ++k) {
    for (int i = slices.begin[k]; i < slices.begin[k + 1]; ++i) {
      if (bands.Of(slices.points[i]) >= 0 && ++seen >= kSeedRobustCount) return k;
    }
  }
  return -1;
}

/// Each rail's candidates in slices [first, end): points within kLocalMaxToleranceM of the
/// highest in their band over +-kLocalMaxHalfWindow slices. The rail head stands 0.17 m above
/// the sleepers, and the window spans several slices so that slices without a rail return add
/// no sleeper tops.
std::array<std::vector<Point>, 2> LocalMaxCandidates(const Slices& slices,
                                                     const RailBands& bands,
                                                     int first,
                                                     int end) {
  const int n_seed = end - first;
  std::array<std::vector<float>, 2> slice_max;
  for (auto& m : slice_max) m.assign(n_seed, -std::numeric_limits<float>::infinity());
  for (int k = 0; k < n_seed; ++k) {
    for (int i = slices.begin[first + k]; i < slices.begin[first + k + 1]; ++i) {
      const int r = bands.Of(slices.points[i]);
      if (r >= 0) slice_max[r][k] = std::max(slice_max[r][k], slices.points[i].z);
    }
  }
  std::array<std::vector<Point>, 2> candidates;
  for (int k = 0; k < n_seed; ++k) {
    std::array<float, 2> z_max;
    for (int r = 0; r < 2; ++r) {
      const auto from = slice_max[r].begin() + std::max(0, k - kLocalMaxHalfWindow);
      const auto to = slice_max[r].begin() + std::min(n_seed - 1, k + kLocalMaxHalfWindow) + 1;
      z_max[r] = *std::max_element(from, to);
    }
    for (int i = slices.begin[first + k]; i < slices.begin[first + k + 1]; ++i) {
      const Point& p = slices.points[i];
      const int r = bands.Of(p);
      if (r >= 0 && p.z >= z_max[r] - kLocalMaxToleranceM) candidates[r].push_back(p);
    }
  }
  return candidates;
}

/// The best line pair of the RANSAC: `side`'s line y = a + b u, z = d + e u (u = x - x0), the
/// other rail on its parallel one gauge across; score < 0 when none was found.
struct SeedPair {
  int score = -1;
  int side = 0;
  double a = 0.0, b = 0.0, d = 0.0, e = 0.0;

  /// The lateral offset from `side`'s line to rail r's.
  double Across(int r, double rail_y) const {
    if (r == side) return 0.0;
    return (side == 0 ? -2.0 : 2.0) * rail_y * std::sqrt(1.0 + b * b);
  }
};

/// RANSAC over line pairs: two candidates of one rail give its line, the other rail's line is
/// its parallel one gauge across. Residuals are lateral and vertical offsets (the rails run
/// nearly along x, so these are within 2 % of the perpendicular distance).
SeedPair RansacSeedPair(const RailExtractionOptions& options,
                        const std::array<std::vector<Point>, 2>& candidates,
                        double x0,
                        double rail_y,
                        int min_seed,
                        std::mt19937* rng) {
  const double w2 = options.rail_head_width_m * options.rail_head_width_m;
  auto inliers_of = [&](const std::vector<Point>& points, const SeedPair& line, bool free_height) {
    int count = 0;
    for (const Point& p : points) {
      const double u = p.x - x0;
      const double dy = p.y - (line.a + line.b * u), dz = p.z - (line.d + line.e * u);
      count += free_height ? (dy * dy < w2 && std::fabs(dz) < kMaxCrossLevelM)
                           : (dy * dy + dz * dz < w2);
    }
    return count;
  };
  SeedPair best;
  for (int it = 0; it < options.ransac_iterations; ++it) {
    const int r = it % 2;
    const std::vector<Point>& c = candidates[r];
    std::uniform_int_distribution<size_t> pick(0, c.size() - 1);
    const Point& p = c[pick(*rng)];
    const Point& q = c[pick(*rng)];
    const double dx = q.x - p.x;
    if (std::fabs(dx) < 0.5) continue;
    SeedPair line;
    line.side = r;
    line.b = (q.y - p.y) / dx;
    line.e = (q.z - p.z) / dx;
    if (std::fabs(line.b) > kMaxSeedSlope || std::fabs(line.e) > kMaxSeedSlope) continue;
    line.a = p.y + line.b * (x0 - p.x);
    line.d = p.z + line.e * (x0 - p.x);
    const int own = inliers_of(c, line, false);
    if (own < min_seed) continue;
    SeedPair other = line;
    other.a += line.Across(1 - r, rail_y);
    line.score = own + inliers_of(candidates[1 - r], other, true);
    if (line.score > best.score) best = line;
  }
  return best;
}

/// Rail r's seed line: least squares on its candidates near the pair's line, then a second pass
/// with the rail's own height. Returns the failure, or an empty string.
std::string FitSeedLine(const RailExtractionOptions& options,
                        const std::vector<Point>& candidates,
                        int r,
                        const SeedPair& pair,
                        double rail_y,
                        int min_seed,
                        SeedLine* line) {
  const double width = options.rail_head_width_m;
  SeedLine guess = *line;
  guess.Set(pair.a + pair.Across(r, rail_y), pair.b, pair.d, pair.e);
  SeedLine refit = *line;
  int inliers = 0;
  for (const Point& p : candidates) {
    const double dy = p.y - guess.Y(p.x), dz = p.z - guess.Z(p.x);
    if (dy * dy < width * width && std::fabs(dz) < (r == pair.side ? width : kMaxCrossLevelM)) {
      refit.Add(p);
      ++inliers;
    }
  }
  if (inliers < min_seed) {
    return SideName(r) + ": the seed line has " + std::to_string(inliers) + " inliers (need " +
           std::to_string(min_seed) + ")";
  }
  if (!refit.Fit()) refit = guess;
  inliers = 0;
  for (const Point& p : candidates) {
    if (refit.Distance(p) < width) {
      line->Add(p);
      ++inliers;
    }
  }
  if (inliers < min_seed || !line->Fit()) *line = refit;
  return "";
}

/// The median height of a seed line above the track bed beside it (returns 0.12 m to `half`
/// aside, in the seed area), if there are at least five such returns.
std::optional<double> MedianBedDrop(const Slices& slices,
                                    const Seeds& seeds,
                                    const SeedLine& line,
                                    double half) {
  std::vector<float> drop;
  for (int i = slices.begin[seeds.first_slice]; i < slices.begin[seeds.end_slice]; ++i) {
    const Point& p = slices.points[i];
    const double dy = std::fabs(p.y - line.Y(p.x));
    if (dy > 0.12 && dy < half) drop.push_back(static_cast<float>(line.Z(p.x) - p.z));
  }
  if (drop.size() < 5) return std::nullopt;
  std::nth_element(drop.begin(), drop.begin() + drop.size() / 2, drop.end());
  return drop[drop.size() / 2];
}

std::string Millimetres(double m) {
  return std::to_string(static_cast<int>(std::lround(m * 1000.0)));
}

/// Seeds both rails: local-maximum-height candidates near each nominal rail in the seed area,
/// then a RANSAC line pair one gauge apart, then a least-squares line per rail on its inliers,
/// which must stand above the track bed around it (not a line through flat ballast).
Seeds FindSeeds(const RailExtractionOptions& options,
                const Slices& slices,
                double rail_y,
                std::mt19937* rng) {
  Seeds seeds;
  const RailBands bands{{rail_y, -rail_y}, options.candidate_half_width_m};
  // The seed area starts at the nearest track-bed returns near the rails.
  const int first = FirstBedSlice(slices, bands);
  if (first < 0) {
    seeds.failure = "no track-bed returns near the nominal rails";
    return seeds;
  }
  const int seed_slices =
      std::max(1, static_cast<int>(std::lround(options.seed_length_m / kSliceM)));
  seeds.first_slice = first;
  seeds.end_slice = std::min(slices.count(), first + seed_slices);
  seeds.x0 = slices.x_min + first * kSliceM;

  const std::array<std::vector<Point>, 2> candidates =
      LocalMaxCandidates(slices, bands, seeds.first_slice, seeds.end_slice);
  const int min_seed = std::max(3, options.min_rail_points / 4);
  for (int r = 0; r < 2; ++r) {
    if (static_cast<int>(candidates[r].size()) < min_seed) {
      seeds.failure = SideName(r) + ": " + std::to_string(candidates[r].size()) +
                      " local-maximum candidates in the seed area (need " +
                      std::to_string(min_seed) + ")";
      return seeds;
    }
  }
  const SeedPair pair = RansacSeedPair(options, candidates, seeds.x0, rail_y, min_seed, rng);
  if (pair.score < 0) {
    seeds.failure = "no seed line with " + std::to_string(min_seed) + " inliers";
    return seeds;
  }
  for (int r = 0; r < 2; ++r) {
    SeedLine line(seeds.x0);
    seeds.failure = FitSeedLine(options, candidates[r], r, pair, rail_y, min_seed, &line);
    if (!seeds.failure.empty()) return seeds;
    const std::optional<double> drop = MedianBedDrop(slices, seeds, line, bands.half);
    if (drop && *drop < options.min_rail_height_m) {
      seeds.failure = SideName(r) + ": the seed line stands " + Millimetres(*drop) +
                      " mm above the track bed (need " + Millimetres(options.min_rail_height_m) +
                      " mm)";
      return seeds;
    }
    seeds.a[r] = line.Y(seeds.x0);
    seeds.b[r] = line.y_slope();
    seeds.d[r] = line.Z(seeds.x0);
    seeds.e[r] = line.z_slope();
  }
  seeds.ok = true;
  return seeds;
}

/// Least-squares plane n . x + d = 0 through points (smallest principal axis), n.z > 0.
bool FitPlane(const std::vector<Eigen::Vector3d>& points, Eigen::Vector3d* n, double* d) {
  if (points.size() < 3) return false;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& p : points) cov += (p - mean) * (p - mean).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(cov);
  if (solver.info() != Eigen::Success) return false;
  *n = solver.eigenvectors().col(0);
  if (n->z() < 0.0) *n = -*n;
  *d = -n->dot(mean);
  return true;
}

/// The points of the track-bed band, from the mounting height and widened with distance for
/// roll and pitch, sorted into slices along the track.
Slices TrackBedSlices(const RailExtractionOptions& options,
                      const std::vector<Eigen::Vector3f>& points_body,
                      double rail_y) {
  const double z_rail = -options.body_above_rail_top_m;
  const double tilt = std::tan(options.max_tilt_deg * M_PI / 180.0);
  Slices slices;
  slices.x_min = options.min_forward_m;
  const int n_slices =
      static_cast<int>(std::ceil((options.max_forward_m - options.min_forward_m) / kSliceM));
  const double corridor_y =
      rail_y + options.candidate_half_width_m +
      0.5 * options.max_forward_m * options.max_forward_m / (2.0 * kMinCurveRadiusM);
  std::vector<int> slice_of(points_body.size(), -1);
  std::vector<int> counts(n_slices + 1, 0);
  for (size_t i = 0; i < points_body.size(); ++i) {
    const Eigen::Vector3f& p = points_body[i];
    if (!p.allFinite() || p.x() < options.min_forward_m || p.x() >= options.max_forward_m) continue;
    const double allowance = tilt * std::hypot(p.x(), p.y());
    if (p.z() < z_rail - 0.6 - allowance || p.z() > z_rail + 0.3 + allowance) continue;
    if (std::fabs(p.y()) > corridor_y) continue;
    const int k = std::min(n_slices - 1, static_cast<int>((p.x() - slices.x_min) / kSliceM));
    slice_of[i] = k;
    ++counts[k + 1];
  }
  slices.begin.assign(n_slices + 1, 0);
  for (int k = 0; k < n_slices; ++k) slices.begin[k + 1] = slices.begin[k] + counts[k + 1];
  slices.points.resize(slices.begin[n_slices]);
  std::vector<int> fill(slices.begin.begin(), slices.begin.end() - 1);
  for (size_t i = 0; i < points_body.size(); ++i) {
    if (slice_of[i] < 0) continue;
    const Eigen::Vector3f& p = points_body[i];
    slices.points[fill[slice_of[i]]++] = {p.x(), p.y(), p.z()};
  }
  return slices;
}

/// The track model of the seed lines: their mean line, their half separation and heights.
TrackModel SeedTrack(const Seeds& seeds) {
  const double seed_slope = 0.5 * (seeds.b[0] + seeds.b[1]);
  TrackModel track(seeds.x0,
                   0.5 * (seeds.a[0] + seeds.a[1]),
                   seed_slope,
                   0.5 * (seeds.a[0] - seeds.a[1]) / std::sqrt(1.0 + seed_slope * seed_slope));
  for (int r = 0; r < 2; ++r) track.SetHeight(r, seeds.d[r], seeds.e[r]);
  return track;
}

/// Region growing from the seeds: both rails step outward together, accept points within
/// rail_head_width_m of their current model and refit (a quadratic once long enough, so curves
/// are followed). A step that breaks the gauge or the cross level is undone and ends the growth.
std::array<std::vector<Point>, 2> GrowRails(const RailExtractionOptions& options,
                                            const Slices& slices,
                                            const Seeds& seeds,
                                            double rail_y,
                                            TrackModel* track) {
  std::array<std::vector<Point>, 2> grown;
  const double width = options.rail_head_width_m;
  const int end_slice = std::min(slices.count(), slices.SliceOf(seeds.x0 + options.max_length_m));
  const int chunk = std::max(1, static_cast<int>(std::lround(kChunkM / kSliceM)));
  std::array<bool, 2> active = {true, true};
  std::array<double, 2> last_x = {seeds.x0, seeds.x0};
  // The first step covers the seed area.
  int k = seeds.first_slice;
  int step_end = seeds.end_slice;
  while (k < end_slice && (active[0] || active[1])) {
    step_end = std::min(step_end, end_slice);
    const TrackModel saved = *track;
    const std::array<size_t, 2> saved_size = {grown[0].size(), grown[1].size()};
    for (int r = 0; r < 2; ++r) {
      if (!active[r]) continue;
      for (int i = slices.begin[k]; i < slices.begin[step_end]; ++i) {
        const Point& p = slices.points[i];
        if (track->Distance(r, p) < width) {
          grown[r].push_back(p);
          last_x[r] = std::max(last_x[r], static_cast<double>(p.x));
        }
      }
    }
    if (grown[0].size() + grown[1].size() > saved_size[0] + saved_size[1]) track->Fit(grown);
    const double x_end = slices.x_min + step_end * kSliceM;
    // Consistency: the rails stay one gauge apart and at similar heights (a wrong rail or a
    // turnout breaks this).
    const double cross_level = track->Z(0, x_end) - track->Z(1, x_end);
    if (std::fabs(2.0 * track->half_separation() - 2.0 * rail_y) > kGaugeToleranceM ||
        std::fabs(cross_level) > kMaxCrossLevelM) {
      *track = saved;
      for (int r = 0; r < 2; ++r) grown[r].resize(saved_size[r]);
      break;
    }
    for (int r = 0; r < 2; ++r) {
      if (active[r] && x_end - last_x[r] > kMaxGapM) active[r] = false;
    }
    k = step_end;
    step_end = k + chunk;
  }
  return grown;
}

/// The rail plane n . x + d = 0 (the ground plane m = [n_p; d_p] of eqs. (28)-(30)).
struct RailPlane {
  Eigen::Vector3d n = Eigen::Vector3d::UnitZ();
  double d = 0.0;
};

/// A rail-top point of the plane: returns from the sides of the rail head lie up to 5 cm lower,
/// more of them on the rail seen from further aside, and would roll the plane.
bool OnRailTop(const RailPlane& plane, const Eigen::Vector3d& p) {
  const double r = plane.n.dot(p) + plane.d;
  return r < kPlaneInlierM && r > -kRailTopBelowM;
}

/// RANSAC over planes through two points of one rail and one of the other; nullopt when no
/// hypothesis was possible.
std::optional<RailPlane> RansacRailPlane(const RailExtractionOptions& options,
                                         const std::array<std::vector<Eigen::Vector3d>, 2>& rail,
                                         std::mt19937* rng) {
  std::optional<RailPlane> best;
  int best_inliers = -1;
  for (int it = 0; it < options.ransac_iterations; ++it) {
    const std::vector<Eigen::Vector3d>& pair_rail = rail[it % 2];
    const std::vector<Eigen::Vector3d>& single_rail = rail[1 - it % 2];
    std::uniform_int_distribution<size_t> pick_pair(0, pair_rail.size() - 1);
    std::uniform_int_distribution<size_t> pick_single(0, single_rail.size() - 1);
    const Eigen::Vector3d& a = pair_rail[pick_pair(*rng)];
    const Eigen::Vector3d& b = pair_rail[pick_pair(*rng)];
    const Eigen::Vector3d& c = single_rail[pick_single(*rng)];
    if (std::fabs(a.x() - b.x()) < 1.0) continue;
    RailPlane plane;
    plane.n = (b - a).cross(c - a);
    if (plane.n.norm() < 1e-9) continue;
    plane.n.normalize();
    if (plane.n.z() < 0.0) plane.n = -plane.n;
    if (plane.n.z() < std::cos(kMaxPlaneTiltRad)) continue;
    plane.d = -plane.n.dot(a);
    int inliers = 0;
    for (const auto& points : rail) {
      for (const Eigen::Vector3d& p : points) {
        inliers += std::fabs(plane.n.dot(p) + plane.d) < kPlaneInlierM;
      }
    }
    if (inliers > best_inliers) {
      best_inliers = inliers;
      best = plane;
    }
  }
  return best;
}

/// Refits the plane by least squares to its inliers, then twice to the rail tops; false if a
/// fit is degenerate or tilts too far. `rms_m`: the final fit's RMS distance.
bool RefineRailPlane(const std::array<std::vector<Eigen::Vector3d>, 2>& rail,
                     RailPlane* plane,
                     double* rms_m) {
  std::vector<Eigen::Vector3d> inliers;
  for (int pass = 0; pass < 3; ++pass) {
    inliers.clear();
    for (int r = 0; r < 2; ++r) {
      for (const Eigen::Vector3d& p : rail[r]) {
        const bool in = pass == 0 ? std::fabs(plane->n.dot(p) + plane->d) < kPlaneInlierM
                                  : OnRailTop(*plane, p);
        if (in) inliers.push_back(p);
      }
    }
    if (!FitPlane(inliers, &plane->n, &plane->d) || plane->n.z() < std::cos(kMaxPlaneTiltRad)) {
      return false;
    }
  }
  double sum_sq = 0.0;
  for (const Eigen::Vector3d& p : inliers) {
    sum_sq += (plane->n.dot(p) + plane->d) * (plane->n.dot(p) + plane->d);
  }
  *rms_m = std::sqrt(sum_sq / static_cast<double>(inliers.size()));
  return true;
}

/// The result's rail points (those on the rail top) and each rail's line at their centroid;
/// false, with the failure set, when a rail keeps too few.
bool OutputRails(const RailExtractionOptions& options,
                 const std::array<std::vector<Eigen::Vector3d>, 2>& rail,
                 const TrackModel& track,
                 const RailPlane& plane,
                 RailExtraction* result) {
  for (int r = 0; r < 2; ++r) {
    std::vector<Eigen::Vector3f>& out = r == 0 ? result->left_points : result->right_points;
    double x_sum = 0.0;
    for (const Eigen::Vector3d& p : rail[r]) {
      if (!OnRailTop(plane, p)) continue;
      out.push_back(p.cast<float>());
      x_sum += p.x();
    }
    if (static_cast<int>(out.size()) < options.min_rail_points) {
      result->failure = SideName(r) + ": " + std::to_string(out.size()) +
                        " points on the rail plane (need " +
                        std::to_string(options.min_rail_points) + ")";
      result->left_points.clear();
      result->right_points.clear();
      return false;
    }
    const double xc = x_sum / static_cast<double>(out.size());
    const Eigen::Vector3d point(xc, track.Y(r, xc), track.Z(r, xc));
    const Eigen::Vector3d direction =
        Eigen::Vector3d(1.0, track.Slope(xc), track.z_slope(r)).normalized();
    (r == 0 ? result->left_point : result->right_point) = point;
    (r == 0 ? result->left_direction : result->right_direction) = direction;
  }
  return true;
}

}  // namespace

bool RailExtractionOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (!(body_above_rail_top_m > 0.0)) return fail("body_above_rail_top_m must be positive");
  if (!(gauge_m > 0.5 && gauge_m < 3.0)) return fail("gauge_m must be within (0.5, 3) m");
  if (!(rail_head_width_m > 0.0)) return fail("rail_head_width_m must be positive");
  if (!(candidate_half_width_m > rail_head_width_m))
    return fail("candidate_half_width_m must exceed rail_head_width_m");
  if (!(seed_length_m >= 1.0)) return fail("seed_length_m must be at least 1 m");
  if (!(max_length_m >= seed_length_m)) return fail("max_length_m must be at least seed_length_m");
  if (!(min_forward_m >= 0.0)) return fail("min_forward_m must not be negative");
  if (!(max_forward_m > min_forward_m + seed_length_m))
    return fail("max_forward_m must exceed min_forward_m + seed_length_m");
  if (!(max_tilt_deg >= 0.0 && max_tilt_deg < 20.0))
    return fail("max_tilt_deg must be within [0, 20)");
  if (!(min_rail_height_m >= 0.0)) return fail("min_rail_height_m must not be negative");
  if (ransac_iterations < 1) return fail("ransac_iterations must be at least 1");
  if (min_rail_points < 3) return fail("min_rail_points must be at least 3");
  return true;
}

RailExtraction ExtractRails(const RailExtractionOptions& options,
                            const std::vector<Eigen::Vector3f>& points_body) {
  RailExtraction result;
  std::string error;
  if (!options.IsValid(&error)) {
    result.failure = "invalid options: " + error;
    return result;
  }
  const double rail_y = 0.5 * options.gauge_m + kRailHeadHalfWidthM;
  const Slices slices = TrackBedSlices(options, points_body, rail_y);
  if (static_cast<int>(slices.points.size()) < 2 * options.min_rail_points) {
    result.failure = "only " + std::to_string(slices.points.size()) +
                     " points in the track-bed band (need " +
                     std::to_string(2 * options.min_rail_points) + ")";
    return result;
  }

  // Seeds: local-maximum-height candidates near each nominal rail and a RANSAC line pair.
  std::mt19937 rng(options.random_seed);
  const Seeds seeds = FindSeeds(options, slices, rail_y, &rng);
  if (!seeds.ok) {
    result.failure = seeds.failure;
    return result;
  }
  TrackModel track = SeedTrack(seeds);
  const std::array<std::vector<Point>, 2> grown = GrowRails(options, slices, seeds, rail_y, &track);
  std::array<std::vector<Eigen::Vector3d>, 2> rail;
  for (int r = 0; r < 2; ++r) {
    if (static_cast<int>(grown[r].size()) < options.min_rail_points) {
      result.failure = SideName(r) + ": " + std::to_string(grown[r].size()) +
                       " points after region growing (need " +
                       std::to_string(options.min_rail_points) + ")";
      return result;
    }
    rail[r].reserve(grown[r].size());
    for (const Point& p : grown[r]) rail[r].emplace_back(p.x, p.y, p.z);
  }

  // The rail plane through both rails: RANSAC, then least squares on the rail tops.
  std::optional<RailPlane> plane = RansacRailPlane(options, rail, &rng);
  if (!plane) {
    result.failure = "no rail plane hypothesis (rails too short)";
    return result;
  }
  double rms_m = 0.0;
  if (!RefineRailPlane(rail, &*plane, &rms_m)) {
    result.failure = "the rail plane fit is degenerate";
    return result;
  }
  if (!OutputRails(options, rail, track, *plane, &result)) return result;
  result.normal = plane->n;
  result.distance = plane->d;
  result.plane_rms_m = rms_m;
  result.ok = true;
  return result;
}

}  // namespace raillomer
