// Speed of the omniview unwrapping module: Unwrap 640x480 -> 720x120 (grey, colour),
// Render 720x120 -> 640x480 (the simulator's path), map construction, AutoCalibrate.
#include <random>

#include <benchmark/benchmark.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

cv::Mat RandomPanorama(int channels) {
  cv::Mat pano(120, 720, CV_8UC(channels));
  cv::RNG rng(7);
  rng.fill(pano, cv::RNG::UNIFORM, 60, 240);
  cv::GaussianBlur(pano, pano, cv::Size(0, 0), 2.0);
  return pano;
}

const OmniUnwrapper& Unwrapper() {
  static const OmniUnwrapper unwrapper(OmniCalibration{}, 640, 480);
  return unwrapper;
}

void BM_UnwrapGrey(benchmark::State& state) {
  const cv::Mat raw = Unwrapper().Render(RandomPanorama(1));
  for (auto _ : state) benchmark::DoNotOptimize(Unwrapper().Unwrap(raw).data);
}
BENCHMARK(BM_UnwrapGrey)->Unit(benchmark::kMicrosecond);

void BM_UnwrapColour(benchmark::State& state) {
  const cv::Mat raw = Unwrapper().Render(RandomPanorama(3));
  for (auto _ : state) benchmark::DoNotOptimize(Unwrapper().Unwrap(raw).data);
}
BENCHMARK(BM_UnwrapColour)->Unit(benchmark::kMicrosecond);

void BM_RenderGrey(benchmark::State& state) {
  const cv::Mat pano = RandomPanorama(1);
  for (auto _ : state) benchmark::DoNotOptimize(Unwrapper().Render(pano).data);
}
BENCHMARK(BM_RenderGrey)->Unit(benchmark::kMicrosecond);

void BM_RenderColour(benchmark::State& state) {
  const cv::Mat pano = RandomPanorama(3);
  for (auto _ : state) benchmark::DoNotOptimize(Unwrapper().Render(pano).data);
}
BENCHMARK(BM_RenderColour)->Unit(benchmark::kMicrosecond);

void BM_ConstructUnwrapper(benchmark::State& state) {
  for (auto _ : state) {
    OmniUnwrapper unwrapper(OmniCalibration{}, 640, 480);
    benchmark::DoNotOptimize(&unwrapper);
  }
}
BENCHMARK(BM_ConstructUnwrapper)->Unit(benchmark::kMillisecond);

void BM_AutoCalibrate(benchmark::State& state) {
  cv::Mat raw = Unwrapper().Render(RandomPanorama(1));
  cv::Mat noise(raw.size(), CV_8UC1);
  cv::RNG rng(3);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 10);
  raw += noise;
  for (auto _ : state) benchmark::DoNotOptimize(AutoCalibrate(raw).calibration.center_x_px);
}
BENCHMARK(BM_AutoCalibrate)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace omnicml
