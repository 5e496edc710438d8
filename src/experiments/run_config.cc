#include "omnicml/experiments/run_config.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <set>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/report/report.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {

// YAML loading and dumping of options structs through one field list per struct, so
// load and dump can never disagree:
//   template <class V> void VisitFields(V& v, SomeOptions& o) {
//     v("gamma", o.gamma);                                        // scalar / vector
//     v.Enum("kind", o.kind, codec);                              // enum by name
//     v.Section("motion", [&](auto& sub) { VisitFields(sub, o.motion); });
//   }
// YamlLoader reads the keys present in a YAML map (absent keys keep their value) and
// throws omnicml::Error "file:line: unknown key 'a.b'" for a key no field claimed;
// YamlDumper emits every field. Doubles are written in the shortest form that reads back
// to the same bits, so dump -> load is exact.
namespace {

// Shortest round-trip text of a double; "nan"/"inf" spelled as YAML understands them.
inline std::string RoundTripDouble(double v) {
  if (std::isnan(v)) return ".nan";
  if (std::isinf(v)) return v > 0 ? ".inf" : "-.inf";
  char buf[64];
  auto res = std::to_chars(buf, buf + sizeof buf, v);
  std::string s(buf, res.ptr);
  // Keep it a float in YAML's eyes ("1" would still parse as double; fine either way).
  return s;
}

// Converters for enum-like fields: to and from their YAML names.
template <class E>
struct EnumCodec {
  std::function<std::string(E)> to_string;
  std::function<E(const std::string&)> from_string;
};

class YamlLoader {
 public:
  YamlLoader(const YAML::Node& node, std::string file, std::string prefix)
      : node_(node), file_(std::move(file)), prefix_(std::move(prefix)) {
    if (node_ && !node_.IsNull() && !node_.IsMap()) {
      throw Error(Where(node_) +
                  (prefix_.empty() ? std::string("the configuration") : "'" + prefix_ + "'") +
                  " must be a map of keys");
    }
  }

  std::string Where(const YAML::Node& n) const {
    const YAML::Mark mark = n.Mark();
    if (mark.line < 0) return file_ + ": ";
    return StrCat(file_, ":", mark.line + 1, ": ");
  }
  std::string Key(const char* key) const { return prefix_.empty() ? key : prefix_ + "." + key; }

  template <class T>
  void operator()(const char* key, T& field) {
    const YAML::Node n = Take(key);
    if (!n) return;
    Read(n, key, field);
  }

  template <class E>
  void Enum(const char* key, E& field, const EnumCodec<E>& codec) {
    const YAML::Node n = Take(key);
    if (!n) return;
    std::string s;
    Read(n, key, s);
    try {
      field = codec.from_string(s);
    } catch (const Error& e) {
      throw Error(Where(n) + "'" + Key(key) + "': " + e.what());
    }
  }

  // A custom reader for fields of unusual shape.
  void Custom(const char* key,
              const std::function<void(const YAML::Node&, const std::string& where)>& read) {
    const YAML::Node n = Take(key);
    if (!n) return;
    read(n, Where(n) + "'" + Key(key) + "'");
  }

  void Section(const char* key, const std::function<void(YamlLoader&)>& body) {
    const YAML::Node n = Take(key);
    if (!n) return;
    YamlLoader sub(n, file_, Key(key));
    body(sub);
    sub.Finish();
  }

  // Throws for the first key that no field claimed.
  void Finish() const {
    if (!node_ || !node_.IsMap()) return;
    for (auto it = node_.begin(); it != node_.end(); ++it) {
      const std::string k = it->first.as<std::string>();
      if (!claimed_.count(k)) {
        throw Error(Where(it->first) + "unknown key '" + Key(k.c_str()) + "'");
      }
    }
  }

 private:
  YAML::Node Take(const char* key) {
    if (!node_ || !node_.IsMap()) return YAML::Node(YAML::NodeType::Undefined);
    claimed_.insert(key);
    for (auto it = node_.begin(); it != node_.end(); ++it) {
      if (it->first.as<std::string>() == key) return it->second;
    }
    return YAML::Node(YAML::NodeType::Undefined);
  }

