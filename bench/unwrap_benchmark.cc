// Speed of the omniview unwrapping module: Unwrap 640x480 -> 720x120 (grey, colour),
// Render 720x120 -> 640x480 (the simulator's path), map construction, AutoCalibrate, and
// the per-frame front end at real resolutions: unwrap + Fourier describe of a 1920x1080
// ring and a 1440x1440 fisheye frame to a 720x150 panorama (one core).
#include <algorithm>
#include <random>
#include <vector>

#include <benchmark/benchmark.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "omnicml/descriptors/fourier_signature.h"
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

// Unwrap + describe of one real-resolution frame (range(0): 0 = 1920x1080 ring with the
// kuanli geometry, clipped top and bottom, masked descriptor; 1 = 1440x1440 equisolid
// fisheye) to a 720x150 colour panorama, Fourier signature with default options.
void BM_UnwrapAndDescribeRealResolution(benchmark::State& state) {
  CameraCalibration camera;
  int width = 1920, height = 1080;
  if (state.range(0) == 0) {
    OmniCalibration ring;
    ring.center_x_px = 974.3;
    ring.center_y_px = 545.9;
    ring.inner_radius_px = 235.0;
    ring.outer_radius_px = 600.0;
    camera = ring;
  } else {
    FisheyeCalibration f;
    f.center_x_px = 719.5;
    f.center_y_px = 719.5;
    f.circle_radius_px = 700.0;
    f.field_of_view_deg = 235.0;
    f.projection = FisheyeProjection::kEquisolid;
    camera = f;
    width = height = 1440;
  }
  camera.SetPanoramaSize(720, 150);
  const OmniUnwrapper unwrapper(camera, width, height);
  cv::Mat raw(height, width, CV_8UC3);
  cv::RNG rng(5);
  rng.fill(raw, cv::RNG::UNIFORM, 0, 255);
  cv::GaussianBlur(raw, raw, cv::Size(0, 0), 3.0);
  const FourierSignature fourier;
  const cv::Mat& mask = unwrapper.valid_mask();
  const bool masked = unwrapper.valid_fraction() < 1.0;
  for (auto _ : state) {
    const cv::Mat pano = unwrapper.Unwrap(raw);
    const Descriptor d = masked ? fourier.ComputeMasked(pano, mask) : fourier.Compute(pano);
    benchmark::DoNotOptimize(d.features.data());
  }
  state.SetLabel(state.range(0) == 0 ? "ring 1920x1080, masked" : "fisheye 1440x1440");
}
BENCHMARK(BM_UnwrapAndDescribeRealResolution)
    ->Arg(0)
    ->Arg(1)
    ->Unit(benchmark::kMicrosecond)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true)
    ->ComputeStatistics("p50", [](const std::vector<double>& v) {
      std::vector<double> s = v;
      std::nth_element(s.begin(), s.begin() + static_cast<std::ptrdiff_t>(s.size() / 2), s.end());
      return s[s.size() / 2];
    });

}  // namespace
}  // namespace omnicml
