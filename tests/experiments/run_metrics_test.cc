// Honest run metrics (coverage next to every error, skipped unreadable frames) and the
// evo-ready TUM files of a run directory (run_recorder.h, evaluation.h).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/compare_experiment.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/report/map_export.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

constexpr int kFramesPerDay = 150;

std::vector<std::string> SplitLine(const std::string& line) {
  std::vector<std::string> cells;
  std::stringstream ss(line);
  std::string cell;
  while (std::getline(ss, cell, ',')) cells.push_back(cell);
  if (!line.empty() && line.back() == ',') cells.push_back("");
  return cells;
}

// days.csv as one map column -> value per row.
std::vector<std::map<std::string, std::string>> ReadDays(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  std::getline(in, line);
  const std::vector<std::string> header = SplitLine(line);
  std::vector<std::map<std::string, std::string>> rows;
  while (std::getline(in, line)) {
    const std::vector<std::string> cells = SplitLine(line);
    EXPECT_EQ(cells.size(), header.size()) << line;
    std::map<std::string, std::string> row;
    for (std::size_t i = 0; i < header.size() && i < cells.size(); ++i) row[header[i]] = cells[i];
    rows.push_back(row);
  }
  return rows;
}

// Lines of a TUM file that are not comments.
std::vector<std::vector<std::string>> TumRows(const fs::path& path) {
  std::ifstream in(path);
  std::vector<std::vector<std::string>> rows;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::stringstream ss(line);
    std::vector<std::string> cells;
    std::string c;
    while (ss >> c) cells.push_back(c);
    EXPECT_EQ(cells.size(), 8u) << line;
    rows.push_back(cells);
  }
  return rows;
}

class RunMetricsTest : public ::testing::Test {
 protected:
  // A two-day home_store log whose days both start at stamp 0 (as two separately
  // imported days would); day 2 starts globally, so its first frames have no estimate
  // until p(x|y) seeds the tracker. One NaN row is inserted in day 2.
  static void SetUpTestSuite() {
    dir_ = new fs::path(fs::temp_directory_path() / StrCat("omnicml_run_metrics_", ::getpid()));
    fs::remove_all(*dir_);
    fs::create_directories(*dir_);
    SimulatorOptions sim;
    sim.world = "home_store";
    sim.days = 2;
    sim.frames_per_day = kFramesPerDay;
    sim.seed = 2;
    sim.output = ImageKind::kPanorama;
    sim.later_days_start = SessionStartMode::kGlobal;
    SimulatedFrameSource source(sim);
    LogWriter writer((*dir_ / "log").string());
    Frame frame;
    int session = -1;
    double start = 0;
    while (source.Next(&frame)) {
      if (frame.session_index != session) {
        session = frame.session_index;
        SessionInfo info = source.Session(session);
        start = info.start_time_s;
        info.start_time_s = 0;
        writer.BeginSession(info);
      }
      frame.stamp_s -= start;
      writer.Write(frame);
    }
    writer.Finish();
    // An unreadable row (NaN odometry) in the middle of day 2.
    std::vector<fs::path> days;
    for (const auto& e : fs::directory_iterator(*dir_ / "log")) {
      if (e.is_directory()) days.push_back(e.path());
    }
    std::sort(days.begin(), days.end());
    ASSERT_EQ(days.size(), 2u);
    const fs::path csv = days[1] / "frames.csv";
    std::vector<std::string> lines;
    {
      std::ifstream in(csv);
      std::string line;
      while (std::getline(in, line)) lines.push_back(line);
    }
    std::vector<std::string> bad = SplitLine(lines[10]);
    bad[2] = "nan";
    std::string bad_line;
    for (std::size_t i = 0; i < bad.size(); ++i) bad_line += (i ? "," : "") + bad[i];
    lines.insert(lines.begin() + 11, bad_line);
    std::ofstream out(csv, std::ios::trunc);
    for (const auto& l : lines) out << l << "\n";
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
  }
  static RunSettings Settings(const fs::path& out) {
    RunSettings s;
    s.input.log_dirs = {(*dir_ / "log").string()};
    s.input.skip_unreadable_frames = true;
    s.overrides.threads = 1;
    s.out_dir = out.string();
    s.quiet = true;
    return s;
  }
  static fs::path* dir_;
};
fs::path* RunMetricsTest::dir_ = nullptr;

