#include "omnicml/mapping/forgetting_policy.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "testing/fake_descriptor.h"

namespace omnicml {
namespace {

using testing::MakeFakeExtractor;

constexpr double kTol = 1e-12;

ViewComponent Component(double x, double y, double w, double sigma = 0.1) {
  ViewComponent c;
  c.weight = w;
  c.eta = 1.0;
  c.mean = MakePose(x, y, 0.0);
  c.covariance = Eigen::Vector3d(sigma * sigma, sigma * sigma, 0.01).asDiagonal();
  return c;
}

// A view whose footprint is a round spread of standard deviation sigma_m around (x, y),
// matched on `matched_passes` passes.
ReferenceView View(float f, std::vector<ViewComponent> components, double x, double y,
                   double sigma_m, int matched_passes) {
  ReferenceView v;
  v.descriptor = MakeFakeExtractor(1)->Make({f});
  v.components = std::move(components);
  v.footprint.weight = 1.0;
  v.footprint.mean = Eigen::Vector2d(x, y);
  v.footprint.scatter = Eigen::Matrix2d::Identity() * sigma_m * sigma_m;
  v.footprint.matched_passes = matched_passes;
  v.footprint.last_expected_frame = 0;
  v.stats.created_session = 0;
  return v;
}

ViewMatch Match(const ViewStore& s, std::size_t row, double similarity) {
  ViewMatch m;
  m.view_index = row;
  m.view_id = s.view(row).id;
  m.similarity = similarity;
  m.relative_heading_rad = 0.0;
  return m;
}

WeightUpdate At(const std::vector<ViewMatch>& matches, double x, double y, double sigma_m,
                std::int64_t frame = 1000, int session = 1) {
  WeightUpdate u;
  u.matches = &matches;
  u.mu_t = MakePose(x, y, 0.0);
  u.c_t = Eigen::Vector3d(sigma_m * sigma_m, sigma_m * sigma_m, 0.01).asDiagonal();
  u.context = UpdateContext{frame, session};
  return u;
}

std::map<std::uint64_t, double> Weights(const ViewStore& s) {
  std::map<std::uint64_t, double> w;
  for (const ReferenceView& v : s.views()) {
    for (const ViewComponent& c : v.components) w[c.id] = c.weight;
  }
  return w;
}

// Forgetting never raises a weight: every component's weight after Apply is at most its
// weight before, except the components whose last rule is the (16) increase.
void ExpectNoWeightRaisedByForgetting(const std::map<std::uint64_t, double>& before,
                                      const ViewStore& after, const WeightChanges& changes) {
  for (const auto& [id, w] : Weights(after)) {
    const auto rule = changes.last_rule.find(id);
    if (rule != changes.last_rule.end() && rule->second == WeightRule::kIncrease) continue;
    EXPECT_LE(w, before.at(id)) << "component " << id;
  }
}

EnvironmentModelOptions PolicyOptions() {
  EnvironmentModelOptions o;
  o.update.beta = 0.2;
  o.update.d_max = 3.0;
  o.forgetting.d_for_m = 2.0;
  o.forgetting.beta_for = 0.5;
  o.forgetting.d_gain_m = 0.1;
  o.forgetting.footprint_gate = 2.0;
  o.forgetting.forget_min_missed_passes = 0;
  o.forgetting.forget_by_matched_passes = true;
  return o;
}

// (16) raises a component within d_max of mu_t to beta S + (1 - beta S) w, (17) lowers
// the others to (1 - beta S) w; both record their rule and the view as touched.
TEST(PassiveForgetting, FollowsEquations16And17) {
  ViewStore s(1, 1.0);
  s.Insert(View(0, {Component(0, 0, 0.5), Component(5, 0, 0.4)}, 0, 0, 0.5, 1));
  const std::vector<ViewMatch> matches = {Match(s, 0, 0.6)};
  WeightChanges changes;
  PassiveForgetting(PolicyOptions()).Apply(At(matches, 0.05, 0, 0.1), s, &changes);
  const double beta_s = 0.2 * 0.6;
  EXPECT_NEAR(s.view(0).components[0].weight, beta_s + (1 - beta_s) * 0.5, kTol);
  EXPECT_NEAR(s.view(0).components[1].weight, (1 - beta_s) * 0.4, kTol);
  EXPECT_EQ(changes.increased, 1);
  EXPECT_EQ(changes.passive_forgotten, 1);
  EXPECT_EQ(changes.last_rule.at(s.view(0).components[0].id), WeightRule::kIncrease);
  EXPECT_EQ(changes.last_rule.at(s.view(0).components[1].id), WeightRule::kPassive);
  EXPECT_EQ(changes.touched_views, std::vector<std::uint64_t>{s.view(0).id});
}

// Passive forgetting leaves views that do not match alone, even right at mu_t.
TEST(PassiveForgetting, LeavesNonMatchingViewsUnchanged) {
  ViewStore s(1, 1.0);
  s.Insert(View(0, {Component(0, 0, 0.5)}, 0, 0, 0.5, 1));
  s.Insert(View(1, {Component(0, 0, 0.7)}, 0, 0, 0.5, 1));
  const std::vector<ViewMatch> matches = {Match(s, 0, 1.0)};
  WeightChanges changes;
  PassiveForgetting(PolicyOptions()).Apply(At(matches, 0, 0, 0.1), s, &changes);
  EXPECT_EQ(s.view(1).components[0].weight, 0.7);
  EXPECT_EQ(changes.last_rule.count(s.view(1).components[0].id), 0u);
}

// (18)-(19): a non-matching view whose footprint holds mu_t loses the fraction
// b = beta_for (1 - d_fp / gate) d_gain / (sigma_x + sigma_y) of each component within
// d_for_m; a view with a component there but its footprint elsewhere keeps its weights.
TEST(ActiveFootprintForgetting, WeakensOnlyViewsWhoseFootprintHoldsTheRobot) {
  ViewStore s(1, 1.0);
  s.Insert(View(0, {Component(0.2, 0, 0.8), Component(8, 0, 0.6)}, 0, 0, 0.5, 1));
  s.Insert(View(1, {Component(0.1, 0, 0.9)}, 20, 0, 0.5, 1));
  const std::vector<ViewMatch> matches;
  const double sigma = 0.1, x = 0.3;
  WeightChanges changes;
  ActiveFootprintForgetting(PolicyOptions()).Apply(At(matches, x, 0, sigma), s, &changes);
  // Footprint covariance 0.25 plus C_t's 0.01 on each axis.
  const double d_fp = x / std::sqrt(0.25 + sigma * sigma);
  const double b = 0.5 * (1.0 - d_fp / 2.0) * 0.1 / (2 * sigma);
  EXPECT_NEAR(s.view(0).components[0].weight, (1 - b) * 0.8, kTol);
  EXPECT_EQ(s.view(0).components[1].weight, 0.6);  // beyond d_for_m
  EXPECT_EQ(s.view(1).components[0].weight, 0.9);  // footprint 20 m away
  EXPECT_EQ(changes.active_forgotten, 1);
  EXPECT_EQ(changes.touched_views, std::vector<std::uint64_t>{s.view(0).id});
  EXPECT_EQ(changes.last_rule.at(s.view(0).components[0].id), WeightRule::kActive);
}

// A view matched on k passes forgets k times more slowly (forget_by_matched_passes), and
// an established view keeps its grace until it has missed forget_min_missed_passes.
TEST(ActiveFootprintForgetting, EvidenceOverPassesSlowsForgetting) {
  EnvironmentModelOptions o = PolicyOptions();
  ViewStore s(1, 1.0);
  s.Insert(View(0, {Component(0, 0, 0.8)}, 0, 0, 0.5, 1));
  s.Insert(View(1, {Component(0, 0, 0.8)}, 0, 0, 0.5, 4));
  const std::vector<ViewMatch> none;
  WeightChanges changes;
  ActiveFootprintForgetting(o).Apply(At(none, 0, 0, 0.1), s, &changes);
  const double lost_once = 0.8 - s.view(0).components[0].weight;
  const double lost_four = 0.8 - s.view(1).components[0].weight;
  EXPECT_GT(lost_once, 0.0);
  EXPECT_NEAR(lost_four, lost_once / 4.0, kTol);

  o.forgetting.forget_min_missed_passes = 2;
  o.forgetting.forget_unconfirmed_views = false;
  ViewStore grace(1, 1.0);
  grace.Insert(View(0, {Component(0, 0, 0.8)}, 0, 0, 0.5, 1));
  WeightChanges none_changed;
  ActiveFootprintForgetting(o).Apply(At(none, 0, 0, 0.1), grace, &none_changed);
  EXPECT_EQ(grace.view(0).components[0].weight, 0.8);
  EXPECT_EQ(grace.view(0).footprint.missed_passes, 1);  // the pass is counted
}

// On random maps and estimates, neither policy raises a weight except by (16) on a
// matching view, and passive never touches a view that does not match.
TEST(ForgettingPolicy, NeverRaisesWeights) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> pos(-3.0, 3.0), w(0.0, 1.0), sim(0.05, 1.0);
  for (int trial = 0; trial < 50; ++trial) {
    ViewStore s(1, 0.5);
    for (int v = 0; v < 8; ++v) {
      std::vector<ViewComponent> comps;
      for (int k = 0; k < 3; ++k) comps.push_back(Component(pos(rng), pos(rng), w(rng), 0.3));
      s.Insert(View(static_cast<float>(v), comps, pos(rng), pos(rng), 0.8,
                    1 + static_cast<int>(rng() % 3)));
    }
    std::vector<ViewMatch> matches;
    for (std::size_t row = 0; row < s.size(); row += 3) matches.push_back(Match(s, row, sim(rng)));
    const WeightUpdate u = At(matches, pos(rng), pos(rng), 0.2);
    for (const ForgettingMode mode : {ForgettingMode::kPassive, ForgettingMode::kActive}) {
      EnvironmentModelOptions o = PolicyOptions();
      o.forgetting.mode = mode;
      ViewStore copy = s;
      const auto before = Weights(copy);
      WeightChanges changes;
      MakeForgettingPolicy(o)->Apply(u, copy, &changes);
      ExpectNoWeightRaisedByForgetting(before, copy, changes);
      for (const auto& [id, rule] : changes.last_rule) {
        if (mode == ForgettingMode::kPassive) EXPECT_NE(rule, WeightRule::kActive);
      }
      EXPECT_NO_THROW(copy.CheckInvariants());
    }
  }
}

// The static policy changes nothing and tells Update not to adapt the map.
TEST(StaticForgetting, LeavesTheStoreUnchanged) {
  ViewStore s(1, 1.0);
  s.Insert(View(0, {Component(0, 0, 0.5)}, 0, 0, 0.5, 1));
  const ViewStore before = s;
  const std::vector<ViewMatch> matches = {Match(s, 0, 1.0)};
  WeightChanges changes;
  StaticForgetting policy;
  policy.Apply(At(matches, 0, 0, 0.1), s, &changes);
  EXPECT_FALSE(policy.AdaptsMap());
  EXPECT_EQ(s.views(), before.views());
  EXPECT_TRUE(changes.touched_views.empty());
  EXPECT_TRUE(changes.last_rule.empty());
}

// The mode option selects the implementation.
TEST(ForgettingPolicy, ModeSelectsTheImplementation) {
  for (const ForgettingMode mode :
       {ForgettingMode::kActive, ForgettingMode::kPassive, ForgettingMode::kStatic}) {
    EnvironmentModelOptions o;
    o.forgetting.mode = mode;
    const auto policy = MakeForgettingPolicy(o);
    EXPECT_EQ(policy->mode(), mode);
    EXPECT_EQ(policy->AdaptsMap(), mode != ForgettingMode::kStatic);
  }
}

}  // namespace
}  // namespace omnicml
