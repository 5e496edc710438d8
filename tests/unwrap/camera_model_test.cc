#include "omnicml/unwrap/camera_model.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <unistd.h>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

constexpr double kDeg = kTwoPi / 360.0;

fs::path TestDir(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / StrCat("omnicml_camera_model_test_", ::getpid()) / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

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

FisheyeCalibration Fisheye(FisheyeProjection projection) {
  FisheyeCalibration f;
  f.center_x_px = 731.3;
  f.center_y_px = 709.8;
  f.circle_radius_px = 690.0;
  f.field_of_view_deg = 235.0;
  f.projection = projection;
  f.min_elevation_deg = -25.0;
  f.max_elevation_deg = 70.0;
  f.azimuth0_rad = 0.4;
  f.panorama_width = 720;
  f.panorama_height = 150;
  return f;
}

EquirectangularCalibration Equirect() {
  EquirectangularCalibration e;
  e.min_elevation_deg = -30.0;
  e.max_elevation_deg = 45.0;
  e.azimuth0_rad = -1.1;
  e.panorama_width = 720;
  e.panorama_height = 150;
  return e;
}

// Column distance on the circle of W columns.
double ColumnError(double a, double b, int width) {
  double d = std::fmod(std::abs(a - b), width);
  return std::min(d, width - d);
}

// A 3-D direction projected through the model's equations lands, mapped back by the
// panorama model (ImageToPanorama), on the column/row the panorama convention gives it.
TEST(CameraModel, DirectionRoundTripThroughEveryModel) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> azimuth(0.0, kTwoPi);
  for (const CameraCalibration& c :
       {CameraCalibration(Fisheye(FisheyeProjection::kEquidistant)),
        CameraCalibration(Fisheye(FisheyeProjection::kEquisolid)), CameraCalibration(Equirect())}) {
    const double lo = c.model == CameraModelType::kFisheye ? c.fisheye.min_elevation_deg
                                                           : c.equirectangular.min_elevation_deg;
    const double hi = c.model == CameraModelType::kFisheye ? c.fisheye.max_elevation_deg
                                                           : c.equirectangular.max_elevation_deg;
    std::uniform_real_distribution<double> elevation(lo * kDeg, hi * kDeg);
    for (int i = 0; i < 200; ++i) {
      const double a = azimuth(rng), e = elevation(rng);
      const cv::Point2d expected = DirectionToPanorama(c, a, e);
      const cv::Point2d image = DirectionToImage(c, a, e, 1440, 1440);
      const std::optional<cv::Point2d> back = ImageToPanorama(c, image, 1440, 1440);
      ASSERT_TRUE(back.has_value()) << ToString(c.model) << " a=" << a << " e=" << e;
      EXPECT_LT(ColumnError(back->x, expected.x, c.panorama_width()), 1e-6) << ToString(c.model);
      EXPECT_NEAR(back->y, expected.y, 1e-6) << ToString(c.model);
      // And the forward map of that panorama position samples the same image point.
      const cv::Point2d forward = PanoramaToImage(c, expected.x, expected.y, 1440, 1440);
      EXPECT_NEAR(forward.x, image.x, 1e-6) << ToString(c.model);
      EXPECT_NEAR(forward.y, image.y, 1e-6) << ToString(c.model);
    }
  }
}

// The fisheye projections follow their equations: a ray 90 deg from the axis (the horizon)
// lies at f pi/2 (equidistant) or 2 f sin(pi/4) (equisolid), and the image circle is the
// field of view's edge.
TEST(CameraModel, FisheyeRadiusFollowsProjection) {
  for (const FisheyeProjection p :
       {FisheyeProjection::kEquidistant, FisheyeProjection::kEquisolid}) {
    const FisheyeCalibration f = Fisheye(p);
    const CameraCalibration c(f);
    const double psi_max = 0.5 * f.field_of_view_deg * kDeg;
    const double focal = p == FisheyeProjection::kEquidistant
                             ? f.circle_radius_px / psi_max
                             : f.circle_radius_px / (2.0 * std::sin(0.5 * psi_max));
    const cv::Point2d horizon = DirectionToImage(c, 0.3, 0.0, 1440, 1440);
    const double rho = std::hypot(horizon.x - f.center_x_px, horizon.y - f.center_y_px);
    const double expected = p == FisheyeProjection::kEquidistant ? focal * kTwoPi / 4
                                                                 : 2 * focal * std::sin(kTwoPi / 8);
    EXPECT_NEAR(rho, expected, 1e-9);
    const cv::Point2d edge = DirectionToImage(c, 1.0, kTwoPi / 4 - psi_max, 1440, 1440);
    EXPECT_NEAR(std::hypot(edge.x - f.center_x_px, edge.y - f.center_y_px), f.circle_radius_px,
                1e-9);
  }
}

