// The adaptive appearance map of [G 2.2, 2.3] (docs/design.md "Environment model").
//
// The model is a set of reference views U = {(y_i, X_i)}: a descriptor y_i and a mixture
// X_i = {(w_ij, eta_ij, mu_ij, C_ij)} of the poses at which y_i was seen. The weights of X_i
// need not sum to one; their sum is the importance of view i. The xy part of mu_ij is in
// the map frame (metres); its angle phi is stored relative to view i's own panorama
// orientation: a robot at heading phi_t seeing y_t stores phi_t - RelativeHeading(y_t, y_i),
// and a later query y rotates it back by + RelativeHeading(y, y_i).
//
// Localization: Hypothesis(y) = p(x|y), the union over the views with E(y, y_i) < e_max of
// their components, weight w_ij * S_i, heading rotated by the relative heading, normalised
// ("distributed coding").
//
// Map building: Update(y_t, N(mu_t, C_t)) runs the three phases of [G 2.3]: insertion of
// y_t as a new view when no view is within e_max, addition (and merging) of a component
// to every matching view, and the weight rules (16)-(19) followed by removal of weak
// components and of empty views. Forgetting modes select the rules (kActive: all;
// kPassive: (16)-(17) as in [PK]; kStatic: the map never changes).
//
// Nearest-view search keeps all feature vectors in one contiguous float array (a row per
// view, same order as views()) and calls the extractor's raw-pointer Distance, over every
// row (small maps, distances without an L2 lower bound) or over the candidates of an
// exact-pruning index (view_index.h; options index_*), the same matches either way, or,
// on maps of at least ann_min_views views, over the candidates of an approximate graph
// (ann_index.h; options ann_*: the same matches for ~99 % of queries, measured); the
// active-forgetting rule (18)-(19) visits only components near mu_t through a uniform
// grid over component xy positions (spatial_index.h), so its cost does not grow with the
// map.
//
// Determinism: the same sequence of calls gives the same model and the same bytes from
// Serialize. Ties between equal distances are broken by view id.
//
// Thread-safety: thread-compatible. Any number of const calls may run at once; Update,
// ClearEvents, SetForgettingMode and assignment need exclusive access (the engine's
// delayed-update scheme orders them).
#ifndef OMNICML_ENVIRONMENT_MODEL_H_
#define OMNICML_ENVIRONMENT_MODEL_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor.h"
#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/mapping/ann_index.h"
#include "omnicml/mapping/spatial_index.h"
#include "omnicml/mapping/view_index.h"

