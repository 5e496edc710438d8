#include "omnicml/mapping/environment_model.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "testing/fake_descriptor.h"
#include "testing/model_helpers.h"

#include <opencv2/imgproc.hpp>

#include "omnicml/common/options.h"
#include "omnicml/descriptors/descriptor_factory.h"

namespace omnicml {
namespace {

using testing::Bytes;

using testing::FakeDescriptorExtractor;
using testing::MakeFakeExtractor;

constexpr double kTol = 1e-12;

Gaussian Est(double x, double y, double phi, double sx = 0.1, double sy = 0.1, double sphi = 0.1) {
  Gaussian g;
  g.mean = MakePose(x, y, phi);
  g.covariance = Eigen::Vector3d(sx * sx, sy * sy, sphi * sphi).asDiagonal();
  return g;
}

// Feeds `passes` passes through the origin, each of `updates` Updates that see appearance
// {0} with an estimate of standard deviation sigma_m, 100 frames apart (so separate passes
// for the pass bookkeeping of rule (18)); returns the next free frame.
std::int64_t SeeOriginOnPasses(EnvironmentModel& m, FakeDescriptorExtractor& fx, int passes,
                               int updates, double sigma_m) {
  std::int64_t frame = 0;
  for (int pass = 0; pass < passes; ++pass) {
    for (int k = 0; k < updates; ++k) m.Update(fx.Make({0}), Est(0, 0, 0, sigma_m), {frame++, 0});
    frame += 100;
  }
  return frame;
}

// The component of a view with the largest id (the one added last).
const ViewComponent& Newest(const ReferenceView& v) {
  return *std::max_element(
      v.components.begin(), v.components.end(),
      [](const ViewComponent& a, const ViewComponent& b) { return a.id < b.id; });
}

const ReferenceView& ViewById(const EnvironmentModel& m, std::uint64_t id) {
  const auto index = m.FindView(id);
  OMNICML_CHECK(index.has_value()) << "no view " << id;
  return m.views()[*index];
}

// Squared Mahalanobis distance, written out independently of the library.
double TestSquaredMahalanobis(const Pose2& a, const Pose2& b, const Eigen::Matrix3d& s) {
  Eigen::Vector3d d = a - b;
  d.z() = std::remainder(d.z(), kTwoPi);
  return d.dot(s.inverse() * d);
}

// The options these tests were written against, given explicitly (the struct's
// defaults are the engine's, docs/design.md "Defaults and their measurements").
EnvironmentModelOptions TestOptions() {
  EnvironmentModelOptions o;
  o.retrieval.e_max = 1.0;
  o.retrieval.top_k = 0;
  o.update.beta = 0.1;
  o.update.d_max = 3.0;
  o.forgetting.d_for_m = 2.0;
  o.forgetting.beta_for = 0.1;
  o.forgetting.d_gain_m = 0.2;
  o.update.look_back_frames = 0;  // LookBack* tests switch it on
  return o;
}

// The sectioned YAML layout round-trips every field exactly.
TEST(EnvironmentModelOptions, SectionsRoundTripThroughYaml) {
  std::mt19937 rng(11);
  EnvironmentModelOptions o;
  RandomizeOptions(&o, rng);
  const std::string yaml = OptionsToYaml(o);
  EXPECT_NE(yaml.find("retrieval:"), std::string::npos) << yaml;
  EXPECT_NE(yaml.find("forgetting:"), std::string::npos) << yaml;
  EnvironmentModelOptions back;
  OptionsFromValue(ParseOptionYaml(yaml, "t.yaml"), OptionSource{"t.yaml", true, {}}, &back);
  EXPECT_TRUE(SameOptions(o, back));
}

// The former flat keys still load into their sections ("forgetting" holding a mode name
// is the former mode key); a section wins over a flat key given as well.
TEST(EnvironmentModelOptions, FlatKeysStillLoad) {
  const EnvironmentModelOptions o = ParseOptionsYaml<EnvironmentModelOptions>(
      "e_max: 0.3\nforgetting: passive\nmax_events: 7\nann_k: 5\nlook_back_frames: 3\n",
      "flat.yaml");
  EXPECT_EQ(o.retrieval.e_max, 0.3);
  EXPECT_EQ(o.forgetting.mode, ForgettingMode::kPassive);
  EXPECT_EQ(o.events.max_events, 7);
  EXPECT_EQ(o.index.ann_k, 5);
  EXPECT_EQ(o.update.look_back_frames, 3);
  const EnvironmentModelOptions both = ParseOptionsYaml<EnvironmentModelOptions>(
      "top_k: 3\nretrieval: {top_k: 4}\nforgetting: {mode: static}\n", "both.yaml");
  EXPECT_EQ(both.retrieval.top_k, 4);
  EXPECT_EQ(both.forgetting.mode, ForgettingMode::kStatic);
  EXPECT_THROW(ParseOptionsYaml<EnvironmentModelOptions>("e_maxx: 1\n", "bad.yaml"), Error);
}

// The engine file's flat layout holds every field under its former key, in the former
// order, and groups back to the same options.
TEST(EnvironmentModelOptions, FlatTreeGroupsBackToTheSameOptions) {
  std::mt19937 rng(5);
  EnvironmentModelOptions o;
  RandomizeOptions(&o, rng);
  const OptionValue flat = FlatModelOptionsValue(OptionsToValue(o));
  std::vector<std::string> keys;
  for (const auto& [k, v] : flat.members) {
    if (v.kind == OptionValue::Kind::kMap) {
      // Options added after the flat layout (Since) have no flat key; they stay in their
      // section, and the section merges back into the grouped one.
      ASSERT_EQ(v.members.size(), 1u) << k;
      if (k == "update") {
        EXPECT_EQ(v.members[0].first, "merge_fusion");
      } else {
        EXPECT_EQ(k, "forgetting");
        EXPECT_EQ(v.members[0].first, "persistence_min_probability");
      }
      continue;
    }
    EXPECT_EQ(v.kind, OptionValue::Kind::kScalar) << k;
    keys.push_back(k);
  }
  ASSERT_EQ(keys.size(), 30u);
  EXPECT_EQ(keys.front(), "e_max");
  EXPECT_EQ(keys[11], "forgetting");
  EXPECT_EQ(keys.back(), "ann_k");
  EnvironmentModelOptions back;
  OptionsFromValue(GroupedModelOptionsValue(flat), OptionSource{"flat", true, {}}, &back);
  EXPECT_TRUE(SameOptions(o, back));
}

// Each invalid option is rejected with an Error naming its field.
TEST(EnvironmentModelOptions, ValidateNamesTheField) {
  EXPECT_NO_THROW(EnvironmentModelOptions{}.Validate());
  auto expect_field = [](EnvironmentModelOptions o, const std::string& field) {
    try {
      o.Validate();
      ADD_FAILURE() << field << " accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  EnvironmentModelOptions o;
  o.retrieval.e_max = 0;
  expect_field(o, "e_max");
  o = {};
  o.retrieval.top_k = -1;
  expect_field(o, "top_k");
  o = {};
  o.update.beta = 1.5;
  expect_field(o, "beta");
  o = {};
  o.update.d_max = -1;
  expect_field(o, "d_max");
  o = {};
  o.forgetting.d_for_m = 0;
  expect_field(o, "d_for_m");
  o = {};
  o.forgetting.beta_for = -0.1;
  expect_field(o, "beta_for");
  o = {};
  o.forgetting.d_gain_m = std::nan("");
  expect_field(o, "d_gain_m");
  o = {};
  o.update.w_min = 1.0;
  expect_field(o, "w_min");
  o = {};
  o.update.merge_delta = -1;
  expect_field(o, "merge_delta");
  o = {};
  o.retrieval.heading_sigma_no_rotation_rad = 0;
  expect_field(o, "heading_sigma_no_rotation_rad");
  o = {};
  o.index.spatial_cell_m = 0;
  expect_field(o, "spatial_cell_m");
  o = {};
  o.events.max_events = -1;
  expect_field(o, "max_events");
  o = {};
  o.update.look_back_frames = -1;
  expect_field(o, "look_back_frames");
  o = {};
  o.forgetting.persistence_min_probability = 1.0;
  expect_field(o, "forgetting.persistence_min_probability");
  o.forgetting.persistence_min_probability = -0.1;
  expect_field(o, "forgetting.persistence_min_probability");
  EXPECT_EQ(ForgettingModeFromString(ToString(ForgettingMode::kPassive)), ForgettingMode::kPassive);
  EXPECT_EQ(ForgettingModeFromString("static"), ForgettingMode::kStatic);
  EXPECT_THROW(ForgettingModeFromString("sometimes"), Error);
}

// FindMatchesNear compares only the views with a component inside one of the discs: a
// disc over every view gives FindMatches' result; a disc that leaves a matching view out
// drops exactly that view.
TEST(EnvironmentModel, FindMatchesNearComparesOnlyViewsInTheDiscs) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  EnvironmentModel m(o, fx);
  // Five views of nearly the same look 2 m apart along x (AddView: no matching needed).
  for (int k = 0; k < 5; ++k) {
    ViewComponent c;
    c.mean = MakePose(2.0 * k, 0.0, 0.0);
    c.covariance = Eigen::Vector3d(0.01, 0.01, 0.01).asDiagonal();
    c.weight = 0.5;
    c.eta = 1.0;
    ViewStats stats;
    stats.created_frame = k;
    m.AddView(fx->Make({0.1f * static_cast<float>(k), 0.0f}), {c}, stats);
  }
  const Descriptor y = fx->Make({0.2f, 0.0f});
  const std::vector<ViewMatch> all = m.FindMatches(y);
  ASSERT_EQ(all.size(), 5u);
  std::size_t candidates = 0;
  const std::vector<ViewMatch> wide = m.FindMatchesNear(y, {{4.0, 0.0, 100.0}}, &candidates);
  EXPECT_EQ(candidates, 5u);
  ASSERT_EQ(wide.size(), all.size());
  for (std::size_t i = 0; i < all.size(); ++i) {
    EXPECT_EQ(wide[i].view_id, all[i].view_id);
    EXPECT_EQ(wide[i].distance, all[i].distance);
  }
  // Discs around x = 0 and x = 8 (radius 2.5 m): views at 0, 2 and 6, 8; the one at 4 m
  // is not compared. Overlapping discs count a view once.
  const std::vector<ViewMatch> near =
      m.FindMatchesNear(y, {{0.0, 0.0, 2.5}, {8.0, 0.0, 2.5}, {1.0, 0.0, 1.5}}, &candidates);
  EXPECT_EQ(candidates, 4u);
  ASSERT_EQ(near.size(), 4u);
  std::vector<ViewMatch> expected;
  for (const ViewMatch& v : all) {
    if (v.view_id != m.views()[2].id) expected.push_back(v);
  }
  for (std::size_t i = 0; i < near.size(); ++i) EXPECT_EQ(near[i].view_id, expected[i].view_id);
  EXPECT_TRUE(m.FindMatchesNear(y, {}).empty());
}

// Insertion happens exactly when every E >= e_max (boundary E == e_max inserts).
TEST(EnvironmentModel, InsertionExactlyWhenEveryDistanceAtLeastEmax) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 1.0;
  EnvironmentModel m(o, fx);
  EXPECT_TRUE(m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0}).view_inserted);
  EXPECT_TRUE(m.Update(fx->Make({1, 0}), Est(1, 0, 0), {1, 0}).view_inserted);  // E = 1 = e_max
  EXPECT_EQ(m.NumViews(), 2u);
  EXPECT_FALSE(m.Update(fx->Make({0, 0.9999f}), Est(0, 1, 0), {2, 0}).view_inserted);
  EXPECT_FALSE(m.Update(fx->Make({0.5f, 0}), Est(0.5, 0, 0), {3, 0}).view_inserted);
  EXPECT_TRUE(m.Update(fx->Make({-1, 0}), Est(-1, 0, 0), {4, 0}).view_inserted);
  EXPECT_EQ(m.NumViews(), 3u);
  ASSERT_FALSE(m.events().empty());
  EXPECT_EQ(m.events().back().type, MapEventType::kViewInserted);
  EXPECT_EQ(m.events().back().reason, "no view within e_max");
  EXPECT_EQ(m.events().back().frame, 4);

