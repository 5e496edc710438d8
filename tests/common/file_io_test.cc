#include "omnicml/common/file_io.h"

#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <fstream>
#include <random>
#include <span>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;

fs::path FreshDir(const std::string& name) {
  const fs::path dir = fs::path(OMNICML_BINARY_DIR) / "test_output" / "file_io" / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::vector<std::string> Entries(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) out.push_back(e.path().filename().string());
  std::sort(out.begin(), out.end());
  return out;
}

std::string Slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream os;
  os << in.rdbuf();
  return os.str();
}

// The message of the omnicml::Error `f` throws ("" when it throws nothing).
template <typename F>
std::string ErrorOf(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// A pid that belonged to a process which has exited (a reaped child).
pid_t DeadPid() {
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  int status = 0;
  ::waitpid(child, &status, 0);
  return child;
}

// A successful write replaces the content and leaves nothing but the target.
TEST(AtomicFile, SuccessLeavesOnlyTheTarget) {
  const fs::path dir = FreshDir("success");
  const fs::path target = dir / "out.txt";
  WriteFileAtomic(target, "first");
  WriteFileAtomic(target, std::string("second\0bytes", 12));
  EXPECT_EQ(Slurp(target), std::string("second\0bytes", 12));
  const std::vector<std::uint8_t> bytes = {1, 2, 3, 0, 255};
  WriteFileAtomic(dir / "bin", bytes);
  EXPECT_EQ(Slurp(dir / "bin"), std::string("\x01\x02\x03\x00\xff", 5));
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"bin", "out.txt"}));
}

// An exception between open and Commit leaves the old target untouched and no temporary;
// so do Discard() and a second Commit().
TEST(AtomicFile, ExceptionBeforeCommitLeavesTargetAndNoTemporary) {
  const fs::path dir = FreshDir("throw");
  const fs::path target = dir / "out.txt";
  WriteFileAtomic(target, "old");
  fs::path temp;
  try {
    AtomicFile file(target);
    temp = file.temp_path();
    EXPECT_TRUE(fs::exists(temp));
    EXPECT_EQ(temp.parent_path(), target.parent_path());
    file.stream() << "half written";
    throw std::runtime_error("simulated failure");
  } catch (const std::runtime_error&) {
  }
  EXPECT_FALSE(fs::exists(temp));
  EXPECT_EQ(Slurp(target), "old");
  {
    AtomicFile file(target);
    file.stream() << "discarded";
    file.Discard();
    file.Commit();  // no-op after Discard
  }
  EXPECT_EQ(Slurp(target), "old");
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"out.txt"}));
}

// Failures name the path, leave no temporary and do not touch the target: a missing
// directory, a target that is a directory (refused before anything is written), and (when not root)
// a directory without write permission.
TEST(AtomicFile, FailuresNamePathAndLeaveNoTemporary) {
  const fs::path dir = FreshDir("fail");
  const fs::path missing = dir / "no" / "such" / "out.txt";
  EXPECT_THAT(ErrorOf([&] { WriteFileAtomic(missing, "x"); }), HasSubstr(missing.string()));

  const fs::path busy = dir / "busy";
  fs::create_directories(busy / "inside");
  const std::string message = ErrorOf([&] { WriteFileAtomic(busy, "x"); });
  EXPECT_THAT(message, HasSubstr(busy.string()));
  EXPECT_THAT(message, HasSubstr("is a directory"));
  EXPECT_TRUE(fs::is_directory(busy / "inside"));
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"busy"}));
  EXPECT_EQ(Entries(busy), (std::vector<std::string>{"inside"}));

  if (::geteuid() != 0) {
    const fs::path locked = dir / "locked";
    fs::create_directories(locked);
    WriteFileAtomic(locked / "out.txt", "old");
    fs::permissions(locked, fs::perms::owner_read | fs::perms::owner_exec);
    EXPECT_THAT(ErrorOf([&] { WriteFileAtomic(locked / "out.txt", "new"); }),
                HasSubstr((locked / "out.txt").string()));
    fs::permissions(locked, fs::perms::owner_all);
    EXPECT_EQ(Slurp(locked / "out.txt"), "old");
    EXPECT_EQ(Entries(locked), (std::vector<std::string>{"out.txt"}));
  }
}

