// omnicml_ros_play: plays a bag written by `omnicml export rosbag` to a running
// omnicml_node and records the poses it publishes (the integration test's and the latency
// measurement's publisher; `rosbag play` works too, without the pacing below).
//
//   omnicml_ros_play BAG [--lockstep [--hold N] | --rate HZ] [--poses-out CSV] [--pose-topic T]
//
// Messages are published in groups of equal bag time (session, odometry and tf before the
// image of the same time). --lockstep keeps the bag's stamps and waits, after each image,
// for the node's pose of that stamp (at most --timeout seconds), so no frame is dropped
// and the run equals `omnicml run` on the log; a session message is preceded and followed
// by a pause of 0.3 s so that it reaches the node after the images before it and before
// the next image. --hold N does not wait for the first N images' poses: a node that
// starts a new map holds the first frames of its first session (~frame_step_frames) and
// publishes their poses once the frame step is measured (N frames, or the next session). --rate HZ
// publishes one image group every 1/HZ s of wall time, restamped with the current time (the node's
// latency is then image capture to pose publish). Exit codes: 0, 2 on bad input or a
// node that never subscribes.
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <iostream>
#include <mutex>
#include <sstream>
#include <thread>
#include <vector>

#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nav_msgs/Odometry.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/String.h>
#include <tf2_msgs/TFMessage.h>
#include <CLI/CLI.hpp>

#include <cstdio>
#include <fstream>
#include <map>
#include <stdexcept>

// ROS 1 message headers need C++17 (see src/ros/ros1.h), so this program includes no
// omnicml header; its errors are std::runtime_error.
namespace {

template <class... A>
std::string Cat(const A&... a) {
  std::ostringstream s;
  (s << ... << a);
  return s.str();
}

// Writes text to path through a temporary file renamed into place.
void WriteFileReplacing(const std::string& path, const std::string& text) {
  const std::string temp = path + ".tmp-" + std::to_string(::getpid());
  {
    std::ofstream out(temp, std::ios::binary);
    out << text;
    if (!out.flush()) throw std::runtime_error(Cat(path, ": cannot write"));
  }
  if (std::rename(temp.c_str(), path.c_str()) != 0) {
    std::remove(temp.c_str());
    throw std::runtime_error(Cat(path, ": cannot write"));
  }
}

struct Args {
  std::string bag;
  bool lockstep = false;
  double rate_hz = 0.0;
  std::string poses_out;
  std::string pose_topic = "/omnicml_node/pose";
  double timeout_s = 20.0;
  std::size_t hold_images = 0;
};

struct ReceivedPose {
  double stamp_s, x, y, phi, cxx, cyy, cpp, delay_ms;
};

class Player {
 public:
  explicit Player(const Args& args) : args_(args) {
    pose_sub_ = nh_.subscribe(args.pose_topic, 1000, &Player::OnPose, this,
                              ros::TransportHints().tcpNoDelay());
  }

  int Run() {
    rosbag::Bag bag;
    try {
      bag.open(args_.bag, rosbag::bagmode::Read);
    } catch (const rosbag::BagException& e) {
      throw std::runtime_error(Cat(args_.bag, ": cannot read the bag: ", e.what()));
    }
    rosbag::View view(bag);
    for (const rosbag::ConnectionInfo* c : view.getConnections()) Advertise(c->topic, c->datatype);
    WaitForSubscribers();
    std::vector<rosbag::MessageInstance> group;
    ros::Time group_time;
    for (const rosbag::MessageInstance& m : view) {
      if (!ros::ok()) break;
      if (!group.empty() && m.getTime() != group_time) PublishGroup(&group);
      group_time = m.getTime();
      group.push_back(m);
    }
    if (!group.empty()) PublishGroup(&group);
    // Poses still on their way.
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, std::chrono::seconds(3), [&] { return poses_.size() >= images_; });
    std::cout << "published " << images_ << " images, received " << poses_.size() << " poses";
    if (args_.lockstep)
      std::cout << ", " << missing_ << " images without a pose within " << args_.timeout_s << " s";
    std::cout << "\n";
    if (!args_.poses_out.empty()) {
      std::ostringstream csv;
      csv.precision(17);
      csv << "stamp_s,x_m,y_m,phi_rad,cov_xx,cov_yy,cov_phiphi,receive_delay_ms\n";
      for (const ReceivedPose& p : poses_)
        csv << p.stamp_s << "," << p.x << "," << p.y << "," << p.phi << "," << p.cxx << "," << p.cyy
            << "," << p.cpp << "," << p.delay_ms << "\n";
      WriteFileReplacing(args_.poses_out, csv.str());
    }
    return 0;
  }