  // Random descriptors: insertion iff the brute-force minimum distance is >= e_max.
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 4.0f);
  auto f4 = MakeFakeExtractor(4);
  EnvironmentModelOptions o4 = TestOptions();
  o4.retrieval.e_max = 1.0;
  o4.forgetting.mode = ForgettingMode::kPassive;
  EnvironmentModel r(o4, f4);
  for (int t = 0; t < 300; ++t) {
    const Descriptor y = f4->Make({u(rng), u(rng), u(rng), u(rng)});
    double min_e = std::numeric_limits<double>::infinity();
    for (const ReferenceView& v : r.views()) min_e = std::min(min_e, f4->Distance(y, v.descriptor));
    const std::size_t before = r.NumViews();
    const UpdateStats s = r.Update(y, Est(u(rng), u(rng), 0), {t, 0});
    EXPECT_EQ(s.view_inserted, min_e >= o4.retrieval.e_max) << "t=" << t;
    EXPECT_EQ(r.NumViews(),
              before + (s.view_inserted ? 1 : 0) - static_cast<std::size_t>(s.views_removed));
  }
}

// eta of the new components follows (11): S_i / sum_l S_l over matching views; their
// weight is raised from 0 by (16) to beta * S_i.
TEST(EnvironmentModel, EtaFollowsEq11) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 2.0;
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});
  m.Update(fx->Make({3, 0}), Est(5, 0, 0), {1, 0});
  ASSERT_EQ(m.NumViews(), 2u);
  const Descriptor y = fx->Make({1.2f, 0});
  const double s_a = 1.0 - fx->Distance(y, m.views()[0].descriptor) / o.retrieval.e_max;
  const double s_b = 1.0 - fx->Distance(y, m.views()[1].descriptor) / o.retrieval.e_max;
  ASSERT_GT(s_a, 0);
  ASSERT_GT(s_b, 0);
  const UpdateStats st = m.Update(y, Est(20, 20, 0), {2, 0});
  EXPECT_EQ(st.matching_views, 2);
  EXPECT_EQ(st.components_added, 2);
  const ViewComponent& a = Newest(m.views()[0]);
  const ViewComponent& b = Newest(m.views()[1]);
  EXPECT_NEAR(a.eta, s_a / (s_a + s_b), kTol);
  EXPECT_NEAR(b.eta, s_b / (s_a + s_b), kTol);
  EXPECT_NEAR(a.weight, o.update.beta * s_a, kTol);
  EXPECT_NEAR(b.weight, o.update.beta * s_b, kTol);
  EXPECT_EQ(m.views()[0].stats.observations, 2);
  EXPECT_EQ(m.views()[0].stats.last_seen_frame, 2);
}

// Rule (16): a component within d_max of mu_t moves to beta S + (1 - beta S) w.
TEST(EnvironmentModel, WeightIncreaseEq16) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.update.merge_delta = 0.0;  // keep components apart so each rule acts on its own component
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});
  const double w0 = m.views()[0].components[0].weight;
  EXPECT_NEAR(w0, o.update.beta, kTol);
  const Descriptor y = fx->Make({0.3f, 0});
  const double bs =
      o.update.beta * (1.0 - fx->Distance(y, m.views()[0].descriptor) / o.retrieval.e_max);
  const UpdateStats st = m.Update(y, Est(0.1, 0, 0), {1, 0});
  ASSERT_EQ(m.views()[0].components.size(), 2u);
  EXPECT_NEAR(m.views()[0].components[0].weight, bs + (1 - bs) * w0, kTol);
  EXPECT_GT(m.views()[0].components[0].weight, w0);
  EXPECT_NEAR(m.views()[0].components[1].weight, bs, kTol);
  EXPECT_EQ(st.components_increased, 2);
  EXPECT_EQ(st.components_passive_forgotten, 0);
}

// Rule (17): a component of a matching view farther than d_max from mu_t decays by (1 - beta S).
TEST(EnvironmentModel, PassiveForgettingEq17) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.update.merge_delta = 0.0;
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});
  const double w0 = m.views()[0].components[0].weight;
  const Descriptor y = fx->Make({0.3f, 0});
  const double bs =
      o.update.beta * (1.0 - fx->Distance(y, m.views()[0].descriptor) / o.retrieval.e_max);
  // d = |(0.5, 0)| / sqrt(0.02) = 3.54 > d_max = 3.
  const Pose2 a = m.views()[0].components[0].mean;
  const double d =
      std::sqrt(TestSquaredMahalanobis(MakePose(0.5, 0, 0), a, Est(0, 0, 0).covariance * 2));
  ASSERT_GT(d, o.update.d_max);
  const UpdateStats st = m.Update(y, Est(0.5, 0, 0), {1, 0});
  EXPECT_NEAR(m.views()[0].components[0].weight, (1 - bs) * w0, kTol);
  EXPECT_EQ(st.components_passive_forgotten, 1);
  // Just inside d_max the same update increases instead.
  EnvironmentModel m2(o, fx);
  m2.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});
  m2.Update(y, Est(0.4, 0, 0), {1, 0});  // d = 2.83 <= 3
  EXPECT_NEAR(m2.views()[0].components[0].weight, bs + (1 - bs) * w0, kTol);
}

// Rules (18)-(19): components of non-matching views within d_for lose the fraction b;
// farther ones are untouched; b is clamped to 1 (then the view disappears, logged).
TEST(EnvironmentModel, ActiveForgettingEq18And19) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.forgetting.d_for_m = 2.0;
  o.forgetting.beta_for = 0.5;
  o.forgetting.d_gain_m = 0.2;
  o.forgetting.forget_min_missed_passes = 0;  // the first miss counts (passes: see below)
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});  // view A at (0, 0)
  m.Update(fx->Make({0, 5}), Est(3, 0, 0), {1, 0});  // view C at (3, 0), 2.8 m from mu_t below
  const double w_a = ViewById(m, 1).components[0].weight;
  const double w_c = ViewById(m, 2).components[0].weight;
  // Non-matching y at mu_t = (0.2, 0), sigma_x + sigma_y = 0.2 + 0.3. A's footprint is the
  // point (0, 0), so its distance is 0.2 / sigma_x = 1 < footprint_gate 2.
  const UpdateStats st = m.Update(fx->Make({5, 0}), Est(0.2, 0, 0, 0.2, 0.3, 0.1), {2, 0});
  EXPECT_TRUE(st.view_inserted);
  const double b = 0.5 * (1.0 - 1.0 / 2.0) * 0.2 / (0.2 + 0.3);
  EXPECT_NEAR(ViewById(m, 1).components[0].weight, (1 - b) * w_a, kTol);
  EXPECT_EQ(ViewById(m, 2).components[0].weight, w_c);
  EXPECT_EQ(st.components_active_forgotten, 1);

  // Outside the footprint (mu_t 0.5 m from it, sigma 0.1 m: distance 5 > 2) nothing is
  // forgotten, although A is within d_for.
  const double w_a2 = ViewById(m, 1).components[0].weight;
  const UpdateStats outside = m.Update(fx->Make({9, 0}), Est(0.5, 0, 0), {3, 0});
  EXPECT_EQ(outside.components_active_forgotten, 0);
  EXPECT_EQ(ViewById(m, 1).components[0].weight, w_a2);

  // A very confident estimate makes b > 1, clamped to 1: A is gone.
  m.Update(fx->Make({5, 0}), Est(0, 0, 0, 1e-4, 1e-4, 0.1), {4, 0});
  EXPECT_FALSE(m.FindView(1).has_value());
  bool saw_component = false, saw_view = false;
  for (const MapEvent& e : m.events()) {
    if (e.view_id != 1 || e.frame != 4) continue;
    if (e.type == MapEventType::kComponentRemoved) {
      saw_component = true;
      EXPECT_EQ(e.reason, "active forgetting (18)-(19)");
      EXPECT_EQ(e.weight, 0.0);
    }
    if (e.type == MapEventType::kViewRemoved) {
      saw_view = true;
      EXPECT_EQ(e.reason, "view empty");
    }
  }
  EXPECT_TRUE(saw_component);
  EXPECT_TRUE(saw_view);
  m.CheckInvariants();
}

// (12)-(14): a new component within delta merges; eta is summed, the mean and covariance
// are the weighted moments of the pair (across the +-pi seam), w is summed and then
// raised by (16). The weights are [G]'s eta shares, or eta times the xy precision
// 1 / sqrt(det C_xy) with merge_precision_weighted.
class MergeWeights : public ::testing::TestWithParam<bool> {};

