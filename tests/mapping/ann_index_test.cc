// The approximate candidate index (ann_index.h) and the model's approximate search
// (options ann_*): removed vectors are never returned, slots are reused, copies
// and repeated builds answer alike, and on maps above ann_min_views the model's matches
// equal the exhaustive scan's for at least 99 % of the queries (several seeds), through
// updates, removals, save and load.
#include "omnicml/mapping/ann_index.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <memory>
#include <random>
#include <set>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/QR>

#include "omnicml/descriptors/fourier_signature.h"
#include "omnicml/mapping/environment_model.h"
#include "testing/model_helpers.h"

namespace omnicml {
namespace {

using testing::Bytes;
using testing::Estimate;
using testing::MakeFourier;

constexpr int kBands = 4, kCoefficients = 16;  // 64 features, the default signature's size
constexpr std::size_t kD = kBands * kCoefficients;

// Descriptor-like vectors along routes: an Ornstein-Uhlenbeck walk (step correlation
// 0.85) in the axes of a rotated, decaying spectrum (as bench/map_scale_benchmark.cc's
// trajectory maps), so consecutive vectors are ~0.3 apart and unrelated ones ~0.75.
class RouteSource {
 public:
  explicit RouteSource(std::uint32_t seed) : rng_(seed) {
    Eigen::MatrixXd g(kD, kD);
    for (Eigen::Index i = 0; i < g.size(); ++i) g.data()[i] = normal_(rng_);
    rotation_ = Eigen::HouseholderQR<Eigen::MatrixXd>(g).householderQ();
    scale_.resize(kD);
    double sum = 0;
    for (std::size_t k = 0; k < kD; ++k) {
      scale_[k] = std::pow(k + 1.0, -0.58) * std::exp(-(k + 1.0) / 40.0);
      sum += scale_[k];
    }
    for (double& s : scale_) s = std::sqrt(s * 0.286 / sum);
    u_.setZero(kD);
  }
  // The next vector of the current route; a new route every `route` vectors.
  std::vector<float> Next(int route = 200) {
    const double rho = 0.85;
    for (std::size_t k = 0; k < kD; ++k) {
      u_[k] = count_ % route == 0 ? normal_(rng_)
                                  : rho * u_[k] + std::sqrt(1 - rho * rho) * normal_(rng_);
    }
    ++count_;
    Eigen::VectorXd s(kD);
    for (std::size_t k = 0; k < kD; ++k) s[k] = scale_[k] * u_[k];
    const Eigen::VectorXd x = rotation_ * s;
    std::vector<float> out(kD);
    for (std::size_t k = 0; k < kD; ++k) out[k] = static_cast<float>(0.15 + x[k]);
    return out;
  }
  std::vector<float> Near(const std::vector<float>& x, double sigma) {
    std::vector<float> out = x;
    for (float& v : out) v += static_cast<float>(sigma * normal_(rng_));
    return out;
  }
  std::mt19937& rng() { return rng_; }

