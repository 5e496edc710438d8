// `omnicml compare`: the [G] Table 1 experiment. The same input is run three times, in
// parallel threads with --jobs > 1 (default: one per core; each engine may also use its
// own map-update worker; the results do not depend on either), under passive, active and
// static forgetting; prints the number of reference views at the given steps
// with the mean and max position error, and writes a report with map-growth and error
// plots. Each mode's full run directory is kept under RUNDIR/<mode>/.
//
// "static" is the baseline of a map that does not adapt: it learns on the first day
// (active forgetting) and is frozen from the second day on. (A map that is static from
// the start would stay empty.)
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/report.h"
#include "omnicml/experiments/run_config.h"
#include "omnicml/experiments/run_recorder.h"
#include "omnicml/report/svg_plot.h"

namespace omnicml::app {

// Defined in cmd_run.cc.
void AddRunInputFlags(CLI::App* cmd, RunSettings* f, bool with_forgetting);
std::string DefaultRunDir(const std::string& command);
ProgressOptions MakeProgress(const RunSettings& f, const std::string& label,
                             std::optional<std::int64_t> total);
OptionOverrides WithDefaultThreads(OptionOverrides overrides);

namespace {

struct ModeResult {
  std::string mode;
  std::vector<FrameRecord> records;
  EvaluationResult eval;
  double wall_s = 0;
  int final_views = 0;
  int final_components = 0;
};

std::string Fixed(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

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

// Views in the map at step s (the s-th frame, 1-based); -1 when the run is shorter.
int ViewsAtStep(const std::vector<FrameRecord>& records, std::int64_t step) {
  if (step > static_cast<std::int64_t>(records.size())) return -1;
  return records[static_cast<std::size_t>(step - 1)].views;
}

std::vector<std::vector<std::string>> TableRows(const std::vector<ModeResult>& results,
                                                const std::vector<std::int64_t>& steps) {
  std::vector<std::vector<std::string>> rows;
  for (const ModeResult& r : results) {
    std::vector<std::string> row = {r.mode};
    for (std::int64_t s : steps) {
      const int v = ViewsAtStep(r.records, s);
      row.push_back(v < 0 ? "-" : std::to_string(v));
    }
    row.push_back(std::to_string(r.final_views));
    row.push_back(Fixed(r.eval.overall.position_m.mean, 3));
    row.push_back(Fixed(r.eval.overall.position_m.max, 3));
    row.push_back(Fixed(r.eval.overall.heading_rad.mean * 180 / kPi, 2));
    row.push_back(Fixed(r.eval.overall.unimodal_fraction * 100, 1));
    // Dead reckoning on the same frames (the same in every row): the bar to beat.
    row.push_back(Fixed(r.eval.overall.odometry_m.mean, 3));
    rows.push_back(row);
  }
  return rows;
}

std::vector<std::string> TableHeader(const std::vector<std::int64_t>& steps) {
  std::vector<std::string> header = {"forgetting"};
  for (std::int64_t s : steps) header.push_back("views@" + std::to_string(s));
  for (const char* h :
       {"views_end", "mean_err_m", "max_err_m", "head_mean_deg", "unimodal%", "odom_err_m"})
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

std::string RenderCompareReport(const std::string& input, const std::vector<ModeResult>& results,
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
  report.AddTable(TableHeader(steps), TableRows(results, steps));

  report.AddHeading("Per day: mean position error (m) / views at the end of the day");
  std::vector<std::string> header = {"day"};
  for (const auto& r : results) header.push_back(r.mode);
  std::vector<std::vector<std::string>> rows;
  std::size_t days = 0;
  for (const auto& r : results) days = std::max(days, r.eval.days.size());
  for (std::size_t d = 0; d < days; ++d) {
    std::vector<std::string> row = {std::to_string(d + 1)};
    for (const auto& r : results) {
      row.push_back(d < r.eval.days.size() ? Fixed(r.eval.days[d].position_m.mean, 3) + " / " +
                                                 std::to_string(r.eval.days[d].views_at_end)
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

void Compare(const RunSettings& f, const std::string& steps_text, int jobs_requested) {
  const std::vector<std::int64_t> steps = ParseSteps(steps_text);
  f.input.Validate();
  if (f.log_every_frames < 1) throw Error("--log-every must be >= 1");
  const CmlEngineOptions base = ResolveEngineOptions(WithDefaultThreads(f.overrides));
  const std::filesystem::path out_dir = f.out_dir.empty() ? DefaultRunDir("compare") : f.out_dir;
  const bool created = !std::filesystem::exists(out_dir);
  if (!created && !std::filesystem::is_directory(out_dir)) {
    throw Error(StrCat("--out '", out_dir.string(), "' exists and is not a directory"));
  }
  std::vector<std::filesystem::path> made;  // removed again if a later step fails
  const std::vector<ForgettingMode> modes = {ForgettingMode::kPassive, ForgettingMode::kActive,
                                             ForgettingMode::kStatic};
  // The three modes are independent runs (each with its own frame source and engine,
  // each deterministic whatever the timing), so they may run in parallel threads; the
  // results are identical to a sequential run. Progress then comes as plain log lines.
  const int jobs = std::clamp(jobs_requested > 0 ? jobs_requested
                                                 : static_cast<int>(std::thread::hardware_concurrency()),
                              1, static_cast<int>(modes.size()));
  std::vector<char> dir_made(modes.size(), 0);
  try {
    auto run_mode = [&](std::size_t index) {
      const ForgettingMode mode = modes[index];
      ModeResult result;
      result.mode = ToString(mode);
      CmlEngineOptions options = base;
      // static: learn the first day actively, then freeze (see the file comment).
      options.model.forgetting = mode == ForgettingMode::kStatic ? ForgettingMode::kActive : mode;
      auto engine = std::make_unique<CmlEngine>(options);
      auto source = OpenFrameSource(f.input);
      RunRecorderOptions ro;
      ro.run_dir = out_dir / result.mode;
      ro.title = "omnicml run (" + result.mode + " forgetting)";
      ro.input_description = f.input.Describe();
      const bool dir_existed = std::filesystem::exists(ro.run_dir);
      RunRecorder recorder(ro);
      SessionEndHook freeze;
      if (mode == ForgettingMode::kStatic) {
        freeze = [](const CmlEngine& e, int session) -> std::unique_ptr<CmlEngine> {
          if (session != 0) return nullptr;
          CmlEngineOptions frozen = e.options();
          frozen.model.forgetting = ForgettingMode::kStatic;
          return RebuildEngineWithOptions(e, frozen);
        };
      }
      ProgressOptions progress = MakeProgress(f, result.mode, CountFrames(f.input, *source));
      if (jobs > 1) progress.progress_bar = false;
      const RunSummary summary = RunEngineOverSource(engine, *source, &recorder, progress, freeze);
      if (summary.frames == 0)
        throw Error(StrCat("the input (", f.input.Describe(), ") has no frames"));
      engine->Finish();
      recorder.Commit(*engine, {{"wall time", Fixed(summary.wall_s, 1) + " s"}});
      if (!dir_existed) dir_made[index] = 1;
      FramesTable table;
      table.stage_names = StageNames();
      table.records = recorder.records();
      result.eval = Evaluate(table, Alignment::kNone);
      result.records = recorder.records();
      result.wall_s = summary.wall_s;
      result.final_views = static_cast<int>(engine->model().NumViews());
      result.final_components = static_cast<int>(engine->model().NumComponents());
      return result;
    };
    std::vector<ModeResult> results(modes.size());
    std::vector<std::exception_ptr> errors(modes.size());
    // Worker w runs modes w, w + jobs, ...; every exception is kept and the first (in mode
    // order) rethrown once all threads are done, so no thread outlives the cleanup.
    auto worker = [&](int w) {
      for (std::size_t i = static_cast<std::size_t>(w); i < modes.size(); i += static_cast<std::size_t>(jobs)) {
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
    for (std::size_t i = 0; i < modes.size(); ++i) {
      if (dir_made[i]) made.push_back(out_dir / ToString(modes[i]));
    }
    for (const auto& e : errors) {
      if (e) std::rethrow_exception(e);
    }
    const std::string table_text = FormatTextTable(TableHeader(steps), TableRows(results, steps), /*left_align_first=*/true);
    WriteFileAtomic(out_dir / "table.txt", table_text);
    WriteFileAtomic(out_dir / "report.html",
                    RenderCompareReport(f.input.Describe(), results, steps, table_text));
    std::cout << "input: " << f.input.Describe() << "\n" << table_text;
    for (const auto& r : results) {
      std::cout << r.mode << ": " << r.records.size() << " frames in " << Fixed(r.wall_s, 1)
                << " s; per-day mean error m:";
      for (const auto& d : r.eval.days) std::cout << " " << Fixed(d.position_m.mean, 3);
      std::cout << "\n";
    }
    std::cout << "report: " << (out_dir / "report.html").string() << "\n";
  } catch (...) {
    std::error_code ec;
    for (const auto& dir : made) std::filesystem::remove_all(dir, ec);
    if (created) {
      std::filesystem::remove(out_dir / "table.txt", ec);
      if (std::filesystem::is_empty(out_dir, ec)) std::filesystem::remove(out_dir, ec);
    }
    throw;
  }
}

const CommandRegistration kRegistration{
    "compare", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "compare",
          "The [G] Table 1 experiment: the same input under passive, active and static forgetting");
      auto flags = std::make_shared<RunSettings>();
      auto steps = std::make_shared<std::string>("2000,4000,6000,8000");
      auto jobs = std::make_shared<int>(0);
      AddRunInputFlags(cmd, flags.get(), /*with_forgetting=*/false);
      cmd->add_option("--steps", *steps,
                      "Steps (frames) at which to report the number of reference views")
          ->capture_default_str();
      cmd->add_option("--jobs", *jobs,
                      "Modes run in parallel (0 = one per core, at most 3); results do not depend on it")
          ->capture_default_str()
          ->check(CLI::Range(0, 64));
      cmd->callback([flags, steps, jobs] { Compare(*flags, *steps, *jobs); });
    }};

}  // namespace
}  // namespace omnicml::app
