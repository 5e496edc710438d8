// Tests of the multi-day log format: round trip, determinism, validation with file and
// line, streaming, crash safety of the writer.
#include "omnicml/logs/log_format.h"

#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;

constexpr int kPanoWidth = 72;
constexpr int kPanoHeight = 12;
constexpr int kRingSize = 40;
constexpr int kFramesPerSession = 6;

// A fresh directory per test, removed afterwards.
class LogTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    root_ = fs::path(::testing::TempDir()) / StrCat("omnicml_logs_", ::getpid(), "_", info->name());
    fs::remove_all(root_);
    fs::create_directories(root_);
  }
  void TearDown() override { fs::remove_all(root_); }
  std::string Path(const std::string& name) const { return (root_ / name).string(); }

  fs::path root_;
};

SessionInfo PanoramaSession() {
  SessionInfo info;
  info.name = "day_01";
  info.day_label = "day 1: lights \"on\"";
  info.start_time_s = 1700000000.125;
  info.camera.kind = ImageKind::kPanorama;
  info.camera.image_width = kPanoWidth;
  info.camera.image_height = kPanoHeight;
  info.start.mode = SessionStartMode::kKnownPose;
  info.start.map_T_robot = MakePose(1.0 / 3.0, -2.0 / 7.0, 0.1 * kPi);
  info.start.covariance = Eigen::Vector3d(0.01, 0.02, 0.003).asDiagonal();
  return info;
}

SessionInfo RingSession() {
  SessionInfo info;
  info.name = "day_02";
  info.day_label = "day 2";
  info.start_time_s = 1700086400.5;
  info.camera.kind = ImageKind::kRawRing;
  info.camera.image_width = kRingSize;
  info.camera.image_height = kRingSize;
  OmniCalibration& c = info.camera.calibration.ring;
  c.center_x_px = 19.5;
  c.center_y_px = 19.25;
  c.inner_radius_px = 4.0;
  c.outer_radius_px = 18.0;
  c.azimuth0_rad = 0.3;
  c.direction = RingDirection::kClockwise;
  c.elevation = ElevationMapping::kLinearInverted;
  c.panorama_width = kPanoWidth;
  c.panorama_height = kPanoHeight;
  info.start.mode = SessionStartMode::kGlobal;
  return info;
}

// Deterministic frames with awkward doubles (not representable in short decimal).
std::vector<Frame> MakeFrames(const SessionInfo& info, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> pos(-50.0, 50.0), ang(-kPi, kPi);
  std::vector<Frame> frames;
  double stamp = info.start_time_s;
  const int type = info.camera.kind == ImageKind::kRawRing ? CV_8UC1 : CV_8UC3;
  for (int i = 0; i < kFramesPerSession; ++i) {
    Frame f;
    stamp += 0.1 + std::uniform_real_distribution<double>(0.0, 1e-3)(rng);
    f.stamp_s = stamp;
    f.image = cv::Mat(info.camera.image_height, info.camera.image_width, type);
    cv::randu(f.image, cv::Scalar::all(0), cv::Scalar::all(256));
    f.odom_T_robot = MakePose(pos(rng), pos(rng), ang(rng));
    if (i % 2 == 0) f.map_T_robot_truth = MakePose(pos(rng), pos(rng), ang(rng));
    frames.push_back(f);
  }
  return frames;
}

// Writes the two-session test log: a colour panorama day and a grey raw ring day.
void WriteTestLog(const std::string& dir) {
  cv::theRNG().state = 12345;  // cv::randu in MakeFrames
  LogWriter writer(dir);
  for (const SessionInfo& info : {PanoramaSession(), RingSession()}) {
    writer.BeginSession(info);
    for (const Frame& f : MakeFrames(info, info.camera.kind == ImageKind::kRawRing ? 2 : 1))
      writer.Write(f);
  }
  writer.AddFile("README.txt", "two test sessions\n");
  writer.Finish();
}

