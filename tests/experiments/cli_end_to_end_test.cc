// End-to-end tests of the omnicml binary on a tiny simulated two-day log: run, resume,
// export, inspect, evaluate, compare, and bad input (exit code 2, no partial output).
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "omnicml/common/file_io.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/report/map_export.h"
#include "omnicml/run/run_config.h"
#include "omnicml/sim/simulator.h"
#include "testing/cli_helpers.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

constexpr int kFramesPerDay = 50;

using testing::CommandResult;
using testing::RunOmnicml;

// Files whose name marks them as temporaries of an atomic write.
std::vector<std::string> TemporaryFiles(const fs::path& dir) {
  std::vector<std::string> out;
  if (!fs::exists(dir)) return out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.find(".tmp-") != std::string::npos || name.find("omnicml-tmp-") != std::string::npos ||
        name.find(".partial-") != std::string::npos)
      out.push_back(e.path().string());
  }
  return out;
}

// Rows of frames.csv without the timing columns (which vary from run to run).
std::vector<std::string> DeterministicRows(const fs::path& csv) {
  std::ifstream in(csv);
  std::string line;
  std::getline(in, line);
  std::vector<std::string> rows;
  while (std::getline(in, line)) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) cells.push_back(cell);
    std::string row;
    for (std::size_t i = 0; i < 21 && i < cells.size(); ++i) row += cells[i] + ",";
    rows.push_back(row);
  }
  return rows;
}

class CliEndToEnd : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(testing::FreshTempDir("omnicml_cli_e2e"));
    // A tiny two-day log of the built-in home_store world (panoramas, to keep it small).
    SimulatorOptions sim;
    sim.world = "home_store";
    sim.days = 2;
    sim.frames_per_day = kFramesPerDay;
    sim.seed = 3;
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
  static std::vector<fs::path> Sessions() {
    std::vector<fs::path> s;
    for (const auto& e : fs::directory_iterator(*dir_ / "log")) {
      if (e.is_directory()) s.push_back(e.path());
    }
    std::sort(s.begin(), s.end());
    return s;
  }
  static fs::path* dir_;
};
fs::path* CliEndToEnd::dir_ = nullptr;

TEST_F(CliEndToEnd, RunWritesTheRunDirectoryAndATumTrajectory) {
  // run: every RUNDIR file exists, no temporaries remain, the TUM file matches frames.csv
  // and config.yaml loads back as the effective configuration.
  const fs::path run = Dir() / "run_all";
  const fs::path tum = Dir() / "all.tum";
  const CommandResult r =
      RunOmnicml("run " + (Dir() / "log").string() + " --out " + run.string() +
                 " --trajectory-out " + tum.string() + " --update-delay 4 --threads 2 --quiet");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* f : {"config.yaml", "frames.csv", "days.csv", "events.csv", "report.html"}) {
    EXPECT_TRUE(fs::is_regular_file(run / f)) << f;
  }
  EXPECT_TRUE(TemporaryFiles(Dir()).empty());
  EXPECT_NE(r.output.find("report.html"), std::string::npos);

  const FramesTable table = ReadFramesCsv(run / "frames.csv");
  ASSERT_EQ(table.records.size(), 2u * kFramesPerDay);
  EXPECT_EQ(table.records.back().session, 1);
  const std::vector<TimedPose> trajectory = ReadTumTrajectory(tum);
  std::vector<const FrameRecord*> with_estimate;
  for (const auto& rec : table.records) {
    if (rec.has_estimate) with_estimate.push_back(&rec);
  }
  ASSERT_EQ(trajectory.size(), with_estimate.size());
  ASSERT_FALSE(trajectory.empty());
  for (std::size_t i = 0; i < trajectory.size(); ++i) {
    EXPECT_EQ(trajectory[i].stamp_s, with_estimate[i]->stamp_s);
    EXPECT_EQ(trajectory[i].pose.x(), with_estimate[i]->estimate.x());
    EXPECT_EQ(trajectory[i].pose.y(), with_estimate[i]->estimate.y());
    EXPECT_NEAR(WrapAngle(trajectory[i].pose.z() - with_estimate[i]->estimate.z()), 0.0, 1e-9);
  }
  // Ground truth is recorded and errors are consistent with it.
  for (const auto& rec : table.records) {
    ASSERT_TRUE(rec.has_truth);
    if (rec.has_estimate) {
      EXPECT_NEAR(rec.position_error_m, (rec.estimate.head<2>() - rec.truth.head<2>()).norm(),
                  1e-9);
    }
  }
  const CmlEngineOptions loaded = LoadEngineOptionsYaml((run / "config.yaml").string());
  CmlEngineOptions expected;
  expected.update_delay_frames = 4;
  expected.threads = 2;
  EXPECT_TRUE(SameEngineOptions(loaded, expected));
}

