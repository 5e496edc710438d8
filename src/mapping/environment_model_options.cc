#include "omnicml/mapping/environment_model_options.h"

#include <cmath>
#include <utility>
#include <vector>

namespace omnicml {
namespace {

// The (former key, new path) pairs of VisitFields' Renamed list, in its order.
class RenameCollector {
 public:
  template <class T>
  void operator()(const char* /*key*/, T& /*field*/) {}
  template <class E>
  void Enum(const char* /*key*/, E& /*field*/, std::initializer_list<E> /*values*/) {}
  template <class S>
  void Section(const char* /*key*/, S& /*sub*/) {}
  template <class T>
  void Renamed(const char* old_key, const char* new_path, T& /*field*/) {
    pairs.emplace_back(old_key, new_path);
  }
  template <class E>
  void RenamedEnum(const char* old_key, const char* new_path, E& /*field*/,
                   std::initializer_list<E> /*values*/) {
    pairs.emplace_back(old_key, new_path);
  }
  std::vector<std::pair<std::string, std::string>> pairs;
};

struct Rename {
  std::string old_key, section, key;
};

std::vector<Rename> Renames() {
  EnvironmentModelOptions o;
  RenameCollector c;
  VisitFields(c, o);
  std::vector<Rename> out;
  for (const auto& [old_key, path] : c.pairs) {
    const std::size_t dot = path.find('.');
    out.push_back(Rename{old_key, path.substr(0, dot), path.substr(dot + 1)});
  }
  return out;
}

OptionValue* FindMember(OptionValue& map, const std::string& key) {
  for (auto& [k, v] : map.members) {
    if (k == key) return &v;
  }
  return nullptr;
}

}  // namespace

std::string ToString(ForgettingMode mode) {
  switch (mode) {
    case ForgettingMode::kActive:
      return "active";
    case ForgettingMode::kPassive:
      return "passive";
    case ForgettingMode::kStatic:
      return "static";
  }
  return "unknown";
}

ForgettingMode ForgettingModeFromString(const std::string& name) {
  if (name == "active") return ForgettingMode::kActive;
  if (name == "passive") return ForgettingMode::kPassive;
  if (name == "static") return ForgettingMode::kStatic;
  throw Error(StrCat("unknown forgetting mode '", name, "' (expected active, passive or static)"));
}

void EnvironmentModelOptions::Validate() const {
  auto fail = [](const char* field, const std::string& rule, double value) {
    throw Error(StrCat("EnvironmentModelOptions.", field, " must be ", rule, ", got ", value));
  };
  auto finite_above = [&](const char* field, double v, bool or_equal) {
    if (!(std::isfinite(v) && (or_equal ? v >= 0 : v > 0))) {
      fail(field, or_equal ? "finite and >= 0" : "finite and > 0", v);
    }
  };
  const Retrieval& r = retrieval;
  finite_above("retrieval.e_max", r.e_max, false);
  if (r.top_k < 0) fail("retrieval.top_k", ">= 0", r.top_k);
  finite_above("retrieval.heading_sigma_no_rotation_rad", r.heading_sigma_no_rotation_rad, false);
  const Update& u = update;
  if (!(u.beta > 0 && u.beta <= 1)) fail("update.beta", "in (0, 1]", u.beta);
  finite_above("update.d_max", u.d_max, false);
  if (!(u.w_min >= 0 && u.w_min < 1)) fail("update.w_min", "in [0, 1)", u.w_min);
  finite_above("update.merge_delta", u.merge_delta, true);
  if (u.look_back_frames < 0) fail("update.look_back_frames", ">= 0", u.look_back_frames);
  if (u.merge_fusion != MergeFusion::kMomentMatching &&
      u.merge_fusion != MergeFusion::kCovarianceIntersection &&
      u.merge_fusion != MergeFusion::kConvexCombination) {
    fail("update.merge_fusion", "moment_matching, covariance_intersection or convex_combination",
         static_cast<int>(u.merge_fusion));
  }
  const Forgetting& f = forgetting;
  if (f.mode != ForgettingMode::kActive && f.mode != ForgettingMode::kPassive &&
      f.mode != ForgettingMode::kStatic) {
    fail("forgetting.mode", "active, passive or static", static_cast<int>(f.mode));
  }
  finite_above("forgetting.d_for_m", f.d_for_m, false);
  finite_above("forgetting.beta_for", f.beta_for, true);
  finite_above("forgetting.d_gain_m", f.d_gain_m, true);
  finite_above("forgetting.footprint_gate", f.footprint_gate, false);
  if (f.forget_min_missed_passes < 0) {
    fail("forgetting.forget_min_missed_passes", ">= 0", f.forget_min_missed_passes);
  }
  if (f.pass_gap_frames < 0) fail("forgetting.pass_gap_frames", ">= 0", f.pass_gap_frames);
  finite_above("forgetting.footprint_confidence", f.footprint_confidence, true);
  if (!(f.persistence_min_probability >= 0 && f.persistence_min_probability < 1)) {
    fail("forgetting.persistence_min_probability", "in [0, 1)", f.persistence_min_probability);
  }
  const Index& i = index;
  finite_above("index.spatial_cell_m", i.spatial_cell_m, false);
  if (i.index_min_views < 0) fail("index.index_min_views", ">= 0", i.index_min_views);
  if (!(i.index_max_bounded_fraction > 0 && i.index_max_bounded_fraction <= 1)) {
    fail("index.index_max_bounded_fraction", "in (0, 1]", i.index_max_bounded_fraction);
  }
  if (i.index_dims < 1) fail("index.index_dims", ">= 1", i.index_dims);
  if (i.ann_min_views < 0) fail("index.ann_min_views", ">= 0", i.ann_min_views);
  if (i.ann_m < 2 || i.ann_m > 64) fail("index.ann_m", "in [2, 64]", i.ann_m);
  if (i.ann_ef_construction < 1) fail("index.ann_ef_construction", ">= 1", i.ann_ef_construction);
  if (i.ann_ef < 1) fail("index.ann_ef", ">= 1", i.ann_ef);
  if (i.ann_k < 1) fail("index.ann_k", ">= 1", i.ann_k);
  if (events.max_events < 0) fail("events.max_events", ">= 0", events.max_events);
}

OptionValue FlatModelOptionsValue(const OptionValue& grouped) {
  OptionValue sections = grouped;
  OptionValue flat = OptionValue::Map();
  flat.line = grouped.line;
  for (const Rename& r : Renames()) {
    OptionValue* section = FindMember(sections, r.section);
    if (section == nullptr || section->kind != OptionValue::Kind::kMap) continue;
    for (auto it = section->members.begin(); it != section->members.end(); ++it) {
      if (it->first != r.key) continue;
      flat.members.emplace_back(r.old_key, std::move(it->second));
      section->members.erase(it);
      break;
    }
  }
  // What has no flat key (an empty section is dropped: it holds nothing to restore).
  for (auto& [key, value] : sections.members) {
    if (value.kind == OptionValue::Kind::kMap && value.members.empty()) continue;
    flat.members.emplace_back(key, std::move(value));
  }
  return flat;
}

OptionValue GroupedModelOptionsValue(const OptionValue& flat) {
  if (flat.kind != OptionValue::Kind::kMap) return flat;
  const std::vector<Rename> renames = Renames();
  OptionValue grouped = OptionValue::Map();
  grouped.line = flat.line;
  // Sections first, in VisitFields' order, then any other key as it came.
  for (const char* name : {"retrieval", "update", "forgetting", "index", "events"}) {
    OptionValue section = OptionValue::Map();
    section.line = flat.line;
    grouped.members.emplace_back(name, std::move(section));
  }
  for (const auto& [key, value] : flat.members) {
    const bool is_section = value.kind == OptionValue::Kind::kMap;
    const Rename* rename = nullptr;
    for (const Rename& r : renames) {
      if (r.old_key == key && !is_section) rename = &r;
    }
    if (rename != nullptr) {
      FindMember(grouped, rename->section)->members.emplace_back(rename->key, value);
    } else if (OptionValue* section = is_section ? FindMember(grouped, key) : nullptr) {
      for (const auto& member : value.members) section->members.push_back(member);
    } else {
      grouped.members.emplace_back(key, value);
    }
  }
  return grouped;
}

}  // namespace omnicml