std::vector<Frame> ReadAll(FrameSource& source) {
  std::vector<Frame> frames;
  Frame f;
  while (source.Next(&f)) {
    frames.push_back(f);
    f = Frame();
  }
  return frames;
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

void WriteFile(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

// Replaces line `line` (1-based) of a text file.
void ReplaceLine(const std::string& path, int line, const std::string& text) {
  std::istringstream in(ReadFile(path));
  std::string out, l;
  for (int n = 1; std::getline(in, l); ++n) out += (n == line ? text : l) + "\n";
  WriteFile(path, out);
}

std::string GetLine(const std::string& path, int line) {
  std::istringstream in(ReadFile(path));
  std::string l;
  for (int n = 1; std::getline(in, l); ++n) {
    if (n == line) return l;
  }
  return "";
}

// 1-based number of the first line containing `needle`, 0 if none.
int FindLine(const std::string& path, const std::string& needle) {
  std::istringstream in(ReadFile(path));
  std::string l;
  for (int n = 1; std::getline(in, l); ++n) {
    if (l.find(needle) != std::string::npos) return n;
  }
  return 0;
}

bool SameBits(double a, double b) { return std::memcmp(&a, &b, sizeof(double)) == 0; }

void ExpectSamePose(const Pose2& a, const Pose2& b) {
  for (int i = 0; i < 3; ++i)
    EXPECT_TRUE(SameBits(a[i], b[i])) << i << ": " << a[i] << " vs " << b[i];
}

// Opens the log and reads every frame; returns the error message ("" if none).
std::string ReadError(const std::string& dir) {
  try {
    LogReader reader(dir);
    ReadAll(reader);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST_F(LogTest, RoundTripIsBitIdentical) {
  // What LogWriter writes, LogReader returns with the same bits: poses, stamps, images, sessions.
  const std::string dir = Path("log");
  WriteTestLog(dir);
  LogReader reader(dir);
  ASSERT_EQ(reader.NumSessions(), 2);
  const SessionInfo expected_sessions[] = {PanoramaSession(), RingSession()};
  for (int s = 0; s < 2; ++s) {
    const SessionInfo& got = reader.Session(s);
    const SessionInfo& want = expected_sessions[s];
    EXPECT_EQ(got.name, want.name);
    EXPECT_EQ(got.day_label, want.day_label);
    EXPECT_TRUE(SameBits(got.start_time_s, want.start_time_s));
    EXPECT_EQ(got.camera.kind, want.camera.kind);
    EXPECT_EQ(got.camera.image_width, want.camera.image_width);
    EXPECT_EQ(got.camera.image_height, want.camera.image_height);
    EXPECT_EQ(got.start.mode, want.start.mode);
    if (want.start.mode == SessionStartMode::kKnownPose) {
      ExpectSamePose(got.start.map_T_robot, want.start.map_T_robot);
      EXPECT_EQ(got.start.covariance, want.start.covariance);
    }
    if (want.camera.kind == ImageKind::kRawRing) {
      const OmniCalibration& a = got.camera.calibration.ring;
      const OmniCalibration& b = want.camera.calibration.ring;
      EXPECT_TRUE(SameBits(a.center_x_px, b.center_x_px));
      EXPECT_TRUE(SameBits(a.center_y_px, b.center_y_px));
      EXPECT_TRUE(SameBits(a.inner_radius_px, b.inner_radius_px));
      EXPECT_TRUE(SameBits(a.outer_radius_px, b.outer_radius_px));
      EXPECT_TRUE(SameBits(a.azimuth0_rad, b.azimuth0_rad));
      EXPECT_EQ(a.direction, b.direction);
      EXPECT_EQ(a.elevation, b.elevation);
      EXPECT_EQ(a.panorama_width, b.panorama_width);
      EXPECT_EQ(a.panorama_height, b.panorama_height);
    }
  }
  cv::theRNG().state = 12345;
  std::vector<Frame> want = MakeFrames(PanoramaSession(), 1);
  for (const Frame& f : MakeFrames(RingSession(), 2)) want.push_back(f);
  const std::vector<Frame> got = ReadAll(reader);
  ASSERT_EQ(got.size(), want.size());
  for (std::size_t i = 0; i < got.size(); ++i) {
    SCOPED_TRACE(i);
    EXPECT_EQ(got[i].session_index, static_cast<int>(i) / kFramesPerSession);
    EXPECT_EQ(got[i].index_in_session, static_cast<std::int64_t>(i) % kFramesPerSession);
    EXPECT_EQ(got[i].global_index, static_cast<std::int64_t>(i));
    EXPECT_TRUE(SameBits(got[i].stamp_s, want[i].stamp_s));
    ExpectSamePose(got[i].odom_T_robot, want[i].odom_T_robot);
    ASSERT_EQ(got[i].map_T_robot_truth.has_value(), want[i].map_T_robot_truth.has_value());
    if (want[i].map_T_robot_truth)
      ExpectSamePose(*got[i].map_T_robot_truth, *want[i].map_T_robot_truth);
    ASSERT_EQ(got[i].image.type(), want[i].image.type());
    ASSERT_EQ(got[i].image.size(), want[i].image.size());
    EXPECT_EQ(cv::norm(got[i].image, want[i].image, cv::NORM_INF), 0.0);
  }
}

TEST_F(LogTest, SameDataTwiceGivesByteIdenticalFiles) {
  // Two writes of the same data produce the same set of files with the same bytes.
  WriteTestLog(Path("a"));
  WriteTestLog(Path("b"));
  std::vector<std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(Path("a"))) {
    if (entry.is_regular_file()) files.push_back(fs::relative(entry.path(), Path("a")).string());
  }
  std::size_t files_b = 0;
  for (const auto& entry : fs::recursive_directory_iterator(Path("b")))
    files_b += entry.is_regular_file();
  EXPECT_EQ(files.size(), files_b);
  EXPECT_EQ(files.size(), 2u * (2 + kFramesPerSession) + 1);  // + README.txt
  for (const auto& f : files) {
    SCOPED_TRACE(f);
    const std::string a = ReadFile(Path("a/" + f));
    EXPECT_FALSE(a.empty());
    EXPECT_EQ(a, ReadFile(Path("b/" + f)));
  }
}

// One way to spoil a good log, and where the reader must report it.
struct Corruption {
  std::string name;
  std::function<void(const std::string& dir)> apply;
  std::string file;  // the message must name this file ...
  std::string line;  // ... and this ":line:" (empty: no line applies)
  std::string what;  // ... and contain this text
};

TEST_F(LogTest, ReaderRejectsEachKindOfBadFileWithFileAndLine) {
  // A good log spoilt in one place fails with a message naming the file and the line.
  const std::string s0 = "/day_01/";
  const std::string s1 = "/day_02/";
  const auto yaml_line = [&](const std::string& dir, const std::string& needle) {
    return StrCat(":", FindLine(dir + s0 + "session.yaml", needle), ":");
  };
  std::vector<Corruption> cases = {
      {"missing session.yaml", [&](const std::string& d) { fs::remove(d + s1 + "session.yaml"); },
       "day_02/session.yaml", "", "missing"},
      {"missing frames.csv", [&](const std::string& d) { fs::remove(d + s1 + "frames.csv"); },
       "day_02/frames.csv", "", "missing"},
      {"missing image", [&](const std::string& d) { fs::remove(d + s0 + "000002.png"); },
       "day_01/frames.csv", ":4:", "000002.png"},
      {"unparsable number",
       [&](const std::string& d) {
         std::string l = GetLine(d + s0 + "frames.csv", 3);
         ReplaceLine(d + s0 + "frames.csv", 3, "12x.5" + l.substr(l.find(',')));
       },
       "day_01/frames.csv", ":3:", "12x.5"},
      {"NaN",
       [&](const std::string& d) {
         std::string l = GetLine(d + s0 + "frames.csv", 5);
         const std::size_t a = l.find(',', l.find(',') + 1);  // after image
         ReplaceLine(d + s0 + "frames.csv", 5,
                     l.substr(0, a + 1) + "nan" + l.substr(l.find(',', a + 1)));
       },
       "day_01/frames.csv", ":5:", "odom_x_m"},
      {"infinity",
       [&](const std::string& d) {
         std::string l = GetLine(d + s1 + "frames.csv", 2);
         ReplaceLine(d + s1 + "frames.csv", 2, "inf" + l.substr(l.find(',')));
       },
       "day_02/frames.csv", ":2:", "inf"},
      {"non-increasing stamp",
       [&](const std::string& d) {
         const std::string prev = GetLine(d + s0 + "frames.csv", 3);
         std::string l = GetLine(d + s0 + "frames.csv", 4);
         ReplaceLine(d + s0 + "frames.csv", 4,
                     prev.substr(0, prev.find(',')) + l.substr(l.find(',')));
       },
       "day_01/frames.csv", ":4:", "does not increase"},
      {"wrong column count",
       [&](const std::string& d) {
         std::string l = GetLine(d + s0 + "frames.csv", 6);
         ReplaceLine(d + s0 + "frames.csv", 6, l.substr(0, l.rfind(',')));
       },
       "day_01/frames.csv", ":6:", "column count"},
      {"half ground truth",
       [&](const std::string& d) {
         std::string l = GetLine(d + s0 + "frames.csv", 2);  // frame 0 has ground truth
         ReplaceLine(d + s0 + "frames.csv", 2, l.substr(0, l.rfind(',') + 1));
       },
       "day_01/frames.csv", ":2:", "ground truth"},
      {"bad header",
       [&](const std::string& d) {
         ReplaceLine(d + s1 + "frames.csv", 1, "stamp,image,x,y,phi,gx,gy,gphi");
       },
       "day_02/frames.csv", ":1:", "header"},
      {"unknown camera model",
       [&](const std::string& d) {
         ReplaceLine(d + s0 + "session.yaml", FindLine(d + s0 + "session.yaml", "model:"),
                     "  model: pinhole");
       },
       "day_01/session.yaml", "", "pinhole"},
      {"bad calibration field",
       [&](const std::string& d) {
         ReplaceLine(d + s1 + "session.yaml", FindLine(d + s1 + "session.yaml", "direction:"),
                     "    direction: sideways");
       },
       "day_02/session.yaml", "", "camera.calibration.direction"},
      {"key of another camera model",
       [&](const std::string& d) {
         const int l = FindLine(d + s1 + "session.yaml", "inner_radius_px:");
         ReplaceLine(d + s1 + "session.yaml", l, "    field_of_view_deg: 180");
       },
       "day_02/session.yaml", "", "field_of_view_deg"},
      {"unknown yaml key",
       [&](const std::string& d) {
         WriteFile(d + s0 + "session.yaml", ReadFile(d + s0 + "session.yaml") + "colour: red\n");
       },
       "day_01/session.yaml", "", "colour"},
      {"unknown nested yaml key",
       [&](const std::string& d) {
         const int l = FindLine(d + s0 + "session.yaml", "image_width:");
         ReplaceLine(d + s0 + "session.yaml", l,
                     GetLine(d + s0 + "session.yaml", l) + "\n  image_widht: 3");
       },
       "day_01/session.yaml", "", "image_widht"},
      {"unknown start mode",
       [&](const std::string& d) {
         ReplaceLine(d + s0 + "session.yaml", FindLine(d + s0 + "session.yaml", "mode:"),
                     "  mode: teleport");
       },
       "day_01/session.yaml", "", "teleport"},
      {"NaN in yaml",
       [&](const std::string& d) {
         ReplaceLine(d + s0 + "session.yaml", FindLine(d + s0 + "session.yaml", "start_time_s:"),
                     "start_time_s: .nan");
       },
       "day_01/session.yaml", "", "start_time_s"},
      {"wrong image size",
       [&](const std::string& d) {
         cv::imwrite(d + s0 + "000001.png",
                     cv::Mat(kPanoHeight, kPanoWidth - 2, CV_8UC3, cv::Scalar(1, 2, 3)));
       },
       "day_01/frames.csv", ":3:", "000001.png"},
      {"wrong channel count",
       [&](const std::string& d) {
         cv::imwrite(d + s0 + "000003.png",
                     cv::Mat(kPanoHeight, kPanoWidth, CV_8UC1, cv::Scalar(7)));
       },
       "day_01/frames.csv", ":5:", "channels"},
      {"undecodable image",
       [&](const std::string& d) { WriteFile(d + s1 + "000004.png", "not a png"); },
       "day_02/frames.csv", ":6:", "000004.png"},
  };
  const std::string good = Path("good");
  WriteTestLog(good);
  ASSERT_EQ(ReadError(good), "");
  for (std::size_t i = 0; i < cases.size(); ++i) {
    const Corruption& c = cases[i];
    SCOPED_TRACE(c.name);
    const std::string dir = Path(StrCat("bad", i));
    fs::copy(good, dir, fs::copy_options::recursive);
    // YAML corruptions are reported at the line of the offending key; compute it now.
    std::string line = c.line;
    if (c.name == "unknown camera model") line = yaml_line(dir, "model:");
    if (c.name == "unknown start mode") line = yaml_line(dir, "mode:");
    if (c.name == "NaN in yaml") line = yaml_line(dir, "start_time_s:");
    c.apply(dir);
    if (c.name == "unknown yaml key") line = yaml_line(dir, "colour:");
    if (c.name == "unknown nested yaml key") line = yaml_line(dir, "image_widht:");
    const std::string message = ReadError(dir);
    ASSERT_NE(message, "") << "no error";
    EXPECT_THAT(message, HasSubstr(c.file));
    if (!line.empty()) {
      EXPECT_THAT(message, HasSubstr(c.file + line));
    }
    EXPECT_THAT(message, HasSubstr(c.what));
    // ValidateLog reports the same problem.
    try {
      ValidateLog(dir);
      ADD_FAILURE() << "ValidateLog accepted the bad log";
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()), message);
    }
  }
}

// A fisheye session with a user mask round-trips through session.yaml (model, every
// calibration field, the mask image next to it).
TEST_F(LogTest, FisheyeSessionWithMaskRoundTrips) {
  SessionInfo info = RingSession();
  FisheyeCalibration f;
  f.center_x_px = 20.25;
  f.center_y_px = 19.5;
  f.circle_radius_px = 19.0;
  f.field_of_view_deg = 235.0;
  f.projection = FisheyeProjection::kEquisolid;
  f.min_elevation_deg = -27.5;
  f.max_elevation_deg = 80.0;
  f.azimuth0_rad = 0.25;
  f.panorama_width = kPanoWidth;
  f.panorama_height = kPanoHeight;
  info.camera.calibration = f;
  info.camera.mask = cv::Mat(kRingSize, kRingSize, CV_8UC1, cv::Scalar(255));
  info.camera.mask(cv::Rect(0, 0, 10, 5)).setTo(0);
  const std::string dir = Path("fisheye");
  {
    LogWriter writer(dir);
    writer.BeginSession(info);
    for (const Frame& frame : MakeFrames(info, 3)) writer.Write(frame);
    writer.Finish();
  }
  LogReader reader(dir);
  const SessionInfo& got = reader.Session(0);
  EXPECT_TRUE(got.camera.calibration == info.camera.calibration);
  EXPECT_EQ(got.camera.mask_image, "mask.png");
  ASSERT_EQ(got.camera.mask.size(), info.camera.mask.size());
  EXPECT_EQ(cv::countNonZero(got.camera.mask != info.camera.mask), 0);
}

TEST_F(LogTest, ReaderStreamsImagesLazily) {
  // Images are loaded only when their frame is reached: deleting a later image after
  // opening still lets the earlier frames be read, and the error comes at that frame.
  const std::string dir = Path("log");
  WriteTestLog(dir);
  LogReader reader(dir);
  fs::remove(dir + "/day_01/000003.png");
  Frame f;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(reader.Next(&f));
    EXPECT_EQ(f.index_in_session, i);
    EXPECT_FALSE(f.image.empty());
  }
  try {
    reader.Next(&f);
    FAIL() << "no error for the deleted image";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("day_01/frames.csv:5:"));
    EXPECT_THAT(e.what(), HasSubstr("000003.png"));
  }
}