  template <class T>
  void Read(const YAML::Node& n, const char* key, T& field) {
    if constexpr (std::is_same_v<T, bool>) {
      try {
        field = n.as<bool>();
      } catch (const YAML::Exception&) {
        throw Error(Where(n) + "'" + Key(key) + "' must be true or false");
      }
    } else if constexpr (std::is_integral_v<T>) {
      const double v = ReadNumber(n, key);
      if (v != std::floor(v) || v < static_cast<double>(std::numeric_limits<T>::lowest()) ||
          v > static_cast<double>(std::numeric_limits<T>::max())) {
        throw Error(Where(n) + "'" + Key(key) + "' must be an integer in range");
      }
      field = static_cast<T>(v);
    } else if constexpr (std::is_floating_point_v<T>) {
      field = static_cast<T>(ReadNumber(n, key));
    } else if constexpr (std::is_same_v<T, std::string>) {
      if (!n.IsScalar()) throw Error(Where(n) + "'" + Key(key) + "' must be a scalar");
      field = n.Scalar();
    } else if constexpr (std::is_same_v<T, std::vector<double>>) {
      if (!n.IsSequence()) throw Error(Where(n) + "'" + Key(key) + "' must be a list of numbers");
      field.clear();
      for (const auto& e : n) field.push_back(ReadNumber(e, key));
    } else if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
      if (!n.IsSequence() || n.size() != 3) {
        throw Error(Where(n) + "'" + Key(key) + "' must be a list of 3 numbers");
      }
      for (int i = 0; i < 3; ++i) field[i] = ReadNumber(n[static_cast<std::size_t>(i)], key);
    } else if constexpr (std::is_same_v<T, Eigen::Matrix3d>) {
      if (!n.IsSequence() || n.size() != 3) {
        throw Error(Where(n) + "'" + Key(key) + "' must be 3 rows of 3 numbers");
      }
      for (std::size_t r = 0; r < 3; ++r) {
        const YAML::Node row = n[r];
        if (!row.IsSequence() || row.size() != 3) {
          throw Error(Where(row) + "'" + Key(key) + "' must be 3 rows of 3 numbers");
        }
        for (std::size_t c = 0; c < 3; ++c) {
          field(static_cast<int>(r), static_cast<int>(c)) = ReadNumber(row[c], key);
        }
      }
    } else {
      static_assert(sizeof(T) == 0, "unsupported option field type");
    }
  }

  double ReadNumber(const YAML::Node& n, const char* key) const {
    if (!n.IsScalar()) throw Error(Where(n) + "'" + Key(key) + "' must be a number");
    const std::string& s = n.Scalar();
    if (s == ".nan" || s == ".NaN" || s == ".NAN") return std::nan("");
    if (s == ".inf" || s == "+.inf" || s == ".Inf") return std::numeric_limits<double>::infinity();
    if (s == "-.inf" || s == "-.Inf") return -std::numeric_limits<double>::infinity();
    double v = 0;
    const char* begin = s.data();
    const char* end = s.data() + s.size();
    if (begin != end && *begin == '+') ++begin;
    auto res = std::from_chars(begin, end, v);
    if (res.ec != std::errc() || res.ptr != end) {
      throw Error(Where(n) + "'" + Key(key) + "': '" + s + "' is not a number");
    }
    return v;
  }

  YAML::Node node_;
  std::string file_;
  std::string prefix_;
  std::set<std::string> claimed_;
};

class YamlDumper {
 public:
  explicit YamlDumper(YAML::Emitter& out) : out_(out) {}

  template <class T>
  void operator()(const char* key, T& field) {
    out_ << YAML::Key << key << YAML::Value;
    Write(field);
  }

  template <class E>
  void Enum(const char* key, E& field, const EnumCodec<E>& codec) {
    out_ << YAML::Key << key << YAML::Value << codec.to_string(field);
  }