// A reader running while the target is rewritten sees the old or the new content in
// full, never a partial or missing file.
TEST(AtomicFile, ConcurrentReaderSeesOldOrNew) {
  const fs::path dir = FreshDir("concurrent");
  const fs::path target = dir / "out.txt";
  const std::string a(100000, 'a');
  const std::string b(150000, 'b');
  WriteFileAtomic(target, a);
  std::atomic<bool> done{false};
  std::atomic<int> reads{0};
  std::atomic<int> bad{0};
  std::thread reader([&] {
    while (!done.load()) {
      const std::string text = ReadTextFile(target);
      if (text != a && text != b) ++bad;
      ++reads;
    }
  });
  for (int i = 0; i < 60; ++i) WriteFileAtomic(target, i % 2 == 0 ? b : a);
  done = true;
  reader.join();
  EXPECT_EQ(bad.load(), 0);
  EXPECT_GT(reads.load(), 0);
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"out.txt"}));
}

// A child process that takes OutputLock(target) and holds it until told to exit; the
// parent waits until the lock is taken (a byte on a pipe), not for a time.
class LockHolder {
 public:
  explicit LockHolder(const fs::path& target) {
    int ready[2], quit[2];
    if (::pipe(ready) != 0 || ::pipe(quit) != 0) throw Error("pipe failed");
    pid_ = ::fork();
    if (pid_ == 0) {
      ::close(ready[0]);
      ::close(quit[1]);
      char c = 'x';
      try {
        OutputLock lock(target, "--out");
        [[maybe_unused]] ssize_t n = ::write(ready[1], &c, 1);
        n = ::read(quit[0], &c, 1);  // until the parent closes its end
      } catch (...) {
        ::_exit(3);
      }
      ::_exit(0);
    }
    ::close(ready[1]);
    ::close(quit[0]);
    quit_ = quit[1];
    char c = 0;
    if (::read(ready[0], &c, 1) != 1) throw Error("lock holder failed");
    ::close(ready[0]);
  }
  ~LockHolder() { Release(); }
  void Release() {
    if (pid_ <= 0) return;
    ::close(quit_);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
  int quit_ = -1;
};

// Temporary names are recognisable; a writer removes the temporaries nobody holds a lock
// on, whatever their pid says (a live pid may belong to another PID namespace), and keeps
// those of writers still at work.
TEST(AtomicFile, StaleTemporariesAreRecognisedByTheirLockNotTheirPid) {
  const fs::path dir = FreshDir("stale");
  const fs::path target = dir / "map.omnicml";
  pid_t pid = 0;
  EXPECT_TRUE(
      IsAtomicTempName(TempPathFor(target, 1234, 7).filename().string(), "map.omnicml", &pid));
  EXPECT_EQ(pid, 1234);
  EXPECT_FALSE(IsAtomicTempName(".map.omnicml.omnicml-tmp-12x-7"));
  EXPECT_FALSE(IsAtomicTempName("map.omnicml"));
  EXPECT_FALSE(IsAtomicTempName(TempPathFor(target, 1, 0).filename().string(), "other"));

  AtomicFile writing(target);  // at work: its temporary is locked
  writing.stream() << "new map";
  const fs::path stale_dead = TempPathFor(target, DeadPid(), 3);
  const fs::path stale_live_pid = TempPathFor(target, 1, 3);  // init lives, but holds no lock
  std::ofstream(stale_dead) << "leftover of a killed run";
  std::ofstream(stale_live_pid) << "leftover of a writer in another PID namespace";
  EXPECT_EQ(RemoveStaleTemporaries(target), 2);
  EXPECT_FALSE(fs::exists(stale_dead));
  EXPECT_FALSE(fs::exists(stale_live_pid));
  EXPECT_TRUE(fs::exists(writing.temp_path()));
  writing.Commit();
  EXPECT_EQ(Slurp(target), "new map");

  // The first write into a directory sweeps it.
  const fs::path dir2 = FreshDir("stale_sweep");
  const fs::path stale2 = TempPathFor(dir2 / "a.csv", 1, 0);
  std::ofstream(stale2) << "x";
  WriteFileAtomic(dir2 / "a.csv", "new");
  EXPECT_EQ(Entries(dir2), (std::vector<std::string>{"a.csv"}));
}

// An output file is a regular file or nothing: AtomicFile refuses FIFOs, sockets,
// directories and symbolic links (to a regular file too) naming the path, leaves them as
// they were and leaves no temporary.
TEST(AtomicFile, RefusesTargetsThatAreNotRegularFiles) {
  const fs::path dir = FreshDir("non_regular");
  const fs::path fifo = dir / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const fs::path real = dir / "real.txt";
  std::ofstream(real) << "precious";
  const fs::path link = dir / "link";
  fs::create_symlink(real, link);
  const fs::path sub = dir / "sub";
  fs::create_directory(sub);
  for (const auto& [path, reason] : {std::pair{fifo, "is a FIFO"}, std::pair{link, "symbolic link"},
                                     std::pair{sub, "is a directory"}}) {
    SCOPED_TRACE(path.string());
    const std::string message = ErrorOf([&] { WriteFileAtomic(path, "new"); });
    EXPECT_THAT(message, HasSubstr(path.string()));
    EXPECT_THAT(message, HasSubstr(reason));
  }
  EXPECT_TRUE(fs::is_fifo(fs::symlink_status(fifo)));
  EXPECT_TRUE(fs::is_symlink(fs::symlink_status(link)));
  EXPECT_EQ(Slurp(real), "precious");
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"fifo", "link", "real.txt", "sub"}));
  EXPECT_EQ(Entries(sub), std::vector<std::string>{});
  // A node swapped in while the file is being written is refused at the rename.
  const fs::path target = dir / "late.txt";
  AtomicFile file(target);
  file.stream() << "data";
  ASSERT_EQ(::mkfifo(target.c_str(), 0600), 0);
  EXPECT_THAT(ErrorOf([&] { file.Commit(); }), HasSubstr("is a FIFO"));
  EXPECT_TRUE(fs::is_fifo(fs::symlink_status(target)));
}

