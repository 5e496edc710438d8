// CLI tests of the input limits ("bounded in every dimension, failing early, leaving nothing
// half-done") and of the `--config` round trips of `simulate`, `mcl` and `topo`: absurd
// sizes, unwritable or misplaced outputs, symbolic-link loops, directories where files
// belong and values that would break a run later all give exit code 2 with one line
// naming the flag or path, before any frame is processed, and leave nothing behind.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/baselines/mcl/mcl.h"
#include "omnicml/baselines/topo/topological.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sim/simulator.h"
#include "testing/cli_helpers.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

constexpr int kFramesPerDay = 30;

using testing::CommandResult;
using testing::RunOmnicml;
using testing::Slurp;
using testing::Spit;

// The entries of a directory (names only, sorted).
std::vector<std::string> Entries(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) out.push_back(e.path().filename().string());
  std::sort(out.begin(), out.end());
  return out;
}

// Rows of a CSV without the columns whose header starts with "time_" (timings vary).
std::vector<std::string> RowsWithoutTimings(const fs::path& csv) {
  std::ifstream in(csv);
  std::string line;
  std::vector<std::string> rows;
  std::vector<bool> keep;
  bool header = true;
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) cells.push_back(cell);
    if (header) {
      for (const auto& c : cells) keep.push_back(c.rfind("time_", 0) != 0);
      header = false;
    }
    std::string row;
    for (std::size_t i = 0; i < cells.size(); ++i) {
      if (i >= keep.size() || keep[i]) row += cells[i] + ",";
    }
    rows.push_back(row);
  }
  return rows;
}

// Exit code 2, one line, naming every piece of `mentions`.
void ExpectBadInput(const CommandResult& r, const std::vector<std::string>& mentions) {
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_EQ(r.output.find("internal error"), std::string::npos) << r.output;
  for (const auto& m : mentions)
    EXPECT_NE(r.output.find(m), std::string::npos) << m << ": " << r.output;
}

class CliLimits : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(testing::FreshTempDir("omnicml_cli_limits"));
    SimulatorOptions sim;
    sim.days = 2;
    sim.frames_per_day = kFramesPerDay;
    sim.seed = 5;
    sim.output = ImageKind::kPanorama;
    SimulatedFrameSource source(sim);
    LogWriter writer((*dir_ / "log").string());
    WriteFrames(source, writer);
    writer.Finish();
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
  }
  static fs::path Dir() { return *dir_; }
  static fs::path Log() { return *dir_ / "log"; }
  // A copy of the log in a fresh directory `name`, its first session's directory returned.
  static fs::path CopyLog(const std::string& name) {
    const fs::path copy = Dir() / name;
    fs::remove_all(copy);
    fs::copy(Log(), copy, fs::copy_options::recursive);
    std::vector<fs::path> sessions;
    for (const auto& e : fs::directory_iterator(copy)) {
      if (e.is_directory()) sessions.push_back(e.path());
    }
    std::sort(sessions.begin(), sessions.end());
    return sessions.front();
  }
  static fs::path* dir_;
};
fs::path* CliLimits::dir_ = nullptr;

