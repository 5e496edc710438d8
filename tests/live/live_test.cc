// Tests of the live module: odometry interpolation and the LiveEngine's queue, sessions,
// commands and equality with the engine fed directly.
#include <atomic>
#include <condition_variable>
#include <filesystem>
#include <mutex>
#include <numbers>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/live/live_engine.h"
#include "omnicml/live/odometry_buffer.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {
namespace {

std::vector<Frame> SimulatedFrames(int days, int frames_per_day,
                                   std::vector<SessionInfo>* sessions) {
  SimulatorOptions options;
  options.days = days;
  options.frames_per_day = frames_per_day;
  options.output = ImageKind::kPanorama;
  options.seed = 3;
  SimulatedFrameSource source(options);
  std::vector<Frame> frames;
  Frame f;
  while (source.Next(&f)) frames.push_back(f);
  for (int k = 0; k < source.NumSessions(); ++k) sessions->push_back(source.Session(k));
  return frames;
}

// Odometry, then the image, of every frame: the two channels of a robot.
void Feed(LiveEngine& live, const std::vector<Frame>& frames) {
  for (const Frame& f : frames) {
    live.AddOdometry(f.stamp_s, f.odom_T_robot);
    live.AddImage(f.stamp_s, f.image);
  }
}

// Callbacks that collect the outputs (under `mutex`).
LiveEngine::Callbacks Collect(std::mutex& mutex, std::vector<LiveOutput>& outputs) {
  return {[&mutex, &outputs](const LiveOutput& o) {
            std::lock_guard<std::mutex> lock(mutex);
            outputs.push_back(o);
          },
          {},
          {}};
}

// Samples are returned exactly at their stamps and interpolated between them, the angle
// along the shorter arc (across +-pi).
TEST(OdometryBuffer, InterpolatesLinearlyAndAlongTheShorterArc) {
  OdometryBuffer buffer;
  const double a = std::numbers::pi - 0.1;
  ASSERT_TRUE(buffer.Add(1.0, MakePose(0.0, 0.0, a)));
  ASSERT_TRUE(buffer.Add(2.0, MakePose(2.0, -4.0, -a)));
  EXPECT_EQ(*buffer.At(1.0), MakePose(0.0, 0.0, a));
  EXPECT_EQ(*buffer.At(2.0), MakePose(2.0, -4.0, -a));
  const Pose2 mid = *buffer.At(1.5);
  EXPECT_NEAR(mid.x(), 1.0, 1e-12);
  EXPECT_NEAR(mid.y(), -2.0, 1e-12);
  EXPECT_NEAR(std::abs(mid.z()), std::numbers::pi, 1e-12);  // through pi, not through 0
  EXPECT_FALSE(buffer.At(0.5).has_value());
  EXPECT_FALSE(buffer.At(2.5).has_value());
  EXPECT_TRUE(buffer.Covers(2.0));
  EXPECT_FALSE(buffer.Covers(2.1));
}

// Stamps that do not increase and non-finite poses are rejected, the buffer unchanged.
TEST(OdometryBuffer, RejectsOutOfOrderAndNonFiniteSamples) {
  OdometryBuffer buffer;
  ASSERT_TRUE(buffer.Add(1.0, Pose2::Zero()));
  EXPECT_FALSE(buffer.Add(1.0, Pose2::Ones()));
  EXPECT_FALSE(buffer.Add(0.5, Pose2::Ones()));
  EXPECT_FALSE(buffer.Add(2.0, Pose2(std::nan(""), 0, 0)));
  EXPECT_EQ(buffer.size(), 1u);
}

// Old samples beyond the history are discarded, two are always kept.
TEST(OdometryBuffer, KeepsItsHistoryBounded) {
  OdometryBuffer buffer(1.0);
  for (int k = 0; k < 100; ++k) ASSERT_TRUE(buffer.Add(0.1 * k, Pose2::Zero()));
  EXPECT_LE(buffer.size(), 12u);
  EXPECT_FALSE(buffer.At(0.0).has_value());
}

// Fed every frame (a queue that never overflows, odometry on its own channel before the
// image), the live engine gives bit-identical estimates to the engine called directly.
TEST(LiveEngine, MatchesTheEngineFedDirectly) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(1, 40, &sessions);
  CmlEngineOptions options;
  CmlEngine direct(options);
  direct.BeginSession(sessions[0]);
  std::vector<Pose2> expected;
  for (const Frame& f : frames) expected.push_back(direct.ProcessFrame(f).estimate->strongest.mean);