TEST_F(CliEndToEnd, ResumeEqualsOneRunOverBothDays) {
  // Day 1 saved with --map-out, day 2 resumed with --map-in: the same estimates as one run.
  const auto sessions = Sessions();
  ASSERT_EQ(sessions.size(), 2u);
  const fs::path all = Dir() / "resume_all", day1 = Dir() / "resume_day1",
                 day2 = Dir() / "resume_day2";
  const fs::path map = Dir() / "day1.map";
  ASSERT_EQ(
      RunOmnicml("run " + (Dir() / "log").string() + " --quiet --out " + all.string()).exit_code,
      0);
  const CommandResult r1 =
      RunOmnicml("run " + sessions[0].string() + " --quiet --threads 2 --out " + day1.string() +
                 " --map-out " + map.string());
  ASSERT_EQ(r1.exit_code, 0) << r1.output;
  ASSERT_TRUE(fs::is_regular_file(map));
  const CommandResult r2 = RunOmnicml("run " + sessions[1].string() + " --quiet --out " +
                                      day2.string() + " --map-in " + map.string());
  ASSERT_EQ(r2.exit_code, 0) << r2.output;
  const auto rows_all = DeterministicRows(all / "frames.csv");
  auto rows_split = DeterministicRows(day1 / "frames.csv");
  const auto rows_day2 = DeterministicRows(day2 / "frames.csv");
  rows_split.insert(rows_split.end(), rows_day2.begin(), rows_day2.end());
  ASSERT_EQ(rows_all.size(), rows_split.size());
  for (std::size_t i = 0; i < rows_all.size(); ++i)
    EXPECT_EQ(rows_all[i], rows_split[i]) << "row " << i;
  // The same for a simulated world resumed with --first-day.
  const fs::path wall = Dir() / "world_all", w1 = Dir() / "world_day1", w2 = Dir() / "world_day2";
  const fs::path wmap = Dir() / "world_day1.map";
  const std::string world = " --world home_store --frames-per-day 30 --seed 5 --quiet ";
  ASSERT_EQ(RunOmnicml("run" + world + "--days 2 --out " + wall.string()).exit_code, 0);
  ASSERT_EQ(
      RunOmnicml("run" + world + "--days 1 --out " + w1.string() + " --map-out " + wmap.string())
          .exit_code,
      0);
  const CommandResult rw = RunOmnicml("run" + world + "--first-day 1 --days 1 --threads 1 --out " +
                                      w2.string() + " --map-in " + wmap.string());
  ASSERT_EQ(rw.exit_code, 0) << rw.output;
  auto world_split = DeterministicRows(w1 / "frames.csv");
  const auto world_day2 = DeterministicRows(w2 / "frames.csv");
  world_split.insert(world_split.end(), world_day2.begin(), world_day2.end());
  EXPECT_EQ(DeterministicRows(wall / "frames.csv"), world_split);
  // Options other than threads/forgetting cannot change on a saved map.
  const CommandResult bad =
      RunOmnicml("run " + sessions[1].string() + " --quiet --out " +
                 (Dir() / "resume_bad").string() + " --map-in " + map.string() + " --e-max 2");
  EXPECT_EQ(bad.exit_code, 2) << bad.output;
  EXPECT_FALSE(fs::exists(Dir() / "resume_bad"));
}