namespace omnicml {

// Which weight rules of [G 2.3] phase 3 run (docs/design.md "Modes").
enum class ForgettingMode : std::uint8_t {
  kActive = 0,   // insertion, mixture update, (16), (17) and active forgetting (18)-(19)
  kPassive = 1,  // insertion, mixture update, (16) and (17) only, as in [PK]
  kStatic = 2,   // Update never changes the model (baseline: a map that does not adapt)
};
// "active", "passive", "static".
std::string ToString(ForgettingMode mode);
// Throws omnicml::Error on any other name.
ForgettingMode ForgettingModeFromString(const std::string& name);

// Every default below is the engine's (CmlEngineOptions::model); the measurements behind
// them are in docs/design.md "Defaults and their measurements".
struct EnvironmentModelOptions {
  // Descriptor distance at which the similarity S reaches 0 (S = max(0, 1 - E / e_max));
  // views with E < e_max match, and y_t becomes a new view iff E >= e_max for every view.
  // In units of the extractor's Distance: tune it per descriptor (the default suits the
  // default Fourier signature on the simulator's panoramas). Must be > 0.
  double e_max = 0.45;
  // Hypothesis uses at most the top_k most similar matching views; 0 = all of them.
  // Update always uses every matching view. Must be >= 0.
  int top_k = 8;
  // [G] (16)-(17) learning rate beta, dimensionless, in (0, 1].
  double beta = 0.2;
  // [G] (15): a component is confirmed (rule 16) iff its Mahalanobis distance d to mu_t
  // under C_t + C_ij is <= d_max, otherwise it decays (rule 17). d is the square root of
  // the quadratic form (NOT squared), dimensionless. Must be > 0.
  double d_max = 3.0;
  // [G] (18)-(19): active forgetting considers components of non-matching views whose xy
  // position is closer than d_for_m to mu_t (Euclidean, metres), then keeps only views
  // whose footprint holds mu_t (footprint_gate below). Must be > 0.
  double d_for_m = 0.5;
  // [G] (19) gain beta_for, dimensionless, >= 0. 0.7 since 2026-11-25 (was 0.5), chosen
  // among {0.5, 0.7, 1.0} with forget_unconfirmed_views on and tracker.gamma 3.0 on
  // institute seeds 1-5 ([G] Table 1 setting; docs/experiments.md "Issue 14 defaults").
  double beta_for = 0.7;
  // [G] (19) d_gain in metres: b = beta_for * max(1 - d_xy / d_for, 0) * d_gain /
  // (sigma_x + sigma_y) with sigma_x, sigma_y the standard deviations (m) of C_t, so the
  // fraction is dimensionless; b is clamped to [0, 1]. A confident estimate (small sigma)
  // forgets faster than an uncertain one. Must be >= 0.
  double d_gain_m = 1.0;
  // Components whose weight falls below w_min after phase 3 are removed, and views left
  // without components are removed. Dimensionless, in [0, 1).
  //
  // A component added by the current Update starts at w = 0 and (16) raises it to
  // beta * S_i; it is exempt from this removal during the Update that created it, so a
  // weak first match (beta * S_i < w_min) is not deleted on sight. Removal is checked in
  // the views an Update touches (matching views, and in kActive the views with a
  // component within d_for_m of mu_t); weights change nowhere else, so such a weak
  // component is removed by the next Update that touches its view and leaves it below.
  double w_min = 0.01;
  // [G] (12): two components of one view merge when their squared Mahalanobis distance
  // under C_n + C_m is below merge_delta (squared, dimensionless, as TrackerOptions::delta).
  // Must be >= 0 (0 disables merging). Components are compared in the view's own frame
  // with their stored covariances (no heading inflation, see below). A merge sums eta and
  // w (w capped at 1) and takes the weighted mean and covariance (13)-(14), the weights
  // set by merge_precision_weighted.
  double merge_delta = 1.0;
  // Weights of the merge (13)-(14): false = [G]'s shares eta_n and eta_m; true = eta
  // times the component's xy precision, eta / sqrt(det C_xy) (1 / sigma^2 for a round
  // covariance), so a component known to centimetres (a survey pose, or many confident
  // matches) is not dragged by one uncertain estimate the way an eta-share drags it.
  // eta is summed either way. Measured (docs/experiments.md "Precision-weighted merge"):
  // institute Table 1 setting seeds 1-5 mean error passive 0.433 -> 0.397 m, active
  // 0.458 -> 0.406 m; store_large adapted survey map 0.47/0.45/0.58 -> 0.35/0.35/0.42 m.
  bool merge_precision_weighted = true;
  // Descriptors without heading information (histograms; RelativeHeading = nullopt):
  // stored headings are used as they are, and wherever a component is compared with or
  // returned for a query, heading_sigma_no_rotation_rad^2 is added to its heading variance
  // so that the heading of such a hypothesis carries little weight. Radians, > 0.
  double heading_sigma_no_rotation_rad = kPi;
  // Which weight rules run.
  ForgettingMode forgetting = ForgettingMode::kActive;
  // Cell size of the spatial grid over component positions, metres, > 0. About d_for_m / 2
  // to d_for_m is a good choice.
  double spatial_cell_m = 1.0;
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
  // when at most pass_gap_frames frames apart in the same session. >= 0.
  int pass_gap_frames = 25;
  // Look-back (an addition to [G 2.3], docs/design.md "Environment model"): a view made
  // at frame t is also given a component at each of the preceding updates of the same
  // session, newest first, whose descriptor matches it (E < e_max), stopping at the first
  // that does not and at most look_back_frames frames back. Without it a view's mixture
  // only holds poses from its creation on (nothing could match it before), so it lies
  // ahead of the view along the direction of travel (store_large survey map: median
  // +0.40 m) and p(x|y) pulls estimates forward; an adapted map then absorbs that bias
  // day after day. Each such component is one [G] (16) confirmation from w = 0: weight
  // beta * S, eta S, the update's pose and covariance. Frames, >= 0 (0: off). The
  // descriptor decides how far back: 25 and 50 give the same store_large runs. The
  // recent updates (at most look_back_frames, of the current session) are saved with the
  // model, so a run resumed from a saved map equals one run.
  int look_back_frames = 50;
  // ... and only when the robot is confident relative to the footprint: the largest
  // standard deviation of C_t's xy part at most footprint_confidence times the
  // footprint's largest standard deviation (dimensionless, >= 0; 0 disables the check).
  double footprint_confidence = 0.0;
  // Divide (19)'s b by the number of passes in which the view matched, so a place seen
  // on many passes needs as many missed passes to fade as one seen once needs. On by
  // default: without it institute's active map drifts over long runs (10 days x 3000
  // frames, seeds 1-3: mean error on day 10 1.90/1.53/1.80 m, with it 0.41/0.63/0.82 m;
  // docs/forgetting.md).
  bool forget_by_matched_passes = true;
  // Unconfirmed views (docs/forgetting.md "Unconfirmed views"): a view made in the current
  // session that has matched on its creation pass only (matched_passes == 1) is weakened
  // by (18) from the first pass through its footprint in which it does not match,
  // without the forget_min_missed_passes whole passes an established view gets, as
  // ORB-SLAM culls recent map points that the next keyframes do not find again. A view
  // that matched on two passes, or one made in an earlier session (its next pass is on
  // another day), keeps the grace. On by default since 2026-11-25: with it the institute
  // map is 0.29-0.34 of passive's at equal or lower error on 4 of 5 seeds; AntWorld's
  // static route keeps every view (the session condition: without it a replayed day lost
  // views there while a global start widened C_t).
  bool forget_unconfirmed_views = true;
  // Also log kComponentAdded and kComponentMerged events (one or more per matching view
  // per Update: large logs). View insertions/removals and component removals are always
  // logged.
  bool log_component_events = false;
  // The event log is a ring of the max_events most recent events (the oldest are
  // dropped), so the model and its map file do not grow with the length of a run;
  // per-session event counts (event_counts()) stay exact. >= 0 (0 keeps no event).
  // Whoever needs the full stream reads the new events after each frame
  // (events_logged(), the run recorder's events.csv).
  int max_events = 10000;
  // Place retrieval at scale (docs/design.md "Place retrieval at scale"): with a
  // distance that is at least the L2 norm of the feature difference (Fourier L2 or L1,
  // colour-histogram L1 or L2), searches can go through an exact candidate index
  // (view_index.h: PCA projection lower bound + kd-tree, then the exact distance for the
  // candidates only); the results are identical to the exhaustive scan either way.
  // The index is built once the map holds index_min_views views (views, >= 0; 0 never
  // builds it) and dropped below half of that. Measured: with e_max <= 0.3 it wins from
  // 1k views on (docs/experiments.md "Map scale").
  int index_min_views = 1000;
  // ... and kept only while it pays: when it is built (and when the map has doubled
  // since), the fraction of views whose bound it must compute is estimated with 32
  // stored views (evenly spaced rows) as queries; above index_max_bounded_fraction the
  // index is dropped and the scan used until the map has doubled. Dimensionless, in
  // (0, 1]; 1 keeps every index. Measured: FindMatches time (index / scan) is 0.85-1.5
  // times this fraction, so 0.6 keeps the index where it is not slower and usually much
  // faster; at the default e_max 0.45 the fraction is 0.70-0.96 (1k-1M views) and the
  // scan is used; at e_max 0.2 (0.3) the index is used from 1k (10k) views.
  double index_max_bounded_fraction = 0.6;
  // Dimensions m of the projection the index bounds the distance with (its kd-tree
  // lives in the leading 8 of them); at most min(feature length, 64), larger values are
  // clamped. >= 1. 32 keeps ~1 % of the views as candidates at e_max 0.45 (measured).
  int index_dims = 32;
  // Approximate retrieval (docs/design.md "Place retrieval at scale", ann_index.h): on
  // maps of at least ann_min_views views (views, >= 0; 0 never) with a distance the
  // candidate index supports, FindMatches, FindAllMatches and Update's search go through
  // an HNSW graph (hnswlib) instead: its k nearest views by L2 (k doubled from
  // max(top_k, ann_k) until the farthest is beyond e_max), then the extractor's exact
  // distance, order and top_k for those only. Not exact: a true match the graph search
  // misses is not returned (never a false one). Measured on synthetic trajectory maps
  // (docs/experiments.md "Approximate retrieval"): FindMatches' top-8 lists hold 0.999
  // of the true matches at 100k views; the radius query of Update 0.95, but Update also
  // gives every view with a component within d_for_m of mu_t the exact distance, so the
  // rules at the robot's place ((16)-(18)) see exactly the scan's matches; only distant
  // (aliased) matches can be missed. Takes precedence
  // over the exact index while active. The graph is kept from the first view on, one
  // insertion per new view (so no Update stalls on a whole-map build when the map
  // crosses ann_min_views: that build took 58 s wall at 100k views on the 2-core
  // development machine), and searched from ann_min_views views on; it is not saved
  // (Deserialize rebuilds it over the views in id order, the same graph when no view was
  // removed). 50k: below it the scan costs <= 0.5 ms
  // and stays exact; at 100k the graph takes ProcessFrame's p99 from 6.3 to 0.7 ms CPU.
  int ann_min_views = 50000;
  // Graph degree M (links per node; 2 M on the bottom layer), in [2, 64]: memory and
  // build time grow with it, and recall. 32 with ann_ef 128: FindMatches at 1M views
  // 694 us CPU with recall 0.993 (M 16 reached 0.985 only at ef 256, 995 us); graph
  // 769 B per view (M 16: 609). docs/experiments.md "Approximate retrieval".
  int ann_m = 32;
  // Candidate list while inserting a view (>= 1): build time against graph quality.
  int ann_ef_construction = 128;
  // Candidate list while searching (>= 1; at least k is used): time against recall.
  int ann_ef = 128;
  // First k of the radius query (views, >= 1): a query with more matches doubles k.
  int ann_k = 32;

