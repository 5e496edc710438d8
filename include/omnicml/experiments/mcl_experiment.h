// The experiments of baseline [W] (`omnicml mcl`): Monte Carlo localization with image
// retrieval gated by visibility areas (baselines/mcl/mcl.h) over a simulated world or a
// log (panorama or raw ring sessions). References are every ref_every-th frame of
// train_day (with ground truth); the queries are every frame of test_day (days 1-based).
//
//   single run (experiment ""): one filter over the test day; the summary text and,
//       with out_dir, the run directory of WriteMclRunDirectory.
//   "tracking": known start, `runs` filters (seeds MixSeed(seed, run)); max/mean errors.
//   "global":   uniform start at frame 0 (run 0) or a random frame of the first half;
//               steps until converged (error < converge_error_m and < success_heading_deg
//               for 3 steps).
//   "kidnap":   known start, carried after a random step in [20, n/3) to a frame at least
//               n/4 ahead (and 40 before the end), no odometry; steps to recover.
//   "noise":    extra odometry noise level x the world's a1..a4 (the filter's model
//               unchanged), success = final error < success_error_m and heading.
// Every experiment is deterministic: same options, same numbers (timings aside).
//
// Thread-safety: thread-compatible.
#ifndef OMNICML_EXPERIMENTS_MCL_EXPERIMENT_H_
#define OMNICML_EXPERIMENTS_MCL_EXPERIMENT_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "omnicml/baselines/mcl/mcl.h"
#include "omnicml/baselines/mcl/occupancy_grid.h"
#include "omnicml/descriptors/descriptor.h"
#include "omnicml/evaluation/evaluation.h"

