// Options of the environment model (environment_model.h), in five sections: retrieval
// (which views match a descriptor), update (the mixture update of [G 2.3] phases 1-2 and
// rule (16)-(17)'s constants), forgetting (which weight rules run, and the active rule
// (18)-(19)), index (the spatial grid and the exact and approximate retrieval indexes)
// and events (the event log). Defaults are the engine's (CmlEngineOptions::model); the
// measurements behind them are in docs/design.md "Defaults and their measurements" and
// docs/results.md.
//
// YAML: `model: {retrieval: {e_max: 0.45}, forgetting: {mode: passive}}`. The flat keys
// of the former layout (`model: {e_max: 0.45, forgetting: passive}`) still load, with
// one deprecation warning line on stderr naming their new places.
#ifndef OMNICML_MAPPING_ENVIRONMENT_MODEL_OPTIONS_H_
#define OMNICML_MAPPING_ENVIRONMENT_MODEL_OPTIONS_H_

#include <cstdint>
#include <string>

#include "omnicml/common/common.h"
#include "omnicml/common/options.h"

namespace omnicml {

// Which weight rules of [G 2.3] phase 3 run (docs/design.md "Modes"; forgetting_policy.h).
enum class ForgettingMode : std::uint8_t {
  kActive = 0,   // insertion, mixture update, (16), (17) and active forgetting (18)-(19)
  kPassive = 1,  // insertion, mixture update, (16) and (17) only, as in [PK]
  kStatic = 2,   // Update never changes the model (baseline: a map that does not adapt)
};
// "active", "passive", "static".
std::string ToString(ForgettingMode mode);
// Throws omnicml::Error on any other name.
ForgettingMode ForgettingModeFromString(const std::string& name);

// How two components of one view are merged ([G] (12)-(14); docs/design.md "Environment
// model").
enum class MergeFusion : std::uint8_t {
  // [G] (13)-(14): the pair as a two-component mixture, moment matched: the weighted mean
  // of the covariances plus the spread of the means.
  kMomentMatching = 0,
  // The pair as two estimates of one place with unknown correlation: covariance
  // intersection (Julier & Uhlmann 1997) with the merge weights as the shares.
  kCovarianceIntersection = 1,
  // The pair as two estimates of one place with unknown correlation, combined linearly:
  // [G] (13)'s weighted mean s_n mu_n + s_m mu_m, and for (14) the covariance of that
  // mean's error that holds whatever the correlation, the smallest (in determinant) of
  // (1 + k) s_n^2 C_n + (1 + 1/k) s_m^2 C_m over k > 0 (LinearCombinationBound in
  // geometry/gaussian_mixture.h): C when C_n = C_m = C, determinant at most that of
  // s_n C_n + s_m C_m, no spread of the means. Unlike kCovarianceIntersection the mean
  // moves by the merge weights alone, not by the weights times the covariances.
  kConvexCombination = 2,
};

struct EnvironmentModelOptions {
  // Which views match a descriptor, and how their components form p(x|y).
  struct Retrieval {
    // Descriptor distance at which the similarity S reaches 0 (S = max(0, 1 - E / e_max));
    // views with E < e_max match, and y_t becomes a new view iff E >= e_max for every
    // view. In units of the extractor's Distance: tune it per descriptor (the default
    // suits the default Fourier signature on the simulator's panoramas). Must be > 0.
    double e_max = 0.45;
    // Hypothesis uses at most the top_k most similar matching views; 0 = all of them.
    // Update always uses every matching view. Must be >= 0.
    int top_k = 8;
    // Descriptors without heading information (histograms; RelativeHeading = nullopt):
    // stored headings are used as they are, and wherever a component is compared with or
    // returned for a query, heading_sigma_no_rotation_rad^2 is added to its heading
    // variance so that the heading of such a hypothesis carries little weight.
    // Radians, > 0.
    double heading_sigma_no_rotation_rad = kPi;
  };

