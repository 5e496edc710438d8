// Tests of the ray-casting renderer: rotation = column roll, ring <-> panorama, light
// zones, occlusion with all hits kept, sensor noise.
#include "omnicml/sim/renderer.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "omnicml/common/common.h"
#include "omnicml/sim/raw_camera.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {

// Two 5 m x 5 m rooms separated by a ceiling-high wall without a door, each with its
// own light zone; `box` adds a low box and `tall_wall` a tall wall behind it in room A.
World TwoRooms(bool tall_wall = true) {
  std::string yaml =
      "name: two_rooms\n"
      "size_m: [10, 5]\n"
      "ceiling_height_m: 3\n"
      "walls:\n"
      "  - {name: outer, polyline_m: [[0, 0], [10, 0], [10, 5], [0, 5], [0, 0]], height_m: 3,\n"
      "     texture: {kind: labels, seed: 4}}\n"
      "  - {name: middle, polyline_m: [[5, 0], [5, 5]], height_m: 3, texture: {kind: noise, seed: "
      "5}}\n";
  if (tall_wall) {
    yaml +=
        "  - {name: tall, polyline_m: [[3.5, 0.5], [3.5, 4.5]], height_m: 2.6,\n"
        "     texture: {kind: plain, color_rgb: [60, 120, 200]}}\n";
  }
  yaml +=
      "boxes:\n"
      "  - {name: low, rectangle_m: [2.0, 2.0, 2.4, 3.0], height_m: 0.5, texture: {kind: labels, "
      "seed: 6}}\n"
      "lights:\n"
      "  - {name: room_a, rectangle_m: [0, 0, 5, 5], intensity: 0.7}\n"
      "  - {name: room_b, rectangle_m: [5, 0, 10, 5], intensity: 0.7}\n"
      "route:\n"
      "  waypoints_m: [[1, 1], [1.5, 1], [1.5, 1.5]]\n";
  return ParseWorld(yaml, "two_rooms.yaml");
}

// Fraction of pixels that differ between two images.
double DiffFraction(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  cv::Mat grey = diff.reshape(1, diff.rows * diff.cols);
  cv::Mat any;
  cv::reduce(grey, any, 1, cv::REDUCE_MAX);
  return static_cast<double>(cv::countNonZero(any)) / any.rows;
}

// Turning in place by k * 360 / W degrees rolls the panorama by exactly k columns,
// after[c] = before[(c + k) mod W] (omni_unwrapper.h convention), people included.
TEST(Renderer, TurnInPlaceRollsPanoramaByWholeColumns) {
  const World world = LoadBuiltinWorld("home_store");
  Renderer renderer(world);
  const int W = world.camera.panorama_width_px;
  std::vector<Person> people = {{Eigen::Vector2d(6.0, 1.5), 0.25, 1.7, 3},
                                {Eigen::Vector2d(2.0, 4.0), 0.3, 1.8, 4}};
  for (const Eigen::Vector2d& xy :
       {Eigen::Vector2d(1.5, 1.2), Eigen::Vector2d(12.5, 5.0), Eigen::Vector2d(20.0, 8.8)}) {
    const int base = 37;
    const cv::Mat before =
        renderer.RenderPanorama(MakePose(xy.x(), xy.y(), kTwoPi * base / W), people);
    for (int k : {1, 5, 90, 359, -3, 700}) {
      const cv::Mat after =
          renderer.RenderPanorama(MakePose(xy.x(), xy.y(), kTwoPi * (base + k) / W), people);
      ASSERT_EQ(after.size(), before.size());
      int mismatched = 0;
      for (int c = 0; c < W; ++c) {
        const int src = ((c + k) % W + W) % W;
        mismatched += cv::norm(after.col(c), before.col(src), cv::NORM_INF) > 0 ? 1 : 0;
      }
      EXPECT_EQ(mismatched, 0) << "k=" << k << " at (" << xy.x() << ", " << xy.y() << ")";
    }
  }
}

