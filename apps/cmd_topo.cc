// `omnicml topo`: the cross-sequence experiment of [UN] (topological localization by
// colour-histogram place recognition; include/omnicml/topological.h). Reference images
// come from one day (session) of a simulated world or a log, the other day is localized
// frame by frame:
//
//   omnicml topo --world home_store --days 2 --train-day 1 --test-day 2 --frames-per-day 285
//       --seed 1 [--places places.yaml | --place-length-m 3] --out RUNDIR
//   omnicml topo --log LOGDIR [--world W] --train-day 1 --test-day 2 --places places.yaml --out
//   RUNDIR
//
// Days are 1-based. Places come from --places (adjacency-map YAML) or are derived from the
// world's route every --place-length-m metres (with --log the route is that of --world or
// of LOGDIR/world.yaml, which `omnicml simulate` writes). RUNDIR receives frames.csv (one
// row per test frame), summary.md (the [UN] Table 1 counts), places.yaml (the map used)
// and topo_config.yaml (the effective options).
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/baselines/topo/topological.h"
#include "omnicml/sim/world.h"

namespace omnicml::app {
namespace {

namespace fs = std::filesystem;

struct TopoArgs {
  std::string world;
  std::string log;
  int days = 0;  // 0: max(train, test)
  int frames_per_day = 300;
  std::uint64_t seed = 1;
  double step_m = 0.2;
  int train_day = 1;
  int test_day = 2;
  std::string places;
  double place_length_m = 3.0;
  std::string out;
  int bins = 32;
  int filter_width = 5;
  bool normalized_rgb = false;
  std::string distance = "jeffrey";
  double band_threshold = 0.05;
  double action_threshold = 0.1;
  bool all_places = false;
  int global_search_after = 0;
  int reference_stride = 1;
  bool global_start = false;
  bool people = true;
};

std::string ConfigYaml(const TopoArgs& a, const TopologicalOptions& o,
                       const CrossSequenceOptions& c, const std::string& places_from) {
  std::ostringstream os;
  os << "# Effective options of `omnicml topo` ([UN] topological localization).\n";
  if (!a.world.empty()) os << "world: \"" << a.world << "\"\n";
  if (!a.log.empty()) os << "log: \"" << a.log << "\"\n";
  if (a.log.empty()) {
    os << "days: " << a.days << "\nframes_per_day: " << a.frames_per_day << "\nseed: " << a.seed
       << "\nstep_m: " << FormatRoundTrip(a.step_m) << "\npeople: " << (a.people ? "true" : "false")
       << "\n";
  }
  os << "train_day: " << c.train_session + 1 << "\ntest_day: " << c.test_session + 1
     << "\nplaces: \"" << places_from << "\"\n"
     << "reference_stride_frames: " << c.reference_stride_frames << "\n"
     << "known_start: " << (c.known_start ? "true" : "false") << "\n"
     << "histogram: {bins: " << o.histogram.bins << ", filter_width: " << o.histogram.filter_width
     << ", normalized_rgb: " << (o.histogram.normalized_rgb ? "true" : "false")
     << ", distance: " << ToString(o.histogram.distance) << "}\n"
     << "band_threshold: [";
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    os << (b ? ", " : "") << FormatRoundTrip(o.band_threshold[b]);
  }
  os << "]\naction_threshold: " << FormatRoundTrip(o.action_threshold) << "\n"
     << "restrict_to_neighbours: " << (o.restrict_to_neighbours ? "true" : "false") << "\n"
     << "global_search_after_frames: " << o.global_search_after_frames << "\n";
  return os.str();
}

void WriteFile(const fs::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  if (!out) throw Error(StrCat(path.string(), ": cannot write"));
}

void RunTopo(TopoArgs a) {
  if (a.out.empty()) throw Error("topo: --out RUNDIR is required");
  if (a.world.empty() && a.log.empty()) throw Error("topo: give --world NAME or --log LOGDIR");
  if (a.train_day < 1 || a.test_day < 1)
    throw Error("topo: --train-day and --test-day are 1-based");
  if (a.train_day == a.test_day) {
    std::cerr << "warning: training and test day are the same (not a cross-sequence test)\n";
  }
  TopologicalOptions options;
  options.histogram.bins = a.bins;
  options.histogram.filter_width = a.filter_width;
  options.histogram.normalized_rgb = a.normalized_rgb;
  options.histogram.distance = HistogramDistanceFromString(a.distance);
  options.band_threshold.fill(a.band_threshold);
  options.action_threshold = a.action_threshold;
  options.restrict_to_neighbours = !a.all_places;
  options.global_search_after_frames = a.global_search_after;
  options.Validate();
  CrossSequenceOptions cross;
  cross.train_session = a.train_day - 1;
  cross.test_session = a.test_day - 1;
  cross.reference_stride_frames = a.reference_stride;
  cross.known_start = !a.global_start;
  cross.Validate();

  // The input and the route.
  std::unique_ptr<FrameSource> source;
  std::unique_ptr<RoutePath> route;
  if (a.log.empty()) {
    SimulatorOptions sim;
    sim.world = a.world;
    sim.days = a.days > 0 ? a.days : std::max(a.train_day, a.test_day);
    a.days = sim.days;
    sim.frames_per_day = a.frames_per_day;
    sim.seed = a.seed;
    sim.step_m = a.step_m;
    sim.people = a.people;
    sim.output = ImageKind::kPanorama;
    sim.Validate();
    auto sim_source = std::make_unique<SimulatedFrameSource>(sim);
    route = std::make_unique<RoutePath>(sim_source->route());
    source = std::move(sim_source);
  } else {
    std::string world = a.world;
    if (world.empty() && fs::exists(fs::path(a.log) / "world.yaml")) {
      world = (fs::path(a.log) / "world.yaml").string();
    }
    if (!world.empty()) {
      const World w = LoadWorld(world);
      route = std::make_unique<RoutePath>(w.route.waypoints_m, w.route.turn_radius_m);
    }
    source = std::make_unique<LogReader>(a.log);
  }

  AdjacencyMap map;
  std::string places_from;
  if (!a.places.empty()) {
    map = LoadAdjacencyMap(a.places);
    places_from = a.places;
  } else {
    if (!route) {
      throw Error("topo: --place-length-m needs a route: give --world or --places places.yaml");
    }
    map = PlacesFromRoute(*route, a.place_length_m);
    places_from = StrCat("route, place_length_m ", FormatRoundTrip(a.place_length_m));
  }

  TopologicalLocalizer localizer(map, options);
  const CrossSequenceResult r = RunCrossSequence(source.get(), &localizer, cross, route.get());

  fs::create_directories(a.out);
  const fs::path out(a.out);
  WriteFile(out / "places.yaml", AdjacencyMapYaml(map));
  WriteFile(out / "topo_config.yaml", ConfigYaml(a, options, cross, places_from));
  {
    const char* bands_rgb[] = {"H", "L", "S", "R", "G", "B"};
    const char* bands_nrgb[] = {"H", "L", "S", "r", "g", "b"};
    const char** bands = a.normalized_rgb ? bands_nrgb : bands_rgb;
    std::ostringstream csv;
    csv << "stamp_s,index,gt_x_m,gt_y_m,gt_phi_rad,true_place,believed_place,state,voted_place,"
           "confidence,voting_bands";
    for (int b = 0; b < ColorHistogram::kBands; ++b) csv << ",vote_" << bands[b];
    for (int b = 0; b < ColorHistogram::kBands; ++b) csv << ",conf_" << bands[b];
    csv << "\n";
    auto name = [&](int p) { return p < 0 ? std::string() : map.places()[p].name; };
    for (const auto& f : r.frames) {
      csv << FormatRoundTrip(f.stamp_s) << "," << f.index_in_session << ","
          << FormatRoundTrip(f.map_T_robot_truth.x()) << ","
          << FormatRoundTrip(f.map_T_robot_truth.y()) << ","
          << FormatRoundTrip(f.map_T_robot_truth.z()) << "," << name(f.true_place) << ","
          << name(f.believed_place) << "," << ToString(f.decision.state) << ","
          << name(f.decision.place) << "," << FormatRoundTrip(f.decision.confidence) << ","
          << f.decision.voting_bands;
      for (const auto& v : f.decision.bands) csv << "," << name(v.place);
      for (const auto& v : f.decision.bands) csv << "," << FormatRoundTrip(v.confidence);
      csv << "\n";
    }
    WriteFile(out / "frames.csv", csv.str());
  }
  const std::string input = a.log.empty() ? a.world : a.log;
  const std::string title =
      StrCat(input, ": train day ", a.train_day, ", test day ", a.test_day, " (", map.size(),
             " places, ", r.references, " reference images)");
  const std::string table = TopologicalSummaryTable(r.counts, title);
  WriteFile(out / "summary.md", table);
  std::cout << table << "run directory: " << a.out << "\n";
}

const CommandRegistration kRegistration{
    "topo", [](CLI::App& app) {
      auto a = std::make_shared<TopoArgs>();
      CLI::App* cmd =
          app.add_subcommand("topo",
                             "Topological localization by colour-histogram place recognition [UN]: "
                             "train on one day, test on another");
      cmd->add_option("--world", a->world, "Built-in world name or world YAML file");
      cmd->add_option("--log", a->log, "A multi-day log directory instead of simulating");
      cmd->add_option("--days", a->days, "Simulated days (0: max of train and test day)")
          ->capture_default_str();
      cmd->add_option("--frames-per-day", a->frames_per_day, "Simulated frames per day")
          ->capture_default_str();
      cmd->add_option("--seed", a->seed, "Simulator seed")->capture_default_str();
      cmd->add_option("--step-m", a->step_m, "Simulated distance between frames, m")
          ->capture_default_str();
      cmd->add_flag(
          "--no-people", [a](std::int64_t) { a->people = false; },
          "Simulate without walking people");
      cmd->add_option("--train-day", a->train_day, "Day (1-based) of the reference images")
          ->capture_default_str();
      cmd->add_option("--test-day", a->test_day, "Day (1-based) to localize")
          ->capture_default_str();
      auto* places = cmd->add_option("--places", a->places, "Adjacency-map YAML of the places");
      cmd->add_option("--place-length-m", a->place_length_m,
                      "Without --places: places every this many metres along the route")
          ->capture_default_str()
          ->excludes(places);
      cmd->add_option("--out", a->out, "Run directory to write");
      cmd->add_option("--bins", a->bins, "Histogram bins per band")->capture_default_str();
      cmd->add_option("--filter-width", a->filter_width, "Low-pass filter width, bins (odd)")
          ->capture_default_str();
      cmd->add_flag("--normalized-rgb", a->normalized_rgb,
                    "Bands 4-6 from r, g, b instead of R, G, B");
      cmd->add_option("--distance", a->distance, "jeffrey | chi_square | l1 | l2 | intersection")
          ->capture_default_str();
      cmd->add_option("--band-threshold", a->band_threshold,
                      "Smallest confidence with which a band votes (all bands)")
          ->capture_default_str();
      cmd->add_option("--action-threshold", a->action_threshold,
                      "Smallest overall confidence of a confident classification")
          ->capture_default_str();
      cmd->add_flag("--all-places", a->all_places,
                    "Compare with all places, not only the believed one and its neighbours");
      cmd->add_option("--global-search-after", a->global_search_after,
                      "After this many non-confident frames compare with all places (0: never)")
          ->capture_default_str();
      cmd->add_option("--reference-stride", a->reference_stride,
                      "Every k-th labelled training frame is a reference image")
          ->capture_default_str();
      cmd->add_flag("--global-start", a->global_start,
                    "Start the test day with no belief instead of the true first place");
      cmd->callback([a] { RunTopo(*a); });
    }};

}  // namespace
}  // namespace omnicml::app
