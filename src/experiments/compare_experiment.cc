#include "omnicml/experiments/compare_experiment.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <memory>
#include <sstream>
#include <thread>

#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/experiments/run_recorder.h"
#include "omnicml/experiments/run_report.h"
#include "omnicml/experiments/survey.h"
#include "omnicml/report/report.h"
#include "omnicml/report/svg_plot.h"

namespace omnicml {

std::vector<std::int64_t> ParseSteps(const std::string& text) {
  std::vector<std::int64_t> steps;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    char* end = nullptr;
    const long long v = std::strtoll(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0' || v < 1) {
      throw Error(StrCat("--steps '", text, "': '", item, "' is not a positive integer"));
    }
    steps.push_back(v);
  }
  if (steps.empty()) throw Error("--steps needs at least one step");
  return steps;
}

namespace {

// Views in the map at step s (the s-th frame, 1-based); -1 when the run is shorter.
int ViewsAtStep(const std::vector<FrameRecord>& records, std::int64_t step) {
  if (step > static_cast<std::int64_t>(records.size())) return -1;
  return records[static_cast<std::size_t>(step - 1)].views;
}

std::vector<std::vector<std::string>> TableRows(const std::vector<CompareModeResult>& results,
                                                const std::vector<std::int64_t>& steps) {
  std::vector<std::vector<std::string>> rows;
  for (const CompareModeResult& r : results) {
    std::vector<std::string> row = {r.mode};
    for (std::int64_t s : steps) {
      const int v = ViewsAtStep(r.records, s);
      row.push_back(v < 0 ? "-" : std::to_string(v));
    }
    row.push_back(std::to_string(r.final_views));
    row.push_back(FormatFixed(r.evaluation.overall.position_m.mean, 3));
    row.push_back(FormatFixed(r.evaluation.overall.position_m.max, 3));
    row.push_back(FormatFixed(r.evaluation.overall.heading_rad.mean * 180 / kPi, 2));
    row.push_back(FormatFixed(r.evaluation.overall.unimodal_fraction * 100, 1));
    // Dead reckoning on the same frames (the same in every row): the bar to beat.
    row.push_back(FormatFixed(r.evaluation.overall.odometry_m.mean, 3));
    // Coverage: the errors above are over the localized frames only; the worst day shows
    // a failed day that the run's overall fraction would hide.
    row.push_back(FormatFixed(r.evaluation.overall.coverage * 100, 1));
    double worst_day = kNaN;
    for (const DayEvaluation& d : r.evaluation.days) {
      if (std::isfinite(d.coverage) && !(worst_day <= d.coverage)) worst_day = d.coverage;
    }
    row.push_back(FormatFixed(worst_day * 100, 1));
    rows.push_back(row);
  }
  return rows;
}

std::vector<std::string> TableHeader(const std::vector<std::int64_t>& steps) {
  std::vector<std::string> header = {"forgetting"};
  for (std::int64_t s : steps) header.push_back("views@" + std::to_string(s));
  for (const char* h :
       {"views_end", "mean_err_m", "max_err_m", "head_mean_deg", "unimodal%", "odom_err_m",
        "coverage%", "min_day_coverage%"})
    header.push_back(h);
  return header;
}

// Moving average over `window` frames (NaN ignored; NaN where the window has none).
std::vector<double> MovingAverage(const std::vector<double>& v, int window) {
  std::vector<double> out(v.size(), kNaN);
  double sum = 0;
  int count = 0;
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (std::isfinite(v[i])) sum += v[i], ++count;
    if (i >= static_cast<std::size_t>(window) &&
        std::isfinite(v[i - static_cast<std::size_t>(window)])) {
      sum -= v[i - static_cast<std::size_t>(window)], --count;
    }
    if (count > 0) out[i] = sum / count;
  }
  return out;
}

