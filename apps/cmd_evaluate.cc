// `omnicml evaluate RUNDIR`: error statistics of a run against ground truth per day
// (mean, RMSE, median, p95, max), evo's APE and RPE figures (evaluation/
// trajectory_metrics.h), error histograms ([G] Fig. 5 and 6) and the change from day to
// day; prints a text table and writes an HTML report (RUNDIR/evaluation.html, or the
// next free RUNDIR/evaluation-N.html so an earlier evaluation is kept; --out FILE).
// Ground truth comes from frames.csv, or from a TUM file (--groundtruth) associated by
// stamp within --max-time-diff; `--estimate EST.tum --groundtruth REF.tum` evaluates two
// TUM files without a run directory.
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/evaluation/trajectory_metrics.h"
#include "omnicml/report/map_export.h"
#include "omnicml/report/report.h"

namespace omnicml::app {
namespace {
namespace fs = std::filesystem;

struct EvaluateFlags {
  std::string run_dir;
  std::string align = "none";
  int bins = 20;
  std::string html_out;
  bool force = false;
  std::string groundtruth;
  std::string estimate;
  double max_time_diff_s = 0.01;
  double rpe_delta_m = 1.0;
};

// RUNDIR/evaluation.html, or evaluation-2.html, -3, ... when taken.
fs::path FreeReportPath(const fs::path& dir) {
  fs::path p = dir / "evaluation.html";
  for (int n = 2; fs::exists(p); ++n) p = dir / StrCat("evaluation-", n, ".html");
  return p;
}

FramesTable LoadTable(const EvaluateFlags& f) {
  FramesTable table;
  if (!f.estimate.empty()) {
    if (!f.run_dir.empty()) throw Error("give either RUNDIR or --estimate, not both");
    if (f.groundtruth.empty()) throw Error("--estimate needs --groundtruth");
    table.records = RecordsFromTum(ReadTumTrajectory(f.estimate));
    if (table.records.empty()) throw Error(StrCat(f.estimate, ": no poses"));
    return table;
  }
  if (f.run_dir.empty()) throw Error("give a run directory (or --estimate and --groundtruth)");
  const fs::path dir(f.run_dir);
  if (!fs::is_directory(dir)) throw Error(StrCat("run directory '", f.run_dir, "' does not exist"));
  const fs::path csv = dir / "frames.csv";
  if (!fs::is_regular_file(csv))
    throw Error(StrCat("'", f.run_dir, "' is not a run directory (no frames.csv)"));
  table = ReadFramesCsv(csv);
  ReadSkippedFrames(dir / "days.csv", &table);  // unreadable input frames, when recorded
  if (table.records.empty()) throw Error(StrCat(csv.string(), ": no frames"));
  return table;
}

void Evaluate(const EvaluateFlags& f) {
  const Alignment alignment = AlignmentFromString(f.align);
  if (f.bins < 1 || f.bins > 1000)
    throw Error(StrCat("--bins must be in 1..1000 (got ", f.bins, ")"));
  TrajectoryMetricsOptions metric_options;
  metric_options.rpe_delta_m = f.rpe_delta_m;
  try {
    metric_options.Validate();
  } catch (const Error&) {
    throw Error(
        StrCat("--rpe-delta-m must be a positive number of metres (got ", f.rpe_delta_m, ")"));
  }
  FramesTable table = LoadTable(f);
  std::string gt_note;
  if (!f.groundtruth.empty()) {
    const int matched =
        AssociateGroundTruth(&table.records, ReadTumTrajectory(f.groundtruth), f.max_time_diff_s);
    gt_note = StrCat("ground truth: ", f.groundtruth, ", ", matched, " of ", table.records.size(),
                     " frames associated within ", f.max_time_diff_s, " s\n");
  }
  const EvaluationResult result = omnicml::Evaluate(table, alignment, f.bins);
  if (result.overall.position_m.count == 0) {
    std::cerr << "omnicml evaluate: warning: no frame has both an estimate and ground truth\n";
  }
  std::vector<FrameRecord> aligned = table.records;
  Align(&aligned, alignment);
  const TrajectoryMetrics metrics = ComputeTrajectoryMetrics(aligned, metric_options);

  fs::path html;
  if (!f.html_out.empty()) {
    html = f.html_out;
    if (fs::exists(html) && !f.force) {
      throw Error(StrCat("--out '", f.html_out,
                         "' exists; choose another name or pass --force to replace it"));
    }
  } else {
    const fs::path dir =
        f.run_dir.empty() ? fs::path(f.estimate).parent_path() : fs::path(f.run_dir);
    html = f.force ? dir / "evaluation.html" : FreeReportPath(dir.empty() ? "." : dir);
  }
  const std::string source = f.run_dir.empty() ? f.estimate : f.run_dir;
  WriteFileAtomic(html,
                  RenderEvaluationHtml(result, table, "omnicml evaluation: " + source, &metrics));
  std::cout << gt_note << FormatEvaluation(result) << "\n"
            << FormatTrajectoryMetrics(metrics) << "report: " << html.string() << "\n";
}

const CommandRegistration kRegistration{
    "evaluate", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "evaluate",
          "Per-day error statistics, evo's APE/RPE and histograms of a run directory (or of "
          "two TUM files)");
      auto flags = std::make_shared<EvaluateFlags>();
      cmd->add_option("rundir", flags->run_dir, "Run directory written by omnicml run");
      cmd->add_option("--align", flags->align,
                      "Alignment of estimate to truth: none | start (per day, first frame) | se2 "
                      "(best rigid fit)")
          ->capture_default_str();
      cmd->add_option("--bins", flags->bins, "Histogram bins")->capture_default_str();
      AddOutputFile(cmd, "--out,--html", &flags->html_out,
                    "HTML report path (default RUNDIR/evaluation.html, or the next free "
                    "evaluation-N.html so earlier evaluations are kept)");
      cmd->add_flag("--force", flags->force,
                    "Replace an existing report (--out FILE, or RUNDIR/evaluation.html)");
      cmd->add_option("--groundtruth", flags->groundtruth,
                      "Reference trajectory (TUM) instead of the run's ground truth; associated "
                      "to the frames by nearest stamp (run_stamp_s, as trajectory.tum)");
      cmd->add_option("--estimate", flags->estimate,
                      "Evaluate this TUM trajectory against --groundtruth (no run directory)");
      cmd->add_option("--max-time-diff", flags->max_time_diff_s,
                      "Largest stamp difference (s) of an associated pair (evo --t_max_diff)")
          ->capture_default_str();
      cmd->add_option("--rpe-delta-m", flags->rpe_delta_m,
                      "Ground-truth path length (m) between the frames of an RPE pair (evo_rpe "
                      "--delta with --delta_unit m)")
          ->capture_default_str();
      cmd->callback([flags] { Evaluate(*flags); });
    }};

}  // namespace
}  // namespace omnicml::app
