// Scale of the environment model: place retrieval at 1k ... 1M views, the
// exhaustive scan against the candidate index (view_index.h), recall, ProcessFrame-like
// cost, memory per view. Public EnvironmentModel API only (AddView to build, FindMatches
// / FindMatchesExhaustive to query, Update for the frame loop).
//
// Synthetic map of the real descriptor: the default FourierSignature (4 bands x 16
// coefficients = 64 magnitudes, L2 distance, 64 complex coefficients for the relative
// heading), e_max 0.45 and top_k 8 (the engine defaults). Two generators:
//
// * trajectory (realistic): views come in routes of 1000; along a route the features
//   follow a stationary Ornstein-Uhlenbeck walk (step correlation 0.843) in the principal
//   axes of a covariance whose spectrum was measured on simulated institute panoramas
//   (2 days x 1500 frames, e_max 0.1 to keep 2687 views, `omnicml export --features`):
//   total variance 0.286 (per-feature standard deviation 0.067), eigenvalues falling as
//   lambda_k ~ k^-0.58 exp(-k / 40), fitted to the measured cumulative shares (8 axes
//   49 %, 16 axes 66 %, 32 axes 85 %; model 49 %, 67 %, 86 %); the axes are a fixed random
//   rotation of the feature space. Consecutive views are ~0.3 apart and unrelated views
//   ~0.76 apart (measured median 0.75).
// * uniform (worst case): i.i.d. uniform features with the same total variance, so no
//   direction carries more of the distance than another and no bound can prune much.
//
// A query is a map view plus Gaussian noise of norm ~0.16, so it matches its view and a
// few route neighbours, as a revisit does.
//
// Counters: views; matches_per_query; candidates (fraction of the views whose exact
// distance the index computes); projected (fraction whose projected bound it computes:
// the rest the kd-tree prunes); recall (matches the index returns that the exhaustive scan
// returns too, over all the scan's matches, 512 queries, top_k lists) and
// identical_lists (fraction of queries with the very same list); bytes_per_view
// (EnvironmentModel::MemoryBytes / views, event log cleared, index included) and
// index_bytes_per_view; estimated_bounded (the model's own estimate of `projected`, which
// decides whether the default options keep the index); rss_bytes_per_view (resident-set growth
// while building, Linux); index_build_s (the AddView that built the index). ProcessFrame-like:
// p50_us and p99_us of FindMatches + Hypothesis + Update per frame. FindMatchesNear: the pose-gated
// search. One fixture at a time is kept, so peak memory is one map's.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <complex>
#include <ctime>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Dense>

#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml {
namespace {

constexpr std::size_t kFeatures = 64;  // 4 bands x 16 coefficients
constexpr int kRouteViews = 1000;
constexpr double kTotalVariance = 0.286;  // measured, see the file comment
constexpr double kRho = 0.843;            // OU step correlation: neighbours ~0.3 apart
constexpr float kMean = 0.15f;
constexpr float kQueryNoise = 0.02f;  // per feature: norm ~0.16

enum Generator { kTrajectory = 0, kUniform = 1 };

// Resident set size in bytes (Linux /proc/self/status VmRSS), 0 if unknown.
std::size_t ResidentBytes() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stoull(line.substr(6)) * 1024;
  }
  return 0;
}

// CPU time of the calling thread, microseconds (CLOCK_THREAD_CPUTIME_ID).
double ThreadCpuMicros() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) * 1e6 + static_cast<double>(ts.tv_nsec) * 1e-3;
}

struct Key {
  int generator = kTrajectory;
  std::size_t views = 0;
  int index_dims = 32;
  double e_max = 0.45;
  bool index = true;
  bool fresh = false;  // a map the benchmark changes (Update): never reused
  bool ann = false;    // the approximate graph (options ann_*) instead of the exact index
  int ann_m = EnvironmentModelOptions{}.index.ann_m;
  int ann_ef_construction = EnvironmentModelOptions{}.index.ann_ef_construction;
  bool operator==(const Key&) const = default;
};

struct ScaleFixture {
  Key key;
  std::unique_ptr<EnvironmentModel> model;
  std::vector<Descriptor> queries;
  double bytes_per_view = 0, index_bytes_per_view = 0, rss_bytes_per_view = 0;
  double index_build_s = 0;
  double recall = 1, identical = 1, candidates = 0, projected = 0, matches = 0;
  // Radius query (FindAllMatches, what Update uses) against the brute force: recall of
  // the true matches and the fraction of identical lists; matches per query.
  double recall_all = 1, identical_all = 1, matches_all = 0;
  // Per query, the scan's top_k list and the true radius-query ids (computed once per map).
  std::vector<std::vector<ViewMatch>> exact;
  std::vector<std::vector<std::uint64_t>> truth_all;
};

