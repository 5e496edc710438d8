#include "omnicml/ros/rosbag_io.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <optional>
#include <set>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/yaml_io.h"
#include "omnicml/live/odometry_buffer.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/unwrap/omni_unwrapper.h"
#include "ros/ros1.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

ros1::PlanarPose ToPlanar(const Pose2& p) { return {p.x(), p.y(), p.z()}; }
Pose2 FromPlanar(const ros1::PlanarPose& p) { return MakePose(p.x_m, p.y_m, p.phi_rad); }

void CheckTopic(const std::string& topic, const char* field) {
  if (topic.empty() || topic[0] != '/')
    throw Error(StrCat(field, " '", topic, "' must start with '/'"));
}

// ---------------------------------------------------------------------------------------
// Export

void WriteFrame(ros1::BagWriter& bag, const Frame& frame, double offset_s,
                const RosbagExportOptions& o) {
  const double t = frame.stamp_s + offset_s;
  bag.WriteImage(o.image_topic, t, o.camera_frame, static_cast<std::uint32_t>(frame.global_index),
                 frame.image, o.compressed);
  bag.WriteOdometry(o.odom_topic, t, o.odom_frame, o.base_frame, ToPlanar(frame.odom_T_robot));
  if (o.odom_tf) bag.WriteTf(t, o.odom_frame, o.base_frame, ToPlanar(frame.odom_T_robot));
  if (frame.map_T_robot_truth)
    bag.WritePoseStamped(o.truth_topic, t, o.map_frame, ToPlanar(*frame.map_T_robot_truth));
}

// A bag written under a temporary name in the target's directory and renamed into place
// by Commit(); removed when destroyed uncommitted.
class StagedBag {
 public:
  StagedBag(const fs::path& target, bool overwrite) : target_(target) {
    if (fs::exists(target) && !overwrite)
      throw Error(StrCat(target.string(), ": exists (use --overwrite to replace it)"));
    CheckOutputFile(target, "--out");
    static std::atomic<std::uint64_t> counter{0};
    RemoveStaleTemporaries(target);
    temp_ = TempPathFor(target, ::getpid(), counter++);
    try {
      bag_ = std::make_unique<ros1::BagWriter>(temp_.string());
    } catch (const std::runtime_error& e) {
      throw Error(StrCat(target.string(), ": cannot create: ", e.what()));
    }
  }
  ~StagedBag() {
    if (!committed_) {
      bag_.reset();
      std::error_code ec;
      fs::remove(temp_, ec);
    }
  }
  ros1::BagWriter& bag() { return *bag_; }
  void Commit() {
    bag_->Close();
    SyncFileSystem(temp_);
    fs::rename(temp_, target_);
    SyncDirectory(target_.parent_path().empty() ? fs::path(".") : target_.parent_path());
    committed_ = true;
  }

 private:
  fs::path target_;
  fs::path temp_;
  std::unique_ptr<ros1::BagWriter> bag_;
  bool committed_ = false;
};

}  // namespace

void RosbagExportOptions::Validate() const {
  CheckTopic(image_topic, "image_topic");
  CheckTopic(odom_topic, "odom_topic");
  CheckTopic(truth_topic, "truth_topic");
  CheckTopic(session_topic, "session_topic");
  for (const std::string* f : {&map_frame, &odom_frame, &base_frame, &camera_frame})
    if (f->empty()) throw Error("frame names must not be empty");
}

