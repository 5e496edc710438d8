#include "omnicml/engine/cml_engine.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <complex>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <random>
#include <set>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
// The room world and route helpers are shared with engine_io_test.cc (same test binary).
namespace engine_testing {

// ---- A tiny synthetic world: a textured rectangular room rendered as panoramas ------
// (independent of the simulator so the engine's own tests stay small and fast).

constexpr double kRoomX = 10.0, kRoomY = 8.0, kWallH = 2.5, kCamH = 1.0;

double WallTexture(double s, double z) {
  // Incommensurate stripes along the perimeter coordinate s (metres), varying with height.
  return 128.0 + 45.0 * std::sin(2.0 * kPi * s / 3.7) +
         30.0 * std::sin(2.0 * kPi * s / 1.13 + 1.7 * z) +
         25.0 * std::sin(2.0 * kPi * s / 0.61 + 0.4) * (z > 1.2 ? 1.0 : -1.0);
}

// Panorama (W x H, CV_8UC1) seen at `pose` (panorama convention of omni_unwrapper.h).
cv::Mat RenderRoom(const Pose2& pose, int width = 128, int height = 24) {
  cv::Mat pano(height, width, CV_8UC1);
  for (int c = 0; c < width; ++c) {
    const double a = pose[2] + kTwoPi * c / width;
    const double dx = std::cos(a), dy = std::sin(a);
    double t = 1e9;
    if (dx > 1e-12) t = std::min(t, (kRoomX - pose[0]) / dx);
    if (dx < -1e-12) t = std::min(t, -pose[0] / dx);
    if (dy > 1e-12) t = std::min(t, (kRoomY - pose[1]) / dy);
    if (dy < -1e-12) t = std::min(t, -pose[1] / dy);
    const double hx = pose[0] + t * dx, hy = pose[1] + t * dy;
    // Perimeter coordinate, counter-clockwise from (0, 0).
    double s;
    if (hy < 1e-6)
      s = hx;
    else if (hx > kRoomX - 1e-6)
      s = kRoomX + hy;
    else if (hy > kRoomY - 1e-6)
      s = kRoomX + kRoomY + (kRoomX - hx);
    else
      s = 2 * kRoomX + kRoomY + (kRoomY - hy);
    for (int r = 0; r < height; ++r) {
      const double elev = (35.0 - 70.0 * r / (height - 1)) * kPi / 180.0;
      const double z = kCamH + t * std::tan(elev);
      double v = z > kWallH ? 210.0 : (z < 0.0 ? 50.0 + 10.0 * std::sin(t) : WallTexture(s, z));
      pano.at<std::uint8_t>(r, c) = cv::saturate_cast<std::uint8_t>(v);
    }
  }
  return pano;
}

struct RouteFrame {
  Pose2 truth;
  Pose2 odom;
};

// Laps around a rectangle inside the room, `step_m` apart, odometry with seeded noise
// (relative noise on translation and rotation, plus a small heading bias).
std::vector<RouteFrame> MakeLaps(int laps, double step_m, std::uint32_t seed,
                                 int start_offset = 0) {
  const std::vector<Eigen::Vector2d> corners = {{2.0, 2.0}, {8.0, 2.0}, {8.0, 6.0}, {2.0, 6.0}};
  std::vector<Pose2> truth;
  for (int lap = 0; lap < laps; ++lap) {
    for (int k = 0; k < 4; ++k) {
      const Eigen::Vector2d a = corners[k], b = corners[(k + 1) % 4];
      const Eigen::Vector2d d = b - a;
      const double heading = std::atan2(d.y(), d.x());
      const int n = static_cast<int>(std::round(d.norm() / step_m));
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector2d p = a + d * (static_cast<double>(i) / n);
        truth.push_back(MakePose(p.x(), p.y(), heading));
      }
    }
  }
  std::rotate(truth.begin(), truth.begin() + start_offset, truth.end());
  std::mt19937 rng(seed);
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<RouteFrame> frames(truth.size());
  frames[0] = {truth[0], MakePose(0.0, 0.0, 0.0)};
  for (std::size_t i = 1; i < truth.size(); ++i) {
    Pose2 rel = Between(truth[i - 1], truth[i]);
    const double dist = rel.head<2>().norm();
    rel[0] *= 1.0 + 0.03 * n01(rng);
    rel[1] += 0.02 * dist * n01(rng);
    rel[2] = WrapAngle(rel[2] + 0.01 * dist + 0.02 * std::abs(rel[2]) * n01(rng));
    frames[i] = {truth[i], Compose(frames[i - 1].odom, rel)};
  }
  return frames;
}