 private:
  void Advertise(const std::string& topic, const std::string& type) {
    if (publishers_.count(topic)) return;
    ros::Publisher p;
    if (type == "sensor_msgs/Image")
      p = nh_.advertise<sensor_msgs::Image>(topic, 100), image_topic_ = topic;
    else if (type == "sensor_msgs/CompressedImage")
      p = nh_.advertise<sensor_msgs::CompressedImage>(topic, 100), image_topic_ = topic;
    else if (type == "nav_msgs/Odometry")
      p = nh_.advertise<nav_msgs::Odometry>(topic, 1000);
    else if (type == "tf2_msgs/TFMessage")
      p = nh_.advertise<tf2_msgs::TFMessage>(topic, 1000);
    else if (type == "std_msgs/String")
      p = nh_.advertise<std_msgs::String>(topic, 10);
    else if (type == "geometry_msgs/PoseStamped")
      return;  // ground truth: not for the node
    else
      throw std::runtime_error(
          Cat(args_.bag, ": topic ", topic, ": type ", type, " is not played"));
    publishers_[topic] = p;
  }

  void WaitForSubscribers() {
    const auto deadline =
        std::chrono::steady_clock::now() + std::chrono::duration<double>(args_.timeout_s);
    while (ros::ok()) {
      bool all = pose_sub_.getNumPublishers() > 0;
      for (const auto& [topic, p] : publishers_)
        if (topic != "/tf" && p.getNumSubscribers() == 0) all = false;
      if (all) return;
      if (std::chrono::steady_clock::now() > deadline)
        throw std::runtime_error(Cat("no node subscribed to every topic of ", args_.bag,
                                     " and publishing ", args_.pose_topic, " within ",
                                     args_.timeout_s, " s"));
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
  }

  template <class M>
  void PublishAs(const rosbag::MessageInstance& m, const ros::Publisher& p,
                 const ros::Time* restamp) {
    auto msg = m.instantiate<M>();
    if (!msg) return;
    if (restamp) {
      if constexpr (std::is_same_v<M, tf2_msgs::TFMessage>) {
        for (auto& t : msg->transforms) t.header.stamp = *restamp;
      } else if constexpr (!std::is_same_v<M, std_msgs::String>) {
        msg->header.stamp = *restamp;
      }
    }
    p.publish(*msg);
  }

  void Publish(const rosbag::MessageInstance& m, const ros::Time* restamp) {
    const auto it = publishers_.find(m.getTopic());
    if (it == publishers_.end()) return;
    const std::string& type = m.getDataType();
    if (type == "sensor_msgs/Image")
      PublishAs<sensor_msgs::Image>(m, it->second, restamp);
    else if (type == "sensor_msgs/CompressedImage")
      PublishAs<sensor_msgs::CompressedImage>(m, it->second, restamp);
    else if (type == "nav_msgs/Odometry")
      PublishAs<nav_msgs::Odometry>(m, it->second, restamp);
    else if (type == "tf2_msgs/TFMessage")
      PublishAs<tf2_msgs::TFMessage>(m, it->second, restamp);
    else if (type == "std_msgs/String")
      PublishAs<std_msgs::String>(m, it->second, restamp);
  }

  void PublishGroup(std::vector<rosbag::MessageInstance>* group) {
    // Sessions first, then odometry and tf, the image last.
    auto rank = [&](const rosbag::MessageInstance& m) {
      if (m.getDataType() == "std_msgs/String") return 0;
      if (m.getTopic() == image_topic_) return 2;
      return 1;
    };
    std::vector<std::size_t> order;
    for (int r = 0; r <= 2; ++r)
      for (std::size_t k = 0; k < group->size(); ++k)
        if (rank((*group)[k]) == r) order.push_back(k);
    const bool has_image = !order.empty() && rank((*group)[order.back()]) == 2;
    if (has_image && args_.rate_hz > 0.0) {
      if (next_tick_ == std::chrono::steady_clock::time_point{})
        next_tick_ = std::chrono::steady_clock::now();
      std::this_thread::sleep_until(next_tick_);
      next_tick_ += std::chrono::duration_cast<std::chrono::steady_clock::duration>(
          std::chrono::duration<double>(1.0 / args_.rate_hz));
    }
    const ros::Time now = ros::Time::now();
    const ros::Time* restamp = args_.rate_hz > 0.0 ? &now : nullptr;
    double image_stamp = 0.0;
    for (const std::size_t k : order) {
      const rosbag::MessageInstance& m = (*group)[k];
      if (rank(m) == 0 && args_.lockstep)
        std::this_thread::sleep_for(std::chrono::milliseconds(300));
      Publish(m, restamp);
      if (rank(m) == 0 && args_.lockstep)
        std::this_thread::sleep_for(std::chrono::milliseconds(300));
      if (rank(m) == 2) {
        if (auto im = m.instantiate<sensor_msgs::Image>())
          image_stamp = im->header.stamp.toSec();
        else if (auto c = m.instantiate<sensor_msgs::CompressedImage>())
          image_stamp = c->header.stamp.toSec();
      }
    }
    group->clear();
    if (!has_image) return;
    std::unique_lock<std::mutex> lock(mutex_);
    ++images_;
    if (args_.lockstep && images_ > args_.hold_images) {
      const bool got = cv_.wait_for(lock, std::chrono::duration<double>(args_.timeout_s), [&] {
        return !poses_.empty() && std::abs(poses_.back().stamp_s - image_stamp) < 1e-6;
      });
      if (!got) ++missing_;
    }
  }

  void OnPose(const geometry_msgs::PoseWithCovarianceStampedConstPtr& msg) {
    const auto& q = msg->pose.pose.orientation;
    ReceivedPose p;
    p.stamp_s = msg->header.stamp.toSec();
    p.x = msg->pose.pose.position.x;
    p.y = msg->pose.pose.position.y;
    p.phi = std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
    p.cxx = msg->pose.covariance[0];
    p.cyy = msg->pose.covariance[7];
    p.cpp = msg->pose.covariance[35];
    p.delay_ms = (ros::Time::now() - msg->header.stamp).toSec() * 1e3;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      poses_.push_back(p);
    }
    cv_.notify_all();
  }

