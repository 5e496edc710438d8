// Trustworthy outputs and inputs through the built `omnicml` binary and the run recorder:
// a second writer of the same outputs refuses naming the holder; a run directory, its map
// and its trajectory commit together and the run directory records the map's SHA-256;
// an interrupted run leaves the old state and no debris; a stale Snakemake lock is
// recovered; every YAML reader refuses alias bombs and duplicate keys; sweep job names
// cannot leave runs/ and grids are bounded; oversized panoramas are refused by `validate`
// and `run` alike; a corrupt PNG gives one line.
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/experiments/sweep.h"
#include "omnicml/run/run_recorder.h"
#include "omnicml/unwrap/omni_unwrapper.h"
#include "testing/cli_helpers.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;

using testing::CommandResult;
using testing::RunOmnicml;
using testing::Slurp;
using testing::Spit;

fs::path FreshDir(const std::string& name) {
  return testing::FreshScratchDir("output_safety", name);
}

// Staging directories, temporaries and lock files anywhere under `dir`.
std::vector<std::string> Debris(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.find(".partial-") != std::string::npos || name.find(".old-") != std::string::npos ||
        IsAtomicTempName(name) || name.find(".omnicml-lock") != std::string::npos) {
      out.push_back(e.path().string());
    }
  }
  return out;
}

bool HaveSnakemake() { return std::system("command -v snakemake >/dev/null 2>&1") == 0; }

// One line of output (the error) that names `what`.
void ExpectOneLineNaming(const CommandResult& r, const std::string& what) {
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_THAT(r.output, HasSubstr(what));
}

// While another process holds an output's lock, `run`, `simulate --overwrite` and
// `sweep` refuse at once with one line naming the output and the holder's pid, and
// write nothing. (The lock is held by this test process, so no timing is involved.)
TEST(OutputSafety, SecondWriterRefusedNamingTheHolder) {
  const fs::path dir = FreshDir("second_writer");
  const std::string pid = StrCat("pid ", ::getpid());
  {
    const fs::path map = dir / "map.omnicml";
    OutputLock held(map, "--map-out");
    const CommandResult r =
        RunOmnicml(StrCat("run --world home_store --frames-per-day 10 --quiet --out ",
                          (dir / "run").string(), " --map-out ", map.string()));
    ExpectOneLineNaming(r, map.string());
    EXPECT_THAT(r.output, HasSubstr(pid));
    EXPECT_FALSE(fs::exists(dir / "run"));
  }
  {
    OutputLock held(dir / "run", "--out");
    const CommandResult r = RunOmnicml(StrCat(
        "run --world home_store --frames-per-day 10 --quiet --out ", (dir / "run").string()));
    ExpectOneLineNaming(r, (dir / "run").string());
    EXPECT_THAT(r.output, HasSubstr(pid));
  }
  {
    OutputLock held(dir / "log", "--out");
    const CommandResult r =
        RunOmnicml(StrCat("simulate --world home_store --frames-per-day 2 --overwrite --out ",
                          (dir / "log").string()));
    ExpectOneLineNaming(r, (dir / "log").string());
    EXPECT_THAT(r.output, HasSubstr(pid));
    EXPECT_FALSE(fs::exists(dir / "log"));
  }
  {
    Spit(dir / "spec.yaml", "inputs:\n  - {world: home_store, days: 1, frames_per_day: 5}\n");
    OutputLock held(dir / "sweep", "--out");
    const CommandResult r = RunOmnicml(StrCat("sweep ", (dir / "spec.yaml").string(), " --out ",
                                              (dir / "sweep").string(), " --no-run"));
    ExpectOneLineNaming(r, (dir / "sweep").string());
    EXPECT_THAT(r.output, HasSubstr(pid));
  }
  EXPECT_EQ(Debris(dir), std::vector<std::string>{});
}