std::string RenderCompareReport(const std::string& input,
                                const std::vector<CompareModeResult>& results,
                                const std::vector<std::int64_t>& steps,
                                const std::string& table_text) {
  HtmlReport report("omnicml compare: passive, active and static forgetting");
  report.AddParagraph("Input: " + input +
                      ". The same frames under three forgetting modes ([G] Table 1). static learns "
                      "on the first day "
                      "(active) and is frozen afterwards. Each mode's run directory (frames.csv, "
                      "report.html) is in "
                      "the sub-directory named after it.");
  report.AddHeading("Reference views at steps, errors");
  report.AddParagraph(
      "Errors are over the localized frames (frames with an estimate); coverage% = localized "
      "/ frames over the run, min_day_coverage% = the lowest coverage of a day.");
  report.AddTable(TableHeader(steps), TableRows(results, steps));

  report.AddHeading(
      "Per day: mean position error (m, localized frames) / coverage % / views at the end of "
      "the day");
  std::vector<std::string> header = {"day"};
  for (const auto& r : results) header.push_back(r.mode);
  std::vector<std::vector<std::string>> rows;
  std::size_t days = 0;
  for (const auto& r : results) days = std::max(days, r.evaluation.days.size());
  for (std::size_t d = 0; d < days; ++d) {
    std::vector<std::string> row = {
        std::to_string((results.empty() || d >= results[0].evaluation.days.size()
                            ? static_cast<int>(d)
                            : results[0].evaluation.days[d].session) +
                       1)};
    for (const auto& r : results) {
      row.push_back(d < r.evaluation.days.size()
                        ? FormatFixed(r.evaluation.days[d].position_m.mean, 3) + " / " +
                              FormatFixed(r.evaluation.days[d].coverage * 100, 1) + " / " +
                              std::to_string(r.evaluation.days[d].views_at_end)
                        : "-");
    }
    rows.push_back(row);
  }
  report.AddTable(header, rows);

  report.AddHeading("Plots");
  SvgPlot growth("Map growth", "step (frame)", "reference views", 960, 320);
  SvgPlot errors("Position error (moving average over 50 frames)", "step (frame)", "error [m]", 960,
                 320);
  SvgPlot hist("Position error histogram", "error [m]", "frames", 640, 320);
  // Common bins over all modes.
  std::vector<double> all;
  for (const auto& r : results) {
    for (const auto& rec : r.records) all.push_back(rec.position_error_m);
  }
  std::vector<double> finite;
  for (double v : all) {
    if (std::isfinite(v)) finite.push_back(v);
  }
  std::sort(finite.begin(), finite.end());
  const double hi = finite.empty() ? 1.0 : std::max(1e-3, Quantile(finite, 0.99));
  std::vector<double> edges;
  for (int i = 0; i <= 25; ++i) edges.push_back(hi * i / 25);
  for (const auto& r : results) {
    std::vector<double> x, views, err;
    for (const auto& rec : r.records) {
      x.push_back(static_cast<double>(rec.global_frame + 1));
      views.push_back(rec.views);
      err.push_back(rec.position_error_m);
    }
    growth.AddLine(r.mode, x, views);
    errors.AddLine(r.mode, x, MovingAverage(err, 50));
    hist.AddHistogram(r.mode, edges, HistogramCounts(err, edges), true);
  }
  report.AddSvg(growth.Render());
  report.AddSvg(errors.Render());
  report.AddSvg(hist.Render());
  report.AddHeading("Table as printed");
  report.AddPreformatted(table_text);
  return report.Render();
}

}  // namespace

std::string FormatCompareTable(const std::vector<CompareModeResult>& modes,
                               const std::vector<std::int64_t>& steps) {
  return FormatTextTable(TableHeader(steps), TableRows(modes, steps), /*left_align_first=*/true);
}

