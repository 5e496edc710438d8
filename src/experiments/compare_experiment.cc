#include "omnicml/experiments/compare_experiment.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <thread>

#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/experiments/replay.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/experiments/survey.h"
#include "omnicml/report/map_export.h"
#include "omnicml/report/report.h"
#include "omnicml/report/svg_plot.h"
#include "omnicml/run/cml_run.h"
#include "omnicml/run/floor_plan.h"
#include "omnicml/run/run_recorder.h"
#include "omnicml/run/run_report.h"

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
  for (const char* h : {"views_end", "mean_err_m", "max_err_m", "head_mean_deg", "unimodal%",
                        "odom_err_m", "coverage%", "min_day_coverage%"})
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

// The final map of a mode over its trajectory, views removed during the run marked
// (from the mode's map events, what its events.csv holds: complete although the model
// keeps only recent events), and the removals counted per session: (by active
// forgetting, otherwise).
std::string ModeMapSvg(const CmlEngine& engine, const std::vector<FrameRecord>& records,
                       const std::vector<MapEvent>& events, const std::string& input,
                       std::map<int, std::pair<int, int>>* removed_by_session) {
  MapPictureOptions pic;
  pic.width_px = 900;
  pic.floor_plan = FloorPlanForRunInput(input);
  std::vector<Pose2> trajectory;
  for (const FrameRecord& r : records) {
    if (r.has_truth) pic.ground_truth.push_back(r.truth);
    if (r.has_estimate) trajectory.push_back(r.estimate);
  }
  std::map<std::uint64_t, bool> last_loss_active;  // view -> its latest component removal
  for (const MapEvent& e : events) {
    if (e.type == MapEventType::kComponentRemoved) {
      last_loss_active[e.view_id] = IsActiveForgettingReason(e.reason);
    } else if (e.type == MapEventType::kViewRemoved) {
      pic.removed_m.push_back(e.position.head<2>());
      const bool active = IsActiveForgettingReason(e.reason) || last_loss_active[e.view_id];
      auto& [by_active, otherwise] = (*removed_by_session)[e.session];
      (active ? by_active : otherwise) += 1;
    }
  }
  return MapToSvg(engine.model(), trajectory, pic);
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
      "/ frames over the run, min_day_coverage% = the lowest coverage of a day. views@s = "
      "reference views in the map right after frame s, while the map updates of the last "
      "update_delay_frames frames are still queued; views_end = after the run's end, queued "
      "updates applied: the saved map (and the sum of days.csv's views_inserted minus "
      "views_removed). days.csv's views_at_end is views@ the day's last frame.");
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

  report.AddHeading("Views removed per day: by active forgetting / otherwise");
  report.AddParagraph(
      "From each mode's events.csv: a view removed by active forgetting lost its last "
      "component by rule (18)-(19) (its place was expected in view but did not match); "
      "otherwise by passive forgetting (17), a weight below w_min or a merge. Where: the red "
      "crosses on the maps below; when, frame by frame: replay.html.");
  std::vector<std::vector<std::string>> removed_rows;
  std::vector<int> sessions;  // every day of the run, survey days included
  if (!results.empty()) {
    for (const FrameRecord& rec : results.front().records) {
      if (sessions.empty() || sessions.back() != rec.session) sessions.push_back(rec.session);
    }
  }
  for (int session : sessions) {
    std::vector<std::string> row = {std::to_string(session + 1)};
    for (const auto& r : results) {
      const auto it = r.views_removed_by_session.find(session);
      row.push_back(it == r.views_removed_by_session.end()
                        ? "0 / 0"
                        : StrCat(it->second.first, " / ", it->second.second));
    }
    removed_rows.push_back(row);
  }
  report.AddTable(header, removed_rows);
  report.AddHeading("Consistency per day (NEES, NIS)");
  report.AddParagraph(
      "Medians of the position NEES (2 dof, consistent 1.39), heading NEES (1 dof, 0.45) and "
      "NIS of the appearance fixes (3 dof, 2.37); in% = frames inside the two-sided 95 % "
      "chi-square band (consistent: 95 %). Each mode's report.html plots them over the run.");
  for (const auto& r : results) {
    std::vector<std::vector<std::string>> consistency;
    for (const DayEvaluation& d : r.evaluation.days) consistency.push_back(ConsistencyPerDayRow(d));
    consistency.push_back(ConsistencyPerDayRow(r.evaluation.overall));
    std::vector<std::string> header = ConsistencyPerDayHeader();
    header[0] = r.mode + ": day";
    report.AddTable(header, consistency);
  }

  report.AddHeading("Plots");
  SvgPlot growth("Map growth", "step (frame)", "reference views", 960, 320);
  SvgPlot errors("Position error (moving average over 50 frames; odometry only may leave the axis)",
                 "step (frame)", "error [m]", 960, 320);
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
  double modes_max = 0;  // the error axis fits the modes; dead reckoning may leave it
  for (const auto& r : results) {
    std::vector<double> x, views, err;
    for (const auto& rec : r.records) {
      x.push_back(static_cast<double>(rec.global_frame + 1));
      views.push_back(rec.views);
      err.push_back(rec.position_error_m);
    }
    growth.AddLine(r.mode, x, views);
    const std::vector<double> smooth = MovingAverage(err, 50);
    for (double v : smooth) {
      if (std::isfinite(v)) modes_max = std::max(modes_max, v);
    }
    errors.AddLine(r.mode, x, smooth);
    hist.AddHistogram(r.mode, edges, HistogramCounts(err, edges), true);
  }
  if (!results.empty()) {
    // Dead reckoning is the same in every mode (same frames): one grey line, the bar to beat.
    std::vector<double> x, odo;
    for (const auto& rec : results.front().records) {
      x.push_back(static_cast<double>(rec.global_frame + 1));
      odo.push_back(rec.odometry_error_m);
    }
    errors.AddSeries(
        {"odometry only", x, MovingAverage(odo, 50), SvgPlot::SeriesStyle::kLine, "#999999"});
    if (modes_max > 0) errors.SetYRange(0, 1.25 * modes_max);
    AddDayMarkers(&growth, results.front().records, 1);
    AddDayMarkers(&errors, results.front().records, 1);
  }
  report.AddSvg(growth.Render());
  report.AddSvg(errors.Render());
  report.AddSvg(hist.Render());
  report.AddHeading("Maps at the end");
  report.AddParagraph(
      "Each mode's final map over its estimated trajectory (ground truth in grey); red crosses "
      "mark where views were removed during the run (events.csv of the mode's directory: "
      "which, when and why). The interactive replay.html shows them appear and go frame by "
      "frame.");
  // Drawn at 900 px (legend and scale bar stay readable), shown two to a row: the
  // viewBox scales each picture to its half of the page.
  report.AddRawHtml(
      "<style>.mode-map{display:inline-block;width:49%;vertical-align:top}"
      ".mode-map svg{width:100%;height:auto}</style>");
  for (const auto& r : results) {
    report.AddRawHtml("<div class=\"mode-map\"><h3>" + XmlEscape(r.mode) + "</h3>" + r.map_svg +
                      "</div>");
  }
  report.AddHeading("Table as printed");
  report.AddPreformatted(table_text);
  return report.Render();
}

}  // namespace