// Every view with E < e_max, sorted by (E, id), by brute force over views().
std::vector<std::uint64_t> TrueMatches(const EnvironmentModel& model, const Descriptor& q) {
  std::vector<std::pair<double, std::uint64_t>> m;
  for (const ReferenceView& v : model.views()) {
    const double e = model.extractor().Distance(q.features.data(), v.descriptor.features.data(),
                                                q.features.size());
    if (e < model.options().retrieval.e_max) m.emplace_back(e, v.id);
  }
  std::sort(m.begin(), m.end());
  std::vector<std::uint64_t> ids;
  for (const auto& [e, id] : m) ids.push_back(id);
  return ids;
}

Descriptor MakeDescriptor(const Eigen::VectorXf& magnitudes, std::mt19937& rng) {
  std::uniform_real_distribution<float> phase(-3.14159265f, 3.14159265f);
  Descriptor d;
  d.kind = DescriptorKind::kFourier;
  d.features.assign(magnitudes.data(), magnitudes.data() + kFeatures);
  d.coefficients.resize(kFeatures);
  for (std::size_t i = 0; i < kFeatures; ++i)
    d.coefficients[i] = std::polar(std::max(d.features[i], 0.0f), phase(rng));
  d.panorama_width = 720;
  return d;
}

// What the index computes for one query (through the public accessor): the fraction of
// the views that are candidates (exact distance), and of those whose projected distance
// is computed (their block is not pruned by the tree).
std::pair<double, double> CandidateFraction(const EnvironmentModel& model, const Descriptor& q) {
  if (!model.IndexActive()) return {1.0, 1.0};
  std::vector<std::size_t> rows;
  const std::size_t bounded =
      model.view_index().Candidates(q.features.data(), model.options().retrieval.e_max, &rows);
  const double n = static_cast<double>(model.NumViews());
  return {static_cast<double>(rows.size()) / n, static_cast<double>(bounded) / n};
}

void Measure(ScaleFixture& f);

