#include "omnicml/unwrap/omni_unwrapper.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <unistd.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

// A fresh empty directory for one test's files.
fs::path TestDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / StrCat("omnicml_unwrap_test_", ::getpid()) / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// Expects `f` to throw omnicml::Error whose message contains every one of `parts`.
template <typename F>
void ExpectErrorMentions(F&& f, std::initializer_list<std::string> parts) {
  try {
    f();
    ADD_FAILURE() << "no omnicml::Error thrown";
  } catch (const Error& e) {
    const std::string what = e.what();
    for (const std::string& part : parts) {
      EXPECT_NE(what.find(part), std::string::npos)
          << "message '" << what << "' lacks '" << part << "'";
    }
  }
}

// A smooth panorama, periodic over azimuth, values within [30, 226] (no clipping).
cv::Mat SmoothPanorama(int width, int height, int channels, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> phase(0.0, kTwoPi);
  cv::Mat pano(height, width, CV_8UC(channels));
  for (int ch = 0; ch < channels; ++ch) {
    const double p1 = phase(rng), p2 = phase(rng), p3 = phase(rng), p4 = phase(rng);
    for (int r = 0; r < height; ++r) {
      for (int c = 0; c < width; ++c) {
        const double a = kTwoPi * c / width;
        const double v = 128.0 + 40.0 * std::sin(2.0 * a + p1) + 25.0 * std::sin(5.0 * a + p2) +
                         18.0 * std::cos(kTwoPi * r / height * 1.5 + p3) +
                         15.0 * std::sin(3.0 * a + kTwoPi * r / height + p4);
        pano.ptr<std::uint8_t>(r)[c * channels + ch] = cv::saturate_cast<std::uint8_t>(v);
      }
    }
  }
  return pano;
}

// A panorama like a room: blocks of random brightness (shelves, walls) with fine noise,
// all clearly brighter than a black background, with a few darker blocks.
cv::Mat BlockPanorama(int width, int height, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> level(70, 240);
  std::uniform_int_distribution<int> block(6, 40);
  std::normal_distribution<double> fine(0.0, 8.0);
  cv::Mat pano(height, width, CV_8UC3);
  for (int c0 = 0; c0 < width;) {
    const int w = std::min(block(rng), width - c0);
    for (int r0 = 0; r0 < height;) {
      const int h = std::min(block(rng), height - r0);
      const cv::Scalar colour(level(rng), level(rng), level(rng));
      pano(cv::Rect(c0, r0, w, h)).setTo(colour);
      r0 += h;
    }
    c0 += w;
  }
  cv::Mat noise(pano.size(), CV_32FC3);
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width * 3; ++c) noise.ptr<float>(r)[c] = static_cast<float>(fine(rng));
  }
  cv::Mat f;
  pano.convertTo(f, CV_32FC3);
  f += noise;
  f.convertTo(pano, CV_8UC3);
  return pano;
}

double MeanAbsoluteError(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  const cv::Scalar s = cv::mean(diff);
  double total = 0.0;
  for (int ch = 0; ch < a.channels(); ++ch) total += s[ch];
  return total / a.channels();
}

void AddGaussianNoise(cv::Mat& image, double sigma, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, sigma);
  for (int r = 0; r < image.rows; ++r) {
    std::uint8_t* p = image.ptr<std::uint8_t>(r);
    for (int i = 0; i < image.cols * image.channels(); ++i) {
      p[i] = cv::saturate_cast<std::uint8_t>(p[i] + noise(rng));
    }
  }
}

// Intensity-weighted circular mean of the image-plane angle (from +x towards +y) of a
// grey image's bright pixels around (cx, cy), and their mean radius.
struct AngleRadius {
  double theta_rad;
  double radius_px;
  cv::Point2d centroid;
};
AngleRadius BrightAngle(const cv::Mat& grey, double cx, double cy) {
  double s = 0.0, co = 0.0, rad = 0.0, wsum = 0.0, mx = 0.0, my = 0.0;
  for (int y = 0; y < grey.rows; ++y) {
    for (int x = 0; x < grey.cols; ++x) {
      const double w = grey.at<std::uint8_t>(y, x);
      if (w < 1.0) continue;
      const double dx = x - cx, dy = y - cy;
      const double r = std::hypot(dx, dy);
      s += w * dy / r;
      co += w * dx / r;
      rad += w * r;
      mx += w * x;
      my += w * y;
      wsum += w;
    }
  }
  return {std::atan2(s, co), rad / wsum, {mx / wsum, my / wsum}};
}

OmniCalibration OffCentreCalibration() {
  OmniCalibration c;
  c.center_x_px = 317.3;
  c.center_y_px = 244.6;
  c.inner_radius_px = 43.2;
  c.outer_radius_px = 221.7;
  c.azimuth0_rad = 0.4;
  return c;
}

