// One description per options struct, driving YAML load and dump, binary encoding,
// equality, validation and randomised tests.
//
// Each options struct is described once, next to its declaration, by a field visitor:
//
//   template <class V>
//   void VisitFields(V& v, TrackerOptions& o) {
//     v("gamma", o.gamma);                                // scalar, vector, array, Eigen
//     v.Enum("forgetting", o.forgetting, {ForgettingMode::kActive, ...});  // by ToString(E)
//     v.NamedEnum("output", o.output, {{ImageKind::kRawRing, "raw_ring"}, ...});
//     v.Section("motion", o.motion);                      // nested struct (its VisitFields)
//     v.Renamed("e_max", "retrieval.e_max", o.retrieval.e_max);  // former key: read, not written
//     v.template Converted<Rep>("kernels", o.kernels, to_rep, from_rep);  // other shapes
//     v.Since(15, [&](auto& w) { w("gate_confidence", o.gate_confidence); });  // newer fields
//   }
//
// The field name is the YAML key and the member name. Supported field types: bool,
// integers, float/double, std::string, std::vector<T>, std::array<T, N> of supported T,
// fixed-size Eigen matrices (a vector is a flat list, a matrix a list of rows). Enums are
// written as their ToString name (found by argument-dependent lookup) and read back by
// comparing with the names of the listed values.
//
// The visitor turns a struct into an OptionValue tree and back; options.cc turns trees
// into YAML text and back and into bytes and back. Doubles are written in their shortest
// round-trip text, so every path (YAML, binary) restores doubles bit for bit (NaN payloads
// aside).
//
// Errors are omnicml::Error "<source>:<line>: ..." naming the key with its section path
// ("tracker.motion.a1"): YAML syntax, duplicate key, unknown key, wrong type or shape,
// out-of-range integer, unknown enum name, and (after a load) the struct's Validate().
// A key given under a former name (Renamed, RenamedEnum) is read into its field and
// reported by one warning line on stderr per section ("<source>:<line>: warning: ...");
// such keys are never written, and a binary (complete) read does not require them.
// A partial read (YAML) keeps the value of absent keys; a complete read (binary) requires
// every field, except fields added in a later format version than the file's.
//
// Format versions of binary files: fields visited inside `Since(version, visit)` were
// added in file format `version`. A complete read of a file of an earlier format version
// (OptionSource::format_version) fills them with their defaults when absent;
// OptionsToFileValue omits them when they equal their defaults, so a file of default
// options keeps the bytes it had before those fields existed. A field added without a
// format bump is declared Since(current format + 1): omitted when default, read when
// present. YAML reads and writes are not affected.
//
// Pure functions and value types; thread-safe.
#ifndef OMNICML_COMMON_OPTIONS_H_
#define OMNICML_COMMON_OPTIONS_H_

#include <array>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <random>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"

namespace omnicml {

// A configuration value: a scalar (text), a list or a map with keys in order.
struct OptionValue {
  enum class Kind : std::uint8_t { kScalar = 0, kList = 1, kMap = 2 };
  Kind kind = Kind::kMap;
  std::string scalar;              // kScalar: the text ("true", "12", "0.45", "home_store")
  bool quoted = false;             // kScalar of a string field: dumped double-quoted
  std::vector<OptionValue> items;  // kList
  std::vector<std::pair<std::string, OptionValue>> members;  // kMap
  int line = 0;  // 1-based line in the source text; 0 when unknown (binary, built)
  // The format version a field was added in (TreeWriter under Since); 0 for fields of
  // every version. Not encoded, not compared.
  std::uint32_t since_version = 0;

  // Declared here, defaulted in options.cc: clang with libstdc++ cannot instantiate the
  // implicit ones while OptionValue is still incomplete (std::pair of it in `members`).
  OptionValue();
  ~OptionValue();
  OptionValue(const OptionValue&);
  OptionValue(OptionValue&&) noexcept;
  OptionValue& operator=(const OptionValue&);
  OptionValue& operator=(OptionValue&&) noexcept;