  Args args_;
  ros::NodeHandle nh_;
  ros::Subscriber pose_sub_;
  std::map<std::string, ros::Publisher> publishers_;
  std::string image_topic_;
  std::chrono::steady_clock::time_point next_tick_{};
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<ReceivedPose> poses_;
  std::size_t images_ = 0;
  std::size_t missing_ = 0;
};

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "omnicml_ros_play", ros::init_options::AnonymousName);
  Args args;
  CLI::App app{"Play an omnicml bag to omnicml_node and record its poses"};
  app.add_option("BAG", args.bag, "Bag written by omnicml export rosbag")->required();
  app.add_flag("--lockstep", args.lockstep, "Keep stamps; wait for each frame's pose");
  app.add_option("--rate", args.rate_hz, "Images per second (restamped with the current time)");
  app.add_option("--poses-out", args.poses_out, "CSV of the poses received");
  app.add_option("--pose-topic", args.pose_topic)->capture_default_str();
  app.add_option("--timeout", args.timeout_s, "Seconds to wait for the node")
      ->capture_default_str();
  app.add_option("--hold", args.hold_images,
                 "With --lockstep: images not waited for at the start (the node's "
                 "~frame_step_frames when it starts a new map)")
      ->capture_default_str();
  try {
    app.parse(argc, argv);
    if (args.lockstep == (args.rate_hz > 0.0))
      throw std::runtime_error("give exactly one of --lockstep and --rate HZ");
    ros::AsyncSpinner spinner(1);
    spinner.start();
    Player player(args);
    const int rc = player.Run();
    spinner.stop();
    return rc;
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  } catch (const std::runtime_error& e) {
    std::cerr << "omnicml_ros_play: error: " << e.what() << "\n";
    return 2;
  }
}