SessionInfo PanoramaSession(const std::string& name, SessionStartMode mode, const Pose2& start) {
  SessionInfo info;
  info.name = name;
  info.camera.kind = ImageKind::kPanorama;
  info.camera.image_width = 128;
  info.camera.image_height = 24;
  info.start.mode = mode;
  info.start.map_T_robot = start;
  info.start.covariance = Eigen::Vector3d(0.01, 0.01, 0.001).asDiagonal();
  return info;
}

Frame MakeFrame(const RouteFrame& r, int session, std::int64_t index) {
  Frame f;
  f.session_index = session;
  f.index_in_session = index;
  f.global_index = index;
  f.stamp_s = static_cast<double>(index);
  f.image = RenderRoom(r.truth);
  f.odom_T_robot = r.odom;
  f.map_T_robot_truth = r.truth;
  return f;
}

CmlEngineOptions TestOptions() {
  CmlEngineOptions o;
  o.update_delay_frames = 2;
  // Descriptor distances in this small room are smaller than in the simulator's worlds.
  o.model.retrieval.e_max = 0.1;
  return o;
}

// Position error of the point estimate (mean when unimodal, else the strongest component).
double PositionError(const FrameResult& r, const Pose2& truth) {
  const Gaussian& g = r.estimate->unimodal ? r.estimate->mean : r.estimate->strongest;
  return PoseDifference(g.mean, truth).head<2>().norm();
}

// Bitwise comparison of two estimates.
void ExpectSameEstimate(const FrameResult& a, const FrameResult& b) {
  ASSERT_EQ(a.estimate.has_value(), b.estimate.has_value()) << "frame " << a.frame;
  if (!a.estimate) return;
  EXPECT_EQ(a.estimate->mean.mean, b.estimate->mean.mean) << "frame " << a.frame;
  EXPECT_EQ(a.estimate->mean.covariance, b.estimate->mean.covariance) << "frame " << a.frame;
  EXPECT_EQ(a.estimate->unimodal, b.estimate->unimodal) << "frame " << a.frame;
  EXPECT_EQ(a.estimate->num_components, b.estimate->num_components) << "frame " << a.frame;
}

}  // namespace engine_testing

