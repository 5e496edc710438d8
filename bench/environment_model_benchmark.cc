// Per-frame cost of the environment model against map size: nearest-view search
// (FindMatches), the hypothesis p(x|y), and Update (matching observation, and novel
// observation that inserts a view), at 1k, 10k and 100k views.
//
// Synthetic map: random 64-float descriptors (uniform in [0, 1]; L2 distance, as the
// Fourier signature's magnitudes), one component per view at a random position in a
// square whose side grows with sqrt(N) so the density stays 4 views / m^2 (active
// forgetting with d_for = 2 m then visits ~50 components per update). Queries are
// perturbed copies of map views, so each matches its view and (almost) no other.
#include <cmath>
#include <complex>
#include <memory>
#include <random>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Core>

#include "omnicml/mapping/environment_model.h"
#include "omnicml/mapping/view_persistence.h"

#include "omnicml/descriptors/descriptor_factory.h"

namespace omnicml {
namespace {

constexpr std::size_t kFeatures = 64;

// L2 distance. Eigen's vectorised reduction (SSE/AVX packets): a plain `sum += d * d`
// loop is not vectorised without -ffast-math (the compiler may not reorder the float sum)
// and costs ~3x more per view.
class L2Extractor : public DescriptorExtractor {
 public:
  DescriptorKind kind() const override { return DescriptorKind::kColorHistogram; }
  Descriptor Compute(const cv::Mat&) const override { throw Error("not supported"); }
  double Distance(const float* a, const float* b, std::size_t n) const override {
    const Eigen::Map<const Eigen::VectorXf> va(a, static_cast<Eigen::Index>(n));
    const Eigen::Map<const Eigen::VectorXf> vb(b, static_cast<Eigen::Index>(n));
    return std::sqrt(static_cast<double>((va - vb).squaredNorm()));
  }
  bool ProvidesHeading() const override { return false; }
  std::optional<double> RelativeHeading(const Descriptor&, const Descriptor&) const override {
    return std::nullopt;
  }
  std::size_t FeatureSize() const override { return kFeatures; }
};

struct Fixture {
  std::unique_ptr<EnvironmentModel> model;
  std::vector<Descriptor> queries;
  std::vector<Pose2> query_poses;
};

// Second benchmark argument: 0 = the L2 extractor above, 1 = the real FourierSignature
// (4 bands x 16 coefficients = 64 features, L2, heading from the coefficients).
std::shared_ptr<const DescriptorExtractor> MakeExtractor(std::int64_t which) {
  if (which == 1) {
    DescriptorOptions options;
    options.kind = DescriptorKind::kFourier;
    options.fourier.bands = 4;
    options.fourier.coefficients = 16;
    return MakeDescriptorExtractor(options);
  }
  (void)which;
  return std::make_shared<L2Extractor>();
}

Descriptor RandomDescriptor(std::mt19937& rng, const DescriptorExtractor& extractor) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Descriptor d;
  d.kind = extractor.kind();
  d.features.resize(kFeatures);
  for (float& f : d.features) f = u(rng);
  if (extractor.ProvidesHeading()) {
    d.coefficients.resize(kFeatures);
    for (std::size_t i = 0; i < kFeatures; ++i)
      d.coefficients[i] = std::polar(d.features[i], 6.28f * u(rng));
    d.panorama_width = 360;
  }
  return d;
}

Fixture MakeFixture(std::size_t num_views, std::int64_t which_extractor = 0) {
  std::mt19937 rng(1234);
  EnvironmentModelOptions o;
  o.retrieval.e_max = 1.0;  // random views are ~3.3 apart; a perturbed copy is ~0.4 from its view
  o.forgetting.d_for_m = 2.0;
  o.retrieval.top_k = 0;
  o.update.beta = 0.1;
  o.forgetting.d_gain_m = 0.2;
  // Random descriptors never match their neighbours, so with the default gain active
  // forgetting would empty the neighbourhood of the repeated query poses within the
  // benchmark's iterations; a tiny gain keeps the map size constant (same work per call).
  o.forgetting.beta_for = 1e-6;
  o.index.spatial_cell_m = 1.0;
  Fixture f;
  f.model = std::make_unique<EnvironmentModel>(o, MakeExtractor(which_extractor));
  if (f.model->extractor().FeatureSize() != kFeatures) throw Error("benchmark expects 64 features");
  const double side_m = std::sqrt(static_cast<double>(num_views) / 4.0);
  std::uniform_real_distribution<double> pos(0.0, side_m);
  std::uniform_real_distribution<double> ang(-kPi, kPi);
  std::normal_distribution<float> noise(0.0f, 0.05f);
  std::vector<Descriptor> descriptors;
  for (std::size_t i = 0; i < num_views; ++i) {
    Descriptor d = RandomDescriptor(rng, f.model->extractor());
    ViewComponent c;
    c.weight = 0.5;
    c.eta = 1.0;
    c.mean = MakePose(pos(rng), pos(rng), ang(rng));
    c.covariance = Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal();
    f.model->AddView(d, {c}, ViewStats{});
    if (i % (num_views / 256 + 1) == 0) {
      Descriptor q = d;
      for (float& v : q.features) v += noise(rng);
      f.queries.push_back(q);
      f.query_poses.push_back(MakePose(c.mean.x() + 0.05, c.mean.y() - 0.05, c.mean.z()));
    }
  }
  return f;
}

void BM_FindMatches(benchmark::State& state) {
  Fixture f = MakeFixture(static_cast<std::size_t>(state.range(0)), state.range(1));
  std::size_t k = 0, matches = 0;
  for (auto _ : state) {
    auto m = f.model->FindMatches(f.queries[k++ % f.queries.size()]);
    matches += m.size();
    benchmark::DoNotOptimize(m);
  }
  state.counters["views"] = static_cast<double>(f.model->NumViews());
  state.counters["matches_per_query"] =
      static_cast<double>(matches) / static_cast<double>(state.iterations());
}

void BM_Hypothesis(benchmark::State& state) {
  Fixture f = MakeFixture(static_cast<std::size_t>(state.range(0)), state.range(1));
  std::size_t k = 0;
  for (auto _ : state) {
    Mixture h = f.model->Hypothesis(f.queries[k++ % f.queries.size()]);
    benchmark::DoNotOptimize(h);
  }
  state.counters["views"] = static_cast<double>(f.model->NumViews());
}

// An observation of a mapped place: search, merge into its view, weight rules, active
// forgetting around mu_t.
void BM_UpdateMatching(benchmark::State& state) {
  Fixture f = MakeFixture(static_cast<std::size_t>(state.range(0)), state.range(1));
  std::size_t k = 0;
  std::int64_t frame = 0;
  for (auto _ : state) {
    const std::size_t q = k++ % f.queries.size();
    Gaussian g;
    g.mean = f.query_poses[q];
    g.covariance = Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal();
    UpdateStats s = f.model->Update(f.queries[q], g, {frame++, 0});
    benchmark::DoNotOptimize(s);
  }
  state.counters["views"] = static_cast<double>(f.model->NumViews());
  state.counters["components"] = static_cast<double>(f.model->NumComponents());
}

// A novel observation: search finds nothing, a view is inserted, active forgetting acts
// on the components around mu_t.
void BM_UpdateNovel(benchmark::State& state) {
  Fixture f = MakeFixture(static_cast<std::size_t>(state.range(0)), state.range(1));
  std::mt19937 rng(99);
  std::size_t k = 0;
  std::int64_t frame = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const Descriptor y = RandomDescriptor(rng, f.model->extractor());
    state.ResumeTiming();
    Gaussian g;
    g.mean = f.query_poses[k++ % f.query_poses.size()];
    g.covariance = Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal();
    UpdateStats s = f.model->Update(y, g, {frame++, 0});
    benchmark::DoNotOptimize(s);
  }
  state.counters["views"] = static_cast<double>(f.model->NumViews());
}