// Column c looks along azimuth heading + 2 pi c / W counter-clockwise: a box straight
// ahead appears around column 0 and one to the left (+90 deg) around column W/4.
TEST(Renderer, ColumnsRunCounterClockwise) {
  const std::string yaml =
      "name: probe\nsize_m: [10, 10]\nceiling_height_m: 3\n"
      "boxes:\n"
      "  - {name: red, rectangle_m: [7.8, 4.8, 8.2, 5.2], height_m: 2, texture: {kind: plain, "
      "color_rgb: [255, 0, 0]}}\n"
      "  - {name: blue, rectangle_m: [4.8, 7.8, 5.2, 8.2], height_m: 2, texture: {kind: plain, "
      "color_rgb: [0, 0, 255]}}\n"
      "route:\n  waypoints_m: [[1, 1], [2, 1], [2, 2]]\n";
  const World world = ParseWorld(yaml, "probe.yaml");
  Renderer renderer(world);
  const cv::Mat pano = renderer.RenderPanorama(MakePose(5, 5, 0));
  const int W = pano.cols;
  const int row = pano.rows / 2;
  const auto red_at = [&](int c) {
    return pano.at<cv::Vec3b>(row, (c + W) % W)[2] > 2 * pano.at<cv::Vec3b>(row, (c + W) % W)[0];
  };
  const auto blue_at = [&](int c) {
    return pano.at<cv::Vec3b>(row, (c + W) % W)[0] > 2 * pano.at<cv::Vec3b>(row, (c + W) % W)[2];
  };
  EXPECT_TRUE(red_at(0));
  EXPECT_TRUE(red_at(-2));
  EXPECT_TRUE(blue_at(W / 4));
  EXPECT_FALSE(blue_at(3 * W / 4));
  EXPECT_FALSE(red_at(W / 2));
}

// The ring image, unwrapped again, reproduces the panorama (bilinear resampling twice).
TEST(Renderer, RingUnwrapsToPanorama) {
  const World world = LoadBuiltinWorld("institute");
  Renderer renderer(world);
  double worst = 0;
  for (const Pose2& pose :
       {MakePose(4.6, 3.0, 1.2), MakePose(2.0, 7.0, -0.4), MakePose(5.4, 12.0, 2.9)}) {
    const cv::Mat pano = renderer.RenderPanorama(pose);
    const cv::Mat ring = renderer.RenderRing(pano);
    ASSERT_EQ(ring.cols, world.camera.ring_width_px);
    ASSERT_EQ(ring.rows, world.camera.ring_height_px);
    ASSERT_EQ(ring.type(), CV_8UC3);
    const cv::Mat back = renderer.unwrapper().Unwrap(ring);
    ASSERT_EQ(back.size(), pano.size());
    // Mean absolute error per channel value; measured 2.2 grey levels at worst.
    const double mae = cv::norm(back, pano, cv::NORM_L1) / (pano.total() * pano.channels());
    worst = std::max(worst, mae);
  }
  RecordProperty("worst_mean_abs_error", std::to_string(worst));
  EXPECT_LT(worst, 4.0);
}

// Every simulated raw camera, unwrapped with its ground-truth calibration, gives back the
// rendered panorama up to resampling (over its valid pixels: the clipped ring loses its
// top and bottom), and the image has the kind's shape.
TEST(RawCamera, GroundTruthUnwrapsToThePanorama) {
  const World world = LoadBuiltinWorld("institute");
  Renderer renderer(world);
  for (SimulatedCamera kind : {SimulatedCamera::kRing, SimulatedCamera::kClippedRing,
                               SimulatedCamera::kBrightCentreRing, SimulatedCamera::kFisheye}) {
    RawCameraRenderer camera(world, kind);
    camera.SetState(renderer.state());
    const RawCameraSetup& setup = camera.setup();
    EXPECT_EQ(SimulatedCameraFromString(ToString(kind)), kind);
    const OmniUnwrapper unwrapper(setup.calibration, setup.image_width, setup.image_height);
    double worst = 0;
    for (const Pose2& pose : {MakePose(4.6, 3.0, 1.2), MakePose(5.4, 12.0, 2.9)}) {
      const cv::Mat pano = renderer.RenderPanorama(pose);
      const cv::Mat raw = camera.Render(pano, pose, {});
      ASSERT_EQ(raw.cols, setup.image_width);
      ASSERT_EQ(raw.rows, setup.image_height);
      const cv::Mat back = unwrapper.Unwrap(raw);
      ASSERT_EQ(back.size(), pano.size());
      cv::Mat diff;
      cv::absdiff(back, pano, diff);
      const cv::Scalar mean = cv::mean(diff, unwrapper.valid_mask());
      worst = std::max(worst, (mean[0] + mean[1] + mean[2]) / 3.0);
    }
    EXPECT_LT(worst, 6.0) << ToString(kind);
    if (kind == SimulatedCamera::kClippedRing) {
      EXPECT_LT(unwrapper.valid_fraction(), 0.99);  // the outermost rows leave the image
    } else {
      EXPECT_EQ(unwrapper.valid_fraction(), 1.0) << ToString(kind);
    }
    if (kind == SimulatedCamera::kBrightCentreRing) {
      const OmniCalibration& r = setup.calibration.ring;
      const cv::Mat raw = camera.Render(renderer.RenderPanorama(MakePose(4.6, 3.0, 1.2)),
                                        MakePose(4.6, 3.0, 1.2), {});
      const cv::Vec3b body =
          raw.at<cv::Vec3b>(static_cast<int>(std::lround(r.center_y_px)),
                            static_cast<int>(std::lround(r.center_x_px + 0.6 * r.inner_radius_px)));
      EXPECT_GT(body[0], 180) << "the hole shows the robot's bright body";
    }
  }
  EXPECT_THROW(SimulatedCameraFromString("pinhole"), Error);
}

