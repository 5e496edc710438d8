#include "omnicml/sim/raw_camera.h"

#include <cmath>
#include <optional>

#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

// Highest elevation the fisheye's sky panorama renders (the zenith itself has no azimuth
// and the renderer's ceiling distance grows as 1 / tan(elevation)), degrees.
constexpr double kSkyElevationDeg = 89.0;
// How far off the image centre the non-trivial kinds put the optical axis, pixels: the
// automatic calibration must find it, not assume it.
constexpr double kOffsetXPx = 4.2;
constexpr double kOffsetYPx = -3.1;
// The clipped ring's radii relative to the world camera's.
constexpr double kClippedScale = 1.25;

FisheyeCalibration FisheyeTruth(const CameraSpec& spec, int side) {
  FisheyeCalibration f;
  f.center_x_px = (side - 1) * 0.5 + kOffsetXPx;
  f.center_y_px = (side - 1) * 0.5 + kOffsetYPx;
  f.circle_radius_px = spec.outer_radius_px + 10.0;
  // The circle's edge looks at the ring's lowest elevation.
  f.field_of_view_deg = 2.0 * (90.0 - spec.elevation_min_deg);
  f.projection = FisheyeProjection::kEquidistant;
  f.min_elevation_deg = spec.elevation_min_deg;
  f.max_elevation_deg = spec.elevation_max_deg;
  f.azimuth0_rad = 0.0;
  f.direction = RingDirection::kCounterClockwise;
  f.panorama_width = spec.panorama_width_px;
  f.panorama_height = spec.panorama_height_px;
  return f;
}

int FisheyeSide(const CameraSpec& spec) {
  return 2 * static_cast<int>(std::ceil(spec.outer_radius_px + 10.0)) + 40;
}

// The world with its camera looking from elevation_min_deg up to kSkyElevationDeg, rows
// as tall as the main camera's.
World SkyWorld(const World& world) {
  World sky = world;
  CameraSpec& c = sky.camera;
  const double rows_per_deg = c.panorama_height_px / (c.elevation_max_deg - c.elevation_min_deg);
  c.panorama_height_px =
      static_cast<int>(std::lround(rows_per_deg * (kSkyElevationDeg - c.elevation_min_deg)));
  c.elevation_max_deg = kSkyElevationDeg;
  return sky;
}

// The robot's body seen from the camera above it: a light disc with a darker hub, four
// bolts and a cable, inside the ring's hole.
void DrawRobotBody(const OmniCalibration& ring, cv::Mat* image) {
  const cv::Point2d c(ring.center_x_px, ring.center_y_px);
  const double r = ring.inner_radius_px - 1.0;
  constexpr int kShift = 4;  // sub-pixel drawing: 1/16 px
  const auto p = [](cv::Point2d q) {
    return cv::Point(static_cast<int>(std::lround(q.x * 16)),
                     static_cast<int>(std::lround(q.y * 16)));
  };
  const auto radius = [](double v) { return static_cast<int>(std::lround(v * 16)); };
  cv::circle(*image, p(c), radius(r), cv::Scalar(212, 216, 220), cv::FILLED, cv::LINE_AA, kShift);
  cv::circle(*image, p(c), radius(0.45 * r), cv::Scalar(150, 150, 155), cv::FILLED, cv::LINE_AA,
             kShift);
  for (int k = 0; k < 4; ++k) {
    const double a = kPi / 4 + k * kPi / 2;
    cv::circle(*image, p(c + 0.75 * r * cv::Point2d(std::cos(a), std::sin(a))), radius(0.07 * r),
               cv::Scalar(40, 40, 40), cv::FILLED, cv::LINE_AA, kShift);
  }
  cv::line(*image, p(c + 0.45 * r * cv::Point2d(1, 0.2)), p(c + 0.98 * r * cv::Point2d(0.98, 0.2)),
           cv::Scalar(30, 30, 30), 2, cv::LINE_AA, kShift);
}

}  // namespace

