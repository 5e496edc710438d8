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
// to every matching view, and the weight rules of the forgetting policy followed by
// removal of weak components and of empty views.
//
// The model is a facade over parts with one job each:
//   ViewStore (view_store.h)              views, feature rows, ids, spatial grid, invariants
//   ViewRetrieval (view_retrieval.h)      which views match: scan, exact index or HNSW graph
//   ForgettingPolicy (forgetting_policy.h) the weight rules: passive (16)-(17), active by
//                                         footprint (16)-(19), static
//   MapEventLog (map_events.h)            the bounded event log with exact counts
// and serialisation (environment_model_io.cc). Options: environment_model_options.h.
//
// Determinism: the same sequence of calls gives the same model and the same bytes from
// Serialize. Ties between equal distances are broken by view id.
//
// Thread-safety: thread-compatible. Any number of const calls may run at once; Update,
// ClearEvents, SetForgettingMode and assignment need exclusive access (the engine's
// delayed-update scheme orders them).
#ifndef OMNICML_MAPPING_ENVIRONMENT_MODEL_H_
#define OMNICML_MAPPING_ENVIRONMENT_MODEL_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor.h"
#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/mapping/ann_index.h"
#include "omnicml/mapping/environment_model_options.h"
#include "omnicml/mapping/forgetting_policy.h"
#include "omnicml/mapping/map_events.h"
#include "omnicml/mapping/reference_view.h"
#include "omnicml/mapping/spatial_index.h"
#include "omnicml/mapping/view_index.h"
#include "omnicml/mapping/view_persistence.h"
#include "omnicml/mapping/view_retrieval.h"
#include "omnicml/mapping/view_store.h"

namespace omnicml {

class EnvironmentModel {
 public:
  // Validates options (throws omnicml::Error). `extractor` must not be null; it defines
  // the descriptor kind and feature length the model accepts.
  EnvironmentModel(const EnvironmentModelOptions& options,
                   std::shared_ptr<const DescriptorExtractor> extractor);

  // Views with E(y, y_i) < e_max, sorted by distance (ties by view id), limited to
  // options.retrieval.top_k when > 0. Throws omnicml::Error if y's kind or feature length
  // differs from the extractor's.
  std::vector<ViewMatch> FindMatches(const Descriptor& y) const;
  // The same without the top_k limit (what Update uses).
  std::vector<ViewMatch> FindAllMatches(const Descriptor& y) const;
  // FindMatches by the exhaustive scan over every view, whether or not an index is
  // active: the reference the indexes are tested and benchmarked against. Same result.
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
  bool IndexSupported() const { return retrieval_.IndexSupported(); }
  // Whether searches currently go through the candidate index.
  bool IndexActive() const { return retrieval_.IndexActive(); }
  // The estimated fraction of views the index must bound (options
  // index.index_max_bounded_fraction) at its last evaluation; -1 before any.
  double IndexBoundedFraction() const { return retrieval_.IndexBoundedFraction(); }
  const ViewIndex& view_index() const { return retrieval_.view_index(); }
  // Whether searches currently go through the approximate graph (options index.ann_*):
  // the graph is kept from the first view on and used from ann_min_views views on.
  bool AnnActive() const { return retrieval_.AnnActive(store_.size()); }
  const AnnIndex& ann_index() const { return retrieval_.ann_index(); }

  // p(x|y) (docs/design.md "Environment model"): for each match, each component j of the
  // view gives mean (x, y, wrap(phi_ij + relative heading)), covariance C_ij (heading
  // variance raised by heading_sigma_no_rotation_rad^2 when there is no relative heading)
  // and weight w_ij * S_i; weights normalised to sum 1. Empty when nothing matches.
  // Order: by match order, then component order (deterministic).
  Mixture Hypothesis(const Descriptor& y) const;
  // The same from matches obtained from this model (FindMatches) since the last Update.
  Mixture Hypothesis(const std::vector<ViewMatch>& matches) const;

  // [G 2.3] with the unimodal estimate N(estimate.mean, estimate.covariance) of the pose
  // where y was seen (estimate.weight is ignored). Does nothing with static forgetting.
  // Throws omnicml::Error on a descriptor of the wrong kind/length or a covariance that
  // is not finite and SPD; the model is unchanged then.
  UpdateStats Update(const Descriptor& y, const Gaussian& estimate, const UpdateContext& context);

  // Adds a view as it is, without matching or weight rules (importing a map, building
  // synthetic maps for benchmarks and tests). Component ids are assigned by the model
  // (the given ones are ignored); a kViewInserted event with reason "added" is logged.
  // Throws omnicml::Error on a descriptor of the wrong kind/length, no components, a
  // weight outside [0, 1], eta <= 0, a covariance that is not finite and SPD, or a
  // spread that is not finite, symmetric and positive semi-definite.
  // Returns the new view's id.
  std::uint64_t AddView(const Descriptor& y, std::vector<ViewComponent> components,
                        const ViewStats& stats);