  std::mutex mutex;
  std::vector<LiveOutput> outputs;
  LiveEngineOptions live_options;
  live_options.queue_capacity_frames = 1000;
  LiveEngine live(std::make_unique<CmlEngine>(options), live_options, sessions[0], sessions[0],
                  Collect(mutex, outputs));
  Feed(live, frames);
  live.Stop(true);
  ASSERT_EQ(outputs.size(), frames.size());
  for (std::size_t k = 0; k < frames.size(); ++k) {
    ASSERT_TRUE(outputs[k].estimate.has_value());
    EXPECT_EQ(outputs[k].estimate->strongest.mean, expected[k]) << "frame " << k;
    EXPECT_FALSE(outputs[k].odometry_held);
    // map_T_odom * odom_T_robot is the estimate.
    const Pose2 back = Compose(*outputs[k].map_T_odom, outputs[k].odom_T_robot);
    EXPECT_NEAR(PoseDifference(back, expected[k]).norm(), 0.0, 1e-9);
  }
  EXPECT_EQ(live.stats().dropped_frames, 0);
  EXPECT_EQ(live.engine().counters().frames, static_cast<std::int64_t>(frames.size()));
}

// With a queue of one frame and a busy worker, every frame but the newest is dropped and
// counted; the dropped count reaches the outputs.
TEST(LiveEngine, DropsTheOldestFrameWhenTheQueueIsFull) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(1, 8, &sessions);
  std::mutex mutex;
  std::condition_variable cv;
  bool in_callback = false, release = false;
  std::vector<LiveOutput> outputs;
  LiveEngine live(std::make_unique<CmlEngine>(CmlEngineOptions{}), {}, sessions[0], sessions[0],
                  {[&](const LiveOutput& o) {
                     std::unique_lock<std::mutex> lock(mutex);
                     outputs.push_back(o);
                     in_callback = true;
                     cv.notify_all();
                     cv.wait(lock, [&] { return release; });
                   },
                   {},
                   {}});
  live.AddFrame(frames[0].stamp_s, frames[0].image, frames[0].odom_T_robot);
  {
    std::unique_lock<std::mutex> lock(mutex);
    cv.wait(lock, [&] { return in_callback; });
  }
  int accepted_without_drop = 0;
  for (std::size_t k = 1; k < frames.size(); ++k)
    accepted_without_drop +=
        live.AddFrame(frames[k].stamp_s, frames[k].image, frames[k].odom_T_robot);
  {
    std::lock_guard<std::mutex> lock(mutex);
    release = true;
  }
  cv.notify_all();
  live.Stop(true);
  EXPECT_EQ(accepted_without_drop, 1);  // only the first into the empty queue
  const LiveStats stats = live.stats();
  EXPECT_EQ(stats.received_frames, 8);
  EXPECT_EQ(stats.dropped_frames, 6);
  EXPECT_EQ(stats.processed_frames, 2);
  ASSERT_EQ(outputs.size(), 2u);
  EXPECT_EQ(outputs[1].stamp_s, frames.back().stamp_s);
  EXPECT_EQ(outputs[1].dropped_frames, 6);
}

