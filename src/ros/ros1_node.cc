// C++17 (ros1.h): the node's roscpp transport.
#include <cmath>
#include <stdexcept>

#include <geometry_msgs/PoseArray.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nav_msgs/Odometry.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/Int64.h>
#include <std_msgs/String.h>
#include <std_srvs/Trigger.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>

#include "ros/ros1.h"

namespace omnicml::ros1 {
namespace {

geometry_msgs::Pose ToPoseMsg(const PlanarPose& pose) {
  geometry_msgs::Pose p;
  p.position.x = pose.x_m;
  p.position.y = pose.y_m;
  p.orientation.z = std::sin(0.5 * pose.phi_rad);
  p.orientation.w = std::cos(0.5 * pose.phi_rad);
  return p;
}

PlanarPose FromPoseMsg(const geometry_msgs::Pose& p) {
  const auto& q = p.orientation;
  return {p.position.x, p.position.y,
          std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))};
}

template <class T>
void GetParamT(const std::string& name, T* value) {
  ros::NodeHandle pnh("~");
  if (!pnh.hasParam(name)) return;
  if (!pnh.getParam(name, *value))
    throw std::runtime_error("parameter ~" + name + " has the wrong type");
}

}  // namespace

void InitNode(int& argc, char** argv, const std::string& name) {
  ros::init(argc, argv, name, ros::init_options::NoSigintHandler);
  // Started here, not by the first NodeHandle: roscpp shuts a node down when the last
  // NodeHandle that started it goes (a parameter read's temporary one), and its console
  // then stays silent for good. Shutdown() ends it.
  ros::start();
}
bool Ok() { return ros::ok(); }
void Shutdown() { ros::shutdown(); }
double NowSeconds() { return ros::Time::now().toSec(); }
void LogInfo(const std::string& text) { ROS_INFO("%s", text.c_str()); }
void LogWarn(const std::string& text) { ROS_WARN("%s", text.c_str()); }
void LogWarnThrottled(double period_s, const std::string& text) {
  ROS_WARN_THROTTLE(period_s, "%s", text.c_str());
}
void LogError(const std::string& text) { ROS_ERROR("%s", text.c_str()); }

void GetParam(const std::string& name, std::string* value) { GetParamT(name, value); }
void GetParam(const std::string& name, bool* value) { GetParamT(name, value); }
void GetParam(const std::string& name, int* value) { GetParamT(name, value); }
void GetParam(const std::string& name, double* value) {
  ros::NodeHandle pnh("~");
  int as_int = 0;
  if (pnh.hasParam(name) && !pnh.getParam(name, *value)) {
    if (!pnh.getParam(name, as_int))
      throw std::runtime_error("parameter ~" + name + " is not a number");
    *value = as_int;
  }
}
void GetParam(const std::string& name, std::vector<double>* value) { GetParamT(name, value); }

struct NodeTransport::Impl {
  NodeTopics topics;
  NodeHandlers handlers;
  ros::NodeHandle nh;
  ros::NodeHandle pnh{"~"};
  ros::CallbackQueue service_queue;
  std::unique_ptr<ros::AsyncSpinner> spinner, service_spinner;
  ros::Publisher pose_pub, hypotheses_pub, views_pub, dropped_pub, tf_pub;
  ros::Subscriber image_sub, odom_sub, session_sub;
  std::vector<ros::ServiceServer> services;

  void OnImage(const sensor_msgs::ImageConstPtr& m) {
    const std::string where =
        topics.image_topic + ": image seq " + std::to_string(m->header.seq) + ": ";
    handlers.on_image(m->header.stamp.toSec(), [m, where] {
      try {
        return ImageFromRaw(m->encoding, m->width, m->height, m->step, m->is_bigendian != 0,
                            m->data);
      } catch (const std::runtime_error& e) {
        throw std::runtime_error(where + e.what());
      }
    });
  }
  void OnCompressed(const sensor_msgs::CompressedImageConstPtr& m) {
    const std::string where =
        topics.image_topic + ": image seq " + std::to_string(m->header.seq) + ": ";
    handlers.on_image(m->header.stamp.toSec(), [m, where] {
      try {
        return ImageFromCompressed(m->format, m->data);
      } catch (const std::runtime_error& e) {
        throw std::runtime_error(where + e.what());
      }
    });
  }
  void OnOdom(const nav_msgs::OdometryConstPtr& m) {
    handlers.on_odometry(m->header.stamp.toSec(), FromPoseMsg(m->pose.pose));
  }
  void OnSession(const std_msgs::StringConstPtr& m) { handlers.on_session(m->data); }
  bool Reply(const std::pair<bool, std::string>& r, std_srvs::Trigger::Response& res) {
    res.success = r.first;
    res.message = r.second;
    return true;
  }
  bool OnSave(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    return Reply(handlers.save_map(), res);
  }
  bool OnNewSession(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    return Reply(handlers.new_session(), res);
  }
  bool OnActive(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    return Reply(handlers.forgetting("active"), res);
  }
  bool OnPassive(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    return Reply(handlers.forgetting("passive"), res);
  }
  bool OnStatic(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    return Reply(handlers.forgetting("static"), res);
  }
};

