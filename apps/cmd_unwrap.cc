// `omnicml unwrap RAW --out PANO.png (--calibration CALIB.yaml | --auto-calibrate)
//   [--width W --height H] [--save-calibration FILE.yaml]`:
// unwraps a raw catadioptric ring image into a cylindrical panorama. With
// --auto-calibrate the ring's centre and radii are estimated from RAW itself and printed
// with the fit residuals; --save-calibration stores the calibration used.
#include <iomanip>
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml::app {
namespace {

struct UnwrapArgs {
  std::string raw;
  std::string out;
  std::string calibration;
  bool auto_calibrate = false;
  int width = 0;
  int height = 0;
  std::string save_calibration;
};

void PrintCalibration(const OmniCalibration& c) {
  std::cout << std::fixed << std::setprecision(3) << "  center_px: (" << c.center_x_px << ", "
            << c.center_y_px << ")\n"
            << "  inner_radius_px: " << c.inner_radius_px << "\n"
            << "  outer_radius_px: " << c.outer_radius_px << "\n"
            << "  azimuth0_rad: " << c.azimuth0_rad << "\n"
            << "  direction: "
            << (c.direction == RingDirection::kCounterClockwise ? "counter_clockwise" : "clockwise")
            << "\n"
            << "  elevation: "
            << (c.elevation == ElevationMapping::kLinear ? "linear" : "linear_inverted") << "\n"
            << "  panorama: " << c.panorama_width << "x" << c.panorama_height << "\n";
  std::cout.unsetf(std::ios::floatfield);
}

void RunUnwrap(const UnwrapArgs& args) {
  if (args.calibration.empty() == !args.auto_calibrate) {
    throw Error("unwrap: give exactly one of --calibration CALIB.yaml or --auto-calibrate");
  }
  if ((args.width > 0) != (args.height > 0) || args.width < 0 || args.height < 0) {
    throw Error(StrCat("unwrap: --width and --height must both be positive (got ", args.width,
                       " and ", args.height, ")"));
  }
  const cv::Mat raw = ReadImage(args.raw);
  OmniCalibration calibration;
  if (!args.calibration.empty()) calibration = OmniCalibration::FromYamlFile(args.calibration);
  if (args.width > 0) {
    calibration.panorama_width = args.width;
    calibration.panorama_height = args.height;
  }
  if (args.auto_calibrate) {
    AutoCalibrationResult result;
    try {
      result = AutoCalibrate(raw, calibration);
    } catch (const Error& e) {
      throw Error(StrCat(args.raw, ": ", e.what()));
    }
    calibration = result.calibration;
    std::cout << "auto-calibration of " << args.raw << " (" << raw.cols << "x" << raw.rows
              << "):\n";
    PrintCalibration(calibration);
    std::cout << std::setprecision(3) << std::fixed << "  inner circle: " << result.inner_inliers
              << " inlier edge points, RMS residual " << result.inner_residual_px << " px\n"
              << "  outer circle: " << result.outer_inliers << " inlier edge points, RMS residual "
              << result.outer_residual_px << " px\n";
    std::cout.unsetf(std::ios::floatfield);
  }
  if (!args.save_calibration.empty()) {
    calibration.ToYamlFile(args.save_calibration);
    std::cout << "saved calibration to " << args.save_calibration << "\n";
  }
  std::unique_ptr<OmniUnwrapper> unwrapper;
  try {
    unwrapper = std::make_unique<OmniUnwrapper>(calibration, raw.cols, raw.rows);
  } catch (const Error& e) {
    throw Error(StrCat(args.raw, ": ", e.what()));
  }
  const cv::Mat panorama = unwrapper->Unwrap(raw);
  WriteImage(args.out, panorama);
  std::cout << "wrote " << panorama.cols << "x" << panorama.rows << " panorama to " << args.out
            << "\n";
}

const CommandRegistration kUnwrap{
    "unwrap", [](CLI::App& app) {
      auto args = std::make_shared<UnwrapArgs>();
      CLI::App* cmd =
          app.add_subcommand("unwrap", "Unwrap a raw catadioptric ring image into a panorama");
      cmd->add_option("RAW", args->raw, "Raw ring image (grey or colour)")->required();
      AddOutputFile(cmd, "--out", &args->out, "Output panorama image (e.g. pano.png)")->required();
      CLI::Option* calib = cmd->add_option("--calibration", args->calibration,
                                           "Calibration YAML (OmniCalibration keys)");
      CLI::Option* autocal = cmd->add_flag("--auto-calibrate", args->auto_calibrate,
                                           "Estimate centre and radii from RAW itself");
      calib->excludes(autocal);
      cmd->add_option("--width", args->width,
                      "Panorama width (azimuth bins); overrides the calibration");
      cmd->add_option("--height", args->height,
                      "Panorama height (rows); overrides the calibration");
      AddOutputFile(cmd, "--save-calibration", &args->save_calibration,
                      "Write the calibration used to this YAML file");
      cmd->callback([args] { RunUnwrap(*args); });
    }};

}  // namespace
}  // namespace omnicml::app
