// The [G] Table 1 experiment (compare_experiment.h) and the CML run (run_experiment.h)
// on short simulated runs.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/experiments/compare_experiment.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/report/report.h"
#include "omnicml/run/run_config.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

class CompareExperimentTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           StrCat("omnicml_compare_experiment_", ::testing::UnitTest::GetInstance()->random_seed(),
                  "_", ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Two days of home_store, 150 frames each, quiet.
  static RunSettings ShortRun(const fs::path& out) {
    RunSettings s;
    s.input.world = "home_store";
    s.input.days = 2;
    s.input.frames_per_day = 150;
    s.input.seed = 1;
    s.overrides.threads = 1;
    s.out_dir = out.string();
    s.quiet = true;
    return s;
  }

  fs::path dir_;
};

// Same frames, same estimates, same map sizes; stage timings excluded.
void ExpectSameRecords(const std::vector<FrameRecord>& a, const std::vector<FrameRecord>& b) {
  ASSERT_EQ(a.size(), b.size());
  auto same = [](double x, double y) { return (std::isnan(x) && std::isnan(y)) || x == y; };
  for (std::size_t i = 0; i < a.size(); ++i) {
    SCOPED_TRACE(StrCat("frame ", i));
    EXPECT_EQ(a[i].global_frame, b[i].global_frame);
    EXPECT_EQ(a[i].has_estimate, b[i].has_estimate);
    for (int k = 0; k < 3; ++k) EXPECT_TRUE(same(a[i].estimate[k], b[i].estimate[k]));
    EXPECT_TRUE(same(a[i].position_error_m, b[i].position_error_m));
    EXPECT_EQ(a[i].unimodal, b[i].unimodal);
    EXPECT_EQ(a[i].views, b[i].views);
    EXPECT_EQ(a[i].map_components, b[i].map_components);
    EXPECT_EQ(a[i].mixture_components, b[i].mixture_components);
  }
}

TEST_F(CompareExperimentTest, ParallelJobsGiveTheResultsOfOneAfterTheOther) {
  // --jobs 3 (one thread per mode) and --jobs 1: the same table, records, map events and
  // configurations.
  CompareExperimentOptions sequential;
  sequential.settings = ShortRun(dir_ / "jobs1");
  sequential.steps = {100, 200, 300};
  sequential.jobs = 1;
  CompareExperimentOptions parallel = sequential;
  parallel.settings.out_dir = (dir_ / "jobs3").string();
  parallel.jobs = 3;
  const CompareExperimentResult a = RunCompareExperiment(sequential);
  const CompareExperimentResult b = RunCompareExperiment(parallel);

  EXPECT_EQ(a.table_text, b.table_text);
  EXPECT_EQ(ReadTextFile(dir_ / "jobs1" / "table.txt"), ReadTextFile(dir_ / "jobs3" / "table.txt"));
  ASSERT_EQ(a.modes.size(), 3u);
  ASSERT_EQ(b.modes.size(), 3u);
  for (std::size_t m = 0; m < 3; ++m) {
    SCOPED_TRACE(a.modes[m].mode);
    EXPECT_EQ(a.modes[m].mode, b.modes[m].mode);
    ExpectSameRecords(a.modes[m].records, b.modes[m].records);
    EXPECT_EQ(a.modes[m].final_views, b.modes[m].final_views);
    for (const char* file : {"events.csv", "config.yaml"}) {
      EXPECT_EQ(ReadTextFile(dir_ / "jobs1" / a.modes[m].mode / file),
                ReadTextFile(dir_ / "jobs3" / b.modes[m].mode / file))
          << file;
    }
  }
}

TEST_F(CompareExperimentTest, StaticLearnsDayOneLikeActiveThenStopsChangingTheMap) {
  // static is active on day 1 (same frames, same records), then frozen: after the
  // queued updates of day 1 have landed, its map never changes size again.
  CompareExperimentOptions options;
  options.settings = ShortRun(dir_ / "cmp");
  options.steps = {150};
  options.jobs = 1;
  const CompareExperimentResult r = RunCompareExperiment(options);
  ASSERT_EQ(r.modes.size(), 3u);
  const CompareModeResult& active = r.modes[1];
  const CompareModeResult& frozen = r.modes[2];
  ASSERT_EQ(active.mode, "active");
  ASSERT_EQ(frozen.mode, "static");
  const std::vector<FrameRecord> day1_active(active.records.begin(), active.records.begin() + 150);
  const std::vector<FrameRecord> day1_static(frozen.records.begin(), frozen.records.begin() + 150);
  ExpectSameRecords(day1_active, day1_static);
  ASSERT_EQ(frozen.records.size(), 300u);
  const int settled = frozen.records[150 + 20].views;  // update_delay_frames (8) later
  EXPECT_GT(settled, 0);
  for (std::size_t i = 150 + 20; i < frozen.records.size(); ++i) {
    EXPECT_EQ(frozen.records[i].views, settled) << "frame " << i;
  }
  EXPECT_EQ(frozen.final_views, settled);
  // The table names the three modes in order, one row each.
  EXPECT_NE(r.table_text.find("passive"), std::string::npos);
  EXPECT_LT(r.table_text.find("passive"), r.table_text.find("static"));
}