// A second process asking for a locked output is refused naming the path and the
// holder's pid; the lock is shared within a process and its file removed on release.
TEST(OutputLock, SecondWriterRefusedNamingTheHolder) {
  const fs::path dir = FreshDir("lock");
  const fs::path target = dir / "map.omnicml";
  {
    LockHolder holder(target);
    EXPECT_TRUE(fs::exists(OutputLock::LockPathFor(target)));
    const std::string message = ErrorOf([&] { OutputLock lock(target, "--map-out"); });
    EXPECT_THAT(message, HasSubstr("--map-out '" + target.string() + "'"));
    EXPECT_THAT(message, HasSubstr(StrCat("pid ", holder.pid())));
    EXPECT_THAT(message, HasSubstr("in use by another writer"));
    EXPECT_FALSE(OutputLock::HeldByThisProcess(target));
    holder.Release();
    OutputLock mine(target, "--map-out");
    EXPECT_TRUE(OutputLock::HeldByThisProcess(dir / "." / "map.omnicml"));
    OutputLock again(target, "--map-out");  // same process: shared
  }
  EXPECT_EQ(Entries(dir), std::vector<std::string>{});
}

// Staging directories of a target are removed by a writer holding (or able to take) the
// target's lock, whatever pid they name; while another process holds it they are kept.
TEST(StagingDir, StaleOnesAreRemovedUnderTheTargetsLock) {
  const fs::path dir = FreshDir("staging");
  const fs::path target = dir / "log";
  fs::create_directories(StagingDirFor(target, DeadPid()) / "day_01");
  fs::create_directories(dir / "log.old-77");
  fs::create_directories(StagingDirFor(target, 1));  // a live pid, but no lock held
  fs::create_directories(StagingDirFor(dir / "other", 5));
  EXPECT_EQ(StagingDirFor(dir / "log/", 42).filename(), "log.partial-42");
  {
    LockHolder holder(target);
    EXPECT_EQ(RemoveStaleStagingDirs(target), 0);
  }
  EXPECT_EQ(RemoveStaleStagingDirs(target), 3);
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"other.partial-5"}));
}