// The default calibration suits a 640x480 ring and a 720x120 panorama.
TEST(OmniCalibration, DefaultFitsVgaRing) {
  const OmniCalibration c;
  EXPECT_NO_THROW(c.ValidateFor(640, 480));
  EXPECT_EQ(c.panorama_width, 720);
  EXPECT_EQ(c.panorama_height, 120);
}

// Render then Unwrap reproduces a smooth panorama (grey and colour, both directions and
// both elevation mappings) with a small mean absolute error.
TEST(OmniUnwrapper, RenderThenUnwrapRoundTrip) {
  for (const RingDirection direction :
       {RingDirection::kCounterClockwise, RingDirection::kClockwise}) {
    for (const ElevationMapping elevation :
         {ElevationMapping::kLinear, ElevationMapping::kLinearInverted}) {
      OmniCalibration calib = OffCentreCalibration();
      calib.direction = direction;
      calib.elevation = elevation;
      const OmniUnwrapper unwrapper(calib, 640, 480);
      for (const int channels : {1, 3}) {
        const cv::Mat pano = SmoothPanorama(720, 120, channels, 5 + channels);
        const cv::Mat raw = unwrapper.Render(pano);
        ASSERT_EQ(raw.size(), cv::Size(640, 480));
        ASSERT_EQ(raw.type(), pano.type());
        const cv::Mat back = unwrapper.Unwrap(raw);
        ASSERT_EQ(back.size(), pano.size());
        ASSERT_EQ(back.type(), pano.type());
        SCOPED_TRACE(StrCat("channels ", channels, " direction ", static_cast<int>(direction),
                            " elevation ", static_cast<int>(elevation)));
        // Measured: 0.035..0.041 grey levels (8-bit rounding of two resamplings), at most 3.
        EXPECT_LT(MeanAbsoluteError(back, pano), 0.2);
        // The first and last rows too (they sample half a radial bin from the ring's edge).
        EXPECT_LT(MeanAbsoluteError(back.row(0), pano.row(0)), 0.5);
        EXPECT_LT(MeanAbsoluteError(back.row(119), pano.row(119)), 0.5);
        double max_error = 0.0;
        cv::Mat diff;
        cv::absdiff(back, pano, diff);
        cv::minMaxLoc(diff.reshape(1), nullptr, &max_error);
        EXPECT_LE(max_error, 6.0);
      }
    }
  }
}

// A feature at panorama column c appears at image angle azimuth0 - 2 pi c / W
// (counter-clockwise on screen) or azimuth0 + 2 pi c / W (clockwise); with azimuth0 = 0 a
// feature at azimuth 90 degrees lies straight above the centre (counter-clockwise) or
// below it (clockwise).
TEST(OmniUnwrapper, ColumnConvention) {
  const int width = 720;
  for (const RingDirection direction :
       {RingDirection::kCounterClockwise, RingDirection::kClockwise}) {
    const double sign = direction == RingDirection::kCounterClockwise ? -1.0 : 1.0;
    for (const double azimuth0 : {0.0, 0.4, -2.5}) {
      for (const int column : {0, 90, 180, 300, 533, 719}) {
        OmniCalibration calib;
        calib.azimuth0_rad = azimuth0;
        calib.direction = direction;
        const OmniUnwrapper unwrapper(calib, 640, 480);
        cv::Mat pano(120, width, CV_8UC1, cv::Scalar(0));
        // A narrow bright stripe centred on `column`, wrapping around.
        for (int dc = -2; dc <= 2; ++dc) pano.col((column + dc + width) % width).setTo(200);
        const cv::Mat raw = unwrapper.Render(pano);
        const AngleRadius found = BrightAngle(raw, calib.center_x_px, calib.center_y_px);
        const double expected = azimuth0 + sign * kTwoPi * column / width;
        EXPECT_NEAR(WrapAngle(found.theta_rad - expected), 0.0, 0.2 * kTwoPi / width)
            << "column " << column << " azimuth0 " << azimuth0;
        // And the panorama comes back with the stripe at the same column.
        const cv::Mat back = unwrapper.Unwrap(raw);
        cv::Mat column_sum;
        cv::reduce(back, column_sum, 0, cv::REDUCE_SUM, CV_64F);
        cv::Point max_loc;
        cv::minMaxLoc(column_sum, nullptr, nullptr, nullptr, &max_loc);
        EXPECT_LE(std::abs(std::remainder(max_loc.x - column, static_cast<double>(width))), 2.0);
      }
    }
    // Screen geometry, independent of the formula: azimuth 90 degrees, azimuth0 = 0.
    OmniCalibration calib;
    calib.direction = direction;
    const OmniUnwrapper unwrapper(calib, 640, 480);
    cv::Mat pano(120, width, CV_8UC1, cv::Scalar(0));
    pano.colRange(width / 4 - 2, width / 4 + 3).setTo(200);
    const AngleRadius found =
        BrightAngle(unwrapper.Render(pano), calib.center_x_px, calib.center_y_px);
    EXPECT_NEAR(found.centroid.x, calib.center_x_px, 2.0);
    if (direction == RingDirection::kCounterClockwise) {
      EXPECT_LT(found.centroid.y, calib.center_y_px - 100.0)
          << "azimuth 90 deg must be above the centre";
    } else {
      EXPECT_GT(found.centroid.y, calib.center_y_px + 100.0)
          << "azimuth 90 deg must be below the centre";
    }
  }
}

