#include "omnicml/mapping/environment_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "omnicml/descriptors/color_histogram.h"
#include "omnicml/descriptors/fourier_signature.h"

namespace omnicml {
namespace {

constexpr std::uint32_t kModelMagic = 0x4D45434Fu;  // "OCEM" little-endian
// Version 2 adds each view's footprint (ViewFootprint); version 1 maps are still read,
// their footprints estimated from the components. Version 3 adds the number of events
// logged and the per-session event counts before the (bounded) event ring; earlier
// versions rebuild the counts from their complete log. Version 4 adds the look-back's
// recent updates after the events (none are read from earlier versions).
constexpr std::uint32_t kModelVersion = 4;

// mu_t with its angle expressed relative to view i's panorama: phi_t minus the relative
// heading RelativeHeading(y_t, y_i) (docs/design.md "Environment model", phase 2). Without a
// relative heading (histograms) the heading is stored as it is.
Pose2 InViewFrame(const Pose2& mu_t, const std::optional<double>& relative_heading_rad) {
  if (!relative_heading_rad) return mu_t;
  return MakePose(mu_t.x(), mu_t.y(), mu_t.z() - *relative_heading_rad);
}

// The covariance a stored component is compared or returned with: its own, plus the
// heading inflation when the query has no relative heading.
Eigen::Matrix3d EffectiveCovariance(const Eigen::Matrix3d& c,
                                    const std::optional<double>& relative_heading_rad,
                                    double heading_sigma_rad) {
  if (relative_heading_rad) return c;
  Eigen::Matrix3d out = c;
  out(2, 2) += heading_sigma_rad * heading_sigma_rad;
  return out;
}

// [G] eqs. (13)-(14): merges `other` into `keep` by MomentMatch; the heading mean is
// anchored at `keep`'s (the wrapped difference, not the circular mean). The pair's
// weights are eta_n and eta_m ([G]; shares eta_n / (eta_n + eta_m)), or with
// `precision_weighted` eta / sqrt(det C_xy), the share times the xy precision
// (EnvironmentModelOptions::merge_precision_weighted). eta and w are summed (w clamped
// to 1 to stay a weight).
void MergeInto(ViewComponent& keep, const ViewComponent& other, bool precision_weighted) {
  double weight_keep = keep.eta, weight_other = other.eta;
  if (precision_weighted) {
    // Covariances are SPD (checked on insertion and load), so the determinants are > 0.
    weight_keep /= std::sqrt(keep.covariance.topLeftCorner<2, 2>().determinant());
    weight_other /= std::sqrt(other.covariance.topLeftCorner<2, 2>().determinant());
  }
  const Gaussian pair[2] = {Gaussian{keep.mean, keep.covariance, weight_keep},
                            Gaussian{other.mean, other.covariance, weight_other}};
  const Gaussian merged = MomentMatch(pair, HeadingMean::kAnchored);
  keep.covariance = merged.covariance;
  keep.mean = merged.mean;
  keep.eta += other.eta;
  keep.weight = std::min(1.0, keep.weight + other.weight);
}

// Pass bookkeeping of rule (18) (docs/forgetting.md): an Update in which the view is
// expected to match (it matched, or mu_t lies inside its footprint) more than gap frames
// after the last one, or in another session, starts a new pass; the pass it closes adds
// to missed_passes if the view never matched during it. A match resets missed_passes.
void NoteExpected(ViewFootprint& f, const UpdateContext& context, bool matched, int gap) {
  const bool new_pass = f.last_expected_frame < 0 || f.last_expected_session != context.session ||
                        std::abs(context.frame - f.last_expected_frame) > gap;
  if (new_pass) {
    if (f.last_expected_frame >= 0 && !f.pass_matched) ++f.missed_passes;
    f.pass_matched = false;
  }
  if (matched) {
    if (!f.pass_matched) ++f.matched_passes;
    f.pass_matched = true;
    f.missed_passes = 0;
  }
  f.last_expected_frame = context.frame;
  f.last_expected_session = context.session;
}

// A footprint estimated from components (maps of version 1, AddView): their xy means
// weighted by eta.
ViewFootprint FootprintFromComponents(const std::vector<ViewComponent>& components) {
  ViewFootprint f;
  for (const ViewComponent& c : components) f.Observe(c.mean.x(), c.mean.y(), c.eta);
  return f;
}

// Whether E(a, b) >= ||a - b||_2 for every pair of feature vectors, which the candidate
// index's projection bound needs (view_index.h): the L2 norm itself, and the L1 norm
// (||v||_1 >= ||v||_2 for every v). Divergences and the intersection distance have no such
// bound; extractors this module does not know are not trusted to have one.
bool DistanceBoundedByL2(const DescriptorExtractor& extractor) {
  if (const auto* f = dynamic_cast<const FourierSignature*>(&extractor)) {
    return f->options().distance == FourierDistance::kL2 ||
           f->options().distance == FourierDistance::kL1;
  }
  if (const auto* c = dynamic_cast<const ColorHistogram*>(&extractor)) {
    return c->options().distance == HistogramDistance::kL2 ||
           c->options().distance == HistogramDistance::kL1;
  }
  return false;
}

// Whether the extractor's distance is exactly the L2 norm of the feature difference
// (then the graph's L2 order is E's order and a top_k query may stop at k neighbours).
bool DistanceIsL2(const DescriptorExtractor& extractor) {
  if (const auto* f = dynamic_cast<const FourierSignature*>(&extractor))
    return f->options().distance == FourierDistance::kL2;
  if (const auto* c = dynamic_cast<const ColorHistogram*>(&extractor))
    return c->options().distance == HistogramDistance::kL2;
  return false;
}

// The order of match lists: (distance, id) is a total order, so a list does not depend
// on the order its matches were found in.
bool MatchBefore(const ViewMatch& a, const ViewMatch& b) {
  return a.distance != b.distance ? a.distance < b.distance : a.view_id < b.view_id;
}

// Which rule last changed a component's weight in this Update (for removal reasons).
enum class Touch : std::uint8_t { kNone, kIncrease, kPassive, kActive };

const char* RemovalReason(Touch t) {
  switch (t) {
    case Touch::kPassive:
      return "passive forgetting (17)";
    case Touch::kActive:
      return kActiveForgettingReason;
    default:
      return "weight below w_min";
  }
}

void WritePose(BinaryWriter& out, const Pose2& p) {
  for (int k = 0; k < 3; ++k) out.Write(p[k]);
}

Pose2 ReadPose(BinaryReader& in, const char* what) {
  Pose2 p;
  for (int k = 0; k < 3; ++k) p[k] = in.Read<double>(what);
  return p;
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

std::string ToString(MapEventType type) {
  switch (type) {
    case MapEventType::kViewInserted:
      return "view_inserted";
    case MapEventType::kViewRemoved:
      return "view_removed";
    case MapEventType::kComponentAdded:
      return "component_added";
    case MapEventType::kComponentMerged:
      return "component_merged";
    case MapEventType::kComponentRemoved:
      return "component_removed";
  }
  return "unknown";
}

void EnvironmentModelOptions::Validate() const {
  auto fail = [](const char* field, const std::string& rule, double value) {
    throw Error(StrCat("EnvironmentModelOptions.", field, " must be ", rule, ", got ", value));
  };
  if (!(std::isfinite(e_max) && e_max > 0)) fail("e_max", "finite and > 0", e_max);
  if (top_k < 0) fail("top_k", ">= 0", top_k);
  if (!(beta > 0 && beta <= 1)) fail("beta", "in (0, 1]", beta);
  if (!(std::isfinite(d_max) && d_max > 0)) fail("d_max", "finite and > 0", d_max);
  if (!(std::isfinite(d_for_m) && d_for_m > 0)) fail("d_for_m", "finite and > 0", d_for_m);
  if (!(std::isfinite(beta_for) && beta_for >= 0)) fail("beta_for", "finite and >= 0", beta_for);
  if (!(std::isfinite(d_gain_m) && d_gain_m >= 0)) fail("d_gain_m", "finite and >= 0", d_gain_m);
  if (!(w_min >= 0 && w_min < 1)) fail("w_min", "in [0, 1)", w_min);
  if (!(std::isfinite(merge_delta) && merge_delta >= 0))
    fail("merge_delta", "finite and >= 0", merge_delta);
  if (!(std::isfinite(heading_sigma_no_rotation_rad) && heading_sigma_no_rotation_rad > 0)) {
    fail("heading_sigma_no_rotation_rad", "finite and > 0", heading_sigma_no_rotation_rad);
  }
  if (forgetting != ForgettingMode::kActive && forgetting != ForgettingMode::kPassive &&
      forgetting != ForgettingMode::kStatic) {
    fail("forgetting", "active, passive or static", static_cast<int>(forgetting));
  }
  if (!(std::isfinite(spatial_cell_m) && spatial_cell_m > 0))
    fail("spatial_cell_m", "finite and > 0", spatial_cell_m);
  if (!(std::isfinite(footprint_gate) && footprint_gate > 0))
    fail("footprint_gate", "finite and > 0", footprint_gate);
  if (forget_min_missed_passes < 0)
    fail("forget_min_missed_passes", ">= 0", forget_min_missed_passes);
  if (pass_gap_frames < 0) fail("pass_gap_frames", ">= 0", pass_gap_frames);
  if (look_back_frames < 0) fail("look_back_frames", ">= 0", look_back_frames);
  if (!(std::isfinite(footprint_confidence) && footprint_confidence >= 0))
    fail("footprint_confidence", "finite and >= 0", footprint_confidence);
  if (max_events < 0) fail("max_events", ">= 0", max_events);
  if (index_min_views < 0) fail("index_min_views", ">= 0", index_min_views);
  if (!(index_max_bounded_fraction > 0 && index_max_bounded_fraction <= 1))
    fail("index_max_bounded_fraction", "in (0, 1]", index_max_bounded_fraction);
  if (index_dims < 1) fail("index_dims", ">= 1", index_dims);
  if (ann_min_views < 0) fail("ann_min_views", ">= 0", ann_min_views);
  if (ann_m < 2 || ann_m > 64) fail("ann_m", "in [2, 64]", ann_m);
  if (ann_ef_construction < 1) fail("ann_ef_construction", ">= 1", ann_ef_construction);
  if (ann_ef < 1) fail("ann_ef", ">= 1", ann_ef);
  if (ann_k < 1) fail("ann_k", ">= 1", ann_k);
}

void EnvironmentModel::LogEvent(MapEvent e) {
  MapEventCounts& n = event_counts_[e.session];
  switch (e.type) {
    case MapEventType::kViewInserted:
      ++n.views_inserted;
      break;
    case MapEventType::kViewRemoved:
      ++n.views_removed;
      break;
    case MapEventType::kComponentAdded:
      ++n.components_added;
      break;
    case MapEventType::kComponentMerged:
      ++n.components_merged;
      break;
    case MapEventType::kComponentRemoved:
      ++n.components_removed;
      break;
  }
  ++events_logged_;
  events_.push_back(std::move(e));
  while (events_.size() > static_cast<std::size_t>(options_.max_events)) events_.pop_front();
}

double ReferenceView::TotalWeight() const {
  double sum = 0.0;
  for (const ViewComponent& c : components) sum += c.weight;
  return sum;
}

void ViewFootprint::Observe(double x_m, double y_m, double w) {
  if (!(w > 0)) return;
  const double total = weight + w;
  const Eigen::Vector2d delta = Eigen::Vector2d(x_m, y_m) - mean;
  mean += (w / total) * delta;
  // Weighted Welford update: w (1 - w / total) delta delta^T, kept exactly symmetric.
  const double k = w * (1.0 - w / total);
  scatter(0, 0) += k * delta.x() * delta.x();
  scatter(1, 1) += k * delta.y() * delta.y();
  scatter(0, 1) += k * delta.x() * delta.y();
  scatter(1, 0) = scatter(0, 1);
  weight = total;
}

Eigen::Matrix2d ViewFootprint::Covariance() const {
  return weight > 0 ? Eigen::Matrix2d(scatter / weight) : Eigen::Matrix2d::Zero();
}

double ViewFootprint::SquaredDistance(const Eigen::Vector2d& p, const Eigen::Matrix2d& s) const {
  const Eigen::Vector2d d = p - mean;
  const Eigen::LLT<Eigen::Matrix2d> llt(s);
  if (llt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return llt.matrixL().solve(d).squaredNorm();
}

EnvironmentModel::EnvironmentModel(const EnvironmentModelOptions& options,
                                   std::shared_ptr<const DescriptorExtractor> extractor)
    : options_(options), extractor_(std::move(extractor)), spatial_(options.spatial_cell_m) {
  options_.Validate();
  if (!extractor_) throw Error("EnvironmentModel: the descriptor extractor is null");
  feature_size_ = extractor_->FeatureSize();
  if (feature_size_ == 0) throw Error("EnvironmentModel: the extractor's FeatureSize() is 0");
  index_supported_ = DistanceBoundedByL2(*extractor_);
  distance_is_l2_ = DistanceIsL2(*extractor_);
}

void EnvironmentModel::CheckDescriptor(const Descriptor& y, const char* where) const {
  if (y.kind != extractor_->kind()) {
    throw Error(StrCat("EnvironmentModel::", where, ": descriptor kind ", ToString(y.kind),
                       " differs from the model's kind ", ToString(extractor_->kind())));
  }
  if (y.features.size() != feature_size_) {
    throw Error(StrCat("EnvironmentModel::", where, ": descriptor has ", y.features.size(),
                       " features, the model expects ", feature_size_));
  }
}

std::vector<ViewMatch> EnvironmentModel::Search(const Descriptor& y, int top_k, bool exhaustive,
                                                const std::vector<std::size_t>* only) const {
  const std::size_t n = feature_size_;
  const float* query = y.features.data();
  const float* rows = features_.data();
  const double e_max = options_.e_max;
  std::vector<ViewMatch> out;
  auto consider = [&](std::size_t i) {
    const double e = extractor_->Distance(query, rows + i * n, n);
    if (e < e_max) {
      ViewMatch m;
      m.view_index = i;
      m.view_id = views_[i].id;
      m.distance = e;
      // docs/design.md: S = max(0, 1 - E / E_max), linear.
      m.similarity = std::max(0.0, 1.0 - e / e_max);
      out.push_back(m);
    }
  };
  if (only != nullptr) {
    for (const std::size_t i : *only) consider(i);
  } else if (AnnActive() && !exhaustive) {
    // Approximate candidate stage (ann_index.h): the graph's nearest views, then the same
    // exact distance as in the scan, so the result equals the scan's whenever the
    // candidates hold the true matches.
    std::vector<std::size_t> candidates;
    AnnCandidates(query, top_k, &candidates);
    for (const std::size_t i : candidates) consider(i);
  } else if (view_index_.built() && !exhaustive) {
    // Candidate stage (view_index.h): every view with E < e_max is among the candidates,
    // and each candidate gets the same exact distance as in the scan below, so the
    // matches are the same.
    std::vector<std::size_t> candidates;
    view_index_.Candidates(query, e_max, &candidates);
    for (const std::size_t i : candidates) consider(i);
  } else {
    // The hot loop: one contiguous row per view, the extractor's raw-pointer distance.
    for (std::size_t i = 0; i < views_.size(); ++i) consider(i);
  }
  std::sort(out.begin(), out.end(), MatchBefore);
  if (top_k > 0 && out.size() > static_cast<std::size_t>(top_k))
    out.resize(static_cast<std::size_t>(top_k));
  for (ViewMatch& m : out) {
    const std::optional<double> rel =
        extractor_->RelativeHeading(y, views_[m.view_index].descriptor);
    if (rel) m.relative_heading_rad = WrapAngle(*rel);
  }
  return out;
}

void EnvironmentModel::BuildIndex() {
  std::vector<std::uint64_t> ids(views_.size());
  for (std::size_t i = 0; i < views_.size(); ++i) ids[i] = views_[i].id;
  const int dims =
      std::min({options_.index_dims, static_cast<int>(feature_size_), ViewIndex::kMaxDims});
  // Quantisation step e_max / 256: the bound loses at most one step per axis (view_index.h).
  view_index_.Build(features_.data(), ids.data(), views_.size(), feature_size_, dims,
                    options_.e_max / 256.0);
  // Does it pay? Bound counts (not times, so the decision is deterministic) for 32 stored
  // views, evenly spaced in storage order, as queries.
  constexpr std::size_t kSamples = 32;
  const std::size_t n = views_.size();
  std::size_t bounded = 0, queries = 0;
  std::vector<std::size_t> scratch;
  for (std::size_t k = 0; k < kSamples && n > 0; ++k) {
    const std::size_t row = k * n / kSamples;
    scratch.clear();
    bounded += view_index_.Candidates(features_.data() + row * feature_size_, options_.e_max,
                                      &scratch);
    ++queries;
  }
  index_bounded_fraction_ =
      queries > 0 ? static_cast<double>(bounded) / static_cast<double>(queries * n) : 1.0;
  if (index_bounded_fraction_ > options_.index_max_bounded_fraction) {
    view_index_.Clear();  // the scan is as fast: revisit when the map has doubled
    index_rejected_at_ = n;
  } else {
    index_rejected_at_ = 0;
  }
}

void EnvironmentModel::AnnCandidates(const float* query, int top_k,
                                     std::vector<std::size_t>* rows) const {
  // Squared L2 limit with the exact index's margin (view_index.h): float sums in the
  // graph and in the extractor differ by ~1e-6 relative.
  const double e_max = options_.e_max;
  const double limit = (1.001 * e_max) * (1.001 * e_max);
  const std::size_t live = ann_index_.size();
  std::size_t k = std::min<std::size_t>(
      live, static_cast<std::size_t>(std::max(top_k, options_.ann_k)));
  std::vector<std::pair<float, std::uint64_t>> near;
  while (true) {
    ann_index_.Nearest(query, k, static_cast<std::size_t>(options_.ann_ef), &near);
    if (near.size() < k || k >= live) break;  // every view the graph reaches
    const double farthest = near.back().first;
    if (!(farthest < limit)) break;  // the radius is covered
    if (top_k > 0 && distance_is_l2_) {
      // E = L2: the top_k are found once top_k returned views are closer than the
      // farthest returned one (margin as above), which bounds every view not returned.
      const double closer = farthest / (1.001 * 1.001);
      std::size_t n = 0;
      for (const auto& [d, id] : near) n += d < closer;
      if (n >= static_cast<std::size_t>(top_k)) break;
    }
    k = std::min(live, 2 * k);
  }
  rows->reserve(rows->size() + near.size());
  for (const auto& [d, id] : near) {
    // Views beyond the radius by the graph's own distance cannot match (E >= L2); the
    // margin keeps the float difference from dropping a border match.
    if (!(d < limit)) continue;
    rows->push_back(index_of_id_.at(id));
  }
}

void EnvironmentModel::SetAnnSearch(int ef, int k) {
  if (ef < 1 || k < 1) throw Error("EnvironmentModel::SetAnnSearch: ef and k must be >= 1");
  options_.ann_ef = ef;
  options_.ann_k = k;
}

void EnvironmentModel::BuildAnn() {
  AnnIndex::Params p;
  p.m = options_.ann_m;
  p.ef_construction = options_.ann_ef_construction;
  ann_index_.Reset(feature_size_, p, views_.size() + views_.size() / 4);
  // Id order: the order the views were inserted in, so a model rebuilt from its file
  // (Deserialize) gets the graph the continuing model has when it removed no view.
  std::vector<std::pair<std::uint64_t, std::size_t>> order;
  order.reserve(views_.size());
  for (std::size_t i = 0; i < views_.size(); ++i) order.emplace_back(views_[i].id, i);
  std::sort(order.begin(), order.end());
  for (const auto& [id, row] : order) ann_index_.Insert(id, features_.data() + row * feature_size_);
}

void EnvironmentModel::MaintainIndex() {
  const std::size_t ann_threshold = static_cast<std::size_t>(options_.ann_min_views);
  // The graph is kept from the first view on (one insertion per new view, spread over
  // the run) and searched from ann_min_views views on (AnnActive), so no Update ever
  // stalls on a whole-map build when the map crosses the threshold.
  if (index_supported_ && ann_threshold > 0 && !ann_index_.built() && !views_.empty()) {
    BuildAnn();
  }
  const std::size_t threshold = static_cast<std::size_t>(options_.index_min_views);
  if (!index_supported_ || threshold == 0) return;
  if (!view_index_.built()) {
    if (views_.size() >= threshold &&
        (index_rejected_at_ == 0 || views_.size() >= 2 * index_rejected_at_)) {
      BuildIndex();
    }
    return;
  }
  if (2 * views_.size() < threshold) {
    view_index_.Clear();  // a map this small is faster to scan
    index_rejected_at_ = 0;
    return;
  }
  switch (view_index_.Pending()) {
    case ViewIndex::Maintenance::kNone:
      break;
    case ViewIndex::Maintenance::kRetree:
      view_index_.Retree();
      break;
    case ViewIndex::Maintenance::kRefit:
      BuildIndex();
      break;
  }
}

std::vector<ViewMatch> EnvironmentModel::FindMatches(const Descriptor& y) const {
  CheckDescriptor(y, "FindMatches");
  return Search(y, options_.top_k);
}

std::vector<ViewMatch> EnvironmentModel::FindAllMatches(const Descriptor& y) const {
  CheckDescriptor(y, "FindAllMatches");
  return Search(y, 0);
}

std::vector<ViewMatch> EnvironmentModel::FindMatchesExhaustive(const Descriptor& y) const {
  CheckDescriptor(y, "FindMatchesExhaustive");
  return Search(y, options_.top_k, /*exhaustive=*/true);
}

std::vector<ViewMatch> EnvironmentModel::FindMatchesNear(const Descriptor& y,
                                                         const std::vector<Disc>& discs,
                                                         std::size_t* candidates) const {
  CheckDescriptor(y, "FindMatchesNear");
  const std::vector<std::size_t> only = RowsNear(discs);
  if (candidates != nullptr) *candidates = only.size();
  return Search(y, options_.top_k, /*exhaustive=*/false, &only);
}

std::vector<std::size_t> EnvironmentModel::RowsNear(const std::vector<Disc>& discs) const {
  std::vector<std::size_t> rows;
  for (const Disc& d : discs) {
    for (const SpatialEntry& e : spatial_.QueryRadius(d.x_m, d.y_m, d.radius_m)) {
      rows.push_back(index_of_id_.at(e.view_id));
    }
  }
  std::sort(rows.begin(), rows.end());
  rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
  return rows;
}

Mixture EnvironmentModel::Hypothesis(const Descriptor& y) const {
  return Hypothesis(FindMatches(y));
}

Mixture EnvironmentModel::Hypothesis(const std::vector<ViewMatch>& matches) const {
  Mixture out;
  double total = 0.0;
  for (const ViewMatch& m : matches) {
    if (m.view_index >= views_.size() || views_[m.view_index].id != m.view_id) {
      throw Error(StrCat("EnvironmentModel::Hypothesis: match of view ", m.view_id,
                         " is stale (the model changed since FindMatches)"));
    }
    const ReferenceView& view = views_[m.view_index];
    for (const ViewComponent& c : view.components) {
      // docs/design.md: weight w_ij * S_i, heading rotated by the relative heading.
      Gaussian g;
      g.mean = m.relative_heading_rad
                   ? MakePose(c.mean.x(), c.mean.y(), c.mean.z() + *m.relative_heading_rad)
                   : c.mean;
      g.covariance = EffectiveCovariance(c.covariance, m.relative_heading_rad,
                                         options_.heading_sigma_no_rotation_rad);
      g.weight = c.weight * m.similarity;
      total += g.weight;
      out.push_back(g);
    }
  }
  if (!(total > 0.0)) return {};
  for (Gaussian& g : out) g.weight /= total;
  return out;
}

std::size_t EnvironmentModel::InsertView(const Descriptor& y, const UpdateContext& context,
                                         const Pose2& where) {
  ReferenceView v;
  v.id = next_view_id_++;
  v.descriptor = y;
  v.stats.created_frame = context.frame;
  v.stats.created_session = context.session;
  v.stats.last_seen_frame = context.frame;
  v.stats.last_seen_session = context.session;
  features_.insert(features_.end(), y.features.begin(), y.features.end());
  index_of_id_[v.id] = views_.size();
  LogEvent(MapEvent{MapEventType::kViewInserted, context.frame, context.session, v.id, 0,
                             where, 0.0, "no view within e_max"});
  views_.push_back(std::move(v));
  const std::size_t index = views_.size() - 1;
  if (view_index_.built()) view_index_.Insert(views_[index].id, index, y.features.data());
  if (ann_index_.built()) ann_index_.Insert(views_[index].id, y.features.data());
  MaintainIndex();
  return index;
}

std::uint64_t EnvironmentModel::AddView(const Descriptor& y, std::vector<ViewComponent> components,
                                        const ViewStats& stats) {
  CheckDescriptor(y, "AddView");
  if (components.empty())
    throw Error("EnvironmentModel::AddView: a view needs at least one component");
  for (std::size_t j = 0; j < components.size(); ++j) {
    const ViewComponent& c = components[j];
    const bool spd = c.covariance.allFinite() &&
                     c.covariance.isApprox(c.covariance.transpose(), 1e-9) &&
                     Eigen::LLT<Eigen::Matrix3d>(c.covariance).info() == Eigen::Success;
    if (!(c.weight >= 0 && c.weight <= 1) || !(c.eta > 0) || !c.mean.allFinite() || !spd) {
      throw Error(StrCat("EnvironmentModel::AddView: component ", j,
                         " is invalid (weight in [0, 1], eta > 0, finite mean, SPD covariance)"));
    }
  }
  ReferenceView v;
  v.id = next_view_id_++;
  v.descriptor = y;
  v.stats = stats;
  v.components = std::move(components);
  v.footprint = FootprintFromComponents(v.components);
  for (ViewComponent& c : v.components) {
    c.id = next_component_id_++;
    c.mean.z() = WrapAngle(c.mean.z());
    c.covariance = 0.5 * (c.covariance + c.covariance.transpose());  // exactly symmetric
    spatial_.Insert(SpatialEntry{v.id, c.id, c.mean.x(), c.mean.y()});
    ++num_components_;
  }
  features_.insert(features_.end(), y.features.begin(), y.features.end());
  index_of_id_[v.id] = views_.size();
  LogEvent(MapEvent{MapEventType::kViewInserted, stats.created_frame,
                             stats.created_session, v.id, 0, v.components.front().mean,
                             v.TotalWeight(), "added"});
  views_.push_back(std::move(v));
  if (view_index_.built())
    view_index_.Insert(views_.back().id, views_.size() - 1, y.features.data());
  if (ann_index_.built()) ann_index_.Insert(views_.back().id, y.features.data());
  MaintainIndex();
  return views_.back().id;
}

void EnvironmentModel::RemoveViewAt(std::size_t index) {
  OMNICML_CHECK(index < views_.size());
  const std::size_t last = views_.size() - 1;
  for (const ViewComponent& c : views_[index].components) {
    spatial_.Remove(views_[index].id, c.id, c.mean.x(), c.mean.y());
    --num_components_;
  }
  const std::uint64_t removed_id = views_[index].id;
  index_of_id_.erase(removed_id);
  if (view_index_.built()) view_index_.Remove(removed_id);
  if (ann_index_.built()) ann_index_.Remove(removed_id);
  if (index != last) {
    // Swap-remove: the last view (and its feature row) takes the freed slot.
    views_[index] = std::move(views_[last]);
    std::copy(features_.begin() + static_cast<std::ptrdiff_t>(last * feature_size_),
              features_.begin() + static_cast<std::ptrdiff_t>((last + 1) * feature_size_),
              features_.begin() + static_cast<std::ptrdiff_t>(index * feature_size_));
    index_of_id_[views_[index].id] = index;
    if (view_index_.built()) view_index_.SetRow(views_[index].id, index);
  }
  views_.pop_back();
  features_.resize(views_.size() * feature_size_);
  MaintainIndex();
}

std::optional<std::size_t> EnvironmentModel::FindView(std::uint64_t view_id) const {
  auto it = index_of_id_.find(view_id);
  if (it == index_of_id_.end()) return std::nullopt;
  return it->second;
}

UpdateStats EnvironmentModel::Update(const Descriptor& y, const Gaussian& estimate,
                                     const UpdateContext& context) {
  UpdateStats stats;
  CheckDescriptor(y, "Update");
  if (!estimate.mean.allFinite())
    throw Error("EnvironmentModel::Update: the estimate's mean is not finite");
  if (!estimate.covariance.allFinite())
    throw Error("EnvironmentModel::Update: the estimate's covariance is not finite");
  const Eigen::Matrix3d c_t = 0.5 * (estimate.covariance + estimate.covariance.transpose());
  if (Eigen::LLT<Eigen::Matrix3d>(c_t).info() != Eigen::Success || !(c_t(0, 0) > 0) ||
      !(c_t(1, 1) > 0)) {
    throw Error("EnvironmentModel::Update: the estimate's covariance is not positive definite");
  }
  if (options_.forgetting == ForgettingMode::kStatic) return stats;  // the map never changes
  const Pose2 mu_t = MakePose(estimate.mean.x(), estimate.mean.y(), estimate.mean.z());

  std::vector<ViewMatch> matches = Search(y, 0);
  if (AnnActive()) {
    // The graph can miss a match (recall < 1). The views with a component within d_for
    // of mu_t are the ones rule (18) would weaken as "expected here but not matching",
    // so they get the exact distance whatever the graph returned: near the robot the
    // Update is the exact scan's; only far-away (aliased) matches may be missed.
    std::vector<std::size_t> rows = RowsNear({{mu_t.x(), mu_t.y(), options_.d_for_m}});
    std::vector<std::size_t> found;
    for (const ViewMatch& m : matches) found.push_back(m.view_index);
    std::sort(found.begin(), found.end());
    std::erase_if(rows, [&](std::size_t r) {
      return std::binary_search(found.begin(), found.end(), r);
    });
    if (!rows.empty()) {
      // Both lists are in MatchBefore order: merge them.
      const std::vector<ViewMatch> extra = Search(y, 0, /*exhaustive=*/false, &rows);
      const auto middle = static_cast<std::ptrdiff_t>(matches.size());
      matches.insert(matches.end(), extra.begin(), extra.end());
      std::inplace_merge(matches.begin(), matches.begin() + middle, matches.end(), MatchBefore);
    }
  }
  stats.matching_views = static_cast<int>(matches.size());
  std::uint64_t inserted_id = 0;

  // Phase 1 ([G 2.3]): insertion iff E(y_t, y_i) >= E_max for every view i.
  if (matches.empty()) {
    const std::size_t index = InsertView(y, context, mu_t);
    stats.view_inserted = true;
    inserted_id = views_[index].id;
    ViewMatch self;
    self.view_index = index;
    self.view_id = views_[index].id;
    self.distance = 0.0;
    self.similarity = 1.0;
    if (extractor_->ProvidesHeading()) self.relative_heading_rad = 0.0;
    matches.push_back(self);
  }

  // Phase 2: one component per matching view, w = 0 and eta = S_i / sum_l S_l (our
  // reading of [G] (11)), then merging of components closer than delta (12).
  double sum_s = 0.0;
  for (const ViewMatch& m : matches) sum_s += m.similarity;
  std::vector<std::uint64_t> fresh;  // components created by this Update, kept separate
  for (const ViewMatch& m : matches) {
    ReferenceView& view = views_[m.view_index];
    view.stats.observations += 1;
    view.stats.last_seen_frame = context.frame;
    view.stats.last_seen_session = context.session;
    view.footprint.Observe(mu_t.x(), mu_t.y(), m.similarity);
    NoteExpected(view.footprint, context, /*matched=*/true, options_.pass_gap_frames);

    ViewComponent added;
    added.weight = 0.0;
    added.eta = m.similarity / sum_s;  // [G] (11)
    added.mean = InViewFrame(mu_t, m.relative_heading_rad);
    added.covariance = c_t;

    std::vector<ViewComponent>& comps = view.components;
    auto closest_within_delta = [&](const ViewComponent& c, std::size_t skip) {
      std::size_t best = comps.size();
      double best_d2 = options_.merge_delta;
      for (std::size_t j = 0; j < comps.size(); ++j) {
        if (j == skip) continue;
        // [G] (12): merge when closer than delta.
        const double d2 =
            SquaredMahalanobis(c.mean, comps[j].mean, c.covariance + comps[j].covariance);
        if (d2 < best_d2) {
          best_d2 = d2;
          best = j;
        }
      }
      return best;
    };

    std::size_t k = closest_within_delta(added, comps.size());
    if (k == comps.size()) {
      fresh.push_back(AppendComponent(view, added, context, "observation", &stats));
      continue;
    }
    // The new component merges into component k; the moved result may now be within
    // delta of another one, which is merged in turn (the earlier one in storage order
    // survives), until no pair involving it is closer than delta.
    ++stats.components_merged;
    {
      const Pose2 old = comps[k].mean;
      MergeInto(comps[k], added, options_.merge_precision_weighted);
      spatial_.Move(view.id, comps[k].id, old.x(), old.y(), comps[k].mean.x(), comps[k].mean.y());
      if (options_.log_component_events) {
        LogEvent(MapEvent{MapEventType::kComponentMerged, context.frame, context.session,
                                   view.id, comps[k].id, comps[k].mean, comps[k].weight,
                                   "merge (12)-(14)"});
      }
    }
    for (;;) {
      const std::size_t j = closest_within_delta(comps[k], k);
      if (j == comps.size()) break;
      const std::size_t keep = std::min(j, k), drop = std::max(j, k);
      const Pose2 old = comps[keep].mean;
      const ViewComponent dropped = comps[drop];
      MergeInto(comps[keep], dropped, options_.merge_precision_weighted);
      spatial_.Remove(view.id, dropped.id, dropped.mean.x(), dropped.mean.y());
      spatial_.Move(view.id, comps[keep].id, old.x(), old.y(), comps[keep].mean.x(),
                    comps[keep].mean.y());
      comps.erase(comps.begin() + static_cast<std::ptrdiff_t>(drop));
      --num_components_;
      if (options_.log_component_events) {
        LogEvent(MapEvent{MapEventType::kComponentMerged, context.frame, context.session,
                                   view.id, comps[keep].id, comps[keep].mean, comps[keep].weight,
                                   "merge (12)-(14)"});
      }
      k = keep;
    }
  }
  std::sort(fresh.begin(), fresh.end());

  // Phase 3: weights. touched[id] = rule applied, per component id, for removal reasons.
  std::unordered_map<std::uint64_t, Touch> touch;
  std::vector<std::uint64_t> touched_views;
  for (const ViewMatch& m : matches) {
    ReferenceView& view = views_[m.view_index];
    touched_views.push_back(view.id);
    const Pose2 mu_view = InViewFrame(mu_t, m.relative_heading_rad);
    const double beta_s = options_.beta * m.similarity;
    for (ViewComponent& c : view.components) {
      const Eigen::Matrix3d s = c_t + EffectiveCovariance(c.covariance, m.relative_heading_rad,
                                                          options_.heading_sigma_no_rotation_rad);
      // [G] eq. (15): Mahalanobis distance of mu_t to the component.
      const double d = std::sqrt(SquaredMahalanobis(mu_view, c.mean, s));
      if (d <= options_.d_max) {
        // [G] eq. (16): weight increase.
        c.weight = beta_s + (1.0 - beta_s) * c.weight;
        touch[c.id] = Touch::kIncrease;
        ++stats.components_increased;
      } else {
        // [G] eq. (17): passive forgetting.
        c.weight = (1.0 - beta_s) * c.weight;
        touch[c.id] = Touch::kPassive;
        ++stats.components_passive_forgotten;
      }
    }
  }
  if (options_.forgetting == ForgettingMode::kActive) {
    std::vector<std::uint64_t> matched_ids;
    for (const ViewMatch& m : matches) matched_ids.push_back(m.view_id);
    std::sort(matched_ids.begin(), matched_ids.end());
    const double sigma_sum_m = std::sqrt(c_t(0, 0)) + std::sqrt(c_t(1, 1));
    const Eigen::Matrix2d c_xy = c_t.topLeftCorner<2, 2>();
    const Eigen::Vector2d mu_xy(mu_t.x(), mu_t.y());
    // Candidates: views with a component within d_for of mu_t (spatial index, entries
    // sorted by view id, then component id), visited a view at a time.
    const std::vector<SpatialEntry> near =
        spatial_.QueryRadius(mu_t.x(), mu_t.y(), options_.d_for_m);
    for (std::size_t first = 0; first < near.size();) {
      std::size_t last = first;
      while (last < near.size() && near[last].view_id == near[first].view_id) ++last;
      const std::uint64_t view_id = near[first].view_id;
      const std::size_t begin = first;
      first = last;
      if (std::binary_search(matched_ids.begin(), matched_ids.end(), view_id))
        continue;  // E_i < E_max
      ReferenceView& view = views_[index_of_id_.at(view_id)];
      ViewFootprint& footprint = view.footprint;
      // docs/forgetting.md: the view is expected to match only where mu_t lies inside its
      // footprint (the spread of the estimates at which it matched), widened by C_t.
      const double d_fp = std::sqrt(
          footprint.SquaredDistance(mu_xy, c_xy + footprint.Covariance()));
      if (!(d_fp < options_.footprint_gate)) continue;
      // Confidently inside: the robot's position uncertainty must not exceed the
      // footprint's own extent (largest standard deviations compared), else a miss says
      // nothing about the view.
      if (options_.footprint_confidence > 0 &&
          LargestEigenvalue2(c_xy) > options_.footprint_confidence * options_.footprint_confidence *
                                        LargestEigenvalue2(footprint.Covariance())) {
        continue;
      }
      NoteExpected(footprint, context, /*matched=*/false, options_.pass_gap_frames);
      // Evidence over passes: only after forget_min_missed_passes whole passes through
      // the footprint without a match does a miss weaken the view; a view made in this
      // session and seen on its creation pass only, from the first pass that misses it
      // (forget_unconfirmed_views).
      const bool unconfirmed = options_.forget_unconfirmed_views &&
                               view.stats.created_session == context.session &&
                               footprint.matched_passes == 1 && !footprint.pass_matched;
      if (footprint.missed_passes < options_.forget_min_missed_passes && !unconfirmed) continue;
      // [G] eq. (19) with d_xy / d_for replaced by the footprint distance d_fp / gate:
      // b = beta_for max(1 - d_fp / gate, 0) d_gain / (sigma_x + sigma_y), in [0, 1].
      double b = std::clamp(options_.beta_for *
                                      std::max(1.0 - d_fp / options_.footprint_gate, 0.0) *
                                      options_.d_gain_m / sigma_sum_m,
                                  0.0, 1.0);
      // Evidence against a place grows with the evidence for it: a view that matched
      // in k passes loses weight k times more slowly than a view seen once.
      if (options_.forget_by_matched_passes && footprint.matched_passes > 1) {
        b /= static_cast<double>(footprint.matched_passes);
      }
      touched_views.push_back(view_id);
      for (std::size_t k = begin; k < last; ++k) {
        for (ViewComponent& c : view.components) {
          if (c.id != near[k].component_id) continue;
          // [G] eq. (18): active forgetting.
          c.weight = (1.0 - b) * c.weight;
          touch[c.id] = Touch::kActive;
          if (b > 0) ++stats.components_active_forgotten;
          break;
        }
      }
    }
  }

  // Removal: components below w_min (except those created by this Update), then views
  // whose mixture is empty. Only views touched above can hold such components.
  for (const std::uint64_t view_id : touched_views) {
    const auto it = index_of_id_.find(view_id);
    if (it == index_of_id_.end()) continue;
    ReferenceView& view = views_[it->second];
    std::vector<ViewComponent>& comps = view.components;
    Pose2 last_position = comps.empty() ? mu_t : comps.back().mean;
    std::size_t out = 0;
    for (std::size_t j = 0; j < comps.size(); ++j) {
      ViewComponent& c = comps[j];
      const bool is_fresh = std::binary_search(fresh.begin(), fresh.end(), c.id);
      if (c.weight >= options_.w_min || is_fresh) {
        if (out != j) comps[out] = std::move(c);
        ++out;
        continue;
      }
      const auto t = touch.find(c.id);
      LogEvent(MapEvent{MapEventType::kComponentRemoved, context.frame, context.session,
                                 view.id, c.id, c.mean, c.weight,
                                 RemovalReason(t == touch.end() ? Touch::kNone : t->second)});
      spatial_.Remove(view.id, c.id, c.mean.x(), c.mean.y());
      --num_components_;
      ++stats.components_removed;
      last_position = c.mean;
    }
    comps.resize(out);
    if (comps.empty()) {
      LogEvent(MapEvent{MapEventType::kViewRemoved, context.frame, context.session,
                                 view.id, 0, last_position, 0.0, "view empty"});
      RemoveViewAt(it->second);
      ++stats.views_removed;
    }
  }
  // Look-back (look_back_frames): after the weights, so the new components are not
  // judged against mu_t, which lies ahead of them.
  if (options_.look_back_frames > 0) {
    if (!recent_updates_.empty() && recent_updates_.back().context.session != context.session) {
      recent_updates_.clear();
    }
    if (stats.view_inserted) AddLookBackComponents(inserted_id, context, &stats);
    recent_updates_.push_back(RecentUpdate{y, mu_t, c_t, context});
    while (recent_updates_.size() > static_cast<std::size_t>(options_.look_back_frames)) {
      recent_updates_.pop_front();
    }
  }
  return stats;
}

void EnvironmentModel::AddLookBackComponents(std::uint64_t view_id, const UpdateContext& context,
                                             UpdateStats* stats) {
  const std::optional<std::size_t> index = FindView(view_id);
  if (!index) return;  // removed again in this Update
  const std::vector<std::size_t> only = {*index};
  for (auto it = recent_updates_.rbegin(); it != recent_updates_.rend(); ++it) {
    if (context.frame - it->context.frame > options_.look_back_frames) break;
    const std::vector<ViewMatch> m = Search(it->y, 0, /*exhaustive=*/true, &only);
    if (m.empty()) break;  // the view's appearance ends here, going back
    ReferenceView& view = views_[*index];
    ViewComponent c;
    c.weight = options_.beta * m.front().similarity;  // one (16) confirmation from w = 0
    c.eta = m.front().similarity;
    c.mean = InViewFrame(it->mu, m.front().relative_heading_rad);
    c.covariance = it->covariance;
    view.footprint.Observe(it->mu.x(), it->mu.y(), m.front().similarity);
    AppendComponent(view, c, context, "look-back", stats);
  }
}

std::uint64_t EnvironmentModel::AppendComponent(ReferenceView& view, ViewComponent c, const UpdateContext& context,
                                                const char* reason, UpdateStats* stats) {
  c.id = next_component_id_++;
  view.components.push_back(c);
  spatial_.Insert(SpatialEntry{view.id, c.id, c.mean.x(), c.mean.y()});
  ++num_components_;
  ++stats->components_added;
  if (options_.log_component_events) {
    LogEvent(MapEvent{MapEventType::kComponentAdded, context.frame, context.session, view.id, c.id, c.mean,
                      c.weight, reason});
  }
  return c.id;
}

std::size_t EnvironmentModel::MemoryBytes() const {
  std::size_t bytes = features_.capacity() * sizeof(float);
  bytes += views_.capacity() * sizeof(ReferenceView);
  for (const ReferenceView& v : views_) {
    bytes += v.descriptor.features.capacity() * sizeof(float);
    bytes += v.descriptor.coefficients.capacity() * sizeof(std::complex<float>);
    bytes += v.components.capacity() * sizeof(ViewComponent);
  }
  bytes += index_of_id_.bucket_count() * sizeof(void*) +
           index_of_id_.size() * (sizeof(std::uint64_t) + sizeof(std::size_t) + 2 * sizeof(void*));
  bytes += spatial_.MemoryBytes();
  bytes += view_index_.MemoryBytes();
  bytes += ann_index_.MemoryBytes();
  bytes += events_.size() * sizeof(MapEvent);
  for (const RecentUpdate& r : recent_updates_) {
    bytes += sizeof(RecentUpdate) + r.y.features.capacity() * sizeof(float) +
             r.y.coefficients.capacity() * sizeof(std::complex<float>);
  }
  bytes += event_counts_.size() * (sizeof(int) + sizeof(MapEventCounts) + 4 * sizeof(void*));
  for (const MapEvent& e : events_) bytes += e.reason.capacity() > 15 ? e.reason.capacity() : 0;
  return bytes;
}

void EnvironmentModel::Serialize(BinaryWriter& out) const {
  out.Write(kModelMagic);
  out.Write(kModelVersion);
  out.Write(extractor_->kind());
  out.Write<std::uint64_t>(feature_size_);
  out.Write(next_view_id_);
  out.Write(next_component_id_);
  out.Write<std::uint64_t>(views_.size());
  for (const ReferenceView& v : views_) {
    out.Write(v.id);
    WriteDescriptorRecord(out, v.descriptor);
    out.Write(v.stats.created_frame);
    out.Write<std::int32_t>(v.stats.created_session);
    out.Write(v.stats.observations);
    out.Write(v.stats.last_seen_frame);
    out.Write<std::int32_t>(v.stats.last_seen_session);
    const ViewFootprint& f = v.footprint;
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
    out.Write<std::uint64_t>(v.components.size());
    for (const ViewComponent& c : v.components) {
      out.Write(c.id);
      out.Write(c.weight);
      out.Write(c.eta);
      WritePose(out, c.mean);
      for (int r = 0; r < 3; ++r)
        for (int q = 0; q < 3; ++q) out.Write(c.covariance(r, q));
    }
  }
  out.Write<std::uint64_t>(events_logged_);
  out.Write<std::uint64_t>(event_counts_.size());
  for (const auto& [session, n] : event_counts_) {
    out.Write<std::int32_t>(session);
    out.Write(n.views_inserted);
    out.Write(n.views_removed);
    out.Write(n.components_added);
    out.Write(n.components_merged);
    out.Write(n.components_removed);
  }
  out.Write<std::uint64_t>(events_.size());
  for (const MapEvent& e : events_) {
    out.Write(e.type);
    out.Write(e.frame);
    out.Write<std::int32_t>(e.session);
    out.Write(e.view_id);
    out.Write(e.component_id);
    WritePose(out, e.position);
    out.Write(e.weight);
    out.WriteString(e.reason);
  }
  // Version 4: the recent updates of the look-back, so that a run resumed from a saved
  // map (whose queued updates are applied after loading) equals one run.
  out.Write<std::uint64_t>(recent_updates_.size());
  for (const RecentUpdate& r : recent_updates_) {
    WriteDescriptorRecord(out, r.y);
    WritePose(out, r.mu);
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) out.Write(r.covariance(i, j));
    out.Write(r.context.frame);
    out.Write<std::int32_t>(r.context.session);
  }
}

EnvironmentModel EnvironmentModel::Deserialize(
    BinaryReader& in, const EnvironmentModelOptions& options,
    std::shared_ptr<const DescriptorExtractor> extractor) {
  EnvironmentModel model(options, std::move(extractor));
  if (in.Read<std::uint32_t>("environment model magic") != kModelMagic) {
    in.Fail("environment model magic", "not an environment model (bad magic number)");
  }
  const auto version = in.Read<std::uint32_t>("environment model version");
  if (version < 1 || version > kModelVersion) {
    in.Fail("environment model version", StrCat("unsupported environment model version ", version));
  }
  const auto kind = in.Read<std::uint8_t>("model descriptor kind");
  const auto feature_size = in.Read<std::uint64_t>("model feature size");
  if (kind != static_cast<std::uint8_t>(model.extractor_->kind()) ||
      feature_size != model.feature_size_) {
    in.Fail("model descriptor kind",
            StrCat("the stored model uses descriptor kind ", int{kind}, " with ", feature_size,
                   " features, the extractor gives kind ",
                   static_cast<int>(model.extractor_->kind()), " with ", model.feature_size_));
  }
  model.next_view_id_ = in.Read<std::uint64_t>("next view id");
  model.next_component_id_ = in.Read<std::uint64_t>("next component id");
  // Smallest possible view record: id, descriptor (kind, 2 counts, width), counters, count.
  const std::size_t num_views = in.ReadCount("views", 8 + 1 + 8 + 8 + 4 + 8 + 4 + 8 + 8 + 4 + 8);
  model.views_.reserve(num_views);
  for (std::size_t i = 0; i < num_views; ++i) {
    ReferenceView v;
    v.id = in.Read<std::uint64_t>("view id");
    v.descriptor = ReadDescriptorRecord(in);
    if (v.descriptor.kind != model.extractor_->kind() ||
        v.descriptor.features.size() != model.feature_size_) {
      in.Fail("view descriptor",
              StrCat("view ", v.id, " has a descriptor of another kind or length"));
    }
    v.stats.created_frame = in.Read<std::int64_t>("view created frame");
    v.stats.created_session = in.Read<std::int32_t>("view created session");
    v.stats.observations = in.Read<std::int64_t>("view observations");
    v.stats.last_seen_frame = in.Read<std::int64_t>("view last seen frame");
    v.stats.last_seen_session = in.Read<std::int32_t>("view last seen session");
    if (version >= 2) {
      ViewFootprint& f = v.footprint;
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
      if (!(f.weight >= 0) || !f.mean.allFinite() || !f.scatter.allFinite() ||
          f.scatter(0, 0) < 0 || f.scatter(1, 1) < 0 || f.missed_passes < 0 ||
          f.matched_passes < 0) {
        in.Fail("view footprint", StrCat("view ", v.id, " has an invalid footprint"));
      }
    }
    const std::size_t num_components = in.ReadCount("view components", 8 * 15);
    if (num_components == 0)
      in.Fail("view components", StrCat("view ", v.id, " has no components"));
    for (std::size_t j = 0; j < num_components; ++j) {
      ViewComponent c;
      c.id = in.Read<std::uint64_t>("component id");
      c.weight = in.Read<double>("component weight");
      c.eta = in.Read<double>("component eta");
      c.mean = ReadPose(in, "component mean");
      for (int r = 0; r < 3; ++r)
        for (int q = 0; q < 3; ++q) c.covariance(r, q) = in.Read<double>("component covariance");
      const bool spd = c.covariance.allFinite() && c.covariance == c.covariance.transpose() &&
                       Eigen::LLT<Eigen::Matrix3d>(c.covariance).info() == Eigen::Success;
      if (!(c.weight >= 0 && c.weight <= 1) || !(c.eta > 0) || !c.mean.allFinite() || !spd ||
          std::abs(c.mean.z()) > kPi) {
        in.Fail("component", StrCat("component ", c.id, " of view ", v.id, " has invalid values"));
      }
      v.components.push_back(c);
    }
    if (version < 2) v.footprint = FootprintFromComponents(v.components);
    model.views_.push_back(std::move(v));
  }
  if (version >= 3) {
    model.events_logged_ = in.Read<std::uint64_t>("events logged");
    const std::size_t sessions = in.ReadCount("event counts", 4 + 5 * 8);
    for (std::size_t i = 0; i < sessions; ++i) {
      const int session = in.Read<std::int32_t>("event counts session");
      MapEventCounts n;
      for (std::int64_t* c : {&n.views_inserted, &n.views_removed, &n.components_added,
                              &n.components_merged, &n.components_removed}) {
        *c = in.Read<std::int64_t>("event counts");
        if (*c < 0) in.Fail("event counts", StrCat("negative count for session ", session));
      }
      if (!model.event_counts_.emplace(session, n).second) {
        in.Fail("event counts", StrCat("session ", session, " appears twice"));
      }
    }
  }
  const std::size_t num_events = in.ReadCount("events", 1 + 8 + 4 + 8 + 8 + 24 + 8 + 8);
  if (version >= 3 && num_events > model.events_logged_) {
    in.Fail("events", StrCat(num_events, " events stored but only ", model.events_logged_,
                             " logged"));
  }
  for (std::size_t i = 0; i < num_events; ++i) {
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
    if (version < 3) {
      model.LogEvent(std::move(e));  // counts rebuilt from the (then complete) log
    } else {
      model.events_.push_back(std::move(e));
    }
  }
  if (version >= 4) {
    const std::size_t n = in.ReadCount("recent updates", 1 + 8 + 8 + 4 + 24 + 72 + 8 + 4);
    for (std::size_t i = 0; i < n; ++i) {
      RecentUpdate r;
      r.y = ReadDescriptorRecord(in);
      if (r.y.kind != model.extractor_->kind() || r.y.features.size() != model.feature_size_) {
        in.Fail("recent update descriptor", "a descriptor of another kind or length");
      }
      r.mu = ReadPose(in, "recent update pose");
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) r.covariance(a, b) = in.Read<double>("recent update covariance");
      r.context.frame = in.Read<std::int64_t>("recent update frame");
      r.context.session = in.Read<std::int32_t>("recent update session");
      if (!r.mu.allFinite() || !r.covariance.allFinite()) in.Fail("recent update", "non-finite pose or covariance");
      model.recent_updates_.push_back(std::move(r));
    }
    while (model.recent_updates_.size() > static_cast<std::size_t>(options.look_back_frames)) {
      model.recent_updates_.pop_front();
    }
  }
  // A model loaded with a smaller max_events keeps the most recent ones.
  while (model.events_.size() > static_cast<std::size_t>(options.max_events)) {
    model.events_.pop_front();
  }
  model.RebuildDerived();
  // Ids must be unique and below the next ids, or later insertions would collide.
  std::vector<std::uint64_t> view_ids, component_ids;
  for (const ReferenceView& v : model.views_) {
    view_ids.push_back(v.id);
    for (const ViewComponent& c : v.components) component_ids.push_back(c.id);
  }
  std::sort(view_ids.begin(), view_ids.end());
  std::sort(component_ids.begin(), component_ids.end());
  if (std::adjacent_find(view_ids.begin(), view_ids.end()) != view_ids.end() ||
      std::adjacent_find(component_ids.begin(), component_ids.end()) != component_ids.end() ||
      (!view_ids.empty() && view_ids.back() >= model.next_view_id_) ||
      (!component_ids.empty() && component_ids.back() >= model.next_component_id_)) {
    in.Fail("environment model", "duplicate or out-of-range view/component ids");
  }
  return model;
}

void EnvironmentModel::RebuildDerived() {
  features_.clear();
  features_.reserve(views_.size() * feature_size_);
  index_of_id_.clear();
  spatial_.Clear();
  num_components_ = 0;
  for (std::size_t i = 0; i < views_.size(); ++i) {
    const ReferenceView& v = views_[i];
    features_.insert(features_.end(), v.descriptor.features.begin(), v.descriptor.features.end());
    index_of_id_[v.id] = i;
    for (const ViewComponent& c : v.components) {
      spatial_.Insert(SpatialEntry{v.id, c.id, c.mean.x(), c.mean.y()});
      ++num_components_;
    }
  }
  view_index_.Clear();
  ann_index_.Clear();
  index_rejected_at_ = 0;
  index_bounded_fraction_ = -1.0;
  MaintainIndex();
}

void EnvironmentModel::CheckInvariants() const {
  OMNICML_CHECK(features_.size() == views_.size() * feature_size_) << "feature rows out of sync";
  OMNICML_CHECK(index_of_id_.size() == views_.size()) << "id map out of sync";
  std::size_t components = 0;
  std::vector<SpatialEntry> expected;
  for (std::size_t i = 0; i < views_.size(); ++i) {
    const ReferenceView& v = views_[i];
    OMNICML_CHECK(!v.components.empty()) << "view " << v.id << " is empty";
    OMNICML_CHECK(v.id < next_view_id_) << "view id " << v.id;
    const auto it = index_of_id_.find(v.id);
    OMNICML_CHECK(it != index_of_id_.end() && it->second == i) << "id map wrong for view " << v.id;
    OMNICML_CHECK(std::equal(v.descriptor.features.begin(), v.descriptor.features.end(),
                             features_.begin() + static_cast<std::ptrdiff_t>(i * feature_size_)))
        << "feature row of view " << v.id << " differs from its descriptor";
    for (const ViewComponent& c : v.components) {
      OMNICML_CHECK(c.weight >= 0.0 && c.weight <= 1.0) << "weight " << c.weight;
      OMNICML_CHECK(c.eta > 0.0) << "eta " << c.eta;
      OMNICML_CHECK(c.id < next_component_id_) << "component id " << c.id;
      expected.push_back(SpatialEntry{v.id, c.id, c.mean.x(), c.mean.y()});
      ++components;
    }
  }
  OMNICML_CHECK(components == num_components_) << "component count out of sync";
  std::sort(expected.begin(), expected.end(), [](const SpatialEntry& a, const SpatialEntry& b) {
    return a.view_id != b.view_id ? a.view_id < b.view_id : a.component_id < b.component_id;
  });
  OMNICML_CHECK(expected == spatial_.All()) << "spatial index out of sync";
  // The candidate index: present exactly when the options ask for it and it paid at its
  // last evaluation, holding every view once with its current row.
  const std::size_t threshold = static_cast<std::size_t>(options_.index_min_views);
  if (!index_supported_ || threshold == 0) {
    OMNICML_CHECK(!view_index_.built()) << "candidate index built although disabled";
  } else {
    if (views_.size() >= threshold && !view_index_.built()) {
      OMNICML_CHECK(index_rejected_at_ > 0 && views_.size() < 2 * index_rejected_at_)
          << "candidate index missing at " << views_.size() << " views";
    }
    if (2 * views_.size() < threshold) {
      OMNICML_CHECK(!view_index_.built()) << "candidate index kept below half the threshold";
    }
  }
  // The approximate graph: kept from the first view on whenever enabled, holding every
  // view once; searched only from ann_min_views views on.
  const std::size_t ann_threshold = static_cast<std::size_t>(options_.ann_min_views);
  if (!index_supported_ || ann_threshold == 0) {
    OMNICML_CHECK(!ann_index_.built()) << "approximate index built although disabled";
  } else {
    OMNICML_CHECK(views_.empty() || ann_index_.built())
        << "approximate index missing at " << views_.size() << " views";
  }
  if (ann_index_.built()) {
    std::vector<std::uint64_t> ids;
    for (const ReferenceView& v : views_) ids.push_back(v.id);
    std::sort(ids.begin(), ids.end());
    OMNICML_CHECK(ids == ann_index_.Ids()) << "approximate index out of sync";
  }
  if (view_index_.built()) {
    view_index_.CheckInvariants();
    std::vector<std::pair<std::uint64_t, std::size_t>> rows;
    for (std::size_t i = 0; i < views_.size(); ++i) rows.emplace_back(views_[i].id, i);
    std::sort(rows.begin(), rows.end());
    OMNICML_CHECK(rows == view_index_.Entries()) << "candidate index out of sync";
  }
}

// docs/design.md "Global pose graph": the view moves with its anchor node.
void EnvironmentModel::MoveViewRigidly(std::size_t view_index, const Pose2& old_anchor,
                                       const Pose2& new_anchor) {
  OMNICML_CHECK(view_index < views_.size()) << "MoveViewRigidly: no view " << view_index;
  ReferenceView& view = views_[view_index];
  const double dphi = WrapAngle(new_anchor.z() - old_anchor.z());
  const double c = std::cos(dphi);
  const double s = std::sin(dphi);
  Eigen::Matrix2d r;
  r << c, -s, s, c;
  Eigen::Matrix3d j = Eigen::Matrix3d::Identity();
  j.topLeftCorner<2, 2>() = r;
  const auto move_xy = [&](const Eigen::Vector2d& p) -> Eigen::Vector2d {
    return new_anchor.head<2>() + r * (p - old_anchor.head<2>());
  };
  for (ViewComponent& comp : view.components) {
    const Pose2 old = comp.mean;
    const Eigen::Vector2d xy = move_xy(old.head<2>());
    comp.mean = MakePose(xy.x(), xy.y(), old.z() + dphi);
    Eigen::Matrix3d cov = j * comp.covariance * j.transpose();
    comp.covariance = 0.5 * (cov + cov.transpose());
    spatial_.Move(view.id, comp.id, old.x(), old.y(), comp.mean.x(), comp.mean.y());
  }
  if (view.footprint.weight > 0) {
    view.footprint.mean = move_xy(view.footprint.mean);
    const Eigen::Matrix2d scatter = r * view.footprint.scatter * r.transpose();
    view.footprint.scatter = 0.5 * (scatter + scatter.transpose());
  }
}

}  // namespace omnicml
