// Strip plots for grouped results (the sweep summary): one column per group (e.g. an
// option value and a forgetting mode), every run of the group a dot (e.g. one per seed,
// spread sideways so equal values stay visible), the group's mean a black bar and its
// worst value an open red diamond. The legend sits right of the plot area.
//
// Output: one <svg> element, every text XML-escaped; a dot carries a <title> (its label,
// e.g. "seed 3: 0.41") shown by browsers on hover. Non-finite values are left out of
// dots, mean and worst. Pure function; thread-safe.
#ifndef OMNICML_REPORT_STRIP_PLOT_H_
#define OMNICML_REPORT_STRIP_PLOT_H_

#include <string>
#include <vector>

namespace omnicml {

struct StripGroup {
  std::string label;                      // under the column
  std::string color;                      // CSS colour of the dots ("" = the first series colour)
  std::vector<double> values;             // one per run
  std::vector<std::string> point_labels;  // parallel to values (may be empty)
};

struct StripPlotOptions {
  std::string title;
  std::string y_label;
  int width_px = 900;
  int height_px = 320;
  // Which extreme is the worst: the largest (errors) or the smallest (coverage).
  bool worst_is_max = true;
};

std::string RenderStripPlot(const std::vector<StripGroup>& groups, const StripPlotOptions& options);

}  // namespace omnicml

#endif  // OMNICML_REPORT_STRIP_PLOT_H_