// Unwrap, checked against a ring drawn analytically (not by Render): the raw intensity
// 128 + 100 cos(theta - 1) appears in column c as 128 + 100 cos(theta_c - 1) with
// theta_c = azimuth0 - 2 pi c / W, on every row.
TEST(OmniUnwrapper, UnwrapMatchesAnalyticRing) {
  const OmniCalibration calib = OffCentreCalibration();
  cv::Mat raw(480, 640, CV_8UC1);
  for (int y = 0; y < raw.rows; ++y) {
    for (int x = 0; x < raw.cols; ++x) {
      const double theta = std::atan2(y - calib.center_y_px, x - calib.center_x_px);
      raw.at<std::uint8_t>(y, x) =
          cv::saturate_cast<std::uint8_t>(128.0 + 100.0 * std::cos(theta - 1.0));
    }
  }
  const cv::Mat pano = OmniUnwrapper(calib, 640, 480).Unwrap(raw);
  double max_error = 0.0;
  for (int r = 0; r < pano.rows; ++r) {
    for (int c = 0; c < pano.cols; ++c) {
      const double theta = calib.azimuth0_rad - kTwoPi * c / pano.cols;
      const double expected = 128.0 + 100.0 * std::cos(theta - 1.0);
      max_error = std::max(max_error, std::abs(pano.at<std::uint8_t>(r, c) - expected));
    }
  }
  // Bilinear interpolation of a function varying by up to 100/43 levels per pixel near
  // the inner radius, plus 8-bit rounding.
  EXPECT_LT(max_error, 4.0);
}

// The engine-wide turn convention: a counter-clockwise robot turn by k columns rolls the
// unwrapped panorama to after[c] = before[(c + k) mod W]. The turn is simulated on the raw
// image (rotation about the ring centre: a ring of kCounterClockwise direction turns
// clockwise on screen, i.e. image angles grow), for both directions.
TEST(OmniUnwrapper, RobotTurnRollsPanorama) {
  const int k = 37;
  for (const RingDirection direction :
       {RingDirection::kCounterClockwise, RingDirection::kClockwise}) {
    OmniCalibration calib;
    calib.direction = direction;
    calib.azimuth0_rad = 0.3;
    const OmniUnwrapper unwrapper(calib, 640, 480);
    const cv::Mat before = SmoothPanorama(720, 120, 1, 4);
    const cv::Mat raw = unwrapper.Render(before);
    // World features move to smaller robot azimuth by delta = 2 pi k / W.
    const double delta = kTwoPi * k / 720.0;
    const double theta_change = direction == RingDirection::kCounterClockwise ? delta : -delta;
    // getRotationMatrix2D turns counter-clockwise on screen (image angle decreasing) for
    // positive degrees.
    const cv::Mat rotation = cv::getRotationMatrix2D(
        cv::Point2f(static_cast<float>(calib.center_x_px), static_cast<float>(calib.center_y_px)),
        -theta_change * 180.0 / kPi, 1.0);
    cv::Mat turned_raw;
    cv::warpAffine(raw, turned_raw, rotation, raw.size(), cv::INTER_LINEAR);
    const cv::Mat after = unwrapper.Unwrap(turned_raw);
    cv::Mat expected(before.size(), before.type());
    for (int c = 0; c < 720; ++c) before.col((c + k) % 720).copyTo(expected.col(c));
    // Edge rows excluded (the rotation resamples the ring's boundary pixels). Measured:
    // 0.09 grey levels against the right roll, 42.6 against the opposite roll.
    const cv::Rect inner_rows(0, 1, 720, 118);
    EXPECT_LT(MeanAbsoluteError(after(inner_rows), expected(inner_rows)), 0.5)
        << "direction " << static_cast<int>(direction);
    // The wrong roll direction is far off.
    cv::Mat wrong(before.size(), before.type());
    for (int c = 0; c < 720; ++c) before.col((c - k + 720) % 720).copyTo(wrong.col(c));
    EXPECT_GT(MeanAbsoluteError(after(inner_rows), wrong(inner_rows)), 5.0);
  }
}