  // [G 2.3] phases 1-2 and the constants of rules (16)-(17).
  struct Update {
    // [G] (16)-(17) learning rate beta, dimensionless, in (0, 1].
    double beta = 0.2;
    // [G] (15): a component is confirmed (rule 16) iff its Mahalanobis distance d to mu_t
    // under C_t + C_ij is <= d_max, otherwise it decays (rule 17). d is the square root
    // of the quadratic form (NOT squared), dimensionless. Must be > 0.
    double d_max = 3.0;
    // Components whose weight falls below w_min after phase 3 are removed, and views left
    // without components are removed. Dimensionless, in [0, 1).
    //
    // A component added by the current Update starts at w = 0 and (16) raises it to
    // beta * S_i; it is exempt from this removal during the Update that created it, so a
    // weak first match (beta * S_i < w_min) is not deleted on sight. Removal is checked
    // in the views an Update touches (matching views, and with active forgetting the
    // views with a component within d_for_m of mu_t); weights change nowhere else, so
    // such a weak component is removed by the next Update that touches its view and
    // leaves it below.
    double w_min = 0.01;
    // [G] (12): two components of one view merge when their squared Mahalanobis distance
    // under C_n + C_m is below merge_delta (squared, dimensionless, as
    // TrackerOptions::delta). Must be >= 0 (0 disables merging). Components are compared
    // in the view's own frame with their stored covariances. A merge sums eta and w (w
    // capped at 1) and takes the weighted mean and covariance (13)-(14), the weights set
    // by merge_precision_weighted, and the spread about the merged mean by eta shares
    // (ViewComponent::spread; docs/design.md "Spread of a component", (S1)).
    double merge_delta = 1.0;
    // Weights of the merge (13)-(14): false = [G]'s shares eta_n and eta_m; true = eta
    // times the component's xy precision, eta / sqrt(det C_xy) (1 / sigma^2 for a round
    // covariance), so a component known to centimetres (a survey pose, or many confident
    // matches) is not dragged by one uncertain estimate the way an eta-share drags it.
    // eta is summed either way.
    bool merge_precision_weighted = true;
    // How a merge combines the pair's means and covariances. kMomentMatching is [G]
    // (13)-(14): the merged covariance is the weighted mean of the two plus the spread of
    // the means, so a component that keeps being confirmed by estimates that scatter
    // around it widens with every merge, and the estimates localized against it, stored
    // back into the map, widen the next ones. kCovarianceIntersection reads the two as
    // estimates of the same place whose errors are correlated (both come from poses
    // localized against this map): C = (s_n C_n^-1 + s_m C_m^-1)^-1 and the matching
    // mean, s_n, s_m the merge weights normalised to sum 1. It is consistent for any
    // correlation and never wider than the wider of the two. kConvexCombination (the
    // default) keeps (13)'s mean with a covariance that is as consistent (wider than
    // covariance intersection's when the pair's covariances differ); its mean does not
    // weight the pair by covariances that may say little about their errors.
    MergeFusion merge_fusion = MergeFusion::kConvexCombination;
    // Look-back (an addition to [G 2.3], docs/design.md "Environment model"): a view made
    // at frame t is also given a component at each of the preceding updates of the same
    // session, newest first, whose descriptor matches it (E < e_max), stopping at the
    // first that does not and at most look_back_frames frames back. Without it a view's
    // mixture only holds poses from its creation on (nothing could match it before), so
    // it lies ahead of the view along the direction of travel and p(x|y) pulls estimates
    // forward. Each such component is one [G] (16) confirmation from w = 0: weight
    // beta * S, eta S, the update's pose and covariance. Frames, >= 0 (0: off). The
    // recent updates (at most look_back_frames, of the current session) are saved with
    // the model, so a run resumed from a saved map equals one run.
    int look_back_frames = 50;
  };

