// `omnicml export MAP --format json|csv|svg|png --out FILE`: the learned map (views,
// component means, covariance ellipses, weights and eta, counters, descriptor summaries;
// JSON schema in map_export.h and datasets/map_schema.md); the pictures draw the map
// over the floor plan (--world, or the world of --run), ground truth and estimate (--run's
// frames.csv) or a TUM trajectory (--trajectory).
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <opencv2/imgcodecs.hpp>

#include "cli_common.h"
#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/map_export.h"
#include "omnicml/report/report.h"
#include "omnicml/run/floor_plan.h"
#include "omnicml/sim/world.h"

namespace omnicml::app {

namespace {

struct ExportFlags {
  std::string map;
  std::string format;
  std::string out;
  std::string trajectory;
  std::string run;    // run directory: estimate, ground truth and world
  std::string world;  // built-in world name or world file: floor plan
  int world_day = 0;  // floor plan state at this day (0 = the run's last day, else 1)
  std::string color = "weight";
  bool features = false;
  bool no_events = false;
  int width_px = 900;
};

void Export(const ExportFlags& f) {
  std::string format = f.format;
  if (format.empty()) {
    format = std::filesystem::path(f.out).extension().string();
    if (!format.empty()) format = format.substr(1);
  }
  if (format != "json" && format != "csv" && format != "svg" && format != "png") {
    throw Error(StrCat("--format '", format, "': expected json, csv, svg or png"));
  }
  const std::filesystem::path parent = std::filesystem::path(f.out).parent_path();
  if (!parent.empty() && !std::filesystem::is_directory(parent)) {
    throw Error(StrCat("--out '", f.out, "': directory '", parent.string(), "' does not exist"));
  }
  if (f.width_px < 200 || f.width_px > 10000) throw Error("--width must be in 200..10000");
  const std::unique_ptr<CmlEngine> engine = LoadMapForReading(f.map);
  std::vector<Pose2> trajectory;
  MapPictureOptions pic;
  pic.coloring = MapColoringFromString(f.color);
  // The run directory gives the estimate and ground truth (frames.csv) and the world.
  std::string world = f.world;
  int day = f.world_day;
  std::uint64_t seed = 1;
  if (!f.run.empty()) {
    for (const FrameRecord& r :
         ReadFramesCsv(std::filesystem::path(f.run) / "frames.csv").records) {
      if (r.has_estimate) trajectory.push_back(r.estimate);
      if (r.has_truth) pic.ground_truth.push_back(r.truth);
    }
    if (const auto w = ReadRunWorld(f.run)) {
      if (world.empty()) world = w->world;
      if (day == 0) day = w->last_day;
      seed = w->seed;
    }
  }
  if (!f.trajectory.empty()) {
    trajectory.clear();
    for (const TimedPose& p : ReadTumTrajectory(f.trajectory)) trajectory.push_back(p.pose);
  }
  if (!world.empty()) pic.floor_plan = FloorPlanFromWorld(LoadWorld(world), std::max(1, day), seed);
  pic.width_px = f.width_px;
  pic.title = std::filesystem::path(f.map).filename().string();
  if (format == "json") {
    MapExportOptions options;
    options.include_features = f.features;
    options.include_events = !f.no_events;
    WriteFileAtomic(f.out, MapToJson(*engine, options).dump(1) + "\n");
  } else if (format == "csv") {
    WriteFileAtomic(f.out, MapToCsv(engine->model()));
  } else if (format == "svg") {
    WriteFileAtomic(f.out, MapToSvg(engine->model(), trajectory, pic));
  } else {
    std::vector<std::uint8_t> png;
    if (!cv::imencode(".png", MapToImage(engine->model(), trajectory, pic), png)) {
      throw Error("PNG encoding failed");
    }
    WriteFileAtomic(f.out, std::string_view(reinterpret_cast<const char*>(png.data()), png.size()));
  }
  std::cout << "exported " << engine->model().NumViews() << " views, "
            << engine->model().NumComponents() << " components as " << format << " to " << f.out
            << "\n";
}

const CommandRegistration kRegistration{
    "export", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand("export", "Export a learned map as JSON, CSV, SVG or PNG");
      auto flags = std::make_shared<ExportFlags>();
      // Not ->required(): `export rosbag LOG --out BAG` (cmd_rosbag.cc) is a subcommand of
      // export; without one, map and --out are checked in the callback.
      cmd->add_option("map", flags->map, "Map (engine) file written by omnicml run --map-out");
      cmd->add_option("--format", flags->format,
                      "json | csv | svg | png (default: from the --out extension)");
      AddOutputFile(cmd, "--out", &flags->out, "Output file");
      cmd->add_option("--trajectory", flags->trajectory,
                      "TUM trajectory drawn under the map (svg, png)");
      cmd->add_option("--run", flags->run,
                      "Run directory of the map (svg, png): its estimate and ground truth "
                      "(frames.csv) and, for simulated runs, the world's floor plan");
      cmd->add_option("--world", flags->world,
                      "Built-in world name or world file whose floor plan is drawn (svg, png)");
      cmd->add_option("--world-day", flags->world_day,
                      "Draw the floor plan as at the start of this day (default: the run's "
                      "last day, else 1)");
      cmd->add_option("--color", flags->color,
                      "Dots coloured by component weight or by area health (svg, png)")
          ->check(CLI::IsMember({"weight", "health"}))
          ->capture_default_str();
      cmd->add_flag("--features", flags->features, "JSON: include the full descriptor vectors");
      cmd->add_flag("--no-events", flags->no_events, "JSON: leave out the event log");
      cmd->add_option("--width", flags->width_px, "Picture width in pixels (svg, png)")
          ->capture_default_str();
      cmd->callback([flags, cmd] {
        if (!cmd->get_subcommands().empty()) return;
        if (flags->map.empty()) throw CLI::RequiredError("map");
        if (flags->out.empty()) throw CLI::RequiredError("--out");
        Export(*flags);
      });
    }};

}  // namespace
}  // namespace omnicml::app
