// Tests of the SVG plot writer: well-formed output, escaping, ticks, geometry.
#include "omnicml/report/svg_plot.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/report/strip_plot.h"

namespace omnicml {
namespace {

// Minimal XML well-formedness check: balanced, properly nested tags, quoted attributes,
// no raw '<' or '&' outside markup/entities. Returns an empty string when well formed.
std::string CheckWellFormed(const std::string& xml) {
  std::vector<std::string> stack;
  std::size_t i = 0;
  while (i < xml.size()) {
    if (xml[i] == '&') {
      const std::size_t semi = xml.find(';', i);
      if (semi == std::string::npos || semi - i > 6) return "bad entity at " + std::to_string(i);
      const std::string entity = xml.substr(i, semi - i + 1);
      if (entity != "&amp;" && entity != "&lt;" && entity != "&gt;" && entity != "&quot;" &&
          entity != "&apos;") {
        return "unknown entity " + entity;
      }
      i = semi + 1;
      continue;
    }
    if (xml[i] != '<') {
      if (xml[i] == '>') return "raw '>' in text at " + std::to_string(i);
      ++i;
      continue;
    }
    const std::size_t end = xml.find('>', i);
    if (end == std::string::npos) return "unterminated tag";
    std::string tag = xml.substr(i + 1, end - i - 1);
    i = end + 1;
    // Attribute values must be quoted and must not contain '<'.
    int quotes = 0;
    for (char c : tag) {
      if (c == '"') ++quotes;
      if (c == '<') return "'<' inside tag " + tag;
    }
    if (quotes % 2 != 0) return "unbalanced quotes in " + tag;
    if (tag.empty()) return "empty tag";
    if (tag[0] == '/') {
      const std::string name = tag.substr(1);
      if (stack.empty() || stack.back() != name) return "mismatched </" + name + ">";
      stack.pop_back();
    } else if (tag.back() != '/') {
      stack.push_back(tag.substr(0, tag.find_first_of(" \n\t")));
    }
  }
  if (!stack.empty()) return "unclosed <" + stack.back() + ">";
  return "";
}

TEST(SvgPlot, RendersWellFormedSvgWithAllSeriesKinds) {
  // Every series style together yields one balanced <svg> element.
  SvgPlot plot("Errors <day 1> & \"2\"", "frame", "error [m]");
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0, 1);
  std::vector<double> x, y;
  for (int i = 0; i < 50; ++i) {
    x.push_back(i);
    y.push_back(std::abs(noise(rng)));
  }
  plot.AddLine("line 'a'", x, y);
  plot.AddScatter("scatter", x, y);
  plot.AddHistogram("bars", {0, 1, 2, 3}, {4, 2, 1});
  plot.AddHistogram("steps", {0, 1, 2, 3}, {1, 3, 2}, true);
  const std::string svg = plot.Render();
  EXPECT_EQ(CheckWellFormed(svg), "");
  EXPECT_EQ(svg.rfind("<svg", 0), 0u);
  EXPECT_NE(svg.find("Errors &lt;day 1&gt; &amp; &quot;2&quot;"), std::string::npos);
  EXPECT_NE(svg.find("line &apos;a&apos;"), std::string::npos);
}

TEST(SvgPlot, EmptyPlotIsWellFormed) {
  // A plot without data still renders axes and says so.
  SvgPlot plot("empty", "x", "y");
  const std::string svg = plot.Render();
  EXPECT_EQ(CheckWellFormed(svg), "");
  EXPECT_NE(svg.find("no data"), std::string::npos);
}

TEST(SvgPlot, PointsStayInsideThePicture) {
  // All polyline coordinates lie within the viewBox, also with a fixed range that clips.
  SvgPlot plot("t", "x", "y", 400, 300);
  plot.AddLine("a", {-5, 0, 5, 10, 20}, {100, -3, 2, 7, 1});
  plot.SetYRange(0, 5);
  const std::string svg = plot.Render();
  std::regex points_re("points=\"([^\"]*)\"");
  std::regex pair_re("(-?[0-9.]+),(-?[0-9.]+)");
  int n = 0;
  for (auto it = std::sregex_iterator(svg.begin(), svg.end(), points_re);
       it != std::sregex_iterator(); ++it) {
    const std::string pts = (*it)[1];
    for (auto p = std::sregex_iterator(pts.begin(), pts.end(), pair_re);
         p != std::sregex_iterator(); ++p) {
      const double px = std::stod((*p)[1]), py = std::stod((*p)[2]);
      EXPECT_GE(px, 0);
      EXPECT_LE(px, 400);
      EXPECT_GE(py, 0);
      EXPECT_LE(py, 300);
      ++n;
    }
  }
  EXPECT_EQ(n, 5);
}

TEST(SvgPlot, NanSplitsALine) {
  // A NaN in the data breaks the polyline instead of drawing through it.
  SvgPlot plot("t", "x", "y");
  plot.AddLine("a", {0, 1, 2, 3, 4}, {1, 2, std::numeric_limits<double>::quiet_NaN(), 3, 4});
  const std::string svg = plot.Render();
  std::size_t count = 0;
  for (std::size_t pos = svg.find("<polyline"); pos != std::string::npos;
       pos = svg.find("<polyline", pos + 1))
    ++count;
  EXPECT_EQ(count, 2u);
}

TEST(SvgPlot, RejectsMismatchedSeries) {
  // Lengths that do not fit the style are an error, not a silent truncation.
  SvgPlot plot("t", "x", "y");
  EXPECT_THROW(plot.AddLine("a", {0, 1}, {1}), Error);
  EXPECT_THROW(plot.AddHistogram("h", {0, 1}, {1, 2}), Error);
}

TEST(NiceTicks, CoverTheRangeWithRoundSteps) {
  // Ticks lie in the range, are evenly spaced by 1, 2 or 5 times a power of ten.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> lo_dist(-1000, 1000), span_dist(1e-3, 1e4);
  for (int trial = 0; trial < 200; ++trial) {
    const double lo = lo_dist(rng), hi = lo + span_dist(rng);
    const std::vector<double> ticks = NiceTicks(lo, hi, 5);
    ASSERT_GE(ticks.size(), 2u) << lo << " " << hi;
    ASSERT_LE(ticks.size(), 12u);
    const double step = ticks[1] - ticks[0];
    const double mantissa = step / std::pow(10.0, std::floor(std::log10(step) + 1e-9));
    EXPECT_TRUE(std::abs(mantissa - 1) < 1e-6 || std::abs(mantissa - 2) < 1e-6 ||
                std::abs(mantissa - 5) < 1e-6)
        << step;
    for (std::size_t i = 0; i < ticks.size(); ++i) {
      EXPECT_GE(ticks[i], lo - 1e-9 * std::abs(step));
      EXPECT_LE(ticks[i], hi + 1e-9 * std::abs(step));
      if (i > 0) {
        EXPECT_NEAR(ticks[i] - ticks[i - 1], step, 1e-6 * step);
      }
    }
    // The ticks span most of the range (no tick interval is left out at either end).
    EXPECT_LT(ticks.front() - lo, step * 1.0000001);
    EXPECT_LT(hi - ticks.back(), step * 1.0000001);
  }
}

TEST(XmlEscape, EscapesMarkupCharacters) {
  // Markup characters become entities and the result is well formed as text.
  EXPECT_EQ(XmlEscape("a<b>&\"c'"), "a&lt;b&gt;&amp;&quot;c&apos;");
  EXPECT_EQ(CheckWellFormed("<t>" + XmlEscape("<<&&>>") + "</t>"), "");
}

// x coordinates of every point of every polyline of an SVG.
std::vector<double> PolylineXs(const std::string& svg) {
  std::vector<double> xs;
  const std::regex points("points=\"([^\"]*)\"");
  for (auto it = std::sregex_iterator(svg.begin(), svg.end(), points); it != std::sregex_iterator();
       ++it) {
    std::stringstream ss((*it)[1].str());
    std::string pair;
    while (ss >> pair) xs.push_back(std::stod(pair.substr(0, pair.find(','))));
  }
  return xs;
}

TEST(SvgPlot, LegendStaysRightOfTheData) {
  // The legend column starts right of every data point, so it never covers a curve.
  SvgPlot plot("t", "x", "y", 600, 300);
  plot.AddLine("a long series name", {0, 1, 2, 3}, {0, 1, 4, 9});
  plot.AddLine("b", {0, 3}, {9, 0});
  const std::string svg = plot.Render();
  EXPECT_EQ(CheckWellFormed(svg), "");
  const std::vector<double> xs = PolylineXs(svg);
  ASSERT_FALSE(xs.empty());
  const double data_right = *std::max_element(xs.begin(), xs.end());
  const std::regex legend_text("<text x=\"([0-9.]+)\"[^>]*>a long series name</text>");
  std::smatch m;
  ASSERT_TRUE(std::regex_search(svg, m, legend_text)) << svg;
  EXPECT_GT(std::stod(m[1].str()), data_right);
}

TEST(SvgPlot, VerticalMarkersInsideTheRangeWithEscapedLabels) {
  // A marker inside the x range is a dashed line with its label; one outside is left out.
  SvgPlot plot("t", "x", "y", 600, 300);
  plot.AddLine("", {0, 100}, {0, 1});
  plot.AddVerticalMarker(50, "day <2>");
  plot.AddVerticalMarker(500, "day 3");
  const std::string svg = plot.Render();
  EXPECT_EQ(CheckWellFormed(svg), "");
  EXPECT_NE(svg.find("day &lt;2&gt;"), std::string::npos);
  EXPECT_EQ(svg.find("day 3"), std::string::npos);
  EXPECT_NE(svg.find("stroke-dasharray"), std::string::npos);
}

TEST(StripPlot, MarksMeanAndWorstOfEachGroup) {
  // Mean bar at the group's mean, worst diamond at its max (errors) or min (coverage).
  StripGroup a{"passive <a>", "", {1.0, 2.0, 6.0}, {"seed 1", "seed 2", "seed 3"}};
  StripGroup b{"active", "#D55E00", {2.0, std::nan("")}, {}};
  StripPlotOptions o;
  o.title = "errors & more";
  const std::string svg = RenderStripPlot({a, b}, o);
  EXPECT_EQ(CheckWellFormed(svg), "");
  EXPECT_NE(svg.find("passive &lt;a&gt;"), std::string::npos);
  EXPECT_NE(svg.find("<title>mean 3</title>"), std::string::npos);
  EXPECT_NE(svg.find("<title>worst 6</title>"), std::string::npos);
  EXPECT_NE(svg.find("<title>seed 3</title>"), std::string::npos);
  EXPECT_NE(svg.find("<title>mean 2</title>"), std::string::npos);  // NaN left out
  o.worst_is_max = false;
  EXPECT_NE(RenderStripPlot({a}, o).find("<title>worst 1</title>"), std::string::npos);
  EXPECT_EQ(CheckWellFormed(RenderStripPlot({}, o)), "");
}

}  // namespace
}  // namespace omnicml
