// `omnicml sweep SPEC.yaml --out DIR [-j N] [--dry-run|--no-run]`: expands a sweep spec
// (experiments/sweep.h; docs/guide.md "Sweeps") into a Snakemake workflow in DIR and runs it
// locally with N parallel jobs, then collects the summary (summary.csv, summary.html).
// Complete jobs are skipped on rerun. Prints the Snakemake command lines for running the
// same workflow by hand and on a Slurm cluster.
//
// Supervision: the sweep directory is locked (OutputLock) while `omnicml sweep` runs, so
// a second sweep into it refuses. Snakemake runs in its own process group; SIGINT,
// SIGTERM and SIGHUP sent to `omnicml sweep` are forwarded to that whole group (Snakemake
// and its jobs; a second signal sends SIGKILL), and `omnicml sweep` waits for them. Should
// `omnicml sweep` itself be killed, Snakemake receives SIGKILL (PR_SET_PDEATHSIG) and its
// jobs SIGTERM in turn (the Snakefile sets the same for them), so nothing runs on
// unsupervised. `omnicml sweep` is a child subreaper (PR_SET_CHILD_SUBREAPER): a process
// Snakemake started in a session or group of its own that outlives Snakemake is
// re-parented to it, receives SIGTERM (SIGKILL after a grace period) and is waited for. On start, a
// Snakemake lock left in DIR/.snakemake/locks by such a crash is removed (`snakemake --unlock`):
// holding the sweep directory's lock, no other `omnicml sweep` can be using it. Incomplete jobs
// rerun (--rerun-incomplete).
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>
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

// The process group of the running Snakemake (0: none) and the signals forwarded to it.
volatile sig_atomic_t g_child_group = 0;
volatile sig_atomic_t g_signals = 0;

void ForwardSignal(int signal) {
  g_signals = g_signals + 1;
  if (g_child_group > 0) ::kill(-g_child_group, g_signals > 1 ? SIGKILL : signal);
}

// The processes whose parent is this one (from /proc/PID/stat's fourth field).
std::vector<pid_t> Children() {
  std::vector<pid_t> children;
  const pid_t self = ::getpid();
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/proc", ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream is(entry.path() / "stat");
    std::string stat;
    std::getline(is, stat);
    // "pid (comm) state ppid ...": comm may hold spaces and parentheses; it ends at the last ')'.
    const std::size_t close = stat.rfind(')');
    if (close == std::string::npos) continue;
    std::istringstream rest(stat.substr(close + 1));
    std::string state;
    long ppid = 0;
    if (rest >> state >> ppid && ppid == self) children.push_back(std::stoi(name));
  }
  return children;
}