ScaleFixture& Fixture(const Key& key) {
  static ScaleFixture f;
  if (f.key == key && f.model && !key.fresh) return f;
  f = ScaleFixture{};
  f.key = key;
  const std::size_t n = key.views;
  const std::size_t rss0 = ResidentBytes();
  std::shared_ptr<const DescriptorExtractor> extractor =
      MakeDescriptorExtractor(DescriptorOptions{});
  if (extractor->FeatureSize() != kFeatures) throw Error("benchmark expects 64 features");
  EnvironmentModelOptions o;
  o.retrieval.e_max = key.e_max;
  o.retrieval.top_k = 8;
  // Built once, by the last AddView, so index_build_s is one build over the whole map.
  o.index.index_min_views = key.index && !key.ann ? static_cast<int>(n) : 0;
  // The graph is kept from the first view on; searched from n / 2 views, so a
  // ProcessFrame-like run that removes views keeps using it.
  o.index.ann_min_views = key.ann ? static_cast<int>(n / 2) : 0;
  o.index.ann_m = key.ann_m;
  o.index.ann_ef_construction = key.ann_ef_construction;
  o.index.index_dims = key.index_dims;
  o.index.index_max_bounded_fraction = 1.0;  // measure the index even where the model would drop it
  f.model = std::make_unique<EnvironmentModel>(o, extractor);

  std::mt19937 rng(1919);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  std::uniform_real_distribution<double> pos(0.0, std::sqrt(static_cast<double>(n) / 4.0));
  // Principal axes: a fixed random rotation; scales from the measured spectrum.
  Eigen::MatrixXf gauss(kFeatures, kFeatures);
  for (Eigen::Index i = 0; i < gauss.size(); ++i) gauss.data()[i] = normal(rng);
  const Eigen::MatrixXf rotation = Eigen::HouseholderQR<Eigen::MatrixXf>(gauss).householderQ();
  Eigen::VectorXf scale(kFeatures);
  double sum = 0;
  for (std::size_t k = 0; k < kFeatures; ++k) {
    const double lambda = std::pow(k + 1.0, -0.58) * std::exp(-(k + 1.0) / 40.0);
    scale[static_cast<Eigen::Index>(k)] = static_cast<float>(lambda);
    sum += lambda;
  }
  for (Eigen::Index k = 0; k < scale.size(); ++k)
    scale[k] = static_cast<float>(std::sqrt(scale[k] * kTotalVariance / sum));
  const float uniform_half = static_cast<float>(std::sqrt(3.0 * kTotalVariance / kFeatures));
  std::uniform_real_distribution<float> uniform(-uniform_half, uniform_half);
  const float innovation = static_cast<float>(std::sqrt(1.0 - kRho * kRho));

  Eigen::VectorXf u(kFeatures), x(kFeatures);
  const std::size_t query_every = n / 512 + 1;
  double build_s = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (key.generator == kUniform) {
      for (Eigen::Index k = 0; k < x.size(); ++k) x[k] = kMean + uniform(rng);
    } else {
      if (i % kRouteViews == 0) {
        for (Eigen::Index k = 0; k < u.size(); ++k) u[k] = normal(rng);  // a new route
      } else {
        for (Eigen::Index k = 0; k < u.size(); ++k)
          u[k] = static_cast<float>(kRho) * u[k] + innovation * normal(rng);
      }
      x = (rotation * scale.cwiseProduct(u)).array() + kMean;
    }
    Descriptor d = MakeDescriptor(x, rng);
    ViewComponent c;
    c.weight = 0.5;
    c.eta = 1.0;
    c.mean = MakePose(pos(rng), pos(rng), 0.0);
    c.covariance = Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal();
    const auto t0 = std::chrono::steady_clock::now();
    f.model->AddView(d, {c}, ViewStats{});
    if (i + 1 == n)
      build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (i % query_every == 0) {
      Eigen::VectorXf q = x;
      for (Eigen::Index k = 0; k < q.size(); ++k) q[k] += kQueryNoise * normal(rng);
      f.queries.push_back(MakeDescriptor(q, rng));
    }
  }
  f.model->ClearEvents();
  f.index_build_s = build_s;
  f.bytes_per_view = static_cast<double>(f.model->MemoryBytes()) / static_cast<double>(n);
  f.index_bytes_per_view = static_cast<double>(f.model->view_index().MemoryBytes() +
                                               f.model->ann_index().MemoryBytes()) /
                           static_cast<double>(n);
  const std::size_t rss1 = ResidentBytes();
  f.rss_bytes_per_view =
      rss1 > rss0 ? static_cast<double>(rss1 - rss0) / static_cast<double>(n) : 0.0;
  Measure(f);
  return f;
}

// Recall of FindMatches against the exhaustive scan over every query (and for the graph,
// of FindAllMatches against the brute force).
void Measure(ScaleFixture& f) {
  std::size_t found = 0, truth = 0, same = 0;
  double candidates = 0, projected = 0;
  if (f.exact.empty()) {
    for (const Descriptor& q : f.queries) f.exact.push_back(f.model->FindMatchesExhaustive(q));
  }
  for (std::size_t qi = 0; qi < f.queries.size(); ++qi) {
    const Descriptor& q = f.queries[qi];
    const std::vector<ViewMatch>& exact = f.exact[qi];
    const std::vector<ViewMatch> got = f.model->FindMatches(q);
    truth += exact.size();
    for (const ViewMatch& m : exact) {
      found += std::any_of(got.begin(), got.end(),
                           [&](const ViewMatch& g) { return g.view_id == m.view_id; });
    }
    bool equal = exact.size() == got.size();
    for (std::size_t k = 0; equal && k < exact.size(); ++k) {
      equal = exact[k].view_id == got[k].view_id && exact[k].distance == got[k].distance;
    }
    same += equal;
    const auto [c, scanned] = CandidateFraction(*f.model, q);
    candidates += c;
    projected += scanned;
  }
  const double nq = static_cast<double>(f.queries.size());
  f.recall = truth > 0 ? static_cast<double>(found) / static_cast<double>(truth) : 1.0;
  f.identical = static_cast<double>(same) / nq;
  f.candidates = candidates / nq;
  f.projected = projected / nq;
  f.matches = static_cast<double>(truth) / nq;
  if (!f.model->AnnActive()) return;
  std::size_t found_all = 0, truth_all = 0, same_all = 0;
  if (f.truth_all.empty()) {
    for (const Descriptor& q : f.queries) f.truth_all.push_back(TrueMatches(*f.model, q));
  }
  for (std::size_t qi = 0; qi < f.queries.size(); ++qi) {
    const Descriptor& q = f.queries[qi];
    const std::vector<std::uint64_t>& exact = f.truth_all[qi];
    const std::vector<ViewMatch> got = f.model->FindAllMatches(q);
    truth_all += exact.size();
    std::vector<std::uint64_t> ids;
    for (const ViewMatch& m : got) ids.push_back(m.view_id);
    for (const std::uint64_t id : exact) found_all += std::count(ids.begin(), ids.end(), id);
    same_all += ids == exact;
  }
  f.recall_all =
      truth_all > 0 ? static_cast<double>(found_all) / static_cast<double>(truth_all) : 1.0;
  f.identical_all = static_cast<double>(same_all) / nq;
  f.matches_all = static_cast<double>(truth_all) / nq;
}