 private:
  std::mt19937 rng_;
  std::normal_distribution<double> normal_{0.0, 1.0};
  Eigen::MatrixXd rotation_;
  std::vector<double> scale_;
  Eigen::VectorXd u_;
  std::size_t count_ = 0;
};

std::shared_ptr<const FourierSignature> Fourier() {
  FourierOptions f;
  f.bands = kBands;
  f.coefficients = kCoefficients;
  f.distance = FourierDistance::kL2;
  return std::make_shared<FourierSignature>(f);
}

ViewComponent Component(double x, double y) {
  ViewComponent c;
  c.weight = 0.5;
  c.eta = 1.0;
  c.mean = MakePose(x, y, 0.0);
  c.covariance = Eigen::Vector3d(0.04, 0.04, 0.04).asDiagonal();
  return c;
}

// (view id, distance) of a match list: what "the same result" compares.
std::vector<std::pair<std::uint64_t, double>> Key(const std::vector<ViewMatch>& m) {
  std::vector<std::pair<std::uint64_t, double>> k;
  for (const ViewMatch& x : m) k.emplace_back(x.view_id, x.distance);
  return k;
}

// Every view with E < e_max, sorted by (E, id), by brute force.
std::vector<std::pair<std::uint64_t, double>> AllTrue(const EnvironmentModel& m,
                                                      const Descriptor& y) {
  std::vector<std::pair<double, std::uint64_t>> s;
  for (const ReferenceView& v : m.views()) {
    const double e = m.extractor().Distance(y.features.data(), v.descriptor.features.data(), kD);
    if (e < m.options().retrieval.e_max) s.emplace_back(e, v.id);
  }
  std::sort(s.begin(), s.end());
  std::vector<std::pair<std::uint64_t, double>> k;
  for (const auto& [e, id] : s) k.emplace_back(id, e);
  return k;
}

// ---- AnnIndex ------------------------------------------------------------------------

// With k and ef as large as the index, Nearest returns every live vector, sorted by
// distance; removed ones never; freed slots are reused; a copy answers alike.
TEST(AnnIndex, RemovedNeverReturnedSlotsReusedCopiesEqual) {
  RouteSource src(3);
  AnnIndex index;
  index.Reset(kD, AnnIndex::Params{}, 8);
  std::vector<std::vector<float>> x;
  std::set<std::uint64_t> live;
  std::mt19937 rng(5);
  std::uint64_t next_id = 100;
  std::size_t most = 0;
  for (int step = 0; step < 3000; ++step) {
    if (live.size() > 50 && rng() % 3 == 0) {
      auto it = live.begin();
      std::advance(it, rng() % live.size());
      EXPECT_TRUE(index.Remove(*it));
      EXPECT_FALSE(index.Remove(*it));
      live.erase(it);
    } else {
      x.push_back(src.Next());
      index.Insert(next_id, x.back().data());
      live.insert(next_id++);
    }
    most = std::max(most, live.size());
    ASSERT_EQ(index.size(), live.size());
    ASSERT_LE(index.slots(), most);
  }
  EXPECT_EQ(index.Ids(), std::vector<std::uint64_t>(live.begin(), live.end()));
  const AnnIndex copy = index;
  std::vector<std::pair<float, std::uint64_t>> a, b;
  for (int t = 0; t < 30; ++t) {
    const std::vector<float> q = src.Next();
    index.Nearest(q.data(), live.size() + 10, live.size() + 10, &a);
    ASSERT_EQ(a.size(), live.size());
    std::set<std::uint64_t> got;
    for (const auto& [d, id] : a) got.insert(id);
    EXPECT_EQ(got, live);
    EXPECT_TRUE(std::is_sorted(a.begin(), a.end()));
    index.Nearest(q.data(), 10, 40, &a);
    copy.Nearest(q.data(), 10, 40, &b);
    EXPECT_EQ(a.size(), 10u);
    EXPECT_EQ(a, b);
  }
}

// ---- the model -----------------------------------------------------------------------

EnvironmentModelOptions AnnOptions(int min_views) {
  EnvironmentModelOptions o;
  o.retrieval.e_max = 0.45;
  o.retrieval.top_k = 8;
  o.index.index_min_views = 0;
  o.index.ann_min_views = min_views;
  return o;
}

// A trajectory map of n views (routes of 200) and queries near random views.
struct Map {
  std::unique_ptr<EnvironmentModel> model;
  std::vector<Descriptor> queries;
};
Map BuildMap(const EnvironmentModelOptions& o, std::uint32_t seed, int n, int queries) {
  Map m;
  m.model = std::make_unique<EnvironmentModel>(o, Fourier());
  RouteSource src(seed);
  std::vector<std::vector<float>> rows;
  for (int i = 0; i < n; ++i) {
    rows.push_back(src.Next());
    m.model->AddView(MakeFourier(rows.back(), src.rng()), {Component(0.1 * i, 0.0)}, ViewStats{});
  }
  for (int t = 0; t < queries; ++t) {
    m.queries.push_back(MakeFourier(src.Near(rows[src.rng()() % rows.size()], 0.02), src.rng()));
  }
  return m;
}

// Above ann_min_views, FindMatches equals the exhaustive scan, and FindAllMatches the brute
// force, for >= 99 % of the queries, on maps of three seeds; every match it returns is a
// true one (exact distances, same order).
TEST(EnvironmentModelAnn, EqualToExhaustiveForAlmostAllQueries) {
  for (const std::uint32_t seed : {1u, 2u, 3u}) {
    const Map m = BuildMap(AnnOptions(2000), seed, 6000, 300);
    ASSERT_TRUE(m.model->AnnActive());
    m.model->CheckInvariants();
    int same = 0, same_all = 0;
    std::size_t truth = 0, found = 0;
    for (const Descriptor& q : m.queries) {
      const auto got = Key(m.model->FindMatches(q));
      const auto exact = Key(m.model->FindMatchesExhaustive(q));
      same += got == exact;
      const auto all = Key(m.model->FindAllMatches(q));
      const auto all_true = AllTrue(*m.model, q);
      same_all += all == all_true;
      truth += all_true.size();
      for (const auto& match : all) {
        // Never a false match, with the scan's exact distance.
        EXPECT_TRUE(std::find(all_true.begin(), all_true.end(), match) != all_true.end());
        ++found;
      }
    }
    const double n = static_cast<double>(m.queries.size());
    EXPECT_GE(same / n, 0.99) << "seed " << seed;
    EXPECT_GE(same_all / n, 0.99) << "seed " << seed;
    EXPECT_GE(static_cast<double>(found) / static_cast<double>(truth), 0.99) << "seed " << seed;
    EXPECT_GT(truth, m.queries.size());  // queries have several matches each
  }
}

// Two models built the same way answer identically, as does a copy; a model reloaded
// from its file rebuilds the same graph (views in id order, none removed), so it answers
// identically too.
TEST(EnvironmentModelAnn, DeterministicCopiesAndReloadWithoutRemovals) {
  const EnvironmentModelOptions o = AnnOptions(1500);
  const Map a = BuildMap(o, 7, 3000, 200), b = BuildMap(o, 7, 3000, 200);
  const EnvironmentModel copy = *a.model;
  BinaryWriter w;
  a.model->Serialize(w);
  const std::vector<std::uint8_t> bytes = w.Release();
  BinaryReader r(bytes, "model");
  const EnvironmentModel loaded = EnvironmentModel::Deserialize(r, o, a.model->extractor_ptr());
  ASSERT_TRUE(loaded.AnnActive());
  for (const Descriptor& q : a.queries) {
    const auto ref = Key(a.model->FindAllMatches(q));
    EXPECT_EQ(Key(b.model->FindAllMatches(q)), ref);
    EXPECT_EQ(Key(copy.FindAllMatches(q)), ref);
    EXPECT_EQ(Key(loaded.FindAllMatches(q)), ref);
    EXPECT_EQ(Key(loaded.FindMatches(q)), Key(a.model->FindMatches(q)));
  }
}

// Updates with active forgetting insert and remove views on a map above the threshold:
// the graph follows (invariants: its ids are the views'), removed views are never
// returned, two runs of the sequence give the same bytes, and the lists stay equal to
// the scan's for >= 99 % of the queries, before and after a save and load (which
// rebuilds the graph without the removal history).
TEST(EnvironmentModelAnn, UpdatesRemovalsAndReload) {
  EnvironmentModelOptions o = AnnOptions(300);
  o.forgetting.forget_min_missed_passes = 0;
  o.forgetting.beta_for = 0.6;
  o.forgetting.d_for_m = 1.5;
  o.forgetting.pass_gap_frames = 0;
  auto run = [&](std::size_t* removed, int* same, int* queries) {
    Map m = BuildMap(o, 11, 1200, 0);
    RouteSource src(12);
    std::vector<std::vector<float>> places;
    for (int i = 0; i < 400; ++i) places.push_back(src.Next(50));
    std::mt19937 rng(13);
    std::uniform_real_distribution<double> pos(0.0, 20.0);
    for (int t = 0; t < 1500; ++t) {
      const Descriptor y = MakeFourier(src.Near(places[rng() % places.size()], 0.02), rng);
      const auto got = Key(m.model->FindAllMatches(y));
      *same += got == AllTrue(*m.model, y);
      ++*queries;
      for (const auto& [id, e] : got) EXPECT_TRUE(m.model->FindView(id).has_value());
      const UpdateStats s = m.model->Update(y, Estimate(pos(rng), pos(rng)), {t, 0});
      *removed += static_cast<std::size_t>(s.views_removed);
      if (t % 250 == 0) m.model->CheckInvariants();
    }
    m.model->CheckInvariants();
    return m;
  };
  std::size_t removed = 0, removed2 = 0;
  int same = 0, queries = 0, same2 = 0, queries2 = 0;
  const Map m = run(&removed, &same, &queries);
  const Map m2 = run(&removed2, &same2, &queries2);
  ASSERT_TRUE(m.model->AnnActive());
  EXPECT_GT(removed, 10u) << "the sequence should remove views";
  EXPECT_EQ(Bytes(*m.model), Bytes(*m2.model));
  EXPECT_EQ(same, same2);
  EXPECT_GE(static_cast<double>(same) / queries, 0.99);

  BinaryWriter w;
  m.model->Serialize(w);
  const std::vector<std::uint8_t> bytes = w.Release();
  BinaryReader r(bytes, "model");
  const EnvironmentModel loaded = EnvironmentModel::Deserialize(r, o, m.model->extractor_ptr());
  loaded.CheckInvariants();
  ASSERT_TRUE(loaded.AnnActive());
  RouteSource src(14);
  int equal = 0, loaded_exact = 0, n = 0;
  for (int t = 0; t < 300; ++t) {
    const Descriptor y = MakeFourier(src.Near(src.Next(), 0.0), src.rng());
    const auto a = Key(m.model->FindAllMatches(y)), b = Key(loaded.FindAllMatches(y));
    equal += a == b;
    loaded_exact += b == AllTrue(loaded, y);
    ++n;
  }
  EXPECT_GE(static_cast<double>(equal) / n, 0.98);
  EXPECT_GE(static_cast<double>(loaded_exact) / n, 0.99);
}

// Update with the graph: whatever the graph search misses, the views with a component
// within d_for of mu_t get the exact distance, so rules (16)-(18) at the robot's place
// act as with the exhaustive scan. A deliberately poor search (ef 1, k 1) must not let
// rule (18) weaken a local view that matches.
TEST(EnvironmentModelAnn, UpdateNearTheRobotIsExact) {
  EnvironmentModelOptions with_graph = AnnOptions(300);
  with_graph.forgetting.forget_min_missed_passes = 0;  // (18) acts on the first miss
  with_graph.index.ann_ef = 1;
  with_graph.index.ann_k = 1;
  EnvironmentModelOptions scan = with_graph;
  scan.index.ann_min_views = 0;
  const Map g = BuildMap(with_graph, 31, 600, 0);
  const Map e = BuildMap(scan, 31, 600, 0);
  ASSERT_TRUE(g.model->AnnActive());
  ASSERT_FALSE(e.model->AnnActive());
  RouteSource src(32);
  std::mt19937 rng(33);
  int graph_missed = 0;
  for (int t = 0; t < 60; ++t) {
    // Near view i (component at x = 0.1 i), estimated at its place.
    const std::size_t i = 20 + rng() % 560;
    const Descriptor y = MakeFourier(src.Near(g.model->views()[i].descriptor.features, 0.02), rng);
    const Gaussian at = Estimate(0.1 * static_cast<double>(i), 0.0);
    graph_missed += Key(g.model->FindAllMatches(y)) != AllTrue(*g.model, y);
    EnvironmentModel a = *g.model, b = *e.model;
    a.Update(y, at, {t, 0});
    b.Update(y, at, {t, 0});
    for (const ReferenceView& v : b.views()) {
      for (const ViewComponent& c : v.components) {
        // Strictly inside d_for (QueryRadius's boundary), with a margin for rounding.
        if ((c.mean.head<2>() - at.mean.head<2>()).norm() > scan.forgetting.d_for_m - 1e-6)
          continue;
        const auto other = a.FindView(v.id);
        ASSERT_TRUE(other.has_value()) << "view " << v.id << " removed only with the graph";
        for (const ViewComponent& d : a.views()[*other].components) {
          if (d.id == c.id) EXPECT_EQ(d.weight, c.weight) << "view " << v.id << ", t " << t;
        }
      }
    }
  }
  EXPECT_GT(graph_missed, 0) << "the poor search should miss matches, or this tests nothing";
}

// The graph follows the options: searched from ann_min_views views on (kept from the
// first view), never with 0; invalid values
// name the field.
TEST(EnvironmentModelAnn, Options) {
  EnvironmentModelOptions o = AnnOptions(40);
  EnvironmentModel m(o, Fourier());
  RouteSource src(21);
  for (int i = 0; i < 39; ++i) m.AddView(MakeFourier(src.Next(), src.rng()), {Component(i, 0)}, {});
  EXPECT_FALSE(m.AnnActive());
  // Kept (one insertion per view) though not searched: crossing the threshold is no build.
  EXPECT_TRUE(m.ann_index().built());
  EXPECT_EQ(m.ann_index().size(), 39u);
  m.CheckInvariants();
  m.AddView(MakeFourier(src.Next(), src.rng()), {Component(40, 0)}, {});
  EXPECT_TRUE(m.AnnActive());
  m.CheckInvariants();

  EnvironmentModelOptions off = o;
  off.index.ann_min_views = 0;
  EnvironmentModel never(off, Fourier());
  for (int i = 0; i < 60; ++i)
    never.AddView(MakeFourier(src.Next(), src.rng()), {Component(i, 0)}, {});
  EXPECT_FALSE(never.AnnActive());

  for (const auto& [name, set] :
       std::vector<std::pair<std::string, void (*)(EnvironmentModelOptions&)>>{
           {"ann_min_views", [](EnvironmentModelOptions& x) { x.index.ann_min_views = -1; }},
           {"ann_m", [](EnvironmentModelOptions& x) { x.index.ann_m = 1; }},
           {"ann_ef_construction",
            [](EnvironmentModelOptions& x) { x.index.ann_ef_construction = 0; }},
           {"ann_ef", [](EnvironmentModelOptions& x) { x.index.ann_ef = 0; }},
           {"ann_k", [](EnvironmentModelOptions& x) { x.index.ann_k = 0; }}}) {
    EnvironmentModelOptions bad = o;
    set(bad);
    try {
      bad.Validate();
      ADD_FAILURE() << name << " accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace omnicml
