// The engine driver of a run: the loop that feeds every frame of a FrameSource to a
// CmlEngine (BeginSession at each new session, ProcessFrame), hands each result to the
// run recorder, prints progress, and tells observers when a session ends.
//
// Thread-compatible: one thread drives the engine, the source and the recorder.
#ifndef OMNICML_RUN_ENGINE_DRIVER_H_
#define OMNICML_RUN_ENGINE_DRIVER_H_

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/run/run_recorder.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {

// Progress output of RunEngineOverSource.
struct ProgressOptions {
  // Progress bar on stderr, redrawn in place (frames/s, views, ETA); when false, a plain
  // log line every log_every_frames frames and at the end of each session.
  bool progress_bar = false;
  std::int64_t log_every_frames = 500;
  std::string label;                         // prefix of every line, e.g. "active"
  std::optional<std::int64_t> total_frames;  // for the ETA
  bool quiet = false;                        // no output at all
};
// True when stderr is a terminal (isatty).
bool StderrIsTerminal();

struct RunSummary {
  std::int64_t frames = 0;            // frames delivered and processed
  std::int64_t frames_localized = 0;  // of those, frames with an estimate
  std::int64_t frames_skipped = 0;    // input frames skipped as unreadable (LogReader)
  int sessions = 0;
  double wall_s = 0.0;
};

// Watches a run session by session (e.g. change detection scoring the map's health
// against a simulated world's day events). The driver calls OnSessionEnd after the
// last frame of every session, the run's last included, before any SessionEndHook and
// before Finish; the run (RunCml) calls OnCommit after Finish, before the run directory
// is committed. Called from the driving thread; an exception aborts the run.
class RunObserver {
 public:
  virtual ~RunObserver() = default;
  // Session `source_session` (index in the source) has ended; `engine` is between
  // frames. `records` are the frames recorded so far (empty without a recorder).
  virtual void OnSessionEnd(const CmlEngine& engine, int source_session,
                            const std::vector<FrameRecord>& records) = 0;
  // Adds the observer's files to the run directory (RunRecorder::AddFile) and lines to
  // the report's summary (`notes`, appended in order). Default: nothing.
  virtual void OnCommit(RunRecorder& recorder,
                        std::vector<std::pair<std::string, std::string>>* notes) {
    (void)recorder;
    (void)notes;
  }
};

// Drives `engine` over every frame of `source`: BeginSession at each new session,
// ProcessFrame, recorder->Record (when not null), progress. When `source` is a
// LogReader, its per-session counts of skipped unreadable frames go to the summary and
// recorder->RecordSkippedFrames (a session of which every frame was skipped counts in
// the summary only: it has no engine session). Progress lines show the localized
// fraction next to every mean error. Does not call Finish.
// `observers` (optional, not owned) get OnSessionEnd after the last frame of every
// session. `on_session_end(engine, session_index)` (optional) runs after the observers
// at the end of each session but the last, before the next BeginSession, e.g. to change
// the engine's mode (CmlEngine::SetForgettingMode; the engine is between frames there).
// `process` (optional) replaces engine.ProcessFrame(frame) for every frame, e.g. survey
// mapping from trusted poses (experiments/survey.h); empty = ProcessFrame. Throws what
// the engine, the source, the recorder, an observer or the hook throw.
using SessionEndHook = std::function<void(CmlEngine& engine, int session_index)>;
using FrameProcessor = std::function<FrameResult(CmlEngine& engine, const Frame& frame)>;
RunSummary RunEngineOverSource(CmlEngine& engine, FrameSource& source, RunRecorder* recorder,
                               const ProgressOptions& progress,
                               const SessionEndHook& on_session_end = {},
                               const FrameProcessor& process = {},
                               const std::vector<RunObserver*>& observers = {});

}  // namespace omnicml

#endif  // OMNICML_RUN_ENGINE_DRIVER_H_
