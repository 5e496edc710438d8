// Renderer of simulated worlds (docs/design.md "Simulator"): 2.5-D ray casting into a
// cylindrical panorama, then the raw catadioptric ring image through the unwrapper's
// inverse model (OmniUnwrapper::Render) plus seeded sensor noise.
//
// Ray casting: one ray per panorama column, along the map azimuth
//   theta_c = heading + 2 pi c / W   (counter-clockwise; omni_unwrapper.h convention),
// traversing a uniform grid of 1 m cells over the world's wall, shelf, box and window
// segments (and testing the people's cylinders). Every hit along the ray is kept in
// distance order and fills the rows between its bottom and top elevation as seen from
// the camera height that no nearer hit has filled, so tall things behind low shelves
// stay visible; the ray stops once no farther surface can fill a row. Rows left empty
// show the floor (below the horizon) or the ceiling with its lamps (above). Row r of H
// looks at elevation e_r = e_max - (r + 0.5) (e_max - e_min) / H.
//
// Appearance is a function of the world point only (texture coordinates are the
// position along the surface outline and the height; shading is the light of the
// light zones at the hit point and a fixed per-face factor), so the same point looks the
// same from every pose, and turning in place by k * 2 pi / W rolls the panorama by
// exactly k columns: after[c] = before[(c + k) mod W].
//
// Lifecycle: construct from a World, SetState() whenever events changed the world
// state, then render. Render* methods are const and safe to call from several threads
// at once; SetState is not (no rendering may run meanwhile).
#ifndef OMNICML_SIM_RENDERER_H_
#define OMNICML_SIM_RENDERER_H_

#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "omnicml/geometry/pose.h"
#include "omnicml/sim/world.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {

// A walking person, drawn as a vertical cylinder standing on the floor.
struct Person {
  Eigen::Vector2d position_m = Eigen::Vector2d::Zero();
  double radius_m = 0.25;
  double height_m = 1.75;
  std::uint64_t seed = 0;  // picks the clothes' colours
};

// The ring calibration of a simulated camera: centred ring of the camera's radii,
// row 0 (highest elevation) on the outer radius, counter-clockwise, column 0 along the
// image x axis, panorama size of the camera.
OmniCalibration SimulatedCalibration(const CameraSpec& camera);

class Renderer {
 public:
  // Prepares the camera (elevation tables, ring maps) and the world's initial state.
  // noise_seed seeds the sensor-noise table. Throws omnicml::Error on a bad camera.
  explicit Renderer(const World& world, std::uint64_t noise_seed = 0);
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  // Adopts a world state (obstacle offsets, textures, lights, curtains); rebuilds the
  // segment grid and the light grid. The state must belong to this renderer's world.
  void SetState(const WorldState& state);
  const WorldState& state() const;

  // The panorama (CV_8UC3, BGR, panorama_width_px x panorama_height_px) seen by the
  // camera on a robot at map_T_robot (camera at the robot's origin, height_m above the
  // floor), without sensor noise.
  cv::Mat RenderPanorama(const Pose2& map_T_robot, const std::vector<Person>& people = {}) const;
  // As above, into *panorama (reallocated only if its size or type differ).
  void RenderPanorama(const Pose2& map_T_robot, const std::vector<Person>& people,
                      cv::Mat* panorama) const;

  // The raw ring image (CV_8UC3, ring_width_px x ring_height_px, black outside the ring)
  // of a panorama, through OmniUnwrapper::Render; no noise.
  cv::Mat RenderRing(const cv::Mat& panorama) const;

  // Adds the camera's zero-mean Gaussian sensor noise (noise_sigma_gray) to every byte,
  // saturating; the pattern is a function of (noise_seed, frame_seed) only.
  void AddSensorNoise(cv::Mat* image, std::uint64_t frame_seed) const;

  const World& world() const;
  const OmniUnwrapper& unwrapper() const;
  // Elevation of the centre of panorama row r, radians.
  double RowElevationRad(int row) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// A picture of the floor plan in `state` (obstacles filled, walls, windows, light zones
// switched on tinted), `path_m` drawn as a polyline and `poses` as arrows; px_per_m
// pixels per metre, y up. CV_8UC3.
cv::Mat DrawFloorPlan(const World& world, const WorldState& state,
                      const std::vector<Eigen::Vector2d>& path_m, const std::vector<Pose2>& poses,
                      double px_per_m);

}  // namespace omnicml

#endif  // OMNICML_SIM_RENDERER_H_