namespace {
using namespace engine_testing;

// ---- tests ------------------------------------------------------------------------

// Invalid options are rejected with the field's name.
TEST(CmlEngineOptions, ValidateNamesField) {
  // Expects Validate to throw an Error mentioning `field` after `change`.
  const auto expect_named = [](const auto& change, const std::string& field) {
    CmlEngineOptions o;
    change(o);
    try {
      o.Validate();
      ADD_FAILURE() << "no error for " << field;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  const CmlEngineOptions defaults;
  EXPECT_NO_THROW(defaults.Validate());
  expect_named([](CmlEngineOptions& o) { o.update_delay_frames = 0; }, "update_delay_frames");
  expect_named([](CmlEngineOptions& o) { o.model.retrieval.e_max = -1.0; }, "model");
  expect_named([](CmlEngineOptions& o) { o.panorama_width = 64; }, "panorama_width");
  expect_named([](CmlEngineOptions& o) { o.hypothesis_weight_scale = 0.0; },
               "hypothesis_weight_scale");
  expect_named([](CmlEngineOptions& o) { o.appearance_sigma_m = -1.0; }, "appearance_sigma_m");
  expect_named([](CmlEngineOptions& o) { o.anchor_max_sigma_m = -1.0; }, "anchor_max_sigma_m");
  expect_named([](CmlEngineOptions& o) { o.map_update_spacing_m = -0.1; }, "map_update_spacing_m");
  expect_named(
      [](CmlEngineOptions& o) { o.map_update_spacing_m = std::numeric_limits<double>::infinity(); },
      "map_update_spacing_m");
  expect_named([](CmlEngineOptions& o) { o.hypothesis_evidence_scale = 0.0; },
               "hypothesis_evidence_scale");
  expect_named([](CmlEngineOptions& o) { o.hypothesis_evidence_scale = 1.5; },
               "hypothesis_evidence_scale");
  expect_named([](CmlEngineOptions& o) { o.reference_frame_step_m = -0.2; },
               "reference_frame_step_m");
  expect_named(
      [](CmlEngineOptions& o) {
        o.reference_frame_step_m = std::numeric_limits<double>::quiet_NaN();
      },
      "reference_frame_step_m");
  expect_named([](CmlEngineOptions& o) { o.gated_matching.gate_sigmas = 0.0; },
               "gated_matching: gate_sigmas");
  expect_named([](CmlEngineOptions& o) { o.gated_matching.full_search_every_frames = 0; },
               "gated_matching: full_search_every_frames");
  expect_named([](CmlEngineOptions& o) { o.gated_matching.min_views = -1; },
               "gated_matching: min_views");
  expect_named(
      [](CmlEngineOptions& o) {
        o.appearance_offset_curve = {{0.2, 0.25}, {0.2, 0.3}};
      },
      "appearance_offset_curve[1]");
  expect_named(
      [](CmlEngineOptions& o) {
        o.appearance_offset_curve = {{0.2, -0.1}};
      },
      "appearance_offset_curve[0]");
  CmlEngineOptions bad_threads;
  bad_threads.threads = 0;
  EXPECT_THROW(CmlEngine{bad_threads}, Error);
}

// d(E) is read off the appearance curve from (0 m, E 0): exact at its points, linear
// between them, the first crossing when the curve is not monotone, its last travel beyond
// it; the variance is (d / 2)^2.
TEST(AppearanceOffsetCurve, VarianceReadsTheAppearanceCurve) {
  const std::vector<std::array<double, 2>> curve = {
      {0.2, 0.25}, {0.4, 0.35}, {0.6, 0.30}, {0.8, 0.45}};
  const auto d_of = [&](double e) { return 2.0 * std::sqrt(AppearanceOffsetVariance(curve, e)); };
  EXPECT_DOUBLE_EQ(d_of(0.25), 0.2);
  EXPECT_DOUBLE_EQ(d_of(0.125), 0.1);
  EXPECT_DOUBLE_EQ(d_of(0.30), 0.3);  // between 0.2 and 0.4, not at the later 0.6
  // Past the dip: between 0.6 m (E 0.30) and 0.8 m (E 0.45).
  EXPECT_NEAR(d_of(0.40), 0.6 + 0.2 * (0.10 / 0.15), 1e-12);
  EXPECT_DOUBLE_EQ(d_of(0.9), 0.8);
  EXPECT_EQ(AppearanceOffsetVariance(curve, 0.0), 0.0);
  EXPECT_EQ(AppearanceOffsetVariance({}, 0.3), 0.0);
}

// A model with one descriptor for every view, and components with a weight, eta and
// covariance of their own (the p(x|y) widening tests below).
class AppearanceOffset : public ::testing::Test {
 protected:
  void SetUp() override {
    d_.kind = DescriptorKind::kFourier;
    d_.features.assign(extractor_->FeatureSize(), 0.3f);
    d_.coefficients.assign(extractor_->FeatureSize(), std::complex<float>(0.3f, 0.0f));
    d_.panorama_width = 720;
  }
  static ViewComponent Component(double x,
                                 const Eigen::Matrix2d& spread = Eigen::Matrix2d::Zero()) {
    ViewComponent c;
    c.weight = 0.5;
    c.eta = 1.0;
    c.mean = MakePose(x, 0.0, 0.0);
    c.covariance = Eigen::Vector3d(0.01, 0.02, 0.001).asDiagonal();
    c.spread = spread;
    return c;
  }

  CmlEngineOptions o_;
  std::shared_ptr<const DescriptorExtractor> extractor_ = MakeDescriptorExtractor(o_.descriptor);
  EnvironmentModel model_{o_.model, extractor_};
  Descriptor d_;
};

// p(x|y) widens each view's components by the offset of that view's match, and only them.
TEST_F(AppearanceOffset, EachViewsComponentsTakeTheirMatchsOffset) {
  EnvironmentModel& model = model_;
  model.AddView(d_, {Component(0.0), Component(1.0)}, ViewStats{});
  model.AddView(d_, {Component(5.0)}, ViewStats{});
  const std::vector<ViewMatch> matches = {{1, model.views()[1].id, 0.1, 0.9, std::nullopt},
                                          {0, model.views()[0].id, 0.3, 0.5, std::nullopt}};
  const std::vector<std::array<double, 2>> curve = {{0.4, 0.4}};  // d(E) = E m
  const Mixture plain = model.Hypothesis(matches);
  Mixture widened = plain;
  AddAppearanceOffsets(model, matches, curve, &widened);
  ASSERT_EQ(widened.size(), 3u);
  const double v[3] = {0.25 * 0.1 * 0.1, 0.25 * 0.3 * 0.3, 0.25 * 0.3 * 0.3};
  for (std::size_t k = 0; k < 3; ++k) {
    EXPECT_NEAR(widened[k].covariance(0, 0) - plain[k].covariance(0, 0), v[k], 1e-15) << k;
    EXPECT_NEAR(widened[k].covariance(1, 1) - plain[k].covariance(1, 1), v[k], 1e-15) << k;
    EXPECT_EQ(widened[k].covariance(2, 2), plain[k].covariance(2, 2));
    EXPECT_EQ(widened[k].covariance(0, 1), plain[k].covariance(0, 1));
    EXPECT_EQ(widened[k].mean, plain[k].mean);
  }
  Mixture unchanged = plain;
  AddAppearanceOffsets(model, matches, {}, &unchanged);
  for (std::size_t k = 0; k < 3; ++k) EXPECT_EQ(unchanged[k].covariance, plain[k].covariance);
}

// SpreadBeyond keeps the part of a spread the floor does not explain, along its own axes:
// an elongated spread keeps its direction, an axis the floor covers adds nothing.
TEST(AppearanceOffsetSpread, SpreadBeyondTheFloorAlongItsAxes) {
  const double a = 0.3;  // the spread's major axis, 0.3 rad from x
  Eigen::Matrix2d r;
  r << std::cos(a), -std::sin(a), std::sin(a), std::cos(a);
  const auto along_axes = [&](double major, double minor) {
    return Eigen::Matrix2d(r * Eigen::Vector2d(major, minor).asDiagonal() * r.transpose());
  };
  const Eigen::Matrix2d spread = along_axes(1.0, 0.04);
  const Eigen::Matrix2d id = Eigen::Matrix2d::Identity();
  EXPECT_LT((SpreadBeyond(spread, 0.25 * id) - along_axes(0.75, 0.0)).norm(), 1e-12);
  EXPECT_LT((SpreadBeyond(spread, Eigen::Matrix2d::Zero()) - spread).norm(), 1e-12);
  EXPECT_LT((SpreadBeyond(spread, along_axes(0.5, 0.5)) - along_axes(0.5, 0.0)).norm(), 1e-12);
  EXPECT_LT(SpreadBeyond(spread, 2.0 * id).norm(), 1e-15);
  EXPECT_EQ(SpreadBeyond(Eigen::Matrix2d::Zero(), Eigen::Matrix2d::Zero()).norm(), 0.0);
}

// SpreadExcess: the spread beyond the component's own covariance plus the neighbourhood,
// along the spread's axes (the covariance is isotropic here, so the floor is too).
TEST(AppearanceOffsetSpread, SpreadExcessIsBeyondCovarianceAndNeighbourhood) {
  ViewComponent c;
  c.spread << 1.0, 0.0, 0.0, 0.09;
  c.covariance = Eigen::Vector3d(0.04, 0.04, 0.01).asDiagonal();
  const Eigen::Matrix2d excess = SpreadExcess(c, 0.01);
  EXPECT_NEAR(excess(0, 0), 1.0 - 0.04 - 0.01, 1e-12);
  EXPECT_NEAR(excess(1, 1), 0.09 - 0.04 - 0.01, 1e-12);
  EXPECT_NEAR(excess(0, 1), 0.0, 1e-12);
  EXPECT_LT(SpreadExcess(c, 1.0).norm(), 1e-15);  // the neighbourhood covers the spread
}

// Each matched component takes the part of its own spread that its covariance and the
// neighbourhood do not explain, in its xy block, and nothing else changes.
TEST_F(AppearanceOffset, EachComponentTakesItsOwnSpread) {
  EnvironmentModel& model = model_;
  Eigen::Matrix2d along;
  along << 0.5, 0.1, 0.1, 0.3;
  model.AddView(d_, {Component(0.0, along), Component(1.0)}, ViewStats{});
  model.AddView(d_, {Component(5.0, 2.0 * along)}, ViewStats{});
  const std::vector<ViewMatch> matches = {{1, model.views()[1].id, 0.1, 0.9, std::nullopt},
                                          {0, model.views()[0].id, 0.3, 0.5, std::nullopt}};
  const Mixture plain = model.Hypothesis(matches);
  Mixture widened = plain;
  AddSpreadOffsets(model, matches, 0.05, &widened);
  ASSERT_EQ(widened.size(), 3u);
  // Floor: C_xy = diag(0.01, 0.02) plus 0.05 m^2; both spreads exceed it on both axes.
  const Eigen::Matrix2d floor = Eigen::Vector2d(0.06, 0.07).asDiagonal();
  const Eigen::Matrix2d added[3] = {2.0 * along - floor, along - floor, Eigen::Matrix2d::Zero()};
  for (std::size_t k = 0; k < 3; ++k) {
    const Eigen::Matrix3d diff = widened[k].covariance - plain[k].covariance;
    EXPECT_LT((diff.topLeftCorner<2, 2>() - added[k]).norm(), 1e-12) << k;
    EXPECT_EQ(diff.col(2).norm(), 0.0) << k;
    EXPECT_EQ(diff.row(2).norm(), 0.0) << k;
    EXPECT_EQ(widened[k].mean, plain[k].mean);
  }
}

// Frames before any session are refused.
TEST(CmlEngine, ProcessFrameNeedsSession) {
  CmlEngine engine(TestOptions());
  const std::vector<RouteFrame> route = MakeLaps(1, 0.5, 1);
  EXPECT_THROW(engine.ProcessFrame(MakeFrame(route[0], 0, 0)), Error);
}

// Known start pose on an empty map: the first estimate is the start pose; the first
// update reaches the map exactly update_delay_frames frames later.
TEST(CmlEngine, EmptyMapStartsAtKnownPoseAndDelaysUpdates) {
  for (int delay : {1, 3}) {
    CmlEngineOptions o = TestOptions();
    o.update_delay_frames = delay;
    CmlEngine engine(o);
    const std::vector<RouteFrame> route = MakeLaps(1, 0.25, 2);
    engine.BeginSession(PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth));
    for (int i = 0; i <= delay; ++i) {
      const FrameResult r = engine.ProcessFrame(MakeFrame(route[i], 0, i));
      ASSERT_TRUE(r.estimate.has_value());
      if (i == 0) {
        EXPECT_LT(PoseDifference(r.estimate->mean.mean, route[0].truth).norm(), 1e-9);
        EXPECT_TRUE(r.estimate->unimodal);
      }
      // Invisible at t + delay - 1, visible at t + delay (t = 0).
      if (i < delay) {
        EXPECT_EQ(r.stats.num_views, 0u) << "delay " << delay << " frame " << i;
      } else {
        EXPECT_GE(r.stats.num_views, 1u) << "delay " << delay << " frame " << i;
      }
    }
  }
}

// A global start with an empty map falls back to the configured initial pose.
TEST(CmlEngine, GlobalStartOnEmptyMapUsesInitialPose) {
  CmlEngineOptions o = TestOptions();
  o.initial_pose = MakePose(1.0, 2.0, 0.5);
  CmlEngine engine(o);
  engine.BeginSession(PanoramaSession("d1", SessionStartMode::kGlobal, Pose2::Zero()));
  const std::vector<RouteFrame> route = MakeLaps(1, 0.5, 3);
  const FrameResult r = engine.ProcessFrame(MakeFrame(route[0], 0, 0));
  ASSERT_TRUE(r.estimate.has_value());
  EXPECT_LT(PoseDifference(r.estimate->mean.mean, o.initial_pose).norm(), 1e-9);
  EXPECT_EQ(engine.counters().global_fallbacks, 1);
}

// Mapping laps from an empty map beats dead reckoning, and the map stays consistent.
TEST(CmlEngine, MappingBeatsOdometry) {
  CmlEngine engine(TestOptions());
  const std::vector<RouteFrame> route = MakeLaps(4, 0.25, 4);
  engine.BeginSession(PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth));
  double err_engine = 0.0, err_odom = 0.0;
  int n = 0;
  for (std::size_t i = 0; i < route.size(); ++i) {
    const FrameResult r = engine.ProcessFrame(MakeFrame(route[i], 0, static_cast<std::int64_t>(i)));
    ASSERT_TRUE(r.estimate.has_value());
    if (i >= route.size() / 2) {  // second half: after a couple of laps
      err_engine += PositionError(r, route[i].truth);
      err_odom += PoseDifference(Compose(route[0].truth, Between(route[0].odom, route[i].odom)),
                                 route[i].truth)
                      .head<2>()
                      .norm();
      ++n;
    }
  }
  engine.Finish();
  engine.model().CheckInvariants();
  EXPECT_GT(engine.model().NumViews(), 5u);
  EXPECT_TRUE(engine.queued_updates().empty());
  EXPECT_LT(err_engine / n, 0.5 * err_odom / n)
      << "engine " << err_engine / n << " odometry " << err_odom / n;
}

// Pose-gated matching (GatedMatchingOptions): while tracking, p(x|y) compares the views
// near p(x|u) only; the full search still runs every full_search_every_frames frames and
// whenever p(x_t) is not one Gaussian; tracking stays as accurate as with the full search,
// and the run is bit-identical with 1 and 2 threads.
TEST(CmlEngine, GatedMatchingComparesFewerViewsAndTracksAsWell) {
  const std::vector<RouteFrame> route = MakeLaps(4, 0.25, 4);
  struct Run {
    double late_error = 0.0;
    int gated = 0, late = 0;
    double candidates = 0.0, views = 0.0;  // sums over gated frames
    std::vector<FrameResult> results;
  };
  auto run = [&](bool gated, int threads) {
    CmlEngineOptions o = TestOptions();
    o.threads = threads;
    o.gated_matching.enabled = gated;
    o.gated_matching.min_views = 0;
    o.appearance_sigma_m = 0.2;
    CmlEngine engine(o);
    engine.BeginSession(PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth));
    Run out;
    for (std::size_t i = 0; i < route.size(); ++i) {
      FrameResult r = engine.ProcessFrame(MakeFrame(route[i], 0, static_cast<std::int64_t>(i)));
      EXPECT_TRUE(r.estimate.has_value());
      if (!r.estimate) continue;
      if (r.stats.gated_matching) {
        ++out.gated;
        EXPECT_NE(r.frame % o.gated_matching.full_search_every_frames, 0) << "frame " << r.frame;
        EXPECT_LE(r.stats.matching_candidates, r.stats.num_views);
        out.candidates += static_cast<double>(r.stats.matching_candidates);
        out.views += static_cast<double>(r.stats.num_views);
      } else {
        EXPECT_EQ(r.stats.matching_candidates, r.stats.num_views);
      }
      if (i >= route.size() / 2) {
        out.late_error += PositionError(r, route[i].truth);
        ++out.late;
      }
      out.results.push_back(std::move(r));
    }
    engine.Finish();
    engine.model().CheckInvariants();
    return out;
  };
  const Run full = run(false, 1);
  const Run gated = run(true, 1);
  EXPECT_EQ(full.gated, 0);
  // Most frames are tracked by one Gaussian; 1 in 10 searches the whole map.
  EXPECT_GT(gated.gated, static_cast<int>(route.size()) / 2);
  EXPECT_LT(gated.candidates, 0.8 * gated.views) << "the gate must leave views out";
  EXPECT_LT(gated.late_error / gated.late, full.late_error / full.late + 0.05)
      << "gated " << gated.late_error / gated.late << " full " << full.late_error / full.late;
  const Run gated2 = run(true, 2);
  ASSERT_EQ(gated2.results.size(), gated.results.size());
  for (std::size_t i = 0; i < gated.results.size(); ++i) {
    ExpectSameEstimate(gated.results[i], gated2.results[i]);
  }
}

