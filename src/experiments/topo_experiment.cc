#include "omnicml/experiments/topo_experiment.h"

#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/report/report.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

std::string ConfigYaml(const TopoExperimentOptions& a, const TopologicalOptions& o,
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
     << TopologicalOptionsToYaml(o);
  return os.str();
}

}  // namespace

void SetTopoLocalizerOptions(const TopologicalOptions& localizer, TopoExperimentOptions* a) {
  a->localizer = localizer;
  a->bins = localizer.histogram.bins;
  a->filter_width = localizer.histogram.filter_width;
  a->normalized_rgb = localizer.histogram.normalized_rgb;
  a->distance = ToString(localizer.histogram.distance);
  a->band_threshold = localizer.band_threshold[0];
  a->action_threshold = localizer.action_threshold;
  a->all_places = !localizer.restrict_to_neighbours;
  a->global_search_after = localizer.global_search_after_frames;
}

TopoExperimentResult RunTopoExperiment(const TopoExperimentOptions& experiment) {
  TopoExperimentOptions a = experiment;
  if (a.out_dir.empty()) throw Error("topo: --out RUNDIR is required");
  if (a.world.empty() && a.log.empty()) throw Error("topo: give --world NAME or --log LOGDIR");
  if (a.train_day < 1 || a.test_day < 1)
    throw Error("topo: --train-day and --test-day are 1-based");
  if (a.train_day == a.test_day) {
    std::cerr << "warning: training and test day are the same (not a cross-sequence test)\n";
  }
  if (a.log.empty()) {
    CheckLimit("topo: --days", a.days, 0, kMaxDays);
    CheckLimit("topo: --frames-per-day", a.frames_per_day, 1, kMaxFramesPerDay);
    const std::int64_t days = a.days > 0 ? a.days : std::max(a.train_day, a.test_day);
    if (days * a.frames_per_day > kMaxSimulatedFrames) {
      throw Error(StrCat("topo: days x --frames-per-day exceeds the limit of ", kMaxSimulatedFrames,
                         " frames"));
    }
  }
  CheckOutputDirectory(a.out_dir, "--out");
  // Locked and checked now; written to a staging directory renamed into place at the end
  // (common/file_io.h StagedDirectory), so a failure leaves the old directory or none.
  const std::vector<std::string> markers = {"summary.md", "topo_config.yaml", "frames.csv"};
  StagedDirectory staged(a.out_dir, "--out", markers);
  TopologicalOptions options = a.localizer;
  options.histogram.bins = a.bins;
  options.histogram.filter_width = a.filter_width;
  options.histogram.normalized_rgb = a.normalized_rgb;
  options.histogram.distance = HistogramDistanceFromString(a.distance);
  // One value for every band, unless it is the first band's of `localizer` (which keeps
  // per-band thresholds of a configuration file).
  if (a.band_threshold != options.band_threshold[0]) options.band_threshold.fill(a.band_threshold);
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
  CrossSequenceResult r = RunCrossSequence(source.get(), &localizer, cross, route.get());

  const fs::path out = staged.path();
  const auto write = [](const fs::path& path, const std::string& text) {
    WriteFileAtomic(path, text, FileSync::kDeferred);  // durable at staged.Commit()
  };
  write(out / "places.yaml", AdjacencyMapYaml(map));
  write(out / "topo_config.yaml", ConfigYaml(a, options, cross, places_from));
  auto name = [&](int p) { return p < 0 ? std::string() : map.places()[p].name; };
  // The columns stamp_s,index,gt_x_m,gt_y_m,gt_phi_rad,<place> of a labelled frame.
  auto labelled_cells = [&](std::ostream& csv, const TopologicalFrameResult& f) {
    csv << FormatRoundTrip(f.stamp_s) << "," << f.index_in_session << ","
        << FormatRoundTrip(f.map_T_robot_truth.x()) << ","
        << FormatRoundTrip(f.map_T_robot_truth.y()) << ","
        << FormatRoundTrip(f.map_T_robot_truth.z()) << "," << name(f.true_place);
  };
  {
    const char* bands_rgb[] = {"H", "L", "S", "R", "G", "B"};
    const char* bands_nrgb[] = {"H", "L", "S", "r", "g", "b"};
    const char** bands = a.normalized_rgb ? bands_nrgb : bands_rgb;
    std::ostringstream csv;
    csv << "stamp_s,index,gt_x_m,gt_y_m,gt_phi_rad,true_place,believed_place,state,voted_place,"
           "confidence,voting_bands";
    for (int b = 0; b < ColorHistogram::kBands; ++b) csv << ",vote_" << bands[b];
    for (int b = 0; b < ColorHistogram::kBands; ++b) csv << ",conf_" << bands[b];
    for (int b = 0; b < ColorHistogram::kBands; ++b) csv << ",ref_" << bands[b];
    for (int b = 0; b < ColorHistogram::kBands; ++b) csv << ",dist_" << bands[b];
    csv << "\n";
    for (const auto& f : r.frames) {
      labelled_cells(csv, f);
      csv << "," << name(f.believed_place) << "," << ToString(f.decision.state) << ","
          << name(f.decision.place) << "," << FormatRoundTrip(f.decision.confidence) << ","
          << f.decision.voting_bands;
      for (const auto& v : f.decision.bands) csv << "," << name(v.place);
      for (const auto& v : f.decision.bands) csv << "," << FormatRoundTrip(v.confidence);
      for (const auto& v : f.decision.bands) csv << "," << v.reference;
      for (const auto& v : f.decision.bands) csv << "," << FormatRoundTrip(v.distance_nn);
      csv << "\n";
    }
    write(out / "frames.csv", csv.str());
  }
  {
    // The reference images (the ref_* columns of frames.csv index this table).
    std::ostringstream csv;
    csv << "reference,stamp_s,index,gt_x_m,gt_y_m,gt_phi_rad,place\n";
    for (std::size_t i = 0; i < r.reference_frames.size(); ++i) {
      csv << i << ",";
      labelled_cells(csv, r.reference_frames[i]);
      csv << "\n";
    }
    write(out / "references.csv", csv.str());
  }
  const std::string input = a.log.empty() ? a.world : a.log;
  const std::string title =
      StrCat(input, ": train day ", a.train_day, ", test day ", a.test_day, " (", map.size(),
             " places, ", r.references, " reference images)");
  std::string table = TopologicalSummaryTable(r.counts, title);
  if (r.train_frames_without_place > 0 || r.test_frames_without_place() > 0) {
    // Frames outside every place have no label: no reference, and not in the counts.
    table += StrCat("frames in no place (not counted): ", r.train_frames_without_place, " of ",
                    r.train_frames, " training, ", r.test_frames_without_place(), " of ",
                    r.frames.size(), " test\n");
    if (2 * r.train_frames_without_place > r.train_frames) {
      std::cerr << "warning: " << r.train_frames_without_place << " of " << r.train_frames
                << " training frames lie in no place of " << places_from
                << "; are the places those of this world or log?\n";
    }
  }
  if (options.learn_band_thresholds) {
    // The thresholds Localize used: max(band_threshold, learned on the training day).
    std::ostringstream os;
    os << "band thresholds learned on the training day (" << r.calibration.queries
       << " reference queries; band: threshold, correct/votes):";
    const char* names[] = {"H", "L", "S", "R", "G", "B"};
    for (int b = 0; b < ColorHistogram::kBands; ++b) {
      os << (b ? "," : "") << " " << names[b] << " "
         << FormatRoundTrip(localizer.effective_options().band_threshold[b]) << " "
         << r.calibration.correct[b] << "/" << r.calibration.votes[b];
    }
    table += os.str() + "\n";
  }
  write(out / "summary.md", table);
  staged.Commit();
  TopoExperimentResult result;
  result.cross = std::move(r);
  result.places = static_cast<int>(map.size());
  result.summary = table;
  return result;
}

}  // namespace omnicml