TEST_P(MergeWeights, MergeKeepsEtaMeanAndCovariance) {
  const bool precision_weighted = GetParam();
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.update.merge_delta = 1.0;
  o.update.merge_fusion = MergeFusion::kMomentMatching;  // [G] (13)-(14)
  o.update.merge_precision_weighted = precision_weighted;
  EnvironmentModel m(o, fx);
  const Descriptor y = fx->Make({0, 0});
  m.Update(y, Est(0, 0, kPi - 0.05, 0.5, 0.5, 0.2), {0, 0});
  const std::vector<Gaussian> steps = {Est(0.2, -0.1, -kPi + 0.05, 0.4, 0.6, 0.3),
                                       Est(-0.1, 0.15, kPi - 0.1, 0.5, 0.3, 0.25)};
  for (std::size_t k = 0; k < steps.size(); ++k) {
    ASSERT_EQ(m.views()[0].components.size(), 1u);
    const ViewComponent before = m.views()[0].components[0];
    const Gaussian& g = steps[k];
    ASSERT_LT(TestSquaredMahalanobis(g.mean, before.mean, g.covariance + before.covariance),
              o.update.merge_delta);
    const UpdateStats st = m.Update(y, g, {static_cast<std::int64_t>(k) + 1, 0});
    EXPECT_EQ(st.components_merged, 1);
    ASSERT_EQ(m.views()[0].components.size(), 1u);
    const ViewComponent& after = m.views()[0].components[0];
    EXPECT_EQ(after.id, before.id);
    // The new component has eta = 1 (single match); the pair's weights are eta-shares.
    const double eta_new = 1.0;
    EXPECT_NEAR(after.eta, before.eta + eta_new, kTol);
    const auto precision = [&](const Eigen::Matrix3d& c) {
      return precision_weighted ? 1.0 / std::sqrt(c.topLeftCorner<2, 2>().determinant()) : 1.0;
    };
    const double wa = before.eta * precision(before.covariance);
    const double wb = eta_new * precision(g.covariance);
    const double a = wa / (wa + wb), b = wb / (wa + wb);
    Eigen::Vector3d other = g.mean;
    other.z() = before.mean.z() + std::remainder(g.mean.z() - before.mean.z(), kTwoPi);  // unwrap
    Eigen::Vector3d mean = a * before.mean + b * other;
    const Eigen::Vector3d d1 = before.mean - mean, d2 = other - mean;
    const Eigen::Matrix3d cov =
        a * (before.covariance + d1 * d1.transpose()) + b * (g.covariance + d2 * d2.transpose());
    mean.z() = std::remainder(mean.z(), kTwoPi);
    EXPECT_NEAR(after.mean.x(), mean.x(), kTol);
    EXPECT_NEAR(after.mean.y(), mean.y(), kTol);
    EXPECT_NEAR(std::remainder(after.mean.z() - mean.z(), kTwoPi), 0.0, kTol);
    EXPECT_GT(std::abs(after.mean.z()), 3.0);  // near pi, not averaged to 0
    EXPECT_TRUE(after.covariance.isApprox(cov, 1e-12)) << after.covariance << "\n" << cov;
    // w summed (w + 0) then (16) with S = 1 since mu_t is close to the merged mean.
    EXPECT_NEAR(after.weight, o.update.beta + (1 - o.update.beta) * before.weight, kTol);
  }
}

INSTANTIATE_TEST_SUITE_P(EnvironmentModel, MergeWeights, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& info) {
                           return info.param ? "PrecisionWeighted" : "EtaShares";
                         });

// With merge_precision_weighted, a component known to centimetres (a survey pose) moves
// a few centimetres when the view keeps matching at biased, uncertain estimates (0.065 m
// after 40 of them 0.2 m off), while [G]'s eta shares drag it most of the way to their
// mean (0.19 m).
TEST(EnvironmentModel, PreciseComponentIsNotDraggedByUncertainMatches) {
  auto fx = MakeFakeExtractor(2);
  const Descriptor y = fx->Make({0, 0});
  double moved[2];
  for (const bool precision_weighted : {false, true}) {
    EnvironmentModelOptions o = TestOptions();
    o.update.merge_delta = 9.0;  // every estimate below merges (squared Mahalanobis < 9)
    o.update.merge_precision_weighted = precision_weighted;
    EnvironmentModel m(o, fx);
    m.Update(y, Est(0, 0, 0, 0.02, 0.02, 0.01), {0, 0});  // the survey pose
    std::mt19937 rng(7);
    std::normal_distribution<double> noise(0.0, 0.1);
    for (std::int64_t t = 1; t <= 40; ++t) {
      // Estimates 0.2 m off in x on average, sigma 0.25 m: uncertain and biased.
      m.Update(y, Est(0.2 + noise(rng), noise(rng), 0, 0.25, 0.25, 0.05), {t, 0});
    }
    ASSERT_EQ(m.views()[0].components.size(), 1u);
    moved[precision_weighted] = m.views()[0].components[0].mean.head<2>().norm();
    m.CheckInvariants();
  }
  EXPECT_GT(moved[0], 0.15);  // eta shares: about the estimates' mean
  EXPECT_LT(moved[1], 0.1);   // precision weights: the precise component holds
  EXPECT_LT(moved[1], 0.4 * moved[0]) << moved[0] << " " << moved[1];
}

// A view confirmed again and again by estimates that scatter about its place: [G]'s
// moment matching (13)-(14) adds the scatter to the component's covariance at every merge,
// so the component ends up wider than any estimate it was built from; covariance
// intersection of estimates with equal covariances keeps that covariance exactly, and its
// mean is still the estimates' weighted mean.
TEST(EnvironmentModel, CovarianceIntersectionMergeDoesNotWidenWithScatter) {
  auto fx = MakeFakeExtractor(2);
  const Descriptor y = fx->Make({0, 0});
  const double sigma = 0.1;  // every estimate's standard deviation, metres
  double variance[2], offset[2];
  for (const MergeFusion fusion :
       {MergeFusion::kMomentMatching, MergeFusion::kCovarianceIntersection}) {
    EnvironmentModelOptions o = TestOptions();
    o.update.merge_delta = 25.0;  // every estimate below merges
    o.update.merge_fusion = fusion;
    EnvironmentModel m(o, fx);
    std::mt19937 rng(11);
    std::normal_distribution<double> noise(0.0, sigma);
    for (std::int64_t t = 0; t < 40; ++t) {
      m.Update(y, Est(noise(rng), noise(rng), 0, sigma, sigma, 0.05), {t, 0});
    }
    ASSERT_EQ(m.views()[0].components.size(), 1u);
    const ViewComponent& c = m.views()[0].components[0];
    const int i = fusion == MergeFusion::kCovarianceIntersection;
    variance[i] = c.covariance.topLeftCorner<2, 2>().eigenvalues().real().maxCoeff();
    offset[i] = c.mean.head<2>().norm();
    m.CheckInvariants();
  }
  EXPECT_GT(variance[0], 1.5 * sigma * sigma);                    // scatter added
  EXPECT_NEAR(variance[1], sigma * sigma, 1e-9 * sigma * sigma);  // (3) with C_n = C_m
  // Both means average the 40 draws (standard deviation of the mean 0.016 m).
  EXPECT_LT(offset[0], 0.06);
  EXPECT_LT(offset[1], 0.06);
}

// The convex combination keeps [G] (13)'s mean and replaces (14) by the bound of that
// mean's error for any correlation: with eta shares (merge_precision_weighted off) the
// merged mean equals moment matching's after every merge, whatever the covariances; with
// estimates of one covariance scattered about the place, the component keeps exactly that
// covariance (the bound of equal covariances), while moment matching adds the scatter.
TEST(EnvironmentModel, ConvexCombinationMergeKeepsTheMeanAndDropsTheScatter) {
  auto fx = MakeFakeExtractor(2);
  const Descriptor y = fx->Make({0, 0});
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.2);
  std::uniform_real_distribution<double> sigma(0.05, 0.4);
  for (const bool equal_covariances : {false, true}) {
    std::vector<Gaussian> estimates;
    for (int t = 0; t < 30; ++t) {
      const double sx = equal_covariances ? 0.1 : sigma(rng);
      const double sy = equal_covariances ? 0.1 : sigma(rng);
      estimates.push_back(Est(noise(rng), noise(rng), 0.1 * noise(rng), sx, sy, 0.05));
    }
    std::vector<ViewComponent> last;
    for (const MergeFusion fusion :
         {MergeFusion::kMomentMatching, MergeFusion::kConvexCombination}) {
      EnvironmentModelOptions o = TestOptions();
      o.update.merge_delta = 1e6;  // every estimate merges
      o.update.merge_precision_weighted = false;
      o.update.merge_fusion = fusion;
      EnvironmentModel m(o, fx);
      for (std::size_t t = 0; t < estimates.size(); ++t) {
        m.Update(y, estimates[t], {static_cast<std::int64_t>(t), 0});
        ASSERT_EQ(m.views()[0].components.size(), 1u);
      }
      m.CheckInvariants();
      last.push_back(m.views()[0].components[0]);
    }
    EXPECT_LT(PoseDifference(last[0].mean, last[1].mean).norm(), 1e-12);
    // Moment matching adds the scatter of the means (0.2 m) on top.
    EXPECT_GT(last[0].covariance(0, 0), last[1].covariance(0, 0) + 0.5 * 0.2 * 0.2);
    if (equal_covariances) {
      EXPECT_LT((last[1].covariance - estimates[0].covariance).norm(), 1e-9) << last[1].covariance;
    }
  }
}

// A component's spread is the scatter of the estimates merged into it about its mean:
// with equal covariances and one match each (equal eta), covariance intersection keeps
// the estimates' running average as the mean and the spread is their population
// covariance, whatever the order of the merges.
TEST(EnvironmentModel, SpreadIsTheScatterOfTheMergedEstimates) {
  auto fx = MakeFakeExtractor(2);
  const Descriptor y = fx->Make({0, 0});
  EnvironmentModelOptions o = TestOptions();
  o.update.merge_delta = 25.0;  // every estimate below merges
  o.update.merge_fusion = MergeFusion::kCovarianceIntersection;
  EnvironmentModel m(o, fx);
  std::mt19937 rng(5);
  std::normal_distribution<double> along(0.0, 0.3), across(0.0, 0.05);
  std::vector<Eigen::Vector2d> xy;
  for (std::int64_t t = 0; t < 30; ++t) {
    xy.emplace_back(1.0 + along(rng), 2.0 + across(rng));
    m.Update(y, Est(xy.back().x(), xy.back().y(), 0, 0.4, 0.4, 0.05), {t, 0});
    ASSERT_EQ(m.views()[0].components.size(), 1u);
  }
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const Eigen::Vector2d& p : xy) mean += p / static_cast<double>(xy.size());
  Eigen::Matrix2d scatter = Eigen::Matrix2d::Zero();
  for (const Eigen::Vector2d& p : xy)
    scatter += (p - mean) * (p - mean).transpose() / static_cast<double>(xy.size());
  const ViewComponent& c = m.views()[0].components[0];
  EXPECT_LT((c.mean.head<2>() - mean).norm(), 1e-9);
  EXPECT_LT((c.spread - scatter).norm(), 1e-9) << c.spread << "\n" << scatter;
  EXPECT_GT(c.spread(0, 0), 10.0 * c.spread(1, 1));  // elongated along x, as the draws
  m.CheckInvariants();
}