// Arguments: {views, extractor (0 = L2 fake, 1 = FourierSignature)}.
void Sizes(benchmark::internal::Benchmark* b) {
  for (const std::int64_t which : {0, 1}) {
    for (const std::int64_t n : {1000, 10000, 100000}) b->Args({n, which});
  }
  b->ArgNames({"views", "fourier"});
  b->Unit(benchmark::kMicrosecond);
}

// View persistence's refit (view_persistence.h): the grid posterior of (h, P_M) and the
// upper quantiles of P(exists | m), from the counts of `passes` pass outcomes. Its cost
// does not depend on the counts' size; the schedule refits after 2 % more passes.
void BM_PersistenceRefit(benchmark::State& state) {
  std::mt19937_64 rng(7);
  std::bernoulli_distribution matched(0.6);
  ViewPersistence p;
  for (std::int64_t k = 0; k < state.range(0); ++k) {
    p.Record(static_cast<int>(k % 5), matched(rng));
  }
  for (auto _ : state) {
    p.Refit();
    benchmark::DoNotOptimize(p.UpperExistence(2));
  }
}
BENCHMARK(BM_PersistenceRefit)->Arg(1000)->Arg(100000)->Unit(benchmark::kMillisecond);

BENCHMARK(BM_FindMatches)->Apply(Sizes);
BENCHMARK(BM_Hypothesis)->Apply(Sizes);
BENCHMARK(BM_UpdateMatching)->Apply(Sizes);
// Fixed iterations: each call inserts a view, so the map grows by at most 300.
BENCHMARK(BM_UpdateNovel)->Apply(Sizes)->Iterations(300);

}  // namespace
}  // namespace omnicml
