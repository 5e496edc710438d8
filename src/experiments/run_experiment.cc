#include "omnicml/experiments/run_experiment.h"

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <thread>
#include <vector>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/experiments/run_report.h"
#include "omnicml/experiments/survey.h"
#include "omnicml/report/map_export.h"
#include "omnicml/sim/world.h"

namespace omnicml {

std::string DefaultRunDir(const std::string& command) {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[64];
  std::strftime(buf, sizeof buf, "%Y%m%d-%H%M%S", &tm);
  return "runs/" + command + "-" + buf;
}

ProgressOptions MakeProgressOptions(const RunSettings& settings, const std::string& label,
                                    std::optional<std::int64_t> total_frames) {
  ProgressOptions p;
  p.progress_bar = !settings.no_progress_bar && StderrIsTerminal();
  p.log_every_frames = settings.log_every_frames;
  p.label = label;
  p.total_frames = total_frames;
  p.quiet = settings.quiet;
  return p;
}

OptionOverrides WithDefaultThreads(OptionOverrides overrides) {
  if (!overrides.threads && overrides.config_path.empty() &&
      std::thread::hardware_concurrency() >= 2) {
    overrides.threads = 2;
  }
  return overrides;
}

void CheckOutputParent(const std::string& path, const char* flag, const std::string& run_dir) {
  CheckOutputFile(path, flag, run_dir);
}

namespace {

// The engine of a run: a new one from the resolved options, or the saved one of map_in
// with only its mode changed. *note: what a new map's calibration identified (or "").
std::unique_ptr<CmlEngine> MakeRunEngine(const RunExperimentOptions& o, std::string* note) {
  const OptionOverrides& overrides = o.settings.overrides;
  if (o.map_in.empty()) {
    return std::make_unique<CmlEngine>(
        ResolveNewMapOptions(WithDefaultThreads(overrides), o.settings.input, note));
  }
  if (!overrides.OnlyThreadsAndForgetting()) {
    throw Error(StrCat("--map-in '", o.map_in,
                       "': the saved engine's options are used; only --threads and "
                       "--forgetting may change (drop --config, --e-max, --update-delay, "
                       "--descriptor)"));
  }
  std::error_code ec;
  if (!std::filesystem::is_regular_file(o.map_in, ec)) {
    throw Error(StrCat("--map-in '", o.map_in, "' ",
                       ec ? ec.message() : "does not exist or is not a regular file"));
  }
  std::unique_ptr<CmlEngine> engine = LoadEngine(o.map_in);
  // Parse both before changing anything, so a bad value leaves no half-changed engine.
  std::optional<ForgettingMode> forgetting;
  if (overrides.forgetting) forgetting = ForgettingModeFromString(*overrides.forgetting);
  if (overrides.threads) engine->SetThreads(*overrides.threads);
  if (forgetting) engine->SetForgettingMode(*forgetting);
  return engine;
}

}  // namespace

RunExperimentResult RunExperiment(const RunExperimentOptions& o) {
  const RunSettings& f = o.settings;
  f.input.Validate();
  // Every output is checked before the first frame: a run of hours must not fail at its
  // end on an unwritable --map-out, nor leave a half run directory behind.
  const std::string run_dir = f.out_dir.empty() ? DefaultRunDir("run") : f.out_dir;
  CheckOutputDirectory(run_dir, "--out");
  CheckOutputParent(o.map_out, "--map-out", run_dir);
  CheckOutputParent(o.trajectory_out, "--trajectory-out", run_dir);
  CheckReplaceableDirectory(run_dir, "--out", RunDirectoryMarkers());
  CheckRunOutputPlacement("--map-out", o.map_out, run_dir);
  CheckRunOutputPlacement("--trajectory-out", o.trajectory_out, run_dir);
  if (f.log_every_frames < 1) throw Error("--log-every must be >= 1");
  // A second writer of the same outputs refuses now, not after the run.
  std::vector<std::unique_ptr<OutputLock>> locks;
  locks.push_back(std::make_unique<OutputLock>(run_dir, "--out"));
  for (const auto& [flag, path] : {std::pair{"--map-out", o.map_out},
                                   std::pair{"--trajectory-out", o.trajectory_out}}) {
    // A file in the run directory is covered by the run directory's lock.
    if (!path.empty() && !LiesInRunDirectory(path, run_dir)) {
      locks.push_back(std::make_unique<OutputLock>(path, flag));
    }
  }

  f.survey.Validate();
  // Read the survey trajectory before the first frame (a bad line fails at once).
  FrameProcessor process;
  if (f.survey.enabled()) process = MakeSurveyFrameProcessor(f.survey, nullptr);
  std::string calibration_note;
  std::unique_ptr<CmlEngine> engine = MakeRunEngine(o, &calibration_note);
  // Survey with static forgetting: the survey builds the map (active forgetting), which is
  // frozen after the last survey day ([G]'s static "old" map).
  SessionEndHook freeze;
  if (f.survey.enabled() && engine->options().model.forgetting.mode == ForgettingMode::kStatic &&
      engine->session_state().session + 1 < f.survey.days) {
    engine->SetForgettingMode(ForgettingMode::kActive);
    const int last_survey_session = f.survey.days - 1;
    freeze = [last_survey_session](CmlEngine& e, int session) {
      if (session == last_survey_session) e.SetForgettingMode(ForgettingMode::kStatic);
    };
  }
  if (engine->options().model.forgetting.mode == ForgettingMode::kStatic &&
      engine->model().NumViews() == 0 && !f.quiet) {
    std::cerr << "omnicml run: warning: static forgetting on an empty map: the map will stay empty "
                 "(build it first, then resume with --map-in MAP --forgetting static)\n";
  }

  std::unique_ptr<FrameSource> source = OpenFrameSource(f.input);
  RunExperimentResult result;
  result.run_dir = run_dir;
  RunRecorderOptions ro;
  ro.run_dir = result.run_dir;
  ro.trajectory_path = o.trajectory_out;
  ro.title = "omnicml run";
  ro.input_description = f.input.Describe() + (o.map_in.empty() ? "" : ", map " + o.map_in) +
                         (calibration_note.empty() ? "" : "; " + calibration_note);
  RunRecorder recorder(ro);
  // Simulated input: the map's health by area scored against the day events at the end
  // of each day (change_detection.h).
  std::optional<World> world;
  if (!f.input.world.empty()) world = LoadWorld(f.input.world);
  std::vector<ChangeDetectionDay> change_days;
  auto score_changes = [&](CmlEngine& e, int source_session) {
    if (!world) return;
    const int session = e.session_state().session;
    ChangeDetectionOptions cd;
    MapHealthOptions ho;
    ho.cell_m = cd.cell_m;
    const MapHealth health = ComputeMapHealth(e.model(), session, ho);
    if (health.first_session < 0 || health.first_session >= session) return;  // a first map
    std::vector<Eigen::Vector2d> path;
    for (const FrameRecord& r : recorder.records()) {
      if (r.session == session && r.has_truth) path.push_back(r.truth.head<2>());
    }
    const int day = f.input.first_day + source_session + 1;
    const WorldDayChanges changes = ChangesOfDay(*world, day, f.input.seed);
    ChangedSharesFn shares;
    std::unique_ptr<VisibleChanges> visible;
    if (day >= 2) {
      visible = std::make_unique<VisibleChanges>(*world, day, f.input.seed, cd);
      shares = [&visible](const Eigen::Vector2d& p) {
        return ChangedShares{visible->SurfaceFraction(p), visible->LitFraction(p)};
      };
    }
    change_days.push_back(ScoreChangeDetection(health, changes, path, shares, cd));
  };
  int last_source_session = -1;
  result.summary = RunEngineOverSource(
      *engine, *source, &recorder, MakeProgressOptions(f, "run", CountFrames(f.input, *source)),
      [&](CmlEngine& e, int source_session) {
        score_changes(e, source_session);
        last_source_session = source_session;
        if (freeze) freeze(e, source_session);
      },
      process);
  if (result.summary.frames == 0) {
    throw Error(StrCat("the input (", f.input.Describe(), ") has no frames"));
  }
  // The saved engine is the state before Finish(), so a resumed run continues exactly as
  // one uninterrupted run would (queued updates and pending frames included).
  if (result.summary.sessions > 0) score_changes(*engine, last_source_session + 1);
  std::vector<std::uint8_t> map_bytes;
  if (!o.map_out.empty()) map_bytes = EncodeEngine(*engine);
  engine->Finish();
  const double fps =
      static_cast<double>(result.summary.frames) / std::max(result.summary.wall_s, 1e-9);
  char timing[96];
  std::snprintf(timing, sizeof timing, "%.1f s (%.1f frames/s)", result.summary.wall_s, fps);
  result.timing = timing;
  result.threads = engine->options().threads;
  std::vector<std::pair<std::string, std::string>> notes = {
      {"wall time", result.timing}, {"threads", std::to_string(result.threads)}};
  if (world) {
    std::ostringstream csv;
    WriteChangeDetectionCsv(csv, change_days);
    recorder.AddFile("change_detection.csv", csv.str());
    std::ostringstream cells_csv;
    WriteChangeCellsCsv(cells_csv, change_days, ChangeDetectionOptions{}.cell_m);
    recorder.AddFile("change_cells.csv", cells_csv.str());
    notes.emplace_back("change detection (health changed/new vs the day events)",
                       change_days.empty() ? std::string("no day after the map's first")
                                           : ChangeDetectionTotals(change_days));
  }
  // The map commits with the run directory (run_recorder.h).
  if (!o.map_out.empty()) recorder.AddOutput("--map-out", o.map_out, std::move(map_bytes));
  recorder.Commit(*engine, notes);
  result.change_detection = change_days;

  FramesTable table;
  table.stage_names = StageNames();
  // Survey days are not localization (their estimates are the trusted poses): the
  // evaluation covers the days after the survey (survey.h).
  table.records = RecordsAfterSurvey(recorder.records(), f.survey);
  result.survey_frames =
      static_cast<std::int64_t>(recorder.records().size() - table.records.size());
  table.skipped_frames = recorder.skipped_frames();
  if (!table.records.empty()) result.evaluation = Evaluate(table, Alignment::kNone);
  result.views = engine->model().NumViews();
  result.components = engine->model().NumComponents();
  return result;
}

std::string FormatRunExperimentResult(const RunExperimentOptions& options,
                                      const RunExperimentResult& result) {
  std::ostringstream os;
  const std::string survey_note = SurveyExcludedNote(options.settings.survey, result.survey_frames);
  if (!survey_note.empty()) os << survey_note << "\n";
  if (result.evaluation.overall.frames > 0) {
    os << FormatEvaluation(result.evaluation, /*with_histogram=*/false);
  } else {
    os << "no frames after the survey days: nothing to evaluate\n";
  }
  const RunSummary& s = result.summary;
  os << "frames: " << s.frames << " in " << s.sessions << " session(s), " << s.frames_localized
     << " localized ("
     << FormatFixed(s.frames > 0 ? 100.0 * static_cast<double>(s.frames_localized) /
                                       static_cast<double>(s.frames)
                                 : 0.0,
                    1)
     << " % coverage; errors above are over the localized frames)";
  if (s.frames_skipped > 0 || options.settings.input.skip_unreadable_frames)
    os << ", " << s.frames_skipped << " unreadable input frames skipped";
  os << ", " << result.timing << "\n";
  os << "map: " << result.views << " views, " << result.components << " components\n";
  os << "run directory: " << result.run_dir
     << "\nreport: " << (std::filesystem::path(result.run_dir) / "report.html").string()
     << "\nTUM (evo): " << (std::filesystem::path(result.run_dir) / "trajectory.tum").string()
     << " (+ groundtruth.tum, odometry.tum when the input has them)\n";
  os << FormatChangeDetection(result.change_detection);
  if (!options.map_out.empty()) os << "map saved: " << options.map_out << "\n";
  if (!options.trajectory_out.empty()) os << "trajectory (TUM): " << options.trajectory_out << "\n";
  return os.str();
}

}  // namespace omnicml