// A component created below w_min survives the Update that created it and is removed
// by a later Update that leaves it below w_min.
TEST(EnvironmentModel, NewComponentExemptFromRemovalOnce) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.update.w_min = 0.05;
  o.update.beta = 0.1;
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});
  const Descriptor weak = fx->Make({0.9f, 0});  // S ~ 0.1: beta S ~ 0.01 < w_min
  m.Update(weak, Est(10, 0, 0), {1, 0});
  ASSERT_EQ(m.views()[0].components.size(), 2u);
  const ViewComponent fresh = Newest(m.views()[0]);
  EXPECT_LT(fresh.weight, o.update.w_min);
  m.Update(weak, Est(10, 0, 0), {2, 0});  // merges into it, (16) leaves it below w_min
  for (const ViewComponent& c : m.views()[0].components) EXPECT_NE(c.id, fresh.id);
  ASSERT_FALSE(m.events().empty());
  EXPECT_EQ(m.events().back().type, MapEventType::kComponentRemoved);
  EXPECT_EQ(m.events().back().component_id, fresh.id);
  EXPECT_EQ(m.events().back().reason, "weight below w_min");
}

// Hypothesis: union of the matching views' components, weight w S normalised, headings
// rotated by the relative heading and wrapped; stored headings are view-relative.
TEST(EnvironmentModel, HypothesisRotatesHeadingsAndWeighsBySimilarity) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 2.0;
  o.update.merge_delta = 0.0;
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({0, 0}, 0.0), Est(1, 2, 3.0), {0, 0});   // view A, stored phi 3.0
  m.Update(fx->Make({3, 0}, 1.0), Est(-4, 0, 0.2), {1, 0});  // view B
  // Observed again at orientation 0.5 with heading 1.0: stored as 1.0 - 0.5.
  m.Update(fx->Make({0, 0}, 0.5), Est(1, 2.1, 1.0), {2, 0});
  ASSERT_EQ(m.views()[0].components.size(), 2u);
  EXPECT_NEAR(Newest(m.views()[0]).mean.z(), 0.5, 1e-6);

  const Descriptor q = fx->Make({1.5f, 0}, 0.5);  // E = 1.5 to both; rel to A: +0.5, to B: -0.5
  const std::vector<ViewMatch> matches = m.FindMatches(q);
  ASSERT_EQ(matches.size(), 2u);
  const Mixture h = m.Hypothesis(matches);
  ASSERT_EQ(h.size(), 3u);
  double total = 0.0;
  std::vector<double> expected_w;
  std::vector<double> expected_phi;
  for (const ViewMatch& mt : matches) {
    ASSERT_TRUE(mt.relative_heading_rad.has_value());
    for (const ViewComponent& c : m.views()[mt.view_index].components) {
      expected_w.push_back(c.weight * mt.similarity);
      expected_phi.push_back(WrapAngle(c.mean.z() + *mt.relative_heading_rad));
      total += c.weight * mt.similarity;
    }
  }
  double sum = 0.0;
  for (std::size_t k = 0; k < h.size(); ++k) {
    EXPECT_NEAR(h[k].weight, expected_w[k] / total, kTol);
    EXPECT_NEAR(h[k].mean.z(), expected_phi[k], 1e-9);
    EXPECT_GT(h[k].mean.z(), -kPi);
    EXPECT_LE(h[k].mean.z(), kPi);
    sum += h[k].weight;
  }
  EXPECT_NEAR(sum, 1.0, kTol);
  // A's first component: 3.0 + 0.5 wraps to 3.5 - 2 pi.
  EXPECT_NEAR(h[0].mean.z(), 3.5 - kTwoPi, 1e-6);
  EXPECT_NEAR(h[0].mean.x(), 1.0, kTol);
  // B's component: 0.2 - 0.5.
  EXPECT_NEAR(h[2].mean.z(), -0.3, 1e-6);
  EXPECT_TRUE(m.Hypothesis(fx->Make({50, 50})).empty());
}

// Descriptors without heading: headings are kept and the heading variance is inflated.
TEST(EnvironmentModel, HypothesisWithoutHeadingInflatesHeadingVariance) {
  auto fx = MakeFakeExtractor(2, /*provides_heading=*/false);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.heading_sigma_no_rotation_rad = 1.5;
  EnvironmentModel m(o, fx);
  const Gaussian g = Est(1, 2, 2.5, 0.1, 0.2, 0.3);
  m.Update(fx->Make({0, 0}), g, {0, 0});
  const Mixture h = m.Hypothesis(fx->Make({0.1f, 0}));
  ASSERT_EQ(h.size(), 1u);
  EXPECT_NEAR(h[0].mean.z(), 2.5, kTol);
  EXPECT_NEAR(h[0].covariance(2, 2), 0.09 + 2.25, kTol);
  EXPECT_NEAR(h[0].covariance(0, 0), 0.01, kTol);
  EXPECT_NEAR(h[0].weight, 1.0, kTol);
}

// top_k limits the hypothesis to the k most similar views; ties are broken by view id.
TEST(EnvironmentModel, TopKAndDeterministicOrder) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 1.5;
  o.retrieval.top_k = 2;
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({1, 0}), Est(0, 0, 0), {0, 0});
  m.Update(fx->Make({-1, 0}), Est(5, 0, 0), {1, 0});
  m.Update(fx->Make({0, 1.2f}), Est(10, 0, 0), {2, 0});
  ASSERT_EQ(m.NumViews(), 3u);
  const Descriptor q = fx->Make({0, 0});
  const auto all = m.FindAllMatches(q);
  ASSERT_EQ(all.size(), 3u);
  EXPECT_EQ(all[0].view_id, 1u);  // equal distance 1: lower id first
  EXPECT_EQ(all[1].view_id, 2u);
  EXPECT_EQ(all[2].view_id, 3u);
  const auto top = m.FindMatches(q);
  ASSERT_EQ(top.size(), 2u);
  const Mixture h = m.Hypothesis(q);
  ASSERT_EQ(h.size(), 2u);
  EXPECT_NEAR(h[0].mean.x(), 0.0, kTol);
  EXPECT_NEAR(h[1].mean.x(), 5.0, kTol);
}

// FindAllMatches equals a brute-force scan (E < e_max, sorted by distance then id).
TEST(EnvironmentModel, FindMatchesEqualsBruteForce) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 3.0f);
  auto fx = MakeFakeExtractor(3);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 0.8;
  EnvironmentModel m(o, fx);
  for (int t = 0; t < 400; ++t)
    m.Update(fx->Make({u(rng), u(rng), u(rng)}), Est(u(rng), u(rng), 0), {t, 0});
  for (int q = 0; q < 50; ++q) {
    const Descriptor y = fx->Make({u(rng), u(rng), u(rng)});
    std::vector<std::pair<double, std::uint64_t>> expected;
    for (const ReferenceView& v : m.views()) {
      const double e = fx->Distance(y, v.descriptor);
      if (e < o.retrieval.e_max) expected.emplace_back(e, v.id);
    }
    std::sort(expected.begin(), expected.end());
    const auto got = m.FindAllMatches(y);
    ASSERT_EQ(got.size(), expected.size());
    for (std::size_t k = 0; k < got.size(); ++k) {
      EXPECT_EQ(got[k].view_id, expected[k].second);
      EXPECT_EQ(got[k].distance, expected[k].first);
      EXPECT_EQ(m.views()[got[k].view_index].id, got[k].view_id);
    }
  }
}

// Active forgetting removes a view whose place changed for good; passive mode keeps it.
TEST(EnvironmentModel, ActiveForgetsChangedPlacePassiveKeepsIt) {
  auto fx = MakeFakeExtractor(2);
  std::mt19937 rng(11);
  std::normal_distribution<double> jitter(0.0, 0.05);
  for (const ForgettingMode mode : {ForgettingMode::kActive, ForgettingMode::kPassive}) {
    EnvironmentModelOptions o = TestOptions();
    o.forgetting.mode = mode;
    EnvironmentModel m(o, fx);
    const Descriptor before_change = fx->Make({0, 0});
    const Descriptor after_change = fx->Make({5, 0});  // E = 5 >= e_max: the place looks different
    for (int t = 0; t < 20; ++t) m.Update(before_change, Est(jitter(rng), jitter(rng), 0), {t, 0});
    ASSERT_EQ(m.NumViews(), 1u);
    const std::uint64_t old_view = m.views()[0].id;
    const double w_old = m.views()[0].TotalWeight();
    // Ten passes through the place (frames 100 apart between passes), 20 frames each.
    int last_frame = 0;
    for (int pass = 0; pass < 10; ++pass) {
      for (int k = 0; k < 20; ++k) {
        last_frame = 20 + 100 * pass + k;
        m.Update(after_change, Est(jitter(rng), jitter(rng), 0), {last_frame, 1});
      }
    }
    m.CheckInvariants();
    if (mode == ForgettingMode::kActive) {
      EXPECT_FALSE(m.FindView(old_view).has_value());
      EXPECT_EQ(m.NumViews(), 1u);
      const auto it = std::find_if(m.events().begin(), m.events().end(), [&](const MapEvent& e) {
        return e.type == MapEventType::kViewRemoved && e.view_id == old_view;
      });
      ASSERT_NE(it, m.events().end());
      EXPECT_EQ(it->session, 1);
      EXPECT_NEAR(it->position.x(), 0.0, 0.5);
      // The log tells the changed place apart from a new one: at the same place, the new
      // appearance was inserted and the old view's components were forgotten actively.
      const auto inserted =
          std::find_if(m.events().begin(), m.events().end(), [&](const MapEvent& e) {
            return e.type == MapEventType::kViewInserted && e.view_id != old_view;
          });
      ASSERT_NE(inserted, m.events().end());
      EXPECT_EQ(inserted->frame, 20);
      EXPECT_EQ(inserted->reason, "no view within e_max");
      EXPECT_NEAR(inserted->position.x(), 0.0, 0.5);
      for (const MapEvent& e : m.events()) {
        if (e.type == MapEventType::kComponentRemoved && e.view_id == old_view) {
          EXPECT_EQ(e.reason, "active forgetting (18)-(19)");
        }
      }
      // Counters of the new view.
      const ReferenceView& now = m.views()[0];
      EXPECT_EQ(now.stats.created_frame, 20);
      EXPECT_EQ(now.stats.created_session, 1);
      EXPECT_EQ(now.stats.observations, 200);
      EXPECT_EQ(now.stats.last_seen_frame, last_frame);
      EXPECT_EQ(now.stats.last_seen_session, 1);
      EXPECT_GT(now.TotalWeight(), 0.5);
    } else {
      ASSERT_TRUE(m.FindView(old_view).has_value());
      EXPECT_EQ(ViewById(m, old_view).TotalWeight(), w_old);
      EXPECT_EQ(m.NumViews(), 2u);
    }
  }
}