  // Which weight rules run (forgetting_policy.h) and the active rule (18)-(19).
  struct Forgetting {
    ForgettingMode mode = ForgettingMode::kActive;
    // [G] (18)-(19): active forgetting considers components of non-matching views whose
    // xy position is closer than d_for_m to mu_t (Euclidean, metres), then keeps only
    // views whose footprint holds mu_t (footprint_gate). Must be > 0.
    double d_for_m = 0.5;
    // [G] (19) gain beta_for, dimensionless, >= 0.
    double beta_for = 0.7;
    // [G] (19) d_gain in metres: b = beta_for * max(1 - d / footprint_gate, 0) * d_gain /
    // (sigma_x + sigma_y) with sigma_x, sigma_y the standard deviations (m) of C_t, so
    // the fraction is dimensionless; b is clamped to [0, 1]. A confident estimate (small
    // sigma) forgets faster than an uncertain one. Must be >= 0.
    double d_gain_m = 1.0;
    // Rule (18) weakens a non-matching view only where it is expected to match
    // (docs/forgetting.md): mu_t's Mahalanobis distance to the view's footprint (the
    // spread of the estimates at which it matched) under footprint covariance + C_t must
    // be below footprint_gate (dimensionless, > 0), and the view must have missed
    // forget_min_missed_passes whole passes through its footprint in a row (>= 0; 0 lets
    // the first miss count). (19)'s factor 1 - d_xy / d_for becomes 1 - d / footprint_gate;
    // d_for_m is only the radius in which candidates are looked up.
    double footprint_gate = 2.0;
    int forget_min_missed_passes = 1;
    // Two Updates in which a view is expected belong to one pass through its footprint
    // when at most pass_gap_frames frames apart in the same session. Frames, >= 0.
    int pass_gap_frames = 25;
    // Forget only when the robot is confident relative to the footprint: the largest
    // standard deviation of C_t's xy part at most footprint_confidence times the
    // footprint's largest standard deviation (dimensionless, >= 0; 0 disables the check).
    double footprint_confidence = 0.0;
    // Divide (19)'s b by the number of passes in which the view matched, so a place seen
    // on many passes needs as many missed passes to fade as one seen once needs
    // (docs/forgetting.md).
    bool forget_by_matched_passes = true;
    // Unconfirmed views (docs/forgetting.md "Unconfirmed views"): a view made in the
    // current session that has matched on its creation pass only (matched_passes == 1) is
    // weakened by (18) from the first pass through its footprint in which it does not
    // match, without the forget_min_missed_passes whole passes an established view gets,
    // as ORB-SLAM culls recent map points that the next keyframes do not find again. A
    // view that matched on two passes, or one made in an earlier session (its next pass
    // is on another day), keeps the grace.
    bool forget_unconfirmed_views = true;
    // View persistence (docs/forgetting.md "View persistence", view_persistence.h): when a
    // pass through a view's footprint closes without a match and the belief that its place
    // still looks like it (the 95 % upper posterior bound of P(exists | missed run), with
    // the hazard and miss probability estimated from the map's own passes) is below this
    // probability, the whole view is removed. A probability in [0, 1); 0 disables. 0.5:
    // remove a view whose place more likely changed for good than not, at the upper end
    // of what the map's history allows.
    double persistence_min_probability = 0.5;
  };

  // The spatial grid over component positions and the retrieval indexes
  // (docs/design.md "Place retrieval at scale"; view_retrieval.h).
  struct Index {
    // Cell size of the spatial grid over component positions, metres, > 0. About
    // d_for_m / 2 to d_for_m is a good choice.
    double spatial_cell_m = 1.0;
    // Exact candidate index (view_index.h: PCA projection lower bound + kd-tree, then the
    // exact distance for the candidates only), for distances that are at least the L2
    // norm of the feature difference (Fourier L2 or L1, colour-histogram L1 or L2); the
    // results equal the exhaustive scan's. Built once the map holds index_min_views views
    // (views, >= 0; 0 never builds it) and dropped below half of that.
    int index_min_views = 1000;
    // ... and kept only while it pays: when it is built (and when the map has doubled
    // since), the fraction of views whose bound it must compute is estimated with 32
    // stored views (evenly spaced rows) as queries; above index_max_bounded_fraction the
    // index is dropped and the scan used until the map has doubled. Dimensionless, in
    // (0, 1]; 1 keeps every index.
    double index_max_bounded_fraction = 0.6;
    // Dimensions m of the projection the index bounds the distance with (its kd-tree
    // lives in the leading 8 of them); at most min(feature length, 64), larger values are
    // clamped. >= 1.
    int index_dims = 32;
    // Approximate retrieval (ann_index.h): on maps of at least ann_min_views views
    // (views, >= 0; 0 never) with a distance the candidate index supports, FindMatches,
    // FindAllMatches and Update's search go through an HNSW graph (hnswlib) instead: its
    // k nearest views by L2 (k doubled from max(top_k, ann_k) until the farthest is
    // beyond e_max), then the extractor's exact distance, order and top_k for those only.
    // Not exact: a true match the graph search misses is not returned (never a false
    // one). Update also gives every view with a component within d_for_m of mu_t the
    // exact distance, so the rules at the robot's place ((16)-(18)) see exactly the
    // scan's matches; only distant (aliased) matches can be missed. Takes precedence over
    // the exact index while active. The graph is kept from the first view on, one
    // insertion per new view (so no Update stalls on a whole-map build when the map
    // crosses ann_min_views), and searched from ann_min_views views on; it is not saved
    // (Deserialize rebuilds it over the views in id order, the same graph when no view
    // was removed).
    int ann_min_views = 50000;
    // Graph degree M (links per node; 2 M on the bottom layer), in [2, 64]: memory and
    // build time grow with it, and recall.
    int ann_m = 32;
    // Candidate list while inserting a view (>= 1): build time against graph quality.
    int ann_ef_construction = 128;
    // Candidate list while searching (>= 1; at least k is used): time against recall.
    int ann_ef = 128;
    // First k of the radius query (views, >= 1): a query with more matches doubles k.
    int ann_k = 32;
  };