TEST_F(CliLimits, AbsurdSizesAreRefusedUpFront) {
  // Days, frames, threads, jobs, runs and particles beyond common/limits.h: exit 2 naming
  // the flag, nothing written.
  const fs::path out = Dir() / "never";
  ExpectBadInput(RunOmnicml("simulate --days 10000 --frames-per-day 10 --out " + out.string()),
                 {"--days", "10000"});
  ExpectBadInput(RunOmnicml("simulate --days 2 --frames-per-day 2147483647 --out " + out.string()),
                 {"--frames-per-day"});
  ExpectBadInput(RunOmnicml("simulate --days 1000 --frames-per-day 100000 --out " + out.string()),
                 {"--days x --frames-per-day"});
  ExpectBadInput(RunOmnicml("run --world home_store --days 5000 --quiet --out " + out.string()),
                 {"--days"});
  ExpectBadInput(RunOmnicml("run --world home_store --frames-per-day 2147483647 --quiet --out " +
                            out.string()),
                 {"--frames-per-day"});
  ExpectBadInput(
      RunOmnicml("run " + Log().string() + " --threads 100000 --quiet --out " + out.string()),
      {"threads", "100000"});
  const fs::path config = Dir() / "threads.yaml";
  Spit(config, "threads: 100000\n");
  ExpectBadInput(RunOmnicml("run " + Log().string() + " --config " + config.string() +
                            " --quiet --out " + out.string()),
                 {"threads", "threads.yaml"});
  fs::remove(config);
  ExpectBadInput(
      RunOmnicml("compare " + Log().string() + " --jobs 1000 --quiet --out " + out.string()),
      {"--jobs"});
  ExpectBadInput(RunOmnicml("mcl --world home_store --experiment tracking --runs 0"), {"--runs"});
  ExpectBadInput(RunOmnicml("mcl --world home_store --particles 2000000000 --out " + out.string()),
                 {"--particles"});
  ExpectBadInput(RunOmnicml("mcl --world home_store --days 5000 --out " + out.string()),
                 {"--days"});
  ExpectBadInput(
      RunOmnicml("topo --world home_store --days 5000 --frames-per-day 10 --out " + out.string()),
      {"--days"});
  EXPECT_FALSE(fs::exists(out));
  // --help names the ceilings.
  const CommandResult help = RunOmnicml("simulate --help");
  EXPECT_NE(help.output.find("at most 1000"), std::string::npos) << help.output;
}

TEST_F(CliLimits, OutputsAreCheckedBeforeTheRunStarts) {
  // A directory as --map-out or --trajectory-out, a missing directory, a file as --out:
  // exit 2 naming the flag and path before any frame, no run directory left behind.
  const std::vector<std::string> before = Entries(Dir());
  const fs::path out = Dir() / "run_out";
  const fs::path a_dir = Dir() / "a_directory";
  fs::create_directories(a_dir);
  const std::string run = "run " + Log().string() + " --quiet --out " + out.string();
  ExpectBadInput(RunOmnicml(run + " --map-out " + a_dir.string()),
                 {"--map-out", a_dir.string(), "is a directory"});
  ExpectBadInput(RunOmnicml(run + " --trajectory-out " + a_dir.string()),
                 {"--trajectory-out", a_dir.string(), "is a directory"});
  const fs::path missing = Dir() / "no_such_dir" / "map.omap";
  ExpectBadInput(RunOmnicml(run + " --map-out " + missing.string()),
                 {"--map-out", "does not exist"});
  const fs::path a_file = Dir() / "a_file";
  Spit(a_file, "x");
  ExpectBadInput(RunOmnicml("run " + Log().string() + " --quiet --out " + a_file.string()),
                 {"--out", a_file.string(), "not a directory"});
  ExpectBadInput(
      RunOmnicml("run " + Log().string() + " --quiet --out " + (a_file / "sub").string()),
      {"--out", a_file.string()});
  ExpectBadInput(
      RunOmnicml("mcl --world home_store --frames-per-day 10 --out " + (a_file / "sub").string()),
      {"--out"});
  ExpectBadInput(
      RunOmnicml("topo --world home_store --frames-per-day 10 --out " + (a_file / "sub").string()),
      {"--out"});
  ExpectBadInput(RunOmnicml("simulate --days 1 --frames-per-day 5 --out " +
                            (Dir() / "sim_never").string() + " --preview " + a_dir.string()),
                 {"--preview", "is a directory"});
  EXPECT_FALSE(fs::exists(Dir() / "sim_never"));
  if (::geteuid() != 0) {  // root writes anywhere
    const fs::path locked = Dir() / "locked";
    fs::create_directories(locked);
    fs::permissions(locked, fs::perms::owner_read | fs::perms::owner_exec);
    ExpectBadInput(RunOmnicml(run + " --map-out " + (locked / "map.omap").string()),
                   {"--map-out", "not writable"});
    fs::permissions(locked, fs::perms::owner_all);
  }
  // A map-out inside the run directory the run creates is fine.
  const CommandResult ok = RunOmnicml(run + " --map-out " + (out / "map.omap").string());
  EXPECT_EQ(ok.exit_code, 0) << ok.output;
  EXPECT_TRUE(fs::is_regular_file(out / "map.omap"));
  fs::remove_all(out);
  fs::remove_all(a_dir);
  fs::remove(a_file);
  EXPECT_EQ(Entries(Dir()), before) << "left behind";
}