// The forgetting gains of the engine's defaults (the EnvironmentModelOptions defaults).
EnvironmentModelOptions EngineLikeOptions() {
  EnvironmentModelOptions o = TestOptions();
  o.forgetting.d_for_m = 0.5;
  o.forgetting.beta_for = 0.5;
  o.forgetting.d_gain_m = 1.0;
  return o;
}

// A static world is not forgotten: a robot drives back and forth along a corridor whose
// appearance changes every few centimetres (views match within ~3 cm, so every recent
// neighbour is a non-matching view nearby, the AntWorld failure); active keeps as many
// views as passive, although d_for is far larger than the views' spacing.
TEST(EnvironmentModel, StaticWorldIsNotForgotten) {
  auto fx = MakeFakeExtractor(1);
  std::mt19937 rng(3);
  std::normal_distribution<double> jitter(0.0, 0.003);
  std::normal_distribution<float> look(0.0f, 0.05f);
  std::size_t views[2] = {0, 0};
  for (const ForgettingMode mode : {ForgettingMode::kActive, ForgettingMode::kPassive}) {
    EnvironmentModelOptions o = EngineLikeOptions();
    o.forgetting.mode = mode;
    EnvironmentModel m(o, fx);
    int frame = 0;
    for (int session = 0; session < 4; ++session) {
      for (int lap = 0; lap < 3; ++lap) {
        for (int k = 0; k <= 200; ++k) {
          const double x = 0.01 * ((lap % 2 == 0) ? k : 200 - k);  // metres, 1 cm steps
          // Feature: 30 units per metre plus a little noise; e_max 1 = 3.3 cm.
          const Descriptor y = fx->Make({static_cast<float>(30.0 * x) + look(rng)});
          m.Update(y, Est(x + jitter(rng), jitter(rng), 0, 0.01, 0.01, 0.05), {frame++, session});
        }
        frame += 100;
      }
    }
    m.CheckInvariants();
    views[mode == ForgettingMode::kActive ? 0 : 1] = m.NumViews();
  }
  EXPECT_GT(views[1], 30u);
  EXPECT_GE(static_cast<double>(views[0]), 0.8 * static_cast<double>(views[1]))
      << "active " << views[0] << " passive " << views[1];
}

// One odd frame (or one odd pass) does not erase a place: a view seen on two passes that
// fails to match during a single pass but matches again on the next keeps its weight
// rising.
TEST(EnvironmentModel, OneMissedPassDoesNotForget) {
  auto fx = MakeFakeExtractor(1);
  EnvironmentModelOptions o = TestOptions();
  o.forgetting.d_for_m = 1.0;
  EnvironmentModel m(o, fx);
  for (int k = 0; k < 5; ++k) m.Update(fx->Make({0}), Est(0, 0, 0), {k, 0});
  for (int k = 0; k < 5; ++k) m.Update(fx->Make({0}), Est(0, 0, 0), {50 + k, 0});
  const std::uint64_t id = m.views()[0].id;
  ASSERT_EQ(ViewById(m, id).footprint.matched_passes, 2);
  const double w = m.views()[0].TotalWeight();
  // One pass in which the place looks different, then it looks as before again.
  for (int k = 0; k < 5; ++k) m.Update(fx->Make({9}), Est(0, 0, 0), {100 + k, 0});
  ASSERT_TRUE(m.FindView(id).has_value());
  EXPECT_EQ(ViewById(m, id).TotalWeight(), w);
  EXPECT_EQ(ViewById(m, id).footprint.missed_passes, 0);
  for (int k = 0; k < 5; ++k) m.Update(fx->Make({0}), Est(0, 0, 0), {200 + k, 0});
  EXPECT_EQ(ViewById(m, id).footprint.missed_passes, 0);
  // Two passes that miss: the first leaves the view as it is, the second forgets.
  const double w_before = ViewById(m, id).TotalWeight();
  for (int k = 0; k < 5; ++k) m.Update(fx->Make({9}), Est(0, 0, 0), {300 + k, 0});
  ASSERT_TRUE(m.FindView(id).has_value());
  EXPECT_EQ(ViewById(m, id).TotalWeight(), w_before);
  for (int k = 0; k < 5; ++k) m.Update(fx->Make({9}), Est(0, 0, 0), {400 + k, 0});
  ASSERT_TRUE(m.FindView(id).has_value() == false || ViewById(m, id).TotalWeight() < w_before);
  m.CheckInvariants();
}

// forget_unconfirmed_views: a view seen on its creation pass only is weakened from the
// first pass of its session that misses it (as ORB-SLAM culls recent map points not
// found again); with the option off, once it has matched on a second pass, or when the
// missed pass is in a later session (another day: AntWorld's replayed route, where a
// global start widens C_t), that first missed pass is free.
TEST(EnvironmentModel, UnconfirmedViewIsWeakenedOnItsFirstMissedPass) {
  auto fx = MakeFakeExtractor(1);
  auto after_one_missed_pass = [&](bool option, int matched_passes, int missed_session) {
    EnvironmentModelOptions o = TestOptions();
    o.forgetting.d_for_m = 1.0;
    o.forgetting.forget_unconfirmed_views = option;
    EnvironmentModel m(o, fx);
    const std::int64_t frame = SeeOriginOnPasses(m, *fx, matched_passes, 5, 0.1);
    const std::uint64_t id = m.views()[0].id;
    EXPECT_EQ(ViewById(m, id).footprint.matched_passes, matched_passes);
    const double w0 = ViewById(m, id).TotalWeight();
    // One later pass in which the place looks different.
    for (int k = 0; k < 5; ++k) {
      m.Update(fx->Make({9}), Est(0, 0, 0), {frame + k, missed_session});
    }
    m.CheckInvariants();
    const auto found = m.FindView(id);
    const double w1 = found ? ViewById(m, id).TotalWeight() : 0.0;
    return std::make_pair(w0, w1);
  };
  {
    const auto [w0, w1] = after_one_missed_pass(true, 1, 0);
    EXPECT_LT(w1, w0) << "an unconfirmed view loses weight on its first missed pass";
  }
  {
    const auto [w0, w1] = after_one_missed_pass(false, 1, 0);
    EXPECT_EQ(w1, w0) << "without the option the first missed pass is free";
  }
  {
    const auto [w0, w1] = after_one_missed_pass(true, 2, 0);
    EXPECT_EQ(w1, w0) << "a view confirmed on a second pass keeps the free missed pass";
  }
  {
    const auto [w0, w1] = after_one_missed_pass(true, 1, 1);
    EXPECT_EQ(w1, w0) << "a view of an earlier session keeps the free missed pass";
  }
}

// The creation pass itself never weakens the new view: frames of the same pass that see
// another appearance at the same place leave it as it is.
TEST(EnvironmentModel, UnconfirmedViewKeptDuringItsCreationPass) {
  auto fx = MakeFakeExtractor(1);
  EnvironmentModelOptions o = TestOptions();
  o.forgetting.d_for_m = 1.0;
  o.forgetting.forget_unconfirmed_views = true;
  EnvironmentModel m(o, fx);
  for (int k = 0; k < 3; ++k) m.Update(fx->Make({0}), Est(0, 0, 0), {k, 0});
  const std::uint64_t id = m.views()[0].id;
  const double w0 = ViewById(m, id).TotalWeight();
  for (int k = 3; k < 6; ++k) m.Update(fx->Make({9}), Est(0, 0, 0), {k, 0});
  ASSERT_TRUE(m.FindView(id).has_value());
  EXPECT_EQ(ViewById(m, id).TotalWeight(), w0);
  m.CheckInvariants();
}

// forget_by_matched_passes: (19)'s b is divided by the passes in which the view matched,
// so with the same missed passes a view matched on 3 passes loses 1/3 of the weight
// fraction a view matched on 1 pass loses (b unclamped here).
TEST(EnvironmentModel, ForgettingSlowsWithMatchedPasses) {
  auto fx = MakeFakeExtractor(1);
  auto decrement = [&](int matched_passes, bool by_passes) {
    EnvironmentModelOptions o = TestOptions();
    o.forgetting.d_for_m = 1.0;
    o.forgetting.forget_by_matched_passes = by_passes;
    o.forgetting.forget_unconfirmed_views =
        false;  // the same free first missed pass for every view
    EnvironmentModel m(o, fx);
    std::int64_t frame = SeeOriginOnPasses(m, *fx, matched_passes, 3, 0.5);
    const std::uint64_t id = m.views()[0].id;
    EXPECT_EQ(ViewById(m, id).footprint.matched_passes, matched_passes);
    const double w0 = ViewById(m, id).TotalWeight();
    // Two missed passes: the first is free (forget_min_missed_passes 1), the second
    // forgets with one Update.
    for (int k = 0; k < 3; ++k) m.Update(fx->Make({9}), Est(0, 0, 0, 0.5), {frame++, 0});
    frame += 100;
    m.Update(fx->Make({9}), Est(0, 0, 0, 0.5), {frame++, 0});
    EXPECT_TRUE(m.FindView(id).has_value());
    m.CheckInvariants();
    return 1.0 - ViewById(m, id).TotalWeight() / w0;  // the fraction b lost
  };
  const double once = decrement(1, true);
  const double thrice = decrement(3, true);
  ASSERT_GT(once, 0.0);
  ASSERT_LT(once, 1.0) << "b must not be clamped for the ratio to hold";
  EXPECT_NEAR(thrice, once / 3.0, 1e-12);
  EXPECT_NEAR(decrement(3, false), once, 1e-12) << "without the option passes do not matter";
}