// Row 0 lies at the outer radius for kLinear and at the inner radius for kLinearInverted.
TEST(OmniUnwrapper, ElevationMapping) {
  for (const ElevationMapping elevation :
       {ElevationMapping::kLinear, ElevationMapping::kLinearInverted}) {
    OmniCalibration calib;
    calib.elevation = elevation;
    const OmniUnwrapper unwrapper(calib, 640, 480);
    cv::Mat pano(120, 720, CV_8UC1, cv::Scalar(0));
    pano.row(0).setTo(255);
    const AngleRadius found =
        BrightAngle(unwrapper.Render(pano), calib.center_x_px, calib.center_y_px);
    const double bin = (calib.outer_radius_px - calib.inner_radius_px) / calib.panorama_height;
    const double expected = elevation == ElevationMapping::kLinear
                                ? calib.outer_radius_px - 0.5 * bin
                                : calib.inner_radius_px + 0.5 * bin;
    EXPECT_NEAR(found.radius_px, expected, bin);
  }
}

// Render accepts panoramas of another size (resampled) and paints outside the ring with
// the background value.
TEST(OmniUnwrapper, RenderResamplesAndPaintsBackground) {
  const OmniCalibration calib;
  const OmniUnwrapper unwrapper(calib, 640, 480);
  const cv::Mat big = SmoothPanorama(1440, 240, 3, 3);
  const cv::Mat raw = unwrapper.Render(big, cv::Scalar(7, 8, 9));
  ASSERT_EQ(raw.size(), cv::Size(640, 480));
  EXPECT_EQ(raw.at<cv::Vec3b>(0, 0), cv::Vec3b(7, 8, 9));      // outside the outer circle
  EXPECT_EQ(raw.at<cv::Vec3b>(240, 320), cv::Vec3b(7, 8, 9));  // inside the hole
  cv::Mat small;
  cv::resize(big, small, cv::Size(720, 120), 0, 0, cv::INTER_AREA);
  EXPECT_LT(MeanAbsoluteError(unwrapper.Unwrap(raw), small), 1.0);
}

// Auto-calibration recovers centre (1 px) and radii (2 px) of a rendered ring, clean and
// with Gaussian noise, grey and colour.
TEST(AutoCalibrate, RecoversRenderedRing) {
  const OmniCalibration truth = OffCentreCalibration();
  const OmniUnwrapper unwrapper(truth, 640, 480);
  const cv::Mat pano = BlockPanorama(720, 120, 21);
  for (const double noise_sigma : {0.0, 10.0}) {
    for (const bool colour : {false, true}) {
      cv::Mat raw = unwrapper.Render(pano);
      if (!colour) cv::cvtColor(raw, raw, cv::COLOR_BGR2GRAY);
      if (noise_sigma > 0.0) AddGaussianNoise(raw, noise_sigma, 99);
      OmniCalibration initial;
      initial.direction = RingDirection::kClockwise;  // carried over
      initial.azimuth0_rad = 1.25;
      const cv::Mat raw_copy = raw.clone();
      const AutoCalibrationResult result = AutoCalibrate(raw, initial);
      const OmniCalibration& found = result.calibration;
      SCOPED_TRACE(StrCat("noise ", noise_sigma, " colour ", colour));
      EXPECT_NEAR(found.center_x_px, truth.center_x_px, 1.0);
      EXPECT_NEAR(found.center_y_px, truth.center_y_px, 1.0);
      EXPECT_NEAR(found.inner_radius_px, truth.inner_radius_px, 2.0);
      EXPECT_NEAR(found.outer_radius_px, truth.outer_radius_px, 2.0);
      // Tighter: the visible edge of a rendered ring lies 0.5 px outside the radii (Render
      // paints pixels touching the ring); measured errors against it are below 0.05 px.
      EXPECT_NEAR(found.center_x_px, truth.center_x_px, 0.1);
      EXPECT_NEAR(found.center_y_px, truth.center_y_px, 0.1);
      EXPECT_NEAR(found.inner_radius_px, truth.inner_radius_px - 0.5, 0.2);
      EXPECT_NEAR(found.outer_radius_px, truth.outer_radius_px + 0.5, 0.2);
      EXPECT_EQ(found.direction, RingDirection::kClockwise);
      EXPECT_EQ(found.azimuth0_rad, 1.25);
      EXPECT_EQ(found.panorama_width, initial.panorama_width);
      // Most rays give an inlier edge point on each boundary; residuals are sub-pixel.
      EXPECT_GT(result.inner_inliers, 250);
      EXPECT_GT(result.outer_inliers, 250);
      EXPECT_LT(result.inner_residual_px, 1.0);
      EXPECT_LT(result.outer_residual_px, 1.0);
      EXPECT_GT(result.outer_residual_px, 0.0);
      // The input is left untouched, and the same image gives bit-identical results.
      EXPECT_EQ(cv::norm(raw, raw_copy, cv::NORM_INF), 0.0);
      const AutoCalibrationResult again = AutoCalibrate(raw, initial);
      EXPECT_EQ(again.calibration.center_x_px, found.center_x_px);
      EXPECT_EQ(again.calibration.outer_radius_px, found.outer_radius_px);
      EXPECT_EQ(again.inner_residual_px, result.inner_residual_px);
    }
  }
}

