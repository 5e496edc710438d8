// C++17 (ros1.h): image conversions and bag access through librosbag_storage.
#include <cmath>
#include <cstring>
#include <stdexcept>

#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/String.h>
#include <tf2_msgs/TFMessage.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ros/ros1.h"

namespace omnicml::ros1 {
namespace {

std::runtime_error Fail(const std::string& what) { return std::runtime_error(what); }

bool HostIsBigEndian() {
  const std::uint16_t one = 1;
  unsigned char first;
  std::memcpy(&first, &one, 1);
  return first == 0;
}

cv::Mat To8Bit(const cv::Mat& image16) {
  cv::Mat out;
  image16.convertTo(out, CV_8U, 255.0 / 65535.0);
  return out;
}

double Yaw(double qx, double qy, double qz, double qw) {
  return std::atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz));
}

template <class P>
PlanarPose FromPose(const P& p) {
  return {p.position.x, p.position.y,
          Yaw(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)};
}

geometry_msgs::Pose ToPoseMsg(const PlanarPose& pose) {
  geometry_msgs::Pose p;
  p.position.x = pose.x_m;
  p.position.y = pose.y_m;
  p.orientation.z = std::sin(0.5 * pose.phi_rad);
  p.orientation.w = std::cos(0.5 * pose.phi_rad);
  return p;
}

ros::Time ToTime(double stamp_s) {
  if (!std::isfinite(stamp_s) || stamp_s <= 0.0 || stamp_s >= 4294967295.0)
    throw Fail("time " + std::to_string(stamp_s) +
               " s is not a valid ROS time (must be in (0, 2^32) s)");
  ros::Time t;
  t.fromSec(stamp_s);
  if (t.isZero()) throw Fail("time " + std::to_string(stamp_s) + " s rounds to ROS time zero");
  return t;
}

std::string Short(const std::string& s) { return s.size() <= 40 ? s : s.substr(0, 40) + "..."; }

}  // namespace

cv::Mat ImageFromRaw(const std::string& e, std::uint32_t width, std::uint32_t height,
                     std::uint32_t step, bool big_endian, const std::vector<std::uint8_t>& data) {
  int channels = 0, bytes = 1;
  if (e == "mono8" || e == "8UC1")
    channels = 1;
  else if (e == "bgr8" || e == "rgb8" || e == "8UC3")
    channels = 3;
  else if (e == "bgra8" || e == "rgba8")
    channels = 4;
  else if (e == "mono16" || e == "16UC1")
    channels = 1, bytes = 2;
  else if (e == "bgr16" || e == "rgb16")
    channels = 3, bytes = 2;
  else
    throw Fail("image encoding '" + Short(e) +
               "' is not supported (mono8, bgr8, rgb8, bgra8, rgba8, mono16, 16UC1, bgr16, rgb16)");
  if (width < 2 || height < 2 || width > 100000 || height > 100000)
    throw Fail("image of " + std::to_string(width) + "x" + std::to_string(height) + " pixels");
  const std::size_t row_bytes = static_cast<std::size_t>(width) * channels * bytes;
  if (step < row_bytes)
    throw Fail("image step " + std::to_string(step) + " is below width x pixel size " +
               std::to_string(row_bytes));
  const std::size_t need = static_cast<std::size_t>(step) * height;
  if (data.size() < need)
    throw Fail("image data of " + std::to_string(data.size()) +
               " bytes, expected step x height = " + std::to_string(need));
  const int type = CV_MAKETYPE(bytes == 1 ? CV_8U : CV_16U, channels);
  const cv::Mat view(static_cast<int>(height), static_cast<int>(width), type,
                     const_cast<std::uint8_t*>(data.data()), step);
  cv::Mat image = view.clone();
  if (bytes == 2) {
    if (big_endian != HostIsBigEndian()) {
      for (int r = 0; r < image.rows; ++r) {
        auto* p = image.ptr<std::uint16_t>(r);
        for (int c = 0; c < image.cols * channels; ++c)
          p[c] = static_cast<std::uint16_t>((p[c] >> 8) | (p[c] << 8));
      }
    }
    image = To8Bit(image);
  }
  if (e == "rgb8" || e == "rgb16")
    cv::cvtColor(image, image, cv::COLOR_RGB2BGR);
  else if (e == "bgra8")
    cv::cvtColor(image, image, cv::COLOR_BGRA2BGR);
  else if (e == "rgba8")
    cv::cvtColor(image, image, cv::COLOR_RGBA2BGR);
  return image;
}

