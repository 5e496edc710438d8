// The CML run (`omnicml run`): the in-memory run API (run/cml_run.h) with the command's
// settings: outputs checked from flags, a dated run directory by default, survey
// mapping (survey.h) and, on simulated input, change detection as an end-of-session
// observer (change_detection.h); optionally resumed from a saved engine and saved again.
// Also the pieces shared with the other experiments over the same inputs
// (compare_experiment.h).
//
// A run is deterministic: the same input and options give the same run directory
// (except the timings of frames.csv and report.html), whatever `threads` is, and a run
// resumed from the map saved after day k with --first-day k gives the files of one
// uninterrupted run.
//
// Thread-safety: the functions are thread-compatible (one run per call; independent runs
// may go on in parallel threads when their outputs differ).
#ifndef OMNICML_EXPERIMENTS_RUN_EXPERIMENT_H_
#define OMNICML_EXPERIMENTS_RUN_EXPERIMENT_H_

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/change_detection.h"
#include "omnicml/experiments/survey.h"
#include "omnicml/run/engine_driver.h"
#include "omnicml/run/run_config.h"

namespace omnicml {

// What `omnicml run` and `omnicml compare` share: input, option overrides, output
// directory and progress settings (filled from command-line flags).
struct RunSettings {
  RunInput input;
  OptionOverrides overrides;
  // Engine options given as a value (the Python API) under the configuration file and
  // flags of `overrides`; std::nullopt = the defaults.
  std::optional<CmlEngineOptions> base_options;
  std::string out_dir;                  // run directory ("" = a dated default)
  bool quiet = false;                   // no progress output
  bool no_progress_bar = false;         // plain log lines even on a terminal
  std::int64_t log_every_frames = 500;  // frames between plain progress lines
  SurveyOptions survey;                 // --survey-days, --survey-poses (none by default)
};

// "runs/<command>-<YYYYmmdd-HHMMSS>" (UTC now): the run directory when --out is not given.
std::string DefaultRunDir(const std::string& command);

// Progress of a run with these settings: a bar on a terminal unless no_progress_bar,
// plain lines every log_every_frames otherwise, nothing when quiet.
ProgressOptions MakeProgressOptions(const RunSettings& settings, const std::string& label,
                                    std::optional<std::int64_t> total_frames);

// Without --threads and --config, threads = 2 (the engine's map-update worker) when the
// machine has a second core; results are identical with 1 or 2 threads.
OptionOverrides WithDefaultThreads(OptionOverrides overrides);

// Fails early (before a long run) when output file `path` cannot be written
// (CheckOutputFile: a directory, not a regular file, its directory missing or not
// writable); a file inside `run_dir`, which the run creates, needs run_dir to be
// creatable. `flag` names the option in the omnicml::Error. No-op for an empty path.
void CheckOutputParent(const std::string& path, const char* flag, const std::string& run_dir = "");

struct RunExperimentOptions {
  RunSettings settings;        // input, engine options, run directory, progress
  std::string map_in;          // resume from this saved engine ("" = a new engine)
  std::string map_out;         // save the engine here at the end ("" = no)
  std::string trajectory_out;  // TUM trajectory file ("" = no)
};

struct RunExperimentResult {
  std::string run_dir;  // where the run directory went (settings.out_dir or a default)
  RunSummary summary;   // frames, sessions, wall time
  // Of the recorded frames after the survey days (all frames without a survey; empty,
  // overall.frames = 0, when every frame was a survey frame), Alignment::kNone.
  EvaluationResult evaluation;
  std::int64_t survey_frames = 0;  // frames of the survey days (not in `evaluation`)
  std::size_t views = 0;           // map at the end (after Finish)
  std::size_t components = 0;
  int threads = 1;     // the engine's threads
  std::string timing;  // "<wall> s (<fps> frames/s)", as in the report
  // Simulated input: the map's change detection scored per day after the map's first
  // (change_detection.h; also change_detection.csv in the run directory).
  std::vector<ChangeDetectionDay> change_detection;
};

// Runs CML as described in the file comment and writes the run directory (and map_out,
// trajectory_out) atomically. With map_in the saved engine's options are used; only
// settings.overrides.threads and .forgetting may be set (CmlEngine::SetThreads,
// SetForgettingMode). The map saved is the state before Finish(), so a resumed run goes
// on exactly as one uninterrupted run. Progress and warnings go to stderr. Throws
// omnicml::Error (bad input, options, paths; an input without frames), naming the flag
// or file; nothing partial is left behind.
RunExperimentResult RunExperiment(const RunExperimentOptions& options);

// What `omnicml run` prints on stdout for `result`: the evaluation table, frames and
// timing, the map size, the run directory, report and output files.
std::string FormatRunExperimentResult(const RunExperimentOptions& options,
                                      const RunExperimentResult& result);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_RUN_EXPERIMENT_H_