// The worker thread changes nothing: estimates and map are bit-identical with threads
// 1 and 2, and from run to run.
TEST(CmlEngine, BitIdenticalAcrossThreadCounts) {
  const std::vector<RouteFrame> route = MakeLaps(2, 0.3, 5);
  std::vector<std::vector<FrameResult>> results;
  std::vector<std::vector<std::uint8_t>> maps;
  for (int threads : {1, 2, 2}) {
    CmlEngineOptions o = TestOptions();
    o.threads = threads;
    CmlEngine engine(o);
    engine.BeginSession(PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth));
    std::vector<FrameResult> rs;
    for (std::size_t i = 0; i < route.size(); ++i) {
      rs.push_back(engine.ProcessFrame(MakeFrame(route[i], 0, static_cast<std::int64_t>(i))));
    }
    engine.Finish();
    BinaryWriter w;
    engine.model().Serialize(w);
    maps.push_back(w.Release());
    results.push_back(std::move(rs));
  }
  for (std::size_t k = 1; k < results.size(); ++k) {
    ASSERT_EQ(results[k].size(), results[0].size());
    for (std::size_t i = 0; i < results[0].size(); ++i)
      ExpectSameEstimate(results[0][i], results[k][i]);
    EXPECT_EQ(maps[k], maps[0]) << "run " << k;
  }
}

