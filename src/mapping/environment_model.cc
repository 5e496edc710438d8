#include "omnicml/mapping/environment_model.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <optional>
#include <utility>

#include <Eigen/Cholesky>
#include <Eigen/LU>

namespace omnicml {
namespace {

// [G] eqs. (12)-(14): merges `other` into `keep`. The pair's weights are eta_n and eta_m
// ([G]; shares eta_n / (eta_n + eta_m)), or with `precision_weighted` eta / sqrt(det C_xy),
// the share times the xy precision (EnvironmentModelOptions::Update::merge_precision_weighted).
// kMomentMatching: MomentMatch with the heading mean anchored at `keep`'s (the wrapped
// difference, not the circular mean). kCovarianceIntersection: CovarianceIntersection
// with omega = `other`'s share. kConvexCombination: MomentMatch's mean and, instead of
// (14), the smallest covariance of that mean that holds for any correlation of the pair
// (LinearCombinationBound). eta and w are summed (w clamped to 1 to stay a weight).
ViewComponent Merged(const ViewComponent& keep, const ViewComponent& other,
                     const EnvironmentModelOptions::Update& options) {
  double weight_keep = keep.eta, weight_other = other.eta;
  if (options.merge_precision_weighted) {
    // Covariances are SPD (checked on insertion and load), so the determinants are > 0.
    weight_keep /= std::sqrt(keep.covariance.topLeftCorner<2, 2>().determinant());
    weight_other /= std::sqrt(other.covariance.topLeftCorner<2, 2>().determinant());
  }
  const Gaussian pair[2] = {Gaussian{keep.mean, keep.covariance, weight_keep},
                            Gaussian{other.mean, other.covariance, weight_other}};
  const double weight_total = weight_keep + weight_other;
  const double weight_share = weight_total > 0 ? weight_other / weight_total : 0.5;  // other's
  Gaussian merged;
  if (options.merge_fusion == MergeFusion::kCovarianceIntersection) {
    merged = CovarianceIntersection(pair[0], pair[1], weight_share);
  } else {
    merged = MomentMatch(pair, HeadingMean::kAnchored);
    if (options.merge_fusion == MergeFusion::kConvexCombination) {
      merged.covariance = LinearCombinationBound(keep.covariance, 1.0 - weight_share,
                                                 other.covariance, weight_share);
    }
  }
  ViewComponent out = keep;
  out.covariance = merged.covariance;
  out.mean = merged.mean;
  // docs/design.md (S1): the spread about the merged mean, by eta shares (how often each
  // side matched), whatever weights gave the mean.
  const double eta_total = keep.eta + other.eta;
  const double share = eta_total > 0 ? other.eta / eta_total : 0.5;
  const Eigen::Vector2d dk = keep.mean.head<2>() - merged.mean.head<2>();
  const Eigen::Vector2d d_o = other.mean.head<2>() - merged.mean.head<2>();
  const Eigen::Matrix2d spread = (1.0 - share) * (keep.spread + dk * dk.transpose()) +
                                 share * (other.spread + d_o * d_o.transpose());
  out.spread = 0.5 * (spread + spread.transpose());
  out.eta += other.eta;
  out.weight = std::min(1.0, keep.weight + other.weight);
  return out;
}

// The component of `comps` other than `skip` closest to c by [G] (12)'s squared
// Mahalanobis distance, if below merge_delta; comps.size() otherwise.
std::size_t ClosestWithinDelta(const std::vector<ViewComponent>& comps, const ViewComponent& c,
                               std::size_t skip, double merge_delta) {
  std::size_t best = comps.size();
  double best_d2 = merge_delta;
  for (std::size_t j = 0; j < comps.size(); ++j) {
    if (j == skip) continue;
    const double d2 = SquaredMahalanobis(c.mean, comps[j].mean, c.covariance + comps[j].covariance);
    if (d2 < best_d2) {
      best_d2 = d2;
      best = j;
    }
  }
  return best;
}

const EnvironmentModelOptions& Validated(const EnvironmentModelOptions& options) {
  options.Validate();
  return options;
}

std::shared_ptr<const DescriptorExtractor> NonNull(std::shared_ptr<const DescriptorExtractor> e) {
  if (!e) throw Error("EnvironmentModel: the descriptor extractor is null");
  return e;
}

std::size_t FeatureSizeOf(const DescriptorExtractor& e) {
  const std::size_t n = e.FeatureSize();
  if (n == 0) throw Error("EnvironmentModel: the extractor's FeatureSize() is 0");
  return n;
}

bool IsSpd(const Eigen::Matrix3d& c) {
  return Eigen::LLT<Eigen::Matrix3d>(c).info() == Eigen::Success;
}

}  // namespace

EnvironmentModel::EnvironmentModel(const EnvironmentModelOptions& options,
                                   std::shared_ptr<const DescriptorExtractor> extractor)
    : options_(Validated(options)),
      extractor_(NonNull(std::move(extractor))),
      feature_size_(FeatureSizeOf(*extractor_)),
      store_(feature_size_, options_.index.spatial_cell_m),
      retrieval_(options_.retrieval, options_.index, extractor_),
      policy_(MakeForgettingPolicy(options_)),
      events_(options_.events.max_events) {}

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

void EnvironmentModel::SetForgettingMode(ForgettingMode mode) {
  options_.forgetting.mode = mode;
  policy_ = MakeForgettingPolicy(options_);
}

void EnvironmentModel::SetAnnSearch(int ef, int k) {
  if (ef < 1 || k < 1) throw Error("EnvironmentModel::SetAnnSearch: ef and k must be >= 1");
  options_.index.ann_ef = ef;
  options_.index.ann_k = k;
  retrieval_.SetAnnSearch(ef, k);
}

// ---- queries ------------------------------------------------------------------------

std::vector<ViewMatch> EnvironmentModel::FindMatches(const Descriptor& y) const {
  CheckDescriptor(y, "FindMatches");
  return retrieval_.Search(store_, y, options_.retrieval.top_k);
}

std::vector<ViewMatch> EnvironmentModel::FindAllMatches(const Descriptor& y) const {
  CheckDescriptor(y, "FindAllMatches");
  return retrieval_.Search(store_, y, 0);
}

std::vector<ViewMatch> EnvironmentModel::FindMatchesExhaustive(const Descriptor& y) const {
  CheckDescriptor(y, "FindMatchesExhaustive");
  return retrieval_.Search(store_, y, options_.retrieval.top_k, /*exhaustive=*/true);
}

std::vector<ViewMatch> EnvironmentModel::FindMatchesNear(const Descriptor& y,
                                                         const std::vector<Disc>& discs,
                                                         std::size_t* candidates) const {
  CheckDescriptor(y, "FindMatchesNear");
  const std::vector<std::size_t> only = RowsNear(discs);
  if (candidates != nullptr) *candidates = only.size();
  return retrieval_.Search(store_, y, options_.retrieval.top_k, /*exhaustive=*/false, &only);
}

std::vector<std::size_t> EnvironmentModel::RowsNear(const std::vector<Disc>& discs) const {
  std::vector<std::size_t> rows;
  for (const Disc& d : discs) {
    for (const SpatialEntry& e : store_.spatial().QueryRadius(d.x_m, d.y_m, d.radius_m)) {
      rows.push_back(store_.RowOf(e.view_id));
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
    if (m.view_index >= store_.size() || store_.view(m.view_index).id != m.view_id) {
      throw Error(StrCat("EnvironmentModel::Hypothesis: match of view ", m.view_id,
                         " is stale (the model changed since FindMatches)"));
    }
    for (const ViewComponent& c : store_.view(m.view_index).components) {
      // docs/design.md: weight w_ij * S_i, heading rotated by the relative heading.
      Gaussian g;
      g.mean = m.relative_heading_rad
                   ? MakePose(c.mean.x(), c.mean.y(), c.mean.z() + *m.relative_heading_rad)
                   : c.mean;
      g.covariance = EffectiveCovariance(c.covariance, m.relative_heading_rad,
                                         options_.retrieval.heading_sigma_no_rotation_rad);
      g.weight = c.weight * m.similarity;
      total += g.weight;
      out.push_back(g);
    }
  }
  if (!(total > 0.0)) return {};
  for (Gaussian& g : out) g.weight /= total;
  return out;
}

// ---- changes of the store -----------------------------------------------------------

std::size_t EnvironmentModel::InsertView(ReferenceView v) {
  const std::size_t row = store_.Insert(std::move(v));
  retrieval_.OnInsert(store_, row);
  retrieval_.Maintain(store_);
  return row;
}

void EnvironmentModel::RemoveViewAt(std::size_t row) {
  const ViewStore::Removal removal = store_.RemoveAt(row);
  retrieval_.OnRemove(removal.removed_id);
  if (removal.moved_id) retrieval_.OnRowMoved(*removal.moved_id, row);
  retrieval_.Maintain(store_);
}

std::uint64_t EnvironmentModel::AppendComponent(std::size_t row, const ViewComponent& c,
                                                const UpdateContext& context, const char* reason,
                                                UpdateStats* stats) {
  const std::uint64_t id = store_.AppendComponent(row, c);
  ++stats->components_added;
  if (options_.events.log_component_events) {
    events_.Log(MapEvent{MapEventType::kComponentAdded, context.frame, context.session,
                         store_.view(row).id, id, c.mean, c.weight, reason});
  }
  return id;
}

std::uint64_t EnvironmentModel::AddView(const Descriptor& y, std::vector<ViewComponent> components,
                                        const ViewStats& stats) {
  CheckDescriptor(y, "AddView");
  if (components.empty()) {
    throw Error("EnvironmentModel::AddView: a view needs at least one component");
  }
  for (std::size_t j = 0; j < components.size(); ++j) {
    const ViewComponent& c = components[j];
    const bool spd = c.covariance.allFinite() &&
                     c.covariance.isApprox(c.covariance.transpose(), 1e-9) && IsSpd(c.covariance);
    if (!(c.weight >= 0 && c.weight <= 1) || !(c.eta > 0) || !c.mean.allFinite() || !spd ||
        !IsValidSpread(c.spread)) {
      throw Error(StrCat("EnvironmentModel::AddView: component ", j,
                         " is invalid (weight in [0, 1], eta > 0, finite mean, SPD covariance, "
                         "symmetric positive semi-definite spread)"));
    }
  }
  ReferenceView v;
  v.descriptor = y;
  v.stats = stats;
  v.footprint = FootprintFromComponents(components);
  for (ViewComponent& c : components) {
    c.mean.z() = WrapAngle(c.mean.z());
    c.covariance = 0.5 * (c.covariance + c.covariance.transpose());  // exactly symmetric
  }
  v.components = std::move(components);
  const std::size_t row = store_.Insert(std::move(v));
  const ReferenceView& added = store_.view(row);
  events_.Log(MapEvent{MapEventType::kViewInserted, stats.created_frame, stats.created_session,
                       added.id, 0, added.components.front().mean, added.TotalWeight(), "added"});
  const std::uint64_t id = added.id;
  retrieval_.OnInsert(store_, row);
  retrieval_.Maintain(store_);
  return id;
}

// docs/design.md "Global pose graph": the view moves with its anchor node.
void EnvironmentModel::MoveViewRigidly(std::size_t view_index, const Pose2& old_anchor,
                                       const Pose2& new_anchor) {
  OMNICML_CHECK(view_index < store_.size()) << "MoveViewRigidly: no view " << view_index;
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
  const std::size_t n = store_.view(view_index).components.size();
  for (std::size_t k = 0; k < n; ++k) {
    ViewComponent comp = store_.view(view_index).components[k];
    const Eigen::Vector2d xy = move_xy(comp.mean.head<2>());
    comp.mean = MakePose(xy.x(), xy.y(), comp.mean.z() + dphi);
    const Eigen::Matrix3d cov = j * comp.covariance * j.transpose();
    comp.covariance = 0.5 * (cov + cov.transpose());
    const Eigen::Matrix2d spread = r * comp.spread * r.transpose();
    comp.spread = 0.5 * (spread + spread.transpose());
    store_.ReplaceComponent(view_index, k, comp);
  }
  ViewFootprint& footprint = store_.view(view_index).footprint;
  if (footprint.weight > 0) {
    footprint.mean = move_xy(footprint.mean);
    const Eigen::Matrix2d scatter = r * footprint.scatter * r.transpose();
    footprint.scatter = 0.5 * (scatter + scatter.transpose());
  }
}

void EnvironmentModel::SetComponentCovariance(std::size_t view_index, std::size_t k,
                                              const Eigen::Matrix3d& covariance) {
  OMNICML_CHECK(view_index < store_.size()) << "SetComponentCovariance: no view " << view_index;
  OMNICML_CHECK(k < store_.view(view_index).components.size())
      << "SetComponentCovariance: no component " << k << " in view " << view_index;
  ViewComponent comp = store_.view(view_index).components[k];
  comp.covariance = 0.5 * (covariance + covariance.transpose());
  OMNICML_CHECK(comp.covariance.allFinite() && IsSpd(comp.covariance))
      << "SetComponentCovariance: the covariance is not positive definite";
  store_.ReplaceComponent(view_index, k, comp);
}

// ---- Update: [G 2.3] in named phases ------------------------------------------------

UpdateStats EnvironmentModel::Update(const Descriptor& y, const Gaussian& estimate,
                                     const UpdateContext& context) {
  UpdateStats stats;
  CheckDescriptor(y, "Update");
  const Eigen::Matrix3d c_t = CheckedCovariance(estimate);
  if (!policy_->AdaptsMap()) return stats;  // static: the map never changes
  const Pose2 mu_t = MakePose(estimate.mean.x(), estimate.mean.y(), estimate.mean.z());

  std::vector<ViewMatch> matches = FindUpdateMatches(y, mu_t);
  stats.matching_views = static_cast<int>(matches.size());
  InsertIfUnmatched(y, mu_t, context, &matches, &stats);
  const std::optional<std::uint64_t> inserted_id =
      stats.view_inserted ? std::optional<std::uint64_t>(matches.front().view_id) : std::nullopt;
  const std::vector<std::uint64_t> fresh = AddObservations(matches, mu_t, c_t, context, &stats);

  // Phase 3: the weight rules of the forgetting policy.
  WeightChanges changes;
  const bool persistence = ViewPersistenceOn();
  if (persistence) persistence_.MaybeRefit();
  policy_->Apply(WeightUpdate{&matches, mu_t, c_t, context}, store_, &changes);
  if (persistence) {
    for (const PassOutcomes& o : changes.pass_outcomes) RecordPassOutcomes(o);
    open_unmatched_.insert(changes.expected_unmatched.begin(), changes.expected_unmatched.end());
    ClosePersistencePasses(context, &changes);
  }
  stats.components_increased += changes.increased;
  stats.components_passive_forgotten += changes.passive_forgotten;
  stats.components_active_forgotten += changes.active_forgotten;

  RemoveWeakComponents(changes, fresh, mu_t, context, &stats);
  // After the weights, so the look-back's components are not judged against mu_t, which
  // lies ahead of them.
  LookBack(y, mu_t, c_t, context, inserted_id, &stats);
  return stats;
}

Eigen::Matrix3d EnvironmentModel::CheckedCovariance(const Gaussian& estimate) const {
  if (!estimate.mean.allFinite())
    throw Error("EnvironmentModel::Update: the estimate's mean is not finite");
  if (!estimate.covariance.allFinite())
    throw Error("EnvironmentModel::Update: the estimate's covariance is not finite");
  const Eigen::Matrix3d c_t = 0.5 * (estimate.covariance + estimate.covariance.transpose());
  if (!IsSpd(c_t) || !(c_t(0, 0) > 0) || !(c_t(1, 1) > 0)) {
    throw Error("EnvironmentModel::Update: the estimate's covariance is not positive definite");
  }
  return c_t;
}

std::vector<ViewMatch> EnvironmentModel::FindUpdateMatches(const Descriptor& y,
                                                           const Pose2& mu_t) const {
  std::vector<ViewMatch> matches = retrieval_.Search(store_, y, 0);
  if (!AnnActive()) return matches;
  // The graph can miss a match (recall < 1). The views with a component within d_for of
  // mu_t are the ones rule (18) would weaken as "expected here but not matching", so they
  // get the exact distance whatever the graph returned: near the robot the Update is the
  // exact scan's; only far-away (aliased) matches may be missed.
  std::vector<std::size_t> rows = RowsNear({{mu_t.x(), mu_t.y(), options_.forgetting.d_for_m}});
  std::vector<std::size_t> found;
  for (const ViewMatch& m : matches) found.push_back(m.view_index);
  std::sort(found.begin(), found.end());
  std::erase_if(rows,
                [&](std::size_t r) { return std::binary_search(found.begin(), found.end(), r); });
  if (rows.empty()) return matches;
  // Both lists are in MatchBefore order: merge them.
  const std::vector<ViewMatch> extra = retrieval_.Search(store_, y, 0, /*exhaustive=*/false, &rows);
  const auto middle = static_cast<std::ptrdiff_t>(matches.size());
  matches.insert(matches.end(), extra.begin(), extra.end());
  std::inplace_merge(matches.begin(), matches.begin() + middle, matches.end(), MatchBefore);
  return matches;
}

void EnvironmentModel::InsertIfUnmatched(const Descriptor& y, const Pose2& mu_t,
                                         const UpdateContext& context,
                                         std::vector<ViewMatch>* matches, UpdateStats* stats) {
  // Phase 1 ([G 2.3]): insertion iff E(y_t, y_i) >= E_max for every view i.
  if (!matches->empty()) return;
  ReferenceView v;
  v.descriptor = y;
  v.stats.created_frame = context.frame;
  v.stats.created_session = context.session;
  v.stats.last_seen_frame = context.frame;
  v.stats.last_seen_session = context.session;
  const std::size_t row = InsertView(std::move(v));
  const std::uint64_t id = store_.view(row).id;
  events_.Log(MapEvent{MapEventType::kViewInserted, context.frame, context.session, id, 0, mu_t,
                       0.0, "no view within e_max"});
  stats->view_inserted = true;
  ViewMatch self;
  self.view_index = row;
  self.view_id = id;
  self.distance = 0.0;
  self.similarity = 1.0;
  if (extractor_->ProvidesHeading()) self.relative_heading_rad = 0.0;
  matches->push_back(self);
}

std::vector<std::uint64_t> EnvironmentModel::AddObservations(const std::vector<ViewMatch>& matches,
                                                             const Pose2& mu_t,
                                                             const Eigen::Matrix3d& c_t,
                                                             const UpdateContext& context,
                                                             UpdateStats* stats) {
  // Phase 2: one component per matching view, w = 0 and eta = S_i / sum_l S_l (our
  // reading of [G] (11)), then merging of components closer than delta (12).
  double sum_s = 0.0;
  for (const ViewMatch& m : matches) sum_s += m.similarity;
  std::vector<std::uint64_t> fresh;  // components created by this Update, kept separate
  for (const ViewMatch& m : matches) {
    ReferenceView& view = store_.view(m.view_index);
    view.stats.observations += 1;
    view.stats.last_seen_frame = context.frame;
    view.stats.last_seen_session = context.session;
    view.footprint.Observe(mu_t.x(), mu_t.y(), m.similarity);
    const PassOutcomes outcomes =
        view.footprint.NoteExpected(context, /*matched=*/true, options_.forgetting.pass_gap_frames);
    if (ViewPersistenceOn()) RecordPassOutcomes(outcomes);

    ViewComponent added;
    added.weight = 0.0;
    added.eta = m.similarity / sum_s;  // [G] (11)
    added.mean = InViewFrame(mu_t, m.relative_heading_rad);
    added.covariance = c_t;
    const std::size_t k = ClosestWithinDelta(view.components, added, view.components.size(),
                                             options_.update.merge_delta);
    if (k == view.components.size()) {
      fresh.push_back(AppendComponent(m.view_index, added, context, "observation", stats));
    } else {
      ++stats->components_merged;
      MergeObservation(m.view_index, k, added, context);
    }
  }
  std::sort(fresh.begin(), fresh.end());
  return fresh;
}

void EnvironmentModel::MergeObservation(std::size_t row, std::size_t k, const ViewComponent& added,
                                        const UpdateContext& context) {
  const std::vector<ViewComponent>& comps = store_.view(row).components;
  const std::uint64_t view_id = store_.view(row).id;
  auto log_merge = [&](const ViewComponent& c) {
    if (!options_.events.log_component_events) return;
    events_.Log(MapEvent{MapEventType::kComponentMerged, context.frame, context.session, view_id,
                         c.id, c.mean, c.weight, "merge (12)-(14)"});
  };
  // [G] (12)-(14): the new component merges into component k; the moved result may now
  // be within delta of another one, which is merged in turn (the earlier one in storage
  // order survives), until no pair involving it is closer than delta.
  store_.ReplaceComponent(row, k, Merged(comps[k], added, options_.update));
  log_merge(comps[k]);
  for (;;) {
    const std::size_t j = ClosestWithinDelta(comps, comps[k], k, options_.update.merge_delta);
    if (j == comps.size()) break;
    const std::size_t keep = std::min(j, k), drop = std::max(j, k);
    const ViewComponent merged = Merged(comps[keep], comps[drop], options_.update);
    store_.EraseComponent(row, drop);
    store_.ReplaceComponent(row, keep, merged);
    log_merge(comps[keep]);
    k = keep;
  }
}

bool EnvironmentModel::ViewPersistenceOn() const {
  // Only active forgetting observes the passes that miss; counting matches alone
  // (passive) would make every place look permanent.
  return options_.forgetting.persistence_min_probability > 0 &&
         options_.forgetting.mode == ForgettingMode::kActive;
}

void EnvironmentModel::RecordPassOutcomes(const PassOutcomes& o) {
  if (o.closed_missed_run >= 0) persistence_.Record(o.closed_missed_run, false);
  if (o.matched_run >= 0) persistence_.Record(o.matched_run, true);
}

void EnvironmentModel::ClosePersistencePasses(const UpdateContext& context,
                                              WeightChanges* changes) {
  // A pass ends when the view has not been expected for more than pass_gap_frames frames
  // (or the session changed): only then is it known that the view missed the whole pass,
  // and the belief after one more missed pass decides (docs/design.md "View persistence").
  for (auto it = open_unmatched_.begin(); it != open_unmatched_.end();) {
    const std::optional<std::size_t> row = store_.Find(*it);
    if (!row) {
      it = open_unmatched_.erase(it);
      continue;
    }
    ReferenceView& view = store_.view(*row);
    const ViewFootprint& f = view.footprint;
    if (f.pass_matched) {
      it = open_unmatched_.erase(it);
      continue;
    }
    if (!f.PassEnded(context, options_.forgetting.pass_gap_frames)) {
      ++it;
      continue;
    }
    if (persistence_.UpperExistence(f.missed_passes + 1) <
        options_.forgetting.persistence_min_probability) {
      for (ViewComponent& c : view.components) {
        c.weight = 0.0;
        changes->last_rule[c.id] = WeightRule::kPersistence;
      }
      changes->touched_views.push_back(view.id);
    }
    it = open_unmatched_.erase(it);
  }
}

void EnvironmentModel::RemoveWeakComponents(const WeightChanges& changes,
                                            const std::vector<std::uint64_t>& fresh,
                                            const Pose2& mu_t, const UpdateContext& context,
                                            UpdateStats* stats) {
  // Components below w_min (except those created by this Update), then views whose
  // mixture is empty. Only views touched by the weight rules can hold such components.
  for (const std::uint64_t view_id : changes.touched_views) {
    const std::optional<std::size_t> row = store_.Find(view_id);
    if (!row) continue;
    const std::vector<ViewComponent>& comps = store_.view(*row).components;
    Pose2 last_position = comps.empty() ? mu_t : comps.back().mean;
    for (std::size_t j = 0; j < comps.size();) {
      const ViewComponent& c = comps[j];
      if (c.weight >= options_.update.w_min ||
          std::binary_search(fresh.begin(), fresh.end(), c.id)) {
        ++j;
        continue;
      }
      const auto rule = changes.last_rule.find(c.id);
      events_.Log(MapEvent{
          MapEventType::kComponentRemoved, context.frame, context.session, view_id, c.id, c.mean,
          c.weight,
          RemovalReason(rule == changes.last_rule.end() ? WeightRule::kNone : rule->second)});
      last_position = c.mean;
      store_.EraseComponent(*row, j);
      ++stats->components_removed;
    }
    if (comps.empty()) {
      events_.Log(MapEvent{MapEventType::kViewRemoved, context.frame, context.session, view_id, 0,
                           last_position, 0.0, "view empty"});
      RemoveViewAt(*row);
      ++stats->views_removed;
    }
  }
}

void EnvironmentModel::LookBack(const Descriptor& y, const Pose2& mu_t, const Eigen::Matrix3d& c_t,
                                const UpdateContext& context,
                                std::optional<std::uint64_t> inserted_id, UpdateStats* stats) {
  const int frames = options_.update.look_back_frames;
  if (frames <= 0) return;
  if (!recent_updates_.empty() && recent_updates_.back().context.session != context.session) {
    recent_updates_.clear();
  }
  const std::optional<std::size_t> row = inserted_id ? store_.Find(*inserted_id) : std::nullopt;
  if (row) {  // not when removed again in this Update
    const std::vector<std::size_t> only = {*row};
    for (auto it = recent_updates_.rbegin(); it != recent_updates_.rend(); ++it) {
      if (context.frame - it->context.frame > frames) break;
      const std::vector<ViewMatch> m =
          retrieval_.Search(store_, it->y, 0, /*exhaustive=*/true, &only);
      if (m.empty()) break;  // the view's appearance ends here, going back
      ViewComponent c;
      c.weight = options_.update.beta * m.front().similarity;  // one (16) confirmation from 0
      c.eta = m.front().similarity;
      c.mean = InViewFrame(it->mu, m.front().relative_heading_rad);
      c.covariance = it->covariance;
      store_.view(*row).footprint.Observe(it->mu.x(), it->mu.y(), m.front().similarity);
      AppendComponent(*row, c, context, "look-back", stats);
    }
  }
  recent_updates_.push_back(RecentUpdate{y, mu_t, c_t, context});
  while (recent_updates_.size() > static_cast<std::size_t>(frames)) recent_updates_.pop_front();
}

// ---- checks and sizes ---------------------------------------------------------------

void EnvironmentModel::CheckInvariants() const {
  store_.CheckInvariants();
  retrieval_.CheckInvariants(store_);
  OMNICML_CHECK(events_.events().size() <= static_cast<std::size_t>(options_.events.max_events))
      << "event ring beyond max_events";
}

std::size_t EnvironmentModel::MemoryBytes() const {
  std::size_t bytes = store_.MemoryBytes() + retrieval_.MemoryBytes() + events_.MemoryBytes();
  for (const RecentUpdate& r : recent_updates_) {
    bytes += sizeof(RecentUpdate) + r.y.features.capacity() * sizeof(float) +
             r.y.coefficients.capacity() * sizeof(std::complex<float>);
  }
  return bytes;
}

}  // namespace omnicml
