// `omnicml unwrap RAW [RAW...] --out PANO.png [--calibration CALIB.yaml] [--auto-calibrate]
//   [--width W --height H] [--save-calibration FILE.yaml] [--overlay FILE.png]
//   [--mask MASK.png] [--valid-mask-out FILE.png]`:
// unwraps a raw ring, fisheye or equirectangular image (camera_model.h) into a
// cylindrical panorama. With --auto-calibrate the image circle(s) are estimated from the
// RAW frames (pooled) and printed with a confidence, or refused in one line;
// --save-calibration stores the camera section session.yaml takes; --overlay draws the
// calibration on the input for a person to check.
#include <iomanip>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include <opencv2/imgproc.hpp>
#include "command_registry.h"
#include "omnicml/common/common.h"

#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml::app {
namespace {

struct UnwrapArgs {
  std::vector<std::string> raw;
  std::string out;
  std::string calibration;
  bool auto_calibrate = false;
  int width = 0;
  int height = 0;
  std::string save_calibration;
  std::string overlay;
  std::string mask;
  std::string valid_mask_out;
};

void PrintAutoCalibration(const AutoCalibrationResult& r, bool ring) {
  std::cout << std::setprecision(3) << std::fixed << "  confidence: " << r.confidence
            << " (rim: " << r.outer_inliers << " inlier edge points, RMS residual "
            << r.outer_residual_px << " px; " << r.visible_fraction * 100.0
            << " % of the rim inside the image)\n";
  if (ring) {
    std::cout << "  inner boundary: confidence " << r.inner_confidence << ", " << r.inner_inliers
              << " inlier edge points, RMS residual " << r.inner_residual_px << " px\n";
  }
  std::cout.unsetf(std::ios::floatfield);
}

void RunUnwrap(const UnwrapArgs& args) {
  if (args.calibration.empty() && !args.auto_calibrate) {
    throw Error(
        "unwrap: give --calibration CALIB.yaml, --auto-calibrate or both (the file then "
        "gives the model and the fields auto-calibration does not estimate)");
  }
  if ((args.width > 0) != (args.height > 0) || args.width < 0 || args.height < 0) {
    throw Error(StrCat("unwrap: --width and --height must both be positive (got ", args.width,
                       " and ", args.height, ")"));
  }
  std::vector<cv::Mat> frames;
  for (const std::string& path : args.raw) frames.push_back(ReadImage(path));
  const cv::Mat& raw = frames.front();
  for (std::size_t i = 1; i < frames.size(); ++i) {
    if (frames[i].size() != raw.size()) {
      throw Error(StrCat(args.raw[i], ": is ", frames[i].cols, "x", frames[i].rows, ", ",
                         args.raw[0], " is ", raw.cols, "x", raw.rows, " (one camera, one size)"));
    }
  }
  CameraCalibration calibration;
  if (!args.calibration.empty()) calibration = CameraCalibration::FromYamlFile(args.calibration);
  if (args.width > 0) calibration.SetPanoramaSize(args.width, args.height);
  if (args.auto_calibrate) {
    AutoCalibrationResult result;
    try {
      if (calibration.model == CameraModelType::kRing) {
        result = AutoCalibrate(frames, calibration.ring);
        calibration.ring = result.calibration;
      } else if (calibration.model == CameraModelType::kFisheye) {
        calibration.fisheye = AutoCalibrateFisheye(frames, calibration.fisheye, &result);
      } else {
        throw Error("an equirectangular image has no circle to calibrate; drop --auto-calibrate");
      }
    } catch (const Error& e) {
      throw Error(StrCat(args.raw[0],
                         frames.size() > 1 ? StrCat(" (and ", frames.size() - 1, " more)") : "",
                         ": ", e.what()));
    }
    std::cout << "auto-calibration of " << args.raw[0] << " (" << raw.cols << "x" << raw.rows
              << (frames.size() > 1 ? StrCat(", ", frames.size(), " frames") : "") << "):\n"
              << "  model: " << ToString(calibration.model) << "\n"
              << calibration.YamlFields("  ");
    PrintAutoCalibration(result, calibration.model == CameraModelType::kRing);
  }
  if (!args.save_calibration.empty()) {
    calibration.ToYamlFile(args.save_calibration, raw.cols, raw.rows);
    std::cout << "saved calibration (the camera section of session.yaml) to "
              << args.save_calibration << "\n";
  }
  if (!args.overlay.empty()) {
    WriteImage(args.overlay, DrawCalibrationOverlay(raw, calibration));
    std::cout << "wrote calibration overlay to " << args.overlay << "\n";
  }
  cv::Mat user_mask;
  if (!args.mask.empty()) {
    user_mask = ReadImage(args.mask);
    if (user_mask.channels() == 3) cv::cvtColor(user_mask, user_mask, cv::COLOR_BGR2GRAY);
  }
  std::unique_ptr<OmniUnwrapper> unwrapper;
  try {
    unwrapper = std::make_unique<OmniUnwrapper>(calibration, raw.cols, raw.rows, user_mask);
  } catch (const Error& e) {
    throw Error(StrCat(args.raw[0], ": ", e.what()));
  }
  const cv::Mat panorama = unwrapper->Unwrap(raw);
  WriteImage(args.out, panorama);
  std::cout << "wrote " << panorama.cols << "x" << panorama.rows << " panorama to " << args.out
            << " (" << std::lround(100.0 * unwrapper->valid_fraction())
            << " % of its pixels inside the image and the mask)\n";
  if (!args.valid_mask_out.empty()) {
    WriteImage(args.valid_mask_out, unwrapper->valid_mask());
    std::cout << "wrote the panorama's validity mask to " << args.valid_mask_out << "\n";
  }
}

const CommandRegistration kUnwrap{
    "unwrap", [](CLI::App& app) {
      auto args = std::make_shared<UnwrapArgs>();
      CLI::App* cmd = app.add_subcommand(
          "unwrap", "Unwrap a raw ring, fisheye or equirectangular image into a panorama");
      cmd->add_option("RAW", args->raw,
                      "Raw image(s) of one camera; the first is unwrapped, all are used by "
                      "--auto-calibrate")
          ->required();
      AddOutputFile(cmd, "--out", &args->out, "Output panorama image (e.g. pano.png)")->required();
      cmd->add_option("--calibration", args->calibration,
                      "Calibration YAML: a model's keys (model: omni_ring|fisheye|"
                      "equirectangular, default omni_ring) or a session.yaml camera section");
      cmd->add_flag("--auto-calibrate", args->auto_calibrate,
                    "Estimate the image circle(s) from RAW itself (ring or fisheye)");
      AddOutputFile(cmd, "--overlay", &args->overlay,
                    "Write the input with the calibration drawn on it (e.g. overlay.png)");
      cmd->add_option("--mask", args->mask,
                      "Mask image of the raw size: zero marks the robot's body, mounts, cables");
      AddOutputFile(cmd, "--valid-mask-out", &args->valid_mask_out,
                    "Write the panorama's validity mask (255 valid) to this image");
      cmd->add_option("--width", args->width,
                      "Panorama width (azimuth bins); overrides the calibration");
      cmd->add_option("--height", args->height,
                      "Panorama height (rows); overrides the calibration");
      AddOutputFile(cmd, "--save-calibration", &args->save_calibration,
                    "Write the calibration used as session.yaml's camera section");
      cmd->callback([args] { RunUnwrap(*args); });
    }};

}  // namespace
}  // namespace omnicml::app