// Encoded images are decoded by the worker, and only those it processes: with a busy
// worker and a queue of one frame, the dropped ones are never decoded.
TEST(LiveEngine, DecodesOnlyTheFramesItProcesses) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(1, 6, &sessions);
  std::mutex mutex;
  std::condition_variable cv;
  bool in_callback = false, release = false;
  std::atomic<int> decoded{0};
  LiveEngine live(std::make_unique<CmlEngine>(CmlEngineOptions{}), {}, sessions[0], sessions[0],
                  {[&](const LiveOutput&) {
                     std::unique_lock<std::mutex> lock(mutex);
                     in_callback = true;
                     cv.notify_all();
                     cv.wait(lock, [&] { return release; });
                   },
                   {},
                   {}});
  for (const Frame& f : frames) live.AddOdometry(f.stamp_s, f.odom_T_robot);
  auto decoder = [&](const cv::Mat& image) {
    return [&decoded, image] {
      ++decoded;
      return image;
    };
  };
  live.AddEncodedImage(frames[0].stamp_s, decoder(frames[0].image));
  {
    std::unique_lock<std::mutex> lock(mutex);
    cv.wait(lock, [&] { return in_callback; });
  }
  for (std::size_t k = 1; k < frames.size(); ++k)
    live.AddEncodedImage(frames[k].stamp_s, decoder(frames[k].image));
  {
    std::lock_guard<std::mutex> lock(mutex);
    release = true;
  }
  cv.notify_all();
  live.Stop(true);
  EXPECT_EQ(live.stats().processed_frames, 2);
  EXPECT_EQ(live.stats().dropped_frames, 4);
  EXPECT_EQ(decoded.load(), 2);
}

// An image arriving before its odometry waits for it and gets the interpolated pose.
TEST(LiveEngine, InterpolatesOdometryArrivingAfterTheImage) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(1, 2, &sessions);
  std::vector<LiveOutput> outputs;
  std::mutex mutex;
  LiveEngineOptions options;
  options.odometry_wait_s = 60.0;  // never reached: the odometry arrives
  LiveEngine live(std::make_unique<CmlEngine>(CmlEngineOptions{}), options, sessions[0],
                  sessions[0],
                  {[&](const LiveOutput& o) {
                     std::lock_guard<std::mutex> lock(mutex);
                     outputs.push_back(o);
                   },
                   {},
                   {}});
  const double t = frames[0].stamp_s;
  live.AddImage(t, frames[0].image);
  live.AddOdometry(t - 1.0, MakePose(0.0, 0.0, 0.0));
  live.AddOdometry(t + 1.0, MakePose(2.0, 1.0, 0.5));
  live.Stop(true);
  ASSERT_EQ(outputs.size(), 1u);
  EXPECT_FALSE(outputs[0].odometry_held);
  EXPECT_NEAR(outputs[0].odom_T_robot.x(), 1.0, 1e-12);
  EXPECT_NEAR(outputs[0].odom_T_robot.y(), 0.5, 1e-12);
  EXPECT_NEAR(outputs[0].odom_T_robot.z(), 0.25, 1e-12);
}

// A gap in the image stamps begins a new session; BeginSession and SetForgettingMode run
// in order with the frames; Save writes a map that loads back with the same views.
TEST(LiveEngine, SessionsCommandsAndSave) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(2, 20, &sessions);
  LiveEngineOptions options;
  options.queue_capacity_frames = 1000;
  options.session_gap_s = 100.0;
  std::vector<std::vector<LiveViewComponent>> views;
  options.reference_views_every_frames = 10;
  LiveEngine live(std::make_unique<CmlEngine>(CmlEngineOptions{}), options, sessions[0],
                  sessions[1],
                  {{}, [&](const std::vector<LiveViewComponent>& v) { views.push_back(v); }, {}});
  double offset = 0.0;
  for (const Frame& f : frames) {
    // Day 2 a thousand seconds later.
    if (f.session_index == 1) offset = 1000.0 + frames[19].stamp_s - frames[20].stamp_s;
    live.AddFrame(f.stamp_s + offset, f.image, f.odom_T_robot);
  }
  live.SetForgettingMode(ForgettingMode::kStatic);
  const std::filesystem::path path = std::filesystem::temp_directory_path() /
                                     ("omnicml_live_test_" + std::to_string(::getpid()) + ".bin");
  std::future<std::string> saved = live.Save(path.string());
  EXPECT_EQ(saved.get(), "");
  live.Stop(true);
  EXPECT_EQ(live.stats().sessions, 2);
  EXPECT_EQ(live.engine().session_state().session, 1);
  EXPECT_EQ(live.engine().options().model.forgetting.mode, ForgettingMode::kStatic);
  ASSERT_EQ(views.size(), 4u);
  EXPECT_FALSE(views.back().empty());
  const std::unique_ptr<CmlEngine> loaded = LoadEngine(path.string());
  EXPECT_EQ(loaded->model().NumViews(), live.engine().model().NumViews());
  EXPECT_EQ(loaded->counters(), live.engine().counters());
  std::filesystem::remove(path);
}