TEST_F(RunMetricsTest, DaysCsvCountsUnlocalizedAndSkippedFramesNextToTheError) {
  // Day 2 (global start) has frames without an estimate: coverage < 1, localized +
  // unlocalized = frames, the mean error is that of the localized frames, and the NaN
  // row is counted as skipped (in days.csv, the evaluation and the printed summary).
  RunExperimentOptions o;
  o.settings = Settings(*dir_ / "run");
  const RunExperimentResult r = RunExperiment(o);
  EXPECT_EQ(r.summary.frames, 2 * kFramesPerDay);
  EXPECT_EQ(r.summary.frames_skipped, 1);
  EXPECT_LT(r.summary.frames_localized, r.summary.frames);

  const FramesTable table = ReadFramesCsv(*dir_ / "run" / "frames.csv");
  ASSERT_EQ(table.records.size(), 2u * kFramesPerDay);
  const auto days = ReadDays(*dir_ / "run" / "days.csv");
  ASSERT_EQ(days.size(), 2u);
  for (int d = 0; d < 2; ++d) {
    SCOPED_TRACE(StrCat("day ", d + 1));
    int localized = 0;
    double sum = 0;
    int with_error = 0;
    for (const FrameRecord& rec : table.records) {
      if (rec.session != d) continue;
      if (rec.has_estimate) ++localized;
      if (std::isfinite(rec.position_error_m)) {
        sum += rec.position_error_m;
        ++with_error;
      }
    }
    const auto& row = days[static_cast<std::size_t>(d)];
    EXPECT_EQ(std::stoi(row.at("frames")), kFramesPerDay);
    EXPECT_EQ(std::stoi(row.at("frames_localized")), localized);
    EXPECT_EQ(std::stoi(row.at("frames_localized")) + std::stoi(row.at("frames_unlocalized")),
              std::stoi(row.at("frames")));
    EXPECT_DOUBLE_EQ(std::stod(row.at("coverage")), static_cast<double>(localized) / kFramesPerDay);
    EXPECT_EQ(std::stoi(row.at("frames_skipped")), d == 1 ? 1 : 0);
    ASSERT_GT(with_error, 0);
    EXPECT_NEAR(std::stod(row.at("position_error_mean_m")), sum / with_error, 1e-12);
    EXPECT_EQ(r.evaluation.days[static_cast<std::size_t>(d)].frames_with_estimate, localized);
  }
  EXPECT_EQ(std::stod(days[0].at("coverage")), 1.0);  // known start
  EXPECT_LT(std::stod(days[1].at("coverage")), 1.0);  // global start: not at once
  EXPECT_EQ(r.evaluation.overall.frames_skipped, 1);
  EXPECT_EQ(r.evaluation.overall.frames_with_estimate + r.evaluation.overall.frames_unlocalized,
            r.evaluation.overall.frames);

  // The printed summary and table name coverage and the skipped frame.
  const std::string text = FormatRunExperimentResult(o, r);
  EXPECT_NE(text.find("coverage%"), std::string::npos) << text;
  EXPECT_NE(text.find("1 unreadable input frames skipped"), std::string::npos) << text;
  EXPECT_NE(text.find("% coverage"), std::string::npos) << text;
  // evaluate reads the skipped count back from days.csv.
  FramesTable with_skipped = table;
  ReadSkippedFrames(*dir_ / "run" / "days.csv", &with_skipped);
  EXPECT_EQ(with_skipped.skipped_frames, (std::map<int, std::int64_t>{{1, 1}}));
  const std::string html = ReadTextFile(*dir_ / "run" / "report.html");
  EXPECT_NE(html.find("coverage"), std::string::npos);
}

TEST_F(RunMetricsTest, ConsistencyMetricsReachDaysCsvAndReports) {
  // NEES and NIS per day in days.csv equal the evaluation of frames.csv; the NIS is set
  // exactly on frames whose appearance fix was computed (a prior and p(x|y)), and the
  // console summary and the HTML report carry the consistency table and the NEES plot.
  RunExperimentOptions o;
  o.settings = Settings(*dir_ / "nees");
  const RunExperimentResult r = RunExperiment(o);
  const FramesTable table = ReadFramesCsv(*dir_ / "nees" / "frames.csv");
  const auto days = ReadDays(*dir_ / "nees" / "days.csv");
  ASSERT_EQ(days.size(), 2u);
  int with_nis = 0;
  for (const FrameRecord& rec : table.records) {
    if (std::isfinite(rec.nis)) {
      ++with_nis;
      EXPECT_GE(rec.nis, 0.0);
      EXPECT_TRUE(std::isfinite(rec.prior_nees_xy));  // the fix had a prior
    }
  }
  EXPECT_GT(with_nis, 0);
  for (int d = 0; d < 2; ++d) {
    SCOPED_TRACE(StrCat("day ", d + 1));
    const DayEvaluation& e = r.evaluation.days[static_cast<std::size_t>(d)];
    const auto& row = days[static_cast<std::size_t>(d)];
    EXPECT_GT(e.nees_xy.count, 0);
    EXPECT_EQ(std::stoi(row.at("nees_xy_frames")), e.nees_xy.count);
    EXPECT_DOUBLE_EQ(std::stod(row.at("nees_xy_median")), e.nees_xy.median);
    EXPECT_DOUBLE_EQ(std::stod(row.at("nees_phi_p95")), e.nees_phi.p95);
    EXPECT_EQ(std::stoi(row.at("nis_frames")), e.nis.count);
  }
  const std::string text = FormatRunExperimentResult(o, r);
  EXPECT_NE(text.find("position NEES"), std::string::npos) << text;
  EXPECT_NE(text.find("heading NEES"), std::string::npos) << text;
  const std::string html = ReadTextFile(*dir_ / "nees" / "report.html");
  EXPECT_NE(html.find("Position NEES over the run"), std::string::npos);
  EXPECT_NE(html.find("95 % band"), std::string::npos);
}

