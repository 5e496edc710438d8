// Per-frame cost of the global pose graph (engine/pose_graph.h) at 10k views:
// what CmlEngine does for one anchor frame with options.pose_graph.enabled — the frame's
// odometry and node, a loop closure every closure_every_frames (default 10) frames and,
// when due (optimize_every_frames, default 50), the windowed optimisation (window_nodes
// 3000) followed by moving the views of the corrected nodes (EnvironmentModel::
// MoveViewRigidly, the loop of CmlEngine::ApplyPoseGraphCorrections).
//
// Fixture: a 285 m rectangular route (store_large's lap length) at 0.2 m per frame,
// odometry with seeded noise (motion model a1..a4 defaults), one node and one view per
// frame (or every view_every-th frame, as when forgetting keeps a fraction of the views),
// 10,000 frames (about 7 laps), built with the same calls. Each benchmark
// iteration is one further frame, revisiting the route, whose closure links it to the
// node one lap earlier at the true pose. Counters: p50_us, p99_us and max_us of the
// per-frame wall time over the iterations (most frames add a node only; the optimising
// ones make the tail), views, nodes, closures, optimisations. With marginal_covariances
// each optimisation also computes the marginal covariance of the window nodes that
// created a view (Ceres' Covariance, sparse QR; the list CmlEngine passes) and gives it
// to the moved view's component.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <complex>
#include <memory>
#include <random>
#include <vector>

#include <benchmark/benchmark.h>

#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/engine/pose_graph.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml {
namespace {

constexpr double kStepM = 0.2;
constexpr double kSideA = 90.0, kSideB = 52.5;  // 2 (a + b) = 285 m
constexpr int kFramesPerLap = static_cast<int>(2 * (kSideA + kSideB) / kStepM);

// True pose at arc length s along the rectangle (counter-clockwise).
Pose2 RouteAt(double s) {
  s = std::fmod(s, 2 * (kSideA + kSideB));
  if (s < kSideA) return MakePose(s, 0, 0);
  s -= kSideA;
  if (s < kSideB) return MakePose(kSideA, s, kPi / 2);
  s -= kSideB;
  if (s < kSideA) return MakePose(kSideA - s, kSideB, kPi);
  s -= kSideA;
  return MakePose(0, kSideB - s, -kPi / 2);
}

struct Fixture {
  std::unique_ptr<EnvironmentModel> model;
  std::unique_ptr<PoseGraph> graph;
  std::mt19937 rng{15};
  Pose2 odom = Pose2::Zero();
  Pose2 prev_truth = Pose2::Zero();
  std::int64_t frame = 0;
  Descriptor descriptor;
  std::vector<std::int64_t> creators;  // frames that created a view, ascending
  bool marginals = false;

  // One frame: odometry, node at the dead-reckoned pose (as a dead-reckoned anchor
  // would be), a view created by it, and (when the graph accepts it) the closure to
  // the node one lap earlier.
  std::vector<NodeCorrection> Step(bool add_view) {
    const Pose2 truth = RouteAt(static_cast<double>(frame) * kStepM);
    OdometryIncrement u;
    if (frame > 0) {
      u = ComputeIncrement(prev_truth, truth);
      std::normal_distribution<double> n(0.0, 1.0);
      u.rot1_rad += 0.002 * n(rng);
      u.trans_m += 0.005 * n(rng);
      u.rot2_rad += 0.002 * n(rng);
      odom = ApplyIncrement(odom, u);
    }
    prev_truth = truth;
    graph->AddFrameOdometry(frame, u);
    graph->AddNode(frame, odom, std::nullopt);
    if (add_view) {
      ViewComponent c;
      c.weight = 0.5;
      c.eta = 1.0;
      c.mean = odom;
      c.covariance = Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal();
      ViewStats st;
      st.created_frame = frame;
      model->AddView(descriptor, {c}, st);
      creators.push_back(frame);
    }
    std::vector<NodeCorrection> corrections;
    if (frame >= kFramesPerLap) {
      graph->AddClosure(frame - kFramesPerLap, frame, truth,
                        Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal());
      if (graph->ShouldOptimize(frame))
        corrections = graph->Optimize(frame, marginals ? &creators : nullptr);
    }
    ++frame;
    return corrections;
  }

