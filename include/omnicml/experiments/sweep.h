// Parameter sweeps on Snakemake (`omnicml sweep`, `omnicml collect`): a YAML spec of
// inputs (simulated worlds or logs) x seeds x a grid of `omnicml run` options expands into
// jobs; the jobs become a Snakemake workflow in the sweep directory, each job one
// `omnicml run` (or `compare`) writing its run directory; `collect` gathers every run's
// summary into one CSV and an HTML report.
//
// Spec (docs/guide.md "Sweeps"; sample datasets/sweeps/forgetting_home_store.yaml). Keys:
//   command: run                  # run | compare (default run)
//   inputs:                       # at least one; each exactly one of world / logs
//     - {world: home_store, days: 1, frames_per_day: 60, name: hs}   # name optional
//     - {logs: [runs/log_a, runs/log_b], name: a}                    # no seeds for logs
//   seeds: [1, 2]                 # simulator seeds of world inputs (default [1])
//   options:                      # grid: every combination; key = flag without "--"
//     forgetting: [passive, active]
//     e_max: [0.4, 0.45]          # (underscores become dashes: --e-max)
//   args: ["--descriptor", "fourier"]   # fixed extra flags of every job (optional)
//   threads: 1                    # cores per job: Snakemake threads and --threads
//   mem_mb: 2000                  # per-job memory request (Slurm)
//   runtime_min: 60               # per-job time limit (Slurm)
// An unknown key or a bad value is an omnicml::Error "<file>:<line>: key: what".
// Relative paths (logs, world files, option values naming existing files) are made
// absolute against the current directory, since the jobs run inside the sweep directory.
//
// Sweep directory: Snakefile (static; the jobs are read from sweep.json), sweep.json
// (jobs with their argv), spec.yaml (copy), runs/<job>/ (run directories; a compare job
// holds one per forgetting mode), runs/<job>/sweep_job.json (written by the workflow
// when the job succeeded: wall time, peak resident memory, exit code; Snakemake's output,
// so complete jobs are skipped on rerun), logs/<job>.log, and after `collect`
// summary.csv and summary.html.
//
// Pure functions of their inputs except where files are named; thread-compatible.
#ifndef OMNICML_EXPERIMENTS_SWEEP_H_
#define OMNICML_EXPERIMENTS_SWEEP_H_

#include <cstdint>
#include <filesystem>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace omnicml {

struct SweepInput {
  std::string name;               // short name used in job names
  std::string world;              // built-in world name or absolute world file path
  int days = 1;                   // world only, >= 1
  int frames_per_day = 0;         // world only; 0 = the simulator default
  std::vector<std::string> logs;  // absolute log directories (instead of world)
};

struct SweepSpec {
  std::string source;           // file name, for messages
  std::string command = "run";  // run | compare
  std::vector<SweepInput> inputs;
  std::vector<std::uint64_t> seeds = {1};
  // Grid axes in spec order: flag name (without "--", dashes) and its values.
  std::vector<std::pair<std::string, std::vector<std::string>>> options;
  std::vector<std::string> args;  // fixed extra flags
  int threads = 1;                // >= 1
  int mem_mb = 2000;              // > 0
  int runtime_min = 60;           // > 0
};

// Parses a spec; `source` names it in errors. Throws omnicml::Error.
SweepSpec ParseSweepSpec(const std::string& yaml_text, const std::string& source);
SweepSpec LoadSweepSpec(const std::filesystem::path& path);

struct SweepJob {
  std::string name;                                          // unique, [A-Za-z0-9._-]
  std::string input;                                         // SweepInput::name
  std::uint64_t seed = 0;                                    // 0 for logs
  std::vector<std::pair<std::string, std::string>> options;  // one value per grid axis
  std::vector<std::string> argv;  // the full command, run inside the sweep directory
};