  static OptionValue Scalar(std::string text, bool quoted = false);
  static OptionValue List();
  static OptionValue Map();
  // Structural equality (kind, text, items, members); ignores line and quoted.
  bool operator==(const OptionValue& other) const;
};

// Where a tree came from, for error messages, and how strictly to read it.
struct OptionSource {
  std::string name;       // file path or "<engine file>: options"
  bool complete = false;  // every field must be present (binary); else absent keys keep values
  // Top-level keys that are accepted and skipped (not options, e.g. the inputs an app
  // writes into the same file).
  std::vector<std::string> ignored_keys;
  // The file format version of a complete read: fields added in a later version (Since)
  // may be absent and keep their defaults. The largest value: this build's format.
  std::uint32_t format_version = std::numeric_limits<std::uint32_t>::max();
};

// YAML text -> tree. Throws omnicml::Error "<source>:<line>: ..." on a syntax error or a
// duplicate key. Empty text gives an empty map.
OptionValue ParseOptionYaml(const std::string& text, const std::string& source);
// Tree -> YAML (block maps, flow lists, strings double-quoted), ending in a newline.
std::string OptionYaml(const OptionValue& value);
// Tree <-> bytes: u8 kind; scalar: string + u8 quoted; list: u64 count + items; map: u64
// count + (key string, value). Decode throws omnicml::Error (BinaryReader) on damage.
void EncodeOptionValue(BinaryWriter& out, const OptionValue& value);
OptionValue DecodeOptionValue(BinaryReader& in, const char* what);
// Reads a whole text file; throws omnicml::Error naming the path.
std::string ReadOptionFile(const std::string& path);

namespace options_internal {

template <class T>
concept EigenFixed = requires {
  T::RowsAtCompileTime;
  T::ColsAtCompileTime;
}
&&(T::RowsAtCompileTime > 0) && (T::ColsAtCompileTime > 0);

template <class T>
struct IsVector : std::false_type {};
template <class T, class A>
struct IsVector<std::vector<T, A>> : std::true_type {};
template <class T>
struct IsArray : std::false_type {};
template <class T, std::size_t N>
struct IsArray<std::array<T, N>> : std::true_type {};

std::string FormatDouble(double v);
[[noreturn]] void Fail(const OptionSource& src, const OptionValue* at, const std::string& path,
                       const std::string& what);
bool ParseBool(const OptionValue& v, const OptionSource& src, const std::string& path);
double ParseDouble(const OptionValue& v, const OptionSource& src, const std::string& path);
std::int64_t ParseInt(const OptionValue& v, const OptionSource& src, const std::string& path,
                      std::int64_t lo, std::int64_t hi);
std::uint64_t ParseUInt(const OptionValue& v, const OptionSource& src, const std::string& path,
                        std::uint64_t hi);
std::string ParseString(const OptionValue& v, const OptionSource& src, const std::string& path);
// Throws unless v is a list (of n items when n > 0).
void ExpectList(const OptionValue& v, const OptionSource& src, const std::string& path,
                std::size_t n, const char* shape);
std::string JoinPath(const std::string& prefix, const char* key);

template <class T>
OptionValue ToValue(const T& field) {
  if constexpr (std::is_same_v<T, bool>) {
    return OptionValue::Scalar(field ? "true" : "false");
  } else if constexpr (std::is_integral_v<T>) {
    return OptionValue::Scalar(std::to_string(field));
  } else if constexpr (std::is_floating_point_v<T>) {
    return OptionValue::Scalar(FormatDouble(static_cast<double>(field)));
  } else if constexpr (std::is_same_v<T, std::string>) {
    return OptionValue::Scalar(field, /*quoted=*/true);
  } else if constexpr (IsVector<T>::value || IsArray<T>::value) {
    OptionValue list = OptionValue::List();
    for (const auto& e : field) list.items.push_back(ToValue(e));
    return list;
  } else if constexpr (EigenFixed<T>) {
    OptionValue list = OptionValue::List();
    for (int r = 0; r < T::RowsAtCompileTime; ++r) {
      if constexpr (T::ColsAtCompileTime == 1) {
        list.items.push_back(ToValue(static_cast<double>(field(r, 0))));
      } else {
        OptionValue row = OptionValue::List();
        for (int c = 0; c < T::ColsAtCompileTime; ++c) {
          row.items.push_back(ToValue(static_cast<double>(field(r, c))));
        }
        list.items.push_back(std::move(row));
      }
    }
    return list;
  } else {
    static_assert(sizeof(T) == 0, "unsupported option field type");
  }
}

template <class T>
void FromValue(const OptionValue& v, const OptionSource& src, const std::string& path, T& field) {
  if constexpr (std::is_same_v<T, bool>) {
    field = ParseBool(v, src, path);
  } else if constexpr (std::is_integral_v<T> && std::is_signed_v<T>) {
    field = static_cast<T>(
        ParseInt(v, src, path, std::numeric_limits<T>::lowest(), std::numeric_limits<T>::max()));
  } else if constexpr (std::is_integral_v<T>) {
    field = static_cast<T>(ParseUInt(v, src, path, std::numeric_limits<T>::max()));
  } else if constexpr (std::is_floating_point_v<T>) {
    field = static_cast<T>(ParseDouble(v, src, path));
  } else if constexpr (std::is_same_v<T, std::string>) {
    field = ParseString(v, src, path);
  } else if constexpr (IsVector<T>::value) {
    ExpectList(v, src, path, 0, "a list");
    T out(v.items.size());
    for (std::size_t i = 0; i < v.items.size(); ++i) FromValue(v.items[i], src, path, out[i]);
    field = std::move(out);
  } else if constexpr (IsArray<T>::value) {
    ExpectList(v, src, path, field.size(), "a list");
    for (std::size_t i = 0; i < field.size(); ++i) FromValue(v.items[i], src, path, field[i]);
  } else if constexpr (EigenFixed<T>) {
    constexpr int kRows = T::RowsAtCompileTime;
    constexpr int kCols = T::ColsAtCompileTime;
    ExpectList(v, src, path, kRows, kCols == 1 ? "a list of numbers" : "a list of rows");
    for (int r = 0; r < kRows; ++r) {
      const OptionValue& row = v.items[static_cast<std::size_t>(r)];
      if constexpr (kCols == 1) {
        field(r, 0) = ParseDouble(row, src, path);
      } else {
        ExpectList(row, src, path, kCols, "a row of numbers");
        for (int c = 0; c < kCols; ++c) {
          field(r, c) = ParseDouble(row.items[static_cast<std::size_t>(c)], src, path);
        }
      }
    }
  } else {
    static_assert(sizeof(T) == 0, "unsupported option field type");
  }
}

// Struct -> tree.
class TreeWriter {
 public:
  explicit TreeWriter(OptionValue* map) : map_(map) {}
  template <class T>
  void operator()(const char* key, T& field) {
    Add(key, ToValue(field));
  }
  template <class E>
  void Enum(const char* key, E& field, std::initializer_list<E> /*values*/) {
    Add(key, OptionValue::Scalar(ToString(field)));
  }
  template <class E>
  void NamedEnum(const char* key, E& field,
                 std::initializer_list<std::pair<E, const char*>> names) {
    for (const auto& [e, name] : names) {
      if (e == field) {
        Add(key, OptionValue::Scalar(name));
        return;
      }
    }
    throw InternalError(StrCat("options: '", key, "' has a value without a name"));
  }
  template <class Rep, class T, class To, class From>
  void Converted(const char* key, T& field, To to_rep, From /*from_rep*/) {
    Add(key, ToValue(static_cast<Rep>(to_rep(field))));
  }
  template <class S>
  void Section(const char* key, S& sub) {
    OptionValue m = OptionValue::Map();
    TreeWriter w(&m);
    VisitFields(w, sub);
    Add(key, std::move(m));
  }
  template <class T>
  void Renamed(const char* /*old_key*/, const char* /*new_path*/, T& /*field*/) {}
  template <class E>
  void RenamedEnum(const char* /*old_key*/, const char* /*new_path*/, E& /*field*/,
                   std::initializer_list<E> /*values*/) {}
  // The fields `visit(*this)` writes are marked as added in format `version`.
  template <class F>
  void Since(std::uint32_t version, F&& visit) {
    const std::size_t first = map_->members.size();
    visit(*this);
    for (std::size_t i = first; i < map_->members.size(); ++i) {
      map_->members[i].second.since_version = version;
    }
  }

