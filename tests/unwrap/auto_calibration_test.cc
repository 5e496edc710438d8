#include "omnicml/unwrap/auto_calibration.h"

#include <cmath>
#include <filesystem>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

// A textured panorama: random grey blocks (a cluttered scene), seeded.
cv::Mat Blocks(int width, int height, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> level(70, 230);
  cv::Mat pano(height, width, CV_8UC3);
  for (int r = 0; r < height; r += 10) {
    for (int c = 0; c < width; c += 12) {
      pano(cv::Rect(c, r, std::min(12, width - c), std::min(10, height - r)))
          .setTo(cv::Scalar(level(rng), level(rng), level(rng)));
    }
  }
  return pano;
}

void AddNoise(cv::Mat& image, double sigma, std::uint32_t seed) {
  cv::Mat noise(image.size(), CV_32FC(image.channels()));
  cv::theRNG().state = seed;
  cv::randn(noise, 0.0, sigma);
  cv::Mat f;
  image.convertTo(f, CV_32F);
  f += noise;
  f.convertTo(image, image.type());
}

// A mirror ring whose centre is the robot's bright body (with dark details), clipped at the
// top and bottom of a 16:9 image and with a text overlay, is found to within a pixel.
TEST(AutoCalibrate, BrightCentreClippedRingWithText) {
  OmniCalibration truth;
  truth.center_x_px = 652.4;
  truth.center_y_px = 371.8;
  truth.inner_radius_px = 120.0;
  truth.outer_radius_px = 402.0;
  const OmniUnwrapper renderer(truth, 1280, 760);
  cv::Mat tall = renderer.Render(Blocks(720, 120, 4), cv::Scalar(20, 20, 20));
  // The robot's body in the hole: bright, with a dark mount and cables.
  cv::circle(tall, cv::Point(652, 372), 118, cv::Scalar(225, 225, 225), cv::FILLED);
  cv::circle(tall, cv::Point(640, 365), 60, cv::Scalar(30, 30, 30), 12);
  cv::line(tall, cv::Point(600, 300), cv::Point(700, 460), cv::Scalar(40, 40, 200), 5);
  cv::Mat raw = tall.rowRange(20, 740).clone();  // 1280x720: the rim leaves top and bottom
  cv::putText(raw, "Frame 457 (cam v4.6b), selected object: NONE", cv::Point(10, 24),
              cv::FONT_HERSHEY_SIMPLEX, 0.8, cv::Scalar(255, 255, 255), 2);
  AddNoise(raw, 4.0, 9);
  const AutoCalibrationResult r = AutoCalibrate(raw);
  EXPECT_NEAR(r.calibration.center_x_px, truth.center_x_px, 1.0);
  EXPECT_NEAR(r.calibration.center_y_px, truth.center_y_px - 20.0, 1.0);
  EXPECT_NEAR(r.calibration.outer_radius_px, truth.outer_radius_px, 1.5);
  EXPECT_NEAR(r.calibration.inner_radius_px, truth.inner_radius_px, 3.0);
  EXPECT_GT(r.confidence, 0.8);
  EXPECT_LT(r.visible_fraction, 0.95);  // clipped
  // Several frames of the same camera give the same answer within a fraction of a pixel.
  cv::Mat other =
      renderer.Render(Blocks(720, 120, 5), cv::Scalar(20, 20, 20)).rowRange(20, 740).clone();
  AddNoise(other, 4.0, 10);
  const AutoCalibrationResult pooled = AutoCalibrate(std::vector<cv::Mat>{raw, other});
  EXPECT_EQ(pooled.frames_used, 2);
  EXPECT_NEAR(pooled.calibration.center_x_px, truth.center_x_px, 1.0);
  EXPECT_NEAR(pooled.calibration.center_y_px, truth.center_y_px - 20.0, 1.0);
}

