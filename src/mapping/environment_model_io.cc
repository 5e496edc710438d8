// EnvironmentModel::Serialize and Deserialize: the model section of the engine file
// (docs/map_format.md). Little-endian (common/binary_io.h), doubles bit for bit.
//
//   u32 magic "OCEM", u32 version, u8 descriptor kind, u64 feature size,
//   u64 next view id, u64 next component id,
//   u64 n, n x View:      u64 id, Descriptor record, ViewStats, Footprint (version >= 2),
//                         u64 m, m x Component (version >= 5: with its spread)
//   u64 events logged, u64 s, s x (i32 session, 5 x i64 counts)        (version >= 3)
//   u64 e, e x Event
//   u64 r, r x RecentUpdate                                           (version >= 4)
//   16 x i64 passes, 16 x i64 matched, i64 passes at fit, 16 x f64 belief, f64 h, f64 P_M,
//   u64 k, k x u64 view id (open unmatched passes)      (view persistence, version >= 6)
#include <algorithm>
#include <array>
#include <cmath>
#include <deque>
#include <map>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>

#include "omnicml/geometry/pose_io.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml {
namespace {

constexpr std::uint32_t kModelMagic = 0x4D45434Fu;  // "OCEM" little-endian
// Version 2 adds each view's footprint (ViewFootprint); version 1 maps are still read,
// their footprints estimated from the components. Version 3 adds the number of events
// logged and the per-session event counts before the (bounded) event ring; earlier
// versions rebuild the counts from their complete log. Version 4 adds the look-back's
// recent updates after the events (none are read from earlier versions). Version 5 adds
// each component's spread (xx, xy, yy) after its covariance; earlier versions read it as
// zero. Version 6 adds the view persistence counts and belief at the end (empty counts
// and a belief of 1 from earlier versions).
constexpr std::uint32_t kModelVersion = EnvironmentModel::kFormatVersion;

// The smallest encoding of each record, from the sizes of its fields: ReadCount's guard,
// so a corrupted count fails before anything is allocated.
constexpr std::size_t kU8 = 1, kI32 = 4, kI64 = 8, kF64 = 8;
constexpr std::size_t kPoseBytes = 3 * kF64;
constexpr std::size_t kMatrix3Bytes = 9 * kF64;
// Descriptor record (descriptor.h): u8 kind, two u64 counts, i32 width.
constexpr std::size_t kMinDescriptorBytes = kU8 + 2 * kI64 + kI32;
constexpr std::size_t kViewStatsBytes = kI64 + kI32 + kI64 + kI64 + kI32;
constexpr std::size_t kMinViewBytes = kI64 + kMinDescriptorBytes + kViewStatsBytes + kI64;
constexpr std::size_t kComponentBytes = kI64 + 2 * kF64 + kPoseBytes + kMatrix3Bytes;
constexpr std::size_t kEventCountsBytes = kI32 + 5 * kI64;
constexpr std::size_t kMinEventBytes = kU8 + kI64 + kI32 + 2 * kI64 + kPoseBytes + kF64 + kI64;
constexpr std::size_t kMinRecentUpdateBytes =
    kMinDescriptorBytes + kPoseBytes + kMatrix3Bytes + kI64 + kI32;

using internal::ReadMatrix3;
using internal::ReadPose;
using internal::WriteMatrix3;
using internal::WritePose;

// ---- writing ------------------------------------------------------------------------

void WriteStats(BinaryWriter& out, const ViewStats& s) {
  out.Write(s.created_frame);
  out.Write<std::int32_t>(s.created_session);
  out.Write(s.observations);
  out.Write(s.last_seen_frame);
  out.Write<std::int32_t>(s.last_seen_session);
}

void WriteFootprint(BinaryWriter& out, const ViewFootprint& f) {
  out.Write(f.weight);
  out.Write(f.mean.x());
  out.Write(f.mean.y());
  out.Write(f.scatter(0, 0));
  out.Write(f.scatter(0, 1));
  out.Write(f.scatter(1, 1));
  out.Write<std::int32_t>(f.missed_passes);
  out.Write<std::int32_t>(f.matched_passes);
  out.Write(f.last_expected_frame);
  out.Write<std::int32_t>(f.last_expected_session);
  out.Write(f.pass_matched);
}

void WriteView(BinaryWriter& out, const ReferenceView& v) {
  out.Write(v.id);
  WriteDescriptorRecord(out, v.descriptor);
  WriteStats(out, v.stats);
  WriteFootprint(out, v.footprint);
  out.Write<std::uint64_t>(v.components.size());
  for (const ViewComponent& c : v.components) {
    out.Write(c.id);
    out.Write(c.weight);
    out.Write(c.eta);
    WritePose(out, c.mean);
    WriteMatrix3(out, c.covariance);
    out.Write(c.spread(0, 0));
    out.Write(c.spread(0, 1));
    out.Write(c.spread(1, 1));
  }
}

void WriteEvents(BinaryWriter& out, const MapEventLog& log) {
  out.Write<std::uint64_t>(log.events_logged());
  out.Write<std::uint64_t>(log.counts().size());
  for (const auto& [session, n] : log.counts()) {
    out.Write<std::int32_t>(session);
    for (std::int64_t c : {n.views_inserted, n.views_removed, n.components_added,
                           n.components_merged, n.components_removed}) {
      out.Write(c);
    }
  }
  out.Write<std::uint64_t>(log.events().size());
  for (const MapEvent& e : log.events()) {
    out.Write(e.type);
    out.Write(e.frame);
    out.Write<std::int32_t>(e.session);
    out.Write(e.view_id);
    out.Write(e.component_id);
    WritePose(out, e.position);
    out.Write(e.weight);
    out.WriteString(e.reason);
  }
}

// ---- reading ------------------------------------------------------------------------

// What a record must match: the extractor's descriptor kind and feature length.
struct Expected {
  DescriptorKind kind;
  std::size_t feature_size;
  bool Fits(const Descriptor& d) const {
    return d.kind == kind && d.features.size() == feature_size;
  }
};

ViewStats ReadStats(BinaryReader& in) {
  ViewStats s;
  s.created_frame = in.Read<std::int64_t>("view created frame");
  s.created_session = in.Read<std::int32_t>("view created session");
  s.observations = in.Read<std::int64_t>("view observations");
  s.last_seen_frame = in.Read<std::int64_t>("view last seen frame");
  s.last_seen_session = in.Read<std::int32_t>("view last seen session");
  return s;
}

ViewFootprint ReadFootprint(BinaryReader& in, std::uint64_t view_id) {
  ViewFootprint f;
  f.weight = in.Read<double>("view footprint weight");
  f.mean.x() = in.Read<double>("view footprint mean");
  f.mean.y() = in.Read<double>("view footprint mean");
  f.scatter(0, 0) = in.Read<double>("view footprint scatter");
  f.scatter(0, 1) = f.scatter(1, 0) = in.Read<double>("view footprint scatter");
  f.scatter(1, 1) = in.Read<double>("view footprint scatter");
  f.missed_passes = in.Read<std::int32_t>("view footprint missed passes");
  f.matched_passes = in.Read<std::int32_t>("view footprint matched passes");
  f.last_expected_frame = in.Read<std::int64_t>("view footprint last expected frame");
  f.last_expected_session = in.Read<std::int32_t>("view footprint last expected session");
  f.pass_matched = in.Read<bool>("view footprint pass matched");
  if (!(f.weight >= 0) || !f.mean.allFinite() || !f.scatter.allFinite() || f.scatter(0, 0) < 0 ||
      f.scatter(1, 1) < 0 || f.missed_passes < 0 || f.matched_passes < 0) {
    in.Fail("view footprint", StrCat("view ", view_id, " has an invalid footprint"));
  }
  return f;
}

ViewComponent ReadComponent(BinaryReader& in, std::uint32_t version, std::uint64_t view_id) {
  ViewComponent c;
  c.id = in.Read<std::uint64_t>("component id");
  c.weight = in.Read<double>("component weight");
  c.eta = in.Read<double>("component eta");
  c.mean = ReadPose(in, "component mean");
  c.covariance = ReadMatrix3(in, "component covariance");
  const bool spd = c.covariance.allFinite() && c.covariance == c.covariance.transpose() &&
                   Eigen::LLT<Eigen::Matrix3d>(c.covariance).info() == Eigen::Success;
  if (!(c.weight >= 0 && c.weight <= 1) || !(c.eta > 0) || !c.mean.allFinite() || !spd ||
      std::abs(c.mean.z()) > kPi) {
    in.Fail("component", StrCat("component ", c.id, " of view ", view_id, " has invalid values"));
  }
  if (version >= 5) {
    const double xx = in.Read<double>("component spread");
    const double xy = in.Read<double>("component spread");
    const double yy = in.Read<double>("component spread");
    c.spread << xx, xy, xy, yy;
    if (!IsValidSpread(c.spread)) {
      in.Fail("component spread",
              StrCat("component ", c.id, " of view ", view_id, " has an invalid spread"));
    }
  }
  return c;
}

ReferenceView ReadView(BinaryReader& in, std::uint32_t version, const Expected& expected) {
  ReferenceView v;
  v.id = in.Read<std::uint64_t>("view id");
  v.descriptor = ReadDescriptorRecord(in);
  if (!expected.Fits(v.descriptor)) {
    in.Fail("view descriptor",
            StrCat("view ", v.id, " has a descriptor of another kind or length"));
  }
  v.stats = ReadStats(in);
  if (version >= 2) v.footprint = ReadFootprint(in, v.id);
  const std::size_t num_components = in.ReadCount("view components", kComponentBytes);
  if (num_components == 0) in.Fail("view components", StrCat("view ", v.id, " has no components"));
  for (std::size_t j = 0; j < num_components; ++j)
    v.components.push_back(ReadComponent(in, version, v.id));
  if (version < 2) v.footprint = FootprintFromComponents(v.components);
  return v;
}

std::map<int, MapEventCounts> ReadEventCounts(BinaryReader& in) {
  std::map<int, MapEventCounts> counts;
  const std::size_t sessions = in.ReadCount("event counts", kEventCountsBytes);
  for (std::size_t i = 0; i < sessions; ++i) {
    const int session = in.Read<std::int32_t>("event counts session");
    MapEventCounts n;
    for (std::int64_t* c : {&n.views_inserted, &n.views_removed, &n.components_added,
                            &n.components_merged, &n.components_removed}) {
      *c = in.Read<std::int64_t>("event counts");
      if (*c < 0) in.Fail("event counts", StrCat("negative count for session ", session));
    }
    if (!counts.emplace(session, n).second) {
      in.Fail("event counts", StrCat("session ", session, " appears twice"));
    }
  }
  return counts;
}

MapEvent ReadEvent(BinaryReader& in) {
  MapEvent e;
  const auto type = in.Read<std::uint8_t>("event type");
  if (type > static_cast<std::uint8_t>(MapEventType::kComponentRemoved)) {
    in.Fail("event type", StrCat("invalid event type ", int{type}));
  }
  e.type = static_cast<MapEventType>(type);
  e.frame = in.Read<std::int64_t>("event frame");
  e.session = in.Read<std::int32_t>("event session");
  e.view_id = in.Read<std::uint64_t>("event view id");
  e.component_id = in.Read<std::uint64_t>("event component id");
  e.position = ReadPose(in, "event position");
  e.weight = in.Read<double>("event weight");
  e.reason = in.ReadString("event reason");
  return e;
}

// The event section: version >= 3 stores the counts and the number logged before the
// ring; earlier versions stored the complete log, from which both are rebuilt.
void ReadEvents(BinaryReader& in, std::uint32_t version, MapEventLog* log) {
  std::uint64_t logged = 0;
  std::map<int, MapEventCounts> counts;
  if (version >= 3) {
    logged = in.Read<std::uint64_t>("events logged");
    counts = ReadEventCounts(in);
  }
  const std::size_t num_events = in.ReadCount("events", kMinEventBytes);
  if (version >= 3 && num_events > logged) {
    in.Fail("events", StrCat(num_events, " events stored but only ", logged, " logged"));
  }
  std::deque<MapEvent> ring;
  for (std::size_t i = 0; i < num_events; ++i) {
    if (version < 3) {
      log->Log(ReadEvent(in));  // counts rebuilt from the (then complete) log
    } else {
      ring.push_back(ReadEvent(in));
    }
  }
  if (version >= 3) log->Restore(logged, std::move(counts), std::move(ring));
}

// Ids must be unique and below the next ids, or later insertions would collide.
void CheckIds(BinaryReader& in, const std::vector<ReferenceView>& views, std::uint64_t next_view_id,
              std::uint64_t next_component_id) {
  std::vector<std::uint64_t> view_ids, component_ids;
  for (const ReferenceView& v : views) {
    view_ids.push_back(v.id);
    for (const ViewComponent& c : v.components) component_ids.push_back(c.id);
  }
  std::sort(view_ids.begin(), view_ids.end());
  std::sort(component_ids.begin(), component_ids.end());
  if (std::adjacent_find(view_ids.begin(), view_ids.end()) != view_ids.end() ||
      std::adjacent_find(component_ids.begin(), component_ids.end()) != component_ids.end() ||
      (!view_ids.empty() && view_ids.back() >= next_view_id) ||
      (!component_ids.empty() && component_ids.back() >= next_component_id)) {
    in.Fail("environment model", "duplicate or out-of-range view/component ids");
  }
}

}  // namespace