// A frame that the engine rejects (wrong size for the session camera) or that does not
// decode is reported and counted, and the engine goes on with the next frame.
TEST(LiveEngine, ReportsAFailedFrameAndGoesOn) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(1, 2, &sessions);
  std::vector<std::string> errors;
  int outputs = 0;
  LiveEngineOptions options;
  options.queue_capacity_frames = 10;
  LiveEngine live(std::make_unique<CmlEngine>(CmlEngineOptions{}), options, sessions[0],
                  sessions[0],
                  {[&](const LiveOutput&) { ++outputs; },
                   {},
                   [&](const std::string& e) { errors.push_back(e); }});
  live.AddFrame(frames[0].stamp_s, frames[0].image, frames[0].odom_T_robot);
  live.AddFrame(frames[0].stamp_s + 0.01, cv::Mat(7, 9, CV_8UC1, cv::Scalar(3)),
                frames[0].odom_T_robot);
  live.AddOdometry(frames[0].stamp_s + 0.02, frames[0].odom_T_robot);
  live.AddEncodedImage(frames[0].stamp_s + 0.02, []() -> cv::Mat { throw Error("undecodable"); });
  live.AddFrame(frames[1].stamp_s, frames[1].image, frames[1].odom_T_robot);
  live.Stop(true);
  EXPECT_EQ(outputs, 2);
  ASSERT_EQ(errors.size(), 2u);
  EXPECT_NE(errors[1].find("undecodable"), std::string::npos);
  EXPECT_EQ(live.stats().failed_frames, 2);
}

// A new map (the factory constructor): the first frame_step_frames frames are held, the
// factory gets exactly their odometry, and then every frame, held or not, gives the
// estimate of an engine with the factory's options fed directly, in order.
TEST(LiveEngine, NewMapHoldsTheFirstFramesForItsFrameStep) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(1, 40, &sessions);
  // Options that depend on what the factory got, so that a wrong hand-over shows.
  const auto options_for = [](const std::vector<Pose2>& odometry) {
    CmlEngineOptions o;
    o.tracker.motion.a3 *= 1.0 + 0.1 * static_cast<double>(odometry.size());
    return o;
  };
  std::vector<Pose2> first(frames.size());
  for (std::size_t k = 0; k < frames.size(); ++k) first[k] = frames[k].odom_T_robot;
  first.resize(12);
  CmlEngine direct(options_for(first));
  direct.BeginSession(sessions[0]);
  std::vector<Pose2> expected;
  for (const Frame& f : frames) expected.push_back(direct.ProcessFrame(f).estimate->strongest.mean);

  std::mutex mutex;
  std::vector<LiveOutput> outputs;
  std::vector<std::vector<Pose2>> factory_calls;
  LiveEngineOptions live_options;
  live_options.queue_capacity_frames = 1000;
  live_options.frame_step_frames = 12;
  LiveEngine live(
      [&](const std::vector<Pose2>& odometry) {
        factory_calls.push_back(odometry);
        return std::make_unique<CmlEngine>(options_for(odometry));
      },
      live_options, sessions[0], sessions[0], Collect(mutex, outputs));
  Feed(live, frames);
  live.Stop(true);
  ASSERT_EQ(factory_calls.size(), 1u);
  EXPECT_EQ(factory_calls[0], first);
  ASSERT_EQ(outputs.size(), frames.size());
  for (std::size_t k = 0; k < frames.size(); ++k) {
    EXPECT_EQ(outputs[k].frame, static_cast<std::int64_t>(k));
    ASSERT_TRUE(outputs[k].estimate.has_value());
    EXPECT_EQ(outputs[k].estimate->strongest.mean, expected[k]) << "frame " << k;
  }
  EXPECT_EQ(live.engine().options().tracker.motion.a3, options_for(first).tracker.motion.a3);
}

