// Video input (logs/video.h): frame references in frames.csv, sequential decoding,
// `import video`, and the one-line errors for bad videos, rows and limits.
#include "omnicml/logs/video.h"

#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/logs/log_format.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::AllOf;
using ::testing::HasSubstr;

constexpr int kWidth = 96;
constexpr int kHeight = 48;
constexpr int kFrames = 12;

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

// Smooth random colour frames (video codecs and the descriptors both like some structure).
std::vector<cv::Mat> MakeFrames(int n) {
  cv::RNG rng(5);
  std::vector<cv::Mat> frames;
  for (int i = 0; i < n; ++i) {
    cv::Mat small(kHeight / 4, kWidth / 4, CV_8UC3), frame;
    rng.fill(small, cv::RNG::UNIFORM, 0, 256);
    cv::resize(small, frame, cv::Size(kWidth, kHeight), 0, 0, cv::INTER_LINEAR);
    frames.push_back(frame);
  }
  return frames;
}

// Lossless FFV1 in AVI through OpenCV's FFmpeg backend.
void WriteVideo(const std::string& path, const std::vector<cv::Mat>& frames, double fps = 10.0) {
  cv::VideoWriter writer(path, cv::CAP_FFMPEG, cv::VideoWriter::fourcc('F', 'F', 'V', '1'), fps,
                         frames.front().size(), true);
  ASSERT_TRUE(writer.isOpened()) << "FFV1 encoder unavailable";
  for (const cv::Mat& f : frames) writer.write(f);
}

bool Equal(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0;
}

class VideoTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    root_ =
        fs::path(::testing::TempDir()) / StrCat("omnicml_video_", ::getpid(), "_", info->name());
    fs::remove_all(root_);
    fs::create_directories(root_);
    frames_ = MakeFrames(kFrames);
    video_ = Path("day1.avi");
    WriteVideo(video_, frames_);
  }
  void TearDown() override { fs::remove_all(root_); }
  std::string Path(const std::string& name) const { return (root_ / name).string(); }
  std::string WriteText(const std::string& name, const std::string& text) const {
    std::ofstream(Path(name)) << text;
    return Path(name);
  }

  fs::path root_;
  std::vector<cv::Mat> frames_;
  std::string video_;
};

// Only `<video file>#<decimal index>` is a video reference; image names stay image names.
TEST(VideoFrameRef, ParsesOnlyVideoNamesWithIndices) {
  const auto ref = ParseVideoFrameRef("day1.avi#17");
  ASSERT_TRUE(ref.has_value());
  EXPECT_EQ(ref->file, "day1.avi");
  EXPECT_EQ(ref->index, 17);
  EXPECT_EQ(FormatVideoFrameRef(*ref), "day1.avi#17");
  EXPECT_TRUE(ParseVideoFrameRef("sub/Cam.MKV#0").has_value());
  for (const char* not_video : {"000001.png", "a#1.png", "x.avi#", "x.avi#-1", "x.avi#1e3",
                                "x.avi# 3", ".avi#3", "x.avi#1234567890123456789", "x.avi"}) {
    EXPECT_FALSE(ParseVideoFrameRef(not_video).has_value()) << not_video;
  }
}

// Frames come back bit-exact from lossless FFV1; in-order reads never seek, a jump back
// seeks once, and an index past the end is a one-line error naming the file.
TEST_F(VideoTest, ReaderDecodesLosslessFramesSequentially) {
  VideoReader reader(video_);
  EXPECT_EQ(reader.width(), kWidth);
  EXPECT_EQ(reader.height(), kHeight);
  EXPECT_EQ(reader.frame_count(), kFrames);
  EXPECT_DOUBLE_EQ(reader.fps(), 10.0);
  for (int i = 0; i < kFrames; i += (i < 4 ? 1 : 3)) {
    EXPECT_TRUE(Equal(reader.Read(i), frames_[static_cast<std::size_t>(i)])) << "frame " << i;
  }
  EXPECT_EQ(reader.seeks(), 0);
  EXPECT_TRUE(Equal(reader.Read(2), frames_[2]));
  EXPECT_EQ(reader.seeks(), 1);
  EXPECT_TRUE(Equal(reader.Read(3), frames_[3]));
  EXPECT_EQ(reader.seeks(), 1);
  EXPECT_THAT(ErrorOf([&] { reader.Read(kFrames); }),
              AllOf(HasSubstr(video_), HasSubstr("12 frames")));
}

