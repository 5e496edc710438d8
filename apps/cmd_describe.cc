// `omnicml describe IMAGE... [--descriptor fourier|ifh|color] [--config ENGINE.yaml]
//                  [--unwrap CALIB.yaml | --auto-calibrate | --panorama] [--json]`:
// computes the descriptor of each image (panoramas by default; raw ring images are
// unwrapped first with --unwrap or --auto-calibrate) and prints each image's size and
// descriptor length, then for every pair (A, B) the distance E and the relative heading
// heading(B) - heading(A) in degrees ("n/a" for the histograms, which carry no rotation).
// With --config, the descriptor options (kind and per-kind settings, e.g.
// descriptor.fourier.normalize_columns) come from an engine configuration file, the same
// YAML `omnicml run --config` reads; --descriptor overrides its kind.
//
// `omnicml describe --make-sample DIR [--seed N]` writes a procedural 720x120 colour
// panorama and a copy rolled by 90 columns (= the robot turned 45 degrees
// counter-clockwise) into DIR, so that `omnicml describe DIR/sample_panorama.png
// DIR/sample_panorama_rolled.png` shows a heading of about +45 degrees between them.
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/run/run_config.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml::app {
namespace {

constexpr int kSampleWidth = 720;
constexpr int kSampleHeight = 120;
constexpr int kSampleRollColumns = 90;  // 90 * 360 / 720 = 45 degrees

struct DescribeArgs {
  std::vector<std::string> images;
  std::string descriptor;  // empty: the configuration's kind, else fourier
  std::string config;
  std::string calibration;
  bool auto_calibrate = false;
  bool panorama = false;
  bool json = false;
  std::string make_sample;
  std::uint32_t seed = 1;
};

void MakeSample(const DescribeArgs& args) {
  const std::filesystem::path dir(args.make_sample);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec)
    throw Error(StrCat("describe --make-sample: cannot create directory ", dir.string(), ": ",
                       ec.message()));
  const cv::Mat pano = MakeSyntheticPanorama(kSampleWidth, kSampleHeight, args.seed);
  const std::string a = (dir / "sample_panorama.png").string();
  const std::string b = (dir / "sample_panorama_rolled.png").string();
  WriteImage(a, pano);
  WriteImage(b, RollColumns(pano, kSampleRollColumns));
  std::cout << "wrote " << a << " (" << kSampleWidth << "x" << kSampleHeight << ", seed "
            << args.seed << ")\nwrote " << b << " (rolled by " << kSampleRollColumns
            << " columns: the robot turned " << 360.0 * kSampleRollColumns / kSampleWidth
            << " degrees counter-clockwise)\n"
            << "try: omnicml describe " << a << " " << b << "\n";
}

// Reads one input and returns the panorama to describe.
cv::Mat LoadPanorama(const std::string& path, const DescribeArgs& args,
                     std::map<std::pair<int, int>, std::unique_ptr<OmniUnwrapper>>& unwrappers,
                     const std::optional<CameraCalibration>& calibration) {
  const cv::Mat image = ReadImage(path);
  try {
    if (calibration) {
      auto& unwrapper = unwrappers[{image.cols, image.rows}];
      if (!unwrapper)
        unwrapper = std::make_unique<OmniUnwrapper>(*calibration, image.cols, image.rows);
      return unwrapper->Unwrap(image);
    }
    if (args.auto_calibrate) {
      const AutoCalibrationResult result = AutoCalibrate(image);
      return OmniUnwrapper(result.calibration, image.cols, image.rows).Unwrap(image);
    }
    return PreparePanorama(image);
  } catch (const Error& e) {
    throw Error(StrCat(path, ": ", e.what()));
  }
}

std::string FormatDouble(double v, int precision) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(precision) << v;
  return os.str();
}

