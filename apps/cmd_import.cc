// `omnicml import antworld CSV --out DIR [--seed S] [--stride N]`: converts an AntWorld
// route or grid (../shared/datasets/antworld) into a one-session log.
// `omnicml import video VIDEO --poses CSV --out DIR [--calibration YAML] [--fps F] ...`:
// a video and its poses (logs/video.h) as a one-session log whose frames.csv names the
// video's frames.
// `omnicml validate LOGDIR`: reads a whole log (every row and image) and prints its
// sessions and frame counts; the first problem is reported as "file:line: what".
#include <cstdint>
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/logs/antworld.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/logs/video.h"

namespace omnicml::app {
namespace {

struct ImportArgs {
  std::string csv;
  std::string out_dir;
  std::uint64_t seed = 1;
  int stride = 1;
  double row_period_s = 0.1;
};

struct VideoArgs {
  std::string video;
  std::string poses;
  std::string out_dir;
  VideoImportOptions options;
};

const CommandRegistration kImport{
    "import", [](CLI::App& app) {
      auto args = std::make_shared<ImportArgs>();
      CLI::App* cmd = app.add_subcommand("import", "Import external data as an omnicml log");
      cmd->require_subcommand(1);
      CLI::App* antworld = cmd->add_subcommand(
          "antworld", "Import an AntWorld CSV (mm, degrees, 720x150 panoramas)");
      antworld->add_option("CSV", args->csv, "AntWorld pose file; images beside it")->required();
      AddOutputDirectory(antworld, "--out", &args->out_dir, "Output log directory (must not exist)")
          ->required();
      antworld->add_option("--seed", args->seed, "Seed of the odometry noise")
          ->capture_default_str();
      antworld->add_option("--stride", args->stride, "Use every N-th row")->capture_default_str();
      antworld->add_option("--row-period", args->row_period_s, "Seconds between CSV rows")
          ->capture_default_str();
      auto video_args = std::make_shared<VideoArgs>();
      CLI::App* video = cmd->add_subcommand(
          "video", "Import a video (FFmpeg-decodable: .avi .mkv .mp4 .mov .webm) and its poses");
      video->add_option("VIDEO", video_args->video, "Video file")->required();
      video
          ->add_option("--poses", video_args->poses,
                       "Poses CSV: frame or stamp_s, then gt_x_m,gt_y_m,gt_phi_rad and/or "
                       "odom_x_m,odom_y_m,odom_phi_rad; one log frame per row (docs/guide.md)")
          ->required();
      AddOutputDirectory(video, "--out", &video_args->out_dir, "Output log directory")->required();
      VideoImportOptions& vo = video_args->options;
      video->add_option("--calibration", vo.calibration_yaml,
                        "Camera calibration YAML of raw frames, any camera model (default: "
                        "panorama when twice as wide as high, else the ring auto-calibrated)");
      video->add_option("--fps", vo.fps, "Frames per second (default: the video's)");
      video->add_option("--start-time", vo.start_time_s, "Stamp of the video's first frame, s")
          ->capture_default_str();
      video->add_option("--seed", vo.seed, "Seed of the odometry noise (no odometry columns)")
          ->capture_default_str();
      video->add_option("--session-name", vo.session_name,
                        "Session directory name (default: the video's file stem)");
      video->add_option("--day-label", vo.day_label, "Day label of the session")
          ->capture_default_str();
      video->add_flag("--overwrite", vo.overwrite, "Replace an existing log");
      video->callback([video_args] {
        const VideoImportSummary s = ImportVideo(video_args->video, video_args->poses,
                                                 video_args->out_dir, video_args->options);
        std::cout << "wrote " << s.frames << " frames (" << s.frames_with_truth
                  << " with ground truth"
                  << (s.odometry_sampled ? ", odometry sampled from it" : "") << ") to "
                  << video_args->out_dir << "\n";
      });
      antworld->callback([args] {
        AntWorldOptions options;
        options.seed = args->seed;
        options.stride = args->stride;
        options.row_period_s = args->row_period_s;
        const std::int64_t frames = ImportAntWorld(args->csv, args->out_dir, options);
        std::cout << "wrote " << frames << " frames to " << args->out_dir << "\n";
      });
    }};

const CommandRegistration kValidate{
    "validate", [](CLI::App& app) {
      auto log_dir = std::make_shared<std::string>();
      CLI::App* cmd =
          app.add_subcommand("validate", "Check a log completely (every row and image)");
      cmd->add_option("LOGDIR", *log_dir, "Log directory (multi-day) or one session directory")
          ->required();
      cmd->callback([log_dir] {
        const LogSummary summary = ValidateLog(*log_dir);
        for (const LogSessionSummary& s : summary.sessions) {
          std::cout << s.name << ": " << s.frames << " frames (" << s.frames_with_truth
                    << " with ground truth)";
          if (s.frames > 0)
            std::cout << ", stamps " << s.first_stamp_s << " .. " << s.last_stamp_s << " s";
          if (!s.day_label.empty()) std::cout << ", day \"" << s.day_label << "\"";
          std::cout << "\n";
        }
        std::cout << "ok: " << summary.sessions.size() << " sessions, " << summary.total_frames
                  << " frames\n";
      });
    }};

}  // namespace
}  // namespace omnicml::app