  // The event log (map_events.h).
  struct Events {
    // Also log kComponentAdded and kComponentMerged events (one or more per matching
    // view per Update: large logs). View insertions/removals and component removals are
    // always logged.
    bool log_component_events = false;
    // The event log is a ring of the max_events most recent events (the oldest are
    // dropped), so the model and its map file do not grow with the length of a run;
    // per-session event counts (event_counts()) stay exact. Events, >= 0 (0 keeps no
    // event). Whoever needs the full stream reads the new events after each frame
    // (events_logged(), the run recorder's events.csv).
    int max_events = 10000;
  };

  Retrieval retrieval;
  Update update;
  Forgetting forgetting;
  Index index;
  Events events;

  // Throws omnicml::Error naming the first invalid field.
  void Validate() const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, EnvironmentModelOptions::Retrieval& o) {
  v("e_max", o.e_max);
  v("top_k", o.top_k);
  v("heading_sigma_no_rotation_rad", o.heading_sigma_no_rotation_rad);
}

template <class V>
void VisitFields(V& v, EnvironmentModelOptions::Update& o) {
  v("beta", o.beta);
  v("d_max", o.d_max);
  v("w_min", o.w_min);
  v("merge_delta", o.merge_delta);
  v("merge_precision_weighted", o.merge_precision_weighted);
  v("look_back_frames", o.look_back_frames);
  // After engine file format 14 (engine_io.h): stored only when not the default.
  v.Since(15, [&](auto& w) {
    w.NamedEnum("merge_fusion", o.merge_fusion,
                {{MergeFusion::kMomentMatching, "moment_matching"},
                 {MergeFusion::kCovarianceIntersection, "covariance_intersection"},
                 {MergeFusion::kConvexCombination, "convex_combination"}});
  });
}

template <class V>
void VisitFields(V& v, EnvironmentModelOptions::Forgetting& o) {
  v.Enum("mode", o.mode,
         {ForgettingMode::kActive, ForgettingMode::kPassive, ForgettingMode::kStatic});
  v("d_for_m", o.d_for_m);
  v("beta_for", o.beta_for);
  v("d_gain_m", o.d_gain_m);
  v("footprint_gate", o.footprint_gate);
  v("forget_min_missed_passes", o.forget_min_missed_passes);
  v("pass_gap_frames", o.pass_gap_frames);
  v("footprint_confidence", o.footprint_confidence);
  v("forget_by_matched_passes", o.forget_by_matched_passes);
  v("forget_unconfirmed_views", o.forget_unconfirmed_views);
  // Engine file format 16.
  v.Since(16, [&](auto& w) { w("persistence_min_probability", o.persistence_min_probability); });
}

template <class V>
void VisitFields(V& v, EnvironmentModelOptions::Index& o) {
  v("spatial_cell_m", o.spatial_cell_m);
  v("index_min_views", o.index_min_views);
  v("index_max_bounded_fraction", o.index_max_bounded_fraction);
  v("index_dims", o.index_dims);
  v("ann_min_views", o.ann_min_views);
  v("ann_m", o.ann_m);
  v("ann_ef_construction", o.ann_ef_construction);
  v("ann_ef", o.ann_ef);
  v("ann_k", o.ann_k);
}

template <class V>
void VisitFields(V& v, EnvironmentModelOptions::Events& o) {
  v("log_component_events", o.log_component_events);
  v("max_events", o.max_events);
}

template <class V>
void VisitFields(V& v, EnvironmentModelOptions& o) {
  // The flat keys of the former layout, in its order: read (with a deprecation warning),
  // never written; visited before the sections, so that "forgetting" holding a name is
  // the former mode key and holding a map is the section.
  v.Renamed("e_max", "retrieval.e_max", o.retrieval.e_max);
  v.Renamed("top_k", "retrieval.top_k", o.retrieval.top_k);
  v.Renamed("beta", "update.beta", o.update.beta);
  v.Renamed("d_max", "update.d_max", o.update.d_max);
  v.Renamed("d_for_m", "forgetting.d_for_m", o.forgetting.d_for_m);
  v.Renamed("beta_for", "forgetting.beta_for", o.forgetting.beta_for);
  v.Renamed("d_gain_m", "forgetting.d_gain_m", o.forgetting.d_gain_m);
  v.Renamed("w_min", "update.w_min", o.update.w_min);
  v.Renamed("merge_delta", "update.merge_delta", o.update.merge_delta);
  v.Renamed("merge_precision_weighted", "update.merge_precision_weighted",
            o.update.merge_precision_weighted);
  v.Renamed("heading_sigma_no_rotation_rad", "retrieval.heading_sigma_no_rotation_rad",
            o.retrieval.heading_sigma_no_rotation_rad);
  v.RenamedEnum("forgetting", "forgetting.mode", o.forgetting.mode,
                {ForgettingMode::kActive, ForgettingMode::kPassive, ForgettingMode::kStatic});
  v.Renamed("spatial_cell_m", "index.spatial_cell_m", o.index.spatial_cell_m);
  v.Renamed("footprint_gate", "forgetting.footprint_gate", o.forgetting.footprint_gate);
  v.Renamed("forget_min_missed_passes", "forgetting.forget_min_missed_passes",
            o.forgetting.forget_min_missed_passes);
  v.Renamed("pass_gap_frames", "forgetting.pass_gap_frames", o.forgetting.pass_gap_frames);
  v.Renamed("look_back_frames", "update.look_back_frames", o.update.look_back_frames);
  v.Renamed("footprint_confidence", "forgetting.footprint_confidence",
            o.forgetting.footprint_confidence);
  v.Renamed("forget_by_matched_passes", "forgetting.forget_by_matched_passes",
            o.forgetting.forget_by_matched_passes);
  v.Renamed("forget_unconfirmed_views", "forgetting.forget_unconfirmed_views",
            o.forgetting.forget_unconfirmed_views);
  v.Renamed("log_component_events", "events.log_component_events", o.events.log_component_events);
  v.Renamed("max_events", "events.max_events", o.events.max_events);
  v.Renamed("index_min_views", "index.index_min_views", o.index.index_min_views);
  v.Renamed("index_max_bounded_fraction", "index.index_max_bounded_fraction",
            o.index.index_max_bounded_fraction);
  v.Renamed("index_dims", "index.index_dims", o.index.index_dims);
  v.Renamed("ann_min_views", "index.ann_min_views", o.index.ann_min_views);
  v.Renamed("ann_m", "index.ann_m", o.index.ann_m);
  v.Renamed("ann_ef_construction", "index.ann_ef_construction", o.index.ann_ef_construction);
  v.Renamed("ann_ef", "index.ann_ef", o.index.ann_ef);
  v.Renamed("ann_k", "index.ann_k", o.index.ann_k);
  v.Section("retrieval", o.retrieval);
  v.Section("update", o.update);
  v.Section("forgetting", o.forgetting);
  v.Section("index", o.index);
  v.Section("events", o.events);
}

// The options tree (common/options.h OptionsToValue) of EnvironmentModelOptions in the
// flat layout the engine file has always had: the keys of VisitFields' Renamed list, in that
// order, each with its value from the sections. The engine file stores the model's
// options this way, so a map keeps its bytes and files written before the sections
// existed load unchanged. Fields without a flat key stay in their section (a map) after
// the flat keys.
OptionValue FlatModelOptionsValue(const OptionValue& grouped);
// The inverse: the sections' tree from a flat (or already grouped) one; keys it does not
// know are kept as they are, for the reader to report.
OptionValue GroupedModelOptionsValue(const OptionValue& flat);

}  // namespace omnicml

#endif  // OMNICML_MAPPING_ENVIRONMENT_MODEL_OPTIONS_H_