  // Throws omnicml::Error naming the first invalid field.
  void Validate() const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
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
  v("merge_precision_weighted", o.merge_precision_weighted);
  v("heading_sigma_no_rotation_rad", o.heading_sigma_no_rotation_rad);
  v.Enum("forgetting", o.forgetting,
         {ForgettingMode::kActive, ForgettingMode::kPassive, ForgettingMode::kStatic});
  v("spatial_cell_m", o.spatial_cell_m);
  v("footprint_gate", o.footprint_gate);
  v("forget_min_missed_passes", o.forget_min_missed_passes);
  v("pass_gap_frames", o.pass_gap_frames);
  v("look_back_frames", o.look_back_frames);
  v("footprint_confidence", o.footprint_confidence);
  v("forget_by_matched_passes", o.forget_by_matched_passes);
  v("forget_unconfirmed_views", o.forget_unconfirmed_views);
  v("log_component_events", o.log_component_events);
  v("max_events", o.max_events);
  v("index_min_views", o.index_min_views);
  v("index_max_bounded_fraction", o.index_max_bounded_fraction);
  v("index_dims", o.index_dims);
  v("ann_min_views", o.ann_min_views);
  v("ann_m", o.ann_m);
  v("ann_ef_construction", o.ann_ef_construction);
  v("ann_ef", o.ann_ef);
  v("ann_k", o.ann_k);
}

// One Gaussian of a view's mixture X_i.
struct ViewComponent {
  std::uint64_t id = 0;        // unique in the model, never reused
  double weight = 0.0;         // w_ij, dimensionless, in [0, 1]
  double eta = 0.0;            // eta_ij, accumulated (11) share, dimensionless (> 0)
  Pose2 mean = Pose2::Zero();  // (x_m, y_m) map frame; phi_rad relative to the view's panorama
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();  // SPD, (m^2, m^2, rad^2)

