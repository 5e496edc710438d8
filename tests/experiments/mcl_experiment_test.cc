// The [W] Monte Carlo localization experiments (mcl_experiment.h) on a short simulated
// run: result structure, determinism, the run directory.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/experiments/mcl_experiment.h"
#include "omnicml/report/report.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

class MclExperimentTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { prepared_ = new MclPrepared(PrepareMclExperiment(Options())); }
  static void TearDownTestSuite() { delete prepared_; }

  // Two days of home_store, 120 frames each, 500 particles.
  static MclExperimentOptions Options() {
    MclExperimentOptions o;
    o.world = "home_store";
    o.days = 2;
    o.frames_per_day = 120;
    o.seed = 3;
    o.particles = 500;
    o.runs = 2;
    return o;
  }

  static std::size_t Lines(const std::string& text) {
    return static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n'));
  }

  // An empty directory under the system's temporary directory, unique per test program
  // run (gtest's random seed).
  static fs::path FreshDir(const std::string& name) {
    const fs::path dir =
        fs::temp_directory_path() /
        StrCat("omnicml_mcl_", name, "_", ::testing::UnitTest::GetInstance()->random_seed());
    fs::remove_all(dir);
    fs::create_directories(dir);
    return dir;
  }

  static inline MclPrepared* prepared_ = nullptr;
};

TEST_F(MclExperimentTest, PreparationTakesReferencesFromTheTrainingDayAndQueriesTheTestDay) {
  // Every ref_every-th frame of day 1 is a reference; every frame of day 2 a query.
  EXPECT_EQ(prepared_->refs.size(), 60u);
  ASSERT_EQ(prepared_->test.size(), 120u);
  for (const MclFrame& f : prepared_->test) EXPECT_EQ(f.session, 1);
  EXPECT_EQ(prepared_->options.num_particles, 500);
  // The world's own grid holds every true position in a free cell.
  EXPECT_EQ(prepared_->refs_not_free, 0);
  EXPECT_EQ(prepared_->test_not_free, 0);
  EXPECT_EQ(Lines(DescribeMclPrepared(*prepared_)), 2u);
}

TEST_F(MclExperimentTest, MapThatIsNotTheInputsIsRejectedNamingMapAndFrame) {
  // home_store is 25 m x 10 m; a 10 m x 15 m grid (institute's size) cannot hold its
  // route. Without the check the filter ran and reported errors of metres.
  const fs::path dir = FreshDir("wrong_map");
  const std::string yaml = (dir / "small.yaml").string();
  SaveOccupancyGrid(OccupancyGrid(100, 150, 0.1, Eigen::Vector2d::Zero()), yaml);
  MclExperimentOptions o = Options();
  o.map_yaml = yaml;
  std::string what;
  try {
    PrepareMclExperiment(o);
  } catch (const Error& e) {
    what = e.what();
  }
  EXPECT_NE(what.find(yaml), std::string::npos) << what;
  EXPECT_NE(what.find("lies outside the map"), std::string::npos) << what;
  EXPECT_NE(what.find("day 1 frame"), std::string::npos) << what;
  // The same grid made large enough: accepted, and the frames in its free cells counted
  // as such (every cell free, so no warning).
  SaveOccupancyGrid(OccupancyGrid(300, 150, 0.1, Eigen::Vector2d(-2.0, -2.0)), yaml);
  const MclPrepared p = PrepareMclExperiment(o);
  EXPECT_EQ(p.refs_not_free, 0);
  EXPECT_EQ(p.test_not_free, 0);
  // A grid whose cells are all unknown: every true position counted, and a warning line.
  SaveOccupancyGrid(OccupancyGrid(300, 150, 0.1, Eigen::Vector2d(-2.0, -2.0), CellState::kUnknown),
                    yaml);
  const MclPrepared q = PrepareMclExperiment(o);
  EXPECT_EQ(q.refs_not_free, static_cast<int>(q.refs.size()));
  EXPECT_EQ(q.test_not_free, static_cast<int>(q.test.size()));
  EXPECT_NE(DescribeMclPrepared(q).find("warning"), std::string::npos);
  fs::remove_all(dir);
}

TEST_F(MclExperimentTest, TrackingHasOneRowPerRunAndIsDeterministic) {
  // One row per run with max >= mean error, the text has a header, the rows and a
  // summary; the same options give the same numbers.
  MclExperimentOptions o = Options();
  o.experiment = "tracking";
  const MclExperimentResult a = RunMclExperiment(o, *prepared_);
  const MclExperimentResult b = RunMclExperiment(o, *prepared_);
  ASSERT_EQ(a.tracking.size(), 2u);
  EXPECT_TRUE(a.global.empty() && a.kidnap.empty() && a.noise.empty());
  for (std::size_t i = 0; i < a.tracking.size(); ++i) {
    EXPECT_GE(a.tracking[i].max_position_error_m, a.tracking[i].mean_position_error_m);
    EXPECT_GE(a.tracking[i].max_heading_error_deg, 0.0);
    EXPECT_GT(a.tracking[i].ms_per_step, 0.0);
    EXPECT_EQ(a.tracking[i].max_position_error_m, b.tracking[i].max_position_error_m);
    EXPECT_EQ(a.tracking[i].mean_position_error_m, b.tracking[i].mean_position_error_m);
  }
  // Different seeds per run.
  EXPECT_NE(a.tracking[0].mean_position_error_m, a.tracking[1].mean_position_error_m);
  EXPECT_EQ(Lines(a.text), 2u + 2u + 1u);
  EXPECT_NE(a.text.find("\nsummary: "), std::string::npos);
}