// A run's map and trajectory (outside the run directory, or inside it) commit with the
// run directory, whose outputs.yaml records each with its size and SHA-256; a second run
// replaces the whole run directory and leaves no staging directory, temporary or lock.
TEST(OutputSafety, RunDirectoryRecordsTheMapItWrote) {
  const fs::path dir = FreshDir("commit");
  const fs::path map = dir / "map.omnicml";
  const fs::path traj = dir / "traj.tum";
  for (const int seed : {1, 2}) {
    const CommandResult r = RunOmnicml(StrCat(
        "run --world home_store --frames-per-day 40 --quiet --seed ", seed, " --out ",
        (dir / "run").string(), " --map-out ", map.string(), " --trajectory-out ", traj.string()));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const std::string manifest = Slurp(dir / "run" / "outputs.yaml");
    EXPECT_THAT(manifest, HasSubstr("sha256: " + Sha256OfFile(map)));
    EXPECT_THAT(manifest, HasSubstr("sha256: " + Sha256OfFile(traj)));
    EXPECT_THAT(manifest, HasSubstr(StrCat("bytes: ", fs::file_size(map))));
    EXPECT_EQ(Debris(dir), std::vector<std::string>{});
  }
  // Inside the run directory: staged with it.
  const CommandResult r = RunOmnicml(
      StrCat("run --world home_store --frames-per-day 40 --quiet --out ", (dir / "run2").string(),
             " --map-out ", (dir / "run2" / "map.omnicml").string()));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_THAT(Slurp(dir / "run2" / "outputs.yaml"),
              HasSubstr("sha256: " + Sha256OfFile(dir / "run2" / "map.omnicml")));
  EXPECT_THAT(Slurp(dir / "run2" / "outputs.yaml"), HasSubstr("in_run_directory: true"));
  // In a subdirectory of the run directory (replaced whole): refused before the run.
  fs::create_directories(dir / "run2" / "sub");
  const CommandResult deep = RunOmnicml(
      StrCat("run --world home_store --frames-per-day 40 --quiet --out ", (dir / "run2").string(),
             " --map-out ", (dir / "run2" / "sub" / "map.omnicml").string()));
  ExpectOneLineNaming(deep, "subdirectory of the run directory");
  // An unrelated non-empty directory is never replaced.
  fs::create_directories(dir / "home");
  Spit(dir / "home" / "thesis.tex", "years of work");
  const CommandResult unrelated = RunOmnicml(
      StrCat("run --world home_store --frames-per-day 10 --quiet --out ", (dir / "home").string()));
  ExpectOneLineNaming(unrelated, (dir / "home").string());
  EXPECT_EQ(Slurp(dir / "home" / "thesis.tex"), "years of work");
}

// A recorder destroyed without Commit (an error during the run) leaves the earlier run
// directory, map and trajectory exactly as they were and no debris.
TEST(OutputSafety, FailedRunLeavesTheOldStateAndNoDebris) {
  const fs::path dir = FreshDir("failed");
  const fs::path map = dir / "map.bin";
  CmlEngineOptions options;
  options.panorama_width = 64;
  options.panorama_height = 16;
  CmlEngine engine(options);
  const auto commit = [&](const std::string& content, bool finish) {
    RunRecorderOptions ro;
    ro.run_dir = dir / "run";
    ro.trajectory_path = dir / "traj.tum";
    RunRecorder recorder(ro);
    recorder.AddOutput("--map-out", map, std::vector<std::uint8_t>(content.begin(), content.end()));
    if (finish) recorder.Commit(engine);
  };
  commit("old map", true);
  const std::string frames = Slurp(dir / "run" / "frames.csv");
  const std::string manifest = Slurp(dir / "run" / "outputs.yaml");
  commit("new map", false);
  EXPECT_EQ(Slurp(map), "old map");
  EXPECT_EQ(Slurp(dir / "run" / "frames.csv"), frames);
  EXPECT_EQ(Slurp(dir / "run" / "outputs.yaml"), manifest);
  EXPECT_THAT(manifest, HasSubstr(Sha256OfFile(map)));
  EXPECT_EQ(Debris(dir), std::vector<std::string>{});
}