// While the first frames are held, a forgetting-mode change waits in order with them; a
// Save ends the holding (the factory gets the frames so far) and saves after them; so
// do a BeginSession after the first held frame and a gap in the stamps; Stop(false) drops
// held frames but still makes the engine.
TEST(LiveEngine, CommandsWhileHoldingRunInOrder) {
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = SimulatedFrames(1, 10, &sessions);
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("omnicml_live_hold_test_" + std::to_string(::getpid()) + ".bin");
  LiveEngineOptions options;
  options.queue_capacity_frames = 1000;
  options.frame_step_frames = 100;
  {
    std::vector<std::size_t> factory_sizes;
    int outputs = 0;
    LiveEngine live(
        [&](const std::vector<Pose2>& odometry) {
          factory_sizes.push_back(odometry.size());
          return std::make_unique<CmlEngine>(CmlEngineOptions{});
        },
        options, sessions[0], sessions[0], {[&](const LiveOutput&) { ++outputs; }, {}, {}});
    live.BeginSession(sessions[0]);  // before any frame: held, does not end the holding
    for (int k = 0; k < 4; ++k)
      live.AddFrame(frames[k].stamp_s, frames[k].image, frames[k].odom_T_robot);
    live.SetForgettingMode(ForgettingMode::kStatic);
    std::future<std::string> saved = live.Save(path.string());
    for (int k = 4; k < 10; ++k)
      live.AddFrame(frames[k].stamp_s, frames[k].image, frames[k].odom_T_robot);
    EXPECT_EQ(saved.get(), "");
    live.Stop(true);
    EXPECT_EQ(factory_sizes, std::vector<std::size_t>{4});
    EXPECT_EQ(outputs, 10);
    const std::unique_ptr<CmlEngine> loaded = LoadEngine(path.string());
    EXPECT_EQ(loaded->counters().frames, 4);
    EXPECT_EQ(loaded->options().model.forgetting.mode, ForgettingMode::kStatic);
    EXPECT_EQ(live.stats().sessions, 1);
  }
  {
    std::vector<std::size_t> factory_sizes;
    LiveEngine live(
        [&](const std::vector<Pose2>& odometry) {
          factory_sizes.push_back(odometry.size());
          return std::make_unique<CmlEngine>(CmlEngineOptions{});
        },
        options, sessions[0], sessions[0], {});
    for (int k = 0; k < 3; ++k)
      live.AddFrame(frames[k].stamp_s, frames[k].image, frames[k].odom_T_robot);
    live.BeginSession(sessions[0]);
    for (int k = 3; k < 5; ++k)
      live.AddFrame(frames[k].stamp_s, frames[k].image, frames[k].odom_T_robot);
    live.Stop(true);
    EXPECT_EQ(factory_sizes, std::vector<std::size_t>{3});
    EXPECT_EQ(live.stats().sessions, 2);
    EXPECT_EQ(live.engine().counters().frames, 5);
  }
  {
    // A gap in the stamps begins the second session: the first session's frames are all
    // the factory gets, and the new session's frames are not held.
    std::vector<std::size_t> factory_sizes;
    LiveEngineOptions gap = options;
    gap.session_gap_s = 100.0;
    LiveEngine live(
        [&](const std::vector<Pose2>& odometry) {
          factory_sizes.push_back(odometry.size());
          return std::make_unique<CmlEngine>(CmlEngineOptions{});
        },
        gap, sessions[0], sessions[0], {});
    for (int k = 0; k < 6; ++k)
      live.AddFrame(frames[k].stamp_s, frames[k].image, frames[k].odom_T_robot);
    for (int k = 6; k < 10; ++k)
      live.AddFrame(frames[k].stamp_s + 1000.0, frames[k].image, frames[k].odom_T_robot);
    live.Stop(true);
    EXPECT_EQ(factory_sizes, std::vector<std::size_t>{6});
    EXPECT_EQ(live.stats().sessions, 2);
    EXPECT_EQ(live.stats().processed_frames, 10);
  }
  {
    LiveEngine live(
        [](const std::vector<Pose2>&) { return std::make_unique<CmlEngine>(CmlEngineOptions{}); },
        options, sessions[0], sessions[0], {});
    for (int k = 0; k < 5; ++k)
      live.AddFrame(frames[k].stamp_s, frames[k].image, frames[k].odom_T_robot);
    live.Stop(false);
    EXPECT_EQ(live.stats().dropped_frames, 5);
    EXPECT_EQ(live.stats().processed_frames, 0);
    EXPECT_EQ(live.engine().counters().frames, 0);
  }
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace omnicml