void EnvironmentModel::Serialize(BinaryWriter& out) const {
  out.Write(kModelMagic);
  out.Write(kModelVersion);
  out.Write(extractor_->kind());
  out.Write<std::uint64_t>(feature_size_);
  out.Write(store_.next_view_id());
  out.Write(store_.next_component_id());
  out.Write<std::uint64_t>(store_.size());
  for (const ReferenceView& v : store_.views()) WriteView(out, v);
  WriteEvents(out, events_);
  // Version 4: the recent updates of the look-back, so that a run resumed from a saved
  // map (whose queued updates are applied after loading) equals one run.
  out.Write<std::uint64_t>(recent_updates_.size());
  for (const RecentUpdate& r : recent_updates_) {
    WriteDescriptorRecord(out, r.y);
    WritePose(out, r.mu);
    WriteMatrix3(out, r.covariance);
    out.Write(r.context.frame);
    out.Write<std::int32_t>(r.context.session);
  }
  // Version 6: the view persistence counts and belief, so that a resumed run equals one
  // run.
  for (const std::int64_t n : persistence_.passes_by_run()) out.Write(n);
  for (const std::int64_t k : persistence_.matched_by_run()) out.Write(k);
  out.Write(persistence_.passes_at_fit());
  for (const double u : persistence_.upper_existence()) out.Write(u);
  out.Write(persistence_.hazard());
  out.Write(persistence_.miss_probability());
  out.Write<std::uint64_t>(open_unmatched_.size());
  for (const std::uint64_t id : open_unmatched_) out.Write(id);
}