// A global start on day 2 finds the robot from the day-1 map.
TEST(CmlEngine, GlobalStartFindsRobotFromPreviousMap) {
  CmlEngine engine(TestOptions());
  const std::vector<RouteFrame> day1 = MakeLaps(3, 0.25, 6);
  engine.BeginSession(PanoramaSession("d1", SessionStartMode::kKnownPose, day1[0].truth));
  for (std::size_t i = 0; i < day1.size(); ++i) {
    engine.ProcessFrame(MakeFrame(day1[i], 0, static_cast<std::int64_t>(i)));
  }
  // Day 2 starts elsewhere on the route with its own odometry frame and no prior.
  const std::vector<RouteFrame> day2 = MakeLaps(1, 0.25, 7, /*start_offset=*/37);
  engine.BeginSession(PanoramaSession("d2", SessionStartMode::kGlobal, Pose2::Zero()));
  int with_estimate = 0;
  double late_error = 0.0;
  int late = 0;
  for (std::size_t i = 0; i < day2.size(); ++i) {
    const FrameResult r = engine.ProcessFrame(MakeFrame(day2[i], 1, static_cast<std::int64_t>(i)));
    if (r.estimate) ++with_estimate;
    if (i >= 20) {
      ASSERT_TRUE(r.estimate.has_value()) << "frame " << i;
      late_error += PositionError(r, day2[i].truth);
      ++late;
    }
  }
  EXPECT_EQ(engine.counters().global_seeds, 1);
  EXPECT_GT(with_estimate, 0);
  EXPECT_LT(late_error / late, 0.5) << "mean position error after 20 frames of day 2";
}