  // Moves view `view_index` rigidly with the pose it hangs from (the engine's global
  // pose graph, engine/pose_graph.h): with dphi = wrap(new.phi - old.phi) and R(dphi)
  // the rotation, every component mean p becomes new.xy + R(dphi) (p.xy - old.xy) with
  // heading wrap(p.phi + dphi) (the heading relative to the view's panorama turns with
  // the robot), its covariance J C J^T with J = diag(R(dphi), 1), the footprint's mean
  // moves and its scatter rotates the same way, each component's spread becomes R S R^T,
  // and the spatial index follows.
  // Weights, ids, counters and events are unchanged. Poses in the map frame (m, m, rad).
  // Precondition: view_index < NumViews() (OMNICML_CHECK).
  void MoveViewRigidly(std::size_t view_index, const Pose2& old_anchor, const Pose2& new_anchor);
  // Sets the covariance of component `k` of view `view_index` (symmetric positive
  // definite, map frame; m^2, m^2, rad^2); means, weights and the spatial index are
  // unchanged (the engine's pose graph gives a moved view's component its node's marginal
  // covariance). Preconditions (OMNICML_CHECK, the component unchanged when one fails):
  // view_index < NumViews(), k < the view's components, `covariance` finite and positive
  // definite.
  void SetComponentCovariance(std::size_t view_index, std::size_t k,
                              const Eigen::Matrix3d& covariance);

  std::size_t NumViews() const { return store_.size(); }
  std::size_t NumComponents() const { return store_.NumComponents(); }
  // In storage order (the order of the feature rows; changes when views are removed).
  const std::vector<ReferenceView>& views() const { return store_.views(); }
  // Index into views() of the view with this id, or nullopt.
  std::optional<std::size_t> FindView(std::uint64_t view_id) const { return store_.Find(view_id); }
  // The id the next inserted view / component will get.
  std::uint64_t next_view_id() const { return store_.next_view_id(); }
  std::uint64_t next_component_id() const { return store_.next_component_id(); }

  // The most recent events (at most options.events.max_events), oldest first. Event
  // number n (0-based, counted since construction) is events()[n - first_event_number()]
  // while first_event_number() <= n < events_logged().
  const std::deque<MapEvent>& events() const { return events_.events(); }
  // Number of events logged since construction (Deserialize restores it).
  std::uint64_t events_logged() const { return events_.events_logged(); }
  std::uint64_t first_event_number() const { return events_.first_event_number(); }
  // Event counts per session (sessions without events are absent), exact.
  const std::map<int, MapEventCounts>& event_counts() const { return events_.counts(); }
  // Empties the ring; events_logged() and event_counts() go on.
  void ClearEvents() { events_.Clear(); }

  // Approximate heap bytes of the model (views, features, components, indexes, events).
  std::size_t MemoryBytes() const;

  const EnvironmentModelOptions& options() const { return options_; }
  const DescriptorExtractor& extractor() const { return *extractor_; }
  const std::shared_ptr<const DescriptorExtractor>& extractor_ptr() const { return extractor_; }
  // The parts (read-only), for tests, benchmarks and tools.
  const ViewStore& store() const { return store_; }
  const ViewRetrieval& retrieval() const { return retrieval_; }
  const ForgettingPolicy& forgetting_policy() const { return *policy_; }
  // The pass statistics and belief of view persistence (view_persistence.h); counted
  // only in active mode while forgetting.persistence_min_probability > 0 (else empty).
  const ViewPersistence& view_persistence() const { return persistence_; }
  // Whether Update keeps and applies view persistence: active mode with
  // forgetting.persistence_min_probability > 0.
  bool ViewPersistenceOn() const;
  // Switches the weight rules (e.g. build on day 1 with active forgetting, then freeze
  // with static).
  void SetForgettingMode(ForgettingMode mode);
  // Sets options index.ann_ef and index.ann_k (search-time parameters; the graph is
  // unchanged), for tuning them on one map. Throws omnicml::Error unless both are >= 1.
  void SetAnnSearch(int ef, int k);

  // Appends the model's state to `out`: views (descriptors, components, counters) in
  // storage order, next ids, the event counts and the event ring, the look-back's recent
  // updates, the view persistence counts and belief. Options are NOT written (the caller
  // stores them). Same model => same bytes.
  void Serialize(BinaryWriter& out) const;
  // Reads what Serialize wrote. Throws omnicml::Error on truncated or malformed bytes, or
  // when the stored descriptor kind / feature length differ from `extractor`'s. A section
  // whose version lies outside [min_version, kFormatVersion] is refused with the one-line
  // Error "<source>: unsupported environment model version N (this build reads A..B)"
  // before any of it is read (an engine file embeds exactly one model version).
  static EnvironmentModel Deserialize(BinaryReader& in, const EnvironmentModelOptions& options,
                                      std::shared_ptr<const DescriptorExtractor> extractor,
                                      std::uint32_t min_version = kOldestFormatVersion);
  // Versions of the serialized model: Serialize writes kFormatVersion; Deserialize reads
  // kOldestFormatVersion..kFormatVersion (see environment_model_io.cc for the layouts).
  static constexpr std::uint32_t kFormatVersion = 6;
  static constexpr std::uint32_t kOldestFormatVersion = 1;

