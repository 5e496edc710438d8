// `omnicml export MAP --format json|csv|svg|png --out FILE`: the learned map (views,
// component means, covariance ellipses, weights and eta, counters, descriptor summaries;
// JSON schema in map_export.h and datasets/map_schema.md); the pictures draw the map
// over a TUM trajectory when --trajectory is given.
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
#include "omnicml/report/map_export.h"
#include "omnicml/report/report.h"

namespace omnicml::app {

namespace {

struct ExportFlags {
  std::string map;
  std::string format;
  std::string out;
  std::string trajectory;
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
  if (!f.trajectory.empty()) {
    for (const TimedPose& p : ReadTumTrajectory(f.trajectory)) trajectory.push_back(p.pose);
  }
  MapPictureOptions pic;
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
      cmd->add_option("map", flags->map, "Map (engine) file written by omnicml run --map-out")
          ->required();
      cmd->add_option("--format", flags->format,
                      "json | csv | svg | png (default: from the --out extension)");
      cmd->add_option("--out", flags->out, "Output file")->required();
      cmd->add_option("--trajectory", flags->trajectory,
                      "TUM trajectory drawn under the map (svg, png)");
      cmd->add_flag("--features", flags->features, "JSON: include the full descriptor vectors");
      cmd->add_flag("--no-events", flags->no_events, "JSON: leave out the event log");
      cmd->add_option("--width", flags->width_px, "Picture width in pixels (svg, png)")
          ->capture_default_str();
      cmd->callback([flags] { Export(*flags); });
    }};

}  // namespace
}  // namespace omnicml::app