// Raw ring frames are unwrapped with the session calibration and localize like panoramas.
TEST(CmlEngine, RawRingSessionLocalizes) {
  OmniCalibration cal;
  cal.center_x_px = 100;
  cal.center_y_px = 100;
  cal.inner_radius_px = 20;
  cal.outer_radius_px = 90;
  cal.panorama_width = 128;
  cal.panorama_height = 24;
  const OmniUnwrapper renderer(cal, 200, 200);
  CmlEngine engine(TestOptions());
  SessionInfo info = PanoramaSession("ring", SessionStartMode::kKnownPose, Pose2::Zero());
  info.camera.kind = ImageKind::kRawRing;
  info.camera.image_width = 200;
  info.camera.image_height = 200;
  info.camera.calibration = cal;
  const std::vector<RouteFrame> route = MakeLaps(3, 0.3, 8);
  info.start.map_T_robot = route[0].truth;
  engine.BeginSession(info);
  double err = 0.0, odo = 0.0;
  int n = 0;
  for (std::size_t i = 0; i < route.size(); ++i) {
    Frame f = MakeFrame(route[i], 0, static_cast<std::int64_t>(i));
    f.image = renderer.Render(RenderRoom(route[i].truth));
    const FrameResult r = engine.ProcessFrame(f);
    ASSERT_TRUE(r.estimate.has_value());
    if (i >= route.size() / 2) {
      err += PositionError(r, route[i].truth);
      odo += PoseDifference(Compose(route[0].truth, Between(route[0].odom, route[i].odom)),
                            route[i].truth)
                 .head<2>()
                 .norm();
      ++n;
    }
  }
  EXPECT_GT(engine.model().NumViews(), 3u);
  EXPECT_LT(err / n, 0.5 * odo / n) << "engine " << err / n << " odometry " << odo / n;
  // A frame of the wrong size is an error.
  Frame bad = MakeFrame(route[0], 0, 0);
  bad.image = cv::Mat(50, 50, CV_8UC1, cv::Scalar(0));
  EXPECT_THROW(engine.ProcessFrame(bad), Error);
}

