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
// The study runs in memory (RunCompare: engine options as a value, each mode's results
// returned: per-frame records, per-day evaluation, views at the table's steps, the
// engines when asked) on the in-memory run API (run/cml_run.h); it writes OUTDIR and
// the maps only when CompareOutputs asks. `omnicml compare` (RunCompareExperiment: the
// command's flags, OUTDIR always) and the Python compare() are built on it.
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
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/experiments/survey.h"
#include "omnicml/run/engine_driver.h"
#include "omnicml/run/frame_sources.h"

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

// What RunCompare writes; by default nothing.
struct CompareOutputs {
  // OUTDIR (the layout above), staged and renamed into place whole; "" = none.
  std::filesystem::path out_dir;
  // MAPDIR (created when missing) receiving each mode's engine/map after Finish as
  // <mode>.omap, written only once every mode has succeeded; "" = none.
  std::filesystem::path map_out_dir;

  bool any() const { return !out_dir.empty() || !map_out_dir.empty(); }
};

struct CompareSettings {
  // Frames (1-based) at which the table reports the number of views; >= 1 each.
  std::vector<std::int64_t> steps = {2000, 4000, 6000, 8000};
  // Modes run in parallel: 0 = one per core; clamped to [1, 3].
  int jobs = 0;
  // Survey days (--survey-days, --survey-poses): the first days build the map from
  // trusted poses in every mode and are left out of the errors (survey.h).
  SurveyOptions survey;
  // Progress of every mode (label: the mode; no bar with jobs > 1). Quiet by default;
  // log_every_frames >= 1.
  ProgressOptions progress = [] {
    ProgressOptions p;
    p.quiet = true;
    return p;
  }();
  // Also return each mode's engine after Finish (CompareModeResult::engine).
  bool keep_engines = false;
  CompareOutputs outputs;  // nothing written by default
  // Appended to the input line of each mode's report and config.yaml (what a new map's
  // automatic calibration identified, run_config.h ResolveNewMapOptions); "" = nothing.
  std::string input_note;
};

// One mode's run.
struct CompareModeResult {
  std::string mode;                  // "passive", "active", "static"
  std::vector<FrameRecord> records;  // every frame, in order
  // Views in the map right after each of the settings' steps (records[step - 1].views),
  // -1 for a step beyond the run: the map-size columns of the table.
  std::vector<int> views_at_steps;
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
  // The mode's engine after Finish (what <mode>.omap holds); only with keep_engines.
  std::unique_ptr<CmlEngine> engine;
};

struct CompareExperimentResult {
  std::string out_dir;                   // OUTDIR; "" when none was written
  std::string input;                     // RunInput::Describe()
  std::vector<CompareModeResult> modes;  // passive, active, static
  std::string table_text;                // table.txt
  std::string survey_note;               // SurveyExcludedNote ("" without a survey)
};

// The engine options mode `mode` runs with: `options` with model.forgetting.mode = mode,
// except static, which learns actively until the study freezes it (the file comment).
CmlEngineOptions CompareModeOptions(const CmlEngineOptions& options, ForgettingMode mode);

// Runs the study of the file comment over `input` (passive, active, static; each a
// RunCml with CompareModeOptions(options, mode)) and writes what settings.outputs asks,
// nothing otherwise. The results equal what the written run directories hold (records:
// frames.csv; evaluation: the errors of days.csv and table.txt). Throws omnicml::Error
// for bad input, options or settings (naming the flag or field), an input without
// frames (or none after the survey days), or I/O failure; the first error in mode order
// is rethrown after every thread has finished, and nothing partial is left behind.
CompareExperimentResult RunCompare(const CmlEngineOptions& options, const RunInput& input,
                                   const CompareSettings& settings = {});

// `omnicml compare`: RunCompare with the engine options resolved from the settings'
// overrides (forgetting ignored) and OUTDIR always written (settings.out_dir, or
// runs/compare-<date>-<time>). Throws what RunCompare throws.
CompareExperimentResult RunCompareExperiment(const CompareExperimentOptions& options);

// The table (header "forgetting", "views@<step>"..., views_end, mean_err_m, max_err_m,
// head_mean_deg, unimodal%, odom_err_m, coverage%, min_day_coverage%; one row per mode)
// as plain text. The errors are over the localized frames (evaluation.h); coverage% is
// localized / frames over the run, min_day_coverage% the lowest day's.
std::string FormatCompareTable(const std::vector<CompareModeResult>& modes,
                               const std::vector<std::int64_t>& steps);

// What `omnicml compare` prints on stdout: the input, the table, per-mode frames (and
// skipped unreadable frames), wall time, per-day mean errors and coverage, the report
// path (when OUTDIR was written).
std::string FormatCompareExperimentResult(const CompareExperimentResult& result);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_COMPARE_EXPERIMENT_H_