void Report(benchmark::State& state, const ScaleFixture& f, bool indexed) {
  state.counters["views"] = static_cast<double>(f.model->NumViews());
  state.counters["matches_per_query"] = f.matches;
  state.counters["bytes_per_view"] = f.bytes_per_view;
  state.counters["rss_bytes_per_view"] = f.rss_bytes_per_view;
  if (indexed) {
    state.counters["candidates"] = f.candidates;
    state.counters["projected"] = f.projected;
    state.counters["recall"] = f.recall;
    state.counters["identical_lists"] = f.identical;
    state.counters["index_bytes_per_view"] = f.index_bytes_per_view;
    state.counters["index_build_s"] = f.index_build_s;
    // The model's own estimate of the bounded share (32 stored views as queries): the
    // default options keep the index iff it is <= 0.6.
    state.counters["estimated_bounded"] = f.model->IndexBoundedFraction();
  }
  if (indexed && f.model->AnnActive()) {
    state.counters["recall_all"] = f.recall_all;
    state.counters["identical_all"] = f.identical_all;
    state.counters["matches_all"] = f.matches_all;
  }
}

// The timed loop of the retrieval benchmarks: the fixture's queries in turn, through
// FindMatches (indexed: the exact index or the graph, as the model chooses) or the
// exhaustive scan; then the fixture's counters.
void TimeQueries(benchmark::State& state, ScaleFixture& f, bool indexed) {
  std::size_t k = 0;
  for (auto _ : state) {
    const Descriptor& q = f.queries[k++ % f.queries.size()];
    auto m = indexed ? f.model->FindMatches(q) : f.model->FindMatchesExhaustive(q);
    benchmark::DoNotOptimize(m);
  }
  Report(state, f, indexed);
}

// Args: generator (0 trajectory, 1 uniform), views, indexed (0: the exhaustive scan on the
// same map, 1: FindMatches through the exact index, 2: through the approximate graph; the
// scan of a graph's map is the scan of the exact index's map: same generator, same views).
void BM_FindMatches(benchmark::State& state) {
  Key key;
  key.generator = static_cast<int>(state.range(0));
  key.views = static_cast<std::size_t>(state.range(1));
  const bool indexed = state.range(2) != 0;
  key.ann = state.range(2) == 2;
  ScaleFixture& f = Fixture(key);
  TimeQueries(state, f, indexed);
}
BENCHMARK(BM_FindMatches)
    ->ArgNames({"gen", "views", "indexed"})
    ->ArgsProduct({{kTrajectory}, {1000, 3000, 10000, 30000, 100000, 300000, 1000000}, {0, 1, 2}})
    ->ArgsProduct({{kUniform}, {1000, 10000, 100000, 1000000}, {0, 1}})
    ->Unit(benchmark::kMicrosecond);

// The graph's parameters (trajectory map, 100k views; and 1M views with M 32): views, M,
// ef_construction (a graph each), ef and the first k of the radius query (search-time,
// SetAnnSearch on the same graph).
void BM_AnnParams(benchmark::State& state) {
  Key key;
  key.views = static_cast<std::size_t>(state.range(0));
  key.ann = true;
  key.ann_m = static_cast<int>(state.range(1));
  key.ann_ef_construction = static_cast<int>(state.range(2));
  ScaleFixture& f = Fixture(key);
  f.model->SetAnnSearch(static_cast<int>(state.range(3)), static_cast<int>(state.range(4)));
  Measure(f);
  TimeQueries(state, f, /*indexed=*/true);
}
BENCHMARK(BM_AnnParams)
    ->ArgNames({"views", "m", "efc", "ef", "k"})
    ->Apply([](benchmark::internal::Benchmark* b) {
      for (const auto& [m, efc] : std::vector<std::pair<int, int>>{{16, 64}, {16, 128}})
        for (const int ef : {16, 32, 64, 128})
          for (const int k : {32}) b->Args({100000, m, efc, ef, k});  // a graph per (m, efc)
      for (const int ef : {64, 128, 256}) b->Args({1000000, 32, 128, ef, 32});
    })
    ->Unit(benchmark::kMicrosecond);

