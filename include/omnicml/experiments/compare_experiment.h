// The [G] Table 1 experiment (`omnicml compare`): the same input run three times, under
// passive, active and static forgetting; the number of reference views at given steps
// with the mean and max position error, and a report with map-growth and error plots.
//
// "static" is the baseline of a map that does not adapt: it learns on the first day
// (active forgetting) and is frozen from the second day on (CmlEngine::SetForgettingMode
// at the end of day 1). A map static from the start would stay empty. With
// settings.survey (--survey-days N) the first N days build the map from trusted poses in
// every mode (survey.h), static freezes it after day N ([G]'s static "old" map versus
// the adapted one), and the errors cover days N + 1 on.
//
// OUTDIR layout (every file written atomically; a failure removes what the call created):
//   passive/, active/, static/   each mode's full run directory (run/run_recorder.h; with
//                                trajectory.tum, groundtruth.tum, odometry.tum)
//   table.txt                    the table as printed
//   report.html                  the table, per-day errors and views, growth and error
//                                plots (with day boundaries and the odometry-only error),
//                                the error histogram of all modes, each mode's final map
// With map_out_dir, MAPDIR/<mode>.omap holds each mode's final engine/map.
//
// The three modes are independent runs (each with its own frame source and engine, each
// deterministic whatever the timing), so they run in `jobs` parallel threads; the results
// and files are identical to a sequential run (jobs = 1), except measured timings.
//
// Thread-safety: thread-compatible (one experiment per call).
#ifndef OMNICML_EXPERIMENTS_COMPARE_EXPERIMENT_H_
#define OMNICML_EXPERIMENTS_COMPARE_EXPERIMENT_H_

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/run_experiment.h"

namespace omnicml {

// Parses "2000,4000,..." (positive integers). Throws omnicml::Error naming --steps and
// the bad item.
std::vector<std::int64_t> ParseSteps(const std::string& text);

struct CompareExperimentOptions {
  // Input, engine options (overrides.forgetting is ignored: the modes set it), OUTDIR
  // ("" = runs/compare-<date>-<time>), progress.
  RunSettings settings;
  // Frames (1-based) at which the table reports the number of views; >= 1 each.
  std::vector<std::int64_t> steps = {2000, 4000, 6000, 8000};
  // Modes run in parallel: 0 = one per core; clamped to [1, 3].
  int jobs = 0;
  // "" = no maps; otherwise a directory (created when missing) receiving each mode's
  // engine/map at the end as <mode>.omap (loadable with run --map-in, export, inspect),
  // written only once every mode has succeeded.
  std::string map_out_dir;
};

// One mode's run.
struct CompareModeResult {
  std::string mode;                  // "passive", "active", "static"
  std::vector<FrameRecord> records;  // every frame, in order
  // Alignment::kNone; of the frames after the survey days (settings.survey), all
  // frames without a survey.
  EvaluationResult evaluation;
  std::int64_t survey_frames = 0;  // frames of the survey days (not in `evaluation`)
  double wall_s = 0;
  int final_views = 0;  // after Finish
  int final_components = 0;
  // SVG picture of the mode's final map over its estimated trajectory (map_export.h),
  // with the places where views were removed marked; for the report.
  std::string map_svg;
  // Views removed during each session (engine session index, from events.csv): by
  // active forgetting (its last component went by (18)-(19)) and otherwise (passive
  // forgetting, weight below w_min, merges). Sessions without removals are absent.
  std::map<int, std::pair<int, int>> views_removed_by_session;
};

struct CompareExperimentResult {
  std::string out_dir;
  std::string input;                     // RunInput::Describe()
  std::vector<CompareModeResult> modes;  // passive, active, static
  std::string table_text;                // table.txt
  std::string survey_note;               // SurveyExcludedNote ("" without a survey)
};

// Runs the experiment of the file comment and writes OUTDIR. Throws omnicml::Error for
// bad input or options (naming the flag), an input without frames, or I/O failure; the
// first error in mode order is rethrown after every thread has finished.
CompareExperimentResult RunCompareExperiment(const CompareExperimentOptions& options);

// The table (header "forgetting", "views@<step>"..., views_end, mean_err_m, max_err_m,
// head_mean_deg, unimodal%, odom_err_m, coverage%, min_day_coverage%; one row per mode)
// as plain text. The errors are over the localized frames (evaluation.h); coverage% is
// localized / frames over the run, min_day_coverage% the lowest day's.
std::string FormatCompareTable(const std::vector<CompareModeResult>& modes,
                               const std::vector<std::int64_t>& steps);

// What `omnicml compare` prints on stdout: the input, the table, per-mode frames (and
// skipped unreadable frames), wall time, per-day mean errors and coverage, the report
// path.
std::string FormatCompareExperimentResult(const CompareExperimentResult& result);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_COMPARE_EXPERIMENT_H_
