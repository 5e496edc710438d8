// The bounded map event log: the model keeps a ring of model.events.max_events
// events, while the run directory's events.csv (run/run_recorder.h) still gets every event
// and days.csv / inspect use the model's exact per-session counts.
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/report/map_export.h"
#include "omnicml/run/engine_driver.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

std::string ReadText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

struct RecordedRun {
  std::unique_ptr<CmlEngine> engine;
  fs::path dir;
};

// Two home_store days of 150 frames with component events logged (a few hundred events).
RecordedRun RunWithRing(int max_events, const fs::path& dir) {
  SimulatorOptions sim;
  sim.world = "home_store";
  sim.days = 2;
  sim.frames_per_day = 150;
  sim.seed = 2;
  sim.output = ImageKind::kPanorama;
  SimulatedFrameSource source(sim);
  CmlEngineOptions options;
  options.model.events.log_component_events = true;
  options.model.events.max_events = max_events;
  RecordedRun run{std::make_unique<CmlEngine>(options), dir};
  RunRecorderOptions ro;
  ro.run_dir = dir;
  ro.write_report = false;
  RunRecorder recorder(ro);
  ProgressOptions progress;
  progress.quiet = true;
  RunEngineOverSource(*run.engine, source, &recorder, progress);
  run.engine->Finish();
  recorder.Commit(*run.engine);
  EXPECT_EQ(recorder.events_lost(), 0u);
  return run;
}

// A ring smaller than the run's events: the model holds only the last max_events, yet
// events.csv, days.csv and inspect's per-session table equal those of an unbounded log.
TEST(EventLog, RunDirectoryGetsEveryEventAlthoughTheRingIsSmall) {
  const fs::path root = fs::temp_directory_path() / StrCat("omnicml_event_log_", ::getpid());
  fs::remove_all(root);
  const RecordedRun big = RunWithRing(100000, root / "big");
  const RecordedRun small = RunWithRing(300, root / "small");
  const EnvironmentModel& m = small.engine->model();
  ASSERT_GT(m.events_logged(), 300u) << "the run must log more events than the ring holds";
  EXPECT_EQ(m.events().size(), 300u);
  EXPECT_EQ(big.engine->model().events().size(), big.engine->model().events_logged());
  EXPECT_EQ(m.events_logged(), big.engine->model().events_logged());
  EXPECT_EQ(m.event_counts(), big.engine->model().event_counts());
  // The ring is the tail of the full log.
  const auto& all = big.engine->model().events();
  EXPECT_TRUE(std::equal(m.events().begin(), m.events().end(), all.end() - 300));

  const std::string csv = ReadText(small.dir / "events.csv");
  EXPECT_EQ(csv, ReadText(big.dir / "events.csv"));
  EXPECT_EQ(static_cast<std::uint64_t>(std::count(csv.begin(), csv.end(), '\n')),
            m.events_logged() + 1);  // + header

  // inspect: the per-session table is exact; the health section still renders.
  const std::string text = InspectText(*small.engine);
  const std::string full = InspectText(*big.engine);
  const auto table = [](const std::string& s) {
    const auto a = s.find("session  views_alive");
    return s.substr(a, s.find("health by area") - a);
  };
  EXPECT_EQ(table(text), table(full));
  EXPECT_NE(text.find("health by area"), std::string::npos);

  // The ring and the counts survive a save and load; the map file does not hold the
  // events the ring dropped.
  SaveEngine(*small.engine, (root / "small.omap").string());
  SaveEngine(*big.engine, (root / "big.omap").string());
  const auto loaded = LoadEngine((root / "small.omap").string());
  EXPECT_EQ(loaded->model().events(), m.events());
  EXPECT_EQ(loaded->model().events_logged(), m.events_logged());
  EXPECT_EQ(loaded->model().event_counts(), m.event_counts());
  EXPECT_LT(fs::file_size(root / "small.omap"), fs::file_size(root / "big.omap"));
  fs::remove_all(root);
}

}  // namespace
}  // namespace omnicml
