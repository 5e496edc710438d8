#include "omnicml/report/svg_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Margins of the plot area inside the picture, pixels.
constexpr double kLeftPx = 64, kRightPx = 16, kTopPx = 32, kBottomPx = 48;

std::string Num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.2f", v);
  return buf;
}

}  // namespace

std::string XmlEscape(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&apos;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::vector<double> NiceTicks(double lo, double hi, int target_count) {
  if (!std::isfinite(lo) || !std::isfinite(hi)) return {};
  if (lo > hi) std::swap(lo, hi);
  if (hi - lo < 1e-12 * std::max(1.0, std::abs(hi))) {
    const double pad = std::max(1.0, std::abs(hi) * 0.1);
    lo -= pad;
    hi += pad;
  }
  target_count = std::max(2, target_count);
  const double raw_step = (hi - lo) / target_count;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw_step)));
  double step = magnitude;
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    step = m * magnitude;
    if (step >= raw_step) break;
  }
  std::vector<double> ticks;
  const double first = std::ceil(lo / step - 1e-9) * step;
  for (double t = first; t <= hi + step * 1e-9; t += step) {
    ticks.push_back(std::abs(t) < step * 1e-9 ? 0.0 : t);
    if (ticks.size() > 100) break;
  }
  return ticks;
}

std::string FormatTick(double value) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", value);
  return buf;
}

const std::string& SeriesColor(int index) {
  static const std::vector<std::string> kPalette = {"#0072B2", "#D55E00", "#009E73", "#CC79A7",
                                                    "#E69F00", "#56B4E9", "#000000", "#F0E442"};
  return kPalette[static_cast<std::size_t>(std::abs(index)) % kPalette.size()];
}

SvgPlot::SvgPlot(std::string title, std::string x_label, std::string y_label, int width_px,
                 int height_px)
    : title_(std::move(title)),
      x_label_(std::move(x_label)),
      y_label_(std::move(y_label)),
      width_px_(std::max(160, width_px)),
      height_px_(std::max(120, height_px)) {}

void SvgPlot::AddSeries(Series series) {
  const bool histogram = series.style == SeriesStyle::kBars || series.style == SeriesStyle::kSteps;
  const std::size_t expected_x = series.y.size() + (histogram ? 1 : 0);
  if (series.x.size() != expected_x && !(histogram && series.y.empty() && series.x.empty())) {
    throw Error(StrCat("SvgPlot: series '", series.name, "' has ", series.x.size(),
                       " x values and ", series.y.size(), " y values"));
  }
  series_.push_back(std::move(series));
}

void SvgPlot::AddLine(const std::string& name, std::vector<double> x, std::vector<double> y) {
  AddSeries({name, std::move(x), std::move(y), SeriesStyle::kLine, ""});
}

void SvgPlot::AddScatter(const std::string& name, std::vector<double> x, std::vector<double> y) {
  AddSeries({name, std::move(x), std::move(y), SeriesStyle::kScatter, ""});
}

void SvgPlot::AddHistogram(const std::string& name, const std::vector<double>& bin_edges,
                           const std::vector<double>& counts, bool as_steps) {
  if (bin_edges.size() != counts.size() + 1) {
    throw Error(StrCat("SvgPlot: histogram '", name, "' needs ", counts.size() + 1,
                       " bin edges, got ", bin_edges.size()));
  }
  AddSeries({name, bin_edges, counts, as_steps ? SeriesStyle::kSteps : SeriesStyle::kBars, ""});
}

void SvgPlot::AddVerticalMarker(double x, std::string label) {
  markers_.emplace_back(x, std::move(label));
}

void SvgPlot::SetXRange(double lo, double hi) {
  x_fixed_ = true;
  x_lo_ = std::min(lo, hi);
  x_hi_ = std::max(lo, hi);
}

void SvgPlot::SetYRange(double lo, double hi) {
  y_fixed_ = true;
  y_lo_ = std::min(lo, hi);
  y_hi_ = std::max(lo, hi);
}

