// Fuzzes the frames.csv rows of a log session (logs/log_format.h LogReader): a fixed,
// valid session.yaml (panorama 8x4) and two valid images 000000.png (BGR) and
// 000001.png (grey) beside the fuzzed frames.csv. The first input byte picks the reader
// options (load images, skip unreadable frames); the rest is frames.csv.
#include <opencv2/core.hpp>

#include "fuzz_util.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace {

const std::filesystem::path& SessionDir() {
  static const std::filesystem::path dir = [] {
    const auto d = omnicml::fuzz::ScratchDir() / "session";
    std::filesystem::create_directories(d);
    omnicml::SessionInfo info;
    info.day_label = "fuzz";
    info.camera.image_width = 8;
    info.camera.image_height = 4;
    omnicml::fuzz::WriteText(d / "session.yaml", omnicml::SessionYamlText(info));
    omnicml::WriteImage((d / "000000.png").string(), cv::Mat(4, 8, CV_8UC3, cv::Scalar(1, 2, 3)));
    omnicml::WriteImage((d / "000001.png").string(), cv::Mat(4, 8, CV_8UC1, cv::Scalar(7)));
    return d;
  }();
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const auto& dir = SessionDir();
  omnicml::fuzz::WriteBytes(dir / "frames.csv", data + 1, size - 1);
  omnicml::LogReaderOptions options;
  options.load_images = (data[0] & 1) != 0;
  options.skip_unreadable_frames = (data[0] & 2) != 0;
  return omnicml::fuzz::ExpectOnlyErrors([&] {
    omnicml::LogReader reader(dir.string(), options);
    omnicml::Frame frame;
    for (int i = 0; i < 100000 && reader.Next(&frame); ++i) {
    }
  });
}