TEST_F(LogTest, SkipUnreadableFramesCountsThem) {
  // With skip_unreadable_frames the bad frames are skipped, counted and explained; the
  // others arrive in order with dense indices.
  const std::string dir = Path("log");
  WriteTestLog(dir);
  fs::remove(dir + "/day_01/000002.png");
  WriteFile(dir + "/day_02/000000.png", "garbage");
  LogReader reader(dir, LogReaderOptions{.load_images = true, .skip_unreadable_frames = true});
  const std::vector<Frame> frames = ReadAll(reader);
  EXPECT_EQ(frames.size(), 2u * kFramesPerSession - 2);
  EXPECT_EQ(reader.NumSkippedFrames(), 2);
  ASSERT_EQ(reader.SkippedFrameMessages().size(), 2u);
  EXPECT_THAT(reader.SkippedFrameMessages()[0], HasSubstr("day_01/frames.csv:4:"));
  EXPECT_THAT(reader.SkippedFrameMessages()[1], HasSubstr("day_02/frames.csv:2:"));
  for (std::size_t i = 0; i < frames.size(); ++i)
    EXPECT_EQ(frames[i].global_index, static_cast<std::int64_t>(i));
}

TEST_F(LogTest, PoseOnlyReadingSkipsImages) {
  // load_images = false delivers poses without touching image files.
  const std::string dir = Path("log");
  WriteTestLog(dir);
  fs::remove(dir + "/day_02/000001.png");
  LogReader reader(dir, LogReaderOptions{.load_images = false});
  const std::vector<Frame> frames = ReadAll(reader);
  ASSERT_EQ(frames.size(), 2u * kFramesPerSession);
  for (const Frame& f : frames) EXPECT_TRUE(f.image.empty());
}

