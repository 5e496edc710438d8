#include "omnicml/report/report.h"

#include <algorithm>
#include <sstream>

#include "omnicml/common/common.h"
#include "omnicml/report/svg_plot.h"

namespace omnicml {
namespace fs = std::filesystem;

HtmlReport::HtmlReport(std::string title) : title_(std::move(title)) {}

void HtmlReport::AddHeading(const std::string& text, int level) {
  level = std::clamp(level, 1, 4);
  blocks_.push_back(StrCat("<h", level, ">", XmlEscape(text), "</h", level, ">"));
}

void HtmlReport::AddParagraph(const std::string& text) {
  blocks_.push_back("<p>" + XmlEscape(text) + "</p>");
}

void HtmlReport::AddTable(const std::vector<std::string>& header,
                          const std::vector<std::vector<std::string>>& rows) {
  std::ostringstream os;
  // Wide tables scroll sideways inside their own box instead of widening the page.
  os << "<div class=\"scroll\"><table>\n";
  const bool has_header =
      std::any_of(header.begin(), header.end(), [](const std::string& h) { return !h.empty(); });
  if (has_header) {
    os << "<tr>";
    for (const auto& h : header) os << "<th>" << XmlEscape(h) << "</th>";
    os << "</tr>\n";
  }
  for (const auto& row : rows) {
    os << "<tr>";
    const std::size_t n = std::max(row.size(), header.size());
    for (std::size_t i = 0; i < n; ++i) {
      os << "<td>" << (i < row.size() ? XmlEscape(row[i]) : "") << "</td>";
    }
    os << "</tr>\n";
  }
  os << "</table></div>";
  blocks_.push_back(os.str());
}

void HtmlReport::AddKeyValues(const std::vector<std::pair<std::string, std::string>>& items) {
  std::vector<std::vector<std::string>> rows;
  for (const auto& [k, v] : items) rows.push_back({k, v});
  AddTable({"", ""}, rows);
}

void HtmlReport::AddPreformatted(const std::string& text) {
  blocks_.push_back("<pre>" + XmlEscape(text) + "</pre>");
}

void HtmlReport::AddSvg(const std::string& svg) {
  blocks_.push_back("<div class=\"plot\">" + svg + "</div>");
}

void HtmlReport::AddRawHtml(const std::string& html) { blocks_.push_back(html); }

std::string HtmlReport::Render() const {
  std::ostringstream os;
  os << "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>"
     << XmlEscape(title_) << "</title>\n<style>\n"
     << "body{font-family:sans-serif;max-width:1100px;margin:1em auto;padding:0 1em;color:#222}\n"
     << "table{border-collapse:collapse;margin:0.5em 0}\n"
     << "td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}\n"
     << "th{background:#f0f0f0}\npre{background:#f7f7f7;padding:0.5em;overflow:auto}\n"
     << ".plot{display:inline-block;margin:4px;max-width:100%;overflow-x:auto}\n"
     << ".scroll{overflow-x:auto;max-width:100%}\n"
     << "td:first-child,th:first-child{text-align:left}\n</style>\n</head>\n<body>\n<h1>"
     << XmlEscape(title_) << "</h1>\n";
  for (const auto& b : blocks_) os << b << "\n";
  os << "</body>\n</html>\n";
  return os.str();
}

}  // namespace omnicml
