// Tests of the ros module's bag import and export: message conversions, the log -> bag ->
// log round trip (and the engine on both), foreign bags (tf odometry, 16-bit images, gaps)
// and bad bags (one-line errors naming bag, topic and message; nothing left behind).
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <functional>
#include <numbers>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/ros/rosbag_io.h"
#include "omnicml/sim/simulator.h"
#include "ros/ros1.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

class TempDir {
 public:
  TempDir() {
    static int n = 0;
    path_ = fs::temp_directory_path() / StrCat("omnicml_rosbag_test_", ::getpid(), "_", n++);
    fs::create_directories(path_);
  }
  ~TempDir() { fs::remove_all(path_); }
  fs::path operator/(const std::string& name) const { return path_ / name; }
  const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

void SimulateLog(const fs::path& dir, int days, int frames_per_day,
                 ImageKind kind = ImageKind::kPanorama) {
  SimulatorOptions options;
  options.days = days;
  options.frames_per_day = frames_per_day;
  options.output = kind;
  options.seed = 2;
  SimulatedFrameSource source(options);
  LogWriter writer(dir.string());
  WriteFrames(source, writer);
  writer.Finish();
}

std::vector<Frame> ReadAll(const fs::path& dir, std::vector<SessionInfo>* sessions = nullptr) {
  LogReader reader(dir.string());
  std::vector<Frame> frames;
  Frame f;
  while (reader.Next(&f)) frames.push_back(f);
  if (sessions)
    for (int k = 0; k < reader.NumSessions(); ++k) sessions->push_back(reader.Session(k));
  return frames;
}

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// Nothing but the named entries remains in dir (no staging directory, no temporary).
void ExpectOnly(const fs::path& dir, std::vector<std::string> names) {
  std::vector<std::string> found;
  for (const auto& e : fs::directory_iterator(dir)) found.push_back(e.path().filename().string());
  std::sort(found.begin(), found.end());
  std::sort(names.begin(), names.end());
  EXPECT_EQ(found, names);
}

// rgb8 (channels swapped, padded step) and big-endian mono16 (scaled v * 255 / 65535)
// decode to the pixels they carry; PNG-compressed images decode losslessly.
TEST(Ros1, DecodesImageEncodings) {
  cv::Mat bgr = ros1::ImageFromRaw("rgb8", 2, 2, 8, false,
                                   {1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0});
  ASSERT_EQ(bgr.type(), CV_8UC3);
  EXPECT_EQ(bgr.at<cv::Vec3b>(0, 0), cv::Vec3b(3, 2, 1));
  EXPECT_EQ(bgr.at<cv::Vec3b>(1, 1), cv::Vec3b(12, 11, 10));
  cv::Mat mono =
      ros1::ImageFromRaw("mono16", 2, 2, 4, true, {0xFF, 0xFF, 0x00, 0x00, 0x80, 0x00, 0x01, 0x01});
  ASSERT_EQ(mono.type(), CV_8UC1);
  EXPECT_EQ(mono.at<std::uint8_t>(0, 0), 255);
  EXPECT_EQ(mono.at<std::uint8_t>(0, 1), 0);
  EXPECT_EQ(mono.at<std::uint8_t>(1, 0), 128);  // 0x8000 * 255 / 65535 = 127.5 -> 128
  EXPECT_EQ(mono.at<std::uint8_t>(1, 1), 1);    // 0x0101 * 255 / 65535 = 1
  cv::Mat grey(3, 4, CV_8UC1);
  cv::randu(grey, 0, 255);
  std::vector<std::uint8_t> png;
  ASSERT_TRUE(cv::imencode(".png", grey, png));
  EXPECT_EQ(cv::norm(ros1::ImageFromCompressed("png", png), grey, cv::NORM_INF), 0.0);
}

// Unsupported encodings, data shorter than step x height and compressed data of another
// format are errors naming them.
TEST(Ros1, RejectsBadImages) {
  auto error = [](const std::function<void()>& f) {
    try {
      f();
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_THAT(error([] {
                ros1::ImageFromRaw("bayer_rggb8", 4, 4, 4, false, std::vector<std::uint8_t>(16));
              }),
              HasSubstr("bayer_rggb8"));
  EXPECT_THAT(
      error([] { ros1::ImageFromRaw("mono8", 4, 4, 4, false, std::vector<std::uint8_t>(15)); }),
      HasSubstr("15 bytes"));
  EXPECT_THAT(error([] {
                ros1::ImageFromCompressed("tiff", {'I', 'I', 42, 0});
              }),
              HasSubstr("neither PNG nor JPEG"));
}

// log -> bag -> log gives the same sessions, the same images bit for bit, the same
// positions and stamps to 1 ns, angles to 1e-15 rad and the same ground truth; raw and
// compressed images alike.
TEST(RosbagIo, RoundTripKeepsTheLog) {
  TempDir tmp;
  SimulateLog(tmp / "log", 2, 6);
  for (bool compressed : {false, true}) {
    const fs::path bag = tmp / (compressed ? "c.bag" : "r.bag");
    const fs::path back = tmp / (compressed ? "back_c" : "back_r");
    RosbagExportOptions eo;
    eo.compressed = compressed;
    const RosbagExportSummary es = ExportRosbag((tmp / "log").string(), bag.string(), eo);
    EXPECT_EQ(es.frames, 12);
    EXPECT_EQ(es.sessions, 2);
    EXPECT_EQ(es.stamp_offset_s, 1.0);  // the simulator's first stamp is 0
    RosbagImportOptions io;
    io.image_topic = eo.image_topic;
    io.odom_topic = eo.odom_topic;
    io.truth_topic = eo.truth_topic;
    const RosbagImportSummary is = ImportRosbag({bag.string()}, back.string(), io);
    EXPECT_EQ(is.frames, 12);
    EXPECT_EQ(is.sessions, 2);
    EXPECT_EQ(is.frames_with_truth, 12);
    std::vector<SessionInfo> s0, s1;
    const std::vector<Frame> a = ReadAll(tmp / "log", &s0), b = ReadAll(back, &s1);
    ASSERT_EQ(a.size(), b.size());
    ASSERT_EQ(s0.size(), s1.size());
    for (std::size_t k = 0; k < s0.size(); ++k)
      EXPECT_EQ(SessionYamlText(s0[k]), SessionYamlText(s1[k]));
    for (std::size_t k = 0; k < a.size(); ++k) {
      EXPECT_EQ(a[k].session_index, b[k].session_index);
      EXPECT_NEAR(a[k].stamp_s, b[k].stamp_s, 1e-9);
      EXPECT_EQ(cv::norm(a[k].image, b[k].image, cv::NORM_INF), 0.0) << "frame " << k;
      EXPECT_EQ(a[k].odom_T_robot.head<2>(), b[k].odom_T_robot.head<2>());
      EXPECT_NEAR(PoseDifference(a[k].odom_T_robot, b[k].odom_T_robot).z(), 0.0, 1e-15);
      ASSERT_TRUE(b[k].map_T_robot_truth.has_value());
      EXPECT_NEAR(PoseDifference(*a[k].map_T_robot_truth, *b[k].map_T_robot_truth).norm(), 0.0,
                  1e-15);
    }
  }
}

// The engine on the imported log gives the estimates of the original log (to 1e-9 m: the
// angles of odometry differ in their last bits after the quaternion encoding).
TEST(RosbagIo, EngineOnTheImportedLogMatchesTheOriginal) {
  TempDir tmp;
  SimulateLog(tmp / "log", 2, 20);
  ExportRosbag((tmp / "log").string(), (tmp / "x.bag").string());
  RosbagImportOptions io;
  io.image_topic = "/omnicml/image";
  io.odom_tf_frame = "base_link";  // odometry from /tf this time
  ImportRosbag({(tmp / "x.bag").string()}, (tmp / "back").string(), io);
  auto run = [](const fs::path& dir) {
    LogReader reader(dir.string());
    CmlEngine engine(CmlEngineOptions{});
    std::vector<Pose2> out;
    Frame f;
    int session = -1;
    while (reader.Next(&f)) {
      if (f.session_index != session)
        engine.BeginSession(reader.Session(session = f.session_index));
      out.push_back(engine.ProcessFrame(f).estimate->strongest.mean);
    }
    return std::make_pair(out, engine.model().NumViews());
  };
  const auto [a, views_a] = run(tmp / "log");
  const auto [b, views_b] = run(tmp / "back");
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t k = 0; k < a.size(); ++k)
    EXPECT_NEAR(PoseDifference(a[k], b[k]).norm(), 0.0, 1e-9) << k;
  EXPECT_EQ(views_a, views_b);
}

// A foreign bag: 16-bit mono images, odometry on /tf at another rate (interpolated to the
// image stamps), no session topic; a gap of 50 s splits it into two sessions.
TEST(RosbagIo, ImportsAForeignBagWithTfOdometryAndAGap) {
  TempDir tmp;
  const fs::path bag_path = tmp / "foreign.bag";
  {
    ros1::BagWriter bag(bag_path.string());
    for (int k = 0; k < 240; ++k) {  // tf at 20 Hz over 100..106 s and 150..156 s: x = t m
      const double t = (k < 120 ? 100.0 : 150.0) + 0.05 * (k % 120);
      bag.WriteTf(t, "odom", "base_link", {t, 0.0, 0.0});
    }
    for (int k = 0; k < 6; ++k) {  // images at 103, 104.03, 105.06 and 153, ...
      const double t = (k < 3 ? 103.0 : 153.0) + 1.03 * (k % 3);
      bag.WriteRawImage("/cam", t, "mono16", 64, 16, 128, false,
                        std::vector<std::uint8_t>(128 * 16, static_cast<std::uint8_t>(10 * k)));
    }
    bag.Close();
  }
  RosbagImportOptions io;
  io.image_topic = "/cam";
  io.odom_tf_frame = "base_link";
  io.split_gap_s = 20.0;
  const RosbagImportSummary s = ImportRosbag({bag_path.string()}, (tmp / "log").string(), io);
  EXPECT_EQ(s.frames, 6);
  EXPECT_EQ(s.sessions, 2);
  std::vector<SessionInfo> sessions;
  const std::vector<Frame> frames = ReadAll(tmp / "log", &sessions);
  ASSERT_EQ(frames.size(), 6u);
  EXPECT_EQ(sessions[0].camera.kind, ImageKind::kPanorama);
  EXPECT_EQ(sessions[1].start.mode, SessionStartMode::kGlobal);
  EXPECT_NEAR(frames[1].odom_T_robot.x(), 104.03, 1e-9);  // between the 104.0 and 104.05 samples
  EXPECT_EQ(frames[4].session_index, 1);
  EXPECT_EQ(frames[4].image.type(), CV_8UC1);
}

// Bad bags: a missing topic, a wrong type, stamps going backwards and a truncated file
// are errors naming bag, topic and message; the output log is never created.
TEST(RosbagIo, BadBagsFailWithWhereAndLeaveNothing) {
  TempDir tmp;
  SimulateLog(tmp / "log", 1, 4);
  const std::string bag = (tmp / "x.bag").string();
  ExportRosbag((tmp / "log").string(), bag);
  RosbagImportOptions io;
  io.image_topic = "/omnicml/image";
  io.odom_topic = "/odom";
  const std::string out = (tmp / "out").string();

  io.image_topic = "/camera/missing";
  EXPECT_THAT(ErrorOf([&] { ImportRosbag({bag}, out, io); }),
              HasSubstr(bag + ": topic /camera/missing: not in the bag"));
  io.image_topic = "/odom";
  EXPECT_THAT(ErrorOf([&] { ImportRosbag({bag}, out, io); }),
              HasSubstr(bag + ": topic /odom: message 0: type nav_msgs/Odometry"));
  io.image_topic = "/omnicml/image";

  const std::string backwards = (tmp / "backwards.bag").string();
  {
    ros1::BagWriter b(backwards);
    for (int k = 0; k < 3; ++k) {
      b.WriteOdometry("/odom", 10.0 + k, "odom", "base_link", {});
      // The third image's stamp goes back (its bag time does not).
      b.WriteRawImage("/omnicml/image", k == 2 ? 10.5 : 10.0 + k, "mono8", 32, 8, 32, false,
                      std::vector<std::uint8_t>(256, static_cast<std::uint8_t>(k)), 10.0 + k);
    }
    b.Close();
  }
  EXPECT_THAT(
      ErrorOf([&] { ImportRosbag({backwards}, out, io); }),
      HasSubstr(backwards + ": topic /omnicml/image: message 2: stamp 10.5 s is not after"));

  const std::string truncated = (tmp / "truncated.bag").string();
  fs::copy_file(bag, truncated);
  fs::resize_file(truncated, fs::file_size(truncated) / 2);
  EXPECT_THAT(ErrorOf([&] { ImportRosbag({truncated}, out, io); }),
              HasSubstr(truncated + ": cannot read the bag"));

  EXPECT_FALSE(fs::exists(out));
  ExpectOnly(tmp.path(), {"log", "x.bag", "backwards.bag", "truncated.bag"});
}

// Export refuses to replace a bag without overwrite and leaves no temporary when the log
// is bad.
TEST(RosbagIo, ExportIsAtomic) {
  TempDir tmp;
  SimulateLog(tmp / "log", 1, 3);
  const std::string bag = (tmp / "x.bag").string();
  ExportRosbag((tmp / "log").string(), bag);
  EXPECT_THAT(ErrorOf([&] { ExportRosbag((tmp / "log").string(), bag); }), HasSubstr("exists"));
  // Break the second image: the export fails midway and leaves only the old bag.
  const auto size = fs::file_size(bag);
  fs::resize_file(tmp / "log" / "day_001" / "000001.png", 10);
  RosbagExportOptions o;
  o.overwrite = true;
  EXPECT_NE(ErrorOf([&] { ExportRosbag((tmp / "log").string(), bag, o); }), "");
  EXPECT_EQ(fs::file_size(bag), size);
  ExpectOnly(tmp.path(), {"log", "x.bag"});
}

}  // namespace
}  // namespace omnicml
