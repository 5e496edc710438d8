// The in-memory run API (run/cml_run.h), its engine driver's observers and the run
// directory writer (run/run_directory.h).
#include "omnicml/run/cml_run.h"

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/run/run_directory.h"
#include "testing/cli_helpers.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

// A small simulated input: home_store, panoramas (no unwrap), 30 frames a day.
RunInput SmallWorld(int days, int first_day = 0) {
  RunInput in;
  in.world = "home_store";
  in.days = days;
  in.first_day = first_day;
  in.frames_per_day = 30;
  in.seed = 2;
  in.sim_image = ImageKind::kPanorama;
  return in;
}

CmlEngineOptions OneThread() {
  CmlEngineOptions o;
  o.threads = 1;
  return o;
}

// The deterministic content of a record (what frames.csv holds besides timings).
void ExpectSameRecord(const FrameRecord& a, const FrameRecord& b) {
  EXPECT_EQ(a.session, b.session);
  EXPECT_EQ(a.frame, b.frame);
  EXPECT_EQ(a.has_estimate, b.has_estimate);
  EXPECT_EQ(a.estimate, b.estimate) << "session " << a.session << " frame " << a.frame;
  EXPECT_EQ(a.truth, b.truth);
  EXPECT_EQ(a.views, b.views);
  EXPECT_EQ(a.map_components, b.map_components);
  EXPECT_EQ(a.hypotheses, b.hypotheses);
}

// Counts the sessions a run reports to its observers and the records seen at each end.
class SessionCounter : public RunObserver {
 public:
  void OnSessionEnd(const CmlEngine& engine, int source_session,
                    const std::vector<FrameRecord>& records) override {
    sessions.push_back(source_session);
    engine_sessions.push_back(engine.session_state().session);
    records_at_end.push_back(records.size());
  }
  void OnCommit(RunRecorder& recorder,
                std::vector<std::pair<std::string, std::string>>* notes) override {
    recorder.AddFile("observer.txt", "seen " + std::to_string(sessions.size()) + "\n");
    notes->emplace_back("observer", "on commit");
  }
  std::vector<int> sessions, engine_sessions;
  std::vector<std::size_t> records_at_end;
};

// Without outputs a run writes nothing and returns one record per frame, per-day
// statistics over them and the finished engine; the observer hears every session end,
// the last included, with the records so far.
TEST(CmlRun, ReturnsResultsInMemoryAndWritesNothing) {
  const fs::path cwd_before = fs::current_path();
  const fs::path dir = testing::FreshTempDir("omnicml_cml_run_memory");
  fs::current_path(dir);
  SessionCounter counter;
  CmlRunSettings settings;
  settings.observers.push_back(&counter);
  const CmlRunResult r = RunCml(OneThread(), SmallWorld(2), settings);
  fs::current_path(cwd_before);
  EXPECT_TRUE(fs::is_empty(dir));
  fs::remove_all(dir);

  ASSERT_EQ(r.records.size(), 60u);
  EXPECT_EQ(r.summary.frames, 60);
  EXPECT_EQ(r.summary.sessions, 2);
  ASSERT_EQ(r.evaluation.days.size(), 2u);
  EXPECT_EQ(r.evaluation.overall.frames, 60);
  ASSERT_NE(r.engine, nullptr);
  EXPECT_EQ(r.engine->counters().frames, 60);
  EXPECT_EQ(r.resumable_engine, nullptr);  // not asked for
  EXPECT_EQ(counter.sessions, (std::vector<int>{0, 1}));
  EXPECT_EQ(counter.engine_sessions, (std::vector<int>{0, 1}));
  EXPECT_EQ(counter.records_at_end, (std::vector<std::size_t>{30, 60}));
}

