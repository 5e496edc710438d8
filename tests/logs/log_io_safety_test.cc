// Input/output safety of logs: readers accept only regular files with bounded
// lines, and the writer's staging directory never outlives a failed or killed writer.
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/logs/antworld.h"
#include "omnicml/logs/log_format.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;

fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::path(OMNICML_BINARY_DIR) / "test_output" / "log_io_safety" / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

template <typename F>
std::string ErrorOf(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

pid_t DeadPid() {
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  int status = 0;
  ::waitpid(child, &status, 0);
  return child;
}

SessionInfo Session(const std::string& name) {
  SessionInfo info;
  info.name = name;
  info.camera.kind = ImageKind::kPanorama;
  info.camera.image_width = 16;
  info.camera.image_height = 4;
  info.start.mode = SessionStartMode::kKnownPose;
  info.start.map_T_robot = MakePose(0.0, 0.0, 0.0);
  info.start.covariance = Eigen::Vector3d(0.01, 0.01, 0.01).asDiagonal();
  return info;
}

Frame MakeFrame(double stamp_s) {
  Frame f;
  f.stamp_s = stamp_s;
  f.image = cv::Mat(4, 16, CV_8UC3, cv::Scalar(10, 20, 30));
  f.odom_T_robot = MakePose(stamp_s, 0.0, 0.0);
  return f;
}

// A small valid log at `dir`.
void WriteLog(const fs::path& dir) {
  LogWriter writer(dir.string(), /*overwrite=*/true);
  writer.BeginSession(Session("day_01"));
  for (int i = 0; i < 3; ++i) writer.Write(MakeFrame(1.0 + i));
  writer.Finish();
}

// Everything below `dir` whose name marks a temporary of an atomic write or a staging
// directory.
std::vector<std::string> Leftovers(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (IsAtomicTempName(name) || name.find(".partial-") != std::string::npos ||
        name.find(".old-") != std::string::npos) {
      out.push_back(e.path().string());
    }
  }
  return out;
}

// A frames.csv that is a FIFO, a link to /dev/zero or a directory is an Error naming
// it (apps: exit 2), immediately; the reader never blocks on the FIFO.
TEST(LogIoSafety, FramesCsvMustBeARegularFile) {
  const fs::path root = FreshDir("frames_kind");
  const fs::path good = root / "good";
  WriteLog(good);
  ASSERT_EQ(ValidateLog(good.string()).total_frames, 3);
  const struct {
    const char* name;
    const char* reason;
  } cases[] = {{"fifo", "FIFO"}, {"zero", "character device"}, {"dir", "directory"}};
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path log = root / c.name;
    fs::copy(good, log, fs::copy_options::recursive);
    const fs::path csv = log / "day_01" / "frames.csv";
    fs::remove(csv);
    if (std::string(c.name) == "fifo") ASSERT_EQ(::mkfifo(csv.c_str(), 0600), 0);
    if (std::string(c.name) == "zero") fs::create_symlink("/dev/zero", csv);
    if (std::string(c.name) == "dir") fs::create_directory(csv);
    const std::string message = ErrorOf([&] { LogReader reader(log.string()); });
    EXPECT_THAT(message, HasSubstr(csv.string()));
    EXPECT_THAT(message, HasSubstr(c.reason));
    EXPECT_EQ(message.find('\n'), std::string::npos);
  }
  // session.yaml as a FIFO: the same.
  const fs::path log = root / "yaml_fifo";
  fs::copy(good, log, fs::copy_options::recursive);
  const fs::path yaml = log / "day_01" / "session.yaml";
  fs::remove(yaml);
  ASSERT_EQ(::mkfifo(yaml.c_str(), 0600), 0);
  EXPECT_THAT(ErrorOf([&] { LogReader reader(log.string()); }), HasSubstr("FIFO"));
}

// Replaces the image name of the first row of `csv` by `image`.
void SetFirstImage(const fs::path& csv, const std::string& image) {
  std::ifstream in(csv);
  std::string header, row, rest((std::istreambuf_iterator<char>(in)), {});
  std::istringstream lines(rest);
  std::getline(lines, header);
  std::getline(lines, row);
  std::string tail((std::istreambuf_iterator<char>(lines)), {});
  const std::size_t a = row.find(','), b = row.find(',', a + 1);
  row = row.substr(0, a + 1) + image + row.substr(b);
  in.close();
  std::ofstream(csv, std::ios::trunc) << header << "\n" << row << "\n" << tail;
}

// The message of reading every frame of `log` ("" when all frames load).
std::string ReadAllFrames(const fs::path& log, LogReaderOptions options = {}) {
  return ErrorOf([&] {
    LogReader reader(log.string(), options);
    Frame frame;
    while (reader.Next(&frame)) {
    }
  });
}

