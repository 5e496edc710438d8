// `omnicml simulate --world NAME|FILE --days N --frames-per-day M --seed S --out DIR
//   [--panorama] [--preview PNG] [--start known|continue|global] [--step-m D] [--overwrite]`
// writes a simulated multi-day log (one session per day: day_001, day_002, ...) with
// ground truth, plus simulation.yaml (the effective options) and world.yaml (the world
// used) next to the sessions. `omnicml simulate --list` lists the built-in worlds.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/imgproc.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/unwrap/omni_unwrapper.h"
#include "omnicml/sim/renderer.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"

namespace omnicml::app {
namespace {

struct SimulateArgs {
  std::string world = "home_store";
  int days = 1;
  int frames_per_day = 300;
  std::uint64_t seed = 1;
  std::string out;
  bool panorama = false;
  std::string preview;
  std::string start = "known";
  double step_m = 0.2;
  bool overwrite = false;
  bool list = false;
};

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

std::string OptionsYaml(const SimulatorOptions& o, const World& world) {
  std::ostringstream os;
  os << "# Effective options of `omnicml simulate` (SimulatorOptions).\n"
     << "world: \"" << o.world << "\"\n"
     << "world_name: " << world.name << "\n"
     << "days: " << o.days << "\n"
     << "frames_per_day: " << o.frames_per_day << "\n"
     << "seed: " << o.seed << "\n"
     << "output: " << (o.output == ImageKind::kRawRing ? "raw_ring" : "panorama") << "\n"
     << "step_m: " << FormatRoundTrip(o.step_m) << "\n"
     << "later_days_start: " << ToString(o.later_days_start) << "\n"
     << "sensor_noise: " << (o.sensor_noise ? "true" : "false") << "\n"
     << "people: " << (o.people ? "true" : "false") << "\n";
  return os.str();
}

void RunSimulate(const SimulateArgs& args) {
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
  if (args.out.empty()) throw Error("simulate: --out DIR is required (or --list)");
  SimulatorOptions options;
  options.world = args.world;
  options.days = args.days;
  options.frames_per_day = args.frames_per_day;
  options.seed = args.seed;
  options.output = args.panorama ? ImageKind::kPanorama : ImageKind::kRawRing;
  options.step_m = args.step_m;
  options.later_days_start = SessionStartModeFromString(args.start);
  options.Validate();
  const World world = LoadWorld(options.world);
  SimulatedFrameSource source(options, world);

  const auto t0 = std::chrono::steady_clock::now();
  LogWriter writer(args.out, args.overwrite);
  std::vector<DaySamples> samples(options.days);
  Frame frame;
  int session = -1;
  std::int64_t frames = 0;
  while (source.Next(&frame)) {
    if (frame.session_index != session) {
      session = frame.session_index;
      writer.BeginSession(source.Session(session));
    }
    writer.Write(frame);
    ++frames;
    if (!args.preview.empty()) {
      const std::int64_t m = options.frames_per_day;
      const std::int64_t i = frame.index_in_session;
      if (i == 0 || i == m / 4 || i == m / 2 || i == 3 * m / 4) {
        auto& day = samples[frame.session_index];
        if (day.panoramas.size() < 4) {
          day.panoramas.push_back(source.last_panorama().clone());
          day.poses.push_back(*frame.map_T_robot_truth);
        }
      }
    }
  }
  writer.Finish();
  namespace fs = std::filesystem;
  {
    std::ofstream(fs::path(args.out) / "simulation.yaml") << OptionsYaml(options, world);
    std::string world_text;
    bool builtin = false;
    for (const auto& n : BuiltinWorldNames()) builtin |= n == options.world;
    if (builtin) {
      world_text = BuiltinWorldText(options.world);
    } else {
      std::ifstream in(options.world);
      std::stringstream ss;
      ss << in.rdbuf();
      world_text = ss.str();
    }
    std::ofstream(fs::path(args.out) / "world.yaml") << world_text;
  }
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
      cmd->add_option("--world", args->world, "Built-in world name or world YAML file")
          ->capture_default_str();
      cmd->add_option("--days", args->days, "Number of days (sessions)")->capture_default_str();
      cmd->add_option("--frames-per-day", args->frames_per_day, "Frames per day")
          ->capture_default_str();
      cmd->add_option("--seed", args->seed, "Seed of every random stream")->capture_default_str();
      cmd->add_option("--out", args->out, "Output log directory");
      cmd->add_flag("--panorama", args->panorama, "Write panoramas instead of raw ring images");
      cmd->add_option("--preview", args->preview,
                      "Write a PNG with the floor plan, route and sample panoramas");
      cmd->add_option("--start", args->start,
                      "How days after the first start: known|continue|global")
          ->capture_default_str();
      cmd->add_option("--step-m", args->step_m, "Distance between frames, m")
          ->capture_default_str();
      cmd->add_flag("--overwrite", args->overwrite, "Replace an existing log directory");
      cmd->callback([args] { RunSimulate(*args); });
    }};

}  // namespace
}  // namespace omnicml::app