// A staged directory appears whole at Commit, replacing an earlier output of its kind;
// without Commit nothing changes; an unrelated non-empty directory is refused.
TEST(StagedDirectory, CommitsWholeOrNotAtAll) {
  const fs::path dir = FreshDir("staged");
  const fs::path target = dir / "run";
  const std::vector<std::string> markers = {"frames.csv"};
  {
    StagedDirectory staged(target, "--out", markers);
    WriteFileAtomic(staged.path() / "frames.csv", "old", FileSync::kDeferred);
    staged.Commit();
  }
  {
    StagedDirectory staged(target, "--out", markers);
    WriteFileAtomic(staged.path() / "frames.csv", "new", FileSync::kDeferred);
    EXPECT_EQ(Slurp(target / "frames.csv"), "old");  // not yet
  }                                                  // no Commit: discarded
  EXPECT_EQ(Slurp(target / "frames.csv"), "old");
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"run"}));
  {
    StagedDirectory staged(target, "--out", markers);
    WriteFileAtomic(staged.path() / "frames.csv", "new", FileSync::kDeferred);
    WriteFileAtomic(staged.path() / "days.csv", "d", FileSync::kDeferred);
    staged.Commit();
  }
  EXPECT_EQ(Slurp(target / "frames.csv"), "new");
  EXPECT_EQ(Entries(target), (std::vector<std::string>{"days.csv", "frames.csv"}));
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"run"}));
  const fs::path home = dir / "home";
  fs::create_directories(home);
  std::ofstream(home / "thesis.tex") << "years of work";
  EXPECT_THAT(ErrorOf([&] { StagedDirectory staged(home, "--out", markers); }),
              HasSubstr("is not an output of this kind"));
  EXPECT_EQ(Slurp(home / "thesis.tex"), "years of work");
}

// SHA-256 of the FIPS 180-2 test vector "abc", of bytes and of a file alike.
TEST(Sha256, KnownVector) {
  const std::string abc = "abc";
  const std::string expected = "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad";
  EXPECT_EQ(Sha256Hex(std::span<const std::uint8_t>(
                reinterpret_cast<const std::uint8_t*>(abc.data()), abc.size())),
            expected);
  const fs::path dir = FreshDir("sha");
  WriteFileAtomic(dir / "abc", abc);
  EXPECT_EQ(Sha256OfFile(dir / "abc"), expected);
}

// Directories, FIFOs, devices (also behind a symbolic link), symbolic-link loops and
// missing files are rejected with an Error naming the path, without blocking.
TEST(ReadFile, OnlyRegularFiles) {
  const fs::path dir = FreshDir("regular");
  const fs::path fifo = dir / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const fs::path zero = dir / "zero";
  fs::create_symlink("/dev/zero", zero);
  const fs::path loop = dir / "loop";
  fs::create_symlink(loop, loop);
  const fs::path missing = dir / "missing.yaml";
  const struct {
    fs::path path;
    const char* reason;
  } cases[] = {{dir, "directory"},
               {fifo, "FIFO"},
               {zero, "character device"},
               {loop, "symbolic links"},
               {missing, "does not exist"}};
  for (const auto& c : cases) {
    SCOPED_TRACE(c.path.string());
    for (const std::string& message :
         {ErrorOf([&] { ReadTextFile(c.path); }), ErrorOf([&] { CheckRegularFile(c.path); }),
          ErrorOf([&] { ReadBinaryFile(c.path); }), ErrorOf([&] { LineReader r(c.path); })}) {
      EXPECT_THAT(message, HasSubstr(c.path.string()));
      EXPECT_THAT(message, HasSubstr(c.reason));
      EXPECT_EQ(message.find('\n'), std::string::npos);
    }
  }
  const fs::path good = dir / "good.yaml";
  std::ofstream(good) << "a: 1\n";
  const fs::path link = dir / "link.yaml";
  fs::create_symlink(good, link);
  EXPECT_EQ(ReadTextFile(link), "a: 1\n");  // a link to a regular file is fine
  EXPECT_EQ(CheckRegularFile(good, "config"), 5u);
}