  void Custom(const char* key, const std::function<void(YAML::Emitter&)>& write) {
    out_ << YAML::Key << key << YAML::Value;
    write(out_);
  }

  void Section(const char* key, const std::function<void(YamlDumper&)>& body) {
    out_ << YAML::Key << key << YAML::Value << YAML::BeginMap;
    body(*this);
    out_ << YAML::EndMap;
  }

 private:
  template <class T>
  void Write(const T& field) {
    if constexpr (std::is_same_v<T, bool>) {
      out_ << (field ? "true" : "false");
    } else if constexpr (std::is_integral_v<T>) {
      out_ << std::to_string(field);
    } else if constexpr (std::is_floating_point_v<T>) {
      out_ << RoundTripDouble(static_cast<double>(field));
    } else if constexpr (std::is_same_v<T, std::string>) {
      out_ << YAML::DoubleQuoted << field;
    } else if constexpr (std::is_same_v<T, std::vector<double>>) {
      out_ << YAML::Flow << YAML::BeginSeq;
      for (double v : field) out_ << RoundTripDouble(v);
      out_ << YAML::EndSeq;
    } else if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
      out_ << YAML::Flow << YAML::BeginSeq;
      for (int i = 0; i < 3; ++i) out_ << RoundTripDouble(field[i]);
      out_ << YAML::EndSeq;
    } else if constexpr (std::is_same_v<T, Eigen::Matrix3d>) {
      out_ << YAML::Flow << YAML::BeginSeq;
      for (int r = 0; r < 3; ++r) {
        out_ << YAML::Flow << YAML::BeginSeq;
        for (int c = 0; c < 3; ++c) out_ << RoundTripDouble(field(r, c));
        out_ << YAML::EndSeq;
      }
      out_ << YAML::EndSeq;
    } else {
      static_assert(sizeof(T) == 0, "unsupported option field type");
    }
  }

  YAML::Emitter& out_;
};

}  // namespace