// A world whose places change for good: after the change the old views go under active
// forgetting (within a few passes) and stay under passive.
TEST(EnvironmentModel, ChangedWorldIsForgotten) {
  auto fx = MakeFakeExtractor(2);
  std::mt19937 rng(4);
  std::normal_distribution<double> jitter(0.0, 0.02);
  for (const ForgettingMode mode : {ForgettingMode::kActive, ForgettingMode::kPassive}) {
    EnvironmentModelOptions o = EngineLikeOptions();
    o.forgetting.mode = mode;
    EnvironmentModel m(o, fx);
    int frame = 0;
    auto lap = [&](float appearance, int session) {
      for (int k = 0; k <= 50; ++k) {
        const double x = 0.2 * k;  // a 10 m corridor, 0.2 m steps; a view per 0.4 m
        const Descriptor y = fx->Make({static_cast<float>(2.5 * x), appearance});
        m.Update(y, Est(x + jitter(rng), jitter(rng), 0), {frame++, session});
      }
      frame += 100;
    };
    for (int l = 0; l < 3; ++l) lap(0.0f, 0);
    std::set<std::uint64_t> old_views;
    for (const ReferenceView& v : m.views()) old_views.insert(v.id);
    for (int l = 0; l < 6; ++l) lap(10.0f, 1);  // every place looks different now
    std::size_t old_left = 0;
    for (const ReferenceView& v : m.views()) old_left += old_views.count(v.id);
    m.CheckInvariants();
    if (mode == ForgettingMode::kActive) {
      EXPECT_LE(old_left, old_views.size() / 10) << old_left << " of " << old_views.size();
    } else {
      EXPECT_EQ(old_left, old_views.size());
    }
  }
}

// View persistence (persistence_min_probability): a corridor of 30 places, one pass per
// session, each place seen by 3 Updates. The world either changes for good (from session 4
// on, every other place shows a new appearance) or toggles (every place alternates between
// two appearances, a light switched on one day and off the next). (18)-(19) are made
// nearly inert (beta_for 0.01), so what removes views is the persistence belief.
struct CorridorResult {
  std::size_t old_changed_left = 0;  // views of the changed places' first appearance
  std::size_t old_kept_left = 0;     // views of the unchanged places
  std::size_t views = 0;
  double hazard = 0.0;
};

CorridorResult RunCorridor(bool toggling, double min_probability, int sessions,
                           std::vector<std::uint8_t>* saved_at_half = nullptr,
                           std::vector<std::uint8_t>* final_bytes = nullptr) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = EngineLikeOptions();
  o.forgetting.beta_for = 0.01;
  o.forgetting.forget_unconfirmed_views = false;
  o.forgetting.persistence_min_probability = min_probability;
  EnvironmentModel m(o, fx);
  constexpr int kPlaces = 30;
  std::set<std::uint64_t> changed_views, kept_views;
  std::int64_t frame = 0;
  for (int session = 0; session < sessions; ++session) {
    for (int k = 0; k < kPlaces; ++k) {
      const double x = 0.6 * k;
      float appearance = 0.0f;
      if (toggling) {
        appearance = (session % 2 == 0) ? 0.0f : 5.0f;
      } else if (k % 2 == 1 && session >= 4) {
        appearance = 10.0f;
      }
      for (int u = 0; u < 3; ++u) {
        m.Update(fx->Make({static_cast<float>(2.5 * x), appearance}), Est(x, 0, 0),
                 {frame++, session});
      }
      frame += 10;
    }
    frame += 100;
    if (session == 0) {
      for (const ReferenceView& v : m.views()) {
        const int k = static_cast<int>(std::lround(v.components.front().mean.x() / 0.6));
        (k % 2 == 1 ? changed_views : kept_views).insert(v.id);
      }
    }
    if (saved_at_half != nullptr && session == sessions / 2) *saved_at_half = Bytes(m);
  }
  m.CheckInvariants();
  CorridorResult r;
  for (const ReferenceView& v : m.views()) {
    r.old_changed_left += changed_views.count(v.id);
    r.old_kept_left += kept_views.count(v.id);
  }
  r.views = m.NumViews();
  r.hazard = m.view_persistence().hazard();
  if (final_bytes != nullptr) *final_bytes = Bytes(m);
  return r;
}

// Places that changed for good are removed once the map's passes show that misses do not
// come back; unchanged places stay; without the option the old views stay.
TEST(EnvironmentModel, PersistenceRemovesPlacesThatChangedForGood) {
  const CorridorResult with = RunCorridor(false, 0.5, 12);
  const CorridorResult without = RunCorridor(false, 0.0, 12);
  EXPECT_EQ(with.old_kept_left, 15u);
  EXPECT_EQ(with.old_changed_left, 0u);
  EXPECT_EQ(without.old_changed_left, 15u);
  EXPECT_GT(with.hazard, 0.0);
}

// Places whose appearance comes back every other session keep every view: the map's own
// passes say that a miss is followed by a match.
TEST(EnvironmentModel, PersistenceKeepsPlacesThatComeBack) {
  const CorridorResult with = RunCorridor(true, 0.5, 12);
  const CorridorResult without = RunCorridor(true, 0.0, 12);
  EXPECT_EQ(with.views, without.views);
  EXPECT_EQ(with.old_kept_left + with.old_changed_left, 30u);
}

// The counts and the belief are saved with the map: a model loaded halfway goes on as the
// one that never stopped.
TEST(EnvironmentModel, PersistenceSurvivesSerialize) {
  std::vector<std::uint8_t> half, end;
  RunCorridor(false, 0.5, 12, &half, &end);
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = EngineLikeOptions();
  o.forgetting.beta_for = 0.01;
  o.forgetting.forget_unconfirmed_views = false;
  o.forgetting.persistence_min_probability = 0.5;
  BinaryReader in(half, "half");
  EnvironmentModel copy = EnvironmentModel::Deserialize(in, o, fx);
  EXPECT_EQ(in.remaining(), 0u);
  EXPECT_EQ(Bytes(copy), half);
  EXPECT_GT(copy.view_persistence().passes(), 0);
  EXPECT_GT(copy.view_persistence().passes_at_fit(), 0);
}

// Footprints survive Serialize/Deserialize and grow with the matches.
TEST(EnvironmentModel, FootprintFollowsMatches) {
  auto fx = MakeFakeExtractor(1);
  EnvironmentModel m(TestOptions(), fx);
  for (int k = 0; k < 11; ++k) m.Update(fx->Make({0}), Est(0.1 * k, 0, 0), {k, 0});
  ASSERT_EQ(m.NumViews(), 1u);
  const ViewFootprint& f = m.views()[0].footprint;
  EXPECT_NEAR(f.mean.x(), 0.5, 1e-9);
  EXPECT_NEAR(f.Covariance()(0, 0), 0.1, 1e-9);  // variance of 0, 0.1, ..., 1.0
  EXPECT_NEAR(f.Covariance()(1, 1), 0.0, 1e-12);
  BinaryWriter w;
  m.Serialize(w);
  const std::vector<std::uint8_t> bytes = w.Release();
  BinaryReader r(bytes);
  const EnvironmentModel back = EnvironmentModel::Deserialize(r, TestOptions(), fx);
  EXPECT_EQ(back.views()[0].footprint, f);
}

// Static mode never changes the model (bytes identical), even when empty.
TEST(EnvironmentModel, StaticModeNeverChangesTheMap) {
  auto fx = MakeFakeExtractor(2);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 4.0f);
  EnvironmentModel m(TestOptions(), fx);
  for (int t = 0; t < 50; ++t) m.Update(fx->Make({u(rng), u(rng)}), Est(u(rng), u(rng), 0), {t, 0});
  const std::vector<std::uint8_t> frozen = Bytes(m);
  m.SetForgettingMode(ForgettingMode::kStatic);
  for (int t = 50; t < 150; ++t) {
    const UpdateStats s = m.Update(fx->Make({u(rng), u(rng)}), Est(u(rng), u(rng), 0), {t, 0});
    EXPECT_FALSE(s.view_inserted);
  }
  EXPECT_EQ(Bytes(m), frozen);
  EnvironmentModelOptions o = TestOptions();
  o.forgetting.mode = ForgettingMode::kStatic;
  EnvironmentModel empty(o, fx);
  empty.Update(fx->Make({1, 1}), Est(0, 0, 0), {0, 0});
  EXPECT_EQ(empty.NumViews(), 0u);
  EXPECT_TRUE(empty.events().empty());
}

// Over random updates: forgetting never raises a weight (non-matching views only lose
// weight), invariants hold, weights stay in [0, 1].
TEST(EnvironmentModel, ForgettingNeverRaisesWeight) {
  std::mt19937 rng(21);
  std::uniform_real_distribution<float> u(0.0f, 3.0f);
  std::uniform_real_distribution<double> p(0.0, 6.0);
  std::normal_distribution<float> noise(0.0f, 0.15f);
  auto fx = MakeFakeExtractor(3);
  std::vector<std::vector<float>> centres;
  for (int k = 0; k < 12; ++k) centres.push_back({u(rng), u(rng), u(rng)});
  for (const ForgettingMode mode : {ForgettingMode::kActive, ForgettingMode::kPassive}) {
    EnvironmentModelOptions o = TestOptions();
    o.forgetting.mode = mode;
    o.retrieval.e_max = 0.6;
    o.forgetting.d_for_m = 1.5;
    o.forgetting.beta_for = 0.3;
    o.forgetting.forget_min_missed_passes = 0;
    EnvironmentModel m(o, fx);
    int decreases = 0;
    for (int t = 0; t < 600; ++t) {
      std::vector<float> f = centres[rng() % centres.size()];
      for (float& v : f) v += noise(rng);
      const Descriptor y = fx->Make(f);
      std::set<std::uint64_t> matched;
      for (const ViewMatch& mt : m.FindAllMatches(y)) matched.insert(mt.view_id);
      std::map<std::uint64_t, double> before;
      for (const ReferenceView& v : m.views()) {
        if (matched.count(v.id)) continue;
        for (const ViewComponent& c : v.components) before[c.id] = c.weight;
      }
      m.Update(y, Est(p(rng), p(rng), 0, 0.2, 0.2, 0.2), {t, 0});
      for (const ReferenceView& v : m.views()) {
        for (const ViewComponent& c : v.components) {
          EXPECT_GE(c.weight, 0.0);
          EXPECT_LE(c.weight, 1.0);
          const auto it = before.find(c.id);
          if (it == before.end()) continue;
          EXPECT_LE(c.weight, it->second);
          if (c.weight < it->second) ++decreases;
        }
      }
      if (t % 50 == 0) m.CheckInvariants();
    }
    m.CheckInvariants();
    if (mode == ForgettingMode::kActive) {
      EXPECT_GT(decreases, 0);
    } else {
      EXPECT_EQ(decreases, 0);  // passive mode never touches non-matching views
    }
  }
}