NodeTransport::NodeTransport(const NodeTopics& topics, NodeHandlers handlers)
    : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  s.topics = topics;
  s.handlers = std::move(handlers);
  s.pose_pub = s.pnh.advertise<geometry_msgs::PoseWithCovarianceStamped>("pose", 1000);
  s.hypotheses_pub = s.pnh.advertise<geometry_msgs::PoseArray>("hypotheses", 10);
  s.views_pub =
      s.pnh.advertise<visualization_msgs::MarkerArray>("reference_views", 1, /*latch=*/true);
  s.dropped_pub = s.pnh.advertise<std_msgs::Int64>("dropped_frames", 10, /*latch=*/true);
  s.tf_pub = s.nh.advertise<tf2_msgs::TFMessage>("/tf", 1000);
  const auto hints = ros::TransportHints().tcpNoDelay();
  if (topics.compressed)
    s.image_sub =
        s.nh.subscribe(topics.image_topic, topics.image_queue, &Impl::OnCompressed, &s, hints);
  else
    s.image_sub = s.nh.subscribe(topics.image_topic, topics.image_queue, &Impl::OnImage, &s, hints);
  s.odom_sub = s.nh.subscribe(topics.odom_topic, 1000, &Impl::OnOdom, &s, hints);
  if (!topics.session_topic.empty())
    s.session_sub = s.nh.subscribe(topics.session_topic, 10, &Impl::OnSession, &s);
  ros::NodeHandle snh("~");
  snh.setCallbackQueue(&s.service_queue);
  s.services.push_back(snh.advertiseService("save_map", &Impl::OnSave, &s));
  s.services.push_back(snh.advertiseService("new_session", &Impl::OnNewSession, &s));
  s.services.push_back(snh.advertiseService("forgetting_active", &Impl::OnActive, &s));
  s.services.push_back(snh.advertiseService("forgetting_passive", &Impl::OnPassive, &s));
  s.services.push_back(snh.advertiseService("forgetting_static", &Impl::OnStatic, &s));
  s.service_spinner = std::make_unique<ros::AsyncSpinner>(1, &s.service_queue);
  s.service_spinner->start();
  // One thread: the callbacks only convert and enqueue.
  s.spinner = std::make_unique<ros::AsyncSpinner>(1);
  s.spinner->start();
}

NodeTransport::~NodeTransport() {
  StopSubscriptions();
  StopServices();
}

void NodeTransport::StopSubscriptions() {
  if (impl_->spinner) impl_->spinner->stop();
}
void NodeTransport::StopServices() {
  if (impl_->service_spinner) impl_->service_spinner->stop();
}

void NodeTransport::PublishPose(double stamp_s, const PlanarPose& pose,
                                const std::array<double, 9>& c) {
  geometry_msgs::PoseWithCovarianceStamped msg;
  msg.header.stamp.fromSec(stamp_s);
  msg.header.frame_id = impl_->topics.map_frame;
  msg.pose.pose = ToPoseMsg(pose);
  const int idx[3] = {0, 1, 5};  // x, y, yaw in the 6x6 (x y z roll pitch yaw) matrix
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k)
      msg.pose.covariance[static_cast<std::size_t>(idx[r] * 6 + idx[k])] = c[r * 3 + k];
  impl_->pose_pub.publish(msg);
}

void NodeTransport::PublishMapToOdom(double stamp_s, const PlanarPose& map_T_odom) {
  tf2_msgs::TFMessage msg;
  geometry_msgs::TransformStamped t;
  t.header.stamp.fromSec(stamp_s);
  t.header.frame_id = impl_->topics.map_frame;
  t.child_frame_id = impl_->topics.odom_frame;
  const geometry_msgs::Pose p = ToPoseMsg(map_T_odom);
  t.transform.translation.x = p.position.x;
  t.transform.translation.y = p.position.y;
  t.transform.rotation = p.orientation;
  msg.transforms.push_back(t);
  impl_->tf_pub.publish(msg);
}

void NodeTransport::PublishHypotheses(double stamp_s, const std::vector<PlanarPose>& poses) {
  geometry_msgs::PoseArray msg;
  msg.header.stamp.fromSec(stamp_s);
  msg.header.frame_id = impl_->topics.map_frame;
  for (const PlanarPose& p : poses) msg.poses.push_back(ToPoseMsg(p));
  impl_->hypotheses_pub.publish(msg);
}

void NodeTransport::PublishViews(const std::vector<std::array<double, 3>>& views) {
  visualization_msgs::MarkerArray array;
  visualization_msgs::Marker m;
  m.header.stamp = ros::Time::now();
  m.header.frame_id = impl_->topics.map_frame;
  m.ns = "omnicml_views";
  m.id = 0;
  m.type = visualization_msgs::Marker::SPHERE_LIST;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  m.scale.x = m.scale.y = m.scale.z = 0.15;
  for (const auto& v : views) {
    geometry_msgs::Point p;
    p.x = v[0];
    p.y = v[1];
    m.points.push_back(p);
    std_msgs::ColorRGBA color;
    color.r = static_cast<float>(1.0 - v[2]);
    color.g = static_cast<float>(v[2]);
    color.a = 1.0f;
    m.colors.push_back(color);
  }
  array.markers.push_back(m);
  impl_->views_pub.publish(array);
}

void NodeTransport::PublishDropped(std::int64_t dropped) {
  std_msgs::Int64 msg;
  msg.data = dropped;
  impl_->dropped_pub.publish(msg);
}

bool CallTrigger(const std::string& service, double timeout_s, std::string* message) {
  if (!ros::isInitialized()) {
    ros::M_string remappings;
    ros::init(remappings, "omnicml_trigger_client",
              ros::init_options::AnonymousName | ros::init_options::NoSigintHandler);
  }
  // roscpp shuts the node down when its last NodeHandle goes; keep one for later calls.
  static const ros::NodeHandle* const keep_alive = new ros::NodeHandle();
  (void)keep_alive;
  if (!ros::service::waitForService(service, ros::Duration(timeout_s))) {
    *message = service + ": not available within " + std::to_string(timeout_s) + " s";
    return false;
  }
  std_srvs::Trigger srv;
  if (!ros::service::call(service, srv)) {
    *message = service + ": call failed";
    return false;
  }
  *message = srv.response.message;
  return srv.response.success;
}

}  // namespace omnicml::ros1