  bool operator==(const ViewComponent&) const = default;
};

// Per-view counters (frames and sessions as given in UpdateContext).
struct ViewStats {
  std::int64_t created_frame = 0;
  int created_session = 0;
  // Number of Updates in which the view matched (E < e_max), including its creation.
  std::int64_t observations = 0;
  std::int64_t last_seen_frame = 0;
  int last_seen_session = 0;

  bool operator==(const ViewStats&) const = default;
};

// Where a view has been observed to match (docs/forgetting.md): the similarity-weighted
// mean and scatter of the xy of the estimates mu_t of the Updates in which it matched
// (its creation included), and the pass bookkeeping of rule (18).
struct ViewFootprint {
  double weight = 0.0;                                 // sum of S_i of the matches
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();      // map frame, metres
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();   // weighted sum of squares, m^2
  int missed_passes = 0;          // whole passes through the footprint without a match
  int matched_passes = 0;         // passes in which the view matched
  std::int64_t last_expected_frame = -1;  // last Update that expected the view; -1: none
  int last_expected_session = 0;
  bool pass_matched = false;      // the view matched during the current pass

  // Adds a position with weight w (> 0; else ignored), weighted Welford.
  void Observe(double x_m, double y_m, double w);
  // scatter / weight (m^2); zero before the first observation.
  Eigen::Matrix2d Covariance() const;
  // (p - mean)^T s^-1 (p - mean); infinity if s is not positive definite.
  double SquaredDistance(const Eigen::Vector2d& p, const Eigen::Matrix2d& s) const;
  bool operator==(const ViewFootprint&) const = default;
};

struct ReferenceView {
  std::uint64_t id = 0;  // unique in the model, never reused, increasing with creation
  Descriptor descriptor;
  std::vector<ViewComponent> components;  // never empty in a model
  ViewStats stats;
  ViewFootprint footprint;

