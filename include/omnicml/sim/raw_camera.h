// Raw camera images of the kinds real robots record, rendered by the simulator with their
// ground-truth calibration (docs/design.md "Simulator", "Camera models"), so calibration
// and localization can be measured against the truth on each kind:
//   ring                today's catadioptric ring: centred, inside the image, dark hole.
//   clipped_ring        the ring 1.25x larger and a few pixels off-centre, so the image's
//                       top and bottom edges cut it (pixels outside are invalid).
//   bright_centre_ring  today's ring, off-centre, with the robot's bright body filling the
//                       hole (a light disc with dark bolts and a cable).
//   fisheye             one upward circular fisheye (equidistant, 250 deg field of view,
//                       so its edge looks at the ring's lowest elevation), off-centre in a
//                       square image; everything up to the zenith is rendered.
// Every kind's panorama band is the world camera's [elevation_min_deg,
// elevation_max_deg] at panorama_width_px x panorama_height_px, so the engine sees the
// same panorama geometry from each (up to each model's resampling).
//
// Thread-safety: RawCameraRenderer::Render is const and thread-safe; SetState is not.
#ifndef OMNICML_SIM_RAW_CAMERA_H_
#define OMNICML_SIM_RAW_CAMERA_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "omnicml/geometry/pose.h"
#include "omnicml/sim/renderer.h"
#include "omnicml/sim/world.h"
#include "omnicml/unwrap/camera_model.h"

namespace omnicml {

enum class SimulatedCamera { kRing, kClippedRing, kBrightCentreRing, kFisheye };
// "ring", "clipped_ring", "bright_centre_ring", "fisheye".
std::string ToString(SimulatedCamera camera);
// Throws omnicml::Error naming the unknown name and the known ones.
SimulatedCamera SimulatedCameraFromString(const std::string& name);

// A raw camera's ground truth: its calibration and image size.
struct RawCameraSetup {
  CameraCalibration calibration;
  int image_width = 0;
  int image_height = 0;
};

// The ground truth of `kind` for a world's camera spec (kRing: SimulatedCalibration).
RawCameraSetup SimulatedRawCamera(const CameraSpec& spec, SimulatedCamera kind);

// Renders the raw images of one kind. Lifecycle: construct from the world, SetState with
// the main renderer's state whenever it changes, then Render per frame.
class RawCameraRenderer {
 public:
  RawCameraRenderer(const World& world, SimulatedCamera kind);
  ~RawCameraRenderer();
  RawCameraRenderer(const RawCameraRenderer&) = delete;
  RawCameraRenderer& operator=(const RawCameraRenderer&) = delete;

  // The world state (forwarded to the fisheye's own renderer of the sky).
  void SetState(const WorldState& state);
  // The raw image (CV_8UC3 of setup()'s size, no sensor noise) of the robot at
  // map_T_robot. `panorama` is the main renderer's panorama at that pose (the rings are
  // mapped from it); the fisheye renders its own taller panorama, up to the zenith.
  cv::Mat Render(const cv::Mat& panorama, const Pose2& map_T_robot,
                 const std::vector<Person>& people) const;
  const RawCameraSetup& setup() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace omnicml

#endif  // OMNICML_SIM_RAW_CAMERA_H_
