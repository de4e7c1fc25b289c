#include "estimator/pipeline/straight_track.h"

#include <algorithm>
#include <cmath>

namespace raillomer {

namespace {
/// s: the longest history the line is fitted to on a straight.
constexpr double kStraightSpanS = 60.0;
}  // namespace

bool StraightTrackOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (!(sigma_rad >= 0.0 && sigma_rad <= 0.1))
    return fail("sigma_rad must be in [0, 0.1] rad (0 = no heading hold)");
  if (!(detect_s >= 0.5 && detect_s <= 600.0)) return fail("detect_s must be in [0.5, 600] s");
  if (!(tolerance_rad > 0.0 && tolerance_rad <= 0.1))
    return fail("tolerance_rad must be in (0, 0.1] rad");
  if (!(max_rate_rps > 0.0 && max_rate_rps <= 0.1))
    return fail("max_rate_rps must be in (0, 0.1] rad/s");
  return true;
}

void StraightTrackDetector::Reset() {
  samples_.clear();
  heading_ = 0.0;
  straight_ = started_ = ended_ = false;
  rate_ = fit_t_ = fit_h_ = fit_slope_ = 0.0;
}

double StraightTrackDetector::DeviationAt(double t_s) const {
  for (const auto& [t, h] : samples_) {
    if (std::abs(t - t_s) < 1e-6) return h - fit_h_ - fit_slope_ * (t - fit_t_);
  }
  return 0.0;
}

void StraightTrackDetector::Add(double t_s, double raw_heading_change_rad, double bias_rps) {
  heading_ += raw_heading_change_rad;
  samples_.emplace_back(t_s, heading_);
  // Keep exactly one sample at or before the start of the span: `detect_s` to recognise a
  // straight, up to kStraightSpanS once on it (a line that long is not bent by a transition).
  const double span = straight_ ? std::max(options_.detect_s, kStraightSpanS) : options_.detect_s;
  while (samples_.size() > 2 && samples_[1].first <= t_s - span) samples_.pop_front();

  const bool was = straight_;
  bool now = false;
  if (samples_.size() >= 3 && t_s - samples_.front().first >= options_.detect_s) {
    // A least-squares line through the span's headings but its newest second, which must lie
    // on the line's extrapolation: a transition's heading grows with the square of the
    // distance into it, and a line fitted through it all would take part of that as slope.
    const double split = t_s - std::min(1.0, 0.2 * options_.detect_s);
    size_t fit = 0;
    while (fit < samples_.size() && (samples_[fit].first <= split || fit < 2)) ++fit;
    double st = 0.0, sh = 0.0;
    for (size_t i = 0; i < fit; ++i) {
      st += samples_[i].first;
      sh += samples_[i].second;
    }
    const double t_mean = st / static_cast<double>(fit), h_mean = sh / static_cast<double>(fit);
    double stt = 0.0, sth = 0.0;
    for (size_t i = 0; i < fit; ++i) {
      const double dt = samples_[i].first - t_mean;
      stt += dt * dt;
      sth += dt * (samples_[i].second - h_mean);
    }
    const double slope = stt > 0.0 ? sth / stt : 0.0;
    fit_t_ = t_mean;
    fit_h_ = h_mean;
    fit_slope_ = slope;
    rate_ = slope - bias_rps;
    double spread = 0.0;
    for (const auto& [t, h] : samples_) {
      spread = std::max(spread, std::abs(h - h_mean - slope * (t - t_mean)));
    }
    now = spread <= options_.tolerance_rad && std::abs(rate_) <= options_.max_rate_rps;
  }
  straight_ = now;
  started_ = now && !was;
  ended_ = was && !now;
  // A straight is recognised again only on a whole new span: the last seconds before its end
  // were already the curve's, which a short line through them would take for straight.
  if (ended_) samples_.erase(samples_.begin(), samples_.end() - 1);
}

}  // namespace raillomer