// Switching off the lights of room A changes panoramas taken in room A, but not a single
// pixel of panoramas taken in room B behind the wall.
TEST(Renderer, LightsOffChangeOnlyTheirZone) {
  const World world = TwoRooms();
  Renderer renderer(world);
  WorldState state = InitialWorldState(world);
  const Pose2 in_a = MakePose(1.0, 2.5, 0.3), in_b = MakePose(7.5, 2.5, 2.0);
  const cv::Mat a_on = renderer.RenderPanorama(in_a), b_on = renderer.RenderPanorama(in_b);
  state.light_on[world.FindLight("room_a")] = 0;
  renderer.SetState(state);
  const cv::Mat a_off = renderer.RenderPanorama(in_a), b_off = renderer.RenderPanorama(in_b);
  EXPECT_EQ(cv::norm(b_on, b_off, cv::NORM_INF), 0.0);
  EXPECT_GT(DiffFraction(a_on, a_off), 0.9);
  EXPECT_LT(cv::mean(a_off)[0], cv::mean(a_on)[0]);
}

// A scheduled event through the public schedule: curtains closed on day 2 change the
// view of the window and nothing in the other room.
TEST(Renderer, CurtainEventChangesOnlyTheWindowView) {
  const std::string yaml =
      "name: curtain\nsize_m: [10, 5]\nceiling_height_m: 3\n"
      "walls:\n"
      "  - {name: outer, polyline_m: [[0, 0], [10, 0], [10, 5], [0, 5], [0, 0]], height_m: 3}\n"
      "  - {name: middle, polyline_m: [[5, 0], [5, 5]], height_m: 3}\n"
      "windows:\n  - {name: w, from_m: [0, 1.5], to_m: [0, 3.5], bottom_m: 1.0, top_m: 2.2}\n"
      "events:\n  - {type: curtains_closed, day: 2, target: w}\n"
      "route:\n  waypoints_m: [[1, 1], [2, 1], [2, 2]]\n";
  const World world = ParseWorld(yaml, "curtain.yaml");
  Renderer renderer(world);
  const Pose2 near = MakePose(2.5, 2.5, 0.0), far = MakePose(7.5, 2.5, 0.0);
  const cv::Mat near1 = renderer.RenderPanorama(near), far1 = renderer.RenderPanorama(far);
  renderer.SetState(StateAtDayStart(world, 2, 1));
  const cv::Mat near2 = renderer.RenderPanorama(near), far2 = renderer.RenderPanorama(far);
  EXPECT_EQ(cv::norm(far1, far2, cv::NORM_INF), 0.0);
  // The window spans about 2 * atan(1 / 2.5) = 44 degrees of azimuth around column W/2.
  const double changed = DiffFraction(near1, near2);
  EXPECT_GT(changed, 0.02);
  EXPECT_LT(changed, 0.2);
  const int W = near1.cols;
  EXPECT_GT(cv::norm(near1.col(W / 2 + 15), near2.col(W / 2 + 15), cv::NORM_INF),
            0.0);  // off the mullion
  EXPECT_EQ(cv::norm(near1.col(0), near2.col(0), cv::NORM_INF), 0.0);
}

// All hits along a ray are kept: a tall wall behind a low box shows above the box,
// while the box's own rows do not change.
TEST(Renderer, TallSurfacesBehindLowOnesStayVisible) {
  const World with_wall = TwoRooms(true), without_wall = TwoRooms(false);
  Renderer a(with_wall), b(without_wall);
  // From (0.5, 2.5) looking along +x: the box (x 2.0..2.4) in front of the tall wall at 3.5.
  const Pose2 pose = MakePose(0.5, 2.5, 0.0);
  const cv::Mat pa = a.RenderPanorama(pose), pb = b.RenderPanorama(pose);
  const int col = 0;
  const double cam_h = with_wall.camera.height_m;
  int box_rows_equal = 0, box_rows = 0, above_changed = 0, above_rows = 0;
  for (int r = 0; r < pa.rows; ++r) {
    const double tan_e = std::tan(a.RowElevationRad(r));
    const double z_box = cam_h + 1.5 * tan_e;   // height of the ray at the box's front face
    const double z_back = cam_h + 1.9 * tan_e;  // ... at the box's back face
    const double z_wall = cam_h + 3.0 * tan_e;  // ... at the tall wall
    const bool same = cv::norm(pa.row(r).col(col), pb.row(r).col(col), cv::NORM_INF) == 0;
    if (z_box > 0.02 && z_box < 0.48) {
      ++box_rows;
      box_rows_equal += same;
    } else if (z_back > 0.55 && z_wall < 2.55) {
      ++above_rows;
      above_changed += !same;
    }
  }
  ASSERT_GT(box_rows, 3);
  ASSERT_GT(above_rows, 10);
  EXPECT_EQ(box_rows_equal, box_rows);
  EXPECT_EQ(above_changed, above_rows);
}