// The approximate graph on one map per size (built once for all modes). Args: views,
// mode (0: the exhaustive scan, FindMatchesExhaustive; 1: FindMatches (top_k 8) through
// the graph; 2: FindAllMatches (the radius query of Update) through the graph), ef
// (options ann_ef, set with SetAnnSearch; 0: the default).
void BM_Ann(benchmark::State& state) {
  Key key;
  key.views = static_cast<std::size_t>(state.range(0));
  key.ann = true;
  const int mode = static_cast<int>(state.range(1));
  ScaleFixture& f = Fixture(key);
  const int ef = state.range(2) > 0 ? static_cast<int>(state.range(2))
                                    : EnvironmentModelOptions{}.index.ann_ef;
  if (ef != f.model->options().index.ann_ef) {
    f.model->SetAnnSearch(ef, f.model->options().index.ann_k);
    Measure(f);
  }
  std::size_t k = 0;
  for (auto _ : state) {
    const Descriptor& q = f.queries[k++ % f.queries.size()];
    auto m = mode == 0   ? f.model->FindMatchesExhaustive(q)
             : mode == 1 ? f.model->FindMatches(q)
                         : f.model->FindAllMatches(q);
    benchmark::DoNotOptimize(m);
  }
  Report(state, f, true);
}
void AnnArgs(benchmark::internal::Benchmark* b) {
  b->ArgNames({"views", "mode", "ef"});
  for (const int views : {1000, 10000, 100000, 1000000}) {
    // One map for all rows of a size.
    b->Args({views, 0, 0});
    for (const int ef : {32, 64, 128, 256}) b->Args({views, 1, ef});
    for (const int ef : {64, 128, 256}) b->Args({views, 2, ef});
  }
}
BENCHMARK(BM_Ann)->Apply(AnnArgs)->Unit(benchmark::kMicrosecond);

// Projection dimensions of the index (trajectory map, 100k views).
void BM_IndexDims(benchmark::State& state) {
  Key key;
  key.views = 100000;
  key.index_dims = static_cast<int>(state.range(0));
  ScaleFixture& f = Fixture(key);
  TimeQueries(state, f, /*indexed=*/true);
}
BENCHMARK(BM_IndexDims)
    ->ArgName("dims")
    ->Arg(8)
    ->Arg(16)
    ->Arg(24)
    ->Arg(32)
    ->Arg(48)
    ->Unit(benchmark::kMicrosecond);

// The radius: e_max 0.2 and 0.3 (the default 0.45 is BM_FindMatches) on trajectory maps.
// Args: e_max in hundredths, views, indexed.
void BM_Radius(benchmark::State& state) {
  Key key;
  key.e_max = static_cast<double>(state.range(0)) / 100.0;
  key.views = static_cast<std::size_t>(state.range(1));
  const bool indexed = state.range(2) != 0;
  ScaleFixture& f = Fixture(key);
  TimeQueries(state, f, indexed);
}
BENCHMARK(BM_Radius)
    ->ArgNames({"e_max_x100", "views", "indexed"})
    ->ArgsProduct({{20, 30}, {1000, 10000, 100000, 1000000}, {0, 1}})
    ->Unit(benchmark::kMicrosecond);

// Pose-gated matching (cml_engine.h GatedMatchingOptions): FindMatchesNear with one disc
// of radius_cm / 100 metres at a random place of the map (views spread uniformly, 4 per
// square metre, as components ~0.5 m apart). candidates_per_query: views compared. Args:
// views, radius in centimetres (the engine's gate while tracking is ~2-3 m: 4 sigma of
// sqrt(sigma_xy^2 + appearance_sigma^2)).
void BM_FindMatchesNear(benchmark::State& state) {
  Key key;
  key.views = static_cast<std::size_t>(state.range(0));
  key.index = false;
  ScaleFixture& f = Fixture(key);
  const double side = std::sqrt(static_cast<double>(key.views) / 4.0);
  const double radius = static_cast<double>(state.range(1)) / 100.0;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> pos(0.0, side);
  std::size_t k = 0, compared = 0, queries = 0;
  for (auto _ : state) {
    const Descriptor& q = f.queries[k++ % f.queries.size()];
    std::size_t candidates = 0;
    auto m = f.model->FindMatchesNear(q, {{pos(rng), pos(rng), radius}}, &candidates);
    benchmark::DoNotOptimize(m);
    compared += candidates;
    ++queries;
  }
  state.counters["views"] = static_cast<double>(f.model->NumViews());
  state.counters["candidates_per_query"] =
      queries > 0 ? static_cast<double>(compared) / static_cast<double>(queries) : 0.0;
}
BENCHMARK(BM_FindMatchesNear)
    ->ArgNames({"views", "radius_cm"})
    ->ArgsProduct({{10000, 100000, 1000000}, {200, 300}})
    ->Unit(benchmark::kMicrosecond);

