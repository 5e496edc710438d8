// The records of the environment model (environment_model.h): a reference view (y_i, X_i)
// with its mixture components, counters and footprint, a match of a query against a view,
// and where an Update comes from and what it did.
//
// Plain values; thread-compatible.
#ifndef OMNICML_MAPPING_REFERENCE_VIEW_H_
#define OMNICML_MAPPING_REFERENCE_VIEW_H_

#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "omnicml/descriptors/descriptor.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

// One Gaussian of a view's mixture X_i.
struct ViewComponent {
  std::uint64_t id = 0;        // unique in the model, never reused
  double weight = 0.0;         // w_ij, dimensionless, in [0, 1]
  double eta = 0.0;            // eta_ij, accumulated (11) share, dimensionless (> 0)
  Pose2 mean = Pose2::Zero();  // (x_m, y_m) map frame; phi_rad relative to the view's panorama
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();  // SPD, (m^2, m^2, rad^2)
  // The eta-weighted scatter of the xy of the observations merged into this component
  // about its mean (m^2, symmetric positive semi-definite; zero for a single observation):
  // how far from the component's place the robot stood when the view matched it.
  // `covariance` is the uncertainty of the place itself.
  Eigen::Matrix2d spread = Eigen::Matrix2d::Zero();

  bool operator==(const ViewComponent&) const = default;
};

// Whether `s` can be a ViewComponent::spread: finite, exactly symmetric, positive
// semi-definite up to the rounding of the merges that build it (a rank-one spread's
// determinant may come out a few ulps below zero).
bool IsValidSpread(const Eigen::Matrix2d& s);

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

// Where an Update comes from (for counters, events and the pass bookkeeping).
struct UpdateContext {
  std::int64_t frame = 0;
  int session = 0;
};

// The passes NoteExpected closed or matched, as outcomes for the view persistence
// statistics (view_persistence.h); -1: none.
struct PassOutcomes {
  // The previous pass closed without a match; the run of missed passes before it.
  int closed_missed_run = -1;
  // The view matched for the first time in this pass, and it had passed before (its
  // creation pass is no outcome); the run of missed passes before this pass.
  int matched_run = -1;
};

// Where a view has been observed to match (docs/forgetting.md): the similarity-weighted
// mean and scatter of the xy of the estimates mu_t of the Updates in which it matched
// (its creation included), and the pass bookkeeping of rule (18).
struct ViewFootprint {
  double weight = 0.0;                                // sum of S_i of the matches
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();     // map frame, metres
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();  // weighted sum of squares, m^2
  int missed_passes = 0;                  // whole passes through the footprint without a match
  int matched_passes = 0;                 // passes in which the view matched
  std::int64_t last_expected_frame = -1;  // last Update that expected the view; -1: none
  int last_expected_session = 0;
  bool pass_matched = false;  // the view matched during the current pass

  // Adds a position with weight w (> 0; else ignored), weighted Welford.
  void Observe(double x_m, double y_m, double w);
  // scatter / weight (m^2); zero before the first observation.
  Eigen::Matrix2d Covariance() const;
  // (p - mean)^T s^-1 (p - mean); infinity if s is not positive definite.
  double SquaredDistance(const Eigen::Vector2d& p, const Eigen::Matrix2d& s) const;
  // Pass bookkeeping of rule (18) (docs/forgetting.md) for an Update in which the view is
  // expected to match (it matched, or mu_t lies inside the footprint): one more than
  // gap_frames frames after the last such Update, or in another session, starts a new
  // pass; the pass it closes adds to missed_passes if the view never matched during it.
  // A match counts the pass as matched and resets missed_passes. Returns the outcomes.
  PassOutcomes NoteExpected(const UpdateContext& context, bool matched, int gap_frames);
  // Whether the pass of the last expectation is over at `context`: another session, or
  // more than gap_frames frames since it. Meaningful once last_expected_frame >= 0.
  bool PassEnded(const UpdateContext& context, int gap_frames) const;
  bool operator==(const ViewFootprint&) const = default;
};

// A footprint estimated from components (maps of format version 1, AddView): their xy
// means weighted by eta.
ViewFootprint FootprintFromComponents(const std::vector<ViewComponent>& components);

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

// A view whose distance to the query is below e_max.
struct ViewMatch {
  std::size_t view_index = 0;  // into views(); valid until the next Update/Deserialize
  std::uint64_t view_id = 0;
  double distance = 0.0;    // E(y, y_i), extractor units
  double similarity = 0.0;  // S_i in (0, 1]
  // RelativeHeading(y, y_i), radians in (-pi, pi]; nullopt for descriptors without heading.
  std::optional<double> relative_heading_rad;
};

// The order of match lists: (distance, id) is a total order, so a list does not depend
// on the order its matches were found in.
inline bool MatchBefore(const ViewMatch& a, const ViewMatch& b) {
  return a.distance != b.distance ? a.distance < b.distance : a.view_id < b.view_id;
}

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

// mu_t with its angle expressed relative to a view's panorama: phi_t minus the relative
// heading RelativeHeading(y_t, y_i) (docs/design.md "Environment model", phase 2).
// Without a relative heading (histograms) the pose is returned as it is.
Pose2 InViewFrame(const Pose2& mu_t, const std::optional<double>& relative_heading_rad);

// The covariance a stored component is compared or returned with: its own, plus
// heading_sigma_rad^2 on the heading variance when the query has no relative heading.
Eigen::Matrix3d EffectiveCovariance(const Eigen::Matrix3d& c,
                                    const std::optional<double>& relative_heading_rad,
                                    double heading_sigma_rad);

}  // namespace omnicml

#endif  // OMNICML_MAPPING_REFERENCE_VIEW_H_