TEST_F(CliEndToEnd, ExportInspectAndEvaluate) {
  // export writes JSON/CSV/SVG/PNG of the saved map; inspect and evaluate summarise it.
  const fs::path run = Dir() / "run_export";
  const fs::path map = Dir() / "export.map", tum = Dir() / "export.tum";
  ASSERT_EQ(RunOmnicml("run " + (Dir() / "log").string() + " --quiet --out " + run.string() +
                       " --map-out " + map.string() + " --trajectory-out " + tum.string())
                .exit_code,
            0);
  const CommandResult json = RunOmnicml("export " + map.string() + " --format json --out " +
                                        (Dir() / "map.json").string());
  ASSERT_EQ(json.exit_code, 0) << json.output;
  std::ifstream in(Dir() / "map.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["schema"], "omnicml.map");
  EXPECT_EQ(j["schema_version"], kMapSchemaVersion);
  ASSERT_GT(j["views"].size(), 0u);
  EXPECT_EQ(j["model"]["views"].get<std::size_t>(), j["views"].size());
  std::size_t components = 0;
  for (const auto& v : j["views"]) {
    ASSERT_GT(v["components"].size(), 0u);
    components += v["components"].size();
    for (const auto& c : v["components"]) {
      EXPECT_GE(c["weight"].get<double>(), 0.0);
      EXPECT_LE(c["weight"].get<double>(), 1.0);
      EXPECT_GE(c["ellipse"]["major_m"].get<double>(), c["ellipse"]["minor_m"].get<double>());
    }
  }
  EXPECT_EQ(j["model"]["components"].get<std::size_t>(), components);

  ASSERT_EQ(
      RunOmnicml("export " + map.string() + " --out " + (Dir() / "map.csv").string()).exit_code, 0);
  std::ifstream csv(Dir() / "map.csv");
  std::string line;
  std::size_t csv_rows = 0;
  std::getline(csv, line);
  while (std::getline(csv, line)) ++csv_rows;
  EXPECT_EQ(csv_rows, components);

  ASSERT_EQ(RunOmnicml("export " + map.string() + " --format svg --out " +
                       (Dir() / "map.svg").string() + " --trajectory " + tum.string())
                .exit_code,
            0);
  std::ifstream svg_in(Dir() / "map.svg");
  const std::string svg((std::istreambuf_iterator<char>(svg_in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(svg.rfind("<svg", 0), 0u);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);
  EXPECT_NE(svg.find("<ellipse"), std::string::npos);
  EXPECT_NE(svg.find("<polyline"), std::string::npos);

  ASSERT_EQ(RunOmnicml("export " + map.string() + " --format png --out " +
                       (Dir() / "map.png").string() + " --trajectory " + tum.string())
                .exit_code,
            0);
  const cv::Mat png = cv::imread((Dir() / "map.png").string());
  EXPECT_FALSE(png.empty());

  const CommandResult inspect = RunOmnicml("inspect " + map.string());
  ASSERT_EQ(inspect.exit_code, 0) << inspect.output;
  EXPECT_NE(inspect.output.find(std::to_string(j["views"].size()) + " views"), std::string::npos)
      << inspect.output;
  EXPECT_NE(inspect.output.find("health by area"), std::string::npos);

  for (const char* align : {"none", "start", "se2"}) {
    const CommandResult eval = RunOmnicml("evaluate " + run.string() + " --align " + align);
    ASSERT_EQ(eval.exit_code, 0) << eval.output;
    EXPECT_NE(eval.output.find("alignment: " + std::string(align)), std::string::npos);
  }
  EXPECT_TRUE(fs::is_regular_file(run / "evaluation.html"));
  // Each evaluation keeps the earlier ones; --out never replaces a file without --force.
  EXPECT_TRUE(fs::is_regular_file(run / "evaluation-2.html"));
  EXPECT_TRUE(fs::is_regular_file(run / "evaluation-3.html"));
  const CommandResult eval =
      RunOmnicml("evaluate " + run.string() + " --out " + (run / "evaluation.html").string());
  EXPECT_EQ(eval.exit_code, 2) << eval.output;
  EXPECT_NE(eval.output.find("--force"), std::string::npos) << eval.output;
  const CommandResult forced = RunOmnicml("evaluate " + run.string() + " --force --out " +
                                          (run / "evaluation.html").string());
  EXPECT_EQ(forced.exit_code, 0) << forced.output;
  EXPECT_NE(forced.output.find("APE position"), std::string::npos) << forced.output;
  EXPECT_NE(forced.output.find("RPE translation"), std::string::npos) << forced.output;
  EXPECT_TRUE(TemporaryFiles(Dir()).empty());
}

TEST_F(CliEndToEnd, CompareRunsTheThreeModes) {
  // compare prints views at the steps for passive, active and static, and writes a report.
  const fs::path out = Dir() / "compare";
  const fs::path maps = Dir() / "compare_maps";
  const CommandResult r = RunOmnicml("compare " + (Dir() / "log").string() +
                                     " --quiet --jobs 3 --steps 25,50,100,1000 --out " +
                                     out.string() + " --map-out " + maps.string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // --map-out: one map per mode, each holding the views the table reports at the end.
  for (const char* mode : {"passive", "active", "static"}) {
    const fs::path map = maps / (std::string(mode) + ".omap");
    ASSERT_TRUE(fs::is_regular_file(map)) << mode;
    const std::unique_ptr<CmlEngine> engine = DecodeEngine(ReadBinaryFile(map), map.string());
    const std::string views_end = std::to_string(engine->model().NumViews());
    const auto line_start = r.output.find("\n" + std::string(mode) + " ");
    ASSERT_NE(line_start, std::string::npos) << r.output;
    const std::string line =
        r.output.substr(line_start + 1, r.output.find('\n', line_start + 1) - line_start - 1);
    std::stringstream cells(line);
    std::vector<std::string> cell{std::istream_iterator<std::string>(cells), {}};
    ASSERT_GE(cell.size(), 6u) << line;
    EXPECT_EQ(cell[5], views_end) << line;  // forgetting, 4 steps, views_end
  }
  EXPECT_TRUE(fs::is_regular_file(out / "replay.html"));
  // The modes ran in three threads; one after the other they give the same frames.
  const fs::path sequential = Dir() / "compare_sequential";
  const CommandResult r1 =
      RunOmnicml("compare " + (Dir() / "log").string() +
                 " --quiet --jobs 1 --steps 25,50,100,1000 --out " + sequential.string());
  ASSERT_EQ(r1.exit_code, 0) << r1.output;
  for (const char* mode : {"passive", "active", "static"}) {
    EXPECT_EQ(DeterministicRows(out / mode / "frames.csv"),
              DeterministicRows(sequential / mode / "frames.csv"))
        << mode;
  }
  auto slurp = [](const fs::path& p) {
    std::ifstream in(p);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  EXPECT_EQ(slurp(out / "table.txt"), slurp(sequential / "table.txt"));
  EXPECT_FALSE(slurp(out / "table.txt").empty());
  for (const char* mode : {"passive", "active", "static"}) {
    EXPECT_NE(r.output.find(mode), std::string::npos) << r.output;
    EXPECT_TRUE(fs::is_regular_file(out / mode / "frames.csv")) << mode;
  }
  EXPECT_NE(r.output.find("views@25"), std::string::npos);
  EXPECT_NE(r.output.find("odom_err_m"), std::string::npos);
  EXPECT_TRUE(fs::is_regular_file(out / "report.html"));
  // The report: the odometry-only line and day boundaries on the error plot, and the
  // three modes' maps (growth, error, histogram and 3 map pictures = 6 drawings).
  const std::string report = slurp(out / "report.html");
  EXPECT_NE(report.find("odometry only"), std::string::npos);
  EXPECT_NE(report.find(">day 2</text>"), std::string::npos);
  EXPECT_NE(report.find("Views removed per day: by active forgetting / otherwise"),
            std::string::npos);
  std::size_t drawings = 0;
  for (std::size_t p = report.find("<svg"); p != std::string::npos; p = report.find("<svg", p + 1))
    ++drawings;
  EXPECT_EQ(drawings, 6u);
  // Static freezes the map after day 1: its view count never changes on day 2.
  const FramesTable st = ReadFramesCsv(out / "static" / "frames.csv");
  int first_day2_views = -1;
  for (const auto& rec : st.records) {
    if (rec.session != 1) continue;
    if (first_day2_views < 0) first_day2_views = rec.views;
    EXPECT_EQ(rec.views, first_day2_views);
  }
}

TEST_F(CliEndToEnd, MclWritesARunDirectoryThatEvaluates) {
  // `omnicml mcl` writes the run directory of `omnicml run` (frames.csv in the same
  // format, days.csv, config, report), so `evaluate` and the tables work on the baseline too.
  const fs::path out = Dir() / "mcl";
  const CommandResult r = RunOmnicml("mcl --world home_store --days 2 --frames-per-day " +
                                     std::to_string(kFramesPerDay) +
                                     " --seed 3 --particles 2000 --out " + out.string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* f : {"frames.csv", "days.csv", "config.yaml", "report.html", "map.yaml"})
    EXPECT_TRUE(fs::is_regular_file(out / f)) << f;
  const FramesTable table = ReadFramesCsv(out / "frames.csv");
  ASSERT_EQ(table.records.size(), static_cast<std::size_t>(kFramesPerDay));
  double sum = 0.0;
  for (const auto& rec : table.records) {
    ASSERT_TRUE(rec.has_estimate && rec.has_truth);
    const double e = (rec.estimate.head<2>() - rec.truth.head<2>()).norm();
    EXPECT_NEAR(rec.position_error_m, e, 1e-9);
    sum += rec.position_error_m;
  }
  // Tracking from the known start on the day after the reference day stays well inside
  // the aisle width (measured 0.25 m mean with 5000 particles).
  EXPECT_LT(sum / table.records.size(), 1.0);
  const CommandResult eval = RunOmnicml("evaluate " + out.string());
  ASSERT_EQ(eval.exit_code, 0) << eval.output;
  EXPECT_TRUE(fs::is_regular_file(out / "evaluation.html"));

  // Bad input: a run directory that exists is not overwritten piecemeal, an unknown world
  // fails with exit code 2, and neither leaves anything behind.
  const fs::path bad = Dir() / "mcl_bad";
  const CommandResult world = RunOmnicml("mcl --world atlantis --out " + bad.string());
  EXPECT_EQ(world.exit_code, 2) << world.output;
  EXPECT_FALSE(fs::exists(bad));
  EXPECT_TRUE(TemporaryFiles(Dir()).empty());
}

TEST_F(CliEndToEnd, DescribeTakesDescriptorOptionsFromAnEngineConfig) {
  // describe --config reads the descriptor section of an engine configuration, so a user
  // can look at the distances the engine would see; --descriptor overrides the kind.
  const fs::path day1 = Sessions()[0];
  std::string images;
  for (const char* f : {"000000.png", "000001.png"}) images += " " + (day1 / f).string();
  const fs::path color = Dir() / "color.yaml", columns = Dir() / "columns.yaml",
                 bad = Dir() / "bad_descriptor.yaml";
  std::ofstream(color) << "descriptor:\n  kind: color\n";
  std::ofstream(columns) << "descriptor:\n  fourier: {normalize_columns: false}\n";
  std::ofstream(bad) << "descriptor:\n  fourier: {bandz: 3}\n";
  const CommandResult c = RunOmnicml("describe" + images + " --config " + color.string());
  ASSERT_EQ(c.exit_code, 0) << c.output;
  EXPECT_NE(c.output.find("descriptor: color"), std::string::npos) << c.output;
  const CommandResult over = RunOmnicml("describe" + images + " --config " + color.string() +
                                        " --descriptor fourier --json");
  ASSERT_EQ(over.exit_code, 0) << over.output;
  const auto with_columns = RunOmnicml("describe" + images + " --json");
  const auto without =
      RunOmnicml("describe" + images + " --config " + columns.string() + " --json");
  ASSERT_EQ(with_columns.exit_code, 0) << with_columns.output;
  ASSERT_EQ(without.exit_code, 0) << without.output;
  const auto jo = nlohmann::json::parse(over.output),
             jc = nlohmann::json::parse(with_columns.output),
             jn = nlohmann::json::parse(without.output);
  EXPECT_EQ(jo["descriptor"], "fourier");
  // The default configuration equals the built-in default; normalize_columns changes E.
  EXPECT_EQ(jo["pairs"][0]["distance"], jc["pairs"][0]["distance"]);
  EXPECT_NE(jc["pairs"][0]["distance"], jn["pairs"][0]["distance"]);
  const CommandResult b = RunOmnicml("describe" + images + " --config " + bad.string());
  EXPECT_EQ(b.exit_code, 2);
  EXPECT_NE(b.output.find("descriptor.fourier.bandz"), std::string::npos) << b.output;
}

TEST_F(CliEndToEnd, LapBoundOfAWorldRouteOrSaysWhyNot) {
  // A world's route: the closed form and the Monte Carlo; --csv holds one row per pose.
  const fs::path csv = Dir() / "lap_bound.csv";
  const CommandResult r =
      RunOmnicml("lap-bound --world institute --samples 2 --csv " + csv.string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("after the lap's closure"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("2 realisations"), std::string::npos) << r.output;
  std::ifstream in(csv);
  std::string line;
  int rows = 0;
  std::getline(in, line);
  EXPECT_EQ(line, "pose,x_m,y_m,odometry_std_m,closed_std_m");
  while (std::getline(in, line)) ++rows;
  EXPECT_GT(rows, 100);
  EXPECT_TRUE(TemporaryFiles(Dir()).empty());
  // The test log's 50 frames never come back to their start: exit 2, naming the session.
  const CommandResult no_lap = RunOmnicml("lap-bound " + (Dir() / "log").string());
  EXPECT_EQ(no_lap.exit_code, 2) << no_lap.output;
  EXPECT_NE(no_lap.output.find("session 1"), std::string::npos) << no_lap.output;
  EXPECT_NE(no_lap.output.find("does not come back"), std::string::npos) << no_lap.output;
  const CommandResult bad = RunOmnicml("lap-bound --world institute --noise 0.1,x,0,0");
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.output.find("--noise"), std::string::npos) << bad.output;
}

TEST_F(CliEndToEnd, BadInputExitsWithCodeTwoAndLeavesNothing) {
  // Unknown flags or keys, missing logs and foreign map files: exit code 2, a message
  // naming what and where, and no output files.
  const fs::path out = Dir() / "bad_run";
  const CommandResult flag =
      RunOmnicml("run " + (Dir() / "log").string() + " --bogus-flag --out " + out.string());
  EXPECT_EQ(flag.exit_code, 2);
  EXPECT_NE(flag.output.find("--bogus-flag"), std::string::npos) << flag.output;

  const fs::path config = Dir() / "bad.yaml";
  {
    std::ofstream os(config);
    os << "threads: 1\nmodel:\n  e_maxx: 3\n";
  }
  const CommandResult key = RunOmnicml("run " + (Dir() / "log").string() + " --config " +
                                       config.string() + " --out " + out.string());
  EXPECT_EQ(key.exit_code, 2);
  EXPECT_NE(key.output.find("model.e_maxx"), std::string::npos) << key.output;
  EXPECT_NE(key.output.find("bad.yaml:3"), std::string::npos) << key.output;

  const CommandResult missing =
      RunOmnicml("run " + (Dir() / "no_such_log").string() + " --out " + out.string());
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_NE(missing.output.find("no_such_log"), std::string::npos) << missing.output;

  const CommandResult world = RunOmnicml("run --world atlantis --out " + out.string());
  EXPECT_EQ(world.exit_code, 2);
  EXPECT_NE(world.output.find("atlantis"), std::string::npos);

  // A map of another format version, and a truncated map.
  const fs::path foreign = Dir() / "foreign.map";
  {
    std::ofstream os(foreign, std::ios::binary);
    os.write("OMNICML\0", 8);
    const unsigned char version[4] = {99, 0, 0, 0};
    os.write(reinterpret_cast<const char*>(version), 4);
    const unsigned char zeros[12] = {};
    os.write(reinterpret_cast<const char*>(zeros), 12);
  }
  const CommandResult version = RunOmnicml("inspect " + foreign.string());
  EXPECT_EQ(version.exit_code, 2);
  EXPECT_NE(version.output.find("version"), std::string::npos) << version.output;
  const CommandResult resume =
      RunOmnicml("run " + (Dir() / "log").string() + " --map-in " + foreign.string() + " --out " +
                 out.string() + " --map-out " + (Dir() / "never.map").string());
  EXPECT_EQ(resume.exit_code, 2);
  const CommandResult exported =
      RunOmnicml("export " + foreign.string() + " --out " + (Dir() / "never.json").string());
  EXPECT_EQ(exported.exit_code, 2);
  const CommandResult format =
      RunOmnicml("export " + foreign.string() + " --out " + (Dir() / "never.xyz").string());
  EXPECT_EQ(format.exit_code, 2);
  const CommandResult align = RunOmnicml("evaluate " + Dir().string() + " --align affine");
  EXPECT_EQ(align.exit_code, 2);
  const CommandResult not_run = RunOmnicml("evaluate " + Dir().string());
  EXPECT_EQ(not_run.exit_code, 2);
  EXPECT_NE(not_run.output.find("frames.csv"), std::string::npos);

  // A log that breaks in the middle of day 2: the run fails after writing part of its
  // output, and every partial file is removed again.
  const fs::path broken = Dir() / "broken_log";
  fs::copy(Dir() / "log", broken, fs::copy_options::recursive);
  const auto sessions = Sessions();
  {
    std::ofstream os(broken / sessions[1].filename() / "frames.csv", std::ios::app);
    os << "not,a,valid,row\n";
  }
  const CommandResult midway = RunOmnicml(
      "run " + broken.string() + " --quiet --out " + out.string() + " --map-out " +
      (Dir() / "never.map").string() + " --trajectory-out " + (Dir() / "never.tum").string());
  EXPECT_EQ(midway.exit_code, 2) << midway.output;
  EXPECT_NE(midway.output.find("frames.csv:" + std::to_string(kFramesPerDay + 2)),
            std::string::npos)
      << midway.output;
  EXPECT_FALSE(fs::exists(Dir() / "never.tum"));

  // Every error message is a single line.
  for (const CommandResult* r :
       {&key, &missing, &world, &version, &resume, &exported, &format, &align, &not_run, &midway}) {
    EXPECT_EQ(std::count(r->output.begin(), r->output.end(), '\n'), 1) << r->output;
  }
  EXPECT_FALSE(fs::exists(out));
  EXPECT_FALSE(fs::exists(Dir() / "never.map"));
  EXPECT_FALSE(fs::exists(Dir() / "never.json"));
  EXPECT_TRUE(TemporaryFiles(Dir()).empty());
}

// --survey-days on a log: day 1 is mapped from the log's ground truth and left out of
// the errors (the output says so); a bad --survey-poses line fails before any output
// with file:line and exit code 2.
TEST_F(CliEndToEnd, SurveyDaysFromGroundTruthAndTumErrors) {
  const fs::path out = Dir() / "survey_run";
  const CommandResult ok = RunOmnicml("run " + (Dir() / "log").string() +
                                      " --survey-days 1 --quiet --threads 1 --out " + out.string());
  ASSERT_EQ(ok.exit_code, 0) << ok.output;
  EXPECT_NE(ok.output.find("survey day 1 (" + std::to_string(kFramesPerDay) +
                           " frames) excluded from the errors"),
            std::string::npos)
      << ok.output;

  const fs::path tum = Dir() / "bad_survey.tum";
  {
    std::ofstream os(tum);
    os << "# stamp x y z qx qy qz qw\n0 1 2 0 0 0 0 1\n0.5 1 2 0\n";
  }
  const fs::path bad_out = Dir() / "survey_bad";
  const CommandResult bad =
      RunOmnicml("run " + (Dir() / "log").string() + " --survey-days 1 --survey-poses " +
                 tum.string() + " --out " + bad_out.string());
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.output.find(tum.string() + ":3: expected 8 numbers"), std::string::npos)
      << bad.output;
  EXPECT_FALSE(fs::exists(bad_out));
}

}  // namespace
}  // namespace omnicml
