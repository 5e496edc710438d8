// `omnicml sweep SPEC.yaml --out DIR [-j N] [--dry-run|--no-run]`: expands a sweep spec
// (experiments/sweep.h; README "Sweeps") into a Snakemake workflow in DIR and runs it
// locally with N parallel jobs, then collects the summary (summary.csv, summary.html).
// Complete jobs are skipped on rerun. Prints the Snakemake command lines for running the
// same workflow by hand and on a Slurm cluster.
#include <chrono>
#include <cstdlib>
#include <iomanip>
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/experiments/sweep.h"

namespace omnicml::app {
namespace {

struct SweepFlags {
  std::string spec;
  std::string out;
  int jobs = 1;
  bool dry_run = false;
  bool no_run = false;
};

std::string SelfPath() {
  std::error_code ec;
  const std::filesystem::path self = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) throw Error("cannot find the omnicml executable (/proc/self/exe)");
  return self.string();
}

bool HaveSnakemake() { return std::system("command -v snakemake >/dev/null 2>&1") == 0; }

void Sweep(const SweepFlags& f) {
  if (f.jobs < 1 || f.jobs > 4096) throw Error("-j must be in 1..4096");
  const SweepSpec spec = LoadSweepSpec(f.spec);
  const std::vector<SweepJob> jobs = ExpandSweep(spec, SelfPath());
  WriteSweepWorkflow(f.out, spec, ReadTextFile(f.spec, 1 << 20), jobs);
  std::cout << "sweep: " << jobs.size() << " jobs (" << spec.command << ") written to "
            << std::filesystem::absolute(f.out).lexically_normal().string() << "\n";
  std::cout << "  locally:  " << ShellJoin(SnakemakeCommand(f.out, f.jobs, SnakemakeMode::kLocal))
            << "\n";
  std::cout << "  on Slurm: " << ShellJoin(SnakemakeCommand(f.out, 100, SnakemakeMode::kSlurm))
            << "\n";
  std::cout << "  then:     omnicml collect " << f.out << "\n";
  if (f.no_run) return;
  if (!HaveSnakemake()) {
    throw Error(
        "snakemake is not installed (Debian package snakemake; scripts/setup.sh installs it); "
        "the workflow is written, run it with the commands above");
  }
  const SnakemakeMode mode = f.dry_run ? SnakemakeMode::kDryRun : SnakemakeMode::kLocal;
  const std::string command = ShellJoin(SnakemakeCommand(f.out, f.jobs, mode));
  std::cout << "$ " << command << std::endl;
  const auto start = std::chrono::steady_clock::now();
  const int status = std::system(command.c_str());
  if (status != 0) {
    throw Error(StrCat("snakemake failed (status ", status, "); job logs are in ", f.out,
                       "/logs/; rerun the same command to retry the failed jobs"));
  }
  if (f.dry_run) return;
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const std::vector<SweepRow> rows = CollectSweep(f.out);
  std::cout << "sweep done in " << StrCat(std::fixed, std::setprecision(1), seconds) << " s; "
            << rows.size() << " run(s) collected into " << f.out << "/summary.csv and "
            << f.out << "/summary.html\n";
}

const CommandRegistration kRegistration{
    "sweep", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "sweep", "Expand a sweep spec (worlds/logs x seeds x options) into a Snakemake "
                   "workflow and run it");
      auto flags = std::make_shared<SweepFlags>();
      cmd->add_option("spec", flags->spec, "Sweep spec YAML (README \"Sweeps\")")->required();
      cmd->add_option("--out", flags->out, "Sweep directory (created; reused on rerun)")
          ->required();
      cmd->add_option("-j,--jobs", flags->jobs, "Cores for local jobs (snakemake --cores)")
          ->capture_default_str();
      cmd->add_flag("--dry-run", flags->dry_run,
                    "Write the workflow and show what snakemake would run (snakemake -n)");
      cmd->add_flag("--no-run", flags->no_run,
                    "Only write the workflow and print the snakemake command lines");
      cmd->callback([flags] { Sweep(*flags); });
    }};

}  // namespace
}  // namespace omnicml::app
