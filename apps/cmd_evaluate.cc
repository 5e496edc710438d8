// `omnicml evaluate RUNDIR`: error statistics of a run against ground truth per day
// (mean, median, p95, max), error histograms ([G] Fig. 5 and 6) and the change from day
// to day; prints a text table and writes RUNDIR/evaluation.html.
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/report.h"

namespace omnicml::app {
namespace {

struct EvaluateFlags {
  std::string run_dir;
  std::string align = "none";
  int bins = 20;
  std::string html_out;
};

void Evaluate(const EvaluateFlags& f) {
  const Alignment alignment = AlignmentFromString(f.align);
  if (f.bins < 1 || f.bins > 1000)
    throw Error(StrCat("--bins must be in 1..1000 (got ", f.bins, ")"));
  const std::filesystem::path dir(f.run_dir);
  if (!std::filesystem::is_directory(dir))
    throw Error(StrCat("run directory '", f.run_dir, "' does not exist"));
  const std::filesystem::path csv = dir / "frames.csv";
  if (!std::filesystem::is_regular_file(csv)) {
    throw Error(StrCat("'", f.run_dir, "' is not a run directory (no frames.csv)"));
  }
  FramesTable table = ReadFramesCsv(csv);
  ReadSkippedFrames(dir / "days.csv", &table);  // unreadable input frames, when recorded
  if (table.records.empty()) throw Error(StrCat(csv.string(), ": no frames"));
  const EvaluationResult result = omnicml::Evaluate(table, alignment, f.bins);
  if (result.overall.position_m.count == 0) {
    std::cerr << "omnicml evaluate: warning: no frame has both an estimate and ground truth\n";
  }
  const std::filesystem::path html =
      f.html_out.empty() ? dir / "evaluation.html" : std::filesystem::path(f.html_out);
  WriteFileAtomic(html, RenderEvaluationHtml(result, table, "omnicml evaluation: " + f.run_dir));
  std::cout << FormatEvaluation(result) << "report: " << html.string() << "\n";
}

const CommandRegistration kRegistration{
    "evaluate", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "evaluate", "Per-day error statistics and histograms of a run directory");
      auto flags = std::make_shared<EvaluateFlags>();
      cmd->add_option("rundir", flags->run_dir, "Run directory written by omnicml run")->required();
      cmd->add_option("--align", flags->align,
                      "Alignment of estimate to truth: none | start (per day, first frame) | se2 "
                      "(best rigid fit)")
          ->capture_default_str();
      cmd->add_option("--bins", flags->bins, "Histogram bins")->capture_default_str();
      AddOutputFile(cmd, "--html", &flags->html_out,
                      "HTML report path (default RUNDIR/evaluation.html)");
      cmd->callback([flags] { Evaluate(*flags); });
    }};

}  // namespace
}  // namespace omnicml::app