  // Checks internal invariants (the store's, the indexes', weights in [0, 1], ids
  // unique); throws omnicml::InternalError. For tests.
  void CheckInvariants() const;

 private:
  // An update of the current session, kept for the look-back (update.look_back_frames).
  struct RecentUpdate {
    Descriptor y;
    Pose2 mu;
    Eigen::Matrix3d covariance;
    UpdateContext context;
  };

  void CheckDescriptor(const Descriptor& y, const char* where) const;
  // Rows (sorted, unique) of the views with a component strictly inside one of `discs`.
  std::vector<std::size_t> RowsNear(const std::vector<Disc>& discs) const;

  // Update's phases, in order (environment_model.cc).
  // C_t made exactly symmetric; throws unless the estimate is finite with C_t SPD.
  Eigen::Matrix3d CheckedCovariance(const Gaussian& estimate) const;
  // Every view with E < e_max; with the approximate graph active, plus the exact
  // distance of every view with a component within d_for_m of mu_t.
  std::vector<ViewMatch> FindUpdateMatches(const Descriptor& y, const Pose2& mu_t) const;
  // Phase 1: y_t becomes a view when nothing matches; it then is the only match.
  void InsertIfUnmatched(const Descriptor& y, const Pose2& mu_t, const UpdateContext& context,
                         std::vector<ViewMatch>* matches, UpdateStats* stats);
  // Phase 2 for every match; returns the ids of the components kept separate (sorted).
  std::vector<std::uint64_t> AddObservations(const std::vector<ViewMatch>& matches,
                                             const Pose2& mu_t, const Eigen::Matrix3d& c_t,
                                             const UpdateContext& context, UpdateStats* stats);
  // Merges `added` into component k of the view at `row` (12)-(14), then merges on until
  // no pair involving the result is closer than merge_delta.
  void MergeObservation(std::size_t row, std::size_t k, const ViewComponent& added,
                        const UpdateContext& context);
  // Adds the outcomes of one NoteExpected call to the view persistence counts.
  void RecordPassOutcomes(const PassOutcomes& o);
  // After phase 3 with view persistence: the views in open_unmatched_ whose pass has
  // ended without a match are removed (weights 0, touched) when the belief after one more
  // missed pass is below persistence_min_probability.
  void ClosePersistencePasses(const UpdateContext& context, WeightChanges* changes);
  // After phase 3: removes the components below w_min of the touched views (except
  // `fresh`), then the views left empty.
  void RemoveWeakComponents(const WeightChanges& changes, const std::vector<std::uint64_t>& fresh,
                            const Pose2& mu_t, const UpdateContext& context, UpdateStats* stats);
  // Look-back: components for a view inserted by this Update at the recent updates that
  // match it; then remembers this update.
  void LookBack(const Descriptor& y, const Pose2& mu_t, const Eigen::Matrix3d& c_t,
                const UpdateContext& context, std::optional<std::uint64_t> inserted_id,
                UpdateStats* stats);

  // Appends c to the view at `row` (a fresh id, counters, the kComponentAdded event with
  // `reason` when component events are logged); its id.
  std::uint64_t AppendComponent(std::size_t row, const ViewComponent& c,
                                const UpdateContext& context, const char* reason,
                                UpdateStats* stats);
  // Inserts v into the store and the indexes; its row.
  std::size_t InsertView(ReferenceView v);
  void RemoveViewAt(std::size_t row);
  // Deserialize's last section (environment_model_io.cc).
  void ReadRecentUpdates(BinaryReader& in, DescriptorKind kind);
  // ... then (version >= 6) the view persistence counts and belief.
  void ReadViewPersistence(BinaryReader& in);

  EnvironmentModelOptions options_;
  std::shared_ptr<const DescriptorExtractor> extractor_;
  std::size_t feature_size_ = 0;
  ViewStore store_;
  ViewRetrieval retrieval_;  // derived indexes (never serialised); rebuilt on load
  std::shared_ptr<const ForgettingPolicy> policy_;
  MapEventLog events_;
  // The latest updates of the current session, oldest first (look_back_frames).
  std::deque<RecentUpdate> recent_updates_;
  ViewPersistence persistence_;
  // Views whose current pass is open and unmatched (ids, sorted), for the removal at the
  // pass's end (view persistence).
  std::set<std::uint64_t> open_unmatched_;
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_ENVIRONMENT_MODEL_H_
