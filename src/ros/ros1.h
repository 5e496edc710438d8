// The ROS 1 boundary of the ros module. Debian's ROS 1 message headers need
// std::allocator<T>::rebind, which C++20 removed, so every file that includes a ROS header
// is compiled as C++17 (library omnicml_ros1: ros1_bag.cc, ros1_node.cc) and sees only
// this header: standard types and cv::Mat, no omnicml header (those are C++20). The C++20
// side (rosbag_io.cc, ros_node.cc) turns the std::runtime_error thrown here into
// omnicml::Error with the bag, topic and message index.
//
// Poses are planar: (x_m, y_m, phi_rad), read from 3D poses as x, y and the yaw of the
// quaternion (z up), written with z = 0, roll = pitch = 0.
//
// Thread-safety: BagWriter/BagReader thread-compatible; NodeTransport's Publish* may be
// called from any thread (roscpp publishers are thread-safe).
#ifndef OMNICML_SRC_ROS_ROS1_H_
#define OMNICML_SRC_ROS_ROS1_H_

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

namespace omnicml::ros1 {

struct PlanarPose {
  double x_m = 0.0, y_m = 0.0, phi_rad = 0.0;
};

// sensor_msgs/Image fields -> CV_8UC1 or CV_8UC3 (BGR). Encodings: mono8, 8UC1, bgr8, rgb8,
// 8UC3, bgra8, rgba8, mono16, 16UC1, bgr16, rgb16 (16-bit scaled v * 255 / 65535, either
// byte order). Throws std::runtime_error naming the encoding or the size mismatch.
cv::Mat ImageFromRaw(const std::string& encoding, std::uint32_t width, std::uint32_t height,
                     std::uint32_t step, bool big_endian, const std::vector<std::uint8_t>& data);
// sensor_msgs/CompressedImage data: PNG or JPEG (by signature) -> CV_8UC1 or CV_8UC3.
cv::Mat ImageFromCompressed(const std::string& format, const std::vector<std::uint8_t>& data);

// A bag being written. Times are seconds (> 0, representable as ros::Time).
class BagWriter {
 public:
  explicit BagWriter(const std::string& path);  // throws std::runtime_error
  ~BagWriter();
  // CV_8UC1 -> mono8, CV_8UC3 -> bgr8; compressed: sensor_msgs/CompressedImage, PNG.
  void WriteImage(const std::string& topic, double stamp_s, const std::string& frame_id,
                  std::uint32_t seq, const cv::Mat& image, bool compressed);
  // A raw sensor_msgs/Image of any encoding (tests of foreign bags).
  void WriteRawImage(const std::string& topic, double stamp_s, const std::string& encoding,
                     std::uint32_t width, std::uint32_t height, std::uint32_t step, bool big_endian,
                     std::vector<std::uint8_t> data,
                     double bag_time_s = 0.0);  // 0: the stamp
  void WriteOdometry(const std::string& topic, double stamp_s, const std::string& frame,
                     const std::string& child_frame, const PlanarPose& pose);
  void WriteTf(double stamp_s, const std::string& frame, const std::string& child_frame,
               const PlanarPose& pose);
  void WritePoseStamped(const std::string& topic, double stamp_s, const std::string& frame,
                        const PlanarPose& pose);
  void WriteString(const std::string& topic, double time_s, const std::string& text);
  void Close();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// One message during BagReader::ForEach; the reads throw std::runtime_error (without a
// location) when the message is of another type or does not decode.
class BagMessage {
 public:
  virtual ~BagMessage() = default;
  virtual std::string type() const = 0;
  virtual double time_s() const = 0;  // bag (receive) time
  // sensor_msgs/Image or CompressedImage: header stamp and pixels.
  virtual void ReadImage(double* stamp_s, cv::Mat* image) const = 0;
  // nav_msgs/Odometry, geometry_msgs/PoseStamped or PoseWithCovarianceStamped.
  virtual void ReadPose(double* stamp_s, PlanarPose* pose) const = 0;
  // tf2_msgs/TFMessage: the transforms whose child frame is `child` (stamp, pose).
  virtual std::vector<std::pair<double, PlanarPose>> ReadTf(const std::string& child) const = 0;
  // std_msgs/String.
  virtual std::string ReadString() const = 0;
};

class BagReader {
 public:
  // Opens and indexes the bag; throws std::runtime_error (rosbag's message) when it is not
  // a bag, unindexed or truncated.
  explicit BagReader(const std::string& path);
  ~BagReader();
  // (topic, message type) of every connection.
  std::vector<std::pair<std::string, std::string>> Topics() const;
  // Visits the messages of `topic` in bag-time order (every topic when empty); stops when
  // `visit` returns false. A message whose data cannot be read throws std::runtime_error.
  void ForEach(const std::string& topic, const std::function<bool(const BagMessage&)>& visit) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// ---------------------------------------------------------------------------------------
// The node's transport.

// ros::init with the node name (no SIGINT handler: the node installs its own), then
// ros::start: the node runs until Shutdown, whatever NodeHandles come and go.
void InitNode(int& argc, char** argv, const std::string& name);
bool Ok();
void Shutdown();
double NowSeconds();  // ros::Time::now()
void LogInfo(const std::string& text);
void LogWarn(const std::string& text);
void LogWarnThrottled(double period_s, const std::string& text);
void LogError(const std::string& text);

// Private parameters (~name); absent ones keep *value. Throws std::runtime_error on a
// parameter of the wrong type.
void GetParam(const std::string& name, std::string* value);
void GetParam(const std::string& name, bool* value);
void GetParam(const std::string& name, int* value);
void GetParam(const std::string& name, double* value);
void GetParam(const std::string& name, std::vector<double>* value);

struct NodeTopics {
  std::string image_topic, odom_topic, session_topic;
  bool compressed = false;
  std::uint32_t image_queue = 100;
  std::string map_frame = "map", odom_frame = "odom";
};

struct NodeHandlers {
  // An image message: `decode` converts it to CV_8UC1/CV_8UC3 (throws std::runtime_error
  // naming topic, seq and the problem); call it where the image is used, so that images
  // dropped before use are never decoded.
  std::function<void(double stamp_s, std::function<cv::Mat()> decode)> on_image;
  std::function<void(double stamp_s, const PlanarPose& odom_T_robot)> on_odometry;
  std::function<void(const std::string& text)> on_session;
  // Services; each returns (success, message).
  std::function<std::pair<bool, std::string>()> save_map, new_session;
  std::function<std::pair<bool, std::string>(const std::string& mode)> forgetting;
};

class NodeTransport {
 public:
  // Advertises, subscribes (one spinner thread for the subscriptions) and offers the
  // services (their own callback queue and thread).
  NodeTransport(const NodeTopics& topics, NodeHandlers handlers);
  ~NodeTransport();
  void PublishPose(double stamp_s, const PlanarPose& map_T_robot,
                   const std::array<double, 9>& covariance);
  void PublishMapToOdom(double stamp_s, const PlanarPose& map_T_odom);
  void PublishHypotheses(double stamp_s, const std::vector<PlanarPose>& poses);
  // One sphere per (x_m, y_m, weight in [0, 1]); red (0) to green (1).
  void PublishViews(const std::vector<std::array<double, 3>>& views);
  void PublishDropped(std::int64_t dropped);
  // Stops receiving (subscriptions) / serving (services).
  void StopSubscriptions();
  void StopServices();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Calls a std_srvs/Trigger service (initialising ROS in this process as an anonymous
// node first if needed); false when it is not available within timeout_s or the call
// fails. *message: the response's message or what failed.
bool CallTrigger(const std::string& service, double timeout_s, std::string* message);

}  // namespace omnicml::ros1

#endif  // OMNICML_SRC_ROS_ROS1_H_