// A fisheye image circle (scene inside, black outside) gives centre and radius.
TEST(AutoCalibrate, FisheyeImageCircle) {
  FisheyeCalibration truth;
  truth.center_x_px = 735.0;
  truth.center_y_px = 712.5;
  truth.circle_radius_px = 690.0;
  truth.field_of_view_deg = 200.0;
  truth.min_elevation_deg = -10.0;
  truth.max_elevation_deg = 90.0;
  cv::Mat raw = OmniUnwrapper(truth, 1440, 1440).Render(Blocks(720, 120, 6));
  AddNoise(raw, 3.0, 2);
  FisheyeCalibration initial = truth;
  initial.center_x_px = 720;
  initial.center_y_px = 720;
  initial.circle_radius_px = 500;
  AutoCalibrationResult report;
  const FisheyeCalibration found = AutoCalibrateFisheye({raw}, initial, &report);
  EXPECT_NEAR(found.center_x_px, truth.center_x_px, 1.0);
  EXPECT_NEAR(found.center_y_px, truth.center_y_px, 1.0);
  // Render paints up to half a pixel beyond the band's last row.
  EXPECT_NEAR(found.circle_radius_px, truth.circle_radius_px, 2.0);
  EXPECT_GT(report.confidence, 0.8);
}

// A scene without any circle is refused in one line saying why.
TEST(AutoCalibrate, RefusesClutterWithoutRing) {
  cv::Mat raw(720, 1280, CV_8UC3);
  cv::resize(Blocks(128, 72, 8), raw, raw.size(), 0, 0, cv::INTER_NEAREST);
  AddNoise(raw, 3.0, 4);
  try {
    AutoCalibrate(raw);
    ADD_FAILURE() << "calibrated a picture without a ring";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("no ring found ("), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  }
}

// Real mirror-camera frames (../shared/datasets/rings): every frame is calibrated or
// refused with a reason; where a reference exists (kuanli: OCamCalib centre) the centre is
// within 1.5 % of the image width; the three 791x711 frames of one robot agree.
TEST(AutoCalibrate, RealFrames) {
  // ../shared from a checkout next to it, ../../shared from a worktree under wt/.
  fs::path root = fs::path(OMNICML_SOURCE_DIR) / ".." / "shared" / "datasets" / "rings";
  if (!fs::exists(root))
    root = fs::path(OMNICML_SOURCE_DIR) / ".." / ".." / "shared" / "datasets" / "rings";
  if (!fs::exists(root / "kuanli_office" / "example.jpg")) {
    GTEST_SKIP() << "real ring frames not found at " << root
                 << " (../shared/datasets/rings); skipping the real-frame check";
  }
  const cv::Mat kuanli = ReadImage((root / "kuanli_office" / "example.jpg").string());
  const AutoCalibrationResult k = AutoCalibrate(kuanli);
  EXPECT_LT(std::hypot(k.calibration.center_x_px - 974.32, k.calibration.center_y_px - 545.87),
            0.015 * kuanli.cols);
  std::vector<cv::Point2d> centres;
  for (const char* name : {"frame5.jpg", "frame8.jpg", "frame12_edgecase.jpg"}) {
    const AutoCalibrationResult r =
        AutoCalibrate(ReadImage((root / "omicron_soccer" / name).string()));
    centres.emplace_back(r.calibration.center_x_px, r.calibration.center_y_px);
  }
  for (const cv::Point2d& c : centres) {
    EXPECT_LT(std::hypot(c.x - centres[0].x, c.y - centres[0].y), 0.01 * 791);
  }
  for (const char* name : {"frame1.jpg", "WIN_20200226_17_58_26_Pro.jpg"}) {
    try {
      const AutoCalibrationResult r =
          AutoCalibrate(ReadImage((root / "omicron_soccer" / name).string()));
      EXPECT_GE(r.confidence, AutoCalibrationOptions{}.min_rim_confidence) << name;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("no ring found ("), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace omnicml
