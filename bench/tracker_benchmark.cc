// Cost of the tracker's per-frame operations: fusion of two 50-component mixtures
// (gating of all 2500 pairs, covariance intersection of the gated ones, then
// normalisation, pruning, merging and capping) and propagation of 100 components.
//
// Synthetic mixtures (seeded): means uniform in a 10 m x 10 m square with uniform
// headings, covariances with standard deviations of 0.3-1 m and 0.1-0.3 rad, so a
// sizeable share of the pairs falls within the gate (2).
#include <random>
#include <vector>

#include <benchmark/benchmark.h>
#include <Eigen/Core>

#include "omnicml/common/common.h"
#include "omnicml/tracking/tracker.h"

namespace omnicml {
namespace {

Mixture RandomMixture(std::mt19937_64& rng, int n) {
  std::uniform_real_distribution<double> xy(0.0, 10.0), phi(-kPi, kPi), sigma_xy(0.3, 1.0),
      sigma_phi(0.1, 0.3), corr(-0.5, 0.5), w(0.1, 1.0);
  Mixture m;
  for (int i = 0; i < n; ++i) {
    Gaussian g;
    g.mean = MakePose(xy(rng), xy(rng), phi(rng));
    const double sx = sigma_xy(rng), sy = sigma_xy(rng), sp = sigma_phi(rng), r = corr(rng);
    g.covariance << sx * sx, r * sx * sy, 0.0, r * sx * sy, sy * sy, 0.0, 0.0, 0.0, sp * sp;
    g.weight = w(rng);
    m.push_back(g);
  }
  NormalizeWeights(&m);
  return m;
}

void BM_Fuse50x50(benchmark::State& state) {
  std::mt19937_64 rng(42);
  const Mixture p_x_u = RandomMixture(rng, 50);
  const std::vector<Mixture> sources = {RandomMixture(rng, 50)};
  const TrackerOptions options;
  std::size_t out_size = 0;
  for (auto _ : state) {
    const Mixture fused = Fuse(p_x_u, sources, options);
    out_size = fused.size();
    benchmark::DoNotOptimize(fused.data());
  }
  state.counters["components_out"] = static_cast<double>(out_size);
  // Components before the clean-up: one per gated pair plus the unmatched ones copied.
  state.counters["components_fused"] =
      static_cast<double>(FuseOnce(p_x_u, sources[0], options).size());
}
BENCHMARK(BM_Fuse50x50)->Unit(benchmark::kMicrosecond);

// The two halves of BM_Fuse50x50: gating + covariance intersection + weights (8) ...
void BM_FuseOnce50x50(benchmark::State& state) {
  std::mt19937_64 rng(42);
  const Mixture a = RandomMixture(rng, 50);
  const Mixture b = RandomMixture(rng, 50);
  const TrackerOptions options;
  for (auto _ : state) {
    const Mixture fused = FuseOnce(a, b, options);
    benchmark::DoNotOptimize(fused.data());
  }
}
BENCHMARK(BM_FuseOnce50x50)->Unit(benchmark::kMicrosecond);

// ... and the clean-up of its output (normalise, prune, merge, cap).
void BM_SimplifyFused50x50(benchmark::State& state) {
  std::mt19937_64 rng(42);
  const Mixture a = RandomMixture(rng, 50);
  const Mixture b = RandomMixture(rng, 50);
  const TrackerOptions options;
  const Mixture fused = FuseOnce(a, b, options);
  for (auto _ : state) {
    const Mixture simplified = Simplify(fused, options);
    benchmark::DoNotOptimize(simplified.data());
  }
}
BENCHMARK(BM_SimplifyFused50x50)->Unit(benchmark::kMicrosecond);

void BM_Propagate100(benchmark::State& state) {
  std::mt19937_64 rng(43);
  const Mixture prior = RandomMixture(rng, 100);
  const OdometryIncrement u{0.1, 0.5, -0.05};
  const MotionNoise noise;
  for (auto _ : state) {
    const Mixture p = Propagate(prior, u, noise);
    benchmark::DoNotOptimize(p.data());
  }
}
BENCHMARK(BM_Propagate100)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace omnicml