// Reads are bounded: a file over the limit is refused before it is read.
TEST(ReadFile, SizeLimit) {
  const fs::path dir = FreshDir("limit");
  const fs::path big = dir / "big.yaml";
  std::ofstream(big) << std::string(1000, 'x');
  EXPECT_EQ(ReadTextFile(big, 1000).size(), 1000u);
  const std::string message = ErrorOf([&] { ReadTextFile(big, 999, "world file"); });
  EXPECT_THAT(message, HasSubstr(big.string()));
  EXPECT_THAT(message, HasSubstr("too large"));
  EXPECT_THAT(message, HasSubstr("world file"));
  EXPECT_THAT(ErrorOf([&] { ReadBinaryFile(big, 10); }), HasSubstr("too large"));
}

// LineReader returns the lines std::getline would (without "\r"), across its internal
// buffer boundaries, and rejects an overlong line with its number.
TEST(LineReader, MatchesGetlineAndBoundsLines) {
  const fs::path dir = FreshDir("lines");
  std::mt19937 rng(7);
  std::vector<std::string> lines;
  std::string text;
  for (int i = 0; i < 3000; ++i) {
    std::string line(std::uniform_int_distribution<int>(0, 300)(rng), 'a' + i % 26);
    lines.push_back(line);
    text += line + (i % 3 == 0 ? "\r\n" : "\n");
  }
  lines.push_back("last line without a break");
  text += lines.back();
  const fs::path path = dir / "frames.csv";
  std::ofstream(path, std::ios::binary) << text;
  LineReader reader(path, "frames", 300);
  std::string line;
  std::size_t n = 0;
  while (reader.Next(&line)) {
    ASSERT_LT(n, lines.size());
    EXPECT_EQ(line, lines[n]) << "line " << n + 1;
    ++n;
    EXPECT_EQ(reader.line_number(), n);
  }
  EXPECT_EQ(n, lines.size());

  const fs::path longer = dir / "long.csv";
  std::ofstream(longer, std::ios::binary) << "header\n" << std::string(200000, 'z') << "\nend\n";
  LineReader bad(longer, "frames", kMaxCsvLineBytes);
  ASSERT_TRUE(bad.Next(&line));
  const std::string message = ErrorOf([&] { bad.Next(&line); });
  EXPECT_THAT(message, HasSubstr(longer.string() + ":2:"));
  EXPECT_THAT(message, HasSubstr("longer than 65536 bytes"));
  EXPECT_LT(message.size(), 300u);
}

// Excerpt keeps messages on one short line of valid UTF-8: control characters and bytes
// outside valid UTF-8 sequences become '?', valid multi-byte characters stay.
TEST(Excerpt, CutsAndEscapes) {
  EXPECT_EQ(Excerpt("short"), "short");
  EXPECT_EQ(Excerpt(std::string(200, 'x')), std::string(80, 'x') + "...");
  EXPECT_EQ(Excerpt("a\nb\tc"), "a?b?c");
  EXPECT_EQ(Excerpt("caf\xc3\xa9"), "caf\xc3\xa9");
  EXPECT_EQ(Excerpt("k\xff\xfe\xe9y"), "k???y");
  EXPECT_EQ(Excerpt("\xe2\x82"), "??");  // a cut sequence
}

}  // namespace
}  // namespace omnicml

