#include "omnicml/common/yaml_io.h"

#include <cstdint>
#include <set>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"

namespace omnicml {
namespace {

int LineOf(const YAML::Node& node) { return node.Mark().line >= 0 ? node.Mark().line + 1 : 1; }

// Walks `node` with aliases expanded, counting every node visited into *visited.
void CheckTree(const YAML::Node& node, const std::string& source, int depth,
               std::int64_t* visited) {
  if (++*visited > kMaxYamlNodes) {
    throw Error(StrCat(source, ":", LineOf(node), ": YAML document expands to more than ",
                       kMaxYamlNodes, " nodes (aliases of aliases?); refused"));
  }
  if (depth > kMaxYamlDepth) {
    throw Error(StrCat(source, ":", LineOf(node), ": YAML nested deeper than ", kMaxYamlDepth,
                       " levels; refused"));
  }
  if (node.IsSequence()) {
    for (const YAML::Node& item : node) CheckTree(item, source, depth + 1, visited);
  } else if (node.IsMap()) {
    std::set<std::string> keys;
    for (const auto& kv : node) {
      if (kv.first.IsScalar() && !keys.insert(kv.first.Scalar()).second) {
        throw Error(StrCat(source, ":", LineOf(kv.first), ": duplicate key '",
                           Excerpt(kv.first.Scalar(), 60), "'"));
      }
      CheckTree(kv.first, source, depth + 1, visited);
      CheckTree(kv.second, source, depth + 1, visited);
    }
  }
}

}  // namespace

std::size_t FirstNonUtf8Line(std::string_view text) {
  std::size_t line = 1;
  std::size_t i = 0;
  const auto byte = [&](std::size_t k) { return static_cast<unsigned char>(text[k]); };
  while (i < text.size()) {
    const unsigned char c = byte(i);
    if (c == '\n') ++line;
    if (c < 0x80) {
      ++i;
      continue;
    }
    int length = 0;
    std::uint32_t cp = 0;
    if (c >= 0xC2 && c <= 0xDF) {
      length = 2;
      cp = c & 0x1F;
    } else if (c >= 0xE0 && c <= 0xEF) {
      length = 3;
      cp = c & 0x0F;
    } else if (c >= 0xF0 && c <= 0xF4) {
      length = 4;
      cp = c & 0x07;
    } else {
      return line;
    }
    if (i + static_cast<std::size_t>(length) > text.size()) return line;
    for (int k = 1; k < length; ++k) {
      const unsigned char cc = byte(i + static_cast<std::size_t>(k));
      if ((cc & 0xC0) != 0x80) return line;
      cp = (cp << 6) | (cc & 0x3F);
    }
    const bool overlong = (length == 3 && cp < 0x800) || (length == 4 && cp < 0x10000);
    if (overlong || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return line;
    i += static_cast<std::size_t>(length);
  }
  return 0;
}

YAML::Node LoadYaml(std::string_view text, const std::string& source) {
  if (const std::size_t line = FirstNonUtf8Line(text); line > 0) {
    throw Error(StrCat(source, ":", line, ": not valid UTF-8 text (YAML files are UTF-8)"));
  }
  YAML::Node root;
  try {
    root = YAML::Load(std::string(text));
  } catch (const YAML::Exception& e) {
    throw Error(StrCat(source, ":", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  }
  std::int64_t visited = 0;
  CheckTree(root, source, 0, &visited);
  return root;
}

}  // namespace omnicml