// Per-frame statistics are filled in and consistent with the model.
// Largest eigenvalue of the xy block of a covariance (m^2).
double LargestXyVariance(const Eigen::Matrix3d& c) {
  const double h = 0.5 * (c(0, 0) + c(1, 1)), d = 0.5 * (c(0, 0) - c(1, 1));
  return h + std::sqrt(d * d + c(0, 1) * c(1, 0));
}

// Confident anchors: a unimodal estimate that appearance did not fix and whose position
// is less certain than anchor_max_sigma_m waits like a multimodal frame and reaches the
// map through the reconstruction at the next anchor; frames that cannot be reconstructed
// (Finish) still update the map with their filtered estimate. With 0 every unimodal
// estimate updates the map at once.
TEST(CmlEngine, UnconfidentUnimodalFramesWaitForTheNextAnchor) {
  const std::vector<RouteFrame> route = MakeLaps(2, 0.3, 10);
  for (double anchor_sigma : {0.3, 0.0}) {
    CmlEngineOptions o = TestOptions();
    o.anchor_max_sigma_m = anchor_sigma;
    CmlEngine engine(o);
    engine.BeginSession(PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth));
    std::set<std::int64_t> waiting;
    int waited = 0, reconstructed_waiting = 0;
    for (std::size_t i = 0; i < route.size(); ++i) {
      const FrameResult r =
          engine.ProcessFrame(MakeFrame(route[i], 0, static_cast<std::int64_t>(i)));
      ASSERT_TRUE(r.estimate.has_value());
      for (const auto& [frame, g] : r.reconstructed) {
        reconstructed_waiting += waiting.erase(frame) > 0 ? 1 : 0;
      }
      const double var = LargestXyVariance(r.estimate->mean.covariance);
      if (r.estimate->unimodal && !r.map_state) {
        EXPECT_GT(anchor_sigma, 0.0) << "frame " << i;
        EXPECT_GT(var, anchor_sigma * anchor_sigma) << "frame " << i;
        EXPECT_GT(r.stats.pending_multimodal, 0) << "frame " << i;
        waiting.insert(r.frame);
        ++waited;
      }
      if (r.map_state && anchor_sigma > 0.0) {
        EXPECT_TRUE(var <= anchor_sigma * anchor_sigma || r.stats.num_matches > 0) << "frame " << i;
      }
    }
    engine.Finish();
    engine.model().CheckInvariants();
    const EngineCounters& c = engine.counters();
    // Every frame updates the map once: at once, reconstructed, or filtered at Finish;
    // only multimodal frames can be dropped.
    EXPECT_EQ(c.updates_queued + c.dropped_pending_frames, c.frames);
    EXPECT_LE(c.dropped_pending_frames, c.multimodal_frames);
    if (anchor_sigma > 0.0) {
      EXPECT_GT(waited, 10);
      EXPECT_GT(reconstructed_waiting, 0);
    } else {
      EXPECT_EQ(waited, 0);
    }
  }
}