  // Sum of the component weights: the importance of the view.
  double TotalWeight() const;
  bool operator==(const ReferenceView&) const = default;
};

enum class MapEventType : std::uint8_t {
  kViewInserted = 0,
  kViewRemoved = 1,
  kComponentAdded = 2,   // only with options.log_component_events
  kComponentMerged = 3,  // only with options.log_component_events
  kComponentRemoved = 4,
};
// "view_inserted", "view_removed", "component_added", "component_merged", "component_removed".
std::string ToString(MapEventType type);
// MapEvent::reason of a component removed after active forgetting (18)-(19) lowered it.
inline constexpr const char* kActiveForgettingReason = "active forgetting (18)-(19)";

// One change of the map, so a user can tell a changed place (components forgotten at a
// place, then a new view inserted there) from a newly visited one (insertion only).
struct MapEvent {
  MapEventType type = MapEventType::kViewInserted;
  std::int64_t frame = 0;  // UpdateContext of the Update that caused it
  int session = 0;
  std::uint64_t view_id = 0;
  std::uint64_t component_id = 0;  // 0 for view events
  // Where: for view insertion mu_t; for component events the component's mean (phi in
  // view orientation); for view removal the mean of its last component.
  Pose2 position = Pose2::Zero();
  // Weight of the component when removed/merged/added; view total weight otherwise.
  double weight = 0.0;
  // "no view within e_max" (inserted by Update), "added" (AddView), "passive forgetting
  // (17)", "active forgetting (18)-(19)" (the rule that last lowered the removed
  // component's weight), "weight below w_min" (raised by (16) but still below w_min),
  // "view empty", "observation" (component added), "merge (12)-(14)".
  std::string reason;

  bool operator==(const MapEvent&) const = default;
};

// How many events of each type one session (UpdateContext::session) logged, counted as
// they happen: exact however many events the ring (max_events) has dropped.
struct MapEventCounts {
  std::int64_t views_inserted = 0;
  std::int64_t views_removed = 0;
  std::int64_t components_added = 0;   // only with options.log_component_events
  std::int64_t components_merged = 0;  // only with options.log_component_events
  std::int64_t components_removed = 0;