// ProcessFrame-like: per frame FindMatches + Hypothesis + Update (active forgetting) of a
// revisit, on a fresh trajectory map; the map changes as the frames go (components added
// and merged, views inserted when a query matches nothing, the index maintained). Per-frame
// times are taken by hand for p50/p99 (wall) and p50_cpu/p99_cpu (the thread's CPU time).
// Args: views, indexed (0 scan, 1 exact index, 2 approximate graph; with the graph, the
// model is then saved and reloaded and reload_differ is the fraction of queries whose
// FindAllMatches list differs between the two).
void BM_ProcessFrameLike(benchmark::State& state) {
  Key key;
  key.views = static_cast<std::size_t>(state.range(0));
  key.index = state.range(1) != 0;
  key.ann = state.range(1) == 2;
  key.fresh = true;
  ScaleFixture& f = Fixture(key);
  std::vector<double> us, cpu_us;
  std::int64_t frame = 0;
  std::size_t k = 0;
  for (auto _ : state) {
    const Descriptor& q = f.queries[k++ % f.queries.size()];
    const auto t0 = std::chrono::steady_clock::now();
    const double c0 = ThreadCpuMicros();
    const std::vector<ViewMatch> m = f.model->FindMatches(q);
    const Mixture p = f.model->Hypothesis(m);
    Gaussian estimate;
    estimate.mean = p.empty() ? MakePose(0, 0, 0) : p.front().mean;
    estimate.covariance = Eigen::Vector3d(0.05, 0.05, 0.02).asDiagonal();
    const UpdateStats s = f.model->Update(q, estimate, UpdateContext{frame++, 1});
    benchmark::DoNotOptimize(s);
    us.push_back(
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
    cpu_us.push_back(ThreadCpuMicros() - c0);
  }
  std::sort(us.begin(), us.end());
  std::sort(cpu_us.begin(), cpu_us.end());
  // The thread's CPU time per frame: on a shared machine the wall-time tail is mostly
  // other processes' (docs/results.md).
  state.counters["p50_cpu_us"] = cpu_us[cpu_us.size() / 2];
  state.counters["p99_cpu_us"] = cpu_us[std::min(cpu_us.size() - 1, cpu_us.size() * 99 / 100)];
  state.counters["views"] = static_cast<double>(f.model->NumViews());
  state.counters["p50_us"] = us[us.size() / 2];
  state.counters["p99_us"] = us[std::min(us.size() - 1, us.size() * 99 / 100)];
  state.counters["index_active"] = f.model->IndexActive() ? 1 : 0;
  state.counters["ann_active"] = f.model->AnnActive() ? 1 : 0;
  if (f.model->AnnActive()) {
    // Save and reload (the graph is rebuilt in id order): queries whose radius-query list
    // differs between the continuing model and the reloaded one.
    BinaryWriter w;
    f.model->Serialize(w);
    BinaryReader r(w.bytes());
    const EnvironmentModel back =
        EnvironmentModel::Deserialize(r, f.model->options(), f.model->extractor_ptr());
    std::size_t differ = 0;
    for (const Descriptor& q : f.queries) {
      const std::vector<ViewMatch> a = f.model->FindAllMatches(q), b = back.FindAllMatches(q);
      bool equal = a.size() == b.size();
      for (std::size_t i = 0; equal && i < a.size(); ++i) equal = a[i].view_id == b[i].view_id;
      differ += !equal;
    }
    state.counters["reload_differ"] =
        static_cast<double>(differ) / static_cast<double>(f.queries.size());
    state.counters["ann_slots"] = static_cast<double>(f.model->ann_index().slots());
  }
}
BENCHMARK(BM_ProcessFrameLike)
    ->ArgNames({"views", "indexed"})
    ->ArgsProduct({{10000, 100000}, {0, 1, 2}})
    ->Iterations(2000)
    ->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace omnicml