// Auto-calibration with a ring whose hole is dark grey rather than black and whose
// background is noisy still meets the tolerances.
TEST(AutoCalibrate, DarkGreyBackground) {
  OmniCalibration truth;
  truth.center_x_px = 322.0;
  truth.center_y_px = 236.5;
  truth.inner_radius_px = 55.0;
  truth.outer_radius_px = 205.0;
  const cv::Mat raw0 =
      OmniUnwrapper(truth, 640, 480).Render(BlockPanorama(720, 120, 4), cv::Scalar::all(25));
  cv::Mat raw = raw0.clone();
  AddGaussianNoise(raw, 6.0, 5);
  const AutoCalibrationResult result = AutoCalibrate(raw);
  EXPECT_NEAR(result.calibration.center_x_px, truth.center_x_px, 1.0);
  EXPECT_NEAR(result.calibration.center_y_px, truth.center_y_px, 1.0);
  EXPECT_NEAR(result.calibration.inner_radius_px, truth.inner_radius_px, 2.0);
  EXPECT_NEAR(result.calibration.outer_radius_px, truth.outer_radius_px, 2.0);
}

// Dark patches of the scene touching the ring's edges give outlier edge points; the robust
// fit rejects them and still meets the tolerances.
TEST(AutoCalibrate, RobustToDarkPatchesAtTheEdges) {
  const OmniCalibration truth = OffCentreCalibration();
  cv::Mat pano = BlockPanorama(720, 120, 8);
  std::mt19937 rng(13);
  std::uniform_int_distribution<int> start(0, 719 - 30);
  for (int k = 0; k < 4; ++k) {
    pano(cv::Rect(start(rng), 0, 30, 25)).setTo(cv::Scalar::all(0));   // outer edge (row 0)
    pano(cv::Rect(start(rng), 95, 30, 25)).setTo(cv::Scalar::all(0));  // inner edge
  }
  cv::Mat raw = OmniUnwrapper(truth, 640, 480).Render(pano);
  AddGaussianNoise(raw, 8.0, 17);
  const AutoCalibrationResult result = AutoCalibrate(raw);
  EXPECT_NEAR(result.calibration.center_x_px, truth.center_x_px, 1.0);
  EXPECT_NEAR(result.calibration.center_y_px, truth.center_y_px, 1.0);
  EXPECT_NEAR(result.calibration.inner_radius_px, truth.inner_radius_px, 2.0);
  EXPECT_NEAR(result.calibration.outer_radius_px, truth.outer_radius_px, 2.0);
  EXPECT_LT(result.outer_residual_px, 1.0);
  EXPECT_LT(result.inner_residual_px, 1.0);
}

// A ring cut by the top and bottom of the image (a large mirror on a 4:3 sensor) is still
// found from the rays that see its outer edge.
TEST(AutoCalibrate, RingCutByImageBorder) {
  OmniCalibration big;
  big.center_x_px = 321.0;
  big.center_y_px = 282.0;
  big.inner_radius_px = 50.0;
  big.outer_radius_px = 262.0;
  const cv::Mat tall = OmniUnwrapper(big, 640, 564).Render(BlockPanorama(720, 120, 31));
  cv::Mat raw = tall.rowRange(40, 520).clone();  // 640x480, the ring leaves top and bottom
  AddGaussianNoise(raw, 5.0, 3);
  const AutoCalibrationResult result = AutoCalibrate(raw);
  EXPECT_NEAR(result.calibration.center_x_px, big.center_x_px, 1.0);
  EXPECT_NEAR(result.calibration.center_y_px, big.center_y_px - 40.0, 1.0);
  EXPECT_NEAR(result.calibration.inner_radius_px, big.inner_radius_px, 2.0);
  EXPECT_NEAR(result.calibration.outer_radius_px, big.outer_radius_px, 2.0);
  // Such a ring is unwrapped; the rows it loses above and below are marked invalid.
  const OmniUnwrapper clipped(result.calibration, 640, 480);
  EXPECT_LT(clipped.valid_fraction(), 1.0);
  EXPECT_GT(clipped.valid_fraction(), 0.7);
}