  bool operator==(const MapEventCounts&) const = default;
};

// A view whose distance to the query is below e_max.
struct ViewMatch {
  std::size_t view_index = 0;  // into views(); valid until the next Update/Deserialize
  std::uint64_t view_id = 0;
  double distance = 0.0;    // E(y, y_i), extractor units
  double similarity = 0.0;  // S_i in (0, 1]
  // RelativeHeading(y, y_i), radians in (-pi, pi]; nullopt for descriptors without heading.
  std::optional<double> relative_heading_rad;
};

// Where in the log an Update comes from (for counters and events).
struct UpdateContext {
  std::int64_t frame = 0;
  int session = 0;
};

// What one Update did (for per-frame statistics).
struct UpdateStats {
  bool view_inserted = false;
  int matching_views = 0;                // views with E < e_max before insertion
  int components_added = 0;              // new components kept separate
  int components_merged = 0;             // new components merged into an existing one
  int components_increased = 0;          // rule (16) applications
  int components_passive_forgotten = 0;  // rule (17) applications
  int components_active_forgotten = 0;   // rule (18)-(19) applications (b > 0)
  int components_removed = 0;
  int views_removed = 0;
};

class EnvironmentModel {
 public:
  // Validates options (throws omnicml::Error). `extractor` must not be null; it defines
  // the descriptor kind and feature length the model accepts.
  EnvironmentModel(const EnvironmentModelOptions& options,
                   std::shared_ptr<const DescriptorExtractor> extractor);

  // Views with E(y, y_i) < e_max, sorted by distance (ties by view id), limited to
  // options.top_k when > 0. Throws omnicml::Error if y's kind or feature length differs
  // from the extractor's.
  std::vector<ViewMatch> FindMatches(const Descriptor& y) const;
  // The same without the top_k limit (what Update uses).
  std::vector<ViewMatch> FindAllMatches(const Descriptor& y) const;
  // FindMatches by the exhaustive scan over every view, whether or not the index is
  // active: the reference the index is tested and benchmarked against. Same result.
  std::vector<ViewMatch> FindMatchesExhaustive(const Descriptor& y) const;
  // A disc of the map's plane: centre (x, y) and radius, metres.
  struct Disc {
    double x_m = 0.0, y_m = 0.0, radius_m = 0.0;
  };
  // Pose-gated matching: FindMatches restricted to the views with a component whose
  // mean lies strictly inside one of `discs` (spatial index); only those get the exact
  // distance. Same order and top_k as FindMatches, so when every view with E < e_max has
  // such a component the result equals FindMatches'. *candidates (optional): how many
  // views were compared.
  std::vector<ViewMatch> FindMatchesNear(const Descriptor& y, const std::vector<Disc>& discs,
                                         std::size_t* candidates = nullptr) const;

  // Whether the extractor's distance is bounded below by the L2 norm of the feature
  // difference, so the candidate index may serve it (Fourier L1/L2, colour histogram
  // L1/L2); false for the Jeffrey divergence, chi-square, intersection and unknown
  // extractors, which always use the exhaustive scan.
  bool IndexSupported() const { return index_supported_; }
  // Whether searches currently go through the candidate index.
  bool IndexActive() const { return view_index_.built(); }
  // The estimated fraction of views the index must bound (options
  // index_max_bounded_fraction) at its last evaluation; -1 before any.
  double IndexBoundedFraction() const { return index_bounded_fraction_; }
  const ViewIndex& view_index() const { return view_index_; }
  // Whether searches currently go through the approximate graph (options ann_*): the
  // graph is kept from the first view on and used from ann_min_views views on.
  bool AnnActive() const {
    return ann_index_.built() &&
           views_.size() >= static_cast<std::size_t>(options_.ann_min_views);
  }
  const AnnIndex& ann_index() const { return ann_index_; }