std::string ToString(SimulatedCamera camera) {
  switch (camera) {
    case SimulatedCamera::kRing:
      return "ring";
    case SimulatedCamera::kClippedRing:
      return "clipped_ring";
    case SimulatedCamera::kBrightCentreRing:
      return "bright_centre_ring";
    case SimulatedCamera::kFisheye:
      return "fisheye";
  }
  return "?";
}

SimulatedCamera SimulatedCameraFromString(const std::string& name) {
  for (SimulatedCamera c : {SimulatedCamera::kRing, SimulatedCamera::kClippedRing,
                            SimulatedCamera::kBrightCentreRing, SimulatedCamera::kFisheye}) {
    if (ToString(c) == name) return c;
  }
  throw Error(StrCat("unknown simulated camera '", name,
                     "' (known: ring, clipped_ring, bright_centre_ring, fisheye)"));
}

RawCameraSetup SimulatedRawCamera(const CameraSpec& spec, SimulatedCamera kind) {
  RawCameraSetup s;
  s.image_width = spec.ring_width_px;
  s.image_height = spec.ring_height_px;
  OmniCalibration ring = SimulatedCalibration(spec);
  switch (kind) {
    case SimulatedCamera::kRing:
      s.calibration = ring;
      break;
    case SimulatedCamera::kClippedRing:
      ring.center_x_px += kOffsetXPx;
      ring.center_y_px += kOffsetYPx;
      ring.inner_radius_px *= kClippedScale;
      ring.outer_radius_px *= kClippedScale;
      s.calibration = ring;
      break;
    case SimulatedCamera::kBrightCentreRing:
      ring.center_x_px += kOffsetXPx;
      ring.center_y_px += kOffsetYPx;
      s.calibration = ring;
      break;
    case SimulatedCamera::kFisheye:
      s.image_width = s.image_height = FisheyeSide(spec);
      s.calibration = FisheyeTruth(spec, s.image_width);
      break;
  }
  return s;
}

struct RawCameraRenderer::Impl {
  SimulatedCamera kind;
  RawCameraSetup setup;
  OmniUnwrapper unwrapper;                 // ground truth of the image (the sky's for fisheye)
  std::unique_ptr<Renderer> sky_renderer;  // fisheye only

  static CameraCalibration RenderCalibration(const World& world, SimulatedCamera kind,
                                             const RawCameraSetup& setup) {
    if (kind != SimulatedCamera::kFisheye) return setup.calibration;
    const World sky = SkyWorld(world);
    FisheyeCalibration f = setup.calibration.fisheye;
    f.max_elevation_deg = sky.camera.elevation_max_deg;
    f.panorama_height = sky.camera.panorama_height_px;
    return f;
  }

  Impl(const World& world, SimulatedCamera k)
      : kind(k),
        setup(SimulatedRawCamera(world.camera, k)),
        unwrapper(RenderCalibration(world, k, setup), setup.image_width, setup.image_height) {
    if (kind == SimulatedCamera::kFisheye)
      sky_renderer = std::make_unique<Renderer>(SkyWorld(world));
  }
};

RawCameraRenderer::RawCameraRenderer(const World& world, SimulatedCamera kind)
    : impl_(std::make_unique<Impl>(world, kind)) {}

RawCameraRenderer::~RawCameraRenderer() = default;

void RawCameraRenderer::SetState(const WorldState& state) {
  if (impl_->sky_renderer) impl_->sky_renderer->SetState(state);
}

const RawCameraSetup& RawCameraRenderer::setup() const { return impl_->setup; }

cv::Mat RawCameraRenderer::Render(const cv::Mat& panorama, const Pose2& map_T_robot,
                                  const std::vector<Person>& people) const {
  const Impl& m = *impl_;
  if (m.kind == SimulatedCamera::kFisheye) {
    return m.unwrapper.Render(m.sky_renderer->RenderPanorama(map_T_robot, people));
  }
  cv::Mat raw = m.unwrapper.Render(panorama);
  if (m.kind == SimulatedCamera::kBrightCentreRing) DrawRobotBody(m.setup.calibration.ring, &raw);
  return raw;
}

}  // namespace omnicml
