// The weight rules of [G 2.3] phase 3 as pluggable policies (docs/design.md "Modes"),
// the way Cartographer's PoseGraphTrimmer makes trimming pluggable: EnvironmentModel::
// Update runs phases 1-2 (insertion, mixture update), then hands the matches and the
// estimate N(mu_t, C_t) to its policy, then removes the components the policy left below
// w_min.
//
//   PassiveForgetting          (16) weight increase of the components of every matching
//                              view within d_max of mu_t, (17) decay of the others, as
//                              in [PK].
//   ActiveFootprintForgetting  (16)-(17) as above, then (18)-(19) on the non-matching
//                              views expected at mu_t: a component within d_for_m of mu_t
//                              whose view's footprint holds mu_t (footprint_gate) after
//                              enough missed passes loses a fraction b of its weight.
//                              (View persistence's removals are the model's:
//                              EnvironmentModel::Update.)
//   StaticForgetting           no rule: Update leaves the map unchanged.
//
// A policy only lowers weights, except (16) on the components of matching views; it never
// adds or removes components or views. It records which rule last changed each component
// (for the removal reason) and which views it touched (the views removal looks at).
//
// Policies are immutable after construction; thread-safe.
#ifndef OMNICML_MAPPING_FORGETTING_POLICY_H_
#define OMNICML_MAPPING_FORGETTING_POLICY_H_

#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/pose.h"
#include "omnicml/mapping/environment_model_options.h"
#include "omnicml/mapping/map_events.h"
#include "omnicml/mapping/reference_view.h"
#include "omnicml/mapping/view_store.h"

namespace omnicml {

// The rule that last changed a component's weight in one Update.
enum class WeightRule : std::uint8_t { kNone, kIncrease, kPassive, kActive, kPersistence };
// The MapEvent reason of a component removed after `rule` left it below w_min.
const char* RemovalReason(WeightRule rule);

// The input of the weight rules: the matches of y_t (rows into the store, after phase 1-2)
// and the estimate N(mu_t, C_t) (map frame; m, m, rad; C_t SPD, symmetric).
struct WeightUpdate {
  const std::vector<ViewMatch>* matches = nullptr;
  Pose2 mu_t = Pose2::Zero();
  Eigen::Matrix3d c_t = Eigen::Matrix3d::Identity();
  UpdateContext context;
};

// What the weight rules did.
struct WeightChanges {
  std::unordered_map<std::uint64_t, WeightRule> last_rule;  // by component id
  std::vector<std::uint64_t> touched_views;  // view ids, matching ones first, in order
  int increased = 0;                         // (16) applications
  int passive_forgotten = 0;                 // (17) applications
  int active_forgotten = 0;                  // (18)-(19) applications with b > 0
  // The pass outcomes of the rules' NoteExpected calls, for the map's persistence counts,
  // in the order they happened.
  std::vector<PassOutcomes> pass_outcomes;
  // Views expected at mu_t that did not match (their current pass is open, unmatched).
  std::vector<std::uint64_t> expected_unmatched;
};

class ForgettingPolicy {
 public:
  virtual ~ForgettingPolicy() = default;
  virtual ForgettingMode mode() const = 0;
  // Whether Update may change the map at all (false: it returns before phase 1).
  virtual bool AdaptsMap() const { return true; }
  // Applies the policy's rules to the weights of `store`'s components.
  virtual void Apply(const WeightUpdate& update, ViewStore& store,
                     WeightChanges* changes) const = 0;
};

class PassiveForgetting : public ForgettingPolicy {
 public:
  explicit PassiveForgetting(const EnvironmentModelOptions& options);
  ForgettingMode mode() const override { return ForgettingMode::kPassive; }
  void Apply(const WeightUpdate& update, ViewStore& store, WeightChanges* changes) const override;

 private:
  double beta_;
  double d_max_;
  double heading_sigma_no_rotation_rad_;
};

class ActiveFootprintForgetting : public ForgettingPolicy {
 public:
  explicit ActiveFootprintForgetting(const EnvironmentModelOptions& options);
  ForgettingMode mode() const override { return ForgettingMode::kActive; }
  void Apply(const WeightUpdate& update, ViewStore& store, WeightChanges* changes) const override;

 private:
  // (18)-(19) on the view at `row` (not matching), whose components entries[begin, end)
  // lie within d_for_m of mu_t; returns whether the view was weakened (touched).
  bool ForgetView(const WeightUpdate& update, std::size_t row,
                  const std::vector<SpatialEntry>& entries, std::size_t begin, std::size_t end,
                  ViewStore& store, WeightChanges* changes) const;

  PassiveForgetting passive_;
  EnvironmentModelOptions::Forgetting options_;
};

class StaticForgetting : public ForgettingPolicy {
 public:
  ForgettingMode mode() const override { return ForgettingMode::kStatic; }
  bool AdaptsMap() const override { return false; }
  void Apply(const WeightUpdate& /*update*/, ViewStore& /*store*/,
             WeightChanges* /*changes*/) const override {}
};

// The policy of options.forgetting.mode.
std::shared_ptr<const ForgettingPolicy> MakeForgettingPolicy(
    const EnvironmentModelOptions& options);

}  // namespace omnicml

#endif  // OMNICML_MAPPING_FORGETTING_POLICY_H_