std::string SvgPlot::Render() const {
  // Data ranges.
  double x_lo = std::numeric_limits<double>::infinity(), x_hi = -x_lo;
  double y_lo = x_lo, y_hi = -x_lo;
  bool any = false;
  for (const Series& s : series_) {
    for (double v : s.x) {
      if (!std::isfinite(v)) continue;
      x_lo = std::min(x_lo, v);
      x_hi = std::max(x_hi, v);
    }
    for (double v : s.y) {
      if (!std::isfinite(v)) continue;
      y_lo = std::min(y_lo, v);
      y_hi = std::max(y_hi, v);
      any = true;
    }
  }
  if (!any) {
    x_lo = 0, x_hi = 1, y_lo = 0, y_hi = 1;
  }
  if (y_from_zero_) y_lo = std::min(0.0, y_lo);
  if (x_fixed_) x_lo = x_lo_, x_hi = x_hi_;
  if (y_fixed_) y_lo = y_lo_, y_hi = y_hi_;
  std::vector<double> x_ticks = NiceTicks(x_lo, x_hi, 6);
  std::vector<double> y_ticks = NiceTicks(y_lo, y_hi, 5);
  // Extend the ranges to the outer ticks so the plot ends on a labelled value.
  if (!x_fixed_ && !x_ticks.empty()) {
    x_lo = std::min(x_lo, x_ticks.front());
    x_hi = std::max(x_hi, x_ticks.back());
  }
  if (!y_fixed_ && !y_ticks.empty()) {
    y_lo = std::min(y_lo, y_ticks.front());
    y_hi = std::max(y_hi, y_ticks.back());
  }
  if (x_hi - x_lo <= 0) x_hi = x_lo + 1;
  if (y_hi - y_lo <= 0) y_hi = y_lo + 1;

  // The legend takes a column right of the plot area, wide enough for its longest name
  // (about 6.5 px per character at font-size 11), so it never covers data.
  std::size_t longest_name = 0;
  for (const Series& s : series_) longest_name = std::max(longest_name, s.name.size());
  const double legend_w =
      longest_name == 0 ? 0.0
                        : std::min(0.4 * width_px_, 22.0 + 6.5 * static_cast<double>(longest_name));
  const double plot_w = std::max(40.0, width_px_ - kLeftPx - kRightPx - legend_w);
  const double plot_h = height_px_ - kTopPx - kBottomPx;
  auto px = [&](double x) { return kLeftPx + (x - x_lo) / (x_hi - x_lo) * plot_w; };
  auto py = [&](double y) { return kTopPx + plot_h - (y - y_lo) / (y_hi - y_lo) * plot_h; };
  auto clamp_x = [&](double v) { return std::clamp(v, kLeftPx, kLeftPx + plot_w); };
  auto clamp_y = [&](double v) { return std::clamp(v, kTopPx, kTopPx + plot_h); };

  std::ostringstream os;
  os << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << width_px_ << "\" height=\""
     << height_px_ << "\" viewBox=\"0 0 " << width_px_ << " " << height_px_
     << "\" font-family=\"sans-serif\" font-size=\"11\">\n";
  os << "<rect x=\"0\" y=\"0\" width=\"" << width_px_ << "\" height=\"" << height_px_
     << "\" fill=\"white\"/>\n";
  os << "<text x=\"" << Num(width_px_ / 2.0)
     << "\" y=\"18\" text-anchor=\"middle\" font-size=\"13\""
     << " font-weight=\"bold\">" << XmlEscape(title_) << "</text>\n";
  // Grid and ticks.
  os << "<g stroke=\"#dddddd\" stroke-width=\"1\">\n";
  for (double t : x_ticks) {
    if (t < x_lo || t > x_hi) continue;
    os << "<line x1=\"" << Num(px(t)) << "\" y1=\"" << Num(kTopPx) << "\" x2=\"" << Num(px(t))
       << "\" y2=\"" << Num(kTopPx + plot_h) << "\"/>\n";
  }
  for (double t : y_ticks) {
    if (t < y_lo || t > y_hi) continue;
    os << "<line x1=\"" << Num(kLeftPx) << "\" y1=\"" << Num(py(t)) << "\" x2=\""
       << Num(kLeftPx + plot_w) << "\" y2=\"" << Num(py(t)) << "\"/>\n";
  }
  os << "</g>\n";
  os << "<rect x=\"" << Num(kLeftPx) << "\" y=\"" << Num(kTopPx) << "\" width=\"" << Num(plot_w)
     << "\" height=\"" << Num(plot_h) << "\" fill=\"none\" stroke=\"black\"/>\n";
  os << "<g fill=\"black\">\n";
  for (double t : x_ticks) {
    if (t < x_lo || t > x_hi) continue;
    os << "<text x=\"" << Num(px(t)) << "\" y=\"" << Num(kTopPx + plot_h + 14)
       << "\" text-anchor=\"middle\">" << XmlEscape(FormatTick(t)) << "</text>\n";
  }
  for (double t : y_ticks) {
    if (t < y_lo || t > y_hi) continue;
    os << "<text x=\"" << Num(kLeftPx - 4) << "\" y=\"" << Num(py(t) + 4)
       << "\" text-anchor=\"end\">" << XmlEscape(FormatTick(t)) << "</text>\n";
  }
  os << "<text x=\"" << Num(kLeftPx + plot_w / 2) << "\" y=\"" << Num(height_px_ - 8.0)
     << "\" text-anchor=\"middle\">" << XmlEscape(x_label_) << "</text>\n";
  os << "<text x=\"14\" y=\"" << Num(kTopPx + plot_h / 2)
     << "\" text-anchor=\"middle\" transform=\"rotate(-90 14 " << Num(kTopPx + plot_h / 2) << ")\">"
     << XmlEscape(y_label_) << "</text>\n";
  os << "</g>\n";
  if (!any) {
    os << "<text x=\"" << Num(kLeftPx + plot_w / 2) << "\" y=\"" << Num(kTopPx + plot_h / 2)
       << "\" text-anchor=\"middle\" fill=\"#888888\">no data</text>\n";
  }

  // Vertical markers, under the series.
  for (const auto& [mx, label] : markers_) {
    if (!std::isfinite(mx) || mx < x_lo || mx > x_hi) continue;
    os << "<line x1=\"" << Num(px(mx)) << "\" y1=\"" << Num(kTopPx) << "\" x2=\"" << Num(px(mx))
       << "\" y2=\"" << Num(kTopPx + plot_h)
       << "\" stroke=\"#888888\" stroke-width=\"1\" stroke-dasharray=\"4 3\"/>\n";
    if (!label.empty()) {
      os << "<text x=\"" << Num(px(mx) + 3) << "\" y=\"" << Num(kTopPx + 10)
         << "\" fill=\"#666666\" font-size=\"9\">" << XmlEscape(label) << "</text>\n";
    }
  }

  // Series.
  for (std::size_t i = 0; i < series_.size(); ++i) {
    const Series& s = series_[i];
    const std::string color = s.color.empty() ? SeriesColor(static_cast<int>(i)) : s.color;
    switch (s.style) {
      case SeriesStyle::kLine: {
        std::string points;
        auto flush = [&] {
          if (!points.empty()) {
            os << "<polyline fill=\"none\" stroke=\"" << XmlEscape(color)
               << "\" stroke-width=\"1.5\" points=\"" << points << "\"/>\n";
          }
          points.clear();
        };
        for (std::size_t k = 0; k < s.x.size(); ++k) {
          if (!std::isfinite(s.x[k]) || !std::isfinite(s.y[k])) {
            flush();
            continue;
          }
          points += Num(clamp_x(px(s.x[k]))) + "," + Num(clamp_y(py(s.y[k]))) + " ";
        }
        flush();
        break;
      }
      case SeriesStyle::kScatter: {
        os << "<g fill=\"" << XmlEscape(color) << "\" fill-opacity=\"0.6\">\n";
        for (std::size_t k = 0; k < s.x.size(); ++k) {
          if (!std::isfinite(s.x[k]) || !std::isfinite(s.y[k])) continue;
          if (s.x[k] < x_lo || s.x[k] > x_hi || s.y[k] < y_lo || s.y[k] > y_hi) continue;
          os << "<circle cx=\"" << Num(px(s.x[k])) << "\" cy=\"" << Num(py(s.y[k]))
             << "\" r=\"2\"/>\n";
        }
        os << "</g>\n";
        break;
      }
      case SeriesStyle::kBars: {
        os << "<g fill=\"" << XmlEscape(color)
           << "\" fill-opacity=\"0.7\" stroke=\"white\" stroke-width=\"0.5\">\n";
        for (std::size_t k = 0; k < s.y.size(); ++k) {
          if (!std::isfinite(s.y[k]) || !std::isfinite(s.x[k]) || !std::isfinite(s.x[k + 1]))
            continue;
          const double left = clamp_x(px(s.x[k])), right = clamp_x(px(s.x[k + 1]));
          const double top = clamp_y(py(s.y[k])), base = clamp_y(py(std::max(0.0, y_lo)));
          os << "<rect x=\"" << Num(left) << "\" y=\"" << Num(std::min(top, base)) << "\" width=\""
             << Num(std::max(0.0, right - left)) << "\" height=\"" << Num(std::abs(base - top))
             << "\"/>\n";
        }
        os << "</g>\n";
        break;
      }
      case SeriesStyle::kSteps: {
        std::string points;
        const double base = clamp_y(py(std::max(0.0, y_lo)));
        for (std::size_t k = 0; k < s.y.size(); ++k) {
          if (!std::isfinite(s.y[k])) continue;
          const double left = clamp_x(px(s.x[k])), right = clamp_x(px(s.x[k + 1]));
          const double top = clamp_y(py(s.y[k]));
          if (points.empty()) points += Num(left) + "," + Num(base) + " ";
          points += Num(left) + "," + Num(top) + " " + Num(right) + "," + Num(top) + " ";
          if (k + 1 == s.y.size()) points += Num(right) + "," + Num(base) + " ";
        }
        if (!points.empty()) {
          os << "<polyline fill=\"none\" stroke=\"" << XmlEscape(color)
             << "\" stroke-width=\"1.5\" points=\"" << points << "\"/>\n";
        }
        break;
      }
    }
  }

  // Legend, in its column right of the plot area.
  int legend_row = 0;
  for (std::size_t i = 0; i < series_.size(); ++i) {
    if (series_[i].name.empty()) continue;
    const std::string color =
        series_[i].color.empty() ? SeriesColor(static_cast<int>(i)) : series_[i].color;
    const double y = kTopPx + 12 + 14 * legend_row++;
    const double x = kLeftPx + plot_w + 10;
    os << "<rect x=\"" << Num(x) << "\" y=\"" << Num(y - 8)
       << "\" width=\"10\" height=\"10\" fill=\"" << XmlEscape(color) << "\"/>\n";
    os << "<text x=\"" << Num(x + 14) << "\" y=\"" << Num(y + 1) << "\">"
       << XmlEscape(series_[i].name) << "</text>\n";
  }
  os << "</svg>\n";
  return os.str();
}

}  // namespace omnicml
