// Tests of the simulated frame source: determinism down to the log bytes, sessions,
// ground truth, and odometry noise statistics against the a1..a4 model.
#include "omnicml/sim/simulator.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

// A fresh temporary directory removed at the end of the test.
class TempDir {
 public:
  explicit TempDir(const std::string& tag) {
    path_ =
        fs::temp_directory_path() / ("omnicml_sim_test_" + tag + "_" + std::to_string(::getpid()));
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

// Every regular file under root, by relative path, with its bytes.
std::map<std::string, std::string> ReadTree(const fs::path& root) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(root)) {
    if (!entry.is_regular_file()) continue;
    std::ifstream in(entry.path(), std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    files[fs::relative(entry.path(), root).string()] = ss.str();
  }
  return files;
}

void WriteLog(const SimulatorOptions& options, const std::string& dir) {
  SimulatedFrameSource source(options);
  LogWriter writer(dir);
  WriteFrames(source, writer);
  writer.Finish();
}

SimulatorOptions SmallOptions() {
  SimulatorOptions o;
  o.world = "institute";
  o.days = 2;
  o.frames_per_day = 3;
  o.seed = 42;
  return o;
}

// The same options give byte-identical logs (images, frames.csv, session.yaml).
TEST(Simulator, SameSeedGivesByteIdenticalLogs) {
  TempDir tmp("bytes");
  const SimulatorOptions options = SmallOptions();
  WriteLog(options, (tmp.path() / "a").string());
  WriteLog(options, (tmp.path() / "b").string());
  const auto a = ReadTree(tmp.path() / "a");
  const auto b = ReadTree(tmp.path() / "b");
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GE(a.size(), 2u * (3 + 2));  // per day: 3 images, frames.csv, session.yaml
  for (const auto& [name, bytes] : a) {
    ASSERT_TRUE(b.count(name)) << name;
    EXPECT_TRUE(bytes == b.at(name)) << name << " differs";
  }
  // Another seed changes the images and the odometry.
  SimulatorOptions other = options;
  other.seed = 43;
  WriteLog(other, (tmp.path() / "c").string());
  const auto c = ReadTree(tmp.path() / "c");
  EXPECT_NE(a.at("day_001/frames.csv"), c.at("day_001/frames.csv"));
  EXPECT_NE(a.at("day_002/000002.png"), c.at("day_002/000002.png"));
}

// All frames of a source: truth, odometry and image bytes.
struct FrameBytes {
  std::vector<Pose2> truth, odom;
  std::vector<std::string> images;
};
FrameBytes ReadAllFrames(const SimulatorOptions& options, const World& world) {
  SimulatedFrameSource source(options, world);
  FrameBytes out;
  Frame f;
  while (source.Next(&f)) {
    out.truth.push_back(*f.map_T_robot_truth);
    out.odom.push_back(f.odom_T_robot);
    const cv::Mat m = f.image.isContinuous() ? f.image : f.image.clone();
    out.images.emplace_back(reinterpret_cast<const char*>(m.data), m.total() * m.elemSize());
  }
  return out;
}

// Layout intensity 0 reproduces today's world frame for frame and byte for byte; with
// layout changes on, day 1 is unchanged, later days differ, and truth and odometry draw
// the same numbers (the change model has a random stream of its own).
TEST(Simulator, LayoutIntensityZeroIsByteIdentical) {
  SimulatorOptions options;
  options.world = "home_store";
  options.days = 3;
  options.frames_per_day = 4;
  options.step_m = 3.0;
  options.seed = 7;
  const World today = LoadBuiltinWorld("home_store");
  const World zero = ParseWorld("base: home_store\nchanges: {layout_intensity: 0}\n", "zero.yaml");
  const FrameBytes a = ReadAllFrames(options, today);
  const FrameBytes b = ReadAllFrames(options, zero);
  ASSERT_EQ(a.images.size(), 12u);
  EXPECT_EQ(a.truth, b.truth);
  EXPECT_EQ(a.odom, b.odom);
  for (std::size_t i = 0; i < a.images.size(); ++i) EXPECT_TRUE(a.images[i] == b.images[i]) << i;

  const FrameBytes c = ReadAllFrames(options, WithLayoutIntensity(today, 0.8));
  EXPECT_EQ(a.truth, c.truth);
  EXPECT_EQ(a.odom, c.odom);
  int later_differ = 0;
  for (std::size_t i = 0; i < a.images.size(); ++i) {
    if (i < 4) {
      EXPECT_TRUE(a.images[i] == c.images[i]) << "day 1 frame " << i;
    } else {
      later_differ += a.images[i] != c.images[i];
    }
  }
  EXPECT_GE(later_differ, 6);
}

// The panorama output (`run --world --sim-image panorama`) shows what the engine sees
// after unwrapping the ring output of the same seed: same truth and odometry, images
// within the resampling and the sensor noise (mean absolute difference per channel
// value measured 3.7 grey levels at worst over these frames; noise sigma 2 on both).
TEST(Simulator, PanoramaOutputMatchesTheUnwrappedRing) {
  SimulatorOptions ring_options = SmallOptions();
  SimulatorOptions pano_options = ring_options;
  pano_options.output = ImageKind::kPanorama;
  SimulatedFrameSource ring_source(ring_options), pano_source(pano_options);
  EXPECT_EQ(pano_source.Session(0).camera.kind, ImageKind::kPanorama);
  EXPECT_EQ(pano_source.Session(0).camera.image_width,
            pano_source.world().camera.panorama_width_px);
  Frame ring, pano;
  double worst = 0;
  while (ring_source.Next(&ring)) {
    ASSERT_TRUE(pano_source.Next(&pano));
    EXPECT_TRUE(ring.odom_T_robot == pano.odom_T_robot);
    EXPECT_TRUE(ring.map_T_robot_truth == pano.map_T_robot_truth);
    const cv::Mat unwrapped = ring_source.renderer().unwrapper().Unwrap(ring.image);
    ASSERT_EQ(unwrapped.size(), pano.image.size());
    worst = std::max(worst, cv::norm(unwrapped, pano.image, cv::NORM_L1) /
                                static_cast<double>(pano.image.total() * pano.image.channels()));
  }
  EXPECT_FALSE(pano_source.Next(&pano));
  RecordProperty("worst_mean_abs_difference", std::to_string(worst));
  EXPECT_LT(worst, 5.0);
}

// A day's frames do not depend on how many days follow, nor on rendering: the poses of
// day 2 are the same in a 2-day and a 3-day run and with images switched off.
TEST(Simulator, DaysAreIndependentOfTheRest) {
  SimulatorOptions two = SmallOptions();
  two.frames_per_day = 4;
  SimulatorOptions three = two;
  three.days = 3;
  SimulatorOptions blind = three;
  blind.render_images = false;
  SimulatedFrameSource s2(two), s3(three), sb(blind);
  Frame f2, f3, fb;
  int compared = 0;
  while (s2.Next(&f2)) {
    ASSERT_TRUE(s3.Next(&f3));
    ASSERT_TRUE(sb.Next(&fb));
    EXPECT_EQ(f2.stamp_s, f3.stamp_s);
    EXPECT_TRUE(f2.odom_T_robot == f3.odom_T_robot);
    EXPECT_TRUE(*f2.map_T_robot_truth == *f3.map_T_robot_truth);
    EXPECT_TRUE(fb.odom_T_robot == f3.odom_T_robot);
    EXPECT_EQ(cv::norm(f2.image, f3.image, cv::NORM_INF), 0.0);
    EXPECT_TRUE(fb.image.empty());
    ++compared;
  }
  EXPECT_EQ(compared, 8);
}

// Sessions: one per day, named in order, starting at the known route start with frames
// every step_m along the route; images of the declared camera size.
TEST(Simulator, SessionsStartAtTheKnownRouteStart) {
  SimulatorOptions o = SmallOptions();
  o.world = "home_store";
  o.frames_per_day = 4;
  o.output = ImageKind::kPanorama;
  SimulatedFrameSource source(o);
  ASSERT_EQ(source.NumSessions(), 2);
  EXPECT_EQ(source.Session(0).name, "day_001");
  EXPECT_EQ(source.Session(1).name, "day_002");
  Frame frame;
  Pose2 prev_truth = Pose2::Zero();
  int n = 0;
  while (source.Next(&frame)) {
    const SessionInfo& info = source.Session(frame.session_index);
    EXPECT_EQ(frame.global_index, n);
    EXPECT_EQ(frame.image.cols, info.camera.image_width);
    EXPECT_EQ(frame.image.rows, info.camera.image_height);
    EXPECT_EQ(frame.image.type(), CV_8UC3);
    ASSERT_TRUE(frame.map_T_robot_truth.has_value());
    if (frame.index_in_session == 0) {
      EXPECT_EQ(info.start.mode, SessionStartMode::kKnownPose);
      EXPECT_LT(PoseDifference(*frame.map_T_robot_truth, info.start.map_T_robot).norm(), 1e-12);
      EXPECT_LT(PoseDifference(frame.odom_T_robot, info.start.map_T_robot).norm(), 1e-12);
      EXPECT_LT(PoseDifference(*frame.map_T_robot_truth, source.route().PoseAt(0)).norm(), 1e-12);
    } else {
      EXPECT_NEAR((frame.map_T_robot_truth->head<2>() - prev_truth.head<2>()).norm(), o.step_m,
                  1e-6);
    }
    prev_truth = *frame.map_T_robot_truth;
    ++n;
  }
  EXPECT_EQ(n, 8);
}

// With `continue`, day 2 goes on where day 1 ended (route and odometry).
TEST(Simulator, ContinueModeGoesOn) {
  SimulatorOptions o = SmallOptions();
  o.render_images = false;
  o.frames_per_day = 20;
  o.later_days_start = SessionStartMode::kContinue;
  SimulatedFrameSource source(o);
  EXPECT_EQ(source.Session(1).start.mode, SessionStartMode::kContinue);
  Frame frame, last;
  while (source.Next(&frame)) {
    if (frame.session_index == 1 && frame.index_in_session == 0) {
      EXPECT_NEAR((frame.map_T_robot_truth->head<2>() - last.map_T_robot_truth->head<2>()).norm(),
                  o.step_m, 1e-6);
      EXPECT_NEAR((frame.odom_T_robot.head<2>() - last.odom_T_robot.head<2>()).norm(), o.step_m,
                  0.1);
      EXPECT_LT(
          PoseDifference(*frame.map_T_robot_truth, source.route().PoseAt(20 * o.step_m)).norm(),
          1e-9);
    }
    last = frame;
  }
}

// Sampled increments have the variances of M = diag(a1 r1^2 + a2 t^2,
// a3 t^2 + a4 (r1^2 + r2^2), a1 r2^2 + a2 t^2) and zero mean errors.
TEST(Simulator, OdometryNoiseMatchesTheModel) {
  const MotionNoise noise{0.05, 0.02, 0.04, 0.01};
  std::mt19937_64 rng(7);
  const int n = 20000;
  for (const OdometryIncrement u :
       {OdometryIncrement{0.1, 0.3, -0.2}, OdometryIncrement{0.0, 0.2, 0.0},
        OdometryIncrement{0.0, 0.0, 0.5}}) {
    double sum[3] = {0, 0, 0}, sq[3] = {0, 0, 0};
    for (int i = 0; i < n; ++i) {
      const OdometryIncrement v = SampleOdometryIncrement(u, noise, rng);
      const double e[3] = {v.rot1_rad - u.rot1_rad, v.trans_m - u.trans_m, v.rot2_rad - u.rot2_rad};
      for (int k = 0; k < 3; ++k) {
        sum[k] += e[k];
        sq[k] += e[k] * e[k];
      }
    }
    const double r1 = u.rot1_rad, t = u.trans_m, r2 = u.rot2_rad;
    const double m[3] = {noise.a1 * r1 * r1 + noise.a2 * t * t,
                         noise.a3 * t * t + noise.a4 * (r1 * r1 + r2 * r2),
                         noise.a1 * r2 * r2 + noise.a2 * t * t};
    for (int k = 0; k < 3; ++k) {
      const double mean = sum[k] / n, var = sq[k] / n - mean * mean;
      // Standard error of a sample variance: var sqrt(2 / n) = 1 % here; allow 5 sigma.
      EXPECT_NEAR(var, m[k], 0.05 * m[k] + 1e-15) << "component " << k;
      EXPECT_NEAR(mean, 0.0, 5.0 * std::sqrt(m[k] / n) + 1e-15) << "component " << k;
    }
  }
}

// Over a simulated run, the odometry increments' errors normalised by the model's
// standard deviations have unit variance (the world's a1..a4 reach the frames).
TEST(Simulator, FrameOdometryFollowsTheWorldNoise) {
  SimulatorOptions o;
  o.world = "home_store";
  o.frames_per_day = 2000;
  o.render_images = false;
  o.seed = 11;
  SimulatedFrameSource source(o);
  const MotionNoise& a = source.world().odometry_noise;
  Frame frame;
  ASSERT_TRUE(source.Next(&frame));
  Pose2 prev_odom = frame.odom_T_robot, prev_truth = *frame.map_T_robot_truth;
  double sq[3] = {0, 0, 0};
  int count[3] = {0, 0, 0};
  while (source.Next(&frame)) {
    const OdometryIncrement u = ComputeIncrement(prev_truth, *frame.map_T_robot_truth);
    const OdometryIncrement v = ComputeIncrement(prev_odom, frame.odom_T_robot);
    const double m[3] = {
        a.a1 * u.rot1_rad * u.rot1_rad + a.a2 * u.trans_m * u.trans_m,
        a.a3 * u.trans_m * u.trans_m + a.a4 * (u.rot1_rad * u.rot1_rad + u.rot2_rad * u.rot2_rad),
        a.a1 * u.rot2_rad * u.rot2_rad + a.a2 * u.trans_m * u.trans_m};
    const double e[3] = {WrapAngle(v.rot1_rad - u.rot1_rad), v.trans_m - u.trans_m,
                         WrapAngle(v.rot2_rad - u.rot2_rad)};
    for (int k = 0; k < 3; ++k) {
      sq[k] += e[k] * e[k] / m[k];
      ++count[k];
    }
    prev_odom = frame.odom_T_robot;
    prev_truth = *frame.map_T_robot_truth;
  }
  for (int k = 0; k < 3; ++k) {
    ASSERT_GT(count[k], 1900);
    // Unit variance within 5 standard errors (sqrt(2 / n) = 3.2 %).
    EXPECT_NEAR(sq[k] / count[k], 1.0, 0.16) << "component " << k;
  }
}

// People walk in free space at no more than their speed, and they do move.
TEST(Simulator, PeopleWalkInFreeSpace) {
  SimulatorOptions o;
  o.world = "home_store";
  o.frames_per_day = 300;
  o.render_images = false;
  SimulatedFrameSource source(o);
  const World& w = source.world();
  const double max_step = w.people.speed_mps * o.step_m / w.route.speed_mps;
  Frame frame;
  std::vector<Person> prev;
  double moved = 0;
  while (source.Next(&frame)) {
    const auto& people = source.people();
    ASSERT_EQ(static_cast<int>(people.size()), w.people.count);
    for (std::size_t i = 0; i < people.size(); ++i) {
      EXPECT_TRUE(IsFree(w, source.state(), people[i].position_m, people[i].radius_m * 0.99))
          << "person " << i << " at frame " << frame.index_in_session;
      if (!prev.empty()) {
        const double step = (people[i].position_m - prev[i].position_m).norm();
        EXPECT_LE(step, max_step + 1e-9);
        moved += step;
      }
    }
    prev = people;
  }
  EXPECT_GT(moved, 0.5 * max_step * 299 * w.people.count);
}

// With `global`, later days start at seeded places on the route, different per day.
TEST(Simulator, GlobalModeStartsSomewhereOnTheRoute) {
  SimulatorOptions o = SmallOptions();
  o.days = 3;
  o.render_images = false;
  o.later_days_start = SessionStartMode::kGlobal;
  SimulatedFrameSource source(o);
  EXPECT_EQ(source.Session(0).start.mode, SessionStartMode::kKnownPose);
  const Pose2 s2 = source.Session(1).start.map_T_robot, s3 = source.Session(2).start.map_T_robot;
  EXPECT_EQ(source.Session(1).start.mode, SessionStartMode::kGlobal);
  EXPECT_GT((s2.head<2>() - s3.head<2>()).norm(), 1e-3);
  Frame frame;
  while (source.Next(&frame)) {
    if (frame.session_index == 1 && frame.index_in_session == 0) {
      EXPECT_LT(PoseDifference(*frame.map_T_robot_truth, s2).norm(), 1e-12);
      EXPECT_LT(frame.odom_T_robot.norm(), 1e-12);  // no prior: odometry restarts at zero
    }
  }
}

// Bad options are rejected with the field's name.
TEST(Simulator, OptionsAreValidated) {
  SimulatorOptions o;
  o.days = 0;
  try {
    o.Validate();
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("days"), std::string::npos);
  }
  o = SimulatorOptions();
  o.step_m = -1;
  EXPECT_THROW(o.Validate(), Error);
  o = SimulatorOptions();
  o.world = "no_such_world_or_file";
  EXPECT_THROW(SimulatedFrameSource{o}, Error);
}

}  // namespace
}  // namespace omnicml
