#include "omnicml/experiments/run_experiment.h"

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <thread>
#include <vector>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/experiments/survey.h"
#include "omnicml/run/cml_run.h"
#include "omnicml/run/run_report.h"

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

RunExperimentResult RunExperiment(const RunExperimentOptions& o) {
  const RunSettings& f = o.settings;
  f.input.Validate();
  // Every output is checked (and locked) before the first frame (cml_run.h).
  RunOutputs outputs;
  outputs.run_dir = f.out_dir.empty() ? DefaultRunDir("run") : f.out_dir;
  outputs.map_path = o.map_out;
  outputs.trajectory_path = o.trajectory_out;
  outputs.title = "omnicml run";
  outputs.input_description = f.input.Describe() + (o.map_in.empty() ? "" : ", map " + o.map_in);
  const std::vector<std::unique_ptr<OutputLock>> locks = CheckRunOutputs(outputs);
  if (f.log_every_frames < 1) throw Error("--log-every must be >= 1");

  f.survey.Validate();
  CmlRunSettings run;
  run.outputs = outputs;
  // Read the survey trajectory before the first frame (a bad line fails at once).
  if (f.survey.enabled()) run.process = MakeSurveyFrameProcessor(f.survey, nullptr);
  run.evaluate_from_session = f.survey.days;
  // A new map's options: the spatial thresholds and the motion noise, when the options
  // ask, are derived from the input first (run_config.h ResolveNewMapOptions).
  std::string calibration_note;
  std::unique_ptr<CmlEngine> engine =
      MakeRunEngine(o.map_in.empty() ? WithDefaultThreads(f.overrides) : f.overrides, o.map_in,
                    f.input, &calibration_note, f.base_options.value_or(CmlEngineOptions{}));
  if (!calibration_note.empty()) run.outputs.input_description += "; " + calibration_note;
  // Survey with static forgetting: the survey builds the map (active forgetting), which is
  // frozen after the last survey day ([G]'s static "old" map).
  if (f.survey.enabled() && engine->options().model.forgetting.mode == ForgettingMode::kStatic &&
      engine->session_state().session + 1 < f.survey.days) {
    engine->SetForgettingMode(ForgettingMode::kActive);
    const int last_survey_session = f.survey.days - 1;
    run.on_session_end = [last_survey_session](CmlEngine& e, int session) {
      if (session == last_survey_session) e.SetForgettingMode(ForgettingMode::kStatic);
    };
  }
  if (engine->options().model.forgetting.mode == ForgettingMode::kStatic &&
      engine->model().NumViews() == 0 && !f.quiet) {
    std::cerr << "omnicml run: warning: static forgetting on an empty map: the map will stay empty "
                 "(build it first, then resume with --map-in MAP --forgetting static)\n";
  }
  // Simulated input: the map's health by area scored against the day events at the end
  // of each day (change_detection.h).
  std::optional<ChangeDetectionObserver> changes;
  if (!f.input.world.empty()) {
    changes.emplace(f.input.world, f.input.first_day, f.input.seed);
    run.observers.push_back(&*changes);
  }
  run.progress = MakeProgressOptions(f, "run", std::nullopt);

  CmlRunResult r = RunCml(std::move(engine), f.input, run);
  RunExperimentResult result;
  result.run_dir = outputs.run_dir.string();
  result.summary = r.summary;
  // Survey days are not localization (their estimates are the trusted poses): the
  // evaluation covers the days after the survey (survey.h).
  result.evaluation = std::move(r.evaluation);
  result.survey_frames =
      static_cast<std::int64_t>(r.records.size() - RecordsAfterSurvey(r.records, f.survey).size());
  result.views = r.engine->model().NumViews();
  result.components = r.engine->model().NumComponents();
  result.threads = r.engine->options().threads;
  result.timing = r.timing;
  if (changes) result.change_detection = changes->days();
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