TEST_F(CompareExperimentTest, BadStepsAndInputAreErrorsThatLeaveNothing) {
  // Validation happens before any output is created.
  EXPECT_THROW(ParseSteps("100,x"), Error);
  EXPECT_THROW(ParseSteps(""), Error);
  EXPECT_EQ(ParseSteps("5,10"), (std::vector<std::int64_t>{5, 10}));
  CompareExperimentOptions options;
  options.settings = ShortRun(dir_ / "bad");
  options.settings.input.world = "atlantis";
  EXPECT_THROW(RunCompareExperiment(options), Error);
  EXPECT_FALSE(fs::exists(dir_ / "bad"));
}

// The in-memory study of ShortRun's input: two days of home_store, 150 frames each.
RunInput ShortInput() {
  RunInput in;
  in.world = "home_store";
  in.days = 2;
  in.frames_per_day = 150;
  in.seed = 1;
  return in;
}

CmlEngineOptions OneThread() {
  CmlEngineOptions o;
  o.threads = 1;
  return o;
}

std::vector<std::uint8_t> ReadBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

TEST_F(CompareExperimentTest, InMemoryResultsEqualWhatTheWrittenDirectoryHolds) {
  // RunCompare without outputs returns what the same study writes when asked: each
  // mode's records are its frames.csv, its evaluation that of frames.csv, views_at_steps
  // the table's columns, the table is table.txt, the engine is <mode>.omap.
  CompareSettings memory;
  memory.steps = {100, 200, 400};
  memory.jobs = 1;
  memory.keep_engines = true;
  CompareSettings written = memory;
  written.keep_engines = false;
  written.jobs = 3;
  written.outputs.out_dir = dir_ / "cmp";
  written.outputs.map_out_dir = dir_ / "maps";
  const CompareExperimentResult a = RunCompare(OneThread(), ShortInput(), memory);
  const CompareExperimentResult b = RunCompare(OneThread(), ShortInput(), written);

  EXPECT_EQ(a.out_dir, "");
  EXPECT_EQ(b.out_dir, (dir_ / "cmp").string());
  EXPECT_EQ(a.table_text, b.table_text);
  EXPECT_EQ(a.table_text, ReadTextFile(dir_ / "cmp" / "table.txt"));
  ASSERT_EQ(a.modes.size(), 3u);
  ASSERT_EQ(b.modes.size(), 3u);
  for (std::size_t m = 0; m < 3; ++m) {
    const CompareModeResult& r = a.modes[m];
    SCOPED_TRACE(r.mode);
    EXPECT_EQ(r.mode, b.modes[m].mode);
    ExpectSameRecords(r.records, b.modes[m].records);
    const FramesTable csv = ReadFramesCsv(dir_ / "cmp" / r.mode / "frames.csv");
    ExpectSameRecords(r.records, csv.records);
    const EvaluationResult from_csv = Evaluate(csv, Alignment::kNone);
    EXPECT_EQ(r.evaluation.overall.frames, from_csv.overall.frames);
    EXPECT_EQ(r.evaluation.overall.position_m.mean, from_csv.overall.position_m.mean);
    EXPECT_EQ(r.evaluation.overall.coverage, from_csv.overall.coverage);
    ASSERT_EQ(r.evaluation.days.size(), from_csv.days.size());
    for (std::size_t d = 0; d < r.evaluation.days.size(); ++d) {
      EXPECT_EQ(r.evaluation.days[d].position_m.max, from_csv.days[d].position_m.max);
      EXPECT_EQ(r.evaluation.days[d].views_at_end, from_csv.days[d].views_at_end);
    }
    // views@100, views@200 from the records; 400 is beyond the 300 frames.
    EXPECT_EQ(r.views_at_steps, (std::vector<int>{r.records[99].views, r.records[199].views, -1}));
    EXPECT_EQ(r.views_removed_by_session, b.modes[m].views_removed_by_session);
    EXPECT_EQ(r.map_svg, b.modes[m].map_svg);
    // The engine after Finish, byte for byte the saved map; only when asked.
    ASSERT_NE(r.engine, nullptr);
    EXPECT_EQ(b.modes[m].engine, nullptr);
    EXPECT_EQ(static_cast<int>(r.engine->model().NumViews()), r.final_views);
    EXPECT_EQ(EncodeEngine(*r.engine), ReadBytes(dir_ / "maps" / (r.mode + ".omap")));
    // Each mode ran with the study's options, forgetting set by the mode (static: learnt
    // actively, then frozen).
    const ForgettingMode mode = ForgettingModeFromString(r.mode);
    CmlEngineOptions expected = CompareModeOptions(OneThread(), mode);
    EXPECT_EQ(expected.model.forgetting.mode,
              mode == ForgettingMode::kStatic ? ForgettingMode::kActive : mode);
    expected.model.forgetting.mode = mode;
    EXPECT_TRUE(SameEngineOptions(expected, r.engine->options()));
    EXPECT_NE(ReadTextFile(dir_ / "cmp" / r.mode / "config.yaml").find("mode: " + r.mode),
              std::string::npos);
  }
  EXPECT_EQ(FormatCompareExperimentResult(a).find("report:"), std::string::npos);
  EXPECT_NE(FormatCompareExperimentResult(b).find("report:"), std::string::npos);
}

