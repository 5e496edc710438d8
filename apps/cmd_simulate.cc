// `omnicml simulate --world NAME|FILE --days N --frames-per-day M --seed S --out DIR
//   [--panorama] [--camera KIND] [--preview PNG] [--start known|continue|global] [--step-m D]
//   [--overwrite]
//   [--config SIMULATION.yaml]`
// `omnicml simulate --change-report --world W --days N --seed S [--layout-intensity X]`
// prints how much of the panorama differs from day 1 along the route, per day.
// writes a simulated multi-day log (one session per day: day_001, day_002, ...) with
// ground truth, plus simulation.yaml (the effective options) and world.yaml (the world
// used) next to the sessions. `omnicml simulate --list` lists the built-in worlds.
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/imgproc.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sim/renderer.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml::app {
namespace {

struct SimulateArgs {
  std::string world = "home_store";
  int days = 1;
  int frames_per_day = 300;
  std::uint64_t seed = 1;
  std::string out;
  bool panorama = false;
  std::string camera = "ring";  // SimulatedCamera name
  std::string preview;
  std::string start = "known";
  double step_m = 0.2;
  bool overwrite = false;
  bool list = false;
  std::string config;  // SimulatorOptions YAML; flags given override it
  bool change_report = false;
  double layout_intensity = -1;  // < 0: the world's own
  double pose_spacing_m = 2.0;
};

// Prints, for days 2..days, how much of the panorama differs from day 1 at the same
// poses (world.h ChangedPanoramaFraction, the threshold of change detection: 3 sqrt(2)
// sensor-noise sigmas): with the world's events and layout changes, and with the layout
// changes alone (events dropped), beside the expected fraction of changed layout elements.
void PrintChangeReport(const World& world, const SimulateArgs& args) {
  const auto fixed = [](double v, int decimals) {
    std::ostringstream os;
    os << std::fixed << std::setprecision(decimals) << v;
    return os.str();
  };
  World layout_only = world;
  layout_only.events.clear();
  const std::vector<Pose2> poses = RoutePoses(world, args.pose_spacing_m);
  const double threshold = 3.0 * std::sqrt(2.0) * world.camera.noise_sigma_gray;
  const double p = world.changes.layout_intensity;
  const WorldState first_all = StateAtDayStart(world, 1, args.seed);
  const WorldState first_layout = StateAtDayStart(layout_only, 1, args.seed);
  std::cout << "world " << world.name << ", layout_intensity " << p << ", seed " << args.seed
            << ", " << poses.size() << " route poses every " << args.pose_spacing_m
            << " m; fraction of panorama pixels differing from day 1 (> " << fixed(threshold, 2)
            << " grey levels)\n";
  std::cout << "day\texpected_elements\tchanged_layout_only\tchanged_with_events\n";
  for (int d = 2; d <= args.days; ++d) {
    const double expected = 1.0 - std::pow(1.0 - p, d - 1);
    const double layout = ChangedPanoramaFraction(
        layout_only, first_layout, StateAtDayStart(layout_only, d, args.seed), poses, threshold);
    const double all = ChangedPanoramaFraction(
        world, first_all, StateAtDayStart(world, d, args.seed), poses, threshold);
    std::cout << d << "\t" << fixed(expected, 3) << "\t" << fixed(layout, 3) << "\t"
              << fixed(all, 3) << "\n";
  }
}

// Samples of one day for the preview strip.
struct DaySamples {
  std::vector<cv::Mat> panoramas;
  std::vector<Pose2> poses;
};

cv::Mat ComposePreview(const SimulatedFrameSource& source, const std::vector<DaySamples>& days) {
  const World& world = source.world();
  const double px_per_m = std::min(900.0 / world.size_m.x(), 640.0 / world.size_m.y());
  std::vector<Pose2> poses;
  for (const auto& d : days) poses.insert(poses.end(), d.poses.begin(), d.poses.end());
  const cv::Mat plan = DrawFloorPlan(world, StateAtDayStart(world, 1, source.options().seed),
                                     source.route().Sample(0.1), poses, px_per_m);
  constexpr int kThumbW = 360, kThumbH = 60, kLabelW = 90, kGap = 6;
  const int strip_w = kLabelW + 4 * (kThumbW + kGap);
  const int width = std::max(plan.cols, strip_w);
  const int height = plan.rows + static_cast<int>(days.size()) * (kThumbH + kGap) + kGap;
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  plan.copyTo(canvas(cv::Rect(0, 0, plan.cols, plan.rows)));
  int y = plan.rows + kGap;
  for (std::size_t d = 0; d < days.size(); ++d) {
    cv::putText(canvas, StrCat("day ", d + 1), cv::Point(6, y + kThumbH / 2 + 5),
                cv::FONT_HERSHEY_SIMPLEX, 0.55, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    int x = kLabelW;
    for (const cv::Mat& pano : days[d].panoramas) {
      cv::Mat thumb;
      cv::resize(pano, thumb, cv::Size(kThumbW, kThumbH), 0, 0, cv::INTER_AREA);
      thumb.copyTo(canvas(cv::Rect(x, y, kThumbW, kThumbH)));
      x += kThumbW + kGap;
    }
    y += kThumbH + kGap;
  }
  return canvas;
}

// simulation.yaml: every SimulatorOptions field (loadable with --config, whose loader
// skips world_name) and the name of the world.
std::string OptionsYaml(const SimulatorOptions& o, const World& world) {
  return StrCat("# Effective options of `omnicml simulate` (SimulatorOptions); loads back with\n",
                "# `omnicml simulate --config simulation.yaml --out DIR`.\n",
                SimulatorOptionsToYaml(o), "world_name: \"", world.name, "\"\n");
}

// The options of a run: the --config file (or the defaults), then every flag given on the
// command line (without --config, every flag, so the flags' defaults apply).
SimulatorOptions ResolveOptions(const SimulateArgs& args, const CLI::App& cmd) {
  SimulatorOptions options;
  if (!args.config.empty()) options = LoadSimulatorOptions(args.config);
  const auto given = [&](const char* flag) { return args.config.empty() || cmd.count(flag) > 0; };
  if (given("--world")) options.world = args.world;
  if (given("--days")) {
    CheckLimit("--days", args.days, 1, kMaxDays);
    options.days = args.days;
  }
  if (given("--frames-per-day")) {
    CheckLimit("--frames-per-day", args.frames_per_day, 1, kMaxFramesPerDay);
    options.frames_per_day = args.frames_per_day;
  }
  if (given("--seed")) options.seed = args.seed;
  if (given("--panorama"))
    options.output = args.panorama ? ImageKind::kPanorama : ImageKind::kRawRing;
  if (given("--camera")) options.camera = SimulatedCameraFromString(args.camera);
  if (given("--step-m")) options.step_m = args.step_m;
  if (given("--start")) options.later_days_start = SessionStartModeFromString(args.start);
  if (static_cast<std::int64_t>(options.days) * options.frames_per_day > kMaxSimulatedFrames) {
    throw Error(StrCat("--days x --frames-per-day = ", options.days, " x ", options.frames_per_day,
                       " exceeds the limit of ", kMaxSimulatedFrames, " frames"));
  }
  if (!options.render_images) throw Error("simulate: render_images: false writes no images");
  options.Validate();
  return options;
}

void RunSimulate(const SimulateArgs& args, const CLI::App& cmd) {
  if (args.list) {
    for (const auto& name : BuiltinWorldNames()) {
      const World w = LoadBuiltinWorld(name);
      const RoutePath route(w.route.waypoints_m, w.route.turn_radius_m);
      std::ostringstream line;
      line << std::fixed << std::setprecision(1) << name << "\t" << w.size_m.x() << " m x "
           << w.size_m.y() << " m, lap " << route.length_m() << " m\t" << w.description;
      std::cout << line.str() << "\n";
    }
    return;
  }
  if (args.change_report) {
    World world = LoadWorld(args.world);
    if (args.layout_intensity >= 0) world = WithLayoutIntensity(world, args.layout_intensity);
    PrintChangeReport(world, args);
    return;
  }
  if (args.layout_intensity >= 0)
    throw Error(
        "simulate: --layout-intensity goes with --change-report (in a log, set "
        "changes.layout_intensity in a world file)");
  if (args.out.empty()) throw Error("simulate: --out DIR is required (or --list)");
  const SimulatorOptions options = ResolveOptions(args, cmd);
  // Outputs are checked before the first frame is rendered.
  if (!args.overwrite) {
    std::error_code ec;
    if (std::filesystem::exists(std::filesystem::symlink_status(args.out, ec))) {
      throw Error(StrCat("--out '", args.out, "': already exists (remove it or give --overwrite)"));
    }
  }
  CheckOutputDirectory(args.out, "--out");
  CheckOutputFile(args.preview, "--preview");
  if (!args.preview.empty()) {
    // The picture's format comes from its extension: checked now, not after simulating.
    std::string ext = std::filesystem::path(args.preview).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext != ".png" && ext != ".jpg" && ext != ".jpeg" && ext != ".bmp" && ext != ".tif" &&
        ext != ".tiff" && ext != ".ppm" && ext != ".webp") {
      throw Error(StrCat("--preview '", args.preview,
                         "': name an image file (.png, .jpg, .bmp, .tif, .ppm or .webp)"));
    }
  }
  const World world = LoadWorld(options.world);
  // The world's text, saved next to the sessions (read now, so a bad file fails first).
  const std::vector<std::string> builtins = BuiltinWorldNames();
  const bool builtin = std::find(builtins.begin(), builtins.end(), options.world) != builtins.end();
  const std::string world_text = builtin ? BuiltinWorldText(options.world)
                                         : ReadTextFile(options.world, kMaxTextFileBytes, "world");
  SimulatedFrameSource source(options, world);

  const auto t0 = std::chrono::steady_clock::now();
  LogWriter writer(args.out, args.overwrite);
  writer.AddFile("simulation.yaml", OptionsYaml(options, world));
  writer.AddFile("world.yaml", world_text);
  std::vector<DaySamples> samples(options.days);
  std::function<void(const Frame&)> sample_preview;
  if (!args.preview.empty()) {
    sample_preview = [&](const Frame& frame) {
      const std::int64_t m = options.frames_per_day;
      const std::int64_t i = frame.index_in_session;
      if (i == 0 || i == m / 4 || i == m / 2 || i == 3 * m / 4) {
        auto& day = samples[frame.session_index];
        if (day.panoramas.size() < 4) {
          day.panoramas.push_back(source.last_panorama().clone());
          day.poses.push_back(*frame.map_T_robot_truth);
        }
      }
    };
  }
  const std::int64_t frames = WriteFrames(source, writer, sample_preview);
  writer.Finish();
  if (!args.preview.empty()) WriteImage(args.preview, ComposePreview(source, samples));
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::cout << "simulated " << frames << " frames (" << options.days << " day(s) x "
            << options.frames_per_day << ") of world " << world.name << " into " << args.out
            << " in " << seconds << " s\n";
  if (!args.preview.empty()) std::cout << "preview: " << args.preview << "\n";
}

const CommandRegistration kRegistration{
    "simulate", [](CLI::App& app) {
      auto args = std::make_shared<SimulateArgs>();
      CLI::App* cmd =
          app.add_subcommand("simulate", "Write a simulated multi-day log with ground truth");
      cmd->add_flag("--list", args->list, "List the built-in worlds and exit");
      cmd->add_option("--config", args->config,
                      "SimulatorOptions YAML (keys = option names; DIR/simulation.yaml of any "
                      "simulated log loads back); the flags given override it");
      cmd->add_option("--world", args->world, "Built-in world name or world YAML file")
          ->capture_default_str();
      cmd->add_option("--days", args->days, StrCat("Number of days (sessions), at most ", kMaxDays))
          ->capture_default_str();
      cmd->add_option("--frames-per-day", args->frames_per_day,
                      StrCat("Frames per day, at most ", kMaxFramesPerDay, " (and days x frames ",
                             "at most ", kMaxSimulatedFrames, ")"))
          ->capture_default_str();
      cmd->add_option("--seed", args->seed, "Seed of every random stream")->capture_default_str();
      AddOutputDirectory(cmd, "--out", &args->out, "Output log directory");
      cmd->add_flag("--panorama", args->panorama, "Write panoramas instead of raw ring images");
      cmd->add_option("--camera", args->camera,
                      "Raw camera: ring | clipped_ring | bright_centre_ring | fisheye (each with "
                      "its ground-truth calibration in session.yaml)")
          ->check(CLI::IsMember({"ring", "clipped_ring", "bright_centre_ring", "fisheye"}))
          ->capture_default_str();
      AddOutputFile(cmd, "--preview", &args->preview,
                    "Write a PNG with the floor plan, route and sample panoramas");
      cmd->add_option("--start", args->start,
                      "How days after the first start: known|continue|global")
          ->capture_default_str();
      cmd->add_option("--step-m", args->step_m, "Distance between frames, m")
          ->capture_default_str();
      cmd->add_flag("--overwrite", args->overwrite, "Replace an existing log directory");
      cmd->add_flag("--change-report", args->change_report,
                    "Print, per day, the fraction of the panorama that differs from day 1 along "
                    "the route (layout changes alone and with the world's events); no log");
      cmd->add_option("--layout-intensity", args->layout_intensity,
                      "With --change-report: changes.layout_intensity in [0, 1] instead of the "
                      "world's")
          ->check(CLI::Range(0.0, 1.0));
      cmd->add_option("--pose-spacing-m", args->pose_spacing_m,
                      "With --change-report: distance between the route poses compared, m")
          ->capture_default_str()
          ->check(CLI::PositiveNumber);
      cmd->callback([args, cmd] { RunSimulate(*args, *cmd); });
    }};

}  // namespace
}  // namespace omnicml::app
