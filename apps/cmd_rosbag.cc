// `omnicml export rosbag LOG --out BAG` and
// `omnicml import rosbag BAG... --image-topic T (--odom-topic T | --odom-tf FRAME)
//  [--truth-topic T] [--calibration YAML] [--split-gap S] --out LOG`
// (src/ros/rosbag_io.h). Registered as subcommands of `export` and `import`, whose
// registrations sort before this one ("rosbag").
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/ros/rosbag_io.h"

namespace omnicml::app {
namespace {

struct ExportRosbagArgs {
  std::string log;
  std::string out;
  RosbagExportOptions options;
};

struct ImportRosbagArgs {
  std::vector<std::string> bags;
  std::string out;
  std::string first_start = "known";
  std::string later_start = "global";
  RosbagImportOptions options;
};

void AddExport(CLI::App& app) {
  CLI::App* parent = app.get_subcommand("export");
  auto args = std::make_shared<ExportRosbagArgs>();
  CLI::App* cmd = parent->add_subcommand("rosbag",
                                         "Write a log as a ROS 1 bag (images, odometry, tf, "
                                         "ground truth, sessions)");
  cmd->add_option("LOG", args->log, "Log directory")->required();
  AddOutputFile(cmd, "--out", &args->out, "Output bag file")->required();
  RosbagExportOptions& o = args->options;
  cmd->add_flag("--compressed", o.compressed, "sensor_msgs/CompressedImage (PNG) instead of Image");
  cmd->add_option("--image-topic", o.image_topic)->capture_default_str();
  cmd->add_option("--odom-topic", o.odom_topic)->capture_default_str();
  cmd->add_option("--truth-topic", o.truth_topic)->capture_default_str();
  cmd->add_flag("--overwrite", o.overwrite, "Replace an existing bag");
  cmd->callback([args] {
    const RosbagExportSummary s = ExportRosbag(args->log, args->out, args->options);
    std::cout << "wrote " << s.frames << " frames of " << s.sessions << " sessions to "
              << args->out;
    if (s.stamp_offset_s != 0.0) std::cout << " (stamps shifted by " << s.stamp_offset_s << " s)";
    std::cout << "\n";
  });
}

void AddImport(CLI::App& app) {
  CLI::App* parent = app.get_subcommand("import");
  auto args = std::make_shared<ImportRosbagArgs>();
  CLI::App* cmd =
      parent->add_subcommand("rosbag", "Import ROS 1 bags (images + odometry) as one log");
  cmd->add_option("BAG", args->bags, "Bag files, in time order")->required();
  AddOutputDirectory(cmd, "--out", &args->out, "Output log directory")->required();
  RosbagImportOptions& o = args->options;
  cmd->add_option("--image-topic", o.image_topic, "sensor_msgs/Image or CompressedImage topic")
      ->required();
  cmd->add_option("--odom-topic", o.odom_topic, "nav_msgs/Odometry (or PoseStamped) topic");
  cmd->add_option("--odom-tf", o.odom_tf_frame,
                  "Odometry from /tf: the robot's child frame, e.g. base_link");
  cmd->add_option("--truth-topic", o.truth_topic,
                  "Ground truth (Odometry or PoseStamped, map frame)");
  cmd->add_option("--calibration", o.calibration_yaml,
                  "Camera calibration YAML of raw images, any camera model (default: automatic "
                  "from the first frame)");
  cmd->add_option("--split-gap", o.split_gap_s,
                  "New session where image stamps jump by more, seconds")
      ->capture_default_str();
  cmd->add_option("--truth-max-gap", o.truth_max_gap_s,
                  "Largest gap truth is interpolated over, seconds")
      ->capture_default_str();
  cmd->add_option("--start", args->first_start, "First session's start: known | global")
      ->check(CLI::IsMember({"known", "global"}))
      ->capture_default_str();
  cmd->add_option("--later-start", args->later_start,
                  "Later sessions' start: known | continue | global")
      ->check(CLI::IsMember({"known", "continue", "global"}))
      ->capture_default_str();
  cmd->add_option("--session-topic", o.session_topic,
                  "Sessions written by export rosbag (std_msgs/String); \"\" ignores them")
      ->capture_default_str();
  cmd->add_flag("--overwrite", o.overwrite, "Replace an existing log");
  cmd->callback([args] {
    args->options.first_start = SessionStartModeFromString(args->first_start);
    args->options.later_start = SessionStartModeFromString(args->later_start);
    const RosbagImportSummary s = ImportRosbag(args->bags, args->out, args->options);
    std::cout << "wrote " << s.frames << " frames (" << s.frames_with_truth
              << " with ground truth) in " << s.sessions << " sessions to " << args->out;
    if (s.skipped_without_odometry > 0)
      std::cout << "; skipped " << s.skipped_without_odometry
                << " images outside the odometry's time span";
    std::cout << "\n";
  });
}

const CommandRegistration kRegistration{"rosbag", [](CLI::App& app) {
                                          AddExport(app);
                                          AddImport(app);
                                        }};

}  // namespace
}  // namespace omnicml::app