namespace {

template <class V>
void VisitFields(V& v, MotionNoise& o) {
  v("a1", o.a1);
  v("a2", o.a2);
  v("a3", o.a3);
  v("a4", o.a4);
}

template <class V>
void VisitFields(V& v, TrackerOptions& o) {
  v("gamma", o.gamma);
  v("w_min", o.w_min);
  v("delta", o.delta);
  v("max_components", o.max_components);
  v("unimodal_min_weight", o.unimodal_min_weight);
  v("min_covariance_eigenvalue", o.min_covariance_eigenvalue);
  v.Section("motion", [&](auto& sub) { VisitFields(sub, o.motion); });
}

template <class V>
void VisitFields(V& v, EnvironmentModelOptions& o) {
  v("e_max", o.e_max);
  v("top_k", o.top_k);
  v("beta", o.beta);
  v("d_max", o.d_max);
  v("d_for_m", o.d_for_m);
  v("beta_for", o.beta_for);
  v("d_gain_m", o.d_gain_m);
  v("w_min", o.w_min);
  v("merge_delta", o.merge_delta);
  v("heading_sigma_no_rotation_rad", o.heading_sigma_no_rotation_rad);
  v.Enum("forgetting", o.forgetting,
         EnumCodec<ForgettingMode>{[](ForgettingMode m) { return ToString(m); },
                                   ForgettingModeFromString});
  v("spatial_cell_m", o.spatial_cell_m);
  v("log_component_events", o.log_component_events);
}

template <class V>
void VisitFields(V& v, FourierOptions& o) {
  v("bands", o.bands);
  v("coefficients", o.coefficients);
  v.Enum("distance", o.distance,
         EnumCodec<FourierDistance>{[](FourierDistance d) { return ToString(d); },
                                    FourierDistanceFromString});
  v("normalize_bands", o.normalize_bands);
  v("normalize_columns", o.normalize_columns);
}

// IfhOptions::kernels: a list of kernels, each a list of [x, y] pixel offsets.
void ReadKernels(const YAML::Node& n, const std::string& where, std::vector<IfhKernel>* kernels) {
  if (!n.IsSequence())
    throw Error(where + " must be a list of kernels, each a list of [x, y] offsets");
  std::vector<IfhKernel> out;
  for (const auto& kernel : n) {
    if (!kernel.IsSequence()) throw Error(where + ": a kernel must be a list of [x, y] offsets");
    IfhKernel k;
    for (const auto& offset : kernel) {
      if (!offset.IsSequence() || offset.size() != 2) {
        throw Error(where + ": an offset must be [x, y]");
      }
      try {
        k.offsets.emplace_back(offset[0].as<double>(), offset[1].as<double>());
      } catch (const YAML::Exception&) {
        throw Error(where + ": an offset must be two numbers");
      }
    }
    out.push_back(std::move(k));
  }
  *kernels = std::move(out);
}

void WriteKernels(YAML::Emitter& out, const std::vector<IfhKernel>& kernels) {
  out << YAML::Flow << YAML::BeginSeq;
  for (const auto& k : kernels) {
    out << YAML::Flow << YAML::BeginSeq;
    for (const auto& p : k.offsets) {
      out << YAML::Flow << YAML::BeginSeq << RoundTripDouble(p.x) << RoundTripDouble(p.y)
          << YAML::EndSeq;
    }
    out << YAML::EndSeq;
  }
  out << YAML::EndSeq;
}

template <class V>
void VisitFields(V& v, IfhOptions& o) {
  if constexpr (std::is_same_v<V, YamlLoader>) {
    v.Custom("kernels", [&](const YAML::Node& n, const std::string& where) {
      ReadKernels(n, where, &o.kernels);
    });
  } else {
    v.Custom("kernels", [&](YAML::Emitter& out) { WriteKernels(out, o.kernels); });
  }
  v("angles", o.angles);
  v("bins", o.bins);
  v("scales", o.scales);
  v("color", o.color);
  v("sample_fraction", o.sample_fraction);
  v("seed", o.seed);
}

template <class V>
void VisitFields(V& v, ColorHistogramOptions& o) {
  v("bins", o.bins);
  v("filter_width", o.filter_width);
  v("normalized_rgb", o.normalized_rgb);
  v.Enum("distance", o.distance,
         EnumCodec<HistogramDistance>{[](HistogramDistance d) { return ToString(d); },
                                      HistogramDistanceFromString});
}

template <class V>
void VisitFields(V& v, DescriptorOptions& o) {
  v.Enum("kind", o.kind,
         EnumCodec<DescriptorKind>{[](DescriptorKind k) { return ToString(k); },
                                   DescriptorKindFromString});
  v.Section("fourier", [&](auto& sub) { VisitFields(sub, o.fourier); });
  v.Section("ifh", [&](auto& sub) { VisitFields(sub, o.ifh); });
  v.Section("color", [&](auto& sub) { VisitFields(sub, o.color); });
}

template <class V>
void VisitFields(V& v, ReconstructionOptions& o) {
  // o.motion is not configurable: the engine uses tracker.motion.
  v("min_translation_variance_m2", o.min_translation_variance_m2);
  v("min_rotation_variance_rad2", o.min_rotation_variance_rad2);
  v("max_iterations", o.max_iterations);
  v("function_tolerance", o.function_tolerance);
  v("compute_covariances", o.compute_covariances);
}

template <class V>
void VisitFields(V& v, CmlEngineOptions& o) {
  v("update_delay_frames", o.update_delay_frames);
  v("threads", o.threads);
  v("reconstruct_multimodal", o.reconstruct_multimodal);
  v("max_pending_multimodal_frames", o.max_pending_multimodal_frames);
  v("anchor_max_sigma_m", o.anchor_max_sigma_m);
  v("panorama_width", o.panorama_width);
  v("panorama_height", o.panorama_height);
  v("initial_pose", o.initial_pose);
  v("initial_covariance", o.initial_covariance);
  v("global_seed_min_similarity", o.global_seed_min_similarity);
  v("hypothesis_min_similarity", o.hypothesis_min_similarity);
  v("hypothesis_weight_by_similarity", o.hypothesis_weight_by_similarity);
  v("hypothesis_weight_scale", o.hypothesis_weight_scale);
  v("appearance_sigma_m", o.appearance_sigma_m);
  v("continue_odometry_across_sessions", o.continue_odometry_across_sessions);
  v.Section("descriptor", [&](auto& sub) { VisitFields(sub, o.descriptor); });
  v.Section("tracker", [&](auto& sub) { VisitFields(sub, o.tracker); });
  v.Section("model", [&](auto& sub) { VisitFields(sub, o.model); });
  v.Section("reconstruction", [&](auto& sub) { VisitFields(sub, o.reconstruction); });
}

}  // namespace