 private:
  void Add(const char* key, OptionValue v) { map_->members.emplace_back(key, std::move(v)); }
  OptionValue* map_;
};

// Tree -> struct.
class TreeReader {
 public:
  TreeReader(const OptionValue& map, const OptionSource& src, std::string prefix);

  template <class T>
  void operator()(const char* key, T& field) {
    if (const OptionValue* n = Take(key)) FromValue(*n, src_, JoinPath(prefix_, key), field);
  }
  template <class E>
  void Enum(const char* key, E& field, std::initializer_list<E> values) {
    if (const OptionValue* n = Take(key)) EnumValue(n, JoinPath(prefix_, key), field, values);
  }
  // Sets field to the value of `values` named by *n; throws naming `path` otherwise.
  template <class E>
  void EnumValue(const OptionValue* n, const std::string& path, E& field,
                 std::initializer_list<E> values) {
    const std::string name = ParseString(*n, src_, path);
    std::string names;
    for (E e : values) {
      if (ToString(e) == name) {
        field = e;
        return;
      }
      names += (names.empty() ? "" : ", ") + ToString(e);
    }
    Fail(src_, n, path, "unknown value '" + name + "' (one of: " + names + ")");
  }
  template <class E>
  void NamedEnum(const char* key, E& field,
                 std::initializer_list<std::pair<E, const char*>> names) {
    const OptionValue* n = Take(key);
    if (n == nullptr) return;
    const std::string path = JoinPath(prefix_, key);
    const std::string name = ParseString(*n, src_, path);
    std::string list;
    for (const auto& [e, text] : names) {
      if (name == text) {
        field = e;
        return;
      }
      list += (list.empty() ? "" : ", ") + std::string(text);
    }
    Fail(src_, n, path, "unknown value '" + name + "' (one of: " + list + ")");
  }
  template <class Rep, class T, class To, class From>
  void Converted(const char* key, T& field, To to_rep, From from_rep) {
    const OptionValue* n = Take(key);
    if (n == nullptr) return;
    const std::string path = JoinPath(prefix_, key);
    Rep rep = to_rep(field);
    FromValue(*n, src_, path, rep);
    try {
      field = from_rep(rep);
    } catch (const Error& e) {
      Fail(src_, n, path, e.what());
    }
  }
  template <class S>
  void Section(const char* key, S& sub) {
    const OptionValue* n = Take(key);
    if (n == nullptr) return;
    TreeReader r(*n, src_, JoinPath(prefix_, key));
    VisitFields(r, sub);
    r.Finish();
  }
  // A former key: read into `field` when present and not a map (a map under that key is
  // a section of the same name, read by Section), noted for the deprecation warning.
  template <class T>
  void Renamed(const char* old_key, const char* new_path, T& field) {
    if (const OptionValue* n = TakeRenamed(old_key, new_path)) {
      FromValue(*n, src_, JoinPath(prefix_, old_key), field);
    }
  }
  template <class E>
  void RenamedEnum(const char* old_key, const char* new_path, E& field,
                   std::initializer_list<E> values) {
    if (const OptionValue* n = TakeRenamed(old_key, new_path)) {
      EnumValue(n, JoinPath(prefix_, old_key), field, values);
    }
  }
  // Fields added in format `version`: not required by a complete read of an earlier
  // format (absent ones keep their values, the defaults).
  template <class F>
  void Since(std::uint32_t version, F&& visit) {
    const bool saved = optional_;
    if (src_.format_version < version) optional_ = true;
    visit(*this);
    optional_ = saved;
  }
  // Throws for the first key no field claimed (and, for a complete read, was missing);
  // prints the deprecation warning for keys read under a former name.
  void Finish() const;

