// ProcessFrame cost against map size: the whole per-frame pipeline (panorama preparation,
// Fourier descriptor, map barrier and update, nearest-view search, hypothesis, fusion)
// on maps pre-filled with 1k, 10k and 100k synthetic views.
//
// The synthetic map is written in the environment model's binary format (so building a
// 100k-view map does not take 100k full-map insertions) and loaded with
// EnvironmentModel::Deserialize: random Fourier-like descriptors at random places, plus a
// handful of views close to the benchmark frame's descriptor so that every frame has real
// matches, a real hypothesis and a real map update. Reported: wall time per frame (the
// Time column, microseconds) and the mean time of the match stage (match_us).
#include <benchmark/benchmark.h>

#include <cmath>
#include <complex>
#include <cstdint>
#include <memory>
#include <random>
#include <vector>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"

namespace omnicml {
namespace {

// A textured panorama (same image every frame; the robot "moves" only in odometry).
cv::Mat BenchPanorama(int width, int height) {
  cv::Mat pano(height, width, CV_8UC1);
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      const double a = kTwoPi * c / width;
      pano.at<std::uint8_t>(r, c) =
          cv::saturate_cast<std::uint8_t>(128 + 50 * std::sin(3 * a + 0.1 * r) +
                                          30 * std::sin(7 * a) + 20 * std::cos(13 * a + 0.3 * r));
    }
  }
  return pano;
}

// Bytes of an EnvironmentModel::Serialize stream (format version 1, see
// src/environment_model.cc) holding `num_views` views: random ones plus `near` views that
// are small perturbations of `query`.
std::vector<std::uint8_t> SyntheticModelBytes(std::size_t num_views, const Descriptor& query,
                                              int near, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> mag(0.0f, 0.35f);
  std::uniform_real_distribution<double> phase(-kPi, kPi);
  std::uniform_real_distribution<double> place(0.0, 200.0);
  std::normal_distribution<float> jitter(0.0f, 0.01f);
  const std::size_t k = query.features.size();
  BinaryWriter out;
  out.Write<std::uint32_t>(0x4D45434Fu);  // model magic
  out.Write<std::uint32_t>(1u);           // model format version
  out.Write(DescriptorKind::kFourier);
  out.Write<std::uint64_t>(k);
  out.Write<std::uint64_t>(num_views + 1);  // next view id
  out.Write<std::uint64_t>(num_views + 1);  // next component id
  out.Write<std::uint64_t>(num_views);
  for (std::size_t v = 0; v < num_views; ++v) {
    const bool is_near = static_cast<int>(v % (num_views / static_cast<std::size_t>(near))) == 0;
    out.Write<std::uint64_t>(v + 1);
    // Descriptor.
    out.Write(DescriptorKind::kFourier);
    std::vector<float> f(k);
    std::vector<std::complex<float>> coeffs(k);
    for (std::size_t j = 0; j < k; ++j) {
      f[j] = is_near ? std::max(0.0f, query.features[j] + jitter(rng)) : mag(rng);
      coeffs[j] =
          is_near ? query.coefficients[j] : std::polar(f[j], static_cast<float>(phase(rng)));
    }
    out.WriteVector(f);
    out.Write<std::uint64_t>(k);
    for (const auto& c : coeffs) {
      out.Write(c.real());
      out.Write(c.imag());
    }
    out.Write<std::int32_t>(query.panorama_width);
    // Counters.
    out.Write<std::int64_t>(0);
    out.Write<std::int32_t>(0);
    out.Write<std::int64_t>(1);
    out.Write<std::int64_t>(0);
    out.Write<std::int32_t>(0);
    // One component.
    out.Write<std::uint64_t>(1);
    out.Write<std::uint64_t>(v + 1);
    out.Write<double>(0.5);
    out.Write<double>(1.0);
    const double x = is_near ? 10.0 : place(rng), y = is_near ? 10.0 : place(rng);
    out.Write<double>(x);
    out.Write<double>(y);
    out.Write<double>(0.0);
    const double cov[9] = {0.05, 0, 0, 0, 0.05, 0, 0, 0, 0.01};
    for (double c : cov) out.Write<double>(c);
  }
  out.Write<std::uint64_t>(0);  // no events
  return out.Release();
}

void BM_ProcessFrame(benchmark::State& state) {
  const std::size_t num_views = static_cast<std::size_t>(state.range(0));
  CmlEngineOptions options;
  options.threads = static_cast<int>(state.range(1));
  CmlEngine engine(options);
  const cv::Mat pano = BenchPanorama(256, 32);
  const Descriptor query = engine.extractor().Compute(pano);
  const std::vector<std::uint8_t> bytes = SyntheticModelBytes(num_views, query, 8, 1);
  BinaryReader reader(bytes, "synthetic model");
  engine.ReplaceModel(EnvironmentModel::Deserialize(reader, options.model, engine.extractor_ptr()));
  if (engine.model().NumViews() != num_views) {
    state.SkipWithError("synthetic model did not load");
    return;
  }
  SessionInfo info;
  info.camera.kind = ImageKind::kPanorama;
  info.camera.image_width = pano.cols;
  info.camera.image_height = pano.rows;
  info.start.map_T_robot = MakePose(10.0, 10.0, 0.0);
  engine.BeginSession(info);

  Frame frame;
  frame.image = pano;
  double match_us = 0.0;
  std::int64_t i = 0;
  for (auto _ : state) {
    // The robot dithers around the matching place so the estimate stays consistent.
    frame.odom_T_robot = MakePose(0.01 * static_cast<double>(i % 2), 0.0, 0.0);
    frame.global_index = i++;
    const FrameResult r = engine.ProcessFrame(frame);
    match_us += r.stats.match_us;
    benchmark::DoNotOptimize(r.estimate);
  }
  state.counters["match_us"] =
      match_us / static_cast<double>(std::max<std::int64_t>(1, state.iterations()));
  state.counters["views"] = static_cast<double>(engine.model().NumViews());
}

BENCHMARK(BM_ProcessFrame)
    ->ArgNames({"views", "threads"})
    ->Args({1000, 1})
    ->Args({10000, 1})
    ->Args({100000, 1})
    ->Args({10000, 2})
    ->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace omnicml