// Every combination input x seed (worlds) x option values, in spec order; `binary` is
// the omnicml executable the jobs call. Job run directories are runs/<name>. Throws
// omnicml::Error when two jobs would get the same name.
std::vector<SweepJob> ExpandSweep(const SweepSpec& spec, const std::string& binary);

// Writes Snakefile, sweep.json and spec.yaml into `dir` (created when missing); files
// whose content is unchanged are not rewritten, so a rerun keeps Snakemake's state.
void WriteSweepWorkflow(const std::filesystem::path& dir, const SweepSpec& spec,
                        const std::string& spec_text, const std::vector<SweepJob>& jobs);

// Snakemake command lines for the workflow in `dir` (argv, unquoted).
enum class SnakemakeMode { kLocal, kDryRun, kSlurm };
std::vector<std::string> SnakemakeCommand(const std::filesystem::path& dir, int jobs,
                                          SnakemakeMode mode);
// The argv as one shell-quoted line.
std::string ShellJoin(const std::vector<std::string>& argv);

// One day (session) of a run directory of the sweep: a row of summary_days.csv.
struct SweepDay {
  int session = 0;  // 0-based
  int frames = 0;   // frames of the day (localized or not)
  int frames_localized = 0;
  double error_mean_m = 0, error_max_m = 0;  // over the localized frames with truth; NaN if none
  double nees_xy_median = std::numeric_limits<double>::quiet_NaN();
  double nees_xy_in_band = std::numeric_limits<double>::quiet_NaN();
  int views_at_end = 0;  // map size at the day's last frame
};

// One row of summary.csv: a run directory of the sweep.
struct SweepRow {
  std::string job;
  std::string mode;    // compare: the forgetting-mode subdirectory; run: ""
  std::string status;  // complete | incomplete (run files without sweep_job.json) | missing
  std::string input;
  std::uint64_t seed = 0;
  std::vector<std::pair<std::string, std::string>> options;
  int frames = 0;
  int sessions = 0;
  double coverage = 0;           // localized frames / frames
  double unimodal_fraction = 0;  // NaN-free: 0 without frames
  double error_mean_m = 0, error_median_m = 0, error_p95_m = 0, error_max_m = 0;
  double heading_mean_deg = 0;
  double odometry_mean_m = 0;
  int views = 0, components = 0;  // at the end of the run
  double wall_s = 0;              // whole job (a compare job: its modes together)
  double peak_rss_mb = 0;         // peak resident memory of the job's process
  // Consistency over the run (DayEvaluation; NaN without covariances): position NEES
  // (2 dof) median and p95, fraction inside its 95 % band, heading NEES (1 dof) median,
  // NIS (3 dof) median.
  double nees_xy_median = std::numeric_limits<double>::quiet_NaN();
  double nees_xy_p95 = std::numeric_limits<double>::quiet_NaN();
  double nees_xy_in_band = std::numeric_limits<double>::quiet_NaN();
  double nees_phi_median = std::numeric_limits<double>::quiet_NaN();
  double nis_median = std::numeric_limits<double>::quiet_NaN();
  std::vector<SweepDay> days;  // per session, in order
};

// Reads the runs of the sweep in `dir` (jobs from sweep.json; missing runs give a row of
// status "missing") and writes dir/summary.csv, dir/summary_days.csv (one row per run and
// day), dir/summary.html and, per group of runs (input and option values other than
// forgetting), dir/day_plots/<group>.svg: the mean position error per day of each
// forgetting mode over the seeds and the map size per day. Throws omnicml::Error when
// sweep.json is missing or a run file is malformed.
std::vector<SweepRow> CollectSweep(const std::filesystem::path& dir);
// The CSV text of the rows (header line first; option columns from the first row).
std::string SweepRowsToCsv(const std::vector<SweepRow>& rows);
// The CSV text of the rows' days: job, mode, input, seed, options, then the SweepDay
// fields with day = session + 1.
std::string SweepDaysToCsv(const std::vector<SweepRow>& rows);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_SWEEP_H_