std::string SessionMessageText(const SessionInfo& info, double stamp_offset_s) {
  YAML::Emitter out;
  out << YAML::BeginMap << YAML::Key << "name" << YAML::Value << info.name << YAML::Key
      << "stamp_offset_s" << YAML::Value << FormatRoundTrip(stamp_offset_s) << YAML::Key
      << "session" << YAML::Value << YAML::Literal << SessionYamlText(info) << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

SessionInfo ParseSessionMessage(const std::string& text, const std::string& source,
                                double* stamp_offset_s) {
  YAML::Node root;
  try {
    root = LoadYaml(text, source + ": session message");
  } catch (const YAML::Exception& e) {
    throw Error(StrCat(source, ": session message: YAML syntax error: ", e.msg));
  }
  if (!root.IsMap() || !root["name"] || !root["stamp_offset_s"] || !root["session"] ||
      root.size() != 3)
    throw Error(
        StrCat(source, ": session message: expected the keys name, stamp_offset_s and session"));
  // ReadSessionYaml reads files: the session text goes through a private temporary file.
  static std::atomic<std::uint64_t> counter{0};
  const fs::path temp =
      fs::temp_directory_path() / StrCat("omnicml-session-", ::getpid(), "-", counter++, ".yaml");
  SessionInfo info;
  try {
    WriteFileAtomic(temp, root["session"].as<std::string>(), FileSync::kDeferred);
    info = ReadSessionYaml(temp.string());
  } catch (const Error& e) {
    std::error_code ec;
    fs::remove(temp, ec);
    std::string what = e.what();
    if (what.rfind(temp.string(), 0) == 0) what = what.substr(temp.string().size());
    throw Error(StrCat(source, ": session message", what));
  }
  std::error_code ec;
  fs::remove(temp, ec);
  info.name = root["name"].as<std::string>();
  if (stamp_offset_s) *stamp_offset_s = root["stamp_offset_s"].as<double>();
  return info;
}

RosbagExportSummary ExportRosbag(const std::string& log_dir, const std::string& bag_path,
                                 const RosbagExportOptions& options) {
  options.Validate();
  RosbagExportSummary summary;
  // The offset that makes every stamp a positive ROS time: from the first frame.
  {
    LogReaderOptions pose_only;
    pose_only.load_images = false;
    LogReader reader(log_dir, pose_only);
    Frame first;
    if (reader.Next(&first) && first.stamp_s < 1.0) summary.stamp_offset_s = 1.0 - first.stamp_s;
  }
  LogReader reader(log_dir);
  StagedBag staged(bag_path, options.overwrite);
  Frame frame;
  int session = -1;
  while (reader.Next(&frame)) {
    if (frame.session_index != session) {
      session = frame.session_index;
      try {
        staged.bag().WriteString(
            options.session_topic, frame.stamp_s + summary.stamp_offset_s - 1e-6,
            SessionMessageText(reader.Session(session), summary.stamp_offset_s));
      } catch (const std::runtime_error& e) {
        throw Error(StrCat(bag_path, ": frame ", frame.global_index, ": ", e.what()));
      }
      ++summary.sessions;
    }
    try {
      WriteFrame(staged.bag(), frame, summary.stamp_offset_s, options);
    } catch (const Error&) {
      throw;
    } catch (const std::runtime_error& e) {
      throw Error(StrCat(bag_path, ": frame ", frame.global_index, ": cannot write: ", e.what()));
    }
    ++summary.frames;
  }
  staged.Commit();
  return summary;
}

// ---------------------------------------------------------------------------------------
// Import

void RosbagImportOptions::Validate() const {
  CheckTopic(image_topic, "--image-topic");
  if (odom_topic.empty() == odom_tf_frame.empty())
    throw Error("give exactly one of --odom-topic and --odom-tf");
  if (!odom_topic.empty()) CheckTopic(odom_topic, "--odom-topic");
  if (!truth_topic.empty()) CheckTopic(truth_topic, "--truth-topic");
  if (!(split_gap_s >= 0.0) || !std::isfinite(split_gap_s))
    throw Error("--split-gap must be >= 0 seconds");
  if (!(truth_max_gap_s > 0.0) || !std::isfinite(truth_max_gap_s))
    throw Error("truth_max_gap_s must be > 0");
}

namespace {

std::string Where(const std::string& bag, const std::string& topic, std::int64_t index) {
  return StrCat(bag, ": topic ", topic, ": message ", index, ": ");
}

// Opens a bag for reading: unindexed or truncated bags fail here (rosbag reads the index).
std::unique_ptr<ros1::BagReader> OpenBag(const std::string& path) {
  if (!fs::is_regular_file(path)) throw Error(StrCat(path, ": not a regular file"));
  try {
    return std::make_unique<ros1::BagReader>(path);
  } catch (const std::runtime_error& e) {
    throw Error(StrCat(path,
                       ": cannot read the bag (unindexed or truncated? 'rosbag reindex' repairs an "
                       "unindexed one): ",
                       e.what()));
  }
}

std::string TopicType(const std::vector<std::pair<std::string, std::string>>& topics,
                      const std::string& bag, const std::string& topic, bool required) {
  std::string type;
  std::set<std::string> names;
  for (const auto& [t, d] : topics) {
    names.insert(t);
    if (t == topic) {
      if (!type.empty() && type != d)
        throw Error(StrCat(bag, ": topic ", topic, ": mixed types ", type, " and ", d));
      type = d;
    }
  }
  if (type.empty() && required) {
    std::string list;
    for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
    throw Error(
        StrCat(bag, ": topic ", topic, ": not in the bag (topics: ", Excerpt(list, 400), ")"));
  }
  return type;
}

// A stamped planar pose series from an odometry-like topic.
struct PoseSeries {
  std::vector<double> stamps_s;
  std::vector<Pose2> poses;
};

// Visits the messages of a topic with their 0-based index; errors of the bag and of the
// visitor get "<bag>: topic <t>: message <i>: ".
void ForEachIndexed(const ros1::BagReader& bag, const std::string& path, const std::string& topic,
                    const std::function<void(const ros1::BagMessage&, std::int64_t)>& visit) {
  std::int64_t index = 0;
  try {
    bag.ForEach(topic, [&](const ros1::BagMessage& m) {
      visit(m, index);
      ++index;
      return true;
    });
  } catch (const Error&) {
    throw;
  } catch (const std::runtime_error& e) {
    throw Error(StrCat(Where(path, topic, index), e.what()));
  }
}

void AppendSample(PoseSeries* out, double stamp, const Pose2& pose, const std::string& where) {
  if (!pose.allFinite()) throw Error(where + "pose is not finite");
  if (!out->stamps_s.empty() && stamp <= out->stamps_s.back())
    throw Error(StrCat(where, "stamp ", FormatRoundTrip(stamp), " s is not after the previous ",
                       FormatRoundTrip(out->stamps_s.back()), " s"));
  out->stamps_s.push_back(stamp);
  out->poses.push_back(pose);
}

// Reads every message of `topic` as (header stamp, Pose2); stamps must increase.
void ReadPoseTopic(const ros1::BagReader& bag, const std::string& path, const std::string& topic,
                   PoseSeries* out) {
  ForEachIndexed(bag, path, topic, [&](const ros1::BagMessage& m, std::int64_t index) {
    double stamp = 0.0;
    ros1::PlanarPose pose;
    m.ReadPose(&stamp, &pose);
    AppendSample(out, stamp, FromPlanar(pose), Where(path, topic, index));
  });
}

// Odometry from /tf: the transforms whose child frame is `child`.
void ReadTfOdometry(const ros1::BagReader& bag, const std::string& path, const std::string& child,
                    PoseSeries* out) {
  ForEachIndexed(bag, path, "/tf", [&](const ros1::BagMessage& m, std::int64_t index) {
    for (const auto& [stamp, pose] : m.ReadTf(child))
      AppendSample(out, stamp, FromPlanar(pose), Where(path, "/tf", index));
  });
  if (out->stamps_s.empty())
    throw Error(StrCat(path, ": topic /tf: no transform with child frame '", child, "'"));
}

// The pose at stamp_s: a sample with that exact stamp, else interpolated between the two
// samples around it when they are at most max_gap_s apart; nullopt otherwise.
std::optional<Pose2> PoseAt(const PoseSeries& s, double stamp_s, double max_gap_s) {
  const auto it = std::lower_bound(s.stamps_s.begin(), s.stamps_s.end(), stamp_s);
  if (it == s.stamps_s.end()) return std::nullopt;
  const std::size_t k = static_cast<std::size_t>(it - s.stamps_s.begin());
  if (*it == stamp_s) return s.poses[k];
  if (k == 0 || s.stamps_s[k] - s.stamps_s[k - 1] > max_gap_s) return std::nullopt;
  return InterpolatePose(s.stamps_s[k - 1], s.poses[k - 1], s.stamps_s[k], s.poses[k], stamp_s);
}

struct SessionMark {
  double first_stamp_s = 0.0;  // bag stamp (offset included) from which the session applies
  SessionInfo info;
};

// Sessions written by ExportRosbag, in stamp order.
std::vector<SessionMark> ReadSessionTopic(const ros1::BagReader& bag, const std::string& path,
                                          const std::string& topic, double* offset_s) {
  std::vector<SessionMark> marks;
  ForEachIndexed(bag, path, topic, [&](const ros1::BagMessage& m, std::int64_t index) {
    SessionMark mark;
    mark.first_stamp_s = m.time_s();
    const std::string where = Where(path, topic, index);
    mark.info = ParseSessionMessage(m.ReadString(), where.substr(0, where.size() - 2), offset_s);
    marks.push_back(std::move(mark));
  });
  return marks;
}

SessionInfo AutomaticSession(const cv::Mat& image, const std::string& name, int number,
                             const RosbagImportOptions& o, const std::optional<Pose2>& truth,
                             double stamp_s) {
  SessionInfo info;
  info.name = name;
  info.day_label = StrCat("session ", number);
  info.start_time_s = stamp_s;
  info.camera.image_width = image.cols;
  info.camera.image_height = image.rows;
  if (!o.calibration_yaml.empty()) {
    info.camera.kind = ImageKind::kRawRing;
    info.camera.calibration = CameraCalibration::FromYamlFile(o.calibration_yaml);
  } else if (image.cols >= 2 * image.rows) {
    info.camera.kind = ImageKind::kPanorama;
  } else {
    info.camera.kind = ImageKind::kRawRing;
    info.camera.calibration = AutoCalibrate(image).calibration;
  }
  info.start.mode = number == 1 ? o.first_start : o.later_start;
  if (info.start.mode == SessionStartMode::kKnownPose)
    info.start.map_T_robot = truth.value_or(Pose2::Zero());
  return info;
}

}  // namespace

RosbagImportSummary ImportRosbag(const std::vector<std::string>& bag_paths,
                                 const std::string& log_dir, const RosbagImportOptions& options) {
  options.Validate();
  if (bag_paths.empty()) throw Error("no bag given");
  RosbagImportSummary summary;
  LogWriter writer(log_dir, options.overwrite);
  int session_number = 0;
  for (const std::string& path : bag_paths) {
    const std::unique_ptr<ros1::BagReader> bag_reader = OpenBag(path);
    const ros1::BagReader& bag = *bag_reader;
    std::vector<std::pair<std::string, std::string>> topics;
    try {
      topics = bag.Topics();
    } catch (const std::runtime_error& e) {
      throw Error(StrCat(path, ": cannot read the bag: ", e.what()));
    }
    const std::string image_type = TopicType(topics, path, options.image_topic, true);
    if (image_type != "sensor_msgs/Image" && image_type != "sensor_msgs/CompressedImage")
      throw Error(StrCat(Where(path, options.image_topic, 0), "type ", image_type,
                         ", expected sensor_msgs/Image or sensor_msgs/CompressedImage"));
    PoseSeries odom, truth;
    if (!options.odom_topic.empty()) {
      TopicType(topics, path, options.odom_topic, true);
      ReadPoseTopic(bag, path, options.odom_topic, &odom);
    } else {
      ReadTfOdometry(bag, path, options.odom_tf_frame, &odom);
    }
    if (!options.truth_topic.empty()) {
      TopicType(topics, path, options.truth_topic, true);
      ReadPoseTopic(bag, path, options.truth_topic, &truth);
    }
    double offset_s = 0.0;
    std::vector<SessionMark> marks;
    if (!TopicType(topics, path, options.session_topic, false).empty())
      marks = ReadSessionTopic(bag, path, options.session_topic, &offset_s);

    std::size_t next_mark = 0;
    bool session_open = false;
    double prev_stamp = -std::numeric_limits<double>::infinity();
    std::int64_t count = 0;
    ForEachIndexed(
        bag, path, options.image_topic, [&](const ros1::BagMessage& m, std::int64_t index) {
          const std::string where = Where(path, options.image_topic, index);
          ++count;
          cv::Mat image;
          double stamp = 0.0;
          m.ReadImage(&stamp, &image);
          if (stamp <= prev_stamp)
            throw Error(StrCat(where, "stamp ", FormatRoundTrip(stamp),
                               " s is not after the previous ", FormatRoundTrip(prev_stamp), " s"));
          const bool gap =
              options.split_gap_s > 0.0 && session_open && stamp - prev_stamp > options.split_gap_s;
          prev_stamp = stamp;
          const std::optional<Pose2> odom_pose =
              PoseAt(odom, stamp, std::numeric_limits<double>::infinity());
          if (!odom_pose) {
            ++summary.skipped_without_odometry;
            return;
          }
          const std::optional<Pose2> truth_pose =
              truth.stamps_s.empty() ? std::nullopt : PoseAt(truth, stamp, options.truth_max_gap_s);
          try {
            // Sessions: the exported ones, else one per bag, split at gaps.
            if (!marks.empty()) {
              if (next_mark < marks.size() && stamp >= marks[next_mark].first_stamp_s) {
                writer.BeginSession(marks[next_mark++].info);
                ++session_number;
                session_open = true;
              } else if (!session_open) {
                throw Error(
                    StrCat("image before the first session message on ", options.session_topic));
              }
            } else if (!session_open || gap) {
              ++session_number;
              char name[32];
              std::snprintf(name, sizeof(name), "%06d", session_number);
              writer.BeginSession(
                  AutomaticSession(image, name, session_number, options, truth_pose, stamp));
              session_open = true;
            }
            Frame frame;
            frame.stamp_s = stamp - offset_s;
            frame.image = std::move(image);
            frame.odom_T_robot = *odom_pose;
            frame.map_T_robot_truth = truth_pose;
            writer.Write(frame);
          } catch (const Error& e) {
            throw Error(where + e.what());
          }
          ++summary.frames;
          if (truth_pose) ++summary.frames_with_truth;
        });
    if (count == 0) throw Error(StrCat(path, ": topic ", options.image_topic, ": no messages"));
  }
  summary.sessions = session_number;
  writer.Finish();
  return summary;
}

}  // namespace omnicml