// frames.csv may name only images inside its log: an absolute name, one climbing out
// with "..", or a link leading out is refused, with the same message whether or not the
// outside file exists; names into a sibling session are fine; the opt-in (the option or
// the process-wide switch) reads outside images.
TEST(LogIoSafety, ImagesOutsideTheLogAreRefusedUnlessAllowed) {
  const fs::path root = FreshDir("confined");
  const fs::path good = root / "good";
  WriteLog(good);
  const fs::path day = good / "day_01";
  std::string first_image;
  {
    std::ifstream in(day / "frames.csv");
    std::string header, row;
    std::getline(in, header);
    std::getline(in, row);
    const std::size_t a = row.find(','), b = row.find(',', a + 1);
    first_image = row.substr(a + 1, b - a - 1);
  }
  fs::create_directories(root / "outside");
  fs::copy_file(day / first_image, root / "outside" / "present.png");
  const fs::path log = root / "log";
  // Pairs of names: one whose outside target exists, one whose target does not.
  const std::vector<std::pair<std::string, std::string>> names = {
      {(root / "outside" / "present.png").string(), (root / "outside" / "absent.png").string()},
      {"../../outside/present.png", "../../outside/absent.png"},
      {"./../day_01/../../outside/present.png", "./../day_01/../../outside/absent.png"},
      {"link_present.png", "link_absent.png"},
      {"dirlink/present.png", "dirlink/absent.png"},
  };
  for (const auto& [present, absent] : names) {
    std::string messages[2];
    for (int k = 0; k < 2; ++k) {
      fs::remove_all(log);
      fs::copy(good, log, fs::copy_options::recursive);
      fs::create_symlink(root / "outside" / "present.png", log / "day_01" / "link_present.png");
      fs::create_symlink(root / "outside" / "absent.png", log / "day_01" / "link_absent.png");
      fs::create_directory_symlink(root / "outside", log / "day_01" / "dirlink");
      const std::string name = k == 0 ? present : absent;
      SetFirstImage(log / "day_01" / "frames.csv", name);
      std::string message = ReadAllFrames(log);
      EXPECT_THAT(message, HasSubstr("lies outside the log directory")) << name;
      EXPECT_THAT(message, HasSubstr((log / "day_01" / "frames.csv").string() + ":2: ")) << name;
      EXPECT_EQ(message.find('\n'), std::string::npos) << message;
      for (const std::string word : {"present", "absent"}) {
        for (std::size_t at; (at = message.find(word)) != std::string::npos;) {
          message.replace(at, word.size(), "X");
        }
      }
      messages[k] = message;
      // The opt-in reads the existing one and reports the missing one as missing.
      LogReaderOptions allow;
      allow.allow_images_outside_log = true;
      const std::string allowed = ReadAllFrames(log, allow);
      if (k == 0) {
        EXPECT_EQ(allowed, "") << name;
      } else {
        EXPECT_THAT(allowed, HasSubstr("absent.png")) << name;
      }
      SetAllowImagesOutsideLog(true);
      EXPECT_EQ(ReadAllFrames(log), allowed) << name;
      SetAllowImagesOutsideLog(false);
    }
    EXPECT_EQ(messages[0], messages[1]) << "the message tells whether " << present << " exists";
  }
  // Inside the log: a sibling session's image, and a link within the log.
  fs::remove_all(log);
  fs::create_directories(log);
  fs::copy(day, log / "day_01", fs::copy_options::recursive);
  fs::copy(day, log / "day_02", fs::copy_options::recursive);
  SetFirstImage(log / "day_02" / "frames.csv", "../day_01/" + first_image);
  fs::create_symlink(first_image, log / "day_01" / "inner_link.png");
  SetFirstImage(log / "day_01" / "frames.csv", "inner_link.png");
  EXPECT_EQ(ReadAllFrames(log), "");
  // A log given through a symbolic link to it reads the same.
  fs::create_directory_symlink(log, root / "log_link");
  EXPECT_EQ(ReadAllFrames(root / "log_link"), "");
}