TEST_F(LogTest, OpensSingleSessionsAndSeveralLogs) {
  // A session directory reads as a one-session log; several logs concatenate in order.
  const std::string dir = Path("log");
  WriteTestLog(dir);
  LogReader single(dir + "/day_02");  // (the top-level README.txt is ignored by readers)
  ASSERT_EQ(single.NumSessions(), 1);
  EXPECT_EQ(single.Session(0).name, "day_02");
  EXPECT_EQ(ReadAll(single).size(), static_cast<std::size_t>(kFramesPerSession));

  LogReader several(std::vector<std::string>{dir + "/day_02", dir});
  ASSERT_EQ(several.NumSessions(), 3);
  EXPECT_EQ(several.Session(0).name, "day_02");
  EXPECT_EQ(several.Session(1).name, "day_01");
  EXPECT_EQ(several.Session(2).name, "day_02");
  const std::vector<Frame> frames = ReadAll(several);
  ASSERT_EQ(frames.size(), 3u * kFramesPerSession);
  EXPECT_EQ(frames.back().session_index, 2);
  EXPECT_EQ(frames.back().global_index, 3 * kFramesPerSession - 1);

  const LogSummary summary = ValidateLog(dir);
  ASSERT_EQ(summary.sessions.size(), 2u);
  EXPECT_EQ(summary.total_frames, 2 * kFramesPerSession);
  EXPECT_EQ(summary.sessions[0].frames_with_truth, kFramesPerSession / 2);
}