// Serialize/Deserialize round trip is exact (same views, events, ids, bytes, and the
// same future), truncated or corrupted bytes and a mismatching extractor throw Error.
TEST(EnvironmentModel, SerializeRoundTripAndCorruption) {
  std::mt19937 rng(8);
  std::uniform_real_distribution<float> u(0.0f, 3.0f);
  auto fx = MakeFakeExtractor(3);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 0.7;
  o.events.log_component_events = true;
  o.update.look_back_frames = 10;  // the recent updates are saved too
  EnvironmentModel m(o, fx);
  for (int t = 0; t < 300; ++t) {
    m.Update(fx->Make({u(rng), u(rng), u(rng)}, u(rng)), Est(u(rng), u(rng), u(rng) - 1.5),
             {t, t / 100});
  }
  ASSERT_GT(m.NumViews(), 10u);
  const std::vector<std::uint8_t> bytes = Bytes(m);
  BinaryReader in(bytes, "model");
  EnvironmentModel copy = EnvironmentModel::Deserialize(in, o, fx);
  EXPECT_EQ(in.remaining(), 0u);
  copy.CheckInvariants();
  EXPECT_EQ(copy.views(), m.views());
  EXPECT_EQ(copy.events(), m.events());
  EXPECT_EQ(copy.next_view_id(), m.next_view_id());
  EXPECT_EQ(copy.next_component_id(), m.next_component_id());
  EXPECT_EQ(Bytes(copy), bytes);
  for (int t = 300; t < 350; ++t) {
    const Descriptor y = fx->Make({u(rng), u(rng), u(rng)}, u(rng));
    const Gaussian g = Est(u(rng), u(rng), 0);
    m.Update(y, g, {t, 2});  // the saved session goes on: the look-back uses what was saved
    copy.Update(y, g, {t, 2});
  }
  EXPECT_EQ(Bytes(copy), Bytes(m));

  for (std::size_t n = 0; n < bytes.size(); n += (n < 200 ? 1 : 997)) {
    std::vector<std::uint8_t> cut(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(n));
    BinaryReader r(cut, "cut");
    EXPECT_THROW(EnvironmentModel::Deserialize(r, o, fx), Error) << "prefix " << n;
  }
  std::vector<std::uint8_t> bad = bytes;
  bad[0] ^= 0xFF;
  BinaryReader r1(bad);
  EXPECT_THROW(EnvironmentModel::Deserialize(r1, o, fx), Error);
  BinaryReader r2(bytes);
  EXPECT_THROW(EnvironmentModel::Deserialize(r2, o, MakeFakeExtractor(4)), Error);
  BinaryReader r3(bytes);
  EXPECT_THROW(EnvironmentModel::Deserialize(r3, o, MakeFakeExtractor(3, false)), Error);
}

// Bad input is rejected and leaves the model unchanged.
TEST(EnvironmentModel, RejectsBadInputWithoutChange) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModel m(TestOptions(), fx);
  m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});
  const auto bytes = Bytes(m);
  EXPECT_THROW(m.Update(fx->Make({0, 0, 0}), Est(0, 0, 0), {1, 0}), Error);
  Gaussian bad = Est(0, 0, 0);
  bad.covariance(0, 0) = -1;
  EXPECT_THROW(m.Update(fx->Make({0, 0}), bad, {1, 0}), Error);
  bad = Est(0, 0, 0);
  bad.mean.x() = std::nan("");
  EXPECT_THROW(m.Update(fx->Make({0, 0}), bad, {1, 0}), Error);
  EXPECT_THROW(m.FindMatches(MakeFakeExtractor(2, false)->Make({0, 0})), Error);
  EXPECT_EQ(Bytes(m), bytes);
  EXPECT_THROW(EnvironmentModel(TestOptions(), nullptr), Error);
  // Matches from before a change are detected as stale when the view moved away.
  const auto matches = m.FindMatches(fx->Make({0, 0}));
  ASSERT_EQ(matches.size(), 1u);
  std::vector<ViewMatch> stale = matches;
  stale[0].view_id = 999;
  EXPECT_THROW(m.Hypothesis(stale), Error);
}

// With real Fourier signatures: a view learned at heading phi is recognised in a panorama
// rolled by k columns (the robot turned by k 2 pi / W) with heading phi + k 2 pi / W, and
// the rolled observation merges into the same stored component.
TEST(EnvironmentModel, RealFourierSignatureRecoversHeading) {
  std::shared_ptr<const DescriptorExtractor> fx = MakeDescriptorExtractor(DescriptorOptions{});
  cv::Mat noise(48, 360, CV_8UC1);
  cv::RNG cv_rng(17);
  cv_rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
  cv::Mat panorama;
  cv::GaussianBlur(noise, panorama, cv::Size(15, 5), 0, 0, cv::BORDER_REFLECT);
  const int k = 30;  // after[c] = before[(c + k) mod W]
  cv::Mat rolled;
  cv::hconcat(panorama.colRange(k, panorama.cols), panorama.colRange(0, k), rolled);
  const Descriptor y0 = fx->Compute(panorama);
  const Descriptor y1 = fx->Compute(rolled);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 1.0;
  EnvironmentModel m(o, fx);
  m.Update(y0, Est(1, 2, 0.7), {0, 0});
  const double turn = k * kTwoPi / panorama.cols;
  const auto matches = m.FindMatches(y1);
  ASSERT_EQ(matches.size(), 1u);
  EXPECT_GT(matches[0].similarity, 0.99);
  const Mixture h = m.Hypothesis(matches);
  ASSERT_EQ(h.size(), 1u);
  EXPECT_NEAR(h[0].mean.z(), 0.7 + turn, 0.01);
  EXPECT_NEAR(h[0].mean.x(), 1.0, kTol);
  const UpdateStats s = m.Update(y1, Est(1.05, 2, 0.7 + turn), {1, 0});
  EXPECT_EQ(s.components_merged, 1);
  EXPECT_EQ(m.NumComponents(), 1u);
  EXPECT_NEAR(m.views()[0].components[0].mean.z(), 0.7, 0.01);
}

// The event log is a ring: laps over a static corridor keep the views flat while events
// (component events logged) keep coming; the ring, the per-session counts and the map's
// bytes stay bounded, the counts stay exact, and Serialize/Deserialize keep all three.
TEST(EnvironmentModel, EventLogIsABoundedRing) {
  auto fx = MakeFakeExtractor(1);
  EnvironmentModelOptions o = TestOptions();
  o.events.log_component_events = true;
  o.events.max_events = 50;
  EnvironmentModel m(o, fx);
  std::size_t bytes_after_lap_10 = 0, views_after_lap_10 = 0;
  std::uint64_t logged_after_lap_10 = 0;
  std::int64_t frame = 0;
  for (int lap = 0; lap < 40; ++lap) {
    for (int k = 0; k < 20; ++k, ++frame) {
      m.Update(fx->Make({10.0f * k}), Est(k, 0, 0), {frame, lap / 10});
    }
    if (lap == 9) {
      bytes_after_lap_10 = Bytes(m).size();
      views_after_lap_10 = m.NumViews();
      logged_after_lap_10 = m.events_logged();
    }
  }
  EXPECT_EQ(m.NumViews(), views_after_lap_10);
  EXPECT_EQ(m.events().size(), 50u);
  EXPECT_GT(m.events_logged(), logged_after_lap_10 + 500);
  EXPECT_EQ(m.first_event_number(), m.events_logged() - 50);
  EXPECT_EQ(m.events().back().frame, frame - 1);
  // The only growth: one counts entry (i32 session + 5 x i64) for each of 3 new sessions.
  EXPECT_LE(Bytes(m).size(), bytes_after_lap_10 + 3 * (4 + 5 * 8));
  // Exact counts: they add up to every event logged, one entry per session.
  std::int64_t total = 0;
  for (const auto& [session, n] : m.event_counts()) {
    total += n.views_inserted + n.views_removed + n.components_added + n.components_merged +
             n.components_removed;
  }
  EXPECT_EQ(static_cast<std::uint64_t>(total), m.events_logged());
  EXPECT_EQ(m.event_counts().size(), 4u);
  EXPECT_EQ(m.event_counts().at(0).views_inserted, 20);

  BinaryWriter w;
  m.Serialize(w);
  const std::vector<std::uint8_t> bytes = w.Release();
  BinaryReader r(bytes);
  const EnvironmentModel back = EnvironmentModel::Deserialize(r, o, fx);
  EXPECT_EQ(back.events(), m.events());
  EXPECT_EQ(back.events_logged(), m.events_logged());
  EXPECT_EQ(back.event_counts(), m.event_counts());
  EXPECT_EQ(Bytes(back), bytes);
  // Loaded with a smaller ring: the most recent events are kept.
  EnvironmentModelOptions smaller = o;
  smaller.events.max_events = 10;
  BinaryReader r2(bytes);
  const EnvironmentModel cut = EnvironmentModel::Deserialize(r2, smaller, fx);
  ASSERT_EQ(cut.events().size(), 10u);
  EXPECT_TRUE(std::equal(cut.events().begin(), cut.events().end(), m.events().end() - 10));
  EXPECT_EQ(cut.events_logged(), m.events_logged());
  // ClearEvents empties the ring only.
  EnvironmentModel cleared = back;
  cleared.ClearEvents();
  EXPECT_TRUE(cleared.events().empty());
  EXPECT_EQ(cleared.events_logged(), m.events_logged());
  EXPECT_EQ(cleared.event_counts(), m.event_counts());
}

}  // namespace
}  // namespace omnicml

