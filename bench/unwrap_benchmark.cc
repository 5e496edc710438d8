// Speed of the omniview unwrapping module: Unwrap 640x480 -> 720x120 (grey, colour),
// Render 720x120 -> 640x480 (the simulator's path), map construction, AutoCalibrate, and
// the per-frame front end at real resolutions: unwrap + Fourier describe of a 1920x1080
// ring and a 1440x1440 fisheye frame to a 720x150 panorama (one core).
#include <time.h>

#include <algorithm>
#include <chrono>
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

// Thread CPU time, microseconds (the per-frame cost on one core, whatever else runs).
double ThreadCpuMicros() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) * 1e6 + static_cast<double>(t.tv_nsec) * 1e-3;
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// Unwrap + describe of one real-resolution frame (range(0): 0 = 1920x1080 ring with the
// kuanli geometry, clipped top and bottom, masked descriptor; 1 = 1440x1440 equisolid
// fisheye) to a 720x150 colour panorama, Fourier signature with default options, OpenCV
// on one thread. Counters: per-frame medians over all iterations of the thread's CPU time
// and of the wall time, in total and for the unwrap and describe phases (microseconds).
void BM_UnwrapAndDescribeRealResolution(benchmark::State& state) {
  const int threads = cv::getNumThreads();
  cv::setNumThreads(1);
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
  const cv::Mat mask = unwrapper.MaskFor(720, 150);
  std::vector<double> cpu_us, wall_us, unwrap_cpu_us, describe_cpu_us;
  cv::Mat pano;
  for (auto _ : state) {
    const auto w0 = std::chrono::steady_clock::now();
    const double c0 = ThreadCpuMicros();
    unwrapper.Unwrap(raw, &pano);
    const double c1 = ThreadCpuMicros();
    const Descriptor d = fourier.ComputeMasked(pano, mask);
    benchmark::DoNotOptimize(d.features.data());
    const double c2 = ThreadCpuMicros();
    wall_us.push_back(
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - w0).count());
    cpu_us.push_back(c2 - c0);
    unwrap_cpu_us.push_back(c1 - c0);
    describe_cpu_us.push_back(c2 - c1);
  }
  state.counters["p50_cpu_us"] = Median(cpu_us);
  state.counters["p50_wall_us"] = Median(wall_us);
  state.counters["p50_unwrap_cpu_us"] = Median(unwrap_cpu_us);
  state.counters["p50_describe_cpu_us"] = Median(describe_cpu_us);
  state.SetLabel(state.range(0) == 0 ? "ring 1920x1080, masked" : "fisheye 1440x1440");
  cv::setNumThreads(threads);
}
BENCHMARK(BM_UnwrapAndDescribeRealResolution)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace omnicml
