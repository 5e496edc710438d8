#include "omnicml/common/options.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <iostream>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/file_io.h"
#include "omnicml/common/yaml_io.h"

namespace omnicml {

OptionValue::OptionValue() = default;
OptionValue::~OptionValue() = default;
OptionValue::OptionValue(const OptionValue&) = default;
OptionValue::OptionValue(OptionValue&&) noexcept = default;
OptionValue& OptionValue::operator=(const OptionValue&) = default;
OptionValue& OptionValue::operator=(OptionValue&&) noexcept = default;

OptionValue OptionValue::Scalar(std::string text, bool quoted) {
  OptionValue v;
  v.kind = Kind::kScalar;
  v.scalar = std::move(text);
  v.quoted = quoted;
  return v;
}
OptionValue OptionValue::List() {
  OptionValue v;
  v.kind = Kind::kList;
  return v;
}
OptionValue OptionValue::Map() {
  OptionValue v;
  v.kind = Kind::kMap;
  return v;
}
bool OptionValue::operator==(const OptionValue& o) const {
  return kind == o.kind && scalar == o.scalar && items == o.items && members == o.members;
}

namespace {

OptionValue FromYaml(const YAML::Node& n, const std::string& source) {
  const int line = n.Mark().line >= 0 ? n.Mark().line + 1 : 0;
  OptionValue v;
  switch (n.Type()) {
    case YAML::NodeType::Map: {
      v = OptionValue::Map();
      for (auto it = n.begin(); it != n.end(); ++it) {
        if (!it->first.IsScalar()) {
          throw Error(StrCat(source, ":", it->first.Mark().line + 1, ": keys must be scalars"));
        }
        const std::string key = it->first.Scalar();
        for (const auto& [k, unused] : v.members) {
          if (k == key) {
            throw Error(
                StrCat(source, ":", it->first.Mark().line + 1, ": duplicate key '", key, "'"));
          }
        }
        OptionValue child = FromYaml(it->second, source);
        child.line = it->first.Mark().line + 1;  // errors name the key's line
        v.members.emplace_back(key, std::move(child));
      }
      break;
    }
    case YAML::NodeType::Sequence:
      v = OptionValue::List();
      for (const auto& e : n) v.items.push_back(FromYaml(e, source));
      break;
    case YAML::NodeType::Scalar:
      v = OptionValue::Scalar(n.Scalar(), n.Tag() == "!");
      break;
    case YAML::NodeType::Null:
    case YAML::NodeType::Undefined:
      v = OptionValue::Scalar("");
      break;
  }
  v.line = line;
  return v;
}

void ToYaml(YAML::Emitter& out, const OptionValue& v) {
  switch (v.kind) {
    case OptionValue::Kind::kScalar:
      if (v.quoted) {
        out << YAML::DoubleQuoted << v.scalar;
      } else {
        out << v.scalar;
      }
      break;
    case OptionValue::Kind::kList:
      out << YAML::Flow << YAML::BeginSeq;
      for (const OptionValue& e : v.items) ToYaml(out, e);
      out << YAML::EndSeq;
      break;
    case OptionValue::Kind::kMap:
      out << YAML::BeginMap;
      for (const auto& [k, e] : v.members) {
        out << YAML::Key << k << YAML::Value;
        ToYaml(out, e);
      }
      out << YAML::EndMap;
      break;
  }
}

constexpr int kMaxDepth = 32;

OptionValue Decode(BinaryReader& in, const char* what, int depth) {
  if (depth > kMaxDepth) in.Fail(what, "options nested too deeply");
  const auto kind = in.Read<std::uint8_t>(what);
  OptionValue v;
  switch (kind) {
    case 0:
      v = OptionValue::Scalar(in.ReadString(what));
      v.quoted = in.Read<bool>(what);
      break;
    case 1: {
      v = OptionValue::List();
      const std::size_t n = in.ReadCount(what, 1);
      for (std::size_t i = 0; i < n; ++i) v.items.push_back(Decode(in, what, depth + 1));
      break;
    }
    case 2: {
      v = OptionValue::Map();
      const std::size_t n = in.ReadCount(what, 9);
      for (std::size_t i = 0; i < n; ++i) {
        std::string key = in.ReadString(what);
        v.members.emplace_back(std::move(key), Decode(in, what, depth + 1));
      }
      break;
    }
    default:
      in.Fail(what, StrCat("invalid option value kind ", static_cast<int>(kind)));
  }
  return v;
}

}  // namespace

OptionValue ParseOptionYaml(const std::string& text, const std::string& source) {
  YAML::Node root;
  try {
    root = LoadYaml(text, source);
  } catch (const YAML::Exception& e) {
    throw Error(StrCat(source, ":", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  }
  if (!root || root.IsNull()) return OptionValue::Map();
  return FromYaml(root, source);
}

std::string OptionYaml(const OptionValue& value) {
  YAML::Emitter out;
  ToYaml(out, value);
  if (!out.good()) throw InternalError(StrCat("YAML emitter: ", out.GetLastError()));
  return std::string(out.c_str()) + "\n";
}

void EncodeOptionValue(BinaryWriter& out, const OptionValue& v) {
  out.Write<std::uint8_t>(static_cast<std::uint8_t>(v.kind));
  switch (v.kind) {
    case OptionValue::Kind::kScalar:
      out.WriteString(v.scalar);
      out.Write<bool>(v.quoted);
      break;
    case OptionValue::Kind::kList:
      out.Write<std::uint64_t>(v.items.size());
      for (const OptionValue& e : v.items) EncodeOptionValue(out, e);
      break;
    case OptionValue::Kind::kMap:
      out.Write<std::uint64_t>(v.members.size());
      for (const auto& [k, e] : v.members) {
        out.WriteString(k);
        EncodeOptionValue(out, e);
      }
      break;
  }
}

OptionValue DecodeOptionValue(BinaryReader& in, const char* what) { return Decode(in, what, 0); }

std::string ReadOptionFile(const std::string& path) {
  // A regular file of at most kMaxTextFileBytes (no FIFO, device, directory or link loop).
  return ReadTextFile(path, kMaxTextFileBytes, "configuration file");
}

namespace options_internal {

std::string FormatDouble(double v) {
  if (std::isnan(v)) return ".nan";
  if (std::isinf(v)) return v > 0 ? ".inf" : "-.inf";
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, res.ptr);
}

void Fail(const OptionSource& src, const OptionValue* at, const std::string& path,
          const std::string& what) {
  std::string where = src.name;
  if (at != nullptr && at->line > 0) where += StrCat(":", at->line);
  throw Error(StrCat(where, ": '", path, "' ", what));
}

std::string JoinPath(const std::string& prefix, const char* key) {
  return prefix.empty() ? std::string(key) : prefix + "." + key;
}

namespace {
const std::string& ScalarText(const OptionValue& v, const OptionSource& src,
                              const std::string& path, const char* expected) {
  if (v.kind != OptionValue::Kind::kScalar) Fail(src, &v, path, StrCat("must be ", expected));
  return v.scalar;
}
}  // namespace

bool ParseBool(const OptionValue& v, const OptionSource& src, const std::string& path) {
  const std::string& s = ScalarText(v, src, path, "true or false");
  if (s == "true" || s == "True" || s == "TRUE") return true;
  if (s == "false" || s == "False" || s == "FALSE") return false;
  Fail(src, &v, path, "must be true or false (got '" + s + "')");
}

double ParseDouble(const OptionValue& v, const OptionSource& src, const std::string& path) {
  const std::string& s = ScalarText(v, src, path, "a number");
  if (s == ".nan" || s == ".NaN" || s == ".NAN") return std::nan("");
  if (s == ".inf" || s == "+.inf" || s == ".Inf") return std::numeric_limits<double>::infinity();
  if (s == "-.inf" || s == "-.Inf") return -std::numeric_limits<double>::infinity();
  const char* begin = s.data();
  const char* end = s.data() + s.size();
  if (begin != end && *begin == '+') ++begin;
  double x = 0;
  const auto res = std::from_chars(begin, end, x);
  if (s.empty() || res.ec != std::errc() || res.ptr != end) {
    Fail(src, &v, path, "must be a number (got '" + s + "')");
  }
  return x;
}

std::int64_t ParseInt(const OptionValue& v, const OptionSource& src, const std::string& path,
                      std::int64_t lo, std::int64_t hi) {
  const std::string& s = ScalarText(v, src, path, "an integer");
  const char* begin = s.data();
  const char* end = s.data() + s.size();
  if (begin != end && *begin == '+') ++begin;
  std::int64_t x = 0;
  const auto res = std::from_chars(begin, end, x);
  if (s.empty() || res.ec != std::errc() || res.ptr != end) {
    // Integral doubles ("3.0", "1e3") are accepted.
    const double d = ParseDouble(v, src, path);
    if (d != std::floor(d) || d < static_cast<double>(lo) || d > static_cast<double>(hi)) {
      Fail(src, &v, path,
           StrCat("must be an integer in range [", lo, ", ", hi, "] (got '", s, "')"));
    }
    return static_cast<std::int64_t>(d);
  }
  if (x < lo || x > hi) {
    Fail(src, &v, path, StrCat("must be an integer in range [", lo, ", ", hi, "] (got '", s, "')"));
  }
  return x;
}

std::uint64_t ParseUInt(const OptionValue& v, const OptionSource& src, const std::string& path,
                        std::uint64_t hi) {
  const std::string& s = ScalarText(v, src, path, "a non-negative integer");
  const char* begin = s.data();
  const char* end = s.data() + s.size();
  if (begin != end && *begin == '+') ++begin;
  std::uint64_t x = 0;
  const auto res = std::from_chars(begin, end, x);
  if (s.empty() || res.ec != std::errc() || res.ptr != end || x > hi) {
    Fail(src, &v, path, StrCat("must be an integer in range [0, ", hi, "] (got '", s, "')"));
  }
  return x;
}

std::string ParseString(const OptionValue& v, const OptionSource& src, const std::string& path) {
  return ScalarText(v, src, path, "a scalar");
}

void ExpectList(const OptionValue& v, const OptionSource& src, const std::string& path,
                std::size_t n, const char* shape) {
  if (v.kind != OptionValue::Kind::kList || (n > 0 && v.items.size() != n)) {
    Fail(src, &v, path,
         n > 0 ? StrCat("must be ", shape, " of ", n, " entries") : StrCat("must be ", shape));
  }
}

TreeReader::TreeReader(const OptionValue& map, const OptionSource& src, std::string prefix)
    : map_(map), src_(src), prefix_(std::move(prefix)) {
  if (map_.kind != OptionValue::Kind::kMap) {
    if (prefix_.empty()) {
      std::string where = src_.name;
      if (map_.line > 0) where += StrCat(":", map_.line);
      throw Error(where + ": the configuration must be a map of keys");
    }
    Fail(src_, &map_, prefix_, "must be a map of keys");
  }
}

const OptionValue* TreeReader::Take(const char* key) {
  for (const auto& [old_key, new_path] : renamed_) {
    if (old_key == key) return nullptr;  // read under its former meaning (TakeRenamed)
  }
  claimed_.emplace_back(key);
  for (const auto& [k, v] : map_.members) {
    if (k == key) return &v;
  }
  if (!optional_) missing_.emplace_back(key);
  return nullptr;
}

const OptionValue* TreeReader::TakeRenamed(const char* old_key, const char* new_path) {
  for (const auto& [k, v] : map_.members) {
    if (k != old_key || v.kind == OptionValue::Kind::kMap) continue;
    claimed_.emplace_back(old_key);
    if (renamed_.empty()) renamed_line_ = v.line;
    renamed_.emplace_back(old_key, new_path);
    return &v;
  }
  return nullptr;
}

void TreeReader::Finish() const {
  if (!renamed_.empty()) {
    std::string where = src_.name;
    if (renamed_line_ > 0) where += StrCat(":", renamed_line_);
    std::string list;
    for (const auto& [old_key, new_path] : renamed_) {
      list += StrCat(list.empty() ? "" : ", ", JoinPath(prefix_, old_key.c_str()), " -> ",
                     JoinPath(prefix_, new_path.c_str()));
    }
    std::cerr << where
              << ": warning: deprecated option keys, write them in their sections: " << list
              << "\n";
  }
  for (const auto& [k, v] : map_.members) {
    if (std::find(claimed_.begin(), claimed_.end(), k) != claimed_.end()) continue;
    if (prefix_.empty() && std::find(src_.ignored_keys.begin(), src_.ignored_keys.end(), k) !=
                               src_.ignored_keys.end()) {
      continue;
    }
    std::string where = src_.name;
    const int line = v.line;
    if (line > 0) where += StrCat(":", line);
    throw Error(StrCat(where, ": unknown key '", JoinPath(prefix_, k.c_str()), "'"));
  }
  if (src_.complete && !missing_.empty()) {
    throw Error(
        StrCat(src_.name, ": missing option '", JoinPath(prefix_, missing_.front().c_str()), "'"));
  }
}

void OmitNewerDefaults(OptionValue* tree, const OptionValue& defaults,
                       std::uint32_t format_version) {
  if (tree->kind != OptionValue::Kind::kMap || defaults.kind != OptionValue::Kind::kMap) return;
  auto default_of = [&defaults](const std::string& key) -> const OptionValue* {
    for (const auto& [k, v] : defaults.members) {
      if (k == key) return &v;
    }
    return nullptr;
  };
  std::erase_if(tree->members, [&](auto& member) {
    const OptionValue* d = default_of(member.first);
    if (d == nullptr) return false;
    if (member.second.since_version > format_version) return member.second == *d;
    OmitNewerDefaults(&member.second, *d, format_version);
    return false;
  });
}

}  // namespace options_internal
}  // namespace omnicml
