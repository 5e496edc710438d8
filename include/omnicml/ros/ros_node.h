// The ROS 1 layer of omnicml_node over LiveEngine (live/live_engine.h): message
// conversion, publishers, parameters and services. Everything the engine does runs on the
// LiveEngine's worker thread (images are decoded there too); the subscriber callbacks only
// enqueue, and the services run on their own callback queue and thread, so neither a slow
// frame nor a map save ever blocks the spinner that receives images and odometry.
//
// Topics (names relative to the node's private namespace "~" unless absolute):
//   subscribes  image_topic (sensor_msgs/Image, or CompressedImage with ~compressed),
//               odom_topic (nav_msgs/Odometry: odom_T_robot), session_topic (std_msgs/String:
//               a session written by `omnicml export rosbag`; begins that session)
//   publishes   ~pose (geometry_msgs/PoseWithCovarianceStamped, map frame: the strongest
//               component of p(x_t) and its covariance, as `omnicml run` reports it),
//               /tf (tf2_msgs/TFMessage) map_frame -> odom_frame, ~hypotheses
//               (geometry_msgs/PoseArray: the components of p(x_t)), ~reference_views
//               (visualization_msgs/MarkerArray: one sphere per view component, red (weight 0) to
//               green (weight 1), every ~views_every_frames frames), ~dropped_frames
//               (std_msgs/Int64, when it grows)
//   services    ~save_map, ~new_session, ~forgetting_active, ~forgetting_passive,
//               ~forgetting_static (std_srvs/Trigger)
// Parameters: see RosNodeParameters.
//
// Thread-safety: construct, Spin and destroy on one thread.
#ifndef OMNICML_ROS_ROS_NODE_H_
#define OMNICML_ROS_ROS_NODE_H_

#include <memory>
#include <string>
#include <vector>

#include "omnicml/live/live_engine.h"

namespace omnicml {

struct RosNodeParameters {
  std::string image_topic = "/omnicml/image";
  bool compressed = false;  // subscribe to sensor_msgs/CompressedImage
  std::string odom_topic = "/odom";
  std::string session_topic = "/omnicml/session";
  std::string map_frame = "map";
  std::string odom_frame = "odom";
  std::string config;       // engine options YAML (CmlEngineOptions keys); empty: defaults
  std::string forgetting;   // active | passive | static; empty: the config's
  int threads = 0;          // engine threads; 0: the config's
  std::string map_in;       // engine/map file loaded at start (omnicml run --map-out, ~save_map)
  std::string map_out;      // saved on shutdown and by ~save_map
  std::string calibration;  // OmniCalibration YAML: the images are raw rings; else panoramas
  std::string start_mode;   // first session: known | global (default: known, global with map_in)
  std::vector<double> start_pose = {0.0, 0.0, 0.0};  // x_m, y_m, phi_rad (known start)
  std::string new_session_start = "continue";        // ~new_session and stamp gaps
  int queue_size = 1;                                // LiveEngineOptions::queue_capacity_frames
  double odometry_wait_s = 0.5;                      // LiveEngineOptions
  double session_gap_s = 0.0;                        // LiveEngineOptions
  int views_every_frames = 20;  // LiveEngineOptions::reference_views_every_frames
  std::string latency_csv;      // per-frame latencies written here on shutdown
  // A new map: the first frames held to measure the frame step its per-frame options are
  // restated for (LiveEngineOptions::frame_step_frames); 0 or 1: options as configured.
  int frame_step_frames = LiveEngineOptions{}.frame_step_frames;
};

class RosNode {
 public:
  // ros::init for the node `name` (removes the ROS arguments from argv; no SIGINT handler:
  // Spin installs its own). Call once, before constructing the node.
  static void InitRos(int& argc, char** argv, const std::string& name);

  // Reads the private parameters, loads or builds the engine, advertises and subscribes.
  // Requires ros::init. Throws omnicml::Error on a bad parameter or map.
  RosNode();
  ~RosNode();
  // Spins until ros::ok() is false (SIGINT), then stops the engine (queued frames are
  // processed), saves map_out if set, and logs the latency and drop summary.
  void Spin();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace omnicml

#endif  // OMNICML_ROS_ROS_NODE_H_