  // p(x|y) (docs/design.md "Environment model"): for each match, each component j of the
  // view gives mean (x, y, wrap(phi_ij + relative heading)), covariance C_ij (heading
  // variance raised by heading_sigma_no_rotation_rad^2 when there is no relative heading)
  // and weight w_ij * S_i; weights normalised to sum 1. Empty when nothing matches.
  // Order: by match order, then component order (deterministic).
  Mixture Hypothesis(const Descriptor& y) const;
  // The same from matches obtained from this model (FindMatches) since the last Update.
  Mixture Hypothesis(const std::vector<ViewMatch>& matches) const;

  // [G 2.3] with the unimodal estimate N(estimate.mean, estimate.covariance) of the pose
  // where y was seen (estimate.weight is ignored). Does nothing in kStatic mode. Throws
  // omnicml::Error on a descriptor of the wrong kind/length or a covariance that is not
  // finite and SPD; the model is unchanged then.
  UpdateStats Update(const Descriptor& y, const Gaussian& estimate, const UpdateContext& context);

  // Adds a view as it is, without matching or weight rules (importing a map, building
  // synthetic maps for benchmarks and tests). Component ids are assigned by the model
  // (the given ones are ignored); a kViewInserted event with reason "added" is logged.
  // Throws omnicml::Error on a descriptor of the wrong kind/length, no components, a
  // weight outside [0, 1], eta <= 0, or a covariance that is not finite and SPD.
  // Returns the new view's id.
  std::uint64_t AddView(const Descriptor& y, std::vector<ViewComponent> components,
                        const ViewStats& stats);

  // Moves view `view_index` rigidly with the pose it hangs from (the engine's global
  // pose graph, engine/pose_graph.h): with dphi = wrap(new.phi - old.phi) and R(dphi)
  // the rotation, every component mean p becomes new.xy + R(dphi) (p.xy - old.xy) with
  // heading wrap(p.phi + dphi) (the heading relative to the view's panorama turns with
  // the robot), its covariance J C J^T with J = diag(R(dphi), 1), the footprint's mean
  // moves and its scatter rotates the same way, and the spatial index follows.
  // Weights, ids, counters and events are unchanged. Poses in the map frame (m, m, rad).
  // Precondition: view_index < NumViews() (OMNICML_CHECK).
  void MoveViewRigidly(std::size_t view_index, const Pose2& old_anchor, const Pose2& new_anchor);

  std::size_t NumViews() const { return views_.size(); }
  std::size_t NumComponents() const { return num_components_; }
  // In storage order (the order of the feature rows; changes when views are removed).
  const std::vector<ReferenceView>& views() const { return views_; }
  // Index into views() of the view with this id, or nullopt.
  std::optional<std::size_t> FindView(std::uint64_t view_id) const;
  // The id the next inserted view / component will get.
  std::uint64_t next_view_id() const { return next_view_id_; }
  std::uint64_t next_component_id() const { return next_component_id_; }

  // The most recent events (at most options.max_events), oldest first. Event number n
  // (0-based, counted since construction) is events()[n - first_event_number()] while
  // first_event_number() <= n < events_logged().
  const std::deque<MapEvent>& events() const { return events_; }
  // Number of events logged since construction (Deserialize restores it).
  std::uint64_t events_logged() const { return events_logged_; }
  std::uint64_t first_event_number() const { return events_logged_ - events_.size(); }
  // Event counts per session (sessions without events are absent), exact.
  const std::map<int, MapEventCounts>& event_counts() const { return event_counts_; }
  // Empties the ring; events_logged() and event_counts() go on.
  void ClearEvents() { events_.clear(); }

  // Approximate heap bytes of the model (views, features, components, index, events).
  std::size_t MemoryBytes() const;

  const EnvironmentModelOptions& options() const { return options_; }
  const DescriptorExtractor& extractor() const { return *extractor_; }
  const std::shared_ptr<const DescriptorExtractor>& extractor_ptr() const { return extractor_; }
  // Switches the weight rules (e.g. build on day 1 in kActive, then freeze with kStatic).
  void SetForgettingMode(ForgettingMode mode) { options_.forgetting = mode; }
  // Sets options ann_ef and ann_k (search-time parameters; the graph is unchanged), for
  // tuning them on one map. Throws omnicml::Error unless both are >= 1.
  void SetAnnSearch(int ef, int k);