namespace omnicml {
namespace {

// Look-back (look_back_frames): a new view also gets components at the preceding updates
// of its session whose descriptor matches it, newest first, up to the first that does not
// (weight beta * S, eta S, the update's pose and covariance, the footprint observed).
TEST(EnvironmentModel, LookBackGivesANewViewThePosesThatWouldHaveMatchedIt) {
  auto fx = MakeFakeExtractor(2);
  EnvironmentModelOptions o = TestOptions();
  o.retrieval.e_max = 1.0;
  o.update.look_back_frames = 10;
  EnvironmentModel m(o, fx);
  m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});     // view A
  m.Update(fx->Make({0.9f, 0}), Est(1, 0, 0), {1, 0});  // matches A; would match B
  m.Update(fx->Make({0.2f, 0}), Est(2, 0, 0), {2, 0});  // matches A, not B: look-back stops
  m.Update(fx->Make({0.95f, 0}), Est(3, 0, 0, 0.2, 0.3), {3, 0});  // matches A and B
  ASSERT_EQ(m.NumViews(), 1u);
  // A model saved here and loaded again looks back the same way (a resumed run's queued
  // updates are applied after loading).
  const std::vector<std::uint8_t> saved = Bytes(m);
  BinaryReader in(saved, "model");
  EnvironmentModel loaded = EnvironmentModel::Deserialize(in, o, fx);
  const UpdateStats st = m.Update(fx->Make({1.5f, 0}), Est(4, 0, 0), {4, 0});  // view B
  loaded.Update(fx->Make({1.5f, 0}), Est(4, 0, 0), {4, 0});
  EXPECT_EQ(Bytes(loaded), Bytes(m));
  ASSERT_TRUE(st.view_inserted);
  ASSERT_EQ(m.NumViews(), 2u);
  const ReferenceView& b = m.views()[1];
  ASSERT_EQ(b.components.size(), 2u);  // its own pose and frame 3's, not frames 2 or 1
  const ViewComponent& back = Newest(b);
  const double s3 = 1.0 - fx->Distance(fx->Make({0.95f, 0}), b.descriptor) / o.retrieval.e_max;
  EXPECT_NEAR(back.mean.x(), 3.0, kTol);
  EXPECT_NEAR(back.weight, o.update.beta * s3, kTol);
  EXPECT_NEAR(back.eta, s3, kTol);
  EXPECT_NEAR(back.covariance(0, 0), 0.04, kTol);
  EXPECT_NEAR(back.covariance(1, 1), 0.09, kTol);
  EXPECT_EQ(st.components_added, 2);                // the view's own and one looked back
  EXPECT_NEAR(b.footprint.weight, 1.0 + s3, kTol);  // its own match (S = 1) and frame 3
  // The spatial index knows the new component: rule (18)'s candidates near frame 3 include B.
  const std::vector<ViewMatch> near = m.FindMatchesNear(fx->Make({1.5f, 0}), {{3.0, 0.0, 0.1}});
  ASSERT_EQ(near.size(), 1u);
  EXPECT_EQ(near[0].view_id, b.id);
}

// No look-back across sessions, beyond look_back_frames, or with look_back_frames 0.
TEST(EnvironmentModel, LookBackStaysInItsSessionAndWindow) {
  auto fx = MakeFakeExtractor(2);
  const auto components_of_new_view = [&](int look_back, UpdateContext second,
                                          UpdateContext third) {
    EnvironmentModelOptions o = TestOptions();
    o.retrieval.e_max = 1.0;
    o.update.look_back_frames = look_back;
    EnvironmentModel m(o, fx);
    m.Update(fx->Make({0, 0}), Est(0, 0, 0), {0, 0});
    m.Update(fx->Make({0.9f, 0}), Est(1, 0, 0), second);
    OMNICML_CHECK(m.Update(fx->Make({1.4f, 0}), Est(2, 0, 0), third).view_inserted);
    return m.views().back().components.size();
  };
  EXPECT_EQ(components_of_new_view(10, {1, 0}, {2, 0}), 2u);
  EXPECT_EQ(components_of_new_view(10, {1, 0}, {2, 1}), 1u);   // another session
  EXPECT_EQ(components_of_new_view(10, {1, 0}, {12, 0}), 1u);  // 11 frames back
  EXPECT_EQ(components_of_new_view(10, {1, 0}, {11, 0}), 2u);  // 10 frames back
  EXPECT_EQ(components_of_new_view(0, {1, 0}, {2, 0}), 1u);
}

// The pose graph's map operations, on a passive model with two views (view 0 with an
// anisotropic covariance) and their state before the operation.
class PoseGraphMapOps : public ::testing::Test {
 protected:
  static EnvironmentModelOptions PassiveOptions() {
    EnvironmentModelOptions o = TestOptions();
    o.forgetting.mode = ForgettingMode::kPassive;
    return o;
  }
  void SetUp() override {
    m_.Update(fx_->Make({0, 0}), Est(2, 1, 0.3, 0.1, 0.3, 0.05), {0, 0});
    m_.Update(fx_->Make({5, 5}), Est(-4, 3, 0.0), {1, 0});
    ASSERT_EQ(m_.NumViews(), 2u);
    before0_ = m_.views()[0];
    before1_ = m_.views()[1];
  }
  // The changed model serialises and reads back to the same views.
  void ExpectReadsBack() const {
    BinaryWriter w;
    m_.Serialize(w);
    BinaryReader r(w.bytes(), "model");
    EXPECT_EQ(EnvironmentModel::Deserialize(r, o_, fx_).views(), m_.views());
  }

  std::shared_ptr<FakeDescriptorExtractor> fx_ = MakeFakeExtractor(2);
  EnvironmentModelOptions o_ = PassiveOptions();
  EnvironmentModel m_{o_, fx_};
  ReferenceView before0_;
  ReferenceView before1_;
};

// SetComponentCovariance (the pose graph's marginals): the component takes the covariance
// (symmetrised), its mean and weight and the other views stay, and the model serialises
// with it; a covariance that is not positive definite is refused (and the component
// keeps its own).
TEST_F(PoseGraphMapOps, SetComponentCovarianceReplacesOnlyTheCovariance) {
  Eigen::Matrix3d cov;
  cov << 0.04, 0.01, 0.0, 0.0, 0.02, 0.0, 0.0, 0.0, 0.001;
  m_.SetComponentCovariance(0, 0, cov);
  const ViewComponent& c = m_.views()[0].components.front();
  EXPECT_NEAR(c.covariance(0, 1), 0.005, kTol);
  EXPECT_NEAR(c.covariance(1, 0), 0.005, kTol);
  EXPECT_NEAR(c.covariance(0, 0), 0.04, kTol);
  EXPECT_NEAR(c.covariance(2, 2), 0.001, kTol);
  EXPECT_EQ(c.mean, before0_.components.front().mean);
  EXPECT_EQ(c.weight, before0_.components.front().weight);
  EXPECT_EQ(m_.views()[1], before1_);
  ExpectReadsBack();
  EXPECT_THROW(m_.SetComponentCovariance(0, 0, Eigen::Matrix3d::Zero()), InternalError);
  EXPECT_EQ(m_.views()[0].components.front().covariance(0, 0), 0.04);
}

// MoveViewRigidly (global pose graph): component means, headings and covariances and
// the footprint follow the anchor's rigid motion; other views stay; moving back
// restores the view.
TEST_F(PoseGraphMapOps, MoveViewRigidlyFollowsTheAnchor) {
  // Anchor (1, 1, 0) -> (5, 5, pi/2): the point (2, 1) is 1 m ahead of the anchor, so it
  // goes to (5, 6); the heading turns by pi/2; x and y variances swap.
  m_.MoveViewRigidly(0, MakePose(1, 1, 0), MakePose(5, 5, kPi / 2));
  const ViewComponent& c = m_.views()[0].components.front();
  EXPECT_NEAR(c.mean.x(), 5.0, kTol);
  EXPECT_NEAR(c.mean.y(), 6.0, kTol);
  EXPECT_NEAR(c.mean.z(), 0.3 + kPi / 2, kTol);
  EXPECT_NEAR(c.covariance(0, 0), 0.09, kTol);
  EXPECT_NEAR(c.covariance(1, 1), 0.01, kTol);
  EXPECT_NEAR(c.covariance(2, 2), 0.0025, kTol);
  EXPECT_NEAR(m_.views()[0].footprint.mean.x(), 5.0, kTol);
  EXPECT_NEAR(m_.views()[0].footprint.mean.y(), 6.0, kTol);
  EXPECT_EQ(m_.views()[1], before1_);
  EXPECT_EQ(c.weight, before0_.components.front().weight);
  m_.MoveViewRigidly(0, MakePose(5, 5, kPi / 2), MakePose(1, 1, 0));
  EXPECT_TRUE(
      m_.views()[0].components.front().mean.isApprox(before0_.components.front().mean, 1e-12));
  EXPECT_TRUE(m_.views()[0].footprint.mean.isApprox(before0_.footprint.mean, 1e-12));
  ExpectReadsBack();
}

// A component's spread turns with the view (it is a map-frame scatter) and is stored; a
// spread that is not positive semi-definite is refused.
TEST_F(PoseGraphMapOps, MoveViewRigidlyTurnsTheSpread) {
  ViewComponent c;
  c.weight = 0.5;
  c.eta = 2.0;
  c.mean = MakePose(2, 1, 0);
  c.covariance = Eigen::Vector3d(0.01, 0.01, 0.001).asDiagonal();
  c.spread = Eigen::Vector2d(0.2, 0.01).asDiagonal();
  ViewComponent indefinite = c;
  indefinite.spread << 0.1, 0.5, 0.5, 0.1;  // eigenvalues 0.6 and -0.4
  EXPECT_THROW(m_.AddView(fx_->Make({9, 9}), {indefinite}, ViewStats{}), Error);
  m_.AddView(fx_->Make({9, 9}), {c}, ViewStats{});
  ASSERT_EQ(m_.NumViews(), 3u);
  ExpectReadsBack();
  m_.MoveViewRigidly(2, MakePose(1, 1, 0), MakePose(5, 5, kPi / 2));
  const Eigen::Matrix2d& s = m_.views()[2].components.front().spread;
  EXPECT_NEAR(s(0, 0), 0.01, kTol);
  EXPECT_NEAR(s(1, 1), 0.2, kTol);
  EXPECT_NEAR(s(0, 1), 0.0, kTol);
  EXPECT_EQ(s(0, 1), s(1, 0));
  ExpectReadsBack();
}

}  // namespace
}  // namespace omnicml