// An image without a ring is reported as an error, not a wild calibration.
TEST(AutoCalibrate, NoRingIsAnError) {
  ExpectErrorMentions([] { AutoCalibrate(cv::Mat(480, 640, CV_8UC1, cv::Scalar(120))); },
                      {"no ring"});
  // A bright disc without a hole: the outer circle is there, the inner one is not.
  cv::Mat disc(480, 640, CV_8UC1, cv::Scalar(0));
  cv::circle(disc, cv::Point(320, 240), 200, cv::Scalar(200), cv::FILLED);
  ExpectErrorMentions([&] { AutoCalibrate(disc); }, {"no ring", "inner"});
  ExpectErrorMentions([] { AutoCalibrate(cv::Mat()); }, {"empty"});
  ExpectErrorMentions([] { AutoCalibrate(cv::Mat(480, 640, CV_32FC1, cv::Scalar(0))); },
                      {"unsupported"});
}

// Invalid calibrations name the offending field; a ring leaving the image is rejected.
TEST(OmniCalibration, ValidationNamesTheProblem) {
  OmniCalibration c;
  c.outer_radius_px = 30.0;
  ExpectErrorMentions([&] { c.Validate(); }, {"outer_radius_px"});
  c = {};
  c.inner_radius_px = -1.0;
  ExpectErrorMentions([&] { c.Validate(); }, {"inner_radius_px"});
  c = {};
  c.panorama_width = 0;
  ExpectErrorMentions([&] { c.Validate(); }, {"panorama_width"});
  c = {};
  c.panorama_height = 0;
  ExpectErrorMentions([&] { c.Validate(); }, {"panorama_height"});
  // A ring whose centre leaves the image, or with less than half of its panorama inside,
  // is refused; a ring slightly clipped is accepted (its clipped part is masked).
  c = {};
  c.center_x_px = 700.0;
  ExpectErrorMentions([&] { c.ValidateFor(640, 480); }, {"leaves the image", "640x480"});
  ExpectErrorMentions([&] { OmniUnwrapper(c, 640, 480); }, {"leaves the image"});
  c = {};
  c.center_x_px = 620.0;
  c.center_y_px = 460.0;
  ExpectErrorMentions([&] { OmniUnwrapper(c, 640, 480); }, {"leaves the image"});
  c = {};
  c.outer_radius_px = 241.0;
  EXPECT_NO_THROW(OmniUnwrapper(c, 640, 480));
}

// Unwrap rejects empty images, images of another size and unsupported types.
TEST(OmniUnwrapper, BadImagesAreErrors) {
  const OmniUnwrapper unwrapper(OmniCalibration{}, 640, 480);
  ExpectErrorMentions([&] { unwrapper.Unwrap(cv::Mat()); }, {"empty"});
  ExpectErrorMentions([&] { unwrapper.Unwrap(cv::Mat(1, 1, CV_8UC1)); }, {"1x1", "640x480"});
  ExpectErrorMentions([&] { unwrapper.Unwrap(cv::Mat(480, 640, CV_8UC1).t()); }, {"480x640"});
  ExpectErrorMentions([&] { unwrapper.Unwrap(cv::Mat(480, 640, CV_32FC1)); }, {"unsupported"});
  ExpectErrorMentions([&] { unwrapper.Unwrap(cv::Mat(480, 640, CV_8UC2)); },
                      {"unsupported", "2 channel"});
  ExpectErrorMentions([&] { unwrapper.Render(cv::Mat()); }, {"empty"});
}

// PreparePanorama passes panoramas through, resizes on request, and rejects degenerate input.
TEST(PreparePanorama, PassThroughResizeAndErrors) {
  const cv::Mat pano = SmoothPanorama(720, 150, 3, 1);
  const cv::Mat same = PreparePanorama(pano);
  EXPECT_EQ(same.data, pano.data);
  const cv::Mat small = PreparePanorama(pano, 360, 60);
  EXPECT_EQ(small.size(), cv::Size(360, 60));
  EXPECT_EQ(small.type(), pano.type());
  // Shrinking averages: the mean brightness is kept.
  EXPECT_NEAR(cv::mean(small)[0], cv::mean(pano)[0], 0.5);
  ExpectErrorMentions([] { PreparePanorama(cv::Mat()); }, {"empty"});
  ExpectErrorMentions([] { PreparePanorama(cv::Mat(1, 1, CV_8UC1, cv::Scalar(3))); }, {"1x1"});
  ExpectErrorMentions([&] { PreparePanorama(pano, -5, 10); }, {"negative"});
}

