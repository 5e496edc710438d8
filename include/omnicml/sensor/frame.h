// Frames, sessions and the streaming frame source shared by log readers, the simulator
// and the engine (docs/design.md "Data flow", "Logs", "Sessions").
#ifndef OMNICML_SENSOR_FRAME_H_
#define OMNICML_SENSOR_FRAME_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "omnicml/geometry/pose.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {

// How a session (one day) starts.
enum class SessionStartMode {
  kKnownPose,  // the robot leaves its dock at a known pose with covariance
  kContinue,   // odometry and estimate go on from the previous session
  kGlobal,     // no prior: the first confident p(x|y) seeds the mixture
};
std::string ToString(SessionStartMode mode);                        // known|continue|global
SessionStartMode SessionStartModeFromString(const std::string& s);  // throws omnicml::Error

struct SessionStart {
  SessionStartMode mode = SessionStartMode::kKnownPose;
  Pose2 map_T_robot = Pose2::Zero();                                             // kKnownPose only
  Eigen::Matrix3d covariance = Eigen::Vector3d(0.01, 0.01, 0.001).asDiagonal();  // m^2, rad^2
};

enum class ImageKind { kRawRing, kPanorama };

// What a session's camera delivers.
struct CameraModel {
  // kRawRing: a raw camera image of `calibration`'s model (ring, fisheye or
  // equirectangular; camera_model.h) that is unwrapped into the panorama.
  ImageKind kind = ImageKind::kPanorama;
  int image_width = 0;  // pixels of the delivered image
  int image_height = 0;
  CameraCalibration calibration;  // meaningful for kRawRing only
  // Optional user mask (CV_8UC1, image size; kRawRing only): zero marks pixels that never
  // show the scene (robot body, mounts, cables). Empty: every pixel is usable.
  cv::Mat mask;
  // The mask's file as named in session.yaml (relative to the session directory); "" when
  // there is none.
  std::string mask_image;
};

struct SessionInfo {
  std::string name;       // directory name (sessions sort by name)
  std::string day_label;  // free text, e.g. "day 3"
  double start_time_s = 0.0;
  CameraModel camera;
  SessionStart start;
};

struct Frame {
  int session_index = 0;  // 0-based index of the session (day)
  std::int64_t index_in_session = 0;
  std::int64_t global_index = 0;  // 0-based over all sessions
  double stamp_s = 0.0;           // strictly increasing within a session
  cv::Mat image;                  // raw ring or panorama, CV_8UC1 or CV_8UC3 (BGR)
  Pose2 odom_T_robot = Pose2::Zero();
  std::optional<Pose2> map_T_robot_truth;  // ground truth, when known
};

// A stream of frames over one or more sessions, read lazily (a 100k-frame log is never
// held in memory). Not thread-safe; one consumer.
class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual int NumSessions() const = 0;
  virtual const SessionInfo& Session(int index) const = 0;
  // Fills `frame` with the next frame and returns true, or returns false at the end of
  // the last session. Throws omnicml::Error (naming file and line) on a bad frame.
  virtual bool Next(Frame* frame) = 0;
};

}  // namespace omnicml

#endif  // OMNICML_SENSOR_FRAME_H_
