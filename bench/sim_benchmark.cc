// Speed of the simulator: panorama ray casting, ring rendering, sensor noise, whole
// frames (SimulatedFrameSource::Next) and the per-frame cost of the panorama the engine
// sees (ring + unwrap against the direct panorama) for the built-in worlds, one core
// (docs/results.md "Simulator speed").
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "omnicml/common/limits.h"
#include "omnicml/sim/renderer.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace {

const char* const kWorlds[] = {"home_store", "institute", "store_large"};

// Poses along the world's route, so the views are typical.
std::vector<omnicml::Pose2> RoutePoses(const omnicml::World& world, int n) {
  const omnicml::RoutePath route(world.route.waypoints_m, world.route.turn_radius_m);
  std::vector<omnicml::Pose2> poses;
  for (int i = 0; i < n; ++i) poses.push_back(route.PoseAt(route.length_m() * i / n));
  return poses;
}

// Ray casting into the 720x120 panorama (people included).
void BM_RenderPanorama(benchmark::State& state) {
  const omnicml::World world = omnicml::LoadBuiltinWorld(kWorlds[state.range(0)]);
  omnicml::Renderer renderer(world);
  const auto poses = RoutePoses(world, 64);
  std::vector<omnicml::Person> people;
  for (int i = 0; i < world.people.count; ++i) {
    people.push_back({poses[(i * 7) % poses.size()].head<2>() + Eigen::Vector2d(0.8, 0.3), 0.25,
                      1.75, static_cast<std::uint64_t>(i)});
  }
  cv::Mat pano;
  std::size_t i = 0;
  for (auto _ : state) {
    renderer.RenderPanorama(poses[i++ % poses.size()], people, &pano);
    benchmark::DoNotOptimize(pano.data);
  }
  state.SetLabel(kWorlds[state.range(0)]);
}
BENCHMARK(BM_RenderPanorama)->DenseRange(0, 2)->Unit(benchmark::kMicrosecond);

// Panorama -> 640x480 ring (OmniUnwrapper::Render).
void BM_RenderRing(benchmark::State& state) {
  const omnicml::World world = omnicml::LoadBuiltinWorld("home_store");
  omnicml::Renderer renderer(world);
  const cv::Mat pano = renderer.RenderPanorama(RoutePoses(world, 1)[0]);
  for (auto _ : state) {
    cv::Mat ring = renderer.RenderRing(pano);
    benchmark::DoNotOptimize(ring.data);
  }
}
BENCHMARK(BM_RenderRing)->Unit(benchmark::kMicrosecond);

// Sensor noise on a 640x480x3 ring.
void BM_SensorNoise(benchmark::State& state) {
  const omnicml::World world = omnicml::LoadBuiltinWorld("home_store");
  omnicml::Renderer renderer(world);
  cv::Mat ring(world.camera.ring_height_px, world.camera.ring_width_px, CV_8UC3,
               cv::Scalar::all(100));
  std::uint64_t seed = 0;
  for (auto _ : state) {
    renderer.AddSensorNoise(&ring, seed++);
    benchmark::DoNotOptimize(ring.data);
  }
}
BENCHMARK(BM_SensorNoise)->Unit(benchmark::kMicrosecond);

// Whole frames: truth, odometry, events, people, panorama, ring, noise.
void BM_SimulatedFrame(benchmark::State& state) {
  omnicml::SimulatorOptions options;
  options.world = kWorlds[state.range(0)];
  options.frames_per_day = omnicml::kMaxFramesPerDay;
  options.output = state.range(1) ? omnicml::ImageKind::kRawRing : omnicml::ImageKind::kPanorama;
  omnicml::SimulatedFrameSource source(options);
  omnicml::Frame frame;
  for (auto _ : state) {
    source.Next(&frame);
    benchmark::DoNotOptimize(frame.image.data);
  }
  state.SetLabel(std::string(kWorlds[state.range(0)]) +
                 (state.range(1) ? " ring 640x480" : " panorama 720x120"));
}
BENCHMARK(BM_SimulatedFrame)->ArgsProduct({{0, 1, 2}, {0, 1}})->Unit(benchmark::kMicrosecond);

// Per frame, what `omnicml run --world` spends to hand the engine its panorama, one core:
// arg 1 = 0: ray casting + ring render + ring noise + Unwrap (--sim-image raw_ring, the
// default); 1: ray casting + panorama noise (--sim-image panorama). Route poses, the
// world's people standing still.
void BM_EnginePanoramaPerFrame(benchmark::State& state) {
  const omnicml::World world = omnicml::LoadBuiltinWorld(kWorlds[state.range(0)]);
  omnicml::Renderer renderer(world, 1);
  const auto poses = RoutePoses(world, 64);
  std::vector<omnicml::Person> people;
  for (int i = 0; i < world.people.count; ++i) {
    people.push_back({poses[(i * 7) % poses.size()].head<2>() + Eigen::Vector2d(0.8, 0.3), 0.25,
                      1.75, static_cast<std::uint64_t>(i)});
  }
  const bool direct = state.range(1) != 0;
  cv::Mat pano;
  std::uint64_t i = 0;
  for (auto _ : state) {
    renderer.RenderPanorama(poses[i % poses.size()], people, &pano);
    cv::Mat seen;
    if (direct) {
      seen = pano.clone();
      renderer.AddSensorNoise(&seen, i);
    } else {
      cv::Mat ring = renderer.RenderRing(pano);
      renderer.AddSensorNoise(&ring, i);
      seen = renderer.unwrapper().Unwrap(ring);
    }
    ++i;
    benchmark::DoNotOptimize(seen.data);
  }
  state.SetLabel(std::string(kWorlds[state.range(0)]) +
                 (direct ? " direct panorama" : " ring + unwrap"));
}
BENCHMARK(BM_EnginePanoramaPerFrame)
    ->ArgsProduct({{0, 1, 2}, {0, 1}})
    ->Unit(benchmark::kMicrosecond);

}  // namespace