// Every YAML reader refuses an alias bomb (also under an unknown key) and duplicate keys
// with one line naming the file: engine, simulator, topological and MCL configurations,
// a world, a sweep spec, a calibration and a session.yaml (via `validate`).
TEST(OutputSafety, EveryYamlReaderRefusesAliasBombsAndDuplicateKeys) {
  const fs::path dir = FreshDir("yaml");
  std::string bomb = "a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n";
  for (int i = 1; i < 9; ++i) {
    bomb += StrCat("a", i, ": &a", i, " [");
    for (int k = 0; k < 10; ++k) bomb += StrCat(k ? ", " : "", "*a", i - 1);
    bomb += "]\n";
  }
  bomb += "no_such_key: *a8\n";
  const fs::path bomb_file = dir / "bomb.yaml";
  Spit(bomb_file, bomb);
  const fs::path dup = dir / "dup.yaml";
  Spit(dup, "inputs:\n  - {world: home_store}\nseeds: [1]\nseeds: [2]\n");
  // A session whose session.yaml is the bomb.
  const fs::path log = dir / "log";
  ASSERT_EQ(
      RunOmnicml(StrCat("simulate --world home_store --frames-per-day 2 --out ", log.string()))
          .exit_code,
      0);
  const fs::path session_yaml = log / "day_001" / "session.yaml";
  const std::string session_text = Slurp(session_yaml);
  for (const std::string& args :
       {StrCat("run --world home_store --frames-per-day 5 --quiet --config ", bomb_file.string()),
        StrCat("simulate --out ", (dir / "s").string(), " --config ", bomb_file.string()),
        StrCat("topo --world home_store --days 2 --out ", (dir / "t").string(), " --config ",
               bomb_file.string()),
        StrCat("mcl --world home_store --config ", bomb_file.string()),
        StrCat("run --quiet --world ", bomb_file.string()),
        StrCat("sweep ", bomb_file.string(), " --out ", (dir / "w").string(), " --no-run"),
        StrCat("unwrap ", (log / "day_001" / "000000.png").string(), " --out ",
               (dir / "p.png").string(), " --calibration ", bomb_file.string())}) {
    SCOPED_TRACE(args);
    const CommandResult r = RunOmnicml(args);
    ExpectOneLineNaming(r, bomb_file.string());
    EXPECT_THAT(r.output, HasSubstr(StrCat("more than ", kMaxYamlNodes, " nodes")));
  }
  Spit(session_yaml, bomb);
  ExpectOneLineNaming(RunOmnicml("validate " + log.string()), session_yaml.string());
  Spit(session_yaml, session_text + "day_label: twice\nday_label: again\n");
  ExpectOneLineNaming(RunOmnicml("validate " + log.string()), "duplicate key 'day_label'");
  const CommandResult d =
      RunOmnicml(StrCat("sweep ", dup.string(), " --out ", (dir / "w").string(), " --no-run"));
  ExpectOneLineNaming(d, dup.string() + ":4: duplicate key 'seeds'");
  // A world file with a duplicate key.
  const fs::path world = dir / "world.yaml";
  Spit(world, "name: w\nname: v\n");
  ExpectOneLineNaming(RunOmnicml("run --quiet --world " + world.string()),
                      world.string() + ":2: duplicate key 'name'");
}

// Sweep specs: job names that would leave runs/ ('.', '..'), grids beyond kMaxSweepJobs,
// the same option twice (also spelt with '_' and '-') and non-UTF-8 text are refused
// naming the spec.
TEST(OutputSafety, SweepSpecsCannotEscapeOrExplode) {
  for (const char* name : {".", "..", ".hidden"}) {
    SCOPED_TRACE(name);
    EXPECT_THAT(
        [&] {
          try {
            ParseSweepSpec(StrCat("inputs:\n  - {world: home_store, name: '", name, "'}\n"),
                           "s.yaml");
          } catch (const Error& e) {
            return std::string(e.what());
          }
          return std::string();
        }(),
        HasSubstr("is not a job name"));
  }
  std::string big =
      "inputs:\n  - {world: home_store}\nseeds: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\noptions:\n";
  for (const char* flag : {"e-max", "update-delay", "descriptor", "threads", "forgetting"}) {
    big += StrCat("  ", flag, ": [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n");
  }
  try {
    ParseSweepSpec(big, "s.yaml");
    ADD_FAILURE() << "a 10^6-job grid was accepted";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr(StrCat("s.yaml: the sweep has more than ", kMaxSweepJobs)));
  }
  try {
    ParseSweepSpec("inputs:\n  - {world: home_store}\noptions:\n  e_max: [1]\n  e-max: [2]\n",
                   "s.yaml");
    ADD_FAILURE() << "a duplicate option was accepted";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("duplicate option"));
  }
  try {
    ParseSweepSpec("inputs:\n  - {world: home_store, name: caf\xe9}\n", "s.yaml");
    ADD_FAILURE() << "non-UTF-8 text was accepted";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("s.yaml:2: not valid UTF-8"));
  }
}

