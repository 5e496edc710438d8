// Scale of the environment model (issue 19): nearest-view search (FindMatches, the exact
// linear scan) at 1k, 10k, 100k and 1M views, and memory per view, through the public
// EnvironmentModel API only (AddView to build, FindMatches to query).
//
// Synthetic map of the real descriptor: the default FourierSignature (4 bands x 16
// coefficients = 64 magnitudes, L2 distance, 64 complex coefficients for the relative
// heading), e_max 0.45 (the engine default). Views come in routes of 1000: along a route
// the magnitudes follow a stationary Ornstein-Uhlenbeck walk (per-feature mean 0.3,
// standard deviation 0.075, step correlation 0.875), so consecutive views are ~0.3 apart
// and unrelated views ~0.85 apart, as measured on simulated institute panoramas
// (`omnicml describe --panorama --json`: neighbours 0.46-0.50 at 50 frames a day,
// unrelated 0.75-0.99). A query is a map view plus Gaussian noise of norm ~0.16, so it
// matches its view and a few route neighbours, as a revisit does.
//
// Counters: views, matches_per_query, bytes_per_view (EnvironmentModel::MemoryBytes over
// the views, event log cleared), rss_bytes_per_view (resident-set growth while building,
// Linux; 0 elsewhere). One fixture at a time is kept, so peak memory is one map's.
#include <cmath>
#include <complex>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml {
namespace {

constexpr std::size_t kFeatures = 64;  // 4 bands x 16 coefficients
constexpr int kRouteViews = 1000;
constexpr float kMean = 0.3f, kSigma = 0.075f, kRho = 0.875f;

// Resident set size in bytes (Linux /proc/self/status VmRSS), 0 if unknown.
std::size_t ResidentBytes() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stoull(line.substr(6)) * 1024;
  }
  return 0;
}

struct ScaleFixture {
  std::size_t num_views = 0;
  std::unique_ptr<EnvironmentModel> model;
  std::vector<Descriptor> queries;
  double bytes_per_view = 0, rss_bytes_per_view = 0;
};

Descriptor MakeDescriptor(const std::vector<float>& magnitudes, std::mt19937& rng) {
  std::uniform_real_distribution<float> phase(-3.14159265f, 3.14159265f);
  Descriptor d;
  d.kind = DescriptorKind::kFourier;
  d.features = magnitudes;
  d.coefficients.resize(kFeatures);
  for (std::size_t i = 0; i < kFeatures; ++i)
    d.coefficients[i] = std::polar(std::max(magnitudes[i], 0.0f), phase(rng));
  d.panorama_width = 720;
  return d;
}

// Builds (or returns the cached) map of n views; the previous one is freed first.
ScaleFixture& Fixture(std::size_t n) {
  static ScaleFixture f;
  if (f.num_views == n && f.model) return f;
  f = ScaleFixture{};
  const std::size_t rss0 = ResidentBytes();
  DescriptorOptions descriptor;  // defaults: Fourier, 4 bands x 16 coefficients
  std::shared_ptr<const DescriptorExtractor> extractor = MakeDescriptorExtractor(descriptor);
  if (extractor->FeatureSize() != kFeatures) throw Error("benchmark expects 64 features");
  EnvironmentModelOptions o;
  o.e_max = 0.45;
  o.top_k = 8;
  f.model = std::make_unique<EnvironmentModel>(o, extractor);
  std::mt19937 rng(1919);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  std::uniform_real_distribution<double> pos(0.0, std::sqrt(static_cast<double>(n) / 4.0));
  const float innovation = kSigma * std::sqrt(1.0f - kRho * kRho);
  std::vector<float> x(kFeatures);
  const std::size_t query_every = n / 512 + 1;
  for (std::size_t i = 0; i < n; ++i) {
    if (i % kRouteViews == 0) {
      for (float& v : x) v = kMean + kSigma * normal(rng);  // a new route
    } else {
      for (float& v : x) v = kMean + kRho * (v - kMean) + innovation * normal(rng);
    }
    Descriptor d = MakeDescriptor(x, rng);
    ViewComponent c;
    c.weight = 0.5;
    c.eta = 1.0;
    c.mean = MakePose(pos(rng), pos(rng), 0.0);
    c.covariance = Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal();
    f.model->AddView(d, {c}, ViewStats{});
    if (i % query_every == 0) {
      std::vector<float> q = x;
      for (float& v : q) v += 0.02f * normal(rng);  // norm ~0.16
      f.queries.push_back(MakeDescriptor(q, rng));
    }
  }
  f.model->ClearEvents();
  f.num_views = n;
  f.bytes_per_view = static_cast<double>(f.model->MemoryBytes()) / static_cast<double>(n);
  const std::size_t rss1 = ResidentBytes();
  f.rss_bytes_per_view =
      rss1 > rss0 ? static_cast<double>(rss1 - rss0) / static_cast<double>(n) : 0.0;
  return f;
}

// The exact scan (every view's distance), matches sorted and cut to top_k 8.
void BM_FindMatchesScale(benchmark::State& state) {
  ScaleFixture& f = Fixture(static_cast<std::size_t>(state.range(0)));
  std::size_t k = 0, matches = 0;
  for (auto _ : state) {
    auto m = f.model->FindMatches(f.queries[k++ % f.queries.size()]);
    matches += m.size();
    benchmark::DoNotOptimize(m);
  }
  state.counters["views"] = static_cast<double>(f.model->NumViews());
  state.counters["matches_per_query"] =
      static_cast<double>(matches) / static_cast<double>(state.iterations());
  state.counters["bytes_per_view"] = f.bytes_per_view;
  state.counters["rss_bytes_per_view"] = f.rss_bytes_per_view;
  state.counters["ns_per_view"] = benchmark::Counter(
      static_cast<double>(state.iterations()) * static_cast<double>(f.model->NumViews()),
      benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_FindMatchesScale)
    ->Arg(1000)
    ->Arg(10000)
    ->Arg(100000)
    ->Arg(1000000)
    ->ArgName("views")
    ->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace omnicml

