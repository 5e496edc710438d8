// Self-contained HTML reports (inline SVG plots, tables, preformatted text; no external
// scripts, fonts or style sheets). Output files are written with AtomicFile /
// WriteFileAtomic from omnicml/common/file_io.h (included here for existing users).
//
// HtmlReport is thread-compatible (one thread at a time per object).
#ifndef OMNICML_REPORT_REPORT_H_
#define OMNICML_REPORT_REPORT_H_

#include <string>
#include <vector>

#include "omnicml/common/file_io.h"

namespace omnicml {

// An HTML page assembled from blocks, rendered by Render() into one string.
class HtmlReport {
 public:
  explicit HtmlReport(std::string title);

  // <h2>/<h3> heading; level is clamped to 1..4.
  void AddHeading(const std::string& text, int level = 2);
  // A paragraph of plain text (escaped).
  void AddParagraph(const std::string& text);
  // A table; every row should have header.size() cells (shorter rows are padded). A
  // table wider than the page scrolls sideways in its own box.
  void AddTable(const std::vector<std::string>& header,
                const std::vector<std::vector<std::string>>& rows);
  // A key/value list rendered as a two-column table.
  void AddKeyValues(const std::vector<std::pair<std::string, std::string>>& items);
  // Preformatted text (escaped), e.g. a configuration or a text table.
  void AddPreformatted(const std::string& text);
  // An <svg> element inserted verbatim (from SvgPlot::Render or the map drawer).
  void AddSvg(const std::string& svg);
  // Raw, trusted HTML inserted verbatim.
  void AddRawHtml(const std::string& html);

  std::string Render() const;

 private:
  std::string title_;
  std::vector<std::string> blocks_;
};

}  // namespace omnicml

#endif  // OMNICML_REPORT_REPORT_H_