// map_update_spacing_m: a localized frame reaches the map exactly when its estimate lies
// at least the spacing from the session's previous map update (the first update of each
// session always does), so the map sees about one update per spacing of travel whatever
// the distance between frames; every frame is still localized.
TEST(CmlEngine, MapUpdatesAreSpacedByTravel) {
  const std::vector<RouteFrame> day1 = MakeLaps(2, 0.1, 12);
  const std::vector<RouteFrame> day2 = MakeLaps(1, 0.1, 13, 17);
  for (double spacing : {0.25, 0.45}) {
    CmlEngineOptions o = TestOptions();
    o.map_update_spacing_m = spacing;
    o.reconstruct_multimodal = false;  // each update is its own frame's (no reconstruction)
    CmlEngine engine(o);
    std::int64_t frames = 0, updates = 0, localized = 0;
    for (int day = 0; day < 2; ++day) {
      const std::vector<RouteFrame>& route = day == 0 ? day1 : day2;
      engine.BeginSession(
          PanoramaSession(StrCat("d", day), SessionStartMode::kKnownPose, route[0].truth));
      std::optional<Eigen::Vector2d> last;  // position of the session's last map update
      for (std::size_t i = 0; i < route.size(); ++i) {
        const FrameResult r =
            engine.ProcessFrame(MakeFrame(route[i], day, static_cast<std::int64_t>(i)));
        ASSERT_TRUE(r.estimate.has_value());
        ++frames;
        ++localized;
        if (!r.map_state) {
          EXPECT_EQ(r.stats.updates_queued, 0) << "frame " << r.frame;
          continue;
        }
        const Eigen::Vector2d xy = r.map_state->mean.head<2>();
        const bool due = !last || (xy - *last).norm() >= spacing;
        EXPECT_EQ(r.stats.updates_queued, due ? 1 : 0)
            << "spacing " << spacing << " frame " << r.frame << " at "
            << (last ? (xy - *last).norm() : -1.0) << " m from the last update";
        if (due) last = xy;
        updates += r.stats.updates_queued;
      }
    }
    engine.Finish();
    engine.model().CheckInvariants();
    EXPECT_EQ(engine.counters().updates_queued, updates);
    EXPECT_EQ(localized, frames);
    // Frames 0.1 m apart: at most one update in two (0.25 m) or in four (0.45 m) frames
    // beyond the sessions' first ones.
    const double frames_per_update = std::ceil(spacing / 0.1 - 1e-9);
    EXPECT_LE(static_cast<double>(updates), frames / frames_per_update + 2.0 + 0.1 * frames)
        << "spacing " << spacing;
    EXPECT_GT(updates, frames / (2.0 * frames_per_update)) << "spacing " << spacing;
    EXPECT_GT(engine.model().NumViews(), 3u);
  }
}

TEST(CmlEngine, StatisticsAreConsistent) {
  CmlEngine engine(TestOptions());
  const std::vector<RouteFrame> route = MakeLaps(2, 0.3, 9);
  engine.BeginSession(PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth));
  std::int64_t queued = 0, applied = 0;
  for (std::size_t i = 0; i < route.size(); ++i) {
    const FrameResult r = engine.ProcessFrame(MakeFrame(route[i], 0, static_cast<std::int64_t>(i)));
    EXPECT_EQ(r.frame, static_cast<std::int64_t>(i));
    EXPECT_GE(r.stats.describe_us, 0.0);
    EXPECT_GE(r.stats.total_us, r.stats.describe_us);
    EXPECT_LE(r.stats.num_matches, static_cast<int>(r.stats.num_views));
    EXPECT_EQ(r.stats.mixture_components, static_cast<int>(engine.tracker().state().size()));
    EXPECT_EQ(r.estimate->num_components, r.stats.mixture_components);
    if (r.stats.num_matches == 0) {
      EXPECT_EQ(r.stats.hypothesis_components, 0);
    }
    queued += r.stats.updates_queued;
    applied += r.stats.updates_applied;
    EXPECT_EQ(queued - applied, static_cast<std::int64_t>(engine.queued_updates().size()));
  }
  const EngineCounters& c = engine.counters();
  EXPECT_EQ(c.frames, static_cast<std::int64_t>(route.size()));
  EXPECT_EQ(c.unimodal_frames + c.multimodal_frames + c.unknown_frames, c.frames);
  EXPECT_EQ(c.updates_queued, queued);
}

}  // namespace
}  // namespace omnicml