 private:
  bool optional_ = false;  // inside a Since of a later format than the file's
  const OptionValue* Take(const char* key);
  // The scalar or list under a former key, claimed; nullptr when absent or a map.
  const OptionValue* TakeRenamed(const char* old_key, const char* new_path);
  // Former keys read, with their new paths (relative to this section).
  std::vector<std::pair<std::string, std::string>> renamed_;
  int renamed_line_ = 0;
  const OptionValue& map_;
  const OptionSource& src_;
  std::string prefix_;
  std::vector<std::string> claimed_;
  std::vector<std::string> missing_;
};

// Every field set to a different value (see RandomizeOptions).
class Randomizer {
 public:
  explicit Randomizer(std::mt19937& rng) : rng_(rng) {}
  template <class T>
  void operator()(const char* /*key*/, T& field) {
    Randomize(field, /*in_matrix=*/false);
  }
  template <class E>
  void Enum(const char* /*key*/, E& field, std::initializer_list<E> values) {
    std::vector<E> others;
    for (E e : values) {
      if (e != field) others.push_back(e);
    }
    if (!others.empty()) field = others[rng_() % others.size()];
  }
  template <class E>
  void NamedEnum(const char* key, E& field,
                 std::initializer_list<std::pair<E, const char*>> names) {
    std::vector<E> values;
    for (const auto& [e, unused] : names) values.push_back(e);
    std::vector<E> others;
    for (E e : values) {
      if (e != field) others.push_back(e);
    }
    if (!others.empty()) field = others[rng_() % others.size()];
    (void)key;
  }
  template <class Rep, class T, class To, class From>
  void Converted(const char* /*key*/, T& field, To to_rep, From from_rep) {
    Rep rep = to_rep(field);
    Randomize(rep, false);
    field = from_rep(rep);
  }
  template <class S>
  void Section(const char* /*key*/, S& sub) {
    VisitFields(*this, sub);
  }
  template <class T>
  void Renamed(const char* /*old_key*/, const char* /*new_path*/, T& /*field*/) {}
  template <class E>
  void RenamedEnum(const char* /*old_key*/, const char* /*new_path*/, E& /*field*/,
                   std::initializer_list<E> /*values*/) {}
  template <class F>
  void Since(std::uint32_t /*version*/, F&& visit) {
    visit(*this);
  }