TEST_F(CliLimits, SymlinkLoopsAndDirectoriesAreBadInputNamingThePath) {
  // A symbolic-link loop as configuration, map, world or log file and a directory where a
  // file belongs: exit 2 with the path, never exit 1 "internal error".
  const fs::path loop = Dir() / "loop.yaml";
  fs::create_symlink(loop, loop);
  const fs::path out = Dir() / "never";
  const std::string l = loop.string();
  ExpectBadInput(
      RunOmnicml("run " + Log().string() + " --quiet --config " + l + " --out " + out.string()),
      {l});
  ExpectBadInput(
      RunOmnicml("run " + Log().string() + " --quiet --map-in " + l + " --out " + out.string()),
      {l});
  ExpectBadInput(RunOmnicml("inspect " + l), {l});
  ExpectBadInput(RunOmnicml("run --world " + l + " --quiet --out " + out.string()), {l});
  ExpectBadInput(RunOmnicml("simulate --world " + l + " --days 1 --out " + out.string()), {l});
  ExpectBadInput(RunOmnicml("mcl --world home_store --config " + l), {l});
  ExpectBadInput(RunOmnicml("topo --world home_store --config " + l + " --out " + out.string()),
                 {l});
  ExpectBadInput(RunOmnicml("simulate --config " + l + " --out " + out.string()), {l});
  ExpectBadInput(
      RunOmnicml("run " + Log().string() + " --quiet --map-out " + l + " --out " + out.string()),
      {"--map-out", l});
  // session.yaml as a directory.
  const fs::path session = CopyLog("log_dir_session");
  fs::remove(session / "session.yaml");
  fs::create_directory(session / "session.yaml");
  ExpectBadInput(RunOmnicml("validate " + (Dir() / "log_dir_session").string()),
                 {(session / "session.yaml").string()});
  ExpectBadInput(
      RunOmnicml("run " + (Dir() / "log_dir_session").string() + " --quiet --out " + out.string()),
      {(session / "session.yaml").string()});
  EXPECT_FALSE(fs::exists(out));
  fs::remove(loop);
  fs::remove_all(Dir() / "log_dir_session");
}