  // CmlEngine::ApplyPoseGraphCorrections' map loop.
  void MoveViews(const std::vector<NodeCorrection>& corrections) {
    if (corrections.empty()) return;
    for (std::size_t i = 0; i < model->NumViews(); ++i) {
      const std::int64_t f = model->views()[i].stats.created_frame;
      const auto it =
          std::lower_bound(corrections.begin(), corrections.end(), f,
                           [](const NodeCorrection& c, std::int64_t x) { return c.frame < x; });
      if (it != corrections.end() && it->frame == f) {
        model->MoveViewRigidly(i, it->before, it->after);
        if (it->covariance) model->SetComponentCovariance(i, 0, *it->covariance);
      }
    }
  }
};

std::unique_ptr<Fixture> MakeFixture(int frames, bool marginal_covariances, int view_every) {
  auto f = std::make_unique<Fixture>();
  DescriptorOptions d;
  std::shared_ptr<const DescriptorExtractor> extractor = MakeDescriptorExtractor(d);
  f->model = std::make_unique<EnvironmentModel>(EnvironmentModelOptions{}, extractor);
  f->descriptor.kind = DescriptorKind::kFourier;
  f->descriptor.features.assign(extractor->FeatureSize(), 0.3f);
  f->descriptor.coefficients.assign(extractor->FeatureSize(), std::complex<float>(0.3f, 0.0f));
  f->descriptor.panorama_width = 720;
  PoseGraphOptions o;
  o.enabled = true;
  o.marginal_covariances = marginal_covariances;
  f->marginals = marginal_covariances;
  f->graph = std::make_unique<PoseGraph>(o, MotionNoise{}, 1e-6, 1e-6, 1001);
  Gaussian start;
  start.mean = RouteAt(0);
  start.covariance = Eigen::Vector3d(1e-4, 1e-4, 1e-6).asDiagonal();
  f->graph->BeginSession(false, 0, start);
  for (int i = 0; i < frames; ++i) f->MoveViews(f->Step(i % view_every == 0));
  f->model->ClearEvents();
  return f;
}

void BM_PoseGraphPerFrame(benchmark::State& state) {
  std::unique_ptr<Fixture> f = MakeFixture(static_cast<int>(state.range(0)), state.range(1) != 0,
                                           static_cast<int>(state.range(2)));
  std::vector<double> us;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    f->MoveViews(f->Step(false));
    us.push_back(
        std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(us.begin(), us.end());
  auto q = [&](double p) {
    return us[std::min(us.size() - 1,
                       static_cast<std::size_t>(p * static_cast<double>(us.size())))];
  };
  state.counters["p50_us"] = q(0.50);
  state.counters["p99_us"] = q(0.99);
  state.counters["max_us"] = us.back();
  state.counters["views"] = static_cast<double>(f->model->NumViews());
  state.counters["nodes"] = static_cast<double>(f->graph->nodes().size());
  state.counters["closures"] = static_cast<double>(f->graph->closures().size());
  state.counters["optimizations"] = static_cast<double>(f->graph->optimizations());
}
// 500 frames after the 10k-frame fixture: 10 optimisations at the default every 50 frames;
// second argument: marginal_covariances (0 off, 1 on: a sparse QR of the window per
// optimisation, and each moved view's component takes its node's marginal); third: a
// view every this many frames (1: 10k views; 5: 2k, the map active forgetting keeps).
BENCHMARK(BM_PoseGraphPerFrame)
    ->Args({10000, 0, 1})
    ->Args({10000, 1, 1})
    ->Args({10000, 1, 5})
    ->Iterations(500)
    ->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace omnicml

BENCHMARK_MAIN();