// An overlong frames.csv line is an error with file and line number and a short
// message, not an unbounded allocation; a bad value is quoted cut to 80 characters.
TEST(LogIoSafety, OverlongLineAndLongValueAreShortErrors) {
  const fs::path root = FreshDir("long_line");
  const fs::path log = root / "log";
  WriteLog(log);
  const fs::path csv = log / "day_01" / "frames.csv";
  {
    std::ofstream out(csv, std::ios::app | std::ios::binary);
    out << std::string(100000, '7') << "\n";
  }
  LogReader reader(log.string());
  Frame frame;
  std::string message;
  try {
    while (reader.Next(&frame)) {
    }
  } catch (const Error& e) {
    message = e.what();
  }
  EXPECT_THAT(message, HasSubstr(csv.string() + ":5:"));
  EXPECT_THAT(message, HasSubstr("longer than"));
  EXPECT_LT(message.size(), 400u);

  const fs::path log2 = root / "log2";
  WriteLog(log2);
  {
    std::ofstream out(log2 / "day_01" / "frames.csv", std::ios::app | std::ios::binary);
    out << "4.0,000000.png," << std::string(5000, 'x') << ",0,0,,,\n";
  }
  LogReader reader2(log2.string());
  message.clear();
  try {
    while (reader2.Next(&frame)) {
    }
  } catch (const Error& e) {
    message = e.what();
  }
  EXPECT_THAT(message, HasSubstr(":5:"));
  EXPECT_LT(message.size(), 400u);
}

// A writer that fails (an exception between BeginSession and Finish) leaves neither
// staging directory nor temporary files; the target is not created.
TEST(LogIoSafety, FailedWriterLeavesNothing) {
  const fs::path root = FreshDir("failed");
  const fs::path log = root / "log";
  try {
    LogWriter writer(log.string());
    writer.BeginSession(Session("day_01"));
    writer.Write(MakeFrame(1.0));
    writer.Write(MakeFrame(0.5));  // stamp does not increase: throws
    FAIL() << "no exception";
  } catch (const Error&) {
  }
  EXPECT_FALSE(fs::exists(log));
  EXPECT_TRUE(fs::is_empty(root));
}

// The staging directory of a writer killed with SIGKILL (a dead pid) is removed by the
// next writer of the same log; staging directories of other logs are left alone.
TEST(LogIoSafety, KilledWriterLeftoverRemovedByNextWriter) {
  const fs::path root = FreshDir("killed");
  const fs::path log = root / "log";
  const pid_t dead = DeadPid();
  const fs::path leftover = StagingDirFor(log, dead);
  fs::create_directories(leftover / "day_01");
  std::ofstream(leftover / "day_01" / "frames.csv") << "half";
  const fs::path other = StagingDirFor(root / "other_log", dead);
  fs::create_directories(other);

  // A real kill -9: a child writes a session and dies before Finish().
  const pid_t child = ::fork();
  if (child == 0) {
    LogWriter writer(log.string());
    writer.BeginSession(Session("day_01"));
    writer.Write(MakeFrame(1.0));
    ::kill(::getpid(), SIGKILL);
    ::_exit(1);
  }
  int status = 0;
  ::waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status));
  EXPECT_TRUE(fs::exists(StagingDirFor(log, child)));

  WriteLog(log);
  EXPECT_FALSE(fs::exists(leftover));
  EXPECT_FALSE(fs::exists(StagingDirFor(log, child)));
  EXPECT_TRUE(fs::exists(other));
  fs::remove_all(other);
  EXPECT_THAT(Leftovers(root), ::testing::IsEmpty());
  EXPECT_EQ(ValidateLog(log.string()).total_frames, 3);
}

// A temporary file of an atomic write left inside a session directory (a killed run)
// is never read as data: the log still validates.
TEST(LogIoSafety, ReadersIgnoreTemporaries) {
  const fs::path root = FreshDir("temps");
  const fs::path log = root / "log";
  WriteLog(log);
  std::ofstream(TempPathFor(log / "day_01" / "frames.csv", DeadPid(), 0)) << "garbage";
  std::ofstream(TempPathFor(log / "notes.txt", DeadPid(), 0)) << "garbage";
  EXPECT_EQ(ValidateLog(log.string()).total_frames, 3);
}

// The AntWorld route CSV: a FIFO is an error, not a hang; an overlong line is reported
// with its number.
TEST(LogIoSafety, AntWorldCsvBounded) {
  const fs::path root = FreshDir("antworld");
  const fs::path fifo = root / "route.csv";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_THAT(ErrorOf([&] { ReadAntWorldCsv(fifo.string()); }), HasSubstr("FIFO"));
  fs::remove(fifo);
  std::ofstream(fifo) << "X [mm], Y [mm], Z [mm], Heading [degrees], Filename\n"
                      << std::string(70000, '1') << "\n";
  const std::string message = ErrorOf([&] { ReadAntWorldCsv(fifo.string()); });
  EXPECT_THAT(message, HasSubstr("route.csv:2:"));
  EXPECT_THAT(message, HasSubstr("longer than"));
}

}  // namespace
}  // namespace omnicml
