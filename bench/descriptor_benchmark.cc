// Speed of descriptor extraction on a 720x120 panorama and of the distance of one
// descriptor against 1k, 10k and 100k descriptors stored contiguously (the environment
// model's hot loop). The "per_stored" counter is the time per stored descriptor.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "omnicml/descriptors/color_histogram.h"
#include "omnicml/descriptors/fourier_signature.h"
#include "omnicml/descriptors/invariant_feature_histogram.h"

namespace omnicml {
namespace {

const cv::Mat& Panorama() {
  static const cv::Mat pano = MakeSyntheticPanorama(720, 120, 1);
  return pano;
}

template <typename Extractor>
void BM_Extract(benchmark::State& state) {
  const Extractor extractor;
  const cv::Mat& pano = Panorama();
  for (auto _ : state) benchmark::DoNotOptimize(extractor.Compute(pano));
}
BENCHMARK_TEMPLATE(BM_Extract, FourierSignature)
    ->Name("Extract/Fourier_720x120")
    ->Unit(benchmark::kMicrosecond);
// The cost of the default column normalisation: the same without it.
void BM_ExtractFourierBandsOnly(benchmark::State& state) {
  FourierOptions options;
  options.normalize_columns = false;
  const FourierSignature extractor(options);
  const cv::Mat& pano = Panorama();
  for (auto _ : state) benchmark::DoNotOptimize(extractor.Compute(pano));
}
BENCHMARK(BM_ExtractFourierBandsOnly)
    ->Name("Extract/Fourier_720x120_bands_only")
    ->Unit(benchmark::kMicrosecond);
BENCHMARK_TEMPLATE(BM_Extract, InvariantFeatureHistogram)
    ->Name("Extract/IFH_720x120")
    ->Unit(benchmark::kMicrosecond);
BENCHMARK_TEMPLATE(BM_Extract, ColorHistogram)
    ->Name("Extract/ColorHistogram_720x120")
    ->Unit(benchmark::kMicrosecond);

void BM_ExtractIfhSampled(benchmark::State& state) {
  IfhOptions options;
  options.sample_fraction = 0.1;
  const InvariantFeatureHistogram extractor(options);
  for (auto _ : state) benchmark::DoNotOptimize(extractor.Compute(Panorama()));
}
BENCHMARK(BM_ExtractIfhSampled)
    ->Name("Extract/IFH_720x120_sampled10pct")
    ->Unit(benchmark::kMicrosecond);

void BM_RelativeHeading(benchmark::State& state) {
  const FourierSignature fs;
  const Descriptor a = fs.Compute(Panorama()), b = fs.Compute(RollColumns(Panorama(), 77));
  for (auto _ : state) benchmark::DoNotOptimize(fs.RelativeHeading(a, b));
}
BENCHMARK(BM_RelativeHeading)->Name("Fourier/RelativeHeading_720");

// One query against `count` stored descriptors of `n` floats each, contiguous.
template <typename Extractor>
void BM_DistanceScan(benchmark::State& state, const Extractor& extractor, std::size_t n) {
  const auto count = static_cast<std::size_t>(state.range(0));
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<float> stored(count * n), query(n);
  for (auto& v : stored) v = u(rng) / n;
  for (auto& v : query) v = u(rng) / n;
  std::vector<double> out(count);
  const DescriptorExtractor& e = extractor;  // through the interface, as the map does
  for (auto _ : state) {
    for (std::size_t i = 0; i < count; ++i)
      out[i] = e.Distance(query.data(), stored.data() + i * n, n);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  // Seconds per stored descriptor (printed with an SI prefix: "7.0n" = 7 ns).
  state.counters["per_stored"] =
      benchmark::Counter(static_cast<double>(count) * static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}

void BM_DistanceFourierL2(benchmark::State& state) {
  BM_DistanceScan(state, FourierSignature(), 64);
}
void BM_DistanceFourierL1(benchmark::State& state) {
  FourierOptions o;
  o.distance = FourierDistance::kL1;
  BM_DistanceScan(state, FourierSignature(o), 64);
}
void BM_DistanceIfh(benchmark::State& state) {
  const InvariantFeatureHistogram e;
  BM_DistanceScan(state, e, e.FeatureSize());
}
void BM_DistanceColorJeffrey(benchmark::State& state) {
  const ColorHistogram e;
  BM_DistanceScan(state, e, e.FeatureSize());
}
BENCHMARK(BM_DistanceFourierL2)->Name("Distance/Fourier64_L2")->Arg(1000)->Arg(10000)->Arg(100000);
BENCHMARK(BM_DistanceFourierL1)->Name("Distance/Fourier64_L1")->Arg(1000)->Arg(10000)->Arg(100000);
BENCHMARK(BM_DistanceIfh)->Name("Distance/IFH96_intersection")->Arg(1000)->Arg(100000);
BENCHMARK(BM_DistanceColorJeffrey)->Name("Distance/Color192_Jeffrey")->Arg(1000)->Arg(100000);

}  // namespace
}  // namespace omnicml