namespace omnicml {

struct MclExperimentOptions {
  std::vector<std::string> log_dirs;  // logs with ground truth, panorama or raw ring
  std::string map_yaml;               // occupancy grid (map_server); required with log_dirs
  std::string world = "home_store";   // built-in world or world YAML
  int days = 2;                       // simulated days, >= max(train_day, test_day)
  int frames_per_day = 300;
  std::uint64_t seed = 1;    // simulator seed
  int train_day = 1;         // 1-based
  int test_day = 2;          // 1-based
  int ref_every = 2;         // every k-th training frame is a reference
  int panorama_width = 180;  // simulated panorama size, px (>= 16 x 8)
  int panorama_height = 36;
  bool people = true;              // simulate walking people
  std::string descriptor = "ifh";  // ifh | fourier | color
  // ifh only: IfhOptions::normalize_columns (divide each panorama column by its mean
  // brightness before the kernels; for lights that switch between the days).
  bool ifh_normalize_columns = false;
  double grid_resolution_m = 0.1;  // grid rasterised from the world
  int particles = 5000;
  int random_samples = MclOptions{}.random_samples_per_step;  // injected per step ([W])
  double heading_gate_deg = 0.0;   // half width of d(psi); 0: heading independent (omni)
  int top_k = MclOptions{}.top_k;  // retrieved references per query (0 = all)
  double prior_fraction = 0.2;     // [W] eq. (8)
  double min_likelihood = MclOptions{}.min_likelihood;
  // visibility areas cut-off (0 = off)
  double max_distance_from_reference_m = MclOptions{}.visibility.max_distance_from_reference_m;
  bool global = false;         // single run: uniform start
  std::uint64_t mcl_seed = 1;  // filter seed
  std::string out_dir;         // single run: run directory ("" = none)
  std::string experiment;      // "" (single run) | tracking | global | kidnap | noise
  int runs = 20;               // runs per experiment (per noise level), >= 1
  std::string noise_levels = "0,1,4,16,64";
  double success_error_m = 2.0;
  double success_heading_deg = 35.0;
  double converge_error_m = 1.0;
  // The filter's options the fields particles ... mcl_seed above are applied to (the
  // fields without a flag: motion, clustering, visibility ray limits, ...): the defaults,
  // or a configuration file's (SetMclFilterOptions).
  MclOptions filter;
};

// Takes the filter's options from `filter` (a configuration file: LoadMclOptions; the
// config.yaml of an `omnicml mcl` run directory loads back): sets options->filter and the
// flag fields particles, random_samples, heading_gate_deg, top_k, prior_fraction,
// min_likelihood, max_distance_from_reference_m and mcl_seed from it, so that the run
// uses exactly `filter` unless a flag field is changed afterwards.
void SetMclFilterOptions(const MclOptions& filter, MclExperimentOptions* options);

// Everything the runs share, prepared once: rendered or read frames, descriptors, the
// grid, references with their visibility areas.
struct MclPrepared {
  OccupancyGrid grid;
  std::vector<MclReference> refs;  // visibility areas computed
  std::vector<MclFrame> test;
  std::shared_ptr<const DescriptorExtractor> extractor;
  MclOptions options;
  MotionNoise world_noise{.a1 = 0.01, .a2 = 0.002, .a3 = 0.005, .a4 = 0.001};
  std::string input;  // one line naming the input
  double prepare_s = 0;
  // The visibility areas' cut-off distance used (VisibilityRadius), metres; 0: none.
  double visibility_radius_m = 0;
  double reference_spacing_m = 0;  // MedianReferenceSpacing of refs, metres
  // Frames whose ground-truth position lies inside the grid but not in a free cell
  // (an obstacle grown by the rasterisation, or unknown space): references, test frames.
  int refs_not_free = 0;
  int test_not_free = 0;
};

// Validates the options (runs, particles, days and frames within common/limits.h,
// experiment name, out_dir creatable) and
// prepares the frames. Throws omnicml::Error naming the flag or file, and naming the map
// and the frame when a reference or test frame's ground truth lies outside the occupancy
// grid (a map that is not the log's).
MclPrepared PrepareMclExperiment(const MclExperimentOptions& options);
// Two lines for stderr: empty and mean visibility areas; references, queries, grid and
// preparation time; a third when some true positions lie outside the grid's free cells.
std::string DescribeMclPrepared(const MclPrepared& prepared);

// Single run.
struct MclSingleResult {
  std::vector<MclStepRecord> steps;  // one per test frame
  std::vector<FrameRecord> records;  // the same in the evaluation.h schema
  std::string summary_text;          // as printed, and summary.txt of the run directory
};
// Runs one filter; with options.out_dir also writes the run directory (below).
MclSingleResult RunMclSingle(const MclExperimentOptions& options, const MclPrepared& prepared);

// The run directory of a single run, like `omnicml run`'s (run/run_recorder.h):
//   frames.csv   evaluation.h schema (readable by `omnicml evaluate RUNDIR`):
//                  estimate = the MCL estimate (weighted mean of the best cluster),
//                  mean_estimate = the weighted sample mean of all particles,
//                  unimodal = the best cluster holds >= 50 % of the weight,
//                  odometry_error = dead reckoning anchored at the session's first
//                  ground-truth pose, views = map_components = references,
//                  hypotheses = references retrieved per query, mixture_components =
//                  particles; stages "correct" and "total" = one filter step
//                  (descriptors are computed beforehand, excluded)
//   days.csv     per-day statistics (evaluation.h WriteDaysCsv; coverage is 1: the
//                filter has an estimate at every step)
//   trajectory.tum, groundtruth.tum, odometry.tum
//                evo-ready TUM files on the same run-unique stamps (run/run_recorder.h)
//   config.yaml  the effective MclOptions and inputs
//   report.html  summary, per-day table, error over frames, error histogram, configuration
//   summary.txt  the text printed on stdout
//   map.yaml + map.pgm  the occupancy grid used (map_server format)
// The directory commits as one unit: it is assembled in "<out_dir>.partial-<pid>" and
// renamed onto out_dir at the end (common/file_io.h StagedDirectory), so after a failure
// or a kill out_dir is the earlier run directory or absent, never half-written. An
// existing out_dir must be empty or an earlier run directory (frames.csv, summary.txt,
// ...). RunMclSingle holds out_dir's OutputLock from before the filter runs.
void WriteMclRunDirectory(const MclExperimentOptions& options, const MclPrepared& prepared,
                          const MclSingleResult& result);

// Experiments: one row per run (per level for noise) and the text as printed.
struct MclTrackingRun {
  double max_position_error_m = 0;
  double max_heading_error_deg = 0;
  double mean_position_error_m = 0;
  double ms_per_step = 0;
};
struct MclGlobalRun {
  int start_frame = 0;
  int steps_to_converge = -1;  // -1: never
};
struct MclKidnapRun {
  int kidnap_step = 0;
  int to_frame = 0;
  double jump_m = -1;         // -1 without ground truth
  int steps_to_recover = -1;  // -1: never
};
struct MclNoiseLevel {
  double level = 0;
  int successes = 0;
  int runs = 0;
  double mean_final_error_m = 0;
  double mean_max_error_m = 0;
};
struct MclExperimentResult {
  std::string experiment;  // tracking | global | kidnap | noise
  std::vector<MclTrackingRun> tracking;
  std::vector<MclGlobalRun> global;
  std::vector<MclKidnapRun> kidnap;
  std::vector<MclNoiseLevel> noise;
  std::string text;  // header, one line per row, summary (what `omnicml mcl` prints)
};
// Runs options.experiment (tracking | global | kidnap | noise). Throws omnicml::Error for
// another name or bad --noise-levels.
MclExperimentResult RunMclExperiment(const MclExperimentOptions& options,
                                     const MclPrepared& prepared);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_MCL_EXPERIMENT_H_