// Unwrapping an image painted from known directions puts each direction's colour at its
// panorama column/row, within a fraction of a pixel (fixed-point maps included).
TEST(CameraModel, UnwrapPlacesDirectionsWhereTheConventionSays) {
  for (const CameraCalibration& c :
       {CameraCalibration(Fisheye(FisheyeProjection::kEquisolid)), CameraCalibration(Equirect())}) {
    const int size = 1440;
    // A smooth image: value = linear in image x and y, so the sample position can be read
    // back from the unwrapped values.
    cv::Mat xs(size, size, CV_32FC1), ys(size, size, CV_32FC1);
    for (int y = 0; y < size; ++y) {
      for (int x = 0; x < size; ++x) {
        xs.at<float>(y, x) = static_cast<float>(x);
        ys.at<float>(y, x) = static_cast<float>(y);
      }
    }
    const OmniUnwrapper unwrapper(c, size, size);
    // Use the maps through Unwrap on 8-bit images: encode x mod 256 and y mod 256.
    cv::Mat raw(size, size, CV_8UC3);
    for (int y = 0; y < size; ++y) {
      for (int x = 0; x < size; ++x) {
        raw.at<cv::Vec3b>(y, x) =
            cv::Vec3b(static_cast<uchar>(x / 8), static_cast<uchar>(y / 8), 0);
      }
    }
    const cv::Mat pano = unwrapper.Unwrap(raw);
    ASSERT_EQ(pano.cols, c.panorama_width());
    std::mt19937 rng(3);
    std::uniform_int_distribution<int> col(0, pano.cols - 1), row(0, pano.rows - 1);
    for (int i = 0; i < 100; ++i) {
      const int cc = col(rng), rr = row(rng);
      const cv::Point2d p = PanoramaToImage(c, cc, rr, size, size);
      if (p.x < 8 || p.y < 8 || p.x > size - 9 || p.y > size - 9) continue;
      const cv::Vec3b v = pano.at<cv::Vec3b>(rr, cc);
      // Each grey level covers 8 px; bilinear interpolation of the staircase stays within
      // one level of the exact position.
      EXPECT_NEAR(v[0], p.x / 8.0, 1.01) << ToString(c.model);
      EXPECT_NEAR(v[1], p.y / 8.0, 1.01) << ToString(c.model);
    }
  }
}

// The ring model's forward and inverse maps agree (panorama -> image -> panorama).
TEST(CameraModel, RingPanoramaImageRoundTrip) {
  OmniCalibration ring;
  ring.center_x_px = 974.3;
  ring.center_y_px = 545.9;
  ring.inner_radius_px = 235.0;
  ring.outer_radius_px = 600.0;
  ring.azimuth0_rad = 0.7;
  ring.direction = RingDirection::kClockwise;
  const CameraCalibration c(ring);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> col(0.0, 720.0), row(0.0, 119.0);
  for (int i = 0; i < 200; ++i) {
    const double cc = col(rng), rr = row(rng);
    const cv::Point2d p = PanoramaToImage(c, cc, rr, 1920, 1080);
    const std::optional<cv::Point2d> back = ImageToPanorama(c, p, 1920, 1080);
    ASSERT_TRUE(back.has_value());
    EXPECT_LT(ColumnError(back->x, cc, 720), 1e-9);
    EXPECT_NEAR(back->y, rr, 1e-9);
  }
}

