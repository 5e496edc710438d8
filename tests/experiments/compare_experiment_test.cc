// The [G] Table 1 experiment (compare_experiment.h) and the CML run (run_experiment.h)
// on short simulated runs.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/experiments/compare_experiment.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/report/report.h"

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
  EXPECT_NE(ReadTextFile(dir_ / "day2" / "config.yaml").find("mode: static"),
            std::string::npos);
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
