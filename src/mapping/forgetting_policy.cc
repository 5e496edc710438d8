#include "omnicml/mapping/forgetting_policy.h"

#include <algorithm>
#include <cmath>

#include "omnicml/geometry/gaussian_mixture.h"

namespace omnicml {

const char* RemovalReason(WeightRule rule) {
  switch (rule) {
    case WeightRule::kPassive:
      return "passive forgetting (17)";
    case WeightRule::kActive:
      return kActiveForgettingReason;
    case WeightRule::kPersistence:
      return kPersistenceReason;
    default:
      return "weight below w_min";
  }
}

PassiveForgetting::PassiveForgetting(const EnvironmentModelOptions& options)
    : beta_(options.update.beta),
      d_max_(options.update.d_max),
      heading_sigma_no_rotation_rad_(options.retrieval.heading_sigma_no_rotation_rad) {}

void PassiveForgetting::Apply(const WeightUpdate& update, ViewStore& store,
                              WeightChanges* changes) const {
  for (const ViewMatch& m : *update.matches) {
    ReferenceView& view = store.view(m.view_index);
    changes->touched_views.push_back(view.id);
    const Pose2 mu_view = InViewFrame(update.mu_t, m.relative_heading_rad);
    const double beta_s = beta_ * m.similarity;
    for (ViewComponent& c : view.components) {
      const Eigen::Matrix3d s =
          update.c_t +
          EffectiveCovariance(c.covariance, m.relative_heading_rad, heading_sigma_no_rotation_rad_);
      // [G] eq. (15): Mahalanobis distance of mu_t to the component.
      const double d = std::sqrt(SquaredMahalanobis(mu_view, c.mean, s));
      if (d <= d_max_) {
        // [G] eq. (16): weight increase.
        c.weight = beta_s + (1.0 - beta_s) * c.weight;
        changes->last_rule[c.id] = WeightRule::kIncrease;
        ++changes->increased;
      } else {
        // [G] eq. (17): passive forgetting.
        c.weight = (1.0 - beta_s) * c.weight;
        changes->last_rule[c.id] = WeightRule::kPassive;
        ++changes->passive_forgotten;
      }
    }
  }
}

ActiveFootprintForgetting::ActiveFootprintForgetting(const EnvironmentModelOptions& options)
    : passive_(options), options_(options.forgetting) {}

void ActiveFootprintForgetting::Apply(const WeightUpdate& update, ViewStore& store,
                                      WeightChanges* changes) const {
  passive_.Apply(update, store, changes);
  std::vector<std::uint64_t> matched_ids;
  for (const ViewMatch& m : *update.matches) matched_ids.push_back(m.view_id);
  std::sort(matched_ids.begin(), matched_ids.end());
  // Candidates: views with a component within d_for of mu_t (spatial grid, entries
  // sorted by view id, then component id), visited a view at a time.
  const std::vector<SpatialEntry> near =
      store.spatial().QueryRadius(update.mu_t.x(), update.mu_t.y(), options_.d_for_m);
  for (std::size_t first = 0; first < near.size();) {
    std::size_t last = first;
    while (last < near.size() && near[last].view_id == near[first].view_id) ++last;
    const std::uint64_t view_id = near[first].view_id;
    const std::size_t begin = first;
    first = last;
    if (std::binary_search(matched_ids.begin(), matched_ids.end(), view_id)) {
      continue;  // E_i < E_max
    }
    if (ForgetView(update, store.RowOf(view_id), near, begin, last, store, changes)) {
      changes->touched_views.push_back(view_id);
    }
  }
}

bool ActiveFootprintForgetting::ForgetView(const WeightUpdate& update, std::size_t row,
                                           const std::vector<SpatialEntry>& entries,
                                           std::size_t begin, std::size_t end, ViewStore& store,
                                           WeightChanges* changes) const {
  ReferenceView& view = store.view(row);
  ViewFootprint& footprint = view.footprint;
  const Eigen::Matrix2d c_xy = update.c_t.topLeftCorner<2, 2>();
  const Eigen::Vector2d mu_xy(update.mu_t.x(), update.mu_t.y());
  // docs/forgetting.md: the view is expected to match only where mu_t lies inside its
  // footprint (the spread of the estimates at which it matched), widened by C_t.
  const double d_fp = std::sqrt(footprint.SquaredDistance(mu_xy, c_xy + footprint.Covariance()));
  if (!(d_fp < options_.footprint_gate)) return false;
  // Confidently inside: the robot's position uncertainty must not exceed the footprint's
  // own extent (largest standard deviations compared), else a miss says nothing.
  const double confidence = options_.footprint_confidence;
  if (confidence > 0 && LargestEigenvalue2(c_xy) >
                            confidence * confidence * LargestEigenvalue2(footprint.Covariance())) {
    return false;
  }
  changes->pass_outcomes.push_back(
      footprint.NoteExpected(update.context, /*matched=*/false, options_.pass_gap_frames));
  changes->expected_unmatched.push_back(view.id);
  // Evidence over passes: only after forget_min_missed_passes whole passes through the
  // footprint without a match does a miss weaken the view; a view made in this session
  // and seen on its creation pass only, from the first pass that misses it.
  const bool unconfirmed = options_.forget_unconfirmed_views &&
                           view.stats.created_session == update.context.session &&
                           footprint.matched_passes == 1 && !footprint.pass_matched;
  if (footprint.missed_passes < options_.forget_min_missed_passes && !unconfirmed) return false;
  // [G] eq. (19) with d_xy / d_for replaced by the footprint distance d_fp / gate:
  // b = beta_for max(1 - d_fp / gate, 0) d_gain / (sigma_x + sigma_y), in [0, 1].
  const double sigma_sum_m = std::sqrt(update.c_t(0, 0)) + std::sqrt(update.c_t(1, 1));
  double b = std::clamp(options_.beta_for * std::max(1.0 - d_fp / options_.footprint_gate, 0.0) *
                            options_.d_gain_m / sigma_sum_m,
                        0.0, 1.0);
  // Evidence against a place grows with the evidence for it: a view that matched in k
  // passes loses weight k times more slowly than a view seen once.
  if (options_.forget_by_matched_passes && footprint.matched_passes > 1) {
    b /= static_cast<double>(footprint.matched_passes);
  }
  for (std::size_t k = begin; k < end; ++k) {
    for (ViewComponent& c : view.components) {
      if (c.id != entries[k].component_id) continue;
      // [G] eq. (18): active forgetting.
      c.weight = (1.0 - b) * c.weight;
      changes->last_rule[c.id] = WeightRule::kActive;
      if (b > 0) ++changes->active_forgotten;
      break;
    }
  }
  return true;
}

std::shared_ptr<const ForgettingPolicy> MakeForgettingPolicy(
    const EnvironmentModelOptions& options) {
  switch (options.forgetting.mode) {
    case ForgettingMode::kActive:
      return std::make_shared<const ActiveFootprintForgetting>(options);
    case ForgettingMode::kPassive:
      return std::make_shared<const PassiveForgetting>(options);
    case ForgettingMode::kStatic:
      return std::make_shared<const StaticForgetting>();
  }
  throw Error("MakeForgettingPolicy: unknown forgetting mode");
}

}  // namespace omnicml