TEST_F(LogTest, WriterWithoutFinishLeavesNothing) {
  // A writer destroyed before Finish (a crash, an exception) leaves neither the log nor
  // its partial directory.
  const std::string dir = Path("log");
  std::string partial;
  {
    LogWriter writer(dir);
    partial = writer.partial_dir();
    writer.BeginSession(PanoramaSession());
    for (const Frame& f : MakeFrames(PanoramaSession(), 1)) writer.Write(f);
    EXPECT_TRUE(fs::exists(partial));
    EXPECT_FALSE(fs::exists(dir));
  }
  EXPECT_FALSE(fs::exists(dir));
  EXPECT_FALSE(fs::exists(partial));
  EXPECT_TRUE(fs::is_empty(root_));
}

TEST_F(LogTest, WriterRefusesExistingLogUnlessOverwriting) {
  // An existing log is never touched without overwrite; with it, the old log stays intact
  // until Finish swaps in the new one.
  const std::string dir = Path("log");
  WriteTestLog(dir);
  EXPECT_THROW(LogWriter{dir}, Error);
  LogWriter writer(dir, /*overwrite=*/true);
  SessionInfo info = PanoramaSession();
  info.name = "only";
  writer.BeginSession(info);
  writer.Write(MakeFrames(info, 5)[0]);
  EXPECT_EQ(LogReader(dir).NumSessions(), 2);  // old log still complete
  writer.Finish();
  LogReader reader(dir);
  ASSERT_EQ(reader.NumSessions(), 1);
  EXPECT_EQ(reader.Session(0).name, "only");
  EXPECT_EQ(ReadAll(reader).size(), 1u);
  EXPECT_FALSE(fs::exists(writer.partial_dir()));
}