// Circular centroid (in columns) of a grey panorama's column sums.
double ColumnCentroid(const cv::Mat& pano) {
  cv::Mat sums;
  cv::reduce(pano, sums, 0, cv::REDUCE_SUM, CV_64F);
  double s = 0.0, c = 0.0;
  for (int col = 0; col < pano.cols; ++col) {
    const double a = kTwoPi * col / pano.cols;
    s += sums.at<double>(0, col) * std::sin(a);
    c += sums.at<double>(0, col) * std::cos(a);
  }
  double centroid = std::atan2(s, c) * pano.cols / kTwoPi;
  if (centroid < 0.0) centroid += pano.cols;
  return centroid;
}

// Resizing keeps azimuths: column c of the result looks where column c * W_in / W of the
// input looked (a feature keeps its azimuth), shrinking or growing, also across the wrap;
// Render resamples the same way.
TEST(PreparePanorama, ResizeKeepsAzimuth) {
  for (const int in_width : {1440, 2160, 360, 720}) {
    for (const double azimuth_deg : {0.0, 47.3, 359.2}) {
      cv::Mat in(60, in_width, CV_8UC1);
      for (int c = 0; c < in_width; ++c) {
        const double d = std::remainder(c - azimuth_deg / 360.0 * in_width, in_width);
        const double sigma = 3.0 * in_width / 720.0;
        in.col(c).setTo(cv::saturate_cast<std::uint8_t>(
            10.0 + 240.0 * std::exp(-0.5 * d * d / (sigma * sigma))));
      }
      const cv::Mat out = PreparePanorama(in, 720, 120);
      const double expected = azimuth_deg / 360.0 * 720.0;
      EXPECT_NEAR(std::remainder(ColumnCentroid(out) - expected, 720.0), 0.0, 0.05)
          << "input width " << in_width << " azimuth " << azimuth_deg;
    }
  }
  // Render: a stripe at column 200 of a 1440-wide panorama lands at column 100 after Unwrap.
  const OmniUnwrapper unwrapper(OmniCalibration{}, 640, 480);
  cv::Mat wide(120, 1440, CV_8UC1, cv::Scalar(0));
  wide.colRange(198, 203).setTo(200);
  EXPECT_NEAR(ColumnCentroid(unwrapper.Unwrap(unwrapper.Render(wide))), 100.0, 0.1);
}

// ReadImage reports each kind of bad file with its path and the problem; WriteImage is
// atomic (no temporary left behind) and reports unwritable paths.
TEST(ReadImage, BadFilesNameFileAndProblem) {
  const fs::path dir = TestDir("read");
  const std::string missing = (dir / "missing.png").string();
  ExpectErrorMentions([&] { ReadImage(missing); }, {missing, "does not exist"});

  const std::string empty = (dir / "empty.png").string();
  std::ofstream(empty).close();
  ExpectErrorMentions([&] { ReadImage(empty); }, {empty, "empty"});

  const std::string garbage = (dir / "garbage.png").string();
  std::ofstream(garbage) << "this is not an image";
  ExpectErrorMentions([&] { ReadImage(garbage); }, {garbage, "unreadable"});

  const std::string tiny = (dir / "tiny.png").string();
  ASSERT_TRUE(cv::imwrite(tiny, cv::Mat(1, 1, CV_8UC1, cv::Scalar(9))));
  ExpectErrorMentions([&] { ReadImage(tiny); }, {tiny, "1x1"});

  // A grey+alpha PAM decodes to 2 channels.
  const std::string two = (dir / "two.pam").string();
  {
    std::ofstream f(two, std::ios::binary);
    f << "P7\nWIDTH 4\nHEIGHT 3\nDEPTH 2\nMAXVAL 255\nTUPLTYPE GRAYSCALE_ALPHA\nENDHDR\n";
    for (int i = 0; i < 4 * 3 * 2; ++i) f.put(static_cast<char>(i));
  }
  ExpectErrorMentions([&] { ReadImage(two); }, {two, "2 channels"});

  ExpectErrorMentions([&] { ReadImage(dir.string()); }, {dir.string(), "not a regular file"});
}

// 4-channel images become BGR and 16-bit images become 8-bit (scaled) on reading.
TEST(ReadImage, ConvertsAlphaAndSixteenBit) {
  const fs::path dir = TestDir("convert");
  cv::Mat bgra(10, 12, CV_8UC4, cv::Scalar(10, 20, 30, 128));
  const std::string p4 = (dir / "bgra.png").string();
  WriteImage(p4, bgra);
  const cv::Mat read4 = ReadImage(p4);
  EXPECT_EQ(read4.type(), CV_8UC3);
  EXPECT_EQ(read4.at<cv::Vec3b>(3, 4), cv::Vec3b(10, 20, 30));

  cv::Mat grey16(10, 12, CV_16UC1, cv::Scalar(65535));
  grey16.at<std::uint16_t>(0, 0) = 257 * 100;
  const std::string p16 = (dir / "grey16.png").string();
  WriteImage(p16, grey16);
  const cv::Mat read16 = ReadImage(p16);
  EXPECT_EQ(read16.type(), CV_8UC1);
  EXPECT_EQ(read16.at<std::uint8_t>(0, 0), 100);
  EXPECT_EQ(read16.at<std::uint8_t>(5, 5), 255);
}

