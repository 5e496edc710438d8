// Writes the generated seeds of the fuzz corpora (fuzz/README.md): a small engine file
// (a short simulated home_store run) for fuzz_engine_file, images for fuzz_image, the
// default engine configuration for fuzz_engine_config and session.yaml files.
//   make_seeds CORPUS_DIR      (CORPUS_DIR/<harness>/ must exist)
// Deterministic: the same build writes the same bytes.
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "omnicml/common/options.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sim/simulator.h"

namespace {

void Write(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
  if (!out) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    std::exit(1);
  }
}

void Write(const std::string& path, const std::string& text) {
  Write(path, std::vector<std::uint8_t>(text.begin(), text.end()));
}

std::vector<std::uint8_t> Encode(const std::string& ext, const cv::Mat& image,
                                 const std::vector<int>& params = {}) {
  std::vector<std::uint8_t> bytes;
  if (!cv::imencode(ext, image, bytes, params)) std::exit(1);
  return bytes;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_seeds CORPUS_DIR\n");
    return 2;
  }
  const std::string dir = argv[1];

  // Engine: 12 frames of home_store, small panoramas, so the map holds a few views.
  omnicml::SimulatorOptions sim_options;
  sim_options.frames_per_day = 12;
  sim_options.output = omnicml::ImageKind::kPanorama;
  sim_options.people = false;
  omnicml::SimulatedFrameSource sim(sim_options);
  omnicml::CmlEngineOptions options;
  options.panorama_width = 64;
  options.panorama_height = 16;
  options.update_delay_frames = 2;
  omnicml::CmlEngine engine(options);
  engine.BeginSession(sim.Session(0));
  omnicml::Frame frame;
  while (sim.Next(&frame)) engine.ProcessFrame(frame);
  engine.Finish();
  const std::vector<std::uint8_t> file = omnicml::EncodeEngine(engine);
  std::vector<std::uint8_t> whole{0};
  whole.insert(whole.end(), file.begin(), file.end());
  Write(dir + "/engine_file/seed_file", whole);
  constexpr std::size_t kHeader = 8 + 4 + 8, kTrailer = 4;
  std::vector<std::uint8_t> payload{1};
  payload.insert(payload.end(), file.begin() + kHeader, file.end() - kTrailer);
  Write(dir + "/engine_file/seed_payload", payload);
  std::vector<std::uint8_t> empty_payload{1};
  {
    omnicml::CmlEngine fresh(omnicml::CmlEngineOptions{});
    const auto f = omnicml::EncodeEngine(fresh);
    empty_payload.insert(empty_payload.end(), f.begin() + kHeader, f.end() - kTrailer);
  }
  Write(dir + "/engine_file/seed_payload_empty", empty_payload);

  // Images: the shapes and encodings ReadImage accepts, small.
  cv::Mat bgr(6, 16, CV_8UC3);
  cv::randu(bgr, 0, 255);
  cv::Mat grey(6, 16, CV_8UC1);
  cv::randu(grey, 0, 255);
  cv::Mat bgra(4, 8, CV_8UC4, cv::Scalar(1, 2, 3, 4));
  cv::Mat grey16(4, 8, CV_16UC1, cv::Scalar(40000));
  Write(dir + "/image/png_bgr", Encode(".png", bgr));
  Write(dir + "/image/png_grey", Encode(".png", grey));
  Write(dir + "/image/png_bgra", Encode(".png", bgra));
  Write(dir + "/image/png_grey16", Encode(".png", grey16));
  Write(dir + "/image/jpeg_bgr", Encode(".jpg", bgr, {cv::IMWRITE_JPEG_QUALITY, 50}));
  Write(dir + "/image/jpeg_grey", Encode(".jpg", grey, {cv::IMWRITE_JPEG_QUALITY, 50}));
  Write(dir + "/image/pgm_grey", Encode(".pgm", grey));

  // Engine configuration: the full default configuration (what RUNDIR/config.yaml holds).
  Write(dir + "/engine_config/default.yaml", omnicml::OptionsToYaml(options));

  // session.yaml: a panorama session and a raw-ring session of the simulator.
  Write(dir + "/session_yaml/panorama.yaml", omnicml::SessionYamlText(sim.Session(0)));
  omnicml::SimulatorOptions ring_options = sim_options;
  ring_options.output = omnicml::ImageKind::kRawRing;
  ring_options.days = 2;
  omnicml::SimulatedFrameSource ring(ring_options);
  Write(dir + "/session_yaml/ring.yaml", omnicml::SessionYamlText(ring.Session(1)));
  return 0;
}
