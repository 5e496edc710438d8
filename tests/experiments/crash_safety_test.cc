// Crash safety of the writers (common/file_io.h): a child process that writes run
// directories with their map and trajectory beside them (RunRecorder: `omnicml run
// --map-out --trajectory-out --out`) in a loop is killed with SIGKILL at seeded random
// moments; after the next writer settles what the killed one left (StagedDirectory's
// commit journal), the map, the trajectory and the run directory are all old or all
// new, never mixed, and nothing is left behind. Kills at the two steps of a commit (a
// test hook) check both directions of that recovery. A full disk (a 1 MB tmpfs in a
// private mount namespace, when the test may mount one) makes a save fail with an error
// naming the file, the old map intact.
//
// The "next writer" runs as a new process image: this test binary started with
// --next-writer DIR (see main() below), as the next `omnicml` command would be.
#include <fcntl.h>
#include <sched.h>
#include <signal.h>
#include <sys/mount.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/yaml_io.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/run/run_config.h"
#include "omnicml/run/run_recorder.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

fs::path ScratchDir(const std::string& name) {
  const fs::path dir = fs::path(OMNICML_BINARY_DIR) / "test_scratch" / "crash_safety" / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::vector<std::uint8_t> ReadAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::vector<std::uint8_t>((std::istreambuf_iterator<char>(in)),
                                   std::istreambuf_iterator<char>());
}

// Names in `dir` (recursively) that are AtomicFile temporaries or staging directories.
std::vector<std::string> Leftovers(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (IsAtomicTempName(name) || name.find(".partial-") != std::string::npos ||
        name.find(".old-") != std::string::npos ||
        name.find(".omnicml-prev-") != std::string::npos || name == ".omnicml-commit") {
      out.push_back(e.path().string());
    }
  }
  return out;
}

// A short simulated run: the engine after `frames` frames and what the recorder needs.
struct SimRun {
  std::unique_ptr<CmlEngine> engine;
  std::vector<std::pair<Frame, FrameResult>> records;  // images dropped
};

SimRun MakeRun(int frames) {
  SimulatorOptions sim_options;
  sim_options.frames_per_day = frames;
  sim_options.output = ImageKind::kPanorama;
  sim_options.people = false;
  SimulatedFrameSource sim(sim_options);
  CmlEngineOptions options;
  options.panorama_width = 128;
  options.panorama_height = 32;
  options.update_delay_frames = 2;
  options.threads = 1;  // no worker threads alive when the test forks
  SimRun run;
  run.engine = std::make_unique<CmlEngine>(options);
  run.engine->BeginSession(sim.Session(0));
  Frame frame;
  while (sim.Next(&frame)) {
    const FrameResult result = run.engine->ProcessFrame(frame);
    frame.image = cv::Mat();
    run.records.emplace_back(frame, result);
  }
  run.engine->Finish();
  return run;
}

// `omnicml run --map-out DIR/map.omap --trajectory-out DIR/trajectory.tum --out DIR/run`
// with the results of `run`.
void WriteRunWithMap(const SimRun& run, const fs::path& dir) {
  RunRecorderOptions options;
  options.run_dir = dir / "run";
  options.trajectory_path = dir / "trajectory.tum";
  RunRecorder recorder(options);
  recorder.AddOutput("--map-out", dir / "map.omap", EncodeEngine(*run.engine));
  for (const auto& [frame, result] : run.records) recorder.Record(frame, result);
  recorder.Commit(*run.engine);
}

// The sha256 that DIR/run/outputs.yaml records for `flag`, "" when none.
std::string RecordedSha(const fs::path& dir, const std::string& flag) {
  const YAML::Node list = LoadYaml(ReadTextFile(dir / "run" / "outputs.yaml"), "outputs.yaml");
  for (const auto& item : list) {
    if (item["flag"].as<std::string>() == flag) return item["sha256"].as<std::string>();
  }
  return "";
}

