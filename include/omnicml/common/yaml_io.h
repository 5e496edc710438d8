// The one YAML parser entry of the project: every YAML file the library or the CLI reads
// (engine and simulator configurations, worlds, sessions, calibrations, places, occupancy
// grids, sweep specs) is parsed by LoadYaml, so that every reader refuses the same inputs
// up front with a one-line omnicml::Error "<source>:<line>: ...":
//   - text that is not UTF-8 (names the line of the first bad byte, never echoes it);
//   - a YAML syntax error;
//   - a document that, with its aliases expanded, has more than kMaxYamlNodes nodes or
//     nests deeper than kMaxYamlDepth (limits.h): an alias bomb ("billion laughs") is
//     refused after at most kMaxYamlNodes steps, before any reader copies the expansion;
//   - a duplicate key in any mapping (YAML says keys are unique; the first or the last
//     would otherwise win silently).
// yaml-cpp shares the node of an anchor between its aliases, so parsing itself is linear
// in the text; only the walk that readers do expands aliases, and that is what is bounded.
//
// Thread-safety: pure functions.
#ifndef OMNICML_COMMON_YAML_IO_H_
#define OMNICML_COMMON_YAML_IO_H_

#include <cstddef>
#include <string>
#include <string_view>

#include <yaml-cpp/yaml.h>

namespace omnicml {

// Parses `text` (read from `source`, named in errors) with the checks above.
YAML::Node LoadYaml(std::string_view text, const std::string& source);

// 1-based line of the first byte of `text` that is not part of valid UTF-8, or 0 when
// all of `text` is valid UTF-8 (overlong forms, surrogates and code points above
// U+10FFFF are invalid).
std::size_t FirstNonUtf8Line(std::string_view text);

}  // namespace omnicml

#endif  // OMNICML_COMMON_YAML_IO_H_
