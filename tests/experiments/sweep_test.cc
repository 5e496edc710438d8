// Sweeps on Snakemake (experiments/sweep.h, `omnicml sweep` / `omnicml collect`): spec
// parsing and expansion, and a 2x2 sweep run locally end to end (skipped without
// snakemake).
#include "omnicml/experiments/sweep.h"

#include <sys/wait.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

constexpr const char* kSpec2x2 = R"(command: run
inputs:
  - {world: home_store, days: 1, frames_per_day: 60, name: hs}
seeds: [1, 2]
options:
  forgetting: [passive, active]
threads: 1
)";

std::string RunShell(const std::string& command, int* exit_code) {
  std::string out;
  FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return out;
  char buf[4096];
  while (std::fgets(buf, sizeof buf, pipe) != nullptr) out += buf;
  const int status = ::pclose(pipe);
  *exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return out;
}

std::vector<std::map<std::string, std::string>> ReadCsv(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  std::vector<std::string> header;
  std::vector<std::map<std::string, std::string>> rows;
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) cells.push_back(cell);
    if (header.empty()) {
      header = cells;
      continue;
    }
    std::map<std::string, std::string> row;
    for (std::size_t i = 0; i < header.size() && i < cells.size(); ++i) row[header[i]] = cells[i];
    rows.push_back(row);
  }
  return rows;
}

// A 2x2 spec expands into four jobs with distinct names and complete command lines.
TEST(SweepSpec, ExpandsGrid) {
  const SweepSpec spec = ParseSweepSpec(kSpec2x2, "spec.yaml");
  const std::vector<SweepJob> jobs = ExpandSweep(spec, "/bin/omnicml");
  ASSERT_EQ(jobs.size(), 4u);
  EXPECT_EQ(jobs[0].name, "hs.s1.forgetting_passive");
  EXPECT_EQ(jobs[3].name, "hs.s2.forgetting_active");
  const std::string line = ShellJoin(jobs[3].argv);
  EXPECT_EQ(line,
            "/bin/omnicml run --world home_store --days 1 --seed 2 --frames-per-day 60 "
            "--forgetting active --threads 1 --no-progress-bar --out runs/hs.s2.forgetting_active");
}

// Unknown keys and reserved flags are errors naming file and line.
TEST(SweepSpec, RejectsBadKeys) {
  try {
    ParseSweepSpec("inputs:\n  - {world: home_store}\nseed: [1]\n", "bad.yaml");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml:3: seed: unknown key"), std::string::npos)
        << e.what();
  }
  EXPECT_THROW(ParseSweepSpec("inputs:\n  - {world: home_store}\noptions: {out: [a]}\n", "b"),
               Error);
  EXPECT_THROW(ParseSweepSpec("inputs:\n  - {world: no_such_world}\n", "b"), Error);
  EXPECT_THROW(ParseSweepSpec("inputs:\n  - {world: home_store, logs: [x]}\n", "b"), Error);
}

// Arguments with spaces or quotes are quoted for the shell.
TEST(SweepSpec, ShellJoinQuotes) {
  EXPECT_EQ(ShellJoin({"a", "b c", "it's"}), "a 'b c' 'it'\\''s'");
}

// The 2x2 sweep runs locally through Snakemake; summary.csv has four complete rows with
// plausible values; a rerun skips every complete job.
TEST(SweepEndToEnd, TwoByTwoLocally) {
  int code = 0;
  RunShell("command -v snakemake", &code);
  if (code != 0) GTEST_SKIP() << "snakemake is not installed (Debian package snakemake)";
  const fs::path dir =
      fs::temp_directory_path() / ("omnicml_sweep_test_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path spec = dir / "spec_2x2.yaml";
  std::ofstream(spec) << kSpec2x2;
  const std::string sweep = std::string(OMNICML_BINARY_DIR "/omnicml sweep ") + spec.string() +
                            " --out " + (dir / "sweep").string() + " -j 2";
  const auto start = std::chrono::steady_clock::now();
  const std::string out = RunShell(sweep, &code);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(code, 0) << out;
  std::printf("2x2 sweep (4 runs of 60 frames, -j 2): %.1f s\n", seconds);
  EXPECT_NE(out.find("--slurm"), std::string::npos) << out;

  const auto rows = ReadCsv(dir / "sweep" / "summary.csv");
  ASSERT_EQ(rows.size(), 4u);
  for (const auto& row : rows) {
    EXPECT_EQ(row.at("status"), "complete") << row.at("job");
    EXPECT_EQ(row.at("frames"), "60");
    const double mean = std::stod(row.at("error_mean_m"));
    EXPECT_TRUE(std::isfinite(mean) && mean >= 0 && mean < 5) << row.at("job") << " " << mean;
    const double coverage = std::stod(row.at("coverage"));
    EXPECT_GT(coverage, 0.5);
    EXPECT_LE(coverage, 1.0);
    EXPECT_GT(std::stoi(row.at("views")), 0);
    EXPECT_GT(std::stod(row.at("wall_s")), 0);
    EXPECT_GT(std::stod(row.at("peak_rss_mb")), 1);
    // mode is the forgetting mode the run used; seed the simulator seed.
    EXPECT_EQ(row.at("mode"), row.at("forgetting")) << row.at("job");
    EXPECT_TRUE(row.at("seed") == "1" || row.at("seed") == "2") << row.at("job");
  }
  EXPECT_TRUE(fs::exists(dir / "sweep" / "summary.html"));
  // summary_days.csv: one row per run and day, the days' frames adding up to the run's;
  // a per-day plot per group of runs.
  const auto days = ReadCsv(dir / "sweep" / "summary_days.csv");
  ASSERT_FALSE(days.empty());
  for (const auto& row : rows) {
    int frames = 0;
    for (const auto& d : days) {
      if (d.at("job") == row.at("job") && d.at("mode") == row.at("mode"))
        frames += std::stoi(d.at("frames"));
    }
    EXPECT_EQ(frames, std::stoi(row.at("frames"))) << row.at("job");
  }
  ASSERT_TRUE(fs::is_directory(dir / "sweep" / "day_plots"));
  EXPECT_FALSE(fs::is_empty(dir / "sweep" / "day_plots"));

  // Rerun: nothing to do, no marker rewritten.
  std::map<std::string, fs::file_time_type> stamps;
  for (const auto& row : rows) {
    const std::string job = row.at("job");
    stamps[job] = fs::last_write_time(dir / "sweep" / "runs" / job / "sweep_job.json");
  }
  const std::string again = RunShell(sweep, &code);
  ASSERT_EQ(code, 0) << again;
  EXPECT_NE(again.find("Nothing to be done"), std::string::npos) << again;
  for (const auto& [job, stamp] : stamps) {
    EXPECT_EQ(fs::last_write_time(dir / "sweep" / "runs" / job / "sweep_job.json"), stamp) << job;
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omnicml