namespace omnicml {
namespace {

// Outputs are checked before a run: directories, non-regular files, missing or
// non-directory parents and link loops are refused naming flag and path; nothing is
// created; a file inside a run directory still to be made needs that directory creatable.
TEST(CheckOutput, RefusesWhatCannotBeWritten) {
  const fs::path dir = FreshDir("check_output");
  const fs::path file = dir / "file";
  std::ofstream(file) << "x";
  const fs::path loop = dir / "loop";
  fs::create_symlink(loop, loop);
  const fs::path fifo = dir / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  const struct {
    fs::path path;
    const char* reason;
  } bad_files[] = {{dir, "is a directory"},
                   {fifo, "is a FIFO (not a regular file)"},
                   {loop, "is a symbolic link"},
                   {dir / "missing" / "map.omap", "does not exist"},
                   {file / "map.omap", "Not a directory"}};
  for (const auto& c : bad_files) {
    SCOPED_TRACE(c.path.string());
    const std::string message = ErrorOf([&] { CheckOutputFile(c.path, "--map-out"); });
    EXPECT_THAT(message, HasSubstr("--map-out"));
    EXPECT_THAT(message, HasSubstr(c.path.string()));
    EXPECT_THAT(message, HasSubstr(c.reason));
  }
  EXPECT_EQ(ErrorOf([&] { CheckOutputFile(file, "--map-out"); }), "");  // replaced atomically
  EXPECT_EQ(ErrorOf([&] { CheckOutputFile(dir / "new.omap", "--map-out"); }), "");
  // Inside a run directory the run creates (and its parents, created with it).
  EXPECT_EQ(ErrorOf([&] { CheckOutputFile(dir / "run" / "m.omap", "--map-out", dir / "run"); }),
            "");
  EXPECT_THAT(ErrorOf([&] { CheckOutputFile(file / "run" / "m", "--map-out", file / "run"); }),
              HasSubstr("Not a directory"));

  EXPECT_EQ(ErrorOf([&] { CheckOutputDirectory(dir, "--out"); }), "");
  EXPECT_EQ(ErrorOf([&] { CheckOutputDirectory(dir / "a" / "b" / "c", "--out"); }), "");
  EXPECT_THAT(ErrorOf([&] { CheckOutputDirectory(file, "--out"); }),
              HasSubstr("exists and is not a directory"));
  EXPECT_THAT(ErrorOf([&] { CheckOutputDirectory(file / "sub", "--out"); }),
              HasSubstr(file.string()));
  EXPECT_THAT(ErrorOf([&] { CheckOutputDirectory(loop, "--out"); }),
              HasSubstr("is a symbolic link"));
  const fs::path dangling = dir / "dangling";
  fs::create_symlink(dir / "nowhere", dangling);
  EXPECT_THAT(ErrorOf([&] { CheckOutputDirectory(dangling, "--out"); }),
              HasSubstr("is a symbolic link"));
  const fs::path to_dir = dir / "to_dir";
  fs::create_directory_symlink(dir, to_dir);
  EXPECT_THAT(ErrorOf([&] { CheckOutputDirectory(to_dir, "--out"); }),
              HasSubstr("is a symbolic link"));
  const fs::path to_file = dir / "to_file";
  fs::create_symlink(file, to_file);
  EXPECT_THAT(ErrorOf([&] { CheckOutputFile(to_file, "--map-out"); }),
              HasSubstr("is a symbolic link"));
  fs::remove(to_dir);
  fs::remove(to_file);
  if (::geteuid() != 0) {  // root may write anywhere
    const fs::path locked = dir / "locked";
    fs::create_directory(locked);
    fs::permissions(locked, fs::perms::owner_read | fs::perms::owner_exec);
    EXPECT_THAT(ErrorOf([&] { CheckOutputFile(locked / "m", "--map-out"); }),
                HasSubstr("not writable"));
    EXPECT_THAT(ErrorOf([&] { CheckOutputDirectory(locked / "run", "--out"); }),
                HasSubstr("not writable"));
    fs::permissions(locked, fs::perms::owner_all);
  }
  EXPECT_EQ(Entries(dir), (std::vector<std::string>{"dangling", "fifo", "file", "loop"}));
}

}  // namespace
}  // namespace omnicml