// A Snakemake lock left by a killed sweep does not block the rerun: `omnicml sweep`
// holds the sweep directory's own lock, so it removes Snakemake's and completes.
TEST(OutputSafety, StaleSnakemakeLockIsRecovered) {
  if (!HaveSnakemake()) GTEST_SKIP() << "snakemake not installed";
  const fs::path dir = FreshDir("snakemake_lock");
  Spit(dir / "spec.yaml",
       "inputs:\n  - {world: home_store, days: 1, frames_per_day: 10, name: hs}\nseeds: [1]\n");
  const std::string sweep =
      StrCat("sweep ", (dir / "spec.yaml").string(), " --out ", (dir / "sweep").string(), " -j 1");
  ASSERT_EQ(RunOmnicml(sweep + " --no-run").exit_code, 0);
  // What a Snakemake killed with SIGKILL leaves behind.
  fs::create_directories(dir / "sweep" / ".snakemake" / "locks");
  Spit(dir / "sweep" / ".snakemake" / "locks" / "0.input.lock",
       (dir / "sweep" / "Snakefile").string() + "\n");
  const CommandResult r = RunOmnicml(sweep);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("removed the Snakemake lock"));
  EXPECT_THAT(r.output, HasSubstr("1 run(s) collected"));
}

// A ring session declaring a 65536-row panorama is refused by `validate` and `run`
// alike, naming the file and the limit.
TEST(OutputSafety, PanoramaSizeBoundedByEveryReader) {
  const fs::path dir = FreshDir("panorama");
  const fs::path log = dir / "log";
  ASSERT_EQ(
      RunOmnicml(StrCat("simulate --world home_store --frames-per-day 2 --out ", log.string()))
          .exit_code,
      0);
  const fs::path yaml = log / "day_001" / "session.yaml";
  std::string text = Slurp(yaml);
  const std::size_t at = text.find("panorama_height: ");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, text.find('\n', at) - at, "panorama_height: 65536");
  Spit(yaml, text);
  for (const std::string& args :
       {"validate " + log.string(),
        StrCat("run --quiet --out ", (dir / "run").string(), " ", log.string())}) {
    SCOPED_TRACE(args);
    const CommandResult r = RunOmnicml(args);
    ExpectOneLineNaming(r, yaml.string());
    EXPECT_THAT(r.output, HasSubstr(StrCat("[1, ", kMaxPanoramaSidePx, "]")));
  }
}

// `simulate --preview NAME` without an image extension fails before simulating anything,
// leaving no log behind.
TEST(OutputSafety, SimulatePreviewExtensionCheckedFirst) {
  const fs::path dir = FreshDir("preview");
  const CommandResult r =
      RunOmnicml(StrCat("simulate --world home_store --frames-per-day 2 --out ",
                        (dir / "log").string(), " --preview ", (dir / "preview").string()));
  ExpectOneLineNaming(r, (dir / "preview").string());
  EXPECT_FALSE(fs::exists(dir / "log"));
}

// A PNG whose chunks are sound but whose compressed data is not gives exactly one line
// (libpng's own message inside it), not libpng's line on stderr before ours.
TEST(OutputSafety, CorruptPngGivesOneLine) {
  const fs::path dir = FreshDir("png");
  std::vector<std::uint8_t> png;
  ASSERT_TRUE(cv::imencode(".png", MakeSyntheticPanorama(64, 16, 1), png));
  // Find IDAT, scramble its data and fix its CRC so that only the zlib stream is bad.
  const auto be32 = [&](std::size_t i) {
    return (std::uint32_t{png[i]} << 24) | (std::uint32_t{png[i + 1]} << 16) |
           (std::uint32_t{png[i + 2]} << 8) | std::uint32_t{png[i + 3]};
  };
  std::size_t i = 8;
  while (std::string(png.begin() + static_cast<long>(i + 4),
                     png.begin() + static_cast<long>(i + 8)) != "IDAT") {
    i += 12 + be32(i);
  }
  const std::size_t length = be32(i);
  for (std::size_t k = 2; k < length; k += 3) png[i + 8 + k] ^= 0x5A;
  const std::uint32_t crc = Crc32(std::span<const std::uint8_t>(png.data() + i + 4, length + 4));
  for (int b = 0; b < 4; ++b)
    png[i + 8 + length + b] = static_cast<std::uint8_t>(crc >> (24 - 8 * b));
  const fs::path bad = dir / "bad.png";
  Spit(bad, std::string(png.begin(), png.end()));
  const CommandResult r = RunOmnicml("describe " + bad.string());
  ExpectOneLineNaming(r, bad.string());
  EXPECT_THAT(r.output, HasSubstr("PNG:"));
  EXPECT_THAT(r.output, ::testing::Not(HasSubstr("libpng error")));
}

}  // namespace
}  // namespace omnicml