void RunDescribe(const DescribeArgs& args) {
  if (!args.make_sample.empty()) {
    if (!args.images.empty()) throw Error("describe: --make-sample DIR takes no IMAGE arguments");
    MakeSample(args);
    return;
  }
  if (args.images.empty()) throw Error("describe: give at least one IMAGE (or --make-sample DIR)");
  if (static_cast<int>(!args.calibration.empty()) + args.auto_calibrate + args.panorama > 1) {
    throw Error("describe: give at most one of --unwrap CALIB.yaml, --auto-calibrate, --panorama");
  }
  DescriptorOptions options;
  if (!args.config.empty()) options = LoadEngineOptionsYaml(args.config).descriptor;
  if (!args.descriptor.empty()) options.kind = DescriptorKindFromString(args.descriptor);
  const std::unique_ptr<DescriptorExtractor> extractor = MakeDescriptorExtractor(options);
  std::optional<CameraCalibration> calibration;
  if (!args.calibration.empty()) calibration = CameraCalibration::FromYamlFile(args.calibration);

  std::map<std::pair<int, int>, std::unique_ptr<OmniUnwrapper>> unwrappers;
  std::vector<Descriptor> descriptors;
  std::vector<cv::Size> sizes;
  for (const auto& path : args.images) {
    const cv::Mat pano = LoadPanorama(path, args, unwrappers, calibration);
    try {
      descriptors.push_back(extractor->Compute(pano));
    } catch (const Error& e) {
      throw Error(StrCat(path, ": ", e.what()));
    }
    sizes.push_back(pano.size());
  }

  struct Pair {
    std::size_t a, b;
    double distance;
    std::optional<double> heading_deg;
  };
  std::vector<Pair> pairs;
  for (std::size_t i = 0; i < descriptors.size(); ++i) {
    for (std::size_t j = i + 1; j < descriptors.size(); ++j) {
      Pair p{i, j, extractor->Distance(descriptors[i], descriptors[j]), std::nullopt};
      if (extractor->ProvidesHeading() &&
          descriptors[i].panorama_width == descriptors[j].panorama_width) {
        // heading(B) - heading(A): how far the robot turned from image A to image B.
        if (const auto h = extractor->RelativeHeading(descriptors[j], descriptors[i])) {
          p.heading_deg = *h * 180.0 / kPi;
        }
      }
      pairs.push_back(p);
    }
  }

  if (args.json) {
    nlohmann::json out;
    out["descriptor"] = ToString(options.kind);
    out["feature_size"] = extractor->FeatureSize();
    out["images"] = nlohmann::json::array();
    for (std::size_t i = 0; i < descriptors.size(); ++i) {
      out["images"].push_back({{"index", i},
                               {"path", args.images[i]},
                               {"width", sizes[i].width},
                               {"height", sizes[i].height},
                               {"descriptor_size", descriptors[i].features.size()}});
    }
    out["pairs"] = nlohmann::json::array();
    for (const auto& p : pairs) {
      nlohmann::json j = {{"a", p.a}, {"b", p.b}, {"distance", p.distance}};
      j["relative_heading_deg"] =
          p.heading_deg ? nlohmann::json(*p.heading_deg) : nlohmann::json(nullptr);
      out["pairs"].push_back(j);
    }
    std::cout << out.dump(2) << "\n";
    return;
  }
  std::cout << "descriptor: " << ToString(options.kind) << " (" << extractor->FeatureSize()
            << " floats)\n";
  std::cout << std::left << std::setw(4) << "#" << std::setw(12) << "panorama" << std::setw(12)
            << "descriptor"
            << "image\n";
  for (std::size_t i = 0; i < descriptors.size(); ++i) {
    std::cout << std::setw(4) << i << std::setw(12) << StrCat(sizes[i].width, "x", sizes[i].height)
              << std::setw(12) << descriptors[i].features.size() << args.images[i] << "\n";
  }
  if (pairs.empty()) return;
  std::cout << "\n"
            << std::right << std::setw(4) << "A" << std::setw(4) << "B" << std::setw(14)
            << "distance" << std::setw(22) << "heading B-A (deg)"
            << "\n";
  for (const auto& p : pairs) {
    std::cout << std::setw(4) << p.a << std::setw(4) << p.b << std::setw(14)
              << FormatDouble(p.distance, 6) << std::setw(22)
              << (p.heading_deg ? FormatDouble(*p.heading_deg, 2) : std::string("n/a")) << "\n";
  }
}

const CommandRegistration kRegistration{
    "describe", [](CLI::App& app) {
      auto args = std::make_shared<DescribeArgs>();
      CLI::App* cmd = app.add_subcommand(
          "describe",
          "Describe panoramas: sizes, pairwise descriptor distances and relative headings");
      cmd->add_option("images", args->images,
                      "Image files (panoramas, or raw ring images with --unwrap/--auto-calibrate)");
      cmd->add_option(
             "--descriptor", args->descriptor,
             "Descriptor: fourier, ifh or color (default: the --config kind, else fourier)")
          ->check(CLI::IsMember({"fourier", "ifh", "color"}));
      cmd->add_option(
             "--config", args->config,
             "Engine configuration YAML whose descriptor section sets the descriptor options")
          ->check(CLI::ExistingFile);
      auto* unwrap =
          cmd->add_option("--unwrap", args->calibration,
                          "Unwrap raw camera images (any camera model) with this calibration YAML");
      auto* autocal = cmd->add_flag("--auto-calibrate", args->auto_calibrate,
                                    "Unwrap raw ring images, estimating each ring's calibration");
      auto* pano =
          cmd->add_flag("--panorama", args->panorama, "Inputs are panoramas (the default)");
      unwrap->excludes(autocal)->excludes(pano);
      autocal->excludes(pano);
      cmd->add_flag("--json", args->json, "Print JSON instead of a table");
      AddOutputDirectory(
          cmd, "--make-sample", &args->make_sample,
          "Write a synthetic panorama and a copy rolled by 45 degrees into this directory");
      cmd->add_option("--seed", args->seed, "Seed of the --make-sample panorama");
      cmd->callback([args] { RunDescribe(*args); });
    }};

}  // namespace
}  // namespace omnicml::app
