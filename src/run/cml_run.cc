#include "omnicml/run/cml_run.h"

#include <algorithm>
#include <cstdio>
#include <optional>
#include <system_error>
#include <utility>

#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/run/run_directory.h"
#include "omnicml/run/run_recorder.h"
#include "omnicml/run/run_report.h"

namespace omnicml {

std::vector<std::unique_ptr<OutputLock>> CheckRunOutputs(const RunOutputs& o) {
  std::vector<std::unique_ptr<OutputLock>> locks;
  if (!o.any()) return locks;
  // An unstaged run directory lies in one the caller stages, checks and locks.
  const std::filesystem::path run_dir = o.stage_run_dir ? o.run_dir : std::filesystem::path();
  if (!run_dir.empty()) CheckOutputDirectory(run_dir, "--out");
  CheckOutputFile(o.map_path, "--map-out", o.run_dir);
  CheckOutputFile(o.trajectory_path, "--trajectory-out", o.run_dir);
  if (!run_dir.empty()) CheckReplaceableDirectory(run_dir, "--out", RunDirectoryMarkers());
  CheckRunOutputPlacement("--map-out", o.map_path, o.run_dir);
  CheckRunOutputPlacement("--trajectory-out", o.trajectory_path, o.run_dir);
  if (!run_dir.empty()) locks.push_back(std::make_unique<OutputLock>(run_dir, "--out"));
  for (const auto& [flag, path] :
       {std::pair{"--map-out", o.map_path}, std::pair{"--trajectory-out", o.trajectory_path}}) {
    // A file in the run directory is covered by the run directory's lock.
    if (!path.empty() && !LiesInRunDirectory(path, o.run_dir)) {
      locks.push_back(std::make_unique<OutputLock>(path, flag));
    }
  }
  // A commit of this run directory that a killed writer left half done is settled before
  // anything is read: it may have replaced the file --map-in names.
  if (!run_dir.empty()) RecoverInterruptedCommits(run_dir);
  return locks;
}

std::unique_ptr<CmlEngine> MakeRunEngine(const OptionOverrides& overrides,
                                         const std::string& map_in, const RunInput& input,
                                         std::string* note, const CmlEngineOptions& base) {
  if (map_in.empty()) {
    return std::make_unique<CmlEngine>(ResolveNewMapOptions(overrides, input, note, base));
  }
  if (note != nullptr) note->clear();
  if (!overrides.OnlyThreadsAndForgetting()) {
    throw Error(StrCat("--map-in '", map_in,
                       "': the saved engine's options are used; only --threads and "
                       "--forgetting may change (drop --config, --e-max, --update-delay, "
                       "--descriptor)"));
  }
  std::error_code ec;
  if (!std::filesystem::is_regular_file(map_in, ec)) {
    throw Error(StrCat("--map-in '", map_in, "' ",
                       ec ? ec.message() : "does not exist or is not a regular file"));
  }
  std::unique_ptr<CmlEngine> engine = LoadEngine(map_in);
  // Parse both before changing anything, so a bad value leaves no half-changed engine.
  std::optional<ForgettingMode> forgetting;
  if (overrides.forgetting) forgetting = ForgettingModeFromString(*overrides.forgetting);
  if (overrides.threads) engine->SetThreads(*overrides.threads);
  if (forgetting) engine->SetForgettingMode(*forgetting);
  return engine;
}

CmlRunResult RunCml(const CmlEngineOptions& options, const RunInput& input,
                    const CmlRunSettings& settings) {
  options.Validate();
  return RunCml(std::make_unique<CmlEngine>(options), input, settings);
}

CmlRunResult RunCml(std::unique_ptr<CmlEngine> engine, const RunInput& input,
                    const CmlRunSettings& settings) {
  OMNICML_CHECK(engine != nullptr) << "RunCml: no engine";
  OMNICML_CHECK(settings.evaluate_from_session >= 0)
      << "RunCml: evaluate_from_session " << settings.evaluate_from_session;
  const RunOutputs& out = settings.outputs;
  const std::vector<std::unique_ptr<OutputLock>> locks = CheckRunOutputs(out);
  std::unique_ptr<FrameSource> source = OpenFrameSource(input);
  RunRecorderOptions ro;
  ro.run_dir = out.run_dir;
  ro.trajectory_path = out.trajectory_path;
  ro.stage = out.stage_run_dir;
  ro.keep_events = settings.keep_events;
  ro.title = out.title;
  ro.input_description = out.input_description.empty() ? input.Describe() : out.input_description;
  RunRecorder recorder(ro);
  ProgressOptions progress = settings.progress;
  if (!progress.total_frames) progress.total_frames = CountFrames(input, *source);

  CmlRunResult result;
  result.summary =
      RunEngineOverSource(*engine, *source, &recorder, progress, settings.on_session_end,
                          settings.process, settings.observers);
  if (result.summary.frames == 0) {
    throw Error(StrCat("the input (", input.Describe(), ") has no frames"));
  }
  // The saved engine is the state before Finish(), so a resumed run continues exactly as
  // one uninterrupted run would (queued updates and pending frames included).
  std::vector<std::uint8_t> resumable;
  if (!out.map_path.empty() || settings.keep_resumable_engine) resumable = EncodeEngine(*engine);
  engine->Finish();
  const double fps =
      static_cast<double>(result.summary.frames) / std::max(result.summary.wall_s, 1e-9);
  char timing[96];
  std::snprintf(timing, sizeof timing, "%.1f s (%.1f frames/s)", result.summary.wall_s, fps);
  result.timing = timing;
  std::vector<std::pair<std::string, std::string>> notes = {
      {"wall time", result.timing}, {"threads", std::to_string(engine->options().threads)}};
  notes.insert(notes.end(), settings.notes.begin(), settings.notes.end());
  for (RunObserver* o : settings.observers) o->OnCommit(recorder, &notes);
  if (settings.keep_resumable_engine) {
    result.resumable_engine = DecodeEngine(resumable, "the engine before Finish");
  }
  // The map commits with the run directory (run_directory.h).
  if (!out.map_path.empty()) recorder.AddOutput("--map-out", out.map_path, std::move(resumable));
  recorder.Commit(*engine, notes);

  FramesTable table;
  table.stage_names = StageNames();
  for (const FrameRecord& r : recorder.records()) {
    if (r.session >= settings.evaluate_from_session) table.records.push_back(r);
  }
  table.skipped_frames = recorder.skipped_frames();
  if (!table.records.empty()) result.evaluation = Evaluate(table, Alignment::kNone);
  result.skipped_frames = recorder.skipped_frames();
  result.records = recorder.TakeRecords();
  result.events = recorder.TakeEvents();
  result.engine = std::move(engine);
  return result;
}

}  // namespace omnicml