 private:
  double Uniform(double lo, double hi) {
    return std::uniform_real_distribution<double>(lo, hi)(rng_);
  }
  template <class T>
  void Randomize(T& f, bool in_matrix) {
    if constexpr (std::is_same_v<T, bool>) {
      f = !f;
    } else if constexpr (std::is_integral_v<T>) {
      if (f >= 2) {
        f = static_cast<T>(f - 1 - static_cast<T>(rng_() % static_cast<unsigned>(f / 2)));
      } else {
        f = static_cast<T>(f + 1 + static_cast<T>(rng_() % 3));
      }
    } else if constexpr (std::is_floating_point_v<T>) {
      if (f != 0) {
        f = static_cast<T>(f * Uniform(0.5, 0.95));
      } else if (!in_matrix) {
        f = static_cast<T>(Uniform(0.01, 0.1));
      }
    } else if constexpr (std::is_same_v<T, std::string>) {
      f += "_" + std::to_string(rng_() % 1000);
    } else if constexpr (IsVector<T>::value) {
      if (f.empty()) f.emplace_back();  // an empty list gets one element, changed below
      for (auto& e : f) Randomize(e, in_matrix);
    } else if constexpr (IsArray<T>::value) {
      for (auto& e : f) Randomize(e, in_matrix);
    } else if constexpr (EigenFixed<T>) {
      // Matrices keep their zeros (a covariance stays SPD); vectors get all entries.
      for (int r = 0; r < T::RowsAtCompileTime; ++r) {
        for (int c = 0; c < T::ColsAtCompileTime; ++c) {
          double x = f(r, c);
          Randomize(x, T::ColsAtCompileTime > 1);
          f(r, c) = x;
        }
      }
    }
  }
  std::mt19937& rng_;
};

// Removes from *tree (recursively) the members added after `format_version` (since_version
// > format_version) that equal the same member of `defaults`.
void OmitNewerDefaults(OptionValue* tree, const OptionValue& defaults,
                       std::uint32_t format_version);

}  // namespace options_internal

// ---- the generic operations on any struct with a VisitFields -----------------------------

// Every field as a tree (a map).
template <class O>
OptionValue OptionsToValue(const O& options) {
  O copy = options;
  OptionValue map = OptionValue::Map();
  options_internal::TreeWriter w(&map);
  VisitFields(w, copy);
  return map;
}

// Every field as a tree for a binary file of `format_version`: fields added in a later
// version (Since) are left out when they equal their defaults (O{}).
template <class O>
OptionValue OptionsToFileValue(const O& options, std::uint32_t format_version) {
  OptionValue tree = OptionsToValue(options);
  options_internal::OmitNewerDefaults(&tree, OptionsToValue(O{}), format_version);
  return tree;
}

// Reads a tree (a map) into *options; see OptionSource. Does not validate.
template <class O>
void OptionsFromValue(const OptionValue& value, const OptionSource& source, O* options) {
  options_internal::TreeReader r(value, source, "");
  VisitFields(r, *options);
  r.Finish();
}

// Calls options.Validate() when the struct has one; its message is prefixed with `source`.
template <class O>
void ValidateOptions(const O& options, const std::string& source) {
  if constexpr (requires { options.Validate(); }) {
    try {
      options.Validate();
    } catch (const Error& e) {
      throw Error(source + ": invalid configuration: " + e.what());
    }
  }
}

// Every field as YAML; ParseOptionsYaml reads it back to equal options.
template <class O>
std::string OptionsToYaml(const O& options) {
  return OptionYaml(OptionsToValue(options));
}

// YAML text on top of `base` (absent keys keep base's values), validated.
template <class O>
O ParseOptionsYaml(const std::string& text, const std::string& source, const O& base = O{},
                   std::vector<std::string> ignored_keys = {}) {
  O options = base;
  OptionSource src{source, false, std::move(ignored_keys)};
  OptionsFromValue(ParseOptionYaml(text, source), src, &options);
  ValidateOptions(options, source);
  return options;
}

// The YAML file at `path` on top of the defaults, validated.
template <class O>
O LoadOptionsYaml(const std::string& path, std::vector<std::string> ignored_keys = {}) {
  return ParseOptionsYaml<O>(ReadOptionFile(path), path, O{}, std::move(ignored_keys));
}

// Binary: the tree of every field (EncodeOptionValue).
template <class O>
void EncodeOptions(BinaryWriter& out, const O& options) {
  EncodeOptionValue(out, OptionsToValue(options));
}
// Reads what EncodeOptions wrote; every field must be present and no other. Does not
// validate. Throws omnicml::Error naming `what` and the field.
template <class O>
O DecodeOptions(BinaryReader& in, const char* what) {
  O options;
  const OptionValue value = DecodeOptionValue(in, what);
  // Errors name the file and the section: "<map file>: options:<key> ...".
  OptionsFromValue(value, OptionSource{StrCat(in.source(), ": ", what), true, {}}, &options);
  return options;
}

// Field-by-field equality (doubles exact).
template <class O>
bool SameOptions(const O& a, const O& b) {
  return OptionsToValue(a) == OptionsToValue(b);
}

// For tests: every field changed from its current value, deterministically for a seeded
// generator: booleans flipped, integers >= 2 lowered (at least to half), smaller ones
// raised by 1-3, non-zero doubles scaled by U(0.5, 0.95), zero doubles set to U(0.01, 0.1)
// (zeros of matrices kept, so covariances stay SPD), strings suffixed, enums set to another
// listed value. Defaults usually stay valid; callers fix up fields with tighter rules.
template <class O>
void RandomizeOptions(O* options, std::mt19937& rng) {
  options_internal::Randomizer r(rng);
  VisitFields(r, *options);
}

}  // namespace omnicml

#endif  // OMNICML_COMMON_OPTIONS_H_
