// A small, dependency-free writer of SVG plots for the HTML reports: line plots,
// step-histograms and bar histograms, and scatter plots, with axes, "nice" ticks, axis
// labels, a title, a legend (to the right of the plot area, never over the data) and
// labelled vertical markers (e.g. day boundaries on a plot over frames).
//
// The output is a single <svg> element (no XML prolog) meant to be inlined into HTML
// or saved as an .svg file; every text is XML-escaped. Non-finite data points are
// skipped (a NaN breaks a line into separate segments). Axis ranges come from the data
// unless set explicitly; an empty plot renders axes and the text "no data".
//
// Plain value type; thread-compatible.
#ifndef OMNICML_REPORT_SVG_PLOT_H_
#define OMNICML_REPORT_SVG_PLOT_H_

#include <string>
#include <utility>
#include <vector>

namespace omnicml {

// Escapes &, <, >, " and ' for XML text and attribute values.
std::string XmlEscape(const std::string& text);

// Between about target_count and 2 * target_count round tick values (multiples of 1, 2
// or 5 times a power of ten) covering [lo, hi]. lo == hi is widened; lo > hi is swapped.
std::vector<double> NiceTicks(double lo, double hi, int target_count = 5);

// Formats a tick value compactly ("0", "2.5", "1e+04").
std::string FormatTick(double value);

// The default series colours, cycled by series index (colour-blind friendly palette).
const std::string& SeriesColor(int index);

class SvgPlot {
 public:
  enum class SeriesStyle {
    kLine,     // polyline through the points (sorted as given)
    kScatter,  // a dot per point
    kBars,     // histogram bars: x holds the n + 1 bin edges, y the n bin heights
    kSteps,    // histogram as a step outline (x edges, y heights as for kBars), to overlay several
  };

  struct Series {
    std::string name;  // legend text; empty = not in the legend
    std::vector<double> x;
    std::vector<double> y;
    SeriesStyle style = SeriesStyle::kLine;
    std::string color;  // CSS colour; empty = SeriesColor(index)
  };

  // Size in pixels of the whole picture (including margins for labels).
  SvgPlot(std::string title, std::string x_label, std::string y_label, int width_px = 640,
          int height_px = 360);

  // Adds a series; x and y must have equal length, or x one more than y for kBars and
  // kSteps (throws omnicml::Error otherwise).
  void AddSeries(Series series);
  void AddLine(const std::string& name, std::vector<double> x, std::vector<double> y);
  void AddScatter(const std::string& name, std::vector<double> x, std::vector<double> y);
  // Histogram with bin_edges.size() == counts.size() + 1 (throws omnicml::Error otherwise).
  void AddHistogram(const std::string& name, const std::vector<double>& bin_edges,
                    const std::vector<double>& counts, bool as_steps = false);

  // Fixes an axis range instead of taking it from the data.
  void SetXRange(double lo, double hi);
  void SetYRange(double lo, double hi);
  // Makes the y axis start at zero (counts, errors); default true.
  void SetYFromZero(bool from_zero) { y_from_zero_ = from_zero; }
  // A dashed vertical line at data x with a short label at its top (e.g. "day 2"); drawn
  // under the series, only when inside the x range.
  void AddVerticalMarker(double x, std::string label);

  // The <svg> element.
  std::string Render() const;

  const std::vector<Series>& series() const { return series_; }

 private:
  std::string title_, x_label_, y_label_;
  int width_px_, height_px_;
  std::vector<Series> series_;
  std::vector<std::pair<double, std::string>> markers_;
  bool x_fixed_ = false, y_fixed_ = false, y_from_zero_ = true;
  double x_lo_ = 0, x_hi_ = 1, y_lo_ = 0, y_hi_ = 1;
};

}  // namespace omnicml

#endif  // OMNICML_REPORT_SVG_PLOT_H_