EnvironmentModel EnvironmentModel::Deserialize(BinaryReader& in,
                                               const EnvironmentModelOptions& options,
                                               std::shared_ptr<const DescriptorExtractor> extractor,
                                               std::uint32_t min_version) {
  EnvironmentModel model(options, std::move(extractor));
  const Expected expected{model.extractor_->kind(), model.feature_size_};
  if (in.Read<std::uint32_t>("environment model magic") != kModelMagic) {
    in.Fail("environment model magic", "not an environment model (bad magic number)");
  }
  const auto version = in.Read<std::uint32_t>("environment model version");
  const std::uint32_t oldest = std::max<std::uint32_t>(min_version, kOldestFormatVersion);
  if (version < oldest || version > kModelVersion) {
    throw Error(StrCat(in.source(), ": unsupported environment model version ", version,
                       " (this build reads ", oldest, "..", kModelVersion, ")"));
  }
  const auto kind = in.Read<std::uint8_t>("model descriptor kind");
  const auto feature_size = in.Read<std::uint64_t>("model feature size");
  if (kind != static_cast<std::uint8_t>(expected.kind) || feature_size != expected.feature_size) {
    in.Fail("model descriptor kind",
            StrCat("the stored model uses descriptor kind ", int{kind}, " with ", feature_size,
                   " features, the extractor gives kind ", static_cast<int>(expected.kind),
                   " with ", expected.feature_size));
  }
  const auto next_view_id = in.Read<std::uint64_t>("next view id");
  const auto next_component_id = in.Read<std::uint64_t>("next component id");
  const std::size_t num_views = in.ReadCount("views", kMinViewBytes);
  std::vector<ReferenceView> views;
  views.reserve(num_views);
  for (std::size_t i = 0; i < num_views; ++i) views.push_back(ReadView(in, version, expected));
  ReadEvents(in, version, &model.events_);
  if (version >= 4) model.ReadRecentUpdates(in, expected.kind);
  if (version >= 6) model.ReadViewPersistence(in);
  CheckIds(in, views, next_view_id, next_component_id);
  model.store_.Restore(std::move(views), next_view_id, next_component_id);
  model.retrieval_.Rebuild(model.store_);
  return model;
}

