#include "estimator/eval/svg_plot.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <limits>

#include "api/markup.h"

namespace raillomer::eval {

namespace {

constexpr const char* kTruthColour = "#1f1f1f";
constexpr const char* kEstColour = "#d62728";
constexpr const char* kErrorColour = "#1f77b4";

// A rectangle in pixels and the data range it shows.
struct Panel {
  double left_px, top_px, width_px, height_px;
  double x_lo, x_hi, y_lo, y_hi;

  double X(double x) const { return left_px + (x - x_lo) / (x_hi - x_lo) * width_px; }
  double Y(double y) const { return top_px + (y_hi - y) / (y_hi - y_lo) * height_px; }
};

std::string Num(double value) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.2f", value);
  return buffer;
}

std::string TickLabel(double value, double step) {
  // Enough decimals to tell neighbouring ticks apart.
  const int decimals =
      step >= 1.0 ? 0 : std::min(6, static_cast<int>(std::ceil(-std::log10(step))));
  char buffer[48];
  std::snprintf(buffer, sizeof(buffer), "%.*f", decimals, std::fabs(value) < 1e-12 ? 0.0 : value);
  return buffer;
}

std::string Escape(const std::string& text) { return api::EscapeMarkup(text); }

std::string Text(double x, double y, const std::string& text, const std::string& extra = "") {
  return "<text x=\"" + Num(x) + "\" y=\"" + Num(y) + "\"" + (extra.empty() ? "" : " " + extra) +
         ">" + Escape(text) + "</text>\n";
}

std::string Polyline(const std::vector<Eigen::Vector2d>& points_px, const char* colour) {
  std::string out = "<polyline fill=\"none\" stroke=\"" + std::string(colour) +
                    "\" stroke-width=\"1.5\" stroke-linejoin=\"round\" points=\"";
  for (size_t i = 0; i < points_px.size(); ++i) {
    if (i > 0) out += ' ';
    out += Num(points_px[i].x()) + "," + Num(points_px[i].y());
  }
  out += "\"/>\n";
  return out;
}

// Frame, grid, ticks and axis labels of one panel.
std::string Axes(const Panel& panel, const std::string& x_label, const std::string& y_label) {
  std::string out;
  out += "<rect x=\"" + Num(panel.left_px) + "\" y=\"" + Num(panel.top_px) + "\" width=\"" +
         Num(panel.width_px) + "\" height=\"" + Num(panel.height_px) +
         "\" fill=\"none\" stroke=\"#000\"/>\n";
  const std::vector<double> x_ticks = NiceTicks(panel.x_lo, panel.x_hi, 8);
  const std::vector<double> y_ticks = NiceTicks(panel.y_lo, panel.y_hi, 6);
  const double x_step = x_ticks.size() > 1 ? x_ticks[1] - x_ticks[0] : 1.0;
  const double y_step = y_ticks.size() > 1 ? y_ticks[1] - y_ticks[0] : 1.0;
  const double bottom = panel.top_px + panel.height_px;
  for (double t : x_ticks) {
    const double x = panel.X(t);
    out += "<line x1=\"" + Num(x) + "\" y1=\"" + Num(panel.top_px) + "\" x2=\"" + Num(x) +
           "\" y2=\"" + Num(bottom) + "\" stroke=\"#ddd\"/>\n";
    out += "<line x1=\"" + Num(x) + "\" y1=\"" + Num(bottom) + "\" x2=\"" + Num(x) + "\" y2=\"" +
           Num(bottom + 5) + "\" stroke=\"#000\"/>\n";
    out += Text(x, bottom + 18, TickLabel(t, x_step), "text-anchor=\"middle\"");
  }
  for (double t : y_ticks) {
    const double y = panel.Y(t);
    out += "<line x1=\"" + Num(panel.left_px) + "\" y1=\"" + Num(y) + "\" x2=\"" +
           Num(panel.left_px + panel.width_px) + "\" y2=\"" + Num(y) + "\" stroke=\"#ddd\"/>\n";
    out += "<line x1=\"" + Num(panel.left_px - 5) + "\" y1=\"" + Num(y) + "\" x2=\"" +
           Num(panel.left_px) + "\" y2=\"" + Num(y) + "\" stroke=\"#000\"/>\n";
    out += Text(panel.left_px - 8, y + 4, TickLabel(t, y_step), "text-anchor=\"end\"");
  }
  out += Text(panel.left_px + panel.width_px / 2, bottom + 38, x_label, "text-anchor=\"middle\"");
  const double y_mid = panel.top_px + panel.height_px / 2;
  out += Text(panel.left_px - 62,
              y_mid,
              y_label,
              "text-anchor=\"middle\" transform=\"rotate(-90 " + Num(panel.left_px - 62) + " " +
                  Num(y_mid) + ")\"");
  return out;
}

std::string LegendEntry(double x, double y, const char* colour, const std::string& label) {
  return "<line x1=\"" + Num(x) + "\" y1=\"" + Num(y) + "\" x2=\"" + Num(x + 24) + "\" y2=\"" +
         Num(y) + "\" stroke=\"" + colour + "\" stroke-width=\"2\"/>\n" +
         Text(x + 30, y + 4, label);
}

void Extend(const std::vector<Eigen::Vector2d>& points, Eigen::Vector2d* lo, Eigen::Vector2d* hi) {
  for (const Eigen::Vector2d& p : points) {
    if (!p.allFinite()) continue;
    *lo = lo->cwiseMin(p);
    *hi = hi->cwiseMax(p);
  }
}

/// Sizes (px) of the plot and its two panels.
struct PlotLayout {
  double width, margin_left, plot_w, title_h, top_h, gap_h, error_h, height;
};

/// The plot's layout for the options' width (at least 400 px).
PlotLayout Layout(const SvgPlotOptions& options) {
  PlotLayout layout;
  layout.width = std::max(400, options.width_px);
  layout.margin_left = 90;
  const double margin_right = 30;
  layout.plot_w = layout.width - layout.margin_left - margin_right;
  layout.title_h = 40;
  layout.top_h = layout.plot_w * 0.75;
  layout.gap_h = 90;
  layout.error_h = layout.plot_w * 0.35;
  layout.height = layout.title_h + layout.top_h + layout.gap_h + layout.error_h + 70;
  return layout;
}

/// The XML declaration, the opening svg element, a white background and the title.
std::string SvgHeader(const PlotLayout& layout, const std::string& title) {
  std::string svg = "<?xml version=\"1.0\" encoding=\"UTF-8\" standalone=\"no\"?>\n";
  svg += "<svg xmlns=\"http://www.w3.org/2000/svg\" version=\"1.1\" width=\"" + Num(layout.width) +
         "\" height=\"" + Num(layout.height) + "\" viewBox=\"0 0 " + Num(layout.width) + " " +
         Num(layout.height) + "\" font-family=\"sans-serif\" font-size=\"12\">\n";
  svg += "<rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>\n";
  svg += Text(layout.width / 2, 24, title, "text-anchor=\"middle\" font-size=\"15\"");
  return svg;
}

/// The top-down panel: both tracks centred, with equal metres per pixel on both axes.
Panel TopDownRange(const PlotData& data, const PlotLayout& layout) {
  // Panel 1: top-down xy with one metre the same length on both axes.
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector2d hi = -lo;
  Extend(data.xy_truth_m, &lo, &hi);
  Extend(data.xy_est_m, &lo, &hi);
  if (!lo.allFinite() || !hi.allFinite()) lo = hi = Eigen::Vector2d::Zero();
  const Eigen::Vector2d centre = 0.5 * (lo + hi);
  Eigen::Vector2d span = (hi - lo) * 1.05;
  span = span.cwiseMax(Eigen::Vector2d::Constant(1.0));
  const double metres_per_px = std::max(span.x() / layout.plot_w, span.y() / layout.top_h);
  return Panel{layout.margin_left,
               layout.title_h + 10,
               layout.plot_w,
               layout.top_h,
               centre.x() - 0.5 * layout.plot_w * metres_per_px,
               centre.x() + 0.5 * layout.plot_w * metres_per_px,
               centre.y() - 0.5 * layout.top_h * metres_per_px,
               centre.y() + 0.5 * layout.top_h * metres_per_px};
}

/// Panel 1's group: axes, the truth and the aligned estimate (decimated evenly), a legend.
std::string TopDownPanel(const PlotData& data,
                         const SvgPlotOptions& options,
                         const PlotLayout& layout) {
  const Panel xy = TopDownRange(data, layout);
  std::string svg = "<g id=\"top-down\">\n";
  svg += Axes(xy, "x east (m), from " + data.origin_label, "y north (m)");
  auto to_px = [&](const std::vector<Eigen::Vector2d>& points) {
    std::vector<Eigen::Vector2d> px;
    for (size_t i : DecimateEvenly(points.size(), options.max_points_per_line)) {
      px.emplace_back(xy.X(points[i].x()), xy.Y(points[i].y()));
    }
    return px;
  };
  svg += Polyline(to_px(data.xy_truth_m), kTruthColour);
  svg += Polyline(to_px(data.xy_est_m), kEstColour);
  svg += "<rect x=\"" + Num(xy.left_px + 10) + "\" y=\"" + Num(xy.top_px + 10) +
         "\" width=\"170\" height=\"48\" fill=\"#fff\" fill-opacity=\"0.85\" stroke=\"#999\"/>\n";
  svg += LegendEntry(xy.left_px + 20, xy.top_px + 26, kTruthColour, "truth");
  svg += LegendEntry(xy.left_px + 20, xy.top_px + 44, kEstColour, "estimate (aligned)");
  svg += "</g>\n";
  return svg;
}

/// Panel 2's group: axes over the distance and the largest error, the min-max decimated line.
std::string ErrorPanel(const PlotData& data,
                       const SvgPlotOptions& options,
                       const PlotLayout& layout) {
  // Panel 2: error along the truth distance.
  const size_t n = std::min(data.distance_m.size(), data.error_m.size());
  double d_lo = 0.0, d_hi = 1.0, e_hi = 1e-3;
  if (n > 0) {
    d_lo = data.distance_m.front();
    d_hi = std::max(data.distance_m[n - 1], d_lo + 1e-3);
    for (size_t i = 0; i < n; ++i) {
      if (std::isfinite(data.error_m[i])) e_hi = std::max(e_hi, data.error_m[i]);
    }
  }
  Panel err{layout.margin_left,
            layout.title_h + layout.top_h + layout.gap_h,
            layout.plot_w,
            layout.error_h,
            d_lo,
            d_hi,
            0.0,
            e_hi * 1.05};
  std::string svg = "<g id=\"error\">\n";
  svg += Axes(err, "distance along truth (m)", "translational error (m)");
  std::vector<Eigen::Vector2d> error_px;
  const std::vector<double> errors(data.error_m.begin(), data.error_m.begin() + n);
  for (size_t i : DecimateMinMax(errors, options.max_points_per_line)) {
    error_px.emplace_back(err.X(data.distance_m[i]), err.Y(data.error_m[i]));
  }
  svg += Polyline(error_px, kErrorColour);
  svg += "</g>\n";
  return svg;
}

}  // namespace