// A ring clipped by the image border is accepted; the clipped part is invalid in the mask,
// the rest valid; a ring mostly outside the image is refused.
TEST(CameraModel, ClippedRingMarksInvalidPixels) {
  OmniCalibration ring;
  ring.center_x_px = 974.3;
  ring.center_y_px = 545.9;
  ring.inner_radius_px = 235.0;
  ring.outer_radius_px = 600.0;
  const OmniUnwrapper unwrapper(ring, 1920, 1080);
  EXPECT_GT(unwrapper.valid_fraction(), 0.8);
  EXPECT_LT(unwrapper.valid_fraction(), 1.0);
  const cv::Mat& mask = unwrapper.valid_mask();
  for (int r = 0; r < mask.rows; r += 7) {
    for (int c = 0; c < mask.cols; c += 5) {
      const cv::Point2d p = PanoramaToImage(CameraCalibration(ring), c, r, 1920, 1080);
      const bool inside = p.y >= -0.5 && p.y <= 1079.5 && p.x >= -0.5 && p.x <= 1919.5;
      EXPECT_EQ(mask.at<std::uint8_t>(r, c) != 0, inside) << r << "," << c;
    }
  }
  // The innermost row (r = H - 1) is whole; the outermost is cut above and below.
  EXPECT_EQ(cv::countNonZero(mask.row(mask.rows - 1)), mask.cols);
  EXPECT_LT(cv::countNonZero(mask.row(0)), mask.cols);
  OmniCalibration outside = ring;
  outside.center_y_px = -300.0;
  ExpectErrorMentions([&] { OmniUnwrapper(outside, 1920, 1080); }, {"leaves the image"});
}

// A user mask marks the robot's body: panorama pixels sampling it are invalid.
TEST(CameraModel, UserMaskFlowsToValidMask) {
  OmniCalibration ring;  // 640x480 default ring
  cv::Mat user(480, 640, CV_8UC1, cv::Scalar(255));
  // The robot's mast to the right of the centre (image angle 0 = column 0).
  cv::rectangle(user, cv::Point(320, 230), cv::Point(639, 250), cv::Scalar(0), cv::FILLED);
  const OmniUnwrapper unwrapper(ring, 640, 480, user);
  const cv::Mat& mask = unwrapper.valid_mask();
  EXPECT_EQ(mask.at<std::uint8_t>(60, 0), 0);
  EXPECT_EQ(mask.at<std::uint8_t>(60, 360), 255);
  EXPECT_LT(unwrapper.valid_fraction(), 0.99);
  ExpectErrorMentions([&] { OmniUnwrapper(ring, 640, 480, cv::Mat(10, 10, CV_8UC1)); }, {"mask"});
}

// Calibration files: a flat ring file without `model` still loads, every model round
// trips through the session.yaml camera section, and errors name file, line and key.
TEST(CameraModel, YamlRoundTripAndErrors) {
  const fs::path dir = TestDir("yaml");
  const std::string old_ring = (dir / "ring.yaml").string();
  std::ofstream(old_ring) << "center_x_px: 300\ncenter_y_px: 250\ninner_radius_px: 30\n"
                             "outer_radius_px: 200\n";
  const CameraCalibration ring = CameraCalibration::FromYamlFile(old_ring);
  EXPECT_EQ(ring.model, CameraModelType::kRing);
  EXPECT_EQ(ring.ring.center_x_px, 300.0);
  for (const CameraCalibration& c : {CameraCalibration(Fisheye(FisheyeProjection::kEquisolid)),
                                     CameraCalibration(Equirect()), ring}) {
    const std::string path = (dir / StrCat(ToString(c.model), ".yaml")).string();
    c.ToYamlFile(path, 1440, 1440);
    const CameraCalibration back = CameraCalibration::FromYamlFile(path);
    EXPECT_TRUE(back == c) << ToString(c.model);
  }
  const std::string unknown = (dir / "unknown.yaml").string();
  std::ofstream(unknown) << "model: fisheye\ncenter_x_px: 3\ninner_radius_px: 4\n";
  ExpectErrorMentions([&] { CameraCalibration::FromYamlFile(unknown); },
                      {unknown, ":3:", "inner_radius_px"});
  const std::string bad_model = (dir / "bad_model.yaml").string();
  std::ofstream(bad_model) << "model: pinhole\n";
  ExpectErrorMentions([&] { CameraCalibration::FromYamlFile(bad_model); },
                      {bad_model, "pinhole", "fisheye"});
  const std::string bad_value = (dir / "bad_value.yaml").string();
  std::ofstream(bad_value) << "model: fisheye\nfield_of_view_deg: 120\nmin_elevation_deg: -10\n";
  ExpectErrorMentions([&] { CameraCalibration::FromYamlFile(bad_value); },
                      {bad_value, "min_elevation_deg", "field of view"});
  const std::string bad_type = (dir / "bad_type.yaml").string();
  std::ofstream(bad_type) << "model: equirectangular\nmax_elevation_deg: high\n";
  ExpectErrorMentions([&] { CameraCalibration::FromYamlFile(bad_type); },
                      {bad_type, ":2:", "max_elevation_deg", "not a number"});
}

}  // namespace
}  // namespace omnicml
