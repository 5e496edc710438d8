#include "omnicml/report/strip_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "omnicml/report/svg_plot.h"

namespace omnicml {
namespace {

std::string Num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", v);
  return buf;
}

}  // namespace

std::string RenderStripPlot(const std::vector<StripGroup>& groups,
                            const StripPlotOptions& options) {
  const double width = std::max(240, options.width_px);
  // Column labels may be long: rotated under the axis, the bottom margin grows with them.
  std::size_t longest = 0;
  for (const StripGroup& g : groups) longest = std::max(longest, g.label.size());
  const double label_h = std::min(160.0, 6.0 * static_cast<double>(longest) * 0.75 + 10);
  const double height = std::max(160, options.height_px) + label_h;
  const double left = 64, right = 110, top = 32, bottom = 24 + label_h;
  const double plot_w = width - left - right, plot_h = height - top - bottom;

  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const StripGroup& g : groups) {
    for (double v : g.values) {
      if (!std::isfinite(v)) continue;
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  const bool any = std::isfinite(lo);
  if (!any) lo = 0, hi = 1;
  lo = std::min(lo, 0.0);
  hi += 0.05 * (hi - lo);  // headroom: the top dot and its worst mark stay off the frame
  std::vector<double> ticks = NiceTicks(lo, hi, 5);
  if (!ticks.empty()) lo = std::min(lo, ticks.front()), hi = std::max(hi, ticks.back());
  if (hi - lo <= 0) hi = lo + 1;
  auto py = [&](double v) { return top + plot_h - (v - lo) / (hi - lo) * plot_h; };
  const double column_w = plot_w / std::max<std::size_t>(1, groups.size());
  auto cx = [&](std::size_t i) { return left + column_w * (static_cast<double>(i) + 0.5); };

  std::ostringstream os;
  os << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << width << "\" height=\"" << height
     << "\" viewBox=\"0 0 " << width << " " << height
     << "\" font-family=\"sans-serif\" font-size=\"11\">\n"
     << "<rect x=\"0\" y=\"0\" width=\"" << width << "\" height=\"" << height
     << "\" fill=\"white\"/>\n"
     << "<text x=\"" << Num(width / 2) << "\" y=\"18\" text-anchor=\"middle\" font-size=\"13\" "
     << "font-weight=\"bold\">" << XmlEscape(options.title) << "</text>\n";
  os << "<g stroke=\"#dddddd\">\n";
  for (double t : ticks) {
    os << "<line x1=\"" << Num(left) << "\" y1=\"" << Num(py(t)) << "\" x2=\"" << Num(left + plot_w)
       << "\" y2=\"" << Num(py(t)) << "\"/>\n";
  }
  for (std::size_t i = 1; i < groups.size(); ++i) {
    const double x = left + column_w * static_cast<double>(i);
    os << "<line x1=\"" << Num(x) << "\" y1=\"" << Num(top) << "\" x2=\"" << Num(x) << "\" y2=\""
       << Num(top + plot_h) << "\" stroke=\"#eeeeee\"/>\n";
  }
  os << "</g>\n<rect x=\"" << Num(left) << "\" y=\"" << Num(top) << "\" width=\"" << Num(plot_w)
     << "\" height=\"" << Num(plot_h) << "\" fill=\"none\" stroke=\"black\"/>\n";
  for (double t : ticks) {
    os << "<text x=\"" << Num(left - 4) << "\" y=\"" << Num(py(t) + 4) << "\" text-anchor=\"end\">"
       << XmlEscape(FormatTick(t)) << "</text>\n";
  }
  os << "<text x=\"14\" y=\"" << Num(top + plot_h / 2)
     << "\" text-anchor=\"middle\" transform=\"rotate(-90 14 " << Num(top + plot_h / 2) << ")\">"
     << XmlEscape(options.y_label) << "</text>\n";
  if (!any) {
    os << "<text x=\"" << Num(left + plot_w / 2) << "\" y=\"" << Num(top + plot_h / 2)
       << "\" text-anchor=\"middle\" fill=\"#888888\">no data</text>\n";
  }

  const double spread = std::min(column_w * 0.3, 24.0);
  for (std::size_t i = 0; i < groups.size(); ++i) {
    const StripGroup& g = groups[i];
    const double x = cx(i);
    os << "<text x=\"" << Num(x) << "\" y=\"" << Num(top + plot_h + 14)
       << "\" text-anchor=\"end\" transform=\"rotate(-30 " << Num(x) << " "
       << Num(top + plot_h + 14) << ")\">" << XmlEscape(g.label) << "</text>\n";
    const std::string color = g.color.empty() ? SeriesColor(0) : g.color;
    double sum = 0, worst = 0;
    bool have_worst = false;
    int n = 0;
    const std::size_t count = g.values.size();
    for (std::size_t k = 0; k < count; ++k) {
      const double v = g.values[k];
      if (!std::isfinite(v)) continue;
      sum += v;
      ++n;
      if (!have_worst || (options.worst_is_max ? v > worst : v < worst)) worst = v;
      have_worst = true;
      // Spread sideways by index, centred on the column.
      const double dx =
          count > 1 ? spread * (2.0 * static_cast<double>(k) / static_cast<double>(count - 1) - 1)
                    : 0.0;
      os << "<circle cx=\"" << Num(x + dx) << "\" cy=\"" << Num(py(v)) << "\" r=\"3.5\" fill=\""
         << XmlEscape(color) << "\" fill-opacity=\"0.75\"><title>"
         << XmlEscape(k < g.point_labels.size() ? g.point_labels[k] : FormatTick(v))
         << "</title></circle>\n";
    }
    if (n == 0) continue;
    const double mean = sum / n;
    os << "<line x1=\"" << Num(x - spread - 6) << "\" y1=\"" << Num(py(mean)) << "\" x2=\""
       << Num(x + spread + 6) << "\" y2=\"" << Num(py(mean))
       << "\" stroke=\"black\" stroke-width=\"2\"><title>mean " << XmlEscape(FormatTick(mean))
       << "</title></line>\n";
    const double wy = py(worst), wx = x + spread + 12;
    os << "<path d=\"M" << Num(wx) << " " << Num(wy - 5) << " L" << Num(wx + 5) << " " << Num(wy)
       << " L" << Num(wx) << " " << Num(wy + 5) << " L" << Num(wx - 5) << " " << Num(wy)
       << " Z\" fill=\"none\" stroke=\"#c0102a\" stroke-width=\"1.5\"><title>worst "
       << XmlEscape(FormatTick(worst)) << "</title></path>\n";
  }
  // Legend, right of the plot area.
  const double lx = left + plot_w + 12;
  os << "<circle cx=\"" << Num(lx + 5) << "\" cy=\"" << Num(top + 10)
     << "\" r=\"3.5\" fill=\"#666666\"/><text x=\"" << Num(lx + 14) << "\" y=\"" << Num(top + 14)
     << "\">one run (seed)</text>\n";
  os << "<line x1=\"" << Num(lx) << "\" y1=\"" << Num(top + 28) << "\" x2=\"" << Num(lx + 10)
     << "\" y2=\"" << Num(top + 28) << "\" stroke=\"black\" stroke-width=\"2\"/><text x=\""
     << Num(lx + 14) << "\" y=\"" << Num(top + 32) << "\">mean</text>\n";
  os << "<path d=\"M" << Num(lx + 5) << " " << Num(top + 41) << " L" << Num(lx + 10) << " "
     << Num(top + 46) << " L" << Num(lx + 5) << " " << Num(top + 51) << " L" << Num(lx) << " "
     << Num(top + 46) << " Z\" fill=\"none\" stroke=\"#c0102a\" stroke-width=\"1.5\"/><text x=\""
     << Num(lx + 14) << "\" y=\"" << Num(top + 50) << "\">worst</text>\n";
  os << "</svg>\n";
  return os.str();
}

}  // namespace omnicml