bool IsSupportedPlotPath(const std::string& path, std::string* error) {
  const size_t slash = path.find_last_of('/');
  const size_t dot = path.find_last_of('.');
  std::string extension;
  if (dot != std::string::npos && (slash == std::string::npos || dot > slash)) {
    extension = path.substr(dot);
  }
  std::string lower = extension;
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) {
    return static_cast<char>(std::tolower(c));
  });
  if (lower == ".svg") return true;
  if (error) {
    *error = "unsupported plot format '" + (extension.empty() ? path : extension) + "' for " +
             path + "; the supported format is .svg";
  }
  return false;
}

std::vector<size_t> DecimateEvenly(size_t num_points, size_t max_points) {
  std::vector<size_t> indices;
  if (num_points == 0 || max_points == 0) return indices;
  if (num_points <= max_points) {
    for (size_t i = 0; i < num_points; ++i) indices.push_back(i);
    return indices;
  }
  if (max_points == 1) return {0};
  // k (n - 1) / (m - 1) for k = 0 .. m - 1: evenly spread, both ends kept.
  for (size_t k = 0; k < max_points; ++k) {
    indices.push_back(k * (num_points - 1) / (max_points - 1));
  }
  return indices;
}

std::vector<size_t> DecimateMinMax(const std::vector<double>& values, size_t max_points) {
  const size_t n = values.size();
  std::vector<size_t> indices;
  if (n == 0 || max_points == 0) return indices;
  if (n <= max_points) {
    for (size_t i = 0; i < n; ++i) indices.push_back(i);
    return indices;
  }
  const size_t buckets = std::max<size_t>(1, max_points / 2);
  for (size_t b = 0; b < buckets; ++b) {
    const size_t begin = b * n / buckets;
    const size_t end = (b + 1) * n / buckets;
    if (begin >= end) continue;
    size_t lo = begin, hi = begin;
    for (size_t i = begin; i < end; ++i) {
      if (values[i] < values[lo]) lo = i;
      if (values[i] > values[hi]) hi = i;
    }
    indices.push_back(std::min(lo, hi));
    if (lo != hi) indices.push_back(std::max(lo, hi));
  }
  return indices;
}

std::vector<double> NiceTicks(double lo, double hi, int target) {
  std::vector<double> ticks;
  if (!std::isfinite(lo) || !std::isfinite(hi) || hi <= lo || target < 1) return ticks;
  const double raw = (hi - lo) / target;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  double step = magnitude;
  for (double factor : {2.0, 5.0, 10.0}) {
    // The candidate closest to the raw step on a log scale.
    if (std::fabs(std::log(factor * magnitude / raw)) < std::fabs(std::log(step / raw))) {
      step = factor * magnitude;
    }
  }
  const double first = std::ceil(lo / step - 1e-9) * step;
  for (double t = first; t <= hi + 1e-9 * step; t += step) ticks.push_back(t);
  return ticks;
}

std::string RenderSvgPlot(const PlotData& data, const SvgPlotOptions& options) {
  const PlotLayout layout = Layout(options);
  std::string svg = SvgHeader(layout, data.title);
  svg += TopDownPanel(data, options, layout);
  svg += ErrorPanel(data, options, layout);
  svg += "</svg>\n";
  return svg;
}

}  // namespace raillomer::eval
