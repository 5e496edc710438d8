// End to end: the CML engine on a short simulated multi-day log (built-in world
// `home_store`, panoramas straight from the simulator), starting from an empty map,
// against ground truth and against dead-reckoning odometry on the same log.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>
#include <opencv2/videoio.hpp>

#include "omnicml/common/common.h"
#include "omnicml/engine/calibration.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/logs/video.h"
#include "omnicml/sim/simulator.h"
#include "testing/masked_ring_source.h"

namespace omnicml {
namespace {

struct RunErrors {
  std::vector<double> engine_m;    // per frame: position error of the estimate
  std::vector<double> odometry_m;  // per frame: position error of dead reckoning
  std::vector<int> lap;            // per frame: lap (= day) index
  std::vector<Eigen::Vector2d> estimate_xy, truth_xy;  // per frame, for the SE(2) alignment
  int frames_without_estimate = 0;
  EngineCounters counters;
};

double Mean(const std::vector<double>& v, const std::vector<int>& lap, int which) {
  double sum = 0.0;
  int n = 0;
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (which < 0 || lap[i] == which) {
      sum += v[i];
      ++n;
    }
  }
  return n > 0 ? sum / n : 0.0;
}

// Position errors after the rigid 2-D transform that best maps the estimates onto the
// truth (Eigen::umeyama without scale): the map's own frame may be rotated against the
// world's by the heading drift of the first lap, which no later lap can observe.
std::vector<double> AlignedErrors(const RunErrors& e) {
  const Eigen::Index n = static_cast<Eigen::Index>(e.estimate_xy.size());
  Eigen::Matrix2Xd src(2, n), dst(2, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    src.col(i) = e.estimate_xy[i];
    dst.col(i) = e.truth_xy[i];
  }
  const Eigen::Matrix3d t = Eigen::umeyama(src, dst, /*with_scaling=*/false);
  std::vector<double> out(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    out[i] = (t.topLeftCorner<2, 2>() * src.col(i) + t.topRightCorner<2, 1>() - dst.col(i)).norm();
  }
  return out;
}

// The point estimate: the moment-matched mean when unimodal, else the strongest component.
Pose2 PointEstimate(const Estimate& e) { return e.unimodal ? e.mean.mean : e.strongest.mean; }

// Runs the engine over the simulated log. Dead reckoning: the simulator starts day 1's
// odometry at the true start pose and continues it over the days (kContinue), so
// odom_T_robot is the odometry-only estimate in the map frame.
RunErrors RunEngine(const SimulatorOptions& sim, const CmlEngineOptions& options) {
  SimulatedFrameSource source(sim);
  CmlEngine engine(options);
  RunErrors out;
  Frame frame;
  int session = -1;
  while (source.Next(&frame)) {
    if (frame.session_index != session) {
      session = frame.session_index;
      engine.BeginSession(source.Session(session));
    }
    const FrameResult r = engine.ProcessFrame(frame);
    if (!r.estimate) {
      ++out.frames_without_estimate;
      continue;
    }
    const Pose2& truth = *frame.map_T_robot_truth;
    out.engine_m.push_back(PoseDifference(PointEstimate(*r.estimate), truth).head<2>().norm());
    out.odometry_m.push_back(PoseDifference(frame.odom_T_robot, truth).head<2>().norm());
    out.lap.push_back(frame.session_index);
    out.estimate_xy.push_back(PointEstimate(*r.estimate).head<2>());
    out.truth_xy.push_back(truth.head<2>());
  }
  engine.Finish();
  engine.model().CheckInvariants();
  out.counters = engine.counters();
  return out;
}

// From an empty map, over four days of home_store (one lap a day, each day continuing
// where the last ended, shelves restocked and curtains changed between days, people
// walking): the estimate beats dead reckoning by a wide margin and its error falls from
// the first lap (mapping from scratch) to the last (localizing in the learned map).
// Four simulator seeds: a single seed can take one wrong loop-closure decision that
// changes its figures by half a metre, so the margins are asserted on the means over the
// seeds, and every seed must still beat dead reckoning.
TEST(EndToEnd, BeatsOdometryAndImprovesOverLaps) {
  SimulatorOptions sim;
  sim.world = "home_store";
  sim.output = ImageKind::kPanorama;
  sim.days = 4;
  sim.step_m = 0.3;
  sim.later_days_start = SessionStartMode::kContinue;
  {
    const World world = LoadBuiltinWorld(sim.world);
    const RoutePath route(world.route.waypoints_m, world.route.turn_radius_m);
    sim.frames_per_day = static_cast<int>(std::ceil(route.length_m() / sim.step_m));  // one lap
  }
  CmlEngineOptions options;
  options.panorama_width = 360;
  options.panorama_height = 60;
  // The simulator's odometry runs on across kContinue days (one step between them).
  options.continue_odometry_across_sessions = true;

  double engine_sum = 0, odometry_sum = 0, first_sum = 0, last_sum = 0;
  const std::vector<std::uint32_t> seeds = {1, 2, 3, 5};
  for (std::uint32_t seed : seeds) {
    sim.seed = seed;
    const RunErrors e = RunEngine(sim, options);
    ASSERT_EQ(e.frames_without_estimate, 0) << "seed " << seed;
    const int last_lap = e.lap.back();
    const double engine_all = Mean(e.engine_m, e.lap, -1);
    const double odometry_all = Mean(e.odometry_m, e.lap, -1);
    const double engine_first = Mean(e.engine_m, e.lap, 0);
    const double engine_last = Mean(e.engine_m, e.lap, last_lap);
    std::printf(
        "end-to-end seed %u: mean position error engine %.3f m, odometry %.3f m; engine lap 0 %.3f "
        "m, lap %d %.3f m\n",
        seed, engine_all, odometry_all, engine_first, last_lap, engine_last);
    const std::vector<double> aligned = AlignedErrors(e);
    const double aligned_first = Mean(aligned, e.lap, 0),
                 aligned_last = Mean(aligned, e.lap, last_lap);
    std::printf("  aligned (SE(2)): lap 0 %.3f m, lap %d %.3f m\n", aligned_first, last_lap,
                aligned_last);
    std::printf("counters: unimodal %lld multimodal %lld reconstructed %lld dropped %lld\n",
                static_cast<long long>(e.counters.unimodal_frames),
                static_cast<long long>(e.counters.multimodal_frames),
                static_cast<long long>(e.counters.reconstructed_frames),
                static_cast<long long>(e.counters.dropped_pending_frames));
    EXPECT_LT(engine_all, odometry_all) << "seed " << seed;
    // In the map's own frame every seed improves from lap to lap (measured ratios last /
    // first after SE(2) alignment: 0.35, 0.38, 0.47, 0.48 for seeds 1, 2, 3, 5).
    EXPECT_LT(aligned_last, 0.7 * aligned_first) << "seed " << seed;
    engine_sum += engine_all;
    odometry_sum += odometry_all;
    first_sum += engine_first;
    last_sum += engine_last;
  }
  // Measured (default options: normalised columns, e_max 0.45), all / odometry and
  // first / last lap in m: seed 1 0.62 / 4.41, 1.16 / 0.61; seed 2 1.29 / 2.92,
  // 2.28 / 0.89; seed 3 2.09 / 3.66, 2.02 / 2.15; seed 5 0.56 / 3.29, 1.13 / 0.55.
  // Means: engine 1.14 m against odometry 3.57 m (0.32); first lap 1.65 m, last 1.05 m
  // (0.64). Seed 3 under other settings: bands-only descriptor and e_max 0.3 (format
  // version 2 defaults) 1.75 m, laps 2.02 -> 1.47 m; bands-only with e_max 0.45 1.50 m;
  // a 10-degree column window 1.39 m. Seed 3's last lap is no better than its first in
  // the world frame because its map is rotated by 9 degrees about the start (the heading
  // error of the first turn, carried by the anchors that reconstruct lap 0); after SE(2)
  // alignment its laps go 0.73 -> 0.34 m. Lap 0 maps from scratch on dead reckoning; the loop
  // closure at its end anchors the reconstruction of the stretch since the last
  // confident estimate (anchor_max_sigma_m), so later laps localize in corrected poses.
  const double n = static_cast<double>(seeds.size());
  EXPECT_LT(engine_sum / n, 0.5 * odometry_sum / n);
  EXPECT_LT(last_sum / n, 0.8 * first_sum / n);
}

// Sessions: day 2 starts at a random place on the route with no prior (kGlobal, its
// odometry restarting at zero); the engine finds the robot from the day-1 map and then
// tracks it about as well as that map allows.
TEST(EndToEnd, GlobalStartOnDayTwoFindsRobot) {
  SimulatorOptions sim;
  sim.world = "home_store";
  sim.output = ImageKind::kPanorama;
  sim.days = 2;
  sim.step_m = 0.3;
  sim.frames_per_day = 250;  // day 1: about 1.3 laps
  sim.later_days_start = SessionStartMode::kGlobal;
  sim.seed = 3;
  CmlEngineOptions options;
  options.panorama_width = 360;
  options.panorama_height = 60;

  const RunErrors e = RunEngine(sim, options);
  const double day1 = Mean(e.engine_m, e.lap, 0);
  const double day2 = Mean(e.engine_m, e.lap, 1);
  int day2_frames = 0;
  for (int lap : e.lap) day2_frames += lap == 1 ? 1 : 0;
  std::printf(
      "global start: day 1 error %.3f m, day 2 error %.3f m over %d frames with an estimate "
      "(%d without)\n",
      day1, day2, day2_frames, e.frames_without_estimate);
  EXPECT_EQ(e.counters.global_seeds, 1);
  // Found within the first 20 frames of the day, then tracked for the rest.
  EXPECT_LE(e.frames_without_estimate, 20);
  EXPECT_GE(day2_frames, sim.frames_per_day - 20);
  // Measured (seed 3): day 1 1.84 m, day 2 1.52 m; a wrong place would be metres off
  // (the store is 25 m x 10 m).
  EXPECT_LT(day2, 1.5 * day1 + 0.5);
  EXPECT_LT(day2, 2.5);
}

// `omnicml calibrate` honours the session's user mask: noise under the mask leaves the
// descriptor-distance curve and the derived scale unchanged; undeclared, it changes them.
TEST(Calibrate, MaskedPixelsDoNotChangeTheCalibration) {
  SimulatorOptions so;
  so.world = "home_store";
  so.days = 1;
  so.frames_per_day = 40;
  so.seed = 3;
  so.people = false;
  CalibrationOptions co;
  co.max_frames = 40;
  const auto calibrate = [&](bool declare_mask, bool scramble) {
    testing::MaskedRingSource source(so, declare_mask, scramble);
    return Calibrate(source, CmlEngineOptions{}, co);
  };
  const Calibration clean = calibrate(true, false), scrambled = calibrate(true, true);
  ASSERT_EQ(clean.curve.size(), scrambled.curve.size());
  ASSERT_FALSE(clean.curve.empty());
  for (std::size_t i = 0; i < clean.curve.size(); ++i)
    EXPECT_EQ(clean.curve[i].median_distance, scrambled.curve[i].median_distance) << "lag " << i;
  EXPECT_EQ(clean.match_length_m, scrambled.match_length_m);
  EXPECT_NE(calibrate(false, false).curve[0].median_distance,
            calibrate(false, true).curve[0].median_distance);
}

// Per-frame point estimates (or nullopt) of a run over the log at `dir`.
std::vector<std::optional<Pose2>> RunLog(const std::string& dir) {
  LogReader reader(dir);
  CmlEngine engine(CmlEngineOptions{});
  std::vector<std::optional<Pose2>> out;
  Frame frame;
  int session = -1;
  while (reader.Next(&frame)) {
    if (frame.session_index != session) {
      session = frame.session_index;
      engine.BeginSession(reader.Session(session));
    }
    const FrameResult r = engine.ProcessFrame(frame);
    out.push_back(r.estimate ? std::optional<Pose2>(PointEstimate(*r.estimate)) : std::nullopt);
  }
  engine.Finish();
  return out;
}

// A run whose frames come from a video (40 of the simulator's raw rings through
// cv::VideoWriter, lossless FFV1) gives the same estimate on every frame as the run from
// the PNG log.
TEST(EndToEnd, RunFromVideoMatchesRunFromPngLog) {
  namespace fs = std::filesystem;
  const fs::path root = fs::path(::testing::TempDir()) / StrCat("omnicml_video_run_", ::getpid());
  fs::remove_all(root);
  fs::create_directories(root);
  SimulatorOptions sim;
  sim.world = "home_store";
  sim.days = 1;
  sim.frames_per_day = 40;
  sim.seed = 4;
  sim.output = ImageKind::kRawRing;
  const std::string png_log = (root / "png").string(), video_log = (root / "video").string();
  const std::string video = (root / "day.avi").string();
  {
    SimulatedFrameSource source(sim);
    LogWriter png(png_log);
    std::vector<Frame> frames;
    WriteFrames(source, png, [&](const Frame& f) { frames.push_back(f); });
    png.Finish();
    cv::VideoWriter writer(video, cv::CAP_FFMPEG, cv::VideoWriter::fourcc('F', 'F', 'V', '1'), 10.0,
                           frames.front().image.size(), true);
    ASSERT_TRUE(writer.isOpened()) << "FFV1 encoder unavailable";
    for (const Frame& f : frames) writer.write(f.image);
    writer.release();
    LogWriter log(video_log);
    log.BeginSession(source.Session(0));
    const std::string name = log.AddSessionVideo(video);
    for (const Frame& f : frames) log.WriteVideoFrame(f, VideoFrameRef{name, f.index_in_session});
    log.Finish();
  }
  const auto from_png = RunLog(png_log), from_video = RunLog(video_log);
  ASSERT_EQ(from_png.size(), 40u);
  ASSERT_EQ(from_video.size(), from_png.size());
  int estimated = 0;
  for (std::size_t i = 0; i < from_png.size(); ++i) {
    ASSERT_EQ(from_png[i].has_value(), from_video[i].has_value()) << "frame " << i;
    if (!from_png[i]) continue;
    ++estimated;
    EXPECT_EQ(*from_png[i], *from_video[i]) << "frame " << i;
  }
  EXPECT_GT(estimated, 30);
  fs::remove_all(root);
}

}  // namespace
}  // namespace omnicml