TEST_F(RunMetricsTest, TumFilesShareIncreasingRunStampsAndMatchFramesCsv) {
  // trajectory.tum, groundtruth.tum and odometry.tum: equal line counts, identical stamp
  // columns, strictly increasing over both days (which both start at 0), the localized
  // frames only; ground truth and estimate equal frames.csv.
  RunExperimentOptions o;
  o.settings = Settings(*dir_ / "tum");
  o.trajectory_out = (*dir_ / "tum_out.tum").string();
  RunExperiment(o);
  const fs::path run = *dir_ / "tum";
  const auto est = TumRows(run / "trajectory.tum");
  const auto gt = TumRows(run / "groundtruth.tum");
  const auto odo = TumRows(run / "odometry.tum");
  const FramesTable table = ReadFramesCsv(run / "frames.csv");
  std::vector<const FrameRecord*> localized;
  for (const FrameRecord& rec : table.records) {
    if (rec.has_estimate) localized.push_back(&rec);
  }
  ASSERT_EQ(est.size(), localized.size());
  ASSERT_EQ(gt.size(), est.size());
  ASSERT_EQ(odo.size(), est.size());
  for (std::size_t i = 0; i < est.size(); ++i) {
    EXPECT_EQ(est[i][0], gt[i][0]);
    EXPECT_EQ(est[i][0], odo[i][0]);
    if (i > 0) {
      EXPECT_GT(std::stod(est[i][0]), std::stod(est[i - 1][0])) << "line " << i;
    }
  }
  // The raw stamps repeat over the two days; frames.csv keeps them and adds run stamps.
  EXPECT_EQ(table.records.front().stamp_s, 0.0);
  EXPECT_EQ(table.records[kFramesPerDay].stamp_s, 0.0);
  EXPECT_GT(table.records[kFramesPerDay].run_stamp_s, table.records[kFramesPerDay - 1].run_stamp_s);
  const std::vector<TimedPose> truth = ReadTumTrajectory(run / "groundtruth.tum");
  const std::vector<TimedPose> estimate = ReadTumTrajectory(run / "trajectory.tum");
  const std::vector<TimedPose> odometry = ReadTumTrajectory(run / "odometry.tum");
  for (std::size_t i = 0; i < localized.size(); ++i) {
    const FrameRecord& rec = *localized[i];
    ASSERT_TRUE(rec.has_truth);
    EXPECT_EQ(truth[i].stamp_s, rec.run_stamp_s);
    EXPECT_EQ(truth[i].pose.x(), rec.truth.x());
    EXPECT_EQ(truth[i].pose.y(), rec.truth.y());
    EXPECT_NEAR(WrapAngle(truth[i].pose.z() - rec.truth.z()), 0.0, 1e-9);
    EXPECT_EQ(estimate[i].pose.x(), rec.estimate.x());
    EXPECT_EQ(odometry[i].pose.x(), rec.odometry.x());
  }
  // --trajectory-out is the same estimate on the same stamps.
  EXPECT_EQ(TumRows(o.trajectory_out), est);
}

TEST_F(RunMetricsTest, CompareTableGainsCoverageAndEveryModeWritesTumFiles) {
  // The compare table ends in coverage% and min_day_coverage% (day 2 < 100 %), and each
  // mode's run directory holds the three TUM files.
  CompareExperimentOptions o;
  o.settings = Settings(*dir_ / "cmp");
  o.steps = {30, 90};
  o.jobs = 1;
  const CompareExperimentResult r = RunCompareExperiment(o);
  EXPECT_NE(r.table_text.find("coverage%"), std::string::npos) << r.table_text;
  EXPECT_NE(r.table_text.find("min_day_coverage%"), std::string::npos) << r.table_text;
  for (const CompareModeResult& m : r.modes) {
    SCOPED_TRACE(m.mode);
    EXPECT_LT(m.evaluation.overall.coverage, 1.0);
    EXPECT_EQ(m.evaluation.overall.frames_skipped, 1);
    for (const char* f : {"trajectory.tum", "groundtruth.tum", "odometry.tum"}) {
      EXPECT_TRUE(fs::is_regular_file(*dir_ / "cmp" / m.mode / f)) << f;
    }
    EXPECT_EQ(TumRows(*dir_ / "cmp" / m.mode / "trajectory.tum").size(),
              static_cast<std::size_t>(m.evaluation.overall.frames_with_estimate));
  }
  EXPECT_NE(FormatCompareExperimentResult(r).find("1 unreadable frames skipped"),
            std::string::npos);
}

}  // namespace
}  // namespace omnicml