// The run directory written on request holds the same frames as the records returned
// (frames.csv read back), the observer's file, and outputs.yaml naming the map with its
// SHA-256; the map is the resumable engine's encoding.
TEST(CmlRun, RunDirectoryMirrorsTheInMemoryResult) {
  const fs::path dir = testing::FreshTempDir("omnicml_cml_run_dir");
  SessionCounter counter;
  CmlRunSettings settings;
  settings.outputs.run_dir = dir / "run";
  settings.outputs.map_path = dir / "map.omap";
  settings.observers.push_back(&counter);
  settings.keep_resumable_engine = true;
  const CmlRunResult r = RunCml(OneThread(), SmallWorld(2), settings);

  const FramesTable table = ReadFramesCsv(dir / "run" / "frames.csv");
  ASSERT_EQ(table.records.size(), r.records.size());
  for (std::size_t i = 0; i < r.records.size(); ++i)
    ExpectSameRecord(table.records[i], r.records[i]);
  EXPECT_EQ(testing::Slurp(dir / "run" / "observer.txt"), "seen 2\n");
  EXPECT_NE(testing::Slurp(dir / "run" / "report.html").find("on commit"), std::string::npos);
  const std::string map = testing::Slurp(dir / "map.omap");
  ASSERT_FALSE(map.empty());
  const std::vector<std::uint8_t> bytes(map.begin(), map.end());
  EXPECT_NE(testing::Slurp(dir / "run" / "outputs.yaml").find(Sha256Hex(bytes)), std::string::npos);
  ASSERT_NE(r.resumable_engine, nullptr);
  EXPECT_EQ(EncodeEngine(*r.resumable_engine), bytes);
  fs::remove_all(dir);
}

// A run resumed from the engine before Finish goes on exactly as one uninterrupted run:
// day 3 of a 3-day run equals a 1-day run from the 2-day run's resumable engine.
TEST(CmlRun, ResumableEngineContinuesAsOneRun) {
  CmlRunSettings keep;
  keep.keep_resumable_engine = true;
  CmlRunResult first = RunCml(OneThread(), SmallWorld(2), keep);
  ASSERT_NE(first.resumable_engine, nullptr);
  const CmlRunResult resumed = RunCml(std::move(first.resumable_engine), SmallWorld(1, 2));
  const CmlRunResult whole = RunCml(OneThread(), SmallWorld(3));
  ASSERT_EQ(resumed.records.size(), 30u);
  ASSERT_EQ(whole.records.size(), 90u);
  for (std::size_t i = 0; i < 30; ++i) {
    FrameRecord expected = whole.records[60 + i];
    EXPECT_EQ(resumed.records[i].global_frame, expected.global_frame);
    expected.session = resumed.records[i].session;  // the engine's session numbering
    ExpectSameRecord(resumed.records[i], expected);
  }
}

// Invalid options are refused before any frame, naming the field.
TEST(CmlRun, InvalidOptionsAreRefused) {
  CmlEngineOptions bad = OneThread();
  bad.update_delay_frames = -1;
  try {
    RunCml(bad, SmallWorld(1));
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("update_delay_frames"), std::string::npos) << e.what();
  }
}

// A writer destroyed without Commit leaves neither the run directory, nor its staging
// directory, nor the outside output; after Commit outputs.yaml records the output's
// size and SHA-256.
TEST(RunDirectoryWriter, CommitsAsOneUnitOrLeavesNothing) {
  const fs::path dir = testing::FreshTempDir("omnicml_run_directory_writer");
  const std::vector<std::uint8_t> bytes = {1, 2, 3, 4, 5};
  {
    RunDirectoryWriter w(dir / "run", /*stage=*/true);
    w.OpenFile("frames.csv").stream() << "a\n";
    w.AddOutput("--map-out", dir / "map.omap", bytes);
  }
  EXPECT_TRUE(fs::is_empty(dir)) << "debris after an aborted run";
  {
    RunDirectoryWriter w(dir / "run", /*stage=*/true);
    w.OpenFile("frames.csv").stream() << "a\n";
    w.AddOutput("--map-out", dir / "map.omap", bytes);
    w.Commit();
  }
  EXPECT_EQ(testing::Slurp(dir / "run" / "frames.csv"), "a\n");
  EXPECT_EQ(testing::Slurp(dir / "map.omap").size(), bytes.size());
  const std::string manifest = testing::Slurp(dir / "run" / "outputs.yaml");
  EXPECT_NE(manifest.find(Sha256Hex(bytes)), std::string::npos) << manifest;
  EXPECT_NE(manifest.find("bytes: 5"), std::string::npos) << manifest;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omnicml