cv::Mat ImageFromCompressed(const std::string& format, const std::vector<std::uint8_t>& d) {
  const bool png = d.size() >= 8 && d[0] == 0x89 && d[1] == 'P' && d[2] == 'N' && d[3] == 'G';
  const bool jpeg = d.size() >= 3 && d[0] == 0xFF && d[1] == 0xD8 && d[2] == 0xFF;
  if (!png && !jpeg)
    throw Fail("compressed image (format '" + Short(format) + "') is neither PNG nor JPEG");
  cv::Mat image = cv::imdecode(d, cv::IMREAD_UNCHANGED);
  if (image.empty()) throw Fail("compressed image does not decode");
  if (image.depth() == CV_16U) image = To8Bit(image);
  if (image.depth() != CV_8U) throw Fail("compressed image of an unsupported depth");
  if (image.channels() == 4) cv::cvtColor(image, image, cv::COLOR_BGRA2BGR);
  if (image.channels() != 1 && image.channels() != 3)
    throw Fail("compressed image with " + std::to_string(image.channels()) + " channels");
  if (image.cols < 2 || image.rows < 2) throw Fail("compressed image smaller than 2x2");
  return image;
}

// ---------------------------------------------------------------------------------------

struct BagWriter::Impl {
  rosbag::Bag bag;
};