CompareExperimentResult RunCompareExperiment(const CompareExperimentOptions& options) {
  const RunSettings& f = options.settings;
  const std::vector<std::int64_t>& steps = options.steps;
  if (steps.empty()) throw Error("--steps needs at least one step");
  for (std::int64_t s : steps) {
    if (s < 1) throw Error(StrCat("--steps: ", s, " is not a positive integer"));
  }
  f.input.Validate();
  CheckLimit("--jobs", options.jobs, 0, kMaxThreads);
  if (f.log_every_frames < 1) throw Error("--log-every must be >= 1");
  const CmlEngineOptions base = ResolveEngineOptions(WithDefaultThreads(f.overrides));
  f.survey.Validate();
  // One reading of the survey trajectory, shared (read-only) by the modes' threads.
  std::shared_ptr<const SurveyPoses> survey_poses;
  if (!f.survey.poses_path.empty()) {
    survey_poses = std::make_shared<const SurveyPoses>(SurveyPoses::Read(f.survey.poses_path));
  }
  // static freezes the map after the last day that builds it: day 1, or the last survey day.
  const int freeze_after_session = std::max(f.survey.days, 1) - 1;
  const std::filesystem::path out_dir = f.out_dir.empty() ? DefaultRunDir("compare") : f.out_dir;
  // The whole comparison is assembled in a staging directory and renamed into place at
  // the end (common/file_io.h StagedDirectory): a failure or a kill leaves the old one.
  StagedDirectory staged(out_dir, "--out", RunDirectoryMarkers());
  const std::vector<ForgettingMode> modes = {ForgettingMode::kPassive, ForgettingMode::kActive,
                                             ForgettingMode::kStatic};
  // The three modes are independent runs (each with its own frame source and engine,
  // each deterministic whatever the timing), so they may run in parallel threads; the
  // results are identical to a sequential run. Progress then comes as plain log lines.
  const int jobs = std::clamp(
      options.jobs > 0 ? options.jobs : static_cast<int>(std::thread::hardware_concurrency()), 1,
      static_cast<int>(modes.size()));
  {
    auto run_mode = [&](std::size_t index) {
      const ForgettingMode mode = modes[index];
      CompareModeResult result;
      result.mode = ToString(mode);
      CmlEngineOptions engine_options = base;
      // static: learn the first day actively, then freeze (see the file comment).
      engine_options.model.forgetting =
          mode == ForgettingMode::kStatic ? ForgettingMode::kActive : mode;
      CmlEngine engine(engine_options);
      auto source = OpenFrameSource(f.input);
      RunRecorderOptions ro;
      ro.run_dir = staged.path() / result.mode;
      ro.stage = false;  // inside the staging directory
      ro.title = "omnicml run (" + result.mode + " forgetting)";
      ro.input_description = f.input.Describe();
      RunRecorder recorder(ro);
      SessionEndHook freeze;
      if (mode == ForgettingMode::kStatic) {
        freeze = [freeze_after_session](CmlEngine& e, int session) {
          if (session == freeze_after_session) e.SetForgettingMode(ForgettingMode::kStatic);
        };
      }
      ProgressOptions progress = MakeProgressOptions(f, result.mode, CountFrames(f.input, *source));
      if (jobs > 1) progress.progress_bar = false;
      FrameProcessor process;
      if (f.survey.enabled()) process = MakeSurveyFrameProcessor(f.survey, survey_poses);
      const RunSummary summary =
          RunEngineOverSource(engine, *source, &recorder, progress, freeze, process);
      if (summary.frames == 0)
        throw Error(StrCat("the input (", f.input.Describe(), ") has no frames"));
      engine.Finish();
      recorder.Commit(engine, {{"wall time", FormatFixed(summary.wall_s, 1) + " s"}});
      FramesTable table;
      table.stage_names = StageNames();
      // The errors cover the days after the survey (survey.h); views@step all frames.
      table.records = RecordsAfterSurvey(recorder.records(), f.survey);
      result.survey_frames =
          static_cast<std::int64_t>(recorder.records().size() - table.records.size());
      table.skipped_frames = recorder.skipped_frames();
      if (table.records.empty()) {
        throw Error(StrCat("--survey-days ", f.survey.days, ": the input (", f.input.Describe(),
                           ") has no frames after the survey days to evaluate"));
      }
      result.evaluation = Evaluate(table, Alignment::kNone);
      result.records = recorder.records();
      result.wall_s = summary.wall_s;
      result.final_views = static_cast<int>(engine.model().NumViews());
      result.final_components = static_cast<int>(engine.model().NumComponents());
      return result;
    };
    std::vector<CompareModeResult> results(modes.size());
    std::vector<std::exception_ptr> errors(modes.size());
    // Worker w runs modes w, w + jobs, ...; every exception is kept and the first (in mode
    // order) rethrown once all threads are done, so no thread outlives the cleanup.
    auto worker = [&](int w) {
      for (std::size_t i = static_cast<std::size_t>(w); i < modes.size();
           i += static_cast<std::size_t>(jobs)) {
        try {
          results[i] = run_mode(i);
        } catch (...) {
          errors[i] = std::current_exception();
        }
      }
    };
    if (jobs == 1) {
      worker(0);
    } else {
      std::vector<std::thread> threads;
      for (int w = 0; w < jobs; ++w) threads.emplace_back(worker, w);
      for (auto& t : threads) t.join();
    }
    for (const auto& e : errors) {
      if (e) std::rethrow_exception(e);
    }
    CompareExperimentResult out;
    out.out_dir = out_dir.string();
    out.input = f.input.Describe();
    out.survey_note = SurveyExcludedNote(f.survey, results.front().survey_frames);
    // table.txt says which frames its errors cover.
    {
      const EvaluationResult& e = results.front().evaluation;
      std::ostringstream head;
      if (!out.survey_note.empty()) head << "# " << out.survey_note << "\n";
      head << "# errors over " << e.overall.frames << " frames";
      if (!e.days.empty())
        head << " (days " << e.days.front().session + 1 << "-" << e.days.back().session + 1 << ")";
      head << ", localized frames only (coverage%)\n";
      out.table_text = head.str() + FormatCompareTable(results, steps);
    }
    WriteFileAtomic(staged.path() / "table.txt", out.table_text, FileSync::kDeferred);
    WriteFileAtomic(staged.path() / "report.html",
                    RenderCompareReport(out.input, results, steps, out.table_text),
                    FileSync::kDeferred);
    staged.Commit();
    out.modes = std::move(results);
    return out;
  }
}

std::string FormatCompareExperimentResult(const CompareExperimentResult& result) {
  std::ostringstream os;
  os << "input: " << result.input << "\n" << result.table_text;
  for (const auto& r : result.modes) {
    os << r.mode << ": " << r.records.size() << " frames in " << FormatFixed(r.wall_s, 1)
       << " s";
    if (r.evaluation.overall.frames_skipped > 0)
      os << " (" << r.evaluation.overall.frames_skipped << " unreadable frames skipped)";
    os << "; per-day mean error m (localized frames, days "
       << (r.evaluation.days.empty() ? 0 : r.evaluation.days.front().session + 1) << "-):";
    for (const auto& d : r.evaluation.days) os << " " << FormatFixed(d.position_m.mean, 3);
    os << "; per-day coverage %:";
    for (const auto& d : r.evaluation.days) os << " " << FormatFixed(d.coverage * 100, 1);
    os << "\n";
  }
  os << "report: " << (std::filesystem::path(result.out_dir) / "report.html").string() << "\n";
  return os.str();
}

}  // namespace omnicml