// A session whose frames.csv names video frames reads back the video's frames with the
// written poses; a reference past the video's end names frames.csv, its line and the video.
TEST_F(VideoTest, LogReaderTakesFramesFromAVideo) {
  SessionInfo info;
  info.name = "day_01";
  info.camera.kind = ImageKind::kPanorama;
  info.camera.image_width = kWidth;
  info.camera.image_height = kHeight;
  const std::vector<std::int64_t> indices = {0, 1, 2, 5, 6, 11};
  {
    LogWriter writer(Path("log"));
    writer.BeginSession(info);
    const std::string name = writer.AddSessionVideo(video_);
    EXPECT_EQ(name, "day1.avi");
    for (std::size_t k = 0; k < indices.size(); ++k) {
      Frame f;
      f.stamp_s = 0.1 * static_cast<double>(indices[k]);
      f.odom_T_robot = MakePose(0.5 * static_cast<double>(k), 0.0, 0.1);
      if (k % 2 == 0) f.map_T_robot_truth = f.odom_T_robot;
      writer.WriteVideoFrame(f, VideoFrameRef{name, indices[k]});
    }
    EXPECT_THAT(ErrorOf([&] {
                  writer.WriteVideoFrame(Frame{.stamp_s = 9}, {"other.avi", 0});
                }),
                HasSubstr("was not added"));
    writer.Finish();
  }
  EXPECT_TRUE(fs::exists(Path("log/day_01/day1.avi")));
  LogReader reader(Path("log"));
  Frame frame;
  for (std::size_t k = 0; k < indices.size(); ++k) {
    ASSERT_TRUE(reader.Next(&frame));
    EXPECT_TRUE(Equal(frame.image, frames_[static_cast<std::size_t>(indices[k])])) << "row " << k;
    EXPECT_DOUBLE_EQ(frame.odom_T_robot.x(), 0.5 * static_cast<double>(k));
    EXPECT_EQ(frame.map_T_robot_truth.has_value(), k % 2 == 0);
  }
  EXPECT_FALSE(reader.Next(&frame));
  EXPECT_EQ(ValidateLog(Path("log")).total_frames, static_cast<std::int64_t>(indices.size()));

  std::ofstream(Path("log/day_01/frames.csv"), std::ios::app) << "5,day1.avi#40,0,0,0,,,\n";
  const std::string csv = Path("log/day_01/frames.csv");
  EXPECT_THAT(ErrorOf([&] { ValidateLog(Path("log")); }),
              AllOf(HasSubstr(csv + ":8:"), HasSubstr("day1.avi"), HasSubstr("frame 40")));
}

// `import video`: frame-indexed rows with ground truth only get sampled odometry starting
// at the first truth; stamp rows with both groups keep their odometry; frames decode.
TEST_F(VideoTest, ImportVideoWritesALogFromPoses) {
  const std::string by_frame = WriteText(
      "frames.csv", "frame,gt_x_m,gt_y_m,gt_phi_rad\n0,1,2,0.5\n3,1.5,2,0.5\n7,2,2,0.4\n");
  VideoImportOptions options;
  options.start_time_s = 100.0;
  const VideoImportSummary s = ImportVideo(video_, by_frame, Path("a"), options);
  EXPECT_EQ(s.frames, 3);
  EXPECT_EQ(s.frames_with_truth, 3);
  EXPECT_TRUE(s.odometry_sampled);
  LogReader a(Path("a"));
  EXPECT_EQ(a.Session(0).name, "day1");
  EXPECT_EQ(a.Session(0).camera.kind, ImageKind::kPanorama);  // 96x48: twice as wide as high
  Frame f;
  ASSERT_TRUE(a.Next(&f));
  EXPECT_DOUBLE_EQ(f.stamp_s, 100.0);
  EXPECT_EQ(f.odom_T_robot, MakePose(1, 2, 0.5));
  EXPECT_TRUE(Equal(f.image, frames_[0]));
  ASSERT_TRUE(a.Next(&f));
  EXPECT_DOUBLE_EQ(f.stamp_s, 100.3);
  EXPECT_TRUE(Equal(f.image, frames_[3]));
  EXPECT_NE(f.odom_T_robot, *f.map_T_robot_truth);  // sampled with noise

  const std::string by_stamp =
      WriteText("stamps.csv",
                "stamp_s,odom_x_m,odom_y_m,odom_phi_rad,gt_x_m,gt_y_m,gt_phi_rad\n"
                "0.21,0,0,0,,,\n0.49,0.25,0,0,1,1,1\n");
  const VideoImportSummary t = ImportVideo(video_, by_stamp, Path("b"), VideoImportOptions{});
  EXPECT_FALSE(t.odometry_sampled);
  EXPECT_EQ(t.frames_with_truth, 1);
  LogReader b(Path("b"));
  ASSERT_TRUE(b.Next(&f));
  EXPECT_DOUBLE_EQ(f.stamp_s, 0.21);
  EXPECT_TRUE(Equal(f.image, frames_[2]));  // round(0.21 * 10)
  EXPECT_FALSE(f.map_T_robot_truth.has_value());
  ASSERT_TRUE(b.Next(&f));
  EXPECT_TRUE(Equal(f.image, frames_[5]));
  EXPECT_EQ(f.odom_T_robot, MakePose(0.25, 0, 0));
}