// Rays through a corner of the renderer's 1 m segment grid on the grid's border (a wall
// hit exactly where the x and y cell borders are crossed at once) still end on the wall:
// from every point of a 0.2 m lattice in a closed 4 m x 2 m room, every column's horizon
// rows show the red outer wall, never the green floor or blue ceiling behind it.
TEST(Renderer, RaysThroughGridCornersOnTheBorderHitTheWall) {
  const std::string yaml =
      "name: corner_rays\nsize_m: [4, 2]\nceiling_height_m: 3\nambient_light: 1.0\n"
      "floor: {kind: plain, color_rgb: [40, 160, 40]}\n"
      "ceiling: {kind: plain, color_rgb: [40, 40, 160]}\n"
      "walls:\n"
      "  - {name: outer, polyline_m: [[0, 0], [4, 0], [4, 2], [0, 2], [0, 0]], height_m: 3,\n"
      "     texture: {kind: plain, color_rgb: [220, 30, 30]}}\n"
      "route:\n  waypoints_m: [[1, 1], [3, 1], [3, 1.5]]\n"
      "camera: {panorama_width_px: 72, panorama_height_px: 24}\n";
  const World world = ParseWorld(yaml, "corner_rays.yaml");
  Renderer renderer(world);
  std::vector<int> horizon_rows;
  for (int r = 0; r < world.camera.panorama_height_px; ++r) {
    if (std::abs(renderer.RowElevationRad(r)) < 3.0 * kPi / 180.0) horizon_rows.push_back(r);
  }
  ASSERT_FALSE(horizon_rows.empty());
  int poses = 0, pixels = 0, wall_pixels = 0;
  std::string first_miss;
  for (int ix = 1; ix < 20; ++ix) {
    for (int iy = 1; iy < 10; ++iy) {
      const cv::Mat pano = renderer.RenderPanorama(MakePose(0.2 * ix, 0.2 * iy, 0.0));
      ++poses;
      for (int r : horizon_rows) {
        for (int c = 0; c < pano.cols; ++c) {
          const cv::Vec3b px = pano.at<cv::Vec3b>(r, c);
          ++pixels;
          const bool red = px[2] > 2 * std::max(px[0], px[1]);
          wall_pixels += red;
          if (!red && first_miss.empty()) {
            first_miss = "camera (" + std::to_string(0.2 * ix) + ", " + std::to_string(0.2 * iy) +
                         ") column " + std::to_string(c);
          }
        }
      }
    }
  }
  EXPECT_EQ(poses, 171);
  EXPECT_EQ(wall_pixels, pixels) << "first pixel without the wall: " << first_miss;
}

// Sensor noise is zero-mean with the camera's sigma and a function of the frame seed.
TEST(Renderer, SensorNoiseIsSeededWithTheCameraSigma) {
  const World world = LoadBuiltinWorld("home_store");
  Renderer renderer(world, 9);
  cv::Mat flat(world.camera.ring_height_px, world.camera.ring_width_px, CV_8UC3,
               cv::Scalar::all(128));
  cv::Mat n1 = flat.clone(), n2 = flat.clone(), n3 = flat.clone();
  renderer.AddSensorNoise(&n1, 1);
  renderer.AddSensorNoise(&n2, 1);
  renderer.AddSensorNoise(&n3, 2);
  EXPECT_EQ(cv::norm(n1, n2, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(n1, n3, cv::NORM_INF), 0.0);
  cv::Mat diff;
  n1.convertTo(diff, CV_64F);
  diff -= cv::Scalar::all(128);
  cv::Scalar mean, sd;
  cv::meanStdDev(diff.reshape(1), mean, sd);
  // Rounding to integers adds 1/12 grey level^2 of variance.
  const double expected =
      std::sqrt(world.camera.noise_sigma_gray * world.camera.noise_sigma_gray + 1.0 / 12.0);
  EXPECT_NEAR(sd[0], expected, 0.05 * expected);
  EXPECT_NEAR(mean[0], 0.0, 0.02);
}

}  // namespace
}  // namespace omnicml