CmlEngineOptions ParseEngineOptionsYaml(const std::string& yaml_text, const std::string& source,
                                        const CmlEngineOptions& base) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& e) {
    throw Error(StrCat(source, ":", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  }
  CmlEngineOptions options = base;
  YamlLoader loader(root, source, "");
  VisitFields(loader, options);
  loader.Finish();
  try {
    options.Validate();
  } catch (const Error& e) {
    throw Error(StrCat(source, ": invalid configuration: ", e.what()));
  }
  return options;
}

CmlEngineOptions ParseEngineOptionsYaml(const std::string& yaml_text, const std::string& source) {
  const CmlEngineOptions defaults;
  return ParseEngineOptionsYaml(yaml_text, source, defaults);
}

CmlEngineOptions LoadEngineOptionsYaml(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) {
    throw Error(StrCat("configuration file '", path, "' does not exist"));
  }
  return ParseEngineOptionsYaml(ReadTextFile(path), path);
}

std::string EngineOptionsToYaml(const CmlEngineOptions& options) {
  CmlEngineOptions copy = options;
  YAML::Emitter out;
  out << YAML::BeginMap;
  YamlDumper dumper(out);
  VisitFields(dumper, copy);
  out << YAML::EndMap;
  if (!out.good()) throw InternalError(StrCat("YAML emitter: ", out.GetLastError()));
  return std::string(out.c_str()) + "\n";
}

bool SameEngineOptions(const CmlEngineOptions& a, const CmlEngineOptions& b) {
  return EngineOptionsToYaml(a) == EngineOptionsToYaml(b);
}

CmlEngineOptions ResolveEngineOptions(const OptionOverrides& overrides) {
  CmlEngineOptions options = overrides.config_path.empty()
                                 ? CmlEngineOptions{}
                                 : LoadEngineOptionsYaml(overrides.config_path);
  if (overrides.descriptor) {
    options.descriptor.kind = DescriptorKindFromString(*overrides.descriptor);
  }
  if (overrides.forgetting)
    options.model.forgetting = ForgettingModeFromString(*overrides.forgetting);
  if (overrides.e_max) options.model.e_max = *overrides.e_max;
  if (overrides.update_delay_frames) options.update_delay_frames = *overrides.update_delay_frames;
  if (overrides.threads) options.threads = *overrides.threads;
  try {
    options.Validate();
  } catch (const Error& e) {
    throw Error(StrCat("invalid options: ", e.what()));
  }
  return options;
}

}  // namespace omnicml