void EnvironmentModel::ReadViewPersistence(BinaryReader& in) {
  constexpr int kBins = ViewPersistence::kRunBins;
  std::array<std::int64_t, kBins> passes{}, matched{};
  std::array<double, kBins> upper{};
  for (auto& n : passes) n = in.Read<std::int64_t>("view persistence passes");
  for (auto& k : matched) k = in.Read<std::int64_t>("view persistence matched passes");
  const auto at_fit = in.Read<std::int64_t>("view persistence passes at fit");
  for (auto& u : upper) u = in.Read<double>("view persistence belief");
  const auto hazard = in.Read<double>("view persistence hazard");
  const auto miss = in.Read<double>("view persistence miss probability");
  persistence_.Restore(passes, matched, at_fit, upper, hazard, miss, in.source().c_str());
  const std::size_t n = in.ReadCount("view persistence open passes", kI64);
  for (std::size_t i = 0; i < n; ++i) {
    const auto id = in.Read<std::uint64_t>("view persistence open pass view id");
    if (!open_unmatched_.insert(id).second) {
      in.Fail("view persistence open pass view id", StrCat("view ", id, " listed twice"));
    }
  }
}

void EnvironmentModel::ReadRecentUpdates(BinaryReader& in, DescriptorKind kind) {
  const std::size_t n = in.ReadCount("recent updates", kMinRecentUpdateBytes);
  for (std::size_t i = 0; i < n; ++i) {
    RecentUpdate r;
    r.y = ReadDescriptorRecord(in);
    if (r.y.kind != kind || r.y.features.size() != feature_size_) {
      in.Fail("recent update descriptor", "a descriptor of another kind or length");
    }
    r.mu = ReadPose(in, "recent update pose");
    r.covariance = ReadMatrix3(in, "recent update covariance");
    r.context.frame = in.Read<std::int64_t>("recent update frame");
    r.context.session = in.Read<std::int32_t>("recent update session");
    if (!r.mu.allFinite() || !r.covariance.allFinite()) {
      in.Fail("recent update", "non-finite pose or covariance");
    }
    recent_updates_.push_back(std::move(r));
  }
  while (recent_updates_.size() > static_cast<std::size_t>(options_.update.look_back_frames)) {
    recent_updates_.pop_front();
  }
}

}  // namespace omnicml