TEST_F(CliLimits, ValidationCatchesWhatWouldBreakTheRunLater) {
  // Huge or non-positive covariances, out-of-range poses and a header-only frames.csv are
  // rejected by `validate` and `run`, naming file and line; long excerpts are cut.
  struct Case {
    std::string name;
    std::string file;      // "session.yaml" or "frames.csv"
    std::string from, to;  // text replaced in the file ("" from: whole file = to)
    std::vector<std::string> mentions;
  };
  const fs::path session0 = CopyLog("probe");
  const std::string yaml = Slurp(session0 / "session.yaml");
  const std::string csv = Slurp(session0 / "frames.csv");
  fs::remove_all(Dir() / "probe");
  const std::string header = csv.substr(0, csv.find('\n') + 1);
  const std::string row1 =
      csv.substr(header.size(), csv.find('\n', header.size()) + 1 - header.size());
  // The covariance line of session.yaml.
  const std::size_t cov = yaml.find("covariance_diagonal: [");
  ASSERT_NE(cov, std::string::npos) << yaml;
  const std::string cov_line = yaml.substr(cov, yaml.find('\n', cov) - cov);
  const std::size_t pose = yaml.find("pose: [");
  ASSERT_NE(pose, std::string::npos) << yaml;
  const std::string pose_line = yaml.substr(pose, yaml.find('\n', pose) - pose);
  std::vector<std::string> cells;
  {
    std::stringstream ss(row1.substr(0, row1.size() - 1));
    std::string c;
    while (std::getline(ss, c, ',')) cells.push_back(c);
  }
  ASSERT_EQ(cells.size(), 8u) << row1;
  const auto row_with = [&](int column, const std::string& value) {
    std::vector<std::string> c = cells;
    c[column] = value;
    std::string r;
    for (std::size_t i = 0; i < c.size(); ++i) r += (i ? "," : "") + c[i];
    return r + "\n";
  };
  const std::vector<Case> cases = {
      {"huge_heading_variance",
       "session.yaml",
       cov_line,
       "covariance_diagonal: [0.01, 0.01, 9.2e18]",
       {"session.yaml:", "too large"}},
      {"negative_variance",
       "session.yaml",
       cov_line,
       "covariance_diagonal: [0.01, -1, 0.01]",
       {"session.yaml:", "positive"}},
      {"huge_start_pose",
       "session.yaml",
       pose_line,
       "pose: [3e6, 0, 0]",
       {"session.yaml:", "range"}},
      {"huge_odometry", "frames.csv", row1, row_with(2, "1e300"), {"frames.csv:2", "odom_x_m"}},
      {"far_truth", "frames.csv", row1, row_with(6, "-2000000"), {"frames.csv:2", "gt_y_m"}},
      {"huge_heading", "frames.csv", row1, row_with(4, "1e200"), {"frames.csv:2", "odom_phi_rad"}},
      {"header_only", "frames.csv", "", header, {"frames.csv", "no frames"}},
      {"long_excerpt",
       "frames.csv",
       row1,
       row_with(3, std::string(60000, '7') + "x"),
       {"frames.csv:2", "odom_y_m", "..."}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path session = CopyLog(c.name);
    const fs::path file = session / c.file;
    std::string text = Slurp(file);
    if (c.from.empty()) {
      text = c.to;
    } else {
      const std::size_t at = text.find(c.from);
      ASSERT_NE(at, std::string::npos);
      text.replace(at, c.from.size(), c.to);
    }
    Spit(file, text);
    std::vector<std::string> mentions = c.mentions;
    mentions.push_back(session.string());
    const CommandResult v = RunOmnicml("validate " + (Dir() / c.name).string());
    ExpectBadInput(v, mentions);
    EXPECT_LT(v.output.size(), 1500u);
    const fs::path out = Dir() / (c.name + "_run");
    const CommandResult r =
        RunOmnicml("run " + (Dir() / c.name).string() + " --quiet --out " + out.string());
    ExpectBadInput(r, mentions);
    EXPECT_FALSE(fs::exists(out));
    fs::remove_all(Dir() / c.name);
  }
}

TEST_F(CliLimits, SimulateConfigLoadsBackToTheSameLog) {
  // simulation.yaml of a simulated log, given to --config, simulates the same log; a flag
  // given next to it wins.
  const fs::path a = Dir() / "sim_a", b = Dir() / "sim_b", c = Dir() / "sim_c";
  const CommandResult ra = RunOmnicml(
      "simulate --world institute --days 2 --frames-per-day 8 "
      "--seed 7 --panorama --step-m 0.3 --start continue --out " +
      a.string());
  ASSERT_EQ(ra.exit_code, 0) << ra.output;
  ASSERT_TRUE(fs::is_regular_file(a / "simulation.yaml"));
  ASSERT_TRUE(fs::is_regular_file(a / "world.yaml"));
  const SimulatorOptions loaded = LoadSimulatorOptions((a / "simulation.yaml").string());
  EXPECT_EQ(loaded.days, 2);
  EXPECT_EQ(loaded.seed, 7u);
  EXPECT_EQ(loaded.output, ImageKind::kPanorama);
  const CommandResult rb =
      RunOmnicml("simulate --config " + (a / "simulation.yaml").string() + " --out " + b.string());
  ASSERT_EQ(rb.exit_code, 0) << rb.output;
  EXPECT_EQ(Entries(a), Entries(b));
  for (const std::string day : {"day_001", "day_002"}) {
    EXPECT_EQ(Slurp(a / day / "frames.csv"), Slurp(b / day / "frames.csv")) << day;
    EXPECT_EQ(Slurp(a / day / "session.yaml"), Slurp(b / day / "session.yaml")) << day;
    EXPECT_EQ(Slurp(a / day / "000003.png"), Slurp(b / day / "000003.png")) << day;
  }
  EXPECT_EQ(Slurp(a / "simulation.yaml"), Slurp(b / "simulation.yaml"));
  const CommandResult rc = RunOmnicml("simulate --config " + (a / "simulation.yaml").string() +
                                      " --seed 8 --out " + c.string());
  ASSERT_EQ(rc.exit_code, 0) << rc.output;
  EXPECT_EQ(LoadSimulatorOptions((c / "simulation.yaml").string()).seed, 8u);
  EXPECT_NE(Slurp(a / "day_001" / "frames.csv"), Slurp(c / "day_001" / "frames.csv"));
  // An unknown key names file and line.
  const fs::path bad = Dir() / "bad_sim.yaml";
  Spit(bad, "days: 1\nframes_per_dya: 3\n");
  ExpectBadInput(
      RunOmnicml("simulate --config " + bad.string() + " --out " + (Dir() / "never").string()),
      {"bad_sim.yaml:2", "frames_per_dya"});
  EXPECT_FALSE(fs::exists(Dir() / "never"));
  for (const auto& p : {a, b, c, bad}) fs::remove_all(p);
}

TEST_F(CliLimits, MclConfigLoadsBackToTheSameRun) {
  // config.yaml of an mcl run directory, given to --config with the same inputs, repeats
  // the run: same frames.csv (timings aside) and the same config.yaml.
  const std::string inputs = "mcl --world home_store --days 2 --frames-per-day 40 --seed 2 ";
  const fs::path a = Dir() / "mcl_a", b = Dir() / "mcl_b";
  const CommandResult ra = RunOmnicml(inputs +
                                      "--particles 400 --random-samples 7 --top-k 5 "
                                      "--heading-gate-deg 20 --mcl-seed 9 --out " +
                                      a.string());
  ASSERT_EQ(ra.exit_code, 0) << ra.output;
  const CommandResult rb =
      RunOmnicml(inputs + "--config " + (a / "config.yaml").string() + " --out " + b.string());
  ASSERT_EQ(rb.exit_code, 0) << rb.output;
  EXPECT_EQ(Slurp(a / "config.yaml"), Slurp(b / "config.yaml"));
  EXPECT_EQ(RowsWithoutTimings(a / "frames.csv"), RowsWithoutTimings(b / "frames.csv"));
  const MclOptions loaded = LoadMclOptions((b / "config.yaml").string());
  EXPECT_EQ(loaded.num_particles, 400);
  EXPECT_EQ(loaded.seed, 9u);
  EXPECT_FALSE(loaded.heading_independent);
  for (const auto& p : {a, b}) fs::remove_all(p);
}

TEST_F(CliLimits, TopoConfigLoadsBackToTheSameRun) {
  const std::string inputs =
      "topo --world home_store --days 2 --frames-per-day 40 --seed 2 --place-length-m 4 ";
  const fs::path a = Dir() / "topo_a", b = Dir() / "topo_b";
  const CommandResult ra = RunOmnicml(inputs +
                                      "--bins 16 --filter-width 3 --distance chi_square "
                                      "--band-threshold 0.1 --global-search-after 5 --out " +
                                      a.string());
  ASSERT_EQ(ra.exit_code, 0) << ra.output;
  const CommandResult rb =
      RunOmnicml(inputs + "--config " + (a / "topo_config.yaml").string() + " --out " + b.string());
  ASSERT_EQ(rb.exit_code, 0) << rb.output;
  EXPECT_EQ(Slurp(a / "topo_config.yaml"), Slurp(b / "topo_config.yaml"));
  EXPECT_EQ(Slurp(a / "frames.csv"), Slurp(b / "frames.csv"));
  const TopologicalOptions loaded = LoadTopologicalOptions((b / "topo_config.yaml").string());
  EXPECT_EQ(loaded.histogram.bins, 16);
  EXPECT_EQ(loaded.global_search_after_frames, 5);
  for (const auto& p : {a, b}) fs::remove_all(p);
}

}  // namespace
}  // namespace omnicml