namespace omnicml {

void RunInput::Validate() const {
  if (log_dirs.empty() && world.empty()) {
    throw Error("no input: give LOGDIR... or --world NAME");
  }
  if (!log_dirs.empty() && !world.empty()) {
    throw Error("give either LOGDIR... or --world NAME, not both");
  }
  for (const std::string& dir : log_dirs) {
    if (!std::filesystem::is_directory(dir))
      throw Error(StrCat("log directory '", dir, "' does not exist"));
  }
  if (days < 1) throw Error(StrCat("--days must be >= 1 (got ", days, ")"));
  if (first_day < 0) throw Error(StrCat("--first-day must be >= 0 (got ", first_day, ")"));
  if (frames_per_day < 0)
    throw Error(StrCat("--frames-per-day must be >= 0 (got ", frames_per_day, ")"));
  if (!log_dirs.empty() && (first_day != 0)) throw Error("--first-day applies to --world only");
}

std::string RunInput::Describe() const {
  if (!log_dirs.empty()) {
    std::string s = log_dirs.size() == 1 ? "log " : "logs ";
    for (std::size_t i = 0; i < log_dirs.size(); ++i) s += (i ? ", " : "") + log_dirs[i];
    return s;
  }
  const int fpd = frames_per_day > 0 ? frames_per_day : SimulatorOptions{}.frames_per_day;
  return StrCat("world ", world, ", days ", first_day + 1, "-", first_day + days, ", ", fpd,
                " frames/day, seed ", seed);
}

namespace {

// The sessions >= first_day of a simulator, renumbered from 0 (resuming a simulated
// multi-day run from a saved map). Skipped days are still simulated, so the later days
// are exactly those of one run over all days.
class SkipDaysSource : public FrameSource {
 public:
  SkipDaysSource(std::unique_ptr<FrameSource> inner, int first_day)
      : inner_(std::move(inner)), first_day_(first_day) {}
  int NumSessions() const override { return inner_->NumSessions() - first_day_; }
  const SessionInfo& Session(int index) const override {
    return inner_->Session(index + first_day_);
  }
  bool Next(Frame* frame) override {
    while (inner_->Next(frame)) {
      if (frame->session_index < first_day_) continue;
      frame->session_index -= first_day_;
      frame->global_index = delivered_++;
      return true;
    }
    return false;
  }

 private:
  std::unique_ptr<FrameSource> inner_;
  int first_day_;
  std::int64_t delivered_ = 0;
};

}  // namespace

std::unique_ptr<FrameSource> OpenFrameSource(const RunInput& input) {
  input.Validate();
  if (!input.log_dirs.empty()) {
    LogReaderOptions options;
    options.skip_unreadable_frames = input.skip_unreadable_frames;
    return std::make_unique<LogReader>(input.log_dirs, options);
  }
  const std::vector<std::string> names = BuiltinWorldNames();
  const bool builtin = std::find(names.begin(), names.end(), input.world) != names.end();
  if (!builtin && !std::filesystem::is_regular_file(input.world)) {
    std::string list;
    for (std::size_t i = 0; i < names.size(); ++i) list += (i ? ", " : "") + names[i];
    throw Error(
        StrCat("unknown world '", input.world, "' (built-in: ", list, "; or a world YAML file)"));
  }
  SimulatorOptions options;
  options.world = input.world;
  options.days = input.first_day + input.days;
  if (input.frames_per_day > 0) options.frames_per_day = input.frames_per_day;
  options.seed = input.seed;
  auto source = std::make_unique<SimulatedFrameSource>(options);
  if (input.first_day == 0) return source;
  return std::make_unique<SkipDaysSource>(std::move(source), input.first_day);
}

std::optional<std::int64_t> CountFrames(const RunInput& input, const FrameSource& source) {
  if (input.log_dirs.empty()) {
    const int fpd =
        input.frames_per_day > 0 ? input.frames_per_day : SimulatorOptions{}.frames_per_day;
    return static_cast<std::int64_t>(fpd) * input.days;
  }
  const auto* reader = dynamic_cast<const LogReader*>(&source);
  if (reader == nullptr) return std::nullopt;
  std::int64_t total = 0;
  for (int s = 0; s < reader->NumSessions(); ++s) {
    std::ifstream in(std::filesystem::path(reader->SessionDirectory(s)) / "frames.csv");
    if (!in) return std::nullopt;
    std::string line;
    std::getline(in, line);  // header
    while (std::getline(in, line)) {
      if (!line.empty() && line != "\r") ++total;
    }
  }
  return total;
}

}  // namespace omnicml
