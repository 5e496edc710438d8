#include "omnicml/mapping/view_store.h"

#include <algorithm>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "testing/fake_descriptor.h"

namespace omnicml {
namespace {

using testing::MakeFakeExtractor;

constexpr std::size_t kFeatures = 3;

ViewComponent Component(double x, double y, double w = 0.5) {
  ViewComponent c;
  c.weight = w;
  c.eta = 1.0;
  c.mean = MakePose(x, y, 0.0);
  c.covariance = Eigen::Matrix3d::Identity() * 0.01;
  return c;
}

ReferenceView View(float f, std::vector<ViewComponent> components) {
  ReferenceView v;
  v.descriptor = MakeFakeExtractor(kFeatures)->Make({f, f + 1, f + 2});
  v.components = std::move(components);
  return v;
}

// Every view is found at its row, and that row's features are its descriptor's.
void ExpectRowsMatchViews(const ViewStore& s) {
  for (std::size_t row = 0; row < s.size(); ++row) {
    const ReferenceView& v = s.view(row);
    ASSERT_EQ(s.Find(v.id), row);
    EXPECT_TRUE(std::equal(v.descriptor.features.begin(), v.descriptor.features.end(),
                           s.row_features(row)));
  }
}

// Insert gives increasing view ids and fresh component ids, ignoring the ids given.
TEST(ViewStore, InsertAssignsFreshIds) {
  ViewStore s(kFeatures, 1.0);
  ReferenceView a = View(0, {Component(0, 0), Component(1, 0)});
  a.id = 77;
  a.components[0].id = a.components[1].id = 5;
  const std::size_t row_a = s.Insert(a);
  const std::size_t row_b = s.Insert(View(1, {Component(2, 0)}));
  EXPECT_EQ(row_a, 0u);
  EXPECT_EQ(row_b, 1u);
  EXPECT_EQ(s.view(0).id, 1u);
  EXPECT_EQ(s.view(1).id, 2u);
  EXPECT_EQ(s.view(0).components[0].id, 1u);
  EXPECT_EQ(s.view(0).components[1].id, 2u);
  EXPECT_EQ(s.view(1).components[0].id, 3u);
  EXPECT_EQ(s.next_view_id(), 3u);
  EXPECT_EQ(s.next_component_id(), 4u);
  EXPECT_EQ(s.NumComponents(), 3u);
  EXPECT_NO_THROW(s.CheckInvariants());
  ExpectRowsMatchViews(s);
}

// A random sequence of insertions, removals and component edits keeps every invariant;
// removal swaps the last view into the freed row and reports it.
TEST(ViewStore, InvariantsHoldAfterRandomInsertAndRemove) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> pos(-5.0, 5.0);
  ViewStore s(kFeatures, 0.5);
  std::vector<std::uint64_t> live;
  for (int step = 0; step < 400; ++step) {
    const int op = static_cast<int>(rng() % 4);
    if (op <= 1 || s.empty()) {
      std::vector<ViewComponent> comps;
      for (unsigned k = 0; k < 1 + rng() % 3; ++k) comps.push_back(Component(pos(rng), pos(rng)));
      const std::size_t row = s.Insert(View(static_cast<float>(step), comps));
      live.push_back(s.view(row).id);
    } else if (op == 2) {
      const std::size_t row = rng() % s.size();
      const std::size_t last = s.size() - 1;
      const std::uint64_t id = s.view(row).id, last_id = s.view(last).id;
      const ViewStore::Removal r = s.RemoveAt(row);
      EXPECT_EQ(r.removed_id, id);
      if (row != last) {
        ASSERT_TRUE(r.moved_id.has_value());
        EXPECT_EQ(*r.moved_id, last_id);
        EXPECT_EQ(s.view(row).id, last_id);
      } else {
        EXPECT_FALSE(r.moved_id.has_value());
      }
      EXPECT_FALSE(s.Find(id).has_value());
      std::erase(live, id);
    } else {
      const std::size_t row = rng() % s.size();
      s.AppendComponent(row, Component(pos(rng), pos(rng)));
      ViewComponent moved = s.view(row).components.front();
      moved.mean = MakePose(pos(rng), pos(rng), 0.0);
      s.ReplaceComponent(row, 0, moved);
      s.EraseComponent(row, s.view(row).components.size() - 1);
    }
    ASSERT_NO_THROW(s.CheckInvariants()) << "step " << step;
  }
  EXPECT_EQ(s.size(), live.size());
  ExpectRowsMatchViews(s);
}

// The grid follows component moves: a component is found at its new mean, not its old.
TEST(ViewStore, ReplaceComponentMovesItsGridEntry) {
  ViewStore s(kFeatures, 1.0);
  s.Insert(View(0, {Component(0, 0)}));
  ViewComponent c = s.view(0).components[0];
  c.mean = MakePose(10.0, 10.0, 0.5);
  c.weight = 0.25;
  s.ReplaceComponent(0, 0, c);
  EXPECT_TRUE(s.spatial().QueryRadius(0, 0, 0.5).empty());
  ASSERT_EQ(s.spatial().QueryRadius(10, 10, 0.5).size(), 1u);
  EXPECT_EQ(s.view(0).components[0].weight, 0.25);
  EXPECT_NO_THROW(s.CheckInvariants());
}

// CheckInvariants fails when a view's descriptor no longer equals its feature row.
TEST(ViewStore, CheckInvariantsDetectsAStaleRow) {
  ViewStore s(kFeatures, 1.0);
  s.Insert(View(0, {Component(0, 0)}));
  s.view(0).descriptor.features[1] += 1.0f;
  EXPECT_THROW(s.CheckInvariants(), InternalError);
}

// CheckInvariants fails on an empty view and on a weight outside [0, 1].
TEST(ViewStore, CheckInvariantsDetectsEmptyViewsAndBadWeights) {
  ViewStore s(kFeatures, 1.0);
  s.Insert(View(0, {Component(0, 0)}));
  s.view(0).components[0].weight = 1.5;
  EXPECT_THROW(s.CheckInvariants(), InternalError);
  s.view(0).components[0].weight = 0.5;
  s.EraseComponent(0, 0);
  EXPECT_THROW(s.CheckInvariants(), InternalError);
}

// Restore rebuilds rows, id map, grid and counts equal to the incrementally built ones.
TEST(ViewStore, RestoreRebuildsDerivedState) {
  ViewStore s(kFeatures, 1.0);
  for (int i = 0; i < 6; ++i)
    s.Insert(View(static_cast<float>(i), {Component(i, 0), Component(i, 1)}));
  s.RemoveAt(2);
  ViewStore r(kFeatures, 1.0);
  r.Restore(s.views(), s.next_view_id(), s.next_component_id());
  EXPECT_NO_THROW(r.CheckInvariants());
  EXPECT_EQ(r.features(), s.features());
  EXPECT_EQ(r.spatial().All(), s.spatial().All());
  EXPECT_EQ(r.NumComponents(), s.NumComponents());
  EXPECT_EQ(r.next_view_id(), s.next_view_id());
  ExpectRowsMatchViews(r);
}

}  // namespace
}  // namespace omnicml
