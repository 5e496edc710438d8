// The in-memory run API: CML over a run's input (logs or a simulated world) with engine
// options given as a value, the map carried from day to day, the results returned in
// memory (per-frame records, per-day statistics, the engine) and a run directory
// written only when asked. `omnicml run` (experiments/run_experiment.h) and the Python
// run() are built on it; neither goes through a file to hand over options or results.
//
// A run is deterministic: the same input and options give the same records (and run
// directory, except the timings of frames.csv and report.html), whatever `threads` is.
//
// Thread-safety: thread-compatible (one run per call; independent runs may go on in
// parallel threads when their outputs differ).
#ifndef OMNICML_RUN_CML_RUN_H_
#define OMNICML_RUN_CML_RUN_H_

#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/common/file_io.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/run/engine_driver.h"
#include "omnicml/run/frame_sources.h"
#include "omnicml/run/run_config.h"

namespace omnicml {

// What a run writes to disk; by default nothing. Paths are the command's flags: they
// name the outputs in errors and in outputs.yaml (--out, --map-out, --trajectory-out).
struct RunOutputs {
  std::filesystem::path run_dir;          // the run directory (run_recorder.h); "" = none
  std::filesystem::path map_path;         // the engine before Finish (SaveEngine format)
  std::filesystem::path trajectory_path;  // the estimate as a TUM file
  std::string title = "omnicml run";      // report title
  std::string input_description;          // config.yaml and the report; "" = input.Describe()
  // true: run_dir is checked, locked and staged beside its target here and committed
  // whole; false: its files go straight into run_dir, a directory inside one that the
  // caller stages and locks (the per-mode directories of experiments/compare_experiment.h).
  bool stage_run_dir = true;

  bool any() const { return !run_dir.empty() || !map_path.empty() || !trajectory_path.empty(); }
};

// Checks every output of `outputs` before any work (a run of hours must not fail at its
// end on an unwritable map path, nor leave a half run directory behind) and takes their
// locks, so a second writer of the same outputs refuses now. Keep the locks for the
// run. Throws omnicml::Error naming the flag and path. No-op without outputs.
std::vector<std::unique_ptr<OutputLock>> CheckRunOutputs(const RunOutputs& outputs);

struct CmlRunSettings {
  RunOutputs outputs;  // nothing written by default
  // Quiet by default; total_frames (the ETA) is filled from the input when unset.
  ProgressOptions progress = [] {
    ProgressOptions p;
    p.quiet = true;
    return p;
  }();
  // Frames of engine sessions < evaluate_from_session are left out of `evaluation`
  // (survey days, experiments/survey.h). >= 0.
  int evaluate_from_session = 0;
  // Also return the engine as it was before Finish (CmlRunResult::resumable_engine).
  bool keep_resumable_engine = false;
  // Also return every map event of the run (CmlRunResult::events).
  bool keep_events = false;
  FrameProcessor process;               // replaces ProcessFrame (engine_driver.h)
  SessionEndHook on_session_end;        // between sessions (engine_driver.h)
  std::vector<RunObserver*> observers;  // not owned; outlive the call
  // Extra (key, value) lines of the report's summary, after wall time and threads.
  std::vector<std::pair<std::string, std::string>> notes;
};

struct CmlRunResult {
  std::vector<FrameRecord> records;            // one per frame processed, in order
  std::map<int, std::int64_t> skipped_frames;  // unreadable input frames by engine session
  // Per-day and overall statistics of the records of sessions >= evaluate_from_session
  // (Alignment::kNone); overall.frames = 0 when there are none.
  EvaluationResult evaluation;
  RunSummary summary;                 // frames, sessions, wall time
  std::string timing;                 // "<wall> s (<fps> frames/s)", as in the report
  std::unique_ptr<CmlEngine> engine;  // after Finish
  // The engine before Finish (what the map file holds): a resumed run goes on from it as
  // one uninterrupted run would. Only with keep_resumable_engine.
  std::unique_ptr<CmlEngine> resumable_engine;
  // Every map event of the run, oldest first, as events.csv holds them (complete although
  // the model keeps only its most recent events). Only with keep_events.
  std::vector<MapEvent> events;
};

// The engine of a run over `input`: a new one with ResolveNewMapOptions(overrides, input,
// note, base) (run_config.h: the values the options ask to derive from the input, *note
// saying what was derived, "" otherwise), or with `map_in` the engine saved there with only
// overrides.threads and .forgetting applied (CmlEngine::SetThreads, SetForgettingMode; both
// parsed before either changes; *note ""). Throws omnicml::Error naming --map-in when other
// overrides are set or the file cannot be read, and what ResolveNewMapOptions throws.
std::unique_ptr<CmlEngine> MakeRunEngine(const OptionOverrides& overrides,
                                         const std::string& map_in, const RunInput& input,
                                         std::string* note, const CmlEngineOptions& base = {});

// Runs a new engine with `options` (validated; omnicml::Error naming the field) over
// every frame of `input`, then Finish, and writes what settings.outputs asks, committed
// as one unit (run_directory.h). Progress goes to stderr unless quiet. Throws
// omnicml::Error (bad input, options, outputs; an input without frames); nothing
// partial is left behind.
CmlRunResult RunCml(const CmlEngineOptions& options, const RunInput& input,
                    const CmlRunSettings& settings = {});
// The same, going on with `engine` (e.g. one loaded from a saved map).
CmlRunResult RunCml(std::unique_ptr<CmlEngine> engine, const RunInput& input,
                    const CmlRunSettings& settings = {});

}  // namespace omnicml

#endif  // OMNICML_RUN_CML_RUN_H_