// WriteImage writes the file in one step, leaves no temporary file and names the target
// on failure.
TEST(WriteImage, AtomicAndErrors) {
  const fs::path dir = TestDir("write");
  const cv::Mat pano = SmoothPanorama(72, 12, 3, 2);
  const std::string path = (dir / "pano.png").string();
  WriteImage(path, pano);
  WriteImage(path, pano);  // overwrite
  int files = 0;
  for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir)) ++files;
  EXPECT_EQ(files, 1) << "a temporary file was left behind";
  EXPECT_EQ(MeanAbsoluteError(ReadImage(path), pano), 0.0);

  const std::string bad_dir = (dir / "no" / "such" / "dir" / "pano.png").string();
  ExpectErrorMentions([&] { WriteImage(bad_dir, pano); }, {bad_dir});
  ExpectErrorMentions([&] { WriteImage((dir / "noext").string(), pano); }, {"extension"});
  ExpectErrorMentions([&] { WriteImage(path, cv::Mat()); }, {path, "empty"});
}

// The YAML round trip is exact; unknown keys, bad values and missing files are errors
// naming the key or the file.
TEST(OmniCalibration, YamlRoundTripAndErrors) {
  const fs::path dir = TestDir("yaml");
  OmniCalibration c;
  c.center_x_px = 321.123456789;
  c.center_y_px = 239.987654321;
  c.inner_radius_px = 41.5;
  c.outer_radius_px = 218.25;
  c.azimuth0_rad = kPi / 3.0;
  c.direction = RingDirection::kClockwise;
  c.elevation = ElevationMapping::kLinearInverted;
  c.panorama_width = 360;
  c.panorama_height = 90;
  const std::string path = (dir / "calib.yaml").string();
  c.ToYamlFile(path);
  const OmniCalibration back = OmniCalibration::FromYamlFile(path);
  EXPECT_EQ(back.center_x_px, c.center_x_px);
  EXPECT_EQ(back.center_y_px, c.center_y_px);
  EXPECT_EQ(back.inner_radius_px, c.inner_radius_px);
  EXPECT_EQ(back.outer_radius_px, c.outer_radius_px);
  EXPECT_EQ(back.azimuth0_rad, c.azimuth0_rad);
  EXPECT_EQ(back.direction, c.direction);
  EXPECT_EQ(back.elevation, c.elevation);
  EXPECT_EQ(back.panorama_width, c.panorama_width);
  EXPECT_EQ(back.panorama_height, c.panorama_height);
  int files = 0;
  for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir)) ++files;
  EXPECT_EQ(files, 1) << "a temporary file was left behind";

  const std::string unknown = (dir / "unknown.yaml").string();
  std::ofstream(unknown) << "center_x_px: 320\ncentre_y_px: 240\n";
  ExpectErrorMentions([&] { OmniCalibration::FromYamlFile(unknown); },
                      {unknown, "centre_y_px", "unknown key"});

  const std::string bad_value = (dir / "bad_value.yaml").string();
  std::ofstream(bad_value) << "center_x_px: left\n";
  ExpectErrorMentions([&] { OmniCalibration::FromYamlFile(bad_value); },
                      {bad_value, "center_x_px"});

  const std::string bad_direction = (dir / "bad_direction.yaml").string();
  std::ofstream(bad_direction) << "direction: sideways\n";
  ExpectErrorMentions([&] { OmniCalibration::FromYamlFile(bad_direction); },
                      {bad_direction, "sideways"});

  const std::string invalid = (dir / "invalid.yaml").string();
  std::ofstream(invalid) << "inner_radius_px: 300\n";
  ExpectErrorMentions([&] { OmniCalibration::FromYamlFile(invalid); },
                      {invalid, "outer_radius_px"});

  const std::string missing = (dir / "missing.yaml").string();
  ExpectErrorMentions([&] { OmniCalibration::FromYamlFile(missing); }, {missing, "does not exist"});

  const std::string syntax = (dir / "syntax.yaml").string();
  std::ofstream(syntax) << "center_x_px: [1, 2\n";
  ExpectErrorMentions([&] { OmniCalibration::FromYamlFile(syntax); }, {syntax});
}

}  // namespace
}  // namespace omnicml