TEST_F(LogTest, WriterRejectsBadFrames) {
  // The writer refuses what the reader would reject: non-increasing stamps, wrong image
  // size or type, frames before a session, sessions out of name order.
  LogWriter writer(Path("log"));
  std::vector<Frame> frames = MakeFrames(PanoramaSession(), 1);
  EXPECT_THROW(writer.Write(frames[0]), Error);
  writer.BeginSession(PanoramaSession());
  writer.Write(frames[1]);
  EXPECT_THROW(writer.Write(frames[0]), Error);  // earlier stamp
  Frame small = frames[2];
  small.image = cv::Mat(kPanoHeight, kPanoWidth - 1, CV_8UC3, cv::Scalar::all(0));
  EXPECT_THROW(writer.Write(small), Error);
  Frame wide = frames[2];
  wide.image.convertTo(wide.image, CV_16UC3);
  EXPECT_THROW(writer.Write(wide), Error);
  Frame nan = frames[2];
  nan.odom_T_robot.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(writer.Write(nan), Error);
  SessionInfo earlier = PanoramaSession();
  earlier.name = "day_00";
  EXPECT_THROW(writer.BeginSession(earlier), Error);
  writer.Write(frames[2]);
  writer.Finish();
  EXPECT_EQ(ValidateLog(Path("log")).total_frames, 2);
}

}  // namespace
}  // namespace omnicml
