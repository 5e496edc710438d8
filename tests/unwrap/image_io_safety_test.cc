// Image and calibration input safety: only regular files, the declared size
// checked before decoding, and one-line errors without libpng printing its own line.
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;

fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::path(OMNICML_BINARY_DIR) / "test_output" / "image_io_safety" / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

void WriteBytes(const fs::path& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
}

// ReadImage's error for `path`, with what was printed on stderr meanwhile.
std::pair<std::string, std::string> ReadImageError(const fs::path& path) {
  std::string message;
  ::testing::internal::CaptureStderr();
  try {
    ReadImage(path.string());
  } catch (const Error& e) {
    message = e.what();
  }
  return {message, ::testing::internal::GetCapturedStderr()};
}

std::vector<std::uint8_t> Png(int width, int height) {
  std::vector<std::uint8_t> png;
  cv::imencode(".png", cv::Mat(height, width, CV_8UC3, cv::Scalar(1, 2, 3)), png);
  return png;
}

// A PNG or JPEG header declaring more than kMaxImagePixels is refused before decoding.
TEST(ImageIoSafety, DeclaredSizeCheckedBeforeDecoding) {
  const fs::path dir = FreshDir("huge");
  std::vector<std::uint8_t> png = Png(20, 10);
  // IHDR width and height (big endian, bytes 16..23): 20000 x 20000.
  for (int i : {16, 20}) {
    png[i] = 0;
    png[i + 1] = 0;
    png[i + 2] = 20000 >> 8;
    png[i + 3] = 20000 & 0xFF;
  }
  WriteBytes(dir / "huge.png", png);
  auto [message, err] = ReadImageError(dir / "huge.png");
  EXPECT_THAT(message, HasSubstr("huge.png"));
  EXPECT_THAT(message, HasSubstr("20000x20000"));
  EXPECT_EQ(err, "");

  std::vector<std::uint8_t> jpg;
  cv::imencode(".jpg", cv::Mat(10, 20, CV_8UC3, cv::Scalar(1, 2, 3)), jpg);
  // The SOF0 segment: FF C0, length, precision, height, width.
  for (std::size_t i = 2; i + 8 < jpg.size(); ++i) {
    if (jpg[i] == 0xFF && jpg[i + 1] == 0xC0) {
      jpg[i + 5] = 0xFF;  // height 65535
      jpg[i + 6] = 0xFF;
      jpg[i + 7] = 0xFF;  // width 65535
      jpg[i + 8] = 0xFF;
      break;
    }
  }
  WriteBytes(dir / "huge.jpg", jpg);
  std::tie(message, err) = ReadImageError(dir / "huge.jpg");
  EXPECT_THAT(message, HasSubstr("65535x65535"));
  EXPECT_EQ(err, "");
}

// Bytes that start like none of the supported formats are refused before decoding. A
// DICOM-shaped file (128-byte preamble, "DICM") used to reach OpenCV's GDCM decoder,
// which aborted the process on the fuzzer's input
// (fuzz/corpus/image/regression-dicm-preamble); a PGM still decodes (the signature check
// is OpenCV's own).
TEST(ImageIoSafety, UnknownSignatureIsRefusedBeforeDecoding) {
  const fs::path dir = FreshDir("signature");
  std::vector<std::uint8_t> dicom(128, 0);
  for (char c : std::string("DICM")) dicom.push_back(static_cast<std::uint8_t>(c));
  dicom.resize(dicom.size() + 64, 0xA1);
  WriteBytes(dir / "scan.dcm", dicom);
  std::vector<std::uint8_t> fuzzed(90, 0xA1);  // the fuzzer's input, shortened
  fuzzed[0] = 0x89;
  fuzzed[1] = 0x50;
  for (char c : std::string("NG\r\n\x1a")) fuzzed.push_back(static_cast<std::uint8_t>(c));
  fuzzed.resize(124, 0xE0);
  for (char c : std::string("DICM")) fuzzed.push_back(static_cast<std::uint8_t>(c));
  fuzzed.push_back(0x82);
  WriteBytes(dir / "fuzzed.png", fuzzed);
  for (const char* name : {"scan.dcm", "fuzzed.png"}) {
    SCOPED_TRACE(name);
    const auto [message, err] = ReadImageError(dir / name);
    EXPECT_THAT(message, HasSubstr(name));
    EXPECT_THAT(message, HasSubstr("unknown signature"));
    EXPECT_EQ(err, "");
  }
  std::vector<std::uint8_t> pgm;
  ASSERT_TRUE(cv::imencode(".pgm", cv::Mat(3, 4, CV_8UC1, cv::Scalar(7)), pgm));
  WriteBytes(dir / "grey.pgm", pgm);
  const cv::Mat grey = ReadImage((dir / "grey.pgm").string());
  EXPECT_EQ(grey.size(), cv::Size(4, 3));
  EXPECT_EQ(grey.at<std::uint8_t>(2, 3), 7);
}

// Truncated and corrupted PNG files give one line naming the file, and nothing from
// libpng on stderr.
TEST(ImageIoSafety, BrokenPngIsOneQuietLine) {
  const fs::path dir = FreshDir("broken");
  const std::vector<std::uint8_t> png = Png(64, 32);
  WriteBytes(dir / "truncated.png",
             std::vector<std::uint8_t>(png.begin(), png.begin() + png.size() / 2));
  std::vector<std::uint8_t> flipped = png;
  flipped[png.size() / 2] ^= 0x5A;
  WriteBytes(dir / "flipped.png", flipped);
  for (const char* name : {"truncated.png", "flipped.png"}) {
    SCOPED_TRACE(name);
    const auto [message, err] = ReadImageError(dir / name);
    EXPECT_THAT(message, HasSubstr(name));
    EXPECT_THAT(message, HasSubstr("unreadable"));
    EXPECT_EQ(message.find('\n'), std::string::npos);
    EXPECT_EQ(err, "");
  }
}

// FIFOs and devices are rejected without blocking, for images and calibration files.
TEST(ImageIoSafety, OnlyRegularFiles) {
  const fs::path dir = FreshDir("kinds");
  const fs::path fifo = dir / "frame.png";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_THAT(ReadImageError(fifo).first, HasSubstr("FIFO"));
  const fs::path zero = dir / "zero.png";
  fs::create_symlink("/dev/zero", zero);
  EXPECT_THAT(ReadImageError(zero).first, HasSubstr("character device"));
  const fs::path calib = dir / "calib.yaml";
  ASSERT_EQ(::mkfifo(calib.c_str(), 0600), 0);
  try {
    OmniCalibration::FromYamlFile(calib.string());
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("FIFO"));
  }
}

}  // namespace
}  // namespace omnicml