TEST_F(CompareExperimentTest, InMemoryStudyWritesNothingWhenNotAsked) {
  // Without outputs, no file or directory appears (run in an empty working directory,
  // where the command's default runs/ would go); bad settings are errors before any run.
  const fs::path cwd = fs::current_path();
  fs::create_directories(dir_ / "cwd");
  fs::current_path(dir_ / "cwd");
  CompareSettings settings;
  settings.steps = {50};
  settings.jobs = 2;
  RunInput input = ShortInput();
  input.days = 1;
  input.frames_per_day = 60;
  const CompareExperimentResult r = RunCompare(OneThread(), input, settings);
  fs::current_path(cwd);
  EXPECT_TRUE(fs::is_empty(dir_ / "cwd"));
  ASSERT_EQ(r.modes.size(), 3u);
  for (const CompareModeResult& m : r.modes) {
    EXPECT_EQ(m.records.size(), 60u);
    EXPECT_EQ(m.engine, nullptr);
  }
  CompareSettings bad = settings;
  bad.steps = {0};
  EXPECT_THROW(RunCompare(OneThread(), input, bad), Error);
  bad = settings;
  bad.progress.log_every_frames = 0;
  EXPECT_THROW(RunCompare(OneThread(), input, bad), Error);
  CmlEngineOptions bad_options = OneThread();
  bad_options.threads = 0;
  bad = settings;
  bad.outputs.out_dir = dir_ / "never";
  EXPECT_THROW(RunCompare(bad_options, input, bad), Error);
  EXPECT_FALSE(fs::exists(dir_ / "never"));
}

TEST_F(CompareExperimentTest, ResumingWithStaticForgettingFreezesTheSavedMap) {
  // run day 1 with --map-out, then day 2 from it with --forgetting static
  // (CmlEngine::SetForgettingMode): Update never changes a static model, so the second
  // run ends with exactly the views of the saved map (its queued updates are dropped by
  // the static rules too), and its configuration records the mode.
  RunExperimentOptions first;
  first.settings = ShortRun(dir_ / "day1");
  first.settings.input.days = 1;
  first.map_out = (dir_ / "day1.omap").string();
  const RunExperimentResult r1 = RunExperiment(first);
  EXPECT_EQ(r1.summary.frames, 150);
  ASSERT_TRUE(fs::exists(first.map_out));

  RunExperimentOptions second;
  second.settings = ShortRun(dir_ / "day2");
  second.settings.input.days = 1;
  second.settings.input.first_day = 1;
  second.settings.overrides.forgetting = "static";
  second.map_in = first.map_out;
  const RunExperimentResult r2 = RunExperiment(second);
  EXPECT_EQ(r2.summary.frames, 150);
  const std::size_t saved_views = LoadEngine(first.map_out)->model().NumViews();
  EXPECT_GT(saved_views, 0u);
  EXPECT_EQ(r2.views, saved_views);
  EXPECT_NE(ReadTextFile(dir_ / "day2" / "config.yaml").find("mode: static"), std::string::npos);
  // Change detection (change_detection.h): not scored on the map's first day; the resumed
  // run scores simulated day 2 (its first_day + 1) against the day-2 events, in the
  // result and in change_detection.csv.
  EXPECT_TRUE(r1.change_detection.empty());
  ASSERT_EQ(r2.change_detection.size(), 1u);
  const ChangeDetectionDay& cd = r2.change_detection[0];
  EXPECT_EQ(cd.day, 2);
  EXPECT_GT(cd.cells_scored, 0);
  for (const ChangeScore* s : {&cd.visible, &cd.geometric}) {
    EXPECT_LE(s->true_positives, std::min(cd.cells_detected, s->truly_changed));
    EXPECT_LE(s->truly_changed, cd.cells_scored);
  }
  EXPECT_LE(cd.cells_detected, cd.cells_scored);
  EXPECT_EQ(cd.cells_detected, 0) << "a static map inserts and removes nothing";
  const std::string csv = ReadTextFile(dir_ / "day2" / "change_detection.csv");
  EXPECT_EQ(csv.rfind("day,session,changed_items,", 0), 0u) << csv;
  EXPECT_NE(csv.find("\n2,"), std::string::npos) << csv;

  // Anything but threads and forgetting may not change on a saved engine.
  RunExperimentOptions bad = second;
  bad.settings.out_dir = (dir_ / "bad").string();
  bad.settings.overrides.e_max = 0.3;
  EXPECT_THROW(RunExperiment(bad), Error);
  EXPECT_FALSE(fs::exists(dir_ / "bad"));
}

}  // namespace
}  // namespace omnicml
