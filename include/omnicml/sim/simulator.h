// The simulated multi-day frame source (docs/design.md "Simulator", "Sessions", "Motion
// model"): a robot drives laps of a world's route, one session per day, while the
// world's appearance changes by its event schedule and people walk around; frames carry
// the rendered image, noisy odometry and the ground truth.
//
// Ground truth: constant speed along the route loop (corners rounded by arcs), one frame
// every step_m metres; each day starts at the route start (start mode kKnownPose, the
// default, and kGlobal at a seeded random place on the route) or where the previous day
// ended (kContinue). Odometry: each true increment (rot1, trans, rot2) between frames is
// perturbed by sample_motion_model_odometry of Thrun et al. with the world's a1..a4,
//   rot1' = rot1 + N(0, a1 rot1^2 + a2 trans^2)
//   trans' = trans + N(0, a3 trans^2 + a4 (rot1^2 + rot2^2))
//   rot2' = rot2 + N(0, a1 rot2^2 + a2 trans^2)
// (the variances of M in docs/design.md "Motion model"), and odom_T_robot integrates the
// noisy increments with ApplyIncrement. A day's odometry starts at the true start pose
// (kKnownPose), at zero (kGlobal) or where it ended (kContinue).
//
// Determinism: every random stream is seeded from SimulatorOptions::seed with per-day
// and per-frame sub-seeds, so the same options give the same frames byte for byte,
// whatever else the process does. Frames are produced on the fly; memory does not grow
// with the number of frames.
#ifndef OMNICML_SIM_SIMULATOR_H_
#define OMNICML_SIM_SIMULATOR_H_

#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/logs/antworld.h"
#include "omnicml/sensor/frame.h"
#include "omnicml/sim/raw_camera.h"
#include "omnicml/sim/renderer.h"
#include "omnicml/sim/world.h"

namespace omnicml {

struct SimulatorOptions {
  // A built-in world name (BuiltinWorldNames()) or the path of a world YAML file.
  std::string world = "home_store";
  // Number of sessions (days), >= 1.
  int days = 1;
  // Frames per session, >= 1.
  int frames_per_day = 300;
  // Seed of every random stream (odometry noise, people, events, sensor noise).
  std::uint64_t seed = 1;
  // kRawRing: ring images through the unwrapper's inverse model; kPanorama: the
  // panorama itself (no unwrapping needed downstream).
  ImageKind output = ImageKind::kRawRing;
  // Which raw camera renders the kRawRing images (raw_camera.h): today's ring, a clipped
  // ring, a ring around the robot's bright body, or an upward fisheye; each session's
  // camera carries the kind's ground-truth calibration.
  SimulatedCamera camera = SimulatedCamera::kRing;
  // Distance driven between consecutive frames, metres (> 0).
  double step_m = 0.2;
  // How days after the first start (day 1 always starts at the known route start).
  SessionStartMode later_days_start = SessionStartMode::kKnownPose;
  // With false, Frame::image stays empty (fast pose-only runs: trajectories, noise
  // statistics); world events and people still advance.
  bool render_images = true;
  // Add the camera's sensor noise to the delivered images.
  bool sensor_noise = true;
  // Draw the world's people (occluders).
  bool people = true;
  // Standard deviations of the start pose covariance of SessionStart (m, m, rad): in
  // (0, 1e6] m and (0, 10] rad, the square roots of the logs' variance limits
  // (common/limits.h kMaxPositionVarianceM2, kMaxHeadingVarianceRad2).
  double start_sigma_xy_m = 0.1;
  double start_sigma_phi_rad = 0.03;

  // Throws omnicml::Error naming the field.
  void Validate() const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, SimulatorOptions& o) {
  v("world", o.world);
  v("days", o.days);
  v("frames_per_day", o.frames_per_day);
  v("seed", o.seed);
  v.NamedEnum("output", o.output,
              {{ImageKind::kRawRing, "raw_ring"}, {ImageKind::kPanorama, "panorama"}});
  v.Enum("camera", o.camera,
         {SimulatedCamera::kRing, SimulatedCamera::kClippedRing, SimulatedCamera::kBrightCentreRing,
          SimulatedCamera::kFisheye});
  v("step_m", o.step_m);
  v.Enum("later_days_start", o.later_days_start,
         {SessionStartMode::kKnownPose, SessionStartMode::kContinue, SessionStartMode::kGlobal});
  v("render_images", o.render_images);
  v("sensor_noise", o.sensor_noise);
  v("people", o.people);
  v("start_sigma_xy_m", o.start_sigma_xy_m);
  v("start_sigma_phi_rad", o.start_sigma_phi_rad);
}

// SimulatorOptions in YAML (keys = member names; absent keys keep their defaults),
// validated. `world_name`, which `omnicml simulate` writes into simulation.yaml, is
// accepted and skipped (kSimulatorRunKeys), so that file loads back. Throws
// omnicml::Error "<file>:<line>: ..." naming the key.
inline const std::vector<std::string> kSimulatorRunKeys = {"world_name"};
SimulatorOptions ParseSimulatorOptionsYaml(const std::string& yaml_text, const std::string& source);
SimulatorOptions LoadSimulatorOptions(const std::string& path);
// Every field as YAML; LoadSimulatorOptions reads it back to equal options.
std::string SimulatorOptionsToYaml(const SimulatorOptions& options);

// A closed route with rounded corners, parameterised by arc length.
class RoutePath {
 public:
  // Throws omnicml::Error if fewer than 3 distinct waypoints.
  RoutePath(const std::vector<Eigen::Vector2d>& waypoints_m, double turn_radius_m);
  double length_m() const { return length_m_; }
  // Pose at arc length s (taken modulo the loop length): position on the path, heading
  // along its tangent.
  Pose2 PoseAt(double s_m) const;
  // Points every step_m along the loop (for drawing).
  std::vector<Eigen::Vector2d> Sample(double step_m) const;

 private:
  struct Piece {
    bool arc = false;
    Eigen::Vector2d start = Eigen::Vector2d::Zero();  // line: start point; arc: centre
    double heading_rad = 0;                           // line: direction; arc: heading at its start
    double radius_m = 0;                              // arc only
    double turn_sign = 0;                             // arc: +1 counter-clockwise, -1 clockwise
    double length_m = 0;
    double s0_m = 0;  // arc length at the piece's start
  };
  std::vector<Piece> pieces_;
  double length_m_ = 0;
};

// Noisy odometry for a true increment: SampleOdometryIncrement (geometry/motion_model.h) implements
// the sample_motion_model_odometry of the file comment; the simulator calls it with a generator
// seeded per frame.

// FrameSource over simulated days. Not thread-safe; one consumer.
class SimulatedFrameSource : public FrameSource {
 public:
  // Loads the world and prepares the renderer. Throws omnicml::Error on bad options or a
  // bad world.
  explicit SimulatedFrameSource(const SimulatorOptions& options);
  // Uses an already loaded world (options.world is ignored).
  SimulatedFrameSource(const SimulatorOptions& options, const World& world);
  ~SimulatedFrameSource() override;

  int NumSessions() const override;
  const SessionInfo& Session(int index) const override;
  bool Next(Frame* frame) override;

  const World& world() const;
  const SimulatorOptions& options() const;
  const RoutePath& route() const;
  // The world state and the people of the last frame delivered.
  const WorldState& state() const;
  const std::vector<Person>& people() const;
  // The panorama of the last frame delivered (before ring rendering and noise); empty
  // with render_images false.
  const cv::Mat& last_panorama() const;
  const Renderer& renderer() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace omnicml

#endif  // OMNICML_SIM_SIMULATOR_H_