TEST_F(MclExperimentTest, GlobalKidnapAndNoiseRowsFollowTheirDefinitions) {
  // global: run 0 starts at frame 0, others in the first half; kidnap: the target is at
  // least a quarter of the sequence ahead; noise: one row per level, successes <= runs.
  const int n = static_cast<int>(prepared_->test.size());
  MclExperimentOptions o = Options();
  o.experiment = "global";
  const MclExperimentResult g = RunMclExperiment(o, *prepared_);
  ASSERT_EQ(g.global.size(), 2u);
  EXPECT_EQ(g.global[0].start_frame, 0);
  EXPECT_LT(g.global[1].start_frame, n / 2);
  for (const MclGlobalRun& r : g.global) EXPECT_GE(r.steps_to_converge, -1);

  o.experiment = "kidnap";
  const MclExperimentResult k = RunMclExperiment(o, *prepared_);
  ASSERT_EQ(k.kidnap.size(), 2u);
  for (const MclKidnapRun& r : k.kidnap) {
    EXPECT_GE(r.kidnap_step, 20);
    EXPECT_GE(r.to_frame, r.kidnap_step + n / 4);
    EXPECT_LT(r.to_frame, n);
    EXPECT_GT(r.jump_m, 0.0);
  }

  o.experiment = "noise";
  o.noise_levels = "0,4";
  const MclExperimentResult z = RunMclExperiment(o, *prepared_);
  ASSERT_EQ(z.noise.size(), 2u);
  EXPECT_EQ(z.noise[0].level, 0.0);
  EXPECT_EQ(z.noise[1].level, 4.0);
  for (const MclNoiseLevel& l : z.noise) {
    EXPECT_EQ(l.runs, 2);
    EXPECT_LE(l.successes, l.runs);
    EXPECT_GE(l.mean_max_error_m, l.mean_final_error_m);
  }
  o.noise_levels = "0,x";
  EXPECT_THROW(RunMclExperiment(o, *prepared_), Error);
  o.experiment = "teleport";
  EXPECT_THROW(RunMclExperiment(o, *prepared_), Error);
  EXPECT_THROW(PrepareMclExperiment(o), Error);
}

TEST_F(MclExperimentTest, ColumnNormalisedHistogramsAreRecordedAndNeedIfh) {
  // --ifh-normalize-columns changes the references' descriptors, is written to
  // config.yaml (which loads back), and is refused with another descriptor.
  MclExperimentOptions o = Options();
  o.ifh_normalize_columns = true;
  const MclPrepared p = PrepareMclExperiment(o);
  ASSERT_EQ(p.refs.size(), prepared_->refs.size());
  EXPECT_NE(p.refs[0].descriptor.features, prepared_->refs[0].descriptor.features);
  const fs::path dir = FreshDir("ifh_columns");
  o.out_dir = dir.string();
  RunMclSingle(o, p);
  const std::string config = ReadTextFile(dir / "config.yaml");
  EXPECT_NE(config.find("ifh_normalize_columns: true"), std::string::npos) << config;
  EXPECT_EQ(LoadMclOptions((dir / "config.yaml").string()).num_particles, 500);
  fs::remove_all(dir);
  o.out_dir.clear();
  o.descriptor = "fourier";
  EXPECT_THROW(PrepareMclExperiment(o), Error);
}

TEST_F(MclExperimentTest, SingleRunWritesEveryFileOfTheRunDirectory) {
  // One frames.csv row per query, summary.txt = the summary text, the grid, no
  // temporaries or staging directories; a rerun replaces the run directory whole.
  const fs::path parent = FreshDir("experiment");
  const fs::path dir = parent / "run";
  MclExperimentOptions o = Options();
  o.out_dir = dir.string();
  const MclSingleResult r = RunMclSingle(o, *prepared_);
  EXPECT_EQ(r.steps.size(), prepared_->test.size());
  ASSERT_EQ(r.records.size(), prepared_->test.size());
  const auto names_in = [](const fs::path& d) {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(d)) names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  };
  const std::vector<std::string> expected = {
      "config.yaml", "days.csv",     "frames.csv",  "groundtruth.tum", "map.pgm",
      "map.yaml",    "odometry.tum", "report.html", "summary.txt",     "trajectory.tum"};
  EXPECT_EQ(names_in(dir), expected);
  EXPECT_EQ(names_in(parent), std::vector<std::string>{"run"});
  EXPECT_EQ(ReadTextFile(dir / "summary.txt"), r.summary_text);
  EXPECT_EQ(Lines(ReadTextFile(dir / "frames.csv")), 1 + prepared_->test.size());
  // A file added to the run directory does not survive the next run (committed whole).
  { std::ofstream(dir / "notes.txt") << "mine\n"; }
  RunMclSingle(o, *prepared_);
  EXPECT_EQ(names_in(dir), expected);
  EXPECT_EQ(names_in(parent), std::vector<std::string>{"run"});
  fs::remove_all(parent);
}

TEST_F(MclExperimentTest, UnrelatedDirectoryIsRefusedBeforeAnyWork) {
  // A non-empty directory that is not a run directory would be replaced whole: refused,
  // naming it, by the preparation and by the writer; its file is untouched.
  const fs::path dir = FreshDir("unrelated");
  { std::ofstream(dir / "notes.txt") << "mine\n"; }
  MclExperimentOptions o = Options();
  o.out_dir = dir.string();
  for (const auto& call : {std::function<void()>([&] { PrepareMclExperiment(o); }),
                           std::function<void()>([&] { RunMclSingle(o, *prepared_); })}) {
    try {
      call();
      ADD_FAILURE() << "an unrelated directory was accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(dir.string()), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(ReadTextFile(dir / "notes.txt"), "mine\n");
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omnicml
