// Cost of one MCL step ([W], mcl.h) at several particle counts over a synthetic open
// room with 100 references (descriptor computation excluded).
#include <benchmark/benchmark.h>

#include "omnicml/baselines/mcl/mcl.h"
#include "omnicml/descriptors/descriptor_factory.h"

namespace omnicml {
namespace {

void BM_MclStep(benchmark::State& state) {
  OccupancyGrid g(250, 100, 0.1, Eigen::Vector2d(0, 0));
  for (int x = 0; x < 250; ++x) {
    g.Set({x, 0}, CellState::kOccupied);
    g.Set({x, 99}, CellState::kOccupied);
  }
  for (int y = 0; y < 100; ++y) {
    g.Set({0, y}, CellState::kOccupied);
    g.Set({249, y}, CellState::kOccupied);
  }
  DescriptorOptions dopt;
  dopt.kind = DescriptorKind::kInvariantFeatureHistogram;
  std::shared_ptr<const DescriptorExtractor> ex = MakeDescriptorExtractor(dopt);
  std::vector<MclReference> refs;
  for (int i = 0; i < 100; ++i) {
    MclReference r;
    r.map_T_robot = MakePose(1 + 0.23 * i, 2 + 6.0 * (i % 2), i % 2 ? kPi : 0);
    r.descriptor = ex->Compute(MakeSyntheticPanorama(64, 16, static_cast<std::uint32_t>(i)));
    refs.push_back(std::move(r));
  }
  MclOptions o;
  o.num_particles = static_cast<int>(state.range(0));
  o.random_samples_per_step = std::min(50, o.num_particles / 2);
  ComputeVisibilityAreas(g, o, &refs);
  MonteCarloLocalizer mcl(o, g, refs, ex);
  mcl.InitializeGlobal();
  const Descriptor q = ex->Compute(MakeSyntheticPanorama(64, 16, 7));
  for (auto _ : state) {
    mcl.Predict({0.01, 0.2, -0.01});
    benchmark::DoNotOptimize(mcl.Correct(q));
  }
}
BENCHMARK(BM_MclStep)->Arg(500)->Arg(5000)->Arg(50000)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace omnicml
