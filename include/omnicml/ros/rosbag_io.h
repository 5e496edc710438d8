// ROS 1 bags <-> omnicml logs (logs/log_format.h), through librosbag_storage's C++ API
// (rosbag::Bag, rosbag::View): no ROS master is involved.
//
// Export (ExportRosbag) writes, per frame of the log, with the bag time and header stamp
// stamp_s + stamp_offset_s (see below):
//   image_topic    sensor_msgs/Image (mono8 or bgr8, frame camera_frame) or, with
//                  compressed, sensor_msgs/CompressedImage (format "png", lossless)
//   odom_topic     nav_msgs/Odometry, odom_frame -> base_frame (odom_T_robot, z = 0)
//   /tf            tf2_msgs/TFMessage with the same transform
//   truth_topic    geometry_msgs/PoseStamped in map_frame (map_T_robot), frames with truth only
//   session_topic  std_msgs/String, one per session, stamped 1 us before its first frame:
//                  the session's session.yaml text and name, and the stamp offset, as YAML
//                  (SessionMessageText), so an import restores the sessions exactly.
// ROS times must be positive: stamp_offset_s is 1 s minus the log's first stamp when that
// stamp is below 1 s, else 0. Stamps go through ROS's nanosecond times, so imported stamps
// can differ from the original in the last digits (below 1 ns); nothing else changes.
//
// Import (ImportRosbag) reads one or more bags into one log:
//  - images: sensor_msgs/Image (mono8, bgr8, rgb8, bgra8, rgba8, mono16, 16UC1, bgr16,
//    rgb16; 16-bit scaled to 8 bit as v * 255 / 65535; either byte order) or
//    sensor_msgs/CompressedImage (PNG or JPEG), by header stamp;
//  - odometry: nav_msgs/Odometry, geometry_msgs/PoseStamped or PoseWithCovarianceStamped
//    on odom_topic, or the tf transforms (/tf) whose child frame is odom_tf_frame;
//    interpolated to each image stamp (odometry_buffer.h); an image outside the odometry's
//    time span is skipped and counted;
//  - ground truth (optional): the same message types on truth_topic, interpolated when the
//    two samples around the image stamp are at most truth_max_gap_s apart, else absent;
//  - sessions: from session_topic when the bag has it (a bag written by ExportRosbag),
//    else one per bag, split where consecutive image stamps are more than split_gap_s
//    apart (when > 0); camera: the calibration YAML (omni_ring) when given, else automatic
//    from the first image of the session (a panorama when it is at least twice as wide as
//    high, else a raw ring calibrated by AutoCalibrate).
// The log is written by LogWriter (staging directory, renamed when complete): a failure
// leaves nothing under the output path.
//
// Errors: omnicml::Error "<bag>: topic <t>: message <i>: <what>" (i = 0-based index of the
// message on that topic), or "<bag>: <what>" for an unreadable, unindexed or truncated bag.
#ifndef OMNICML_ROS_ROSBAG_IO_H_
#define OMNICML_ROS_ROSBAG_IO_H_

#include <cstdint>
#include <string>
#include <vector>

#include "omnicml/sensor/frame.h"

namespace omnicml {

struct RosbagExportOptions {
  std::string image_topic = "/omnicml/image";         // images (Image or CompressedImage)
  bool compressed = false;                            // CompressedImage (PNG) instead of Image
  std::string odom_topic = "/odom";                   // nav_msgs/Odometry
  bool odom_tf = true;                                // also odom_frame -> base_frame on /tf
  std::string truth_topic = "/omnicml/ground_truth";  // geometry_msgs/PoseStamped, map frame
  std::string session_topic = "/omnicml/session";     // std_msgs/String per session
  std::string map_frame = "map";                      // frame of the ground truth
  std::string odom_frame = "odom";                    // parent frame of the odometry
  std::string base_frame = "base_link";               // the robot (odometry child frame)
  std::string camera_frame = "omni_camera";           // frame_id of the images
  bool overwrite = false;                             // replace an existing bag
  void Validate() const;                              // throws omnicml::Error naming the field
};

struct RosbagExportSummary {
  std::int64_t frames = 0;
  int sessions = 0;
  double stamp_offset_s = 0.0;
};

// Writes the whole log to bag_path (a temporary file renamed into place when complete).
// Throws omnicml::Error naming the log file or the bag.
RosbagExportSummary ExportRosbag(const std::string& log_dir, const std::string& bag_path,
                                 const RosbagExportOptions& options = {});

struct RosbagImportOptions {
  std::string image_topic;    // required
  std::string odom_topic;     // exactly one of odom_topic and odom_tf_frame
  std::string odom_tf_frame;  // child frame of the tf odometry transform, e.g. base_link
  std::string truth_topic;    // optional
  std::string session_topic = "/omnicml/session";  // used when present in the bag
  std::string calibration_yaml;                    // optional OmniCalibration YAML: raw ring images
  double split_gap_s = 0.0;      // > 0: new session where image stamps jump by more; seconds
  double truth_max_gap_s = 0.5;  // seconds, > 0
  SessionStartMode first_start = SessionStartMode::kKnownPose;  // bags without session_topic
  SessionStartMode later_start = SessionStartMode::kGlobal;
  bool overwrite = false;
  void Validate() const;
};

struct RosbagImportSummary {
  std::int64_t frames = 0;
  int sessions = 0;
  std::int64_t frames_with_truth = 0;
  std::int64_t skipped_without_odometry = 0;  // images outside the odometry's time span
};

RosbagImportSummary ImportRosbag(const std::vector<std::string>& bag_paths,
                                 const std::string& log_dir, const RosbagImportOptions& options);

// The session message text (YAML: name, stamp_offset_s, session) and its parser
// (throws omnicml::Error prefixed by `source`).
std::string SessionMessageText(const SessionInfo& info, double stamp_offset_s);
SessionInfo ParseSessionMessage(const std::string& text, const std::string& source,
                                double* stamp_offset_s = nullptr);

}  // namespace omnicml

#endif  // OMNICML_ROS_ROSBAG_IO_H_