// Bad input: one-line errors naming the poses file and its line, or the video file.
TEST_F(VideoTest, ImportVideoErrorsNameFileAndRow) {
  const auto import = [&](const std::string& csv_text, const std::string& video) {
    const std::string csv = WriteText("p.csv", csv_text);
    fs::remove_all(Path("out"));
    return ErrorOf([&] { ImportVideo(video, csv, Path("out"), VideoImportOptions{}); });
  };
  const std::string csv = Path("p.csv");
  EXPECT_THAT(import("time,gt_x_m,gt_y_m,gt_phi_rad\n", video_),
              AllOf(HasSubstr(csv + ":1:"), HasSubstr("first column")));
  EXPECT_THAT(import("frame,gt_x_m,gt_y_m\n", video_),
              AllOf(HasSubstr(csv + ":1:"), HasSubstr("all three")));
  EXPECT_THAT(import("frame,gt_x_m,gt_y_m,gt_phi_rad\n2,0,0,0\n2,1,0,0\n", video_),
              AllOf(HasSubstr(csv + ":3:"), HasSubstr("does not follow")));
  EXPECT_THAT(import("frame,gt_x_m,gt_y_m,gt_phi_rad\n0,0,0,0\n12,1,0,0\n", video_),
              AllOf(HasSubstr(csv + ":3:"), HasSubstr("past the video's end")));
  EXPECT_THAT(import("frame,gt_x_m,gt_y_m,gt_phi_rad\n0,0,0,0\n1,,,\n", video_),
              AllOf(HasSubstr(csv + ":3:"), HasSubstr("no ground truth")));
  EXPECT_THAT(import("frame,odom_x_m,odom_y_m,odom_phi_rad\n1.5,0,0,0\n", video_),
              AllOf(HasSubstr(csv + ":2:"), HasSubstr("frame index")));
  const std::string garbage = WriteText("garbage.avi", std::string(5000, 'x'));
  EXPECT_THAT(import("frame,gt_x_m,gt_y_m,gt_phi_rad\n0,0,0,0\n", garbage),
              AllOf(HasSubstr(garbage), HasSubstr("cannot open video")));
  EXPECT_THAT(import("frame,gt_x_m,gt_y_m,gt_phi_rad\n0,0,0,0\n", Path("missing.avi")),
              HasSubstr(Path("missing.avi")));
  EXPECT_FALSE(fs::exists(Path("out")));
}

// A container that claims more frames than kMaxVideoFrames, or a frame larger than
// kMaxImagePixels, is refused before any frame is decoded.
TEST_F(VideoTest, RefusesHugeDeclaredFrameCountOrSize) {
  std::ifstream in(video_, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const auto patched = [&](const std::string& name, const char* chunk, std::size_t offset,
                           std::uint32_t value) {
    std::string b = bytes;
    const std::size_t at = b.find(chunk);
    EXPECT_NE(at, std::string::npos) << chunk;
    std::memcpy(&b[at + offset], &value, 4);  // AVI is little-endian, as is x86/ARM Linux
    std::ofstream(Path(name), std::ios::binary) << b;
    return Path(name);
  };
  // strh: fccType 'vids' then handler, flags, priority and language, initial frames,
  // scale, rate, start: dwLength at 'vids' + 32.
  const std::string long_video = patched("long.avi", "vids", 32, 0x7fffffffu);
  EXPECT_THAT(ErrorOf([&] { VideoReader r(long_video); }),
              AllOf(HasSubstr(long_video), HasSubstr("frames (at most")));
  // BITMAPINFOHEADER after 'strf' + size: biWidth at +12, biHeight at +16.
  const std::string wide = patched("wide.avi", "strf", 12, 3000000u);  // x 48 rows > 10^8
  const std::string error = ErrorOf([&] {
    VideoReader r(wide);
    r.Read(0);
  });
  EXPECT_THAT(error, HasSubstr(wide));
  EXPECT_EQ(error.find('\n'), std::string::npos);
}

}  // namespace
}  // namespace omnicml
