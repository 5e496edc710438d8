// The cross-sequence experiment of baseline [UN] (`omnicml topo`): topological
// localization by colour-histogram place recognition (baselines/topo/topological.h).
// Reference images come from one day (session) of a simulated world or a log; the other
// day is localized frame by frame. Days are 1-based.
//
// Places come from `places` (adjacency-map YAML) or are derived from the world's route
// every place_length_m metres (with a log the route is that of `world` or of
// LOG/world.yaml, which `omnicml simulate` writes). The run directory receives
//   frames.csv        one row per test frame: truth, true / believed / voted place,
//                     state, confidence, the vote, confidence and nearest reference
//                     image (ref_*, a row of references.csv) and its histogram
//                     distance (dist_*) of each band
//   references.csv    one row per reference image: its training frame, truth, place
//   summary.md        the [UN] Table 1 counts (TopologicalSummaryTable), and how many
//                     training and test frames lie in no place (when any does)
//   places.yaml       the adjacency map used
//   topo_config.yaml  the effective options
// each written atomically. Deterministic: same options, same files.
//
// Thread-safety: thread-compatible.
#ifndef OMNICML_EXPERIMENTS_TOPO_EXPERIMENT_H_
#define OMNICML_EXPERIMENTS_TOPO_EXPERIMENT_H_

#include <cstdint>
#include <string>

#include "omnicml/baselines/topo/topological.h"

namespace omnicml {

struct TopoExperimentOptions {
  std::string world;            // built-in world or world YAML
  std::string log;              // a multi-day log instead of simulating
  int days = 0;                 // simulated days; 0: max(train_day, test_day)
  int frames_per_day = 300;     // simulated frames per day
  std::uint64_t seed = 1;       // simulator seed
  double step_m = 0.2;          // simulated distance between frames, m
  int train_day = 1;            // day of the reference images, 1-based
  int test_day = 2;             // day localized, 1-based
  std::string places;           // adjacency-map YAML ("" = from the route)
  double place_length_m = 3.0;  // without places: one place every this many metres
  std::string out_dir;          // run directory (required)
  int bins = TopologicalHistogramDefaults().bins;  // histogram bins per band
  int filter_width = 5;                            // low-pass filter width, bins (odd)
  bool normalized_rgb = TopologicalHistogramDefaults().normalized_rgb;  // bands 4-6 r, g, b
  std::string distance = "jeffrey";  // jeffrey | chi_square | l1 | l2 | intersection
  double band_threshold = 0.05;      // smallest confidence with which a band votes
  double action_threshold = 0.1;     // smallest overall confidence of a confident class
  bool all_places = false;           // compare with all places, not only the neighbours
  int global_search_after = 0;       // non-confident frames before a global search (0: never)
  int reference_stride = 1;          // every k-th labelled training frame is a reference
  bool global_start = false;         // test day starts with no belief
  bool people = true;                // simulate walking people
  // The localizer's options the fields bins ... global_search_after are applied to: the
  // defaults, or a configuration file's (SetTopoLocalizerOptions). band_threshold
  // replaces all six per-band thresholds unless it equals the first one of this.
  TopologicalOptions localizer;
};

// Takes the localizer's options from `localizer` (a configuration file:
// LoadTopologicalOptions; the topo_config.yaml of an `omnicml topo` run directory loads
// back): sets options->localizer and the flag fields bins, filter_width,
// normalized_rgb, distance, band_threshold, action_threshold, all_places and
// global_search_after from it, so that the run uses exactly `localizer` unless a flag
// field is changed afterwards.
void SetTopoLocalizerOptions(const TopologicalOptions& localizer, TopoExperimentOptions* options);

struct TopoExperimentResult {
  CrossSequenceResult cross;  // per-frame decisions and the [UN] Table 1 counts
  int places = 0;             // places of the adjacency map
  std::string summary;        // summary.md (what `omnicml topo` prints)
};

// Runs the experiment and writes options.out_dir. Warns on stderr when train_day ==
// test_day (not a cross-sequence test). Throws omnicml::Error for bad options (naming
// the flag), unreadable input, places or I/O failure.
TopoExperimentResult RunTopoExperiment(const TopoExperimentOptions& options);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_TOPO_EXPERIMENT_H_