// The state a user finds in DIR: "a" or "b" when the map, the outside trajectory and the
// run directory all belong to that run; otherwise a description of the mix.
std::string StateOf(const fs::path& dir, const std::vector<std::uint8_t>& map_a,
                    const std::vector<std::uint8_t>& map_b) {
  const std::vector<std::uint8_t> map = ReadAll(dir / "map.omap");
  const std::string map_is = map == map_a ? "a" : map == map_b ? "b" : "torn";
  if (!fs::exists(dir / "run" / "outputs.yaml")) return "run directory without outputs.yaml";
  if (RecordedSha(dir, "--map-out") != Sha256Hex(map)) {
    return StrCat("map ", map_is, " is not the map the run directory records");
  }
  if (RecordedSha(dir, "--trajectory-out") != Sha256OfFile(dir / "trajectory.tum")) {
    return StrCat("map ", map_is, ", trajectory of another run");
  }
  return map_is;
}

// Runs the next writer as a new process (this binary with --next-writer DIR): it writes
// DIR/run with its map and trajectory once. Returns its exit code.
int RunNextWriterProcess(const fs::path& dir) {
  const pid_t child = ::fork();
  if (child == 0) {
    ::execl("/proc/self/exe", "crash_safety_test", "--next-writer", dir.c_str(),
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  int status = 0;
  if (child < 0 || ::waitpid(child, &status, 0) != child || !WIFEXITED(status)) return -1;
  return WEXITSTATUS(status);
}

// Forks a child that writes run `run` into `dir` and is killed by the test hook at
// `point` (common/file_io.h TestKillPoint). Returns true when it died by SIGKILL.
bool KilledAt(const SimRun& run, const fs::path& dir, const char* point) {
  const pid_t child = ::fork();
  if (child == 0) {
    ::setenv("OMNICML_TEST_KILL_AT", point, 1);
    try {
      WriteRunWithMap(run, dir);
    } catch (...) {
      ::_exit(3);
    }
    ::_exit(0);
  }
  int status = 0;
  return child > 0 && ::waitpid(child, &status, 0) == child && WIFSIGNALED(status) &&
         WTERMSIG(status) == SIGKILL;
}

// A writer killed after the map and trajectory replaced theirs but before the run
// directory was swapped in leaves a mix (new map beside the old run directory) that the
// next writer of the run directory rolls back to the old state before anything else; a
// writer killed after the swap leaves the new state, whose journal and previous versions
// the next writer removes. Either way nothing is left behind.
TEST(CrashSafety, InterruptedCommitIsSettledByTheNextWriter) {
  const fs::path dir = ScratchDir("window");
  const SimRun a = MakeRun(20);
  const SimRun b = MakeRun(60);
  const std::vector<std::uint8_t> map_a = EncodeEngine(*a.engine);
  const std::vector<std::uint8_t> map_b = EncodeEngine(*b.engine);
  WriteRunWithMap(a, dir);
  ASSERT_EQ(StateOf(dir, map_a, map_b), "a");

  // Between the two steps: the mix is on disk until the next writer starts.
  ASSERT_TRUE(KilledAt(b, dir, "staged-commit-swap"));
  EXPECT_EQ(ReadAll(dir / "map.omap"), map_b);
  EXPECT_NE(StateOf(dir, map_a, map_b), "b");
  EXPECT_FALSE(Leftovers(dir).empty());
  // What the next writer does first (it holds the run directory's lock): back to "a".
  EXPECT_EQ(RecoverInterruptedCommits(dir / "run"), 1);
  EXPECT_EQ(StateOf(dir, map_a, map_b), "a");
  EXPECT_NO_THROW(LoadEngine((dir / "map.omap").string()));
  // Stale staging directories go with the next writer's own staging.
  RemoveStaleStagingDirs(dir / "run");
  EXPECT_EQ(Leftovers(dir), std::vector<std::string>{});

  // A map that did not exist before is removed again.
  fs::remove(dir / "map.omap");
  ASSERT_TRUE(KilledAt(b, dir, "staged-commit-swap"));
  EXPECT_EQ(ReadAll(dir / "map.omap"), map_b);
  EXPECT_EQ(RecoverInterruptedCommits(dir / "run"), 1);
  EXPECT_FALSE(fs::exists(dir / "map.omap"));
  fs::remove_all(dir);
  fs::create_directories(dir);
  WriteRunWithMap(a, dir);

  // After the swap: the new state, with a journal and the previous versions to remove.
  ASSERT_TRUE(KilledAt(b, dir, "staged-commit-settle"));
  EXPECT_EQ(StateOf(dir, map_a, map_b), "b");
  EXPECT_FALSE(Leftovers(dir).empty());
  EXPECT_EQ(RecoverInterruptedCommits(dir / "run"), 1);
  RemoveStaleStagingDirs(dir / "run");
  EXPECT_EQ(StateOf(dir, map_a, map_b), "b");
  EXPECT_EQ(Leftovers(dir), std::vector<std::string>{});

  // The real next writer (a new process) after a kill in the window: it settles the mix
  // and commits its own run (a); nothing is left.
  ASSERT_TRUE(KilledAt(b, dir, "staged-commit-swap"));
  ASSERT_EQ(RunNextWriterProcess(dir), 0);
  EXPECT_EQ(StateOf(dir, map_a, map_b), "a");
  EXPECT_EQ(Leftovers(dir), std::vector<std::string>{});
}

// SIGKILL at random moments of a child writing runs with their map and trajectory.
TEST(CrashSafety, KilledWritersLeaveOldOrNewStateAndNoDebris) {
  const fs::path dir = ScratchDir("kill");
  const SimRun a = MakeRun(20);
  const SimRun b = MakeRun(60);
  const std::vector<std::uint8_t> bytes_a = EncodeEngine(*a.engine);
  const std::vector<std::uint8_t> bytes_b = EncodeEngine(*b.engine);
  ASSERT_NE(bytes_a, bytes_b);
  WriteRunWithMap(a, dir);

  std::mt19937 rng(17);
  std::uniform_int_distribution<int> delay_us(0, 40000);
  constexpr int kKills = 60;
  int kills_with_temporary = 0;
  int kills_mixed_before_recovery = 0;
  int saw_a = 0;
  int saw_b = 0;
  for (int k = 0; k < kKills; ++k) {
    const pid_t child = ::fork();
    ASSERT_GE(child, 0) << std::strerror(errno);
    if (child == 0) {
      // Child: alternate the two runs until killed.
      try {
        for (int i = 0;; ++i) WriteRunWithMap(i % 2 == 0 ? b : a, dir);
      } catch (...) {
        ::_exit(3);
      }
    }
    std::this_thread::sleep_for(std::chrono::microseconds(delay_us(rng)));
    ASSERT_EQ(::kill(child, SIGKILL), 0);
    int status = 0;
    ASSERT_EQ(::waitpid(child, &status, 0), child);
    ASSERT_TRUE(WIFSIGNALED(status)) << "the child ended by itself (status " << status << ")";

    // The map is the old or the new file, complete, and loads.
    const std::vector<std::uint8_t> now = ReadAll(dir / "map.omap");
    ASSERT_TRUE(now == bytes_a || now == bytes_b)
        << "kill " << k << ": torn map (" << now.size() << " bytes)";
    EXPECT_NO_THROW(LoadEngine((dir / "map.omap").string())) << "kill " << k;
    if (!Leftovers(dir).empty()) ++kills_with_temporary;
    const std::string before = StateOf(dir, bytes_a, bytes_b);
    if (before != "a" && before != "b") ++kills_mixed_before_recovery;

    // The next writer settles what the killed one left, then writes. After odd kills
    // the next killed child is the next writer.
    if (k % 2 == 0) {
      ASSERT_EQ(RunNextWriterProcess(dir), 0);
      const auto left = Leftovers(dir);
      EXPECT_TRUE(left.empty()) << "kill " << k << ": left behind: " << left.front();
      EXPECT_EQ(StateOf(dir, bytes_a, bytes_b), "a") << "kill " << k;
    } else {
      RecoverInterruptedCommits(dir / "run");
      const std::string after = StateOf(dir, bytes_a, bytes_b);
      EXPECT_TRUE(after == "a" || after == "b") << "kill " << k << ": " << after;
      (after == "a" ? saw_a : saw_b)++;
    }
  }
  ASSERT_EQ(RunNextWriterProcess(dir), 0);
  EXPECT_TRUE(Leftovers(dir).empty());
  // The kills landed inside writes (temporaries present) often enough to mean something.
  EXPECT_GT(kills_with_temporary, kKills / 4);
  RecordProperty("kills", kKills);
  RecordProperty("kills_with_temporary", kills_with_temporary);
  std::printf(
      "crash safety: %d kills, %d left a temporary, %d left a mix before recovery, "
      "old/new after recovery: %d/%d\n",
      kKills, kills_with_temporary, kills_mixed_before_recovery, saw_a, saw_b);
}

// Disk full: a save into a full 1 MB tmpfs fails naming the file; the old map is intact
// and no temporary is left. Needs a private mount namespace (root / CAP_SYS_ADMIN).
TEST(CrashSafety, DiskFullSaveFailsCleanly) {
  const fs::path dir = ScratchDir("disk_full");
  const SimRun a = MakeRun(20);
  const SimRun b = MakeRun(60);
  const std::vector<std::uint8_t> bytes_a = EncodeEngine(*a.engine);
  int pipe_fds[2];
  ASSERT_EQ(::pipe(pipe_fds), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(pipe_fds[0]);
    const auto report = [&](int code, const std::string& message) {
      (void)!::write(pipe_fds[1], message.data(), message.size());
      ::_exit(code);
    };
    if (::unshare(CLONE_NEWNS) != 0)
      report(77, StrCat("unshare(CLONE_NEWNS): ", std::strerror(errno)));
    if (::mount(nullptr, "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0) {
      report(77, StrCat("mount --make-rprivate /: ", std::strerror(errno)));
    }
    if (::mount("tmpfs", dir.c_str(), "tmpfs", 0, "size=1m") != 0) {
      report(77, StrCat("mount -t tmpfs -o size=1m: ", std::strerror(errno)));
    }
    const fs::path map = dir / "map.omap";
    try {
      SaveEngine(*a.engine, map.string());
      // Fill the rest of the file system.
      std::vector<char> chunk(4096, 'x');
      const int fd = ::open((dir / "filler").c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      while (::write(fd, chunk.data(), chunk.size()) > 0) {
      }
      ::close(fd);
    } catch (const std::exception& e) {
      report(2, StrCat("setting up the full disk: ", e.what()));
    }
    std::string message;
    try {
      SaveEngine(*b.engine, map.string());
      report(1, "SaveEngine on a full disk did not throw");
    } catch (const Error& e) {
      message = e.what();
    }
    if (message.find(map.string()) == std::string::npos)
      report(1, "error without the path: " + message);
    if (ReadAll(map) != bytes_a) report(1, "the old map changed: " + message);
    const auto left = Leftovers(dir);
    if (!left.empty()) report(1, "temporary left: " + left.front() + " after: " + message);
    try {
      (void)LoadEngine(map.string());
    } catch (const std::exception& e) {
      report(1, StrCat("the old map does not load: ", e.what()));
    }
    report(0, message);
  }
  ::close(pipe_fds[1]);
  std::string message;
  char buf[512];
  for (ssize_t n; (n = ::read(pipe_fds[0], buf, sizeof buf)) > 0;) message.append(buf, n);
  ::close(pipe_fds[0]);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status)) << "child died: status " << status;
  if (WEXITSTATUS(status) == 77) GTEST_SKIP() << "cannot mount a small tmpfs here: " << message;
  EXPECT_EQ(WEXITSTATUS(status), 0) << message;
  std::printf("disk full: %s\n", message.c_str());
}

}  // namespace
}  // namespace omnicml

// `crash_safety_test --next-writer DIR`: the next writer of the kill tests (writes
// DIR/run with its map and trajectory once, settling what a killed writer left); any
// other arguments run the tests.
int main(int argc, char** argv) {
  if (argc == 3 && std::string(argv[1]) == "--next-writer") {
    try {
      omnicml::WriteRunWithMap(omnicml::MakeRun(20), argv[2]);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "next writer: %s\n", e.what());
      return 2;
    }
    return 0;
  }
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