std::string FormatCompareTable(const std::vector<CompareModeResult>& modes,
                               const std::vector<std::int64_t>& steps) {
  return FormatTextTable(TableHeader(steps), TableRows(modes, steps), /*left_align_first=*/true);
}

namespace {

// The settings' checks before any work, in the command's order (steps, input, jobs,
// progress); the engine options are checked after them.
void CheckCompareSettings(const RunInput& input, const std::vector<std::int64_t>& steps, int jobs,
                          std::int64_t log_every_frames) {
  if (steps.empty()) throw Error("--steps needs at least one step");
  for (std::int64_t s : steps) {
    if (s < 1) throw Error(StrCat("--steps: ", s, " is not a positive integer"));
  }
  input.Validate();
  CheckLimit("--jobs", jobs, 0, kMaxThreads);
  if (log_every_frames < 1) throw Error("--log-every must be >= 1");
}

}  // namespace

CmlEngineOptions CompareModeOptions(const CmlEngineOptions& options, ForgettingMode mode) {
  CmlEngineOptions o = options;
  // static: learn the first day actively, then freeze (see the file comment).
  o.model.forgetting.mode = mode == ForgettingMode::kStatic ? ForgettingMode::kActive : mode;
  return o;
}

CompareExperimentResult RunCompare(const CmlEngineOptions& options, const RunInput& input,
                                   const CompareSettings& settings) {
  const std::vector<std::int64_t>& steps = settings.steps;
  const SurveyOptions& survey = settings.survey;
  CheckCompareSettings(input, steps, settings.jobs, settings.progress.log_every_frames);
  options.Validate();
  survey.Validate();
  // One reading of the survey trajectory, shared (read-only) by the modes' threads.
  std::shared_ptr<const SurveyPoses> survey_poses;
  if (!survey.poses_path.empty()) {
    survey_poses = std::make_shared<const SurveyPoses>(SurveyPoses::Read(survey.poses_path));
  }
  // static freezes the map after the last day that builds it: day 1, or the last survey day.
  const int freeze_after_session = std::max(survey.days, 1) - 1;
  const CompareOutputs& outputs = settings.outputs;
  // The whole comparison is assembled in a staging directory and renamed into place at
  // the end (common/file_io.h StagedDirectory): a failure or a kill leaves the old one.
  std::optional<StagedDirectory> staged;
  if (!outputs.out_dir.empty()) staged.emplace(outputs.out_dir, "--out", RunDirectoryMarkers());
  const std::vector<ForgettingMode> modes = {ForgettingMode::kPassive, ForgettingMode::kActive,
                                             ForgettingMode::kStatic};
  // The three modes are independent runs (each with its own frame source and engine,
  // each deterministic whatever the timing), so they may run in parallel threads; the
  // results are identical to a sequential run. Progress then comes as plain log lines.
  const int jobs = std::clamp(
      settings.jobs > 0 ? settings.jobs : static_cast<int>(std::thread::hardware_concurrency()), 1,
      static_cast<int>(modes.size()));
  CheckOutputDirectory(outputs.map_out_dir, "--map-out");
  std::vector<std::vector<std::uint8_t>> map_bytes(modes.size());
  auto run_mode = [&](std::size_t index) {
    const ForgettingMode mode = modes[index];
    CompareModeResult result;
    result.mode = ToString(mode);
    CmlRunSettings run;
    if (staged) {
      run.outputs.run_dir = staged->path() / result.mode;
      run.outputs.stage_run_dir = false;  // inside the staging directory
    }
    run.outputs.title = "omnicml run (" + result.mode + " forgetting)";
    if (!settings.input_note.empty()) {
      run.outputs.input_description = input.Describe() + "; " + settings.input_note;
    }
    run.progress = settings.progress;
    run.progress.label = result.mode;
    if (jobs > 1) run.progress.progress_bar = false;
    // The errors cover the days after the survey (survey.h); views@step all frames.
    run.evaluate_from_session = survey.days;
    run.keep_events = true;
    if (mode == ForgettingMode::kStatic) {
      run.on_session_end = [freeze_after_session](CmlEngine& e, int session) {
        if (session == freeze_after_session) e.SetForgettingMode(ForgettingMode::kStatic);
      };
    }
    if (survey.enabled()) run.process = MakeSurveyFrameProcessor(survey, survey_poses);
    CmlRunResult r = RunCml(CompareModeOptions(options, mode), input, run);
    result.survey_frames = static_cast<std::int64_t>(
        std::count_if(r.records.begin(), r.records.end(),
                      [&survey](const FrameRecord& f) { return f.session < survey.days; }));
    if (result.survey_frames == static_cast<std::int64_t>(r.records.size())) {
      throw Error(StrCat("--survey-days ", survey.days, ": the input (", input.Describe(),
                         ") has no frames after the survey days to evaluate"));
    }
    result.evaluation = std::move(r.evaluation);
    result.records = std::move(r.records);
    for (std::int64_t s : steps) result.views_at_steps.push_back(ViewsAtStep(result.records, s));
    result.wall_s = r.summary.wall_s;
    result.final_views = static_cast<int>(r.engine->model().NumViews());
    result.final_components = static_cast<int>(r.engine->model().NumComponents());
    result.map_svg = ModeMapSvg(*r.engine, result.records, r.events, input.Describe(),
                                &result.views_removed_by_session);
    if (!outputs.map_out_dir.empty()) map_bytes[index] = EncodeEngine(*r.engine);
    if (settings.keep_engines) result.engine = std::move(r.engine);
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
  out.out_dir = outputs.out_dir.string();
  out.input = input.Describe();
  out.survey_note = SurveyExcludedNote(survey, results.front().survey_frames);
  // table.txt says which frames its errors cover.
  {
    const EvaluationResult& e = results.front().evaluation;
    std::ostringstream head;
    if (!out.survey_note.empty()) head << "# " << out.survey_note << "\n";
    head << "# errors over " << e.overall.frames << " frames";
    if (!e.days.empty())
      head << " (days " << e.days.front().session + 1 << "-" << e.days.back().session + 1 << ")";
    head << ", localized frames only (coverage%)\n";
    head << "# views@s: views after frame s (updates of the last update_delay_frames frames "
            "still queued); views_end: at the end, queued updates applied (the saved map)\n";
    out.table_text = head.str() + FormatCompareTable(results, steps);
  }
  // The maps are written completely, then commit with the run directory as one unit
  // (StagedDirectory::Commit with companions): old maps and directory or new ones.
  std::vector<std::unique_ptr<AtomicFile>> maps;
  if (!outputs.map_out_dir.empty()) {
    std::filesystem::create_directories(outputs.map_out_dir);
    for (std::size_t i = 0; i < modes.size(); ++i) {
      maps.push_back(
          std::make_unique<AtomicFile>(outputs.map_out_dir / (ToString(modes[i]) + ".omap")));
      maps.back()->stream().write(reinterpret_cast<const char*>(map_bytes[i].data()),
                                  static_cast<std::streamsize>(map_bytes[i].size()));
    }
  }
  std::vector<AtomicFile*> companions;
  for (auto& m : maps) companions.push_back(m.get());
  if (staged) {
    WriteFileAtomic(staged->path() / "table.txt", out.table_text, FileSync::kDeferred);
    WriteFileAtomic(staged->path() / "report.html",
                    RenderCompareReport(out.input, results, steps, out.table_text),
                    FileSync::kDeferred);
    staged->Commit(companions);
  } else {
    for (AtomicFile* m : companions) m->Commit();
  }
  out.modes = std::move(results);
  return out;
}

CompareExperimentResult RunCompareExperiment(const CompareExperimentOptions& options) {
  const RunSettings& f = options.settings;
  CheckCompareSettings(f.input, options.steps, options.jobs, f.log_every_frames);
  // The modes set forgetting; --forgetting is not a flag of the command.
  CompareSettings s;
  const CmlEngineOptions base =
      ResolveNewMapOptions(WithDefaultThreads(f.overrides), f.input, &s.input_note,
                           f.base_options.value_or(CmlEngineOptions{}));
  s.steps = options.steps;
  s.jobs = options.jobs;
  s.survey = f.survey;
  s.progress = MakeProgressOptions(f, "", std::nullopt);
  s.outputs.out_dir = f.out_dir.empty() ? DefaultRunDir("compare") : f.out_dir;
  s.outputs.map_out_dir = options.map_out_dir;
  return RunCompare(base, f.input, s);
}

std::string FormatCompareExperimentResult(const CompareExperimentResult& result) {
  std::ostringstream os;
  os << "input: " << result.input << "\n" << result.table_text;
  for (const auto& r : result.modes) {
    os << r.mode << ": " << r.records.size() << " frames in " << FormatFixed(r.wall_s, 1) << " s";
    if (r.evaluation.overall.frames_skipped > 0)
      os << " (" << r.evaluation.overall.frames_skipped << " unreadable frames skipped)";
    os << "; per-day mean error m (localized frames, days "
       << (r.evaluation.days.empty() ? 0 : r.evaluation.days.front().session + 1) << "-):";
    for (const auto& d : r.evaluation.days) os << " " << FormatFixed(d.position_m.mean, 3);
    os << "; per-day coverage %:";
    for (const auto& d : r.evaluation.days) os << " " << FormatFixed(d.coverage * 100, 1);
    const DayEvaluation& all = r.evaluation.overall;
    if (all.nees_xy.count > 0) {
      os << "; position NEES median " << FormatFixed(all.nees_xy.median, 2) << " p95 "
         << FormatFixed(all.nees_xy.p95, 2) << " in band "
         << FormatFixed(all.nees_xy_in_band * 100, 1) << " %, heading NEES median "
         << FormatFixed(all.nees_phi.median, 2) << " (consistent 1.39 / 5.99 / 95 %, 0.45)";
    }
    os << "\n";
  }
  if (!result.out_dir.empty())
    os << "report: " << (std::filesystem::path(result.out_dir) / "report.html").string() << "\n";
  return os.str();
}

}  // namespace omnicml