// Ends and waits for every process re-parented here after Snakemake exited (this process
// is a child subreaper): SIGTERM, then SIGKILL after `grace`.
void ReapOrphans(std::chrono::milliseconds grace) {
  const auto start = std::chrono::steady_clock::now();
  bool killed = false;
  for (std::vector<pid_t> children = Children(); !children.empty(); children = Children()) {
    const bool late = std::chrono::steady_clock::now() - start > grace;
    if (!killed || late) {
      for (const pid_t pid : children) ::kill(pid, late ? SIGKILL : SIGTERM);
      killed = true;
    }
    while (::waitpid(-1, nullptr, WNOHANG) > 0) {
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

// Runs argv in a new process group, forwarding SIGINT/SIGTERM/SIGHUP to the group, and
// returns its wait status. *signal_received: the first signal forwarded (0: none).
int RunSupervised(const std::vector<std::string>& argv, int* signal_received) {
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  struct sigaction forward {
  }, old_int{}, old_term{}, old_hup{};
  forward.sa_handler = ForwardSignal;
  sigemptyset(&forward.sa_mask);
  g_signals = 0;
  ::sigaction(SIGINT, &forward, &old_int);
  ::sigaction(SIGTERM, &forward, &old_term);
  ::sigaction(SIGHUP, &forward, &old_hup);
  const pid_t parent = ::getpid();
  ::prctl(PR_SET_CHILD_SUBREAPER, 1);
  std::cout.flush();
  const pid_t child = ::fork();
  if (child < 0) throw Error(StrCat("cannot start snakemake: fork failed: ", std::strerror(errno)));
  if (child == 0) {
    ::setpgid(0, 0);
    // Dies with its supervisor, even one killed with SIGKILL.
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(127);
    ::signal(SIGINT, SIG_DFL);
    ::signal(SIGTERM, SIG_DFL);
    ::signal(SIGHUP, SIG_DFL);
    ::execvp(args[0], args.data());
    ::_exit(127);
  }
  ::setpgid(child, child);  // also here: no window in which a signal misses the group
  g_child_group = child;
  if (g_signals > 0) ::kill(-child, SIGTERM);
  int status = 0;
  while (::waitpid(child, &status, 0) < 0 && errno == EINTR) {
  }
  g_child_group = 0;
  ReapOrphans(std::chrono::seconds(5));
  ::sigaction(SIGINT, &old_int, nullptr);
  ::sigaction(SIGTERM, &old_term, nullptr);
  ::sigaction(SIGHUP, &old_hup, nullptr);
  *signal_received = g_signals > 0 ? SIGTERM : 0;
  return status;
}

// Removes a Snakemake lock left in `dir` by a Snakemake that died (the caller holds the
// sweep directory's lock, so no other omnicml sweep runs there).
void RecoverSnakemakeLock(const std::string& dir) {
  const std::filesystem::path locks = std::filesystem::path(dir) / ".snakemake" / "locks";
  std::error_code ec;
  if (!std::filesystem::is_directory(locks, ec) || std::filesystem::is_empty(locks, ec)) return;
  std::vector<std::string> argv = SnakemakeCommand(dir, 1, SnakemakeMode::kLocal);
  argv.push_back("--unlock");
  argv.push_back("--quiet");
  int signal_received = 0;
  const int status = RunSupervised(argv, &signal_received);
  if (signal_received != 0) throw Error("sweep: interrupted while removing a stale Snakemake lock");
  if (status != 0) {
    throw Error(StrCat("sweep: a stale Snakemake lock in ", locks.string(),
                       " could not be removed (snakemake --unlock failed)"));
  }
  std::cout << "sweep: removed the Snakemake lock of an interrupted earlier run\n";
}

void Sweep(const SweepFlags& f) {
  if (f.jobs < 1 || f.jobs > 4096) throw Error("-j must be in 1..4096");
  CheckOutputDirectory(f.out, "--out");
  const SweepSpec spec = LoadSweepSpec(f.spec);
  const std::vector<SweepJob> jobs = ExpandSweep(spec, SelfPath());
  std::error_code ec;
  std::filesystem::create_directories(f.out, ec);
  if (ec) throw Error(StrCat("--out '", f.out, "': cannot create: ", ec.message()));
  // The sweep directory is ours until we return; a second sweep into it refuses.
  const OutputLock lock(f.out, "--out");
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
  RecoverSnakemakeLock(f.out);
  const SnakemakeMode mode = f.dry_run ? SnakemakeMode::kDryRun : SnakemakeMode::kLocal;
  const std::vector<std::string> argv = SnakemakeCommand(f.out, f.jobs, mode);
  std::cout << "$ " << ShellJoin(argv) << std::endl;
  const auto start = std::chrono::steady_clock::now();
  int signal_received = 0;
  const int status = RunSupervised(argv, &signal_received);
  if (signal_received != 0) {
    throw Error(
        StrCat("sweep interrupted: snakemake and its jobs were stopped; rerun the same "
               "command to resume (complete jobs are kept)"));
  }
  if (status != 0) {
    const std::string how = WIFEXITED(status)
                                ? StrCat("exit code ", WEXITSTATUS(status))
                                : StrCat("signal ", WIFSIGNALED(status) ? WTERMSIG(status) : 0);
    throw Error(StrCat("snakemake failed (", how, "); job logs are in ", f.out,
                       "/logs/; rerun the same command to retry the failed jobs"));
  }
  if (f.dry_run) return;
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const std::vector<SweepRow> rows = CollectSweep(f.out);
  std::cout << "sweep done in " << StrCat(std::fixed, std::setprecision(1), seconds) << " s; "
            << rows.size() << " run(s) collected into " << f.out << "/summary.csv and " << f.out
            << "/summary.html\n";
}

const CommandRegistration kRegistration{
    "sweep", [](CLI::App& app) {
      CLI::App* cmd =
          app.add_subcommand("sweep",
                             "Expand a sweep spec (worlds/logs x seeds x options) into a Snakemake "
                             "workflow and run it");
      auto flags = std::make_shared<SweepFlags>();
      cmd->add_option("spec", flags->spec, "Sweep spec YAML (README \"Sweeps\")")->required();
      AddOutputDirectory(cmd, "--out", &flags->out, "Sweep directory (created; reused on rerun)")
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
