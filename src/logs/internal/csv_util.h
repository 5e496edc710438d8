// Small CSV helpers shared by the log reader and the AntWorld reader (private).
#ifndef OMNICML_LOGS_INTERNAL_CSV_UTIL_H_
#define OMNICML_LOGS_INTERNAL_CSV_UTIL_H_

#include <charconv>
#include <cmath>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

namespace omnicml::internal {

// Splits at every comma (no quoting: fields of our formats never contain commas).
inline std::vector<std::string_view> SplitCsv(std::string_view line) {
  std::vector<std::string_view> fields;
  std::size_t begin = 0;
  while (true) {
    const std::size_t comma = line.find(',', begin);
    if (comma == std::string_view::npos) {
      fields.push_back(line.substr(begin));
      return fields;
    }
    fields.push_back(line.substr(begin, comma - begin));
    begin = comma + 1;
  }
}

// Removes leading and trailing spaces and tabs.
inline std::string_view Trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

// Removes a trailing '\r' (files written on Windows).
inline void StripCarriageReturn(std::string* line) {
  if (!line->empty() && line->back() == '\r') line->pop_back();
}

// Parses the whole field as a finite double (correctly rounded, so text written by
// std::to_chars reads back bit-identically). nullopt when the field is empty, has
// trailing characters, or is NaN or infinite.
inline std::optional<double> ParseFiniteDouble(std::string_view field) {
  if (!field.empty() && field.front() == '+') field.remove_prefix(1);
  if (field.empty()) return std::nullopt;
  double value = 0.0;
  const auto [ptr, ec] = std::from_chars(field.data(), field.data() + field.size(), value);
  if (ec != std::errc() || ptr != field.data() + field.size() || !std::isfinite(value)) {
    return std::nullopt;
  }
  return value;
}

}  // namespace omnicml::internal

#endif  // OMNICML_LOGS_INTERNAL_CSV_UTIL_H_