  // Appends the model's state to `out`: views (descriptors, components, counters) in
  // storage order, next ids, the event counts and the event ring. Options are NOT written (the caller stores
  // them). Same model => same bytes.
  void Serialize(BinaryWriter& out) const;
  // Reads what Serialize wrote. Throws omnicml::Error on truncated or malformed bytes, or
  // when the stored descriptor kind / feature length differ from `extractor`'s.
  static EnvironmentModel Deserialize(BinaryReader& in, const EnvironmentModelOptions& options,
                                      std::shared_ptr<const DescriptorExtractor> extractor);

  // Checks internal invariants (feature rows equal descriptors, index consistent, no
  // empty view, weights in [0, 1], ids unique); throws omnicml::InternalError. For tests.
  void CheckInvariants() const;

 private:
  void CheckDescriptor(const Descriptor& y, const char* where) const;
  // `only` (optional): compare these view indices (sorted, unique) instead of every view.
  std::vector<ViewMatch> Search(const Descriptor& y, int top_k, bool exhaustive = false,
                                const std::vector<std::size_t>* only = nullptr) const;
  // Rows (sorted, unique) of the views with a component strictly inside one of `discs`
  // (spatial index).
  std::vector<std::size_t> RowsNear(const std::vector<Disc>& discs) const;
  // Builds, maintains or drops the candidate index after the views changed.
  void MaintainIndex();
  // Builds the index over every view and keeps it iff it pays (index_max_bounded_fraction).
  void BuildIndex();
  // Builds the approximate graph over every view, in id order.
  void BuildAnn();
  // The radius query (top_k 0) or top_k query through the graph: appends to *rows the
  // rows of the views it returns (the candidates for the exact distance).
  void AnnCandidates(const float* query, int top_k, std::vector<std::size_t>* rows) const;
  std::size_t InsertView(const Descriptor& y, const UpdateContext& context, const Pose2& where);
  void RemoveViewAt(std::size_t index);
  // Counts e, appends it to the ring and drops the oldest events beyond max_events.
  void LogEvent(MapEvent e);
  void RebuildDerived();

  EnvironmentModelOptions options_;
  std::shared_ptr<const DescriptorExtractor> extractor_;
  std::size_t feature_size_ = 0;
  std::vector<ReferenceView> views_;
  // The latest updates of the current session, oldest first (look_back_frames).
  struct RecentUpdate {
    Descriptor y;
    Pose2 mu;
    Eigen::Matrix3d covariance;
    UpdateContext context;
  };
  std::deque<RecentUpdate> recent_updates_;
  // Gives the view of id `view_id`, just inserted at `context`, components at the recent
  // updates that match it (look_back_frames).
  void AddLookBackComponents(std::uint64_t view_id, const UpdateContext& context, UpdateStats* stats);
  // Appends c to `view` as a new component (a fresh id, the spatial index, the counters,
  // the kComponentAdded event with `reason` when component events are logged); its id.
  std::uint64_t AppendComponent(ReferenceView& view, ViewComponent c, const UpdateContext& context,
                                const char* reason, UpdateStats* stats);
  std::vector<float> features_;  // views_.size() rows of feature_size_ floats
  std::unordered_map<std::uint64_t, std::size_t> index_of_id_;
  SpatialIndex spatial_;
  bool index_supported_ = false;
  ViewIndex view_index_;  // derived (never serialised); rebuilt on load
  double index_bounded_fraction_ = -1.0;
  std::size_t index_rejected_at_ = 0;  // views when the index was last dropped as unprofitable
  AnnIndex ann_index_;  // derived (never serialised); rebuilt on load (in id order)
  bool distance_is_l2_ = false;  // E is exactly the L2 norm of the feature difference
  std::size_t num_components_ = 0;
  std::uint64_t next_view_id_ = 1;
  std::uint64_t next_component_id_ = 1;
  std::deque<MapEvent> events_;  // ring of the most recent events
  std::uint64_t events_logged_ = 0;
  std::map<int, MapEventCounts> event_counts_;
};

}  // namespace omnicml

#endif  // OMNICML_ENVIRONMENT_MODEL_H_
