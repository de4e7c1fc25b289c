#include "estimator/eval/svg_plot.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <gtest/gtest.h>

namespace raillomer::eval {
namespace {

size_t CountPoints(const std::string& polyline_points) {
  size_t count = 0;
  for (char c : polyline_points) count += c == ',';
  return count;
}

TEST(EvalSvgPlot, OnlySvgIsSupported) {
  std::string error;
  EXPECT_TRUE(IsSupportedPlotPath("/tmp/run.svg", &error));
  EXPECT_TRUE(IsSupportedPlotPath("RUN.SVG", &error));
  EXPECT_FALSE(IsSupportedPlotPath("/tmp/run.png", &error));
  EXPECT_NE(error.find(".svg"), std::string::npos);
  EXPECT_NE(error.find(".png"), std::string::npos);
  EXPECT_FALSE(IsSupportedPlotPath("/tmp/a.svg/plot", &error));
}

TEST(EvalSvgPlot, DecimationKeepsEndsAndBounds) {
  const std::vector<size_t> kept = DecimateEvenly(100000, 4000);
  ASSERT_FALSE(kept.empty());
  EXPECT_LE(kept.size(), 4000u);
  EXPECT_EQ(kept.front(), 0u);
  EXPECT_EQ(kept.back(), 99999u);
  EXPECT_EQ(DecimateEvenly(10, 4000).size(), 10u);
  const std::vector<size_t> barely = DecimateEvenly(4001, 4000);
  EXPECT_EQ(barely.size(), 4000u);
  EXPECT_EQ(barely.back(), 4000u);
  EXPECT_TRUE(std::adjacent_find(barely.begin(), barely.end(), std::greater_equal<size_t>()) ==
              barely.end());

  std::vector<double> values(100000, 0.0);
  values[54321] = 7.0;  // A single spike must survive.
  const std::vector<size_t> min_max = DecimateMinMax(values, 4000);
  EXPECT_LE(min_max.size(), 4000u);
  EXPECT_NE(std::find(min_max.begin(), min_max.end(), 54321u), min_max.end());
  EXPECT_TRUE(std::is_sorted(min_max.begin(), min_max.end()));
}

TEST(EvalSvgPlot, NiceTicks) {
  const std::vector<double> ticks = NiceTicks(-3.2, 17.0, 8);
  ASSERT_GE(ticks.size(), 4u);
  const double step = ticks[1] - ticks[0];
  EXPECT_NEAR(step, 2.0, 1e-12);
  EXPECT_GE(ticks.front(), -3.2);
  EXPECT_LE(ticks.back(), 17.0);
  EXPECT_TRUE(NiceTicks(1.0, 1.0, 5).empty());
}

TEST(EvalSvgPlot, RendersAStandaloneSvgWithBoundedPolylines) {
  PlotData data;
  data.title = "test <&> run";
  data.origin_label = "first truth pose";
  for (int i = 0; i < 100000; ++i) {
    const double s = i * 0.1;
    data.xy_truth_m.emplace_back(s, 20.0 * std::sin(s / 500.0));
    data.xy_est_m.emplace_back(s, 20.0 * std::sin(s / 500.0) + 0.5);
    data.distance_m.push_back(s);
    data.error_m.push_back(0.5 + 0.1 * std::sin(s));
  }
  const std::string svg = RenderSvgPlot(data, SvgPlotOptions{});
  EXPECT_EQ(svg.rfind("<?xml", 0), 0u);
  EXPECT_NE(svg.find("<svg xmlns=\"http://www.w3.org/2000/svg\""), std::string::npos);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);
  EXPECT_NE(svg.find("test &lt;&amp;&gt; run"), std::string::npos);
  EXPECT_NE(svg.find("distance along truth (m)"), std::string::npos);
  EXPECT_NE(svg.find("translational error (m)"), std::string::npos);
  EXPECT_EQ(svg.find("nan"), std::string::npos);
  EXPECT_EQ(svg.find("inf"), std::string::npos);

  // std::regex recurses per character, so walk the attributes by hand.
  size_t lines = 0;
  const std::string key = "points=\"";
  for (size_t at = svg.find(key); at != std::string::npos; at = svg.find(key, at + 1)) {
    const size_t begin = at + key.size();
    const std::string points = svg.substr(begin, svg.find('"', begin) - begin);
    ++lines;
    EXPECT_LE(CountPoints(points), 4000u);
    EXPECT_GT(CountPoints(points), 1000u);
  }
  EXPECT_EQ(lines, 3u);
}

TEST(EvalSvgPlot, EmptyAndSinglePointDataStillRender) {
  PlotData data;
  std::string svg = RenderSvgPlot(data, SvgPlotOptions{});
  EXPECT_EQ(svg.find("nan"), std::string::npos);
  data.xy_truth_m.emplace_back(0, 0);
  data.xy_est_m.emplace_back(0, 0);
  data.distance_m.push_back(0);
  data.error_m.push_back(0);
  svg = RenderSvgPlot(data, SvgPlotOptions{});
  EXPECT_EQ(svg.find("nan"), std::string::npos);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);
}

}  // namespace
}  // namespace raillomer::eval