BagWriter::BagWriter(const std::string& path) : impl_(std::make_unique<Impl>()) {
  try {
    impl_->bag.open(path, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    throw Fail(e.what());
  }
}

BagWriter::~BagWriter() {
  try {
    impl_->bag.close();
  } catch (...) {
  }
}

void BagWriter::WriteImage(const std::string& topic, double stamp_s, const std::string& frame_id,
                           std::uint32_t seq, const cv::Mat& image, bool compressed) {
  const ros::Time t = ToTime(stamp_s);
  if (image.type() != CV_8UC1 && image.type() != CV_8UC3)
    throw Fail("image is not CV_8UC1 or CV_8UC3");
  if (compressed) {
    sensor_msgs::CompressedImage msg;
    msg.header.stamp = t;
    msg.header.frame_id = frame_id;
    msg.header.seq = seq;
    msg.format = "png";
    if (!cv::imencode(".png", image, msg.data)) throw Fail("PNG encoding failed");
    impl_->bag.write(topic, t, msg);
    return;
  }
  sensor_msgs::Image msg;
  msg.header.stamp = t;
  msg.header.frame_id = frame_id;
  msg.header.seq = seq;
  msg.width = static_cast<std::uint32_t>(image.cols);
  msg.height = static_cast<std::uint32_t>(image.rows);
  msg.encoding = image.channels() == 1 ? "mono8" : "bgr8";
  msg.is_bigendian = HostIsBigEndian();
  msg.step = static_cast<std::uint32_t>(image.cols * image.channels());
  msg.data.resize(static_cast<std::size_t>(msg.step) * msg.height);
  for (int r = 0; r < image.rows; ++r)
    std::memcpy(msg.data.data() + static_cast<std::size_t>(r) * msg.step, image.ptr(r), msg.step);
  impl_->bag.write(topic, t, msg);
}

void BagWriter::WriteRawImage(const std::string& topic, double stamp_s, const std::string& encoding,
                              std::uint32_t width, std::uint32_t height, std::uint32_t step,
                              bool big_endian, std::vector<std::uint8_t> data, double bag_time_s) {
  sensor_msgs::Image msg;
  msg.header.stamp = ToTime(stamp_s);
  msg.width = width;
  msg.height = height;
  msg.encoding = encoding;
  msg.is_bigendian = big_endian;
  msg.step = step;
  msg.data = std::move(data);
  impl_->bag.write(topic, bag_time_s > 0.0 ? ToTime(bag_time_s) : msg.header.stamp, msg);
}

void BagWriter::WriteOdometry(const std::string& topic, double stamp_s, const std::string& frame,
                              const std::string& child_frame, const PlanarPose& pose) {
  nav_msgs::Odometry msg;
  msg.header.stamp = ToTime(stamp_s);
  msg.header.frame_id = frame;
  msg.child_frame_id = child_frame;
  msg.pose.pose = ToPoseMsg(pose);
  impl_->bag.write(topic, msg.header.stamp, msg);
}

void BagWriter::WriteTf(double stamp_s, const std::string& frame, const std::string& child_frame,
                        const PlanarPose& pose) {
  tf2_msgs::TFMessage msg;
  geometry_msgs::TransformStamped t;
  t.header.stamp = ToTime(stamp_s);
  t.header.frame_id = frame;
  t.child_frame_id = child_frame;
  const geometry_msgs::Pose p = ToPoseMsg(pose);
  t.transform.translation.x = p.position.x;
  t.transform.translation.y = p.position.y;
  t.transform.rotation = p.orientation;
  msg.transforms.push_back(t);
  impl_->bag.write("/tf", t.header.stamp, msg);
}

void BagWriter::WritePoseStamped(const std::string& topic, double stamp_s, const std::string& frame,
                                 const PlanarPose& pose) {
  geometry_msgs::PoseStamped msg;
  msg.header.stamp = ToTime(stamp_s);
  msg.header.frame_id = frame;
  msg.pose = ToPoseMsg(pose);
  impl_->bag.write(topic, msg.header.stamp, msg);
}

void BagWriter::WriteString(const std::string& topic, double time_s, const std::string& text) {
  std_msgs::String msg;
  msg.data = text;
  impl_->bag.write(topic, ToTime(time_s), msg);
}

void BagWriter::Close() {
  try {
    impl_->bag.close();
  } catch (const rosbag::BagException& e) {
    throw Fail(e.what());
  }
}

// ---------------------------------------------------------------------------------------

namespace {

class Message final : public BagMessage {
 public:
  explicit Message(const rosbag::MessageInstance& m) : m_(m) {}
  std::string type() const override { return m_.getDataType(); }
  double time_s() const override { return m_.getTime().toSec(); }

  void ReadImage(double* stamp_s, cv::Mat* image) const override {
    if (auto im = m_.instantiate<sensor_msgs::Image>()) {
      *stamp_s = im->header.stamp.toSec();
      *image = ImageFromRaw(im->encoding, im->width, im->height, im->step, im->is_bigendian != 0,
                            im->data);
    } else if (auto c = m_.instantiate<sensor_msgs::CompressedImage>()) {
      *stamp_s = c->header.stamp.toSec();
      *image = ImageFromCompressed(c->format, c->data);
    } else {
      throw Fail("type " + type() + ", expected sensor_msgs/Image or sensor_msgs/CompressedImage");
    }
  }
  void ReadPose(double* stamp_s, PlanarPose* pose) const override {
    if (auto o = m_.instantiate<nav_msgs::Odometry>()) {
      *stamp_s = o->header.stamp.toSec();
      *pose = FromPose(o->pose.pose);
    } else if (auto p = m_.instantiate<geometry_msgs::PoseStamped>()) {
      *stamp_s = p->header.stamp.toSec();
      *pose = FromPose(p->pose);
    } else if (auto c = m_.instantiate<geometry_msgs::PoseWithCovarianceStamped>()) {
      *stamp_s = c->header.stamp.toSec();
      *pose = FromPose(c->pose.pose);
    } else {
      throw Fail("type " + type() +
                 ", expected nav_msgs/Odometry, geometry_msgs/PoseStamped or "
                 "geometry_msgs/PoseWithCovarianceStamped");
    }
  }
  std::vector<std::pair<double, PlanarPose>> ReadTf(const std::string& child) const override {
    auto tf = m_.instantiate<tf2_msgs::TFMessage>();
    if (!tf) throw Fail("type " + type() + ", expected tf2_msgs/TFMessage");
    std::vector<std::pair<double, PlanarPose>> out;
    for (const geometry_msgs::TransformStamped& t : tf->transforms) {
      if (t.child_frame_id != child) continue;
      const auto& q = t.transform.rotation;
      out.emplace_back(t.header.stamp.toSec(),
                       PlanarPose{t.transform.translation.x, t.transform.translation.y,
                                  Yaw(q.x, q.y, q.z, q.w)});
    }
    return out;
  }
  std::string ReadString() const override {
    auto s = m_.instantiate<std_msgs::String>();
    if (!s) throw Fail("type " + type() + ", expected std_msgs/String");
    return s->data;
  }

 private:
  const rosbag::MessageInstance& m_;
};

}  // namespace

struct BagReader::Impl {
  rosbag::Bag bag;
};

BagReader::BagReader(const std::string& path) : impl_(std::make_unique<Impl>()) {
  try {
    impl_->bag.open(path, rosbag::bagmode::Read);
  } catch (const rosbag::BagException& e) {
    throw Fail(e.what());
  }
}

BagReader::~BagReader() = default;

std::vector<std::pair<std::string, std::string>> BagReader::Topics() const {
  rosbag::View view(impl_->bag);
  std::vector<std::pair<std::string, std::string>> topics;
  for (const rosbag::ConnectionInfo* c : view.getConnections())
    topics.emplace_back(c->topic, c->datatype);
  return topics;
}

void BagReader::ForEach(const std::string& topic,
                        const std::function<bool(const BagMessage&)>& visit) const {
  try {
    std::unique_ptr<rosbag::View> view =
        topic.empty() ? std::make_unique<rosbag::View>(impl_->bag)
                      : std::make_unique<rosbag::View>(impl_->bag, rosbag::TopicQuery(topic));
    for (const rosbag::MessageInstance& m : *view) {
      const Message message(m);
      if (!visit(message)) break;
    }
  } catch (const rosbag::BagException& e) {
    throw Fail(std::string("cannot read the bag (truncated?): ") + e.what());
  } catch (const ros::Exception& e) {
    throw Fail(std::string("cannot read the message (truncated bag?): ") + e.what());
  }
}

}  // namespace omnicml::ros1
