#include "omnicml/common/file_io.h"

#include <fcntl.h>
#include <openssl/evp.h>
#include <stdio.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <csignal>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>
#include <system_error>

#include "omnicml/common/common.h"
#include "omnicml/common/yaml_io.h"

namespace omnicml {
namespace fs = std::filesystem;

namespace {

constexpr std::string_view kTempMarker = ".omnicml-tmp-";

std::atomic<std::uint64_t> temp_counter{0};

std::string ErrnoText(int err) { return std::error_code(err, std::generic_category()).message(); }

// Writing errors: "<path>: <what>: <reason>".
[[noreturn]] void Fail(std::string_view what, const fs::path& path, std::string_view reason) {
  throw Error(StrCat(path.string(), ": ", what, ": ", reason));
}

// Reading errors: "<path>: cannot read <what>: <reason>".
[[noreturn]] void ReadFail(std::string_view what, const fs::path& path, std::string_view reason) {
  throw Error(StrCat(path.string(), ": cannot read ", what, ": ", reason));
}

const char* FileTypeName(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

void CheckMode(std::string_view what, const fs::path& path, mode_t mode) {
  if (!S_ISREG(mode)) {
    ReadFail(what, path, StrCat("not a regular file (", FileTypeName(mode), ")"));
  }
}

bool AllDigits(std::string_view s) {
  if (s.empty()) return false;
  for (char c : s) {
    if (c < '0' || c > '9') return false;
  }
  return true;
}

fs::path DirectoryOf(const fs::path& target) {
  const fs::path dir = target.parent_path();
  return dir.empty() ? fs::path(".") : dir;
}

// Removes `path` (an AtomicFile temporary) when no process holds its lock: the writer
// holds an flock on it from before it had a name until its rename, and the kernel drops
// the lock when the writer dies, whatever PID namespace or host it ran in.
bool RemoveIfUnlocked(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) return false;
  bool removed = false;
  struct stat opened {
  }, named{};
  if (::flock(fd, LOCK_EX | LOCK_NB) == 0 && ::fstat(fd, &opened) == 0 &&
      ::lstat(path.c_str(), &named) == 0 && S_ISREG(opened.st_mode) &&
      opened.st_ino == named.st_ino && opened.st_dev == named.st_dev) {
    removed = ::unlink(path.c_str()) == 0;
  }
  ::close(fd);  // releases the lock
  return removed;
}

// Removes stale temporaries of every target in `dir`, once per directory and process:
// a directory holding thousands of written images is listed once, not once per image.
void SweepDirectoryOnce(const fs::path& dir) {
  static std::mutex mutex;
  static std::set<std::string> swept;
  std::error_code ec;
  const std::string key = fs::absolute(dir, ec).lexically_normal().string();
  {
    std::lock_guard<std::mutex> lock(mutex);
    if (!swept.insert(key).second) return;
  }
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (IsAtomicTempName(it->path().filename().string())) RemoveIfUnlocked(it->path());
  }
}

const char* NodeTypeName(mode_t mode) {
  if (S_ISLNK(mode)) return "is a symbolic link";
  if (S_ISDIR(mode)) return "is a directory";
  if (S_ISFIFO(mode)) return "is a FIFO (not a regular file)";
  if (S_ISCHR(mode)) return "is a character device (not a regular file)";
  if (S_ISBLK(mode)) return "is a block device (not a regular file)";
  if (S_ISSOCK(mode)) return "is a socket (not a regular file)";
  return "is not a regular file";
}

std::atomic<bool> follow_output_symlinks{false};

}  // namespace

void SetFollowOutputSymlinks(bool follow) { follow_output_symlinks.store(follow); }
bool FollowOutputSymlinks() { return follow_output_symlinks.load(); }

fs::path ResolveOutputFile(const fs::path& path) {
  if (!FollowOutputSymlinks()) return path;
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0 || !S_ISLNK(st.st_mode)) return path;
  if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return path;
  std::error_code ec;
  const fs::path resolved = fs::canonical(path, ec);
  return ec ? path : resolved;
}

std::string OutputNodeProblem(const fs::path& path, bool directory) {
  struct stat st {};
  if (::lstat(path.c_str(), &st) != 0) {
    if (errno == ENOENT) return {};
    return ErrnoText(errno);
  }
  if (S_ISREG(st.st_mode) && !directory) return {};
  if (S_ISLNK(st.st_mode) && !directory && FollowOutputSymlinks()) {
    // Written through: the link must lead to a regular file.
    struct stat target {};
    if (::stat(path.c_str(), &target) != 0) {
      return errno == ENOENT
                 ? std::string("is a dangling symbolic link")
                 : StrCat("is a symbolic link that cannot be followed: ", ErrnoText(errno));
    }
    if (S_ISREG(target.st_mode)) return {};
    return StrCat("is a symbolic link to ", FileTypeName(target.st_mode), " (not a regular file)");
  }
  if (S_ISDIR(st.st_mode) && directory) return {};
  if (directory && S_ISREG(st.st_mode)) return "exists and is not a directory";
  return NodeTypeName(st.st_mode);
}

// ---------------------------------------------------------------------------------------
// Writing

fs::path TempPathFor(const fs::path& target, pid_t pid, std::uint64_t n) {
  return DirectoryOf(target) /
         StrCat(".", target.filename().string(), kTempMarker, static_cast<long>(pid), "-", n);
}

bool IsAtomicTempName(std::string_view file_name, std::string_view name, pid_t* pid) {
  if (file_name.size() < 2 || file_name.front() != '.') return false;
  const std::size_t marker = file_name.rfind(kTempMarker);
  if (marker == std::string_view::npos || marker < 1) return false;
  const std::string_view target = file_name.substr(1, marker - 1);
  if (!name.empty() && target != name) return false;
  const std::string_view rest = file_name.substr(marker + kTempMarker.size());
  const std::size_t dash = rest.find('-');
  if (dash == std::string_view::npos) return false;
  const std::string_view pid_text = rest.substr(0, dash);
  if (!AllDigits(pid_text) || !AllDigits(rest.substr(dash + 1)) || pid_text.size() > 9) {
    return false;
  }
  if (pid != nullptr) *pid = static_cast<pid_t>(std::stol(std::string(pid_text)));
  return true;
}

int RemoveStaleTemporaries(const fs::path& target) {
  const std::string name = target.filename().string();
  int removed = 0;
  std::error_code ec;
  for (fs::directory_iterator it(DirectoryOf(target), ec), end; !ec && it != end;
       it.increment(ec)) {
    if (IsAtomicTempName(it->path().filename().string(), name) && RemoveIfUnlocked(it->path())) {
      ++removed;
    }
  }
  return removed;
}

fs::path StagingDirFor(const fs::path& target, pid_t pid) {
  fs::path t = target.lexically_normal();
  if (!t.has_filename()) t = t.parent_path();
  return fs::path(StrCat(t.string(), ".partial-", static_cast<long>(pid)));
}

// For cleaning up after other writers of `target`: *t gets the target normalised (no
// trailing separator) and *lock its lock unless this process holds it already. Every
// writer of a target holds its lock, so while we hold it, what a writer left behind
// belongs to nobody alive. False (nothing to do) for a target without a file name or one
// another process is writing.
bool LockForCleanup(const fs::path& target, fs::path* t, std::unique_ptr<OutputLock>* lock) {
  *t = target.lexically_normal();
  if (!t->has_filename()) *t = t->parent_path();
  const std::string name = t->filename().string();
  if (name.empty() || name == "." || name == "..") return false;
  if (OutputLock::HeldByThisProcess(*t)) return true;
  try {
    *lock = std::make_unique<OutputLock>(*t, "output");
  } catch (const Error&) {
    return false;  // another process is writing it
  }
  return true;
}

int RemoveStaleStagingDirs(const fs::path& target) {
  fs::path t;
  std::unique_ptr<OutputLock> lock;
  if (!LockForCleanup(target, &t, &lock)) return 0;
  int removed = 0;
  std::error_code ec;
  for (fs::directory_iterator it(DirectoryOf(t), ec), end; !ec && it != end; it.increment(ec)) {
    const std::string entry = it->path().filename().string();
    for (const std::string_view suffix : {".partial-", ".old-"}) {
      const std::string prefix = StrCat(t.filename().string(), suffix);
      if (entry.size() <= prefix.size() || entry.compare(0, prefix.size(), prefix) != 0) continue;
      const std::string pid_text = entry.substr(prefix.size());
      if (!AllDigits(pid_text) || pid_text.size() > 9) continue;
      std::error_code rm;
      if (fs::remove_all(it->path(), rm) > 0 && !rm) ++removed;
    }
  }
  return removed;
}

// ---------------------------------------------------------------------------------------
// Output locks

namespace {

struct HeldLock {
  int fd = -1;
  int count = 0;
  fs::path lock_path;
};

std::mutex& LockRegistryMutex() {
  static std::mutex mutex;
  return mutex;
}
std::map<std::string, HeldLock>& LockRegistry() {
  static std::map<std::string, HeldLock> registry;
  return registry;
}

// The lock file's path made absolute with its directory resolved, so that two spellings
// of one output ("runs/a", "./runs/a/") share a key.
std::string LockKey(const fs::path& lock_path) {
  std::error_code ec;
  fs::path dir = fs::weakly_canonical(fs::absolute(DirectoryOf(lock_path), ec), ec);
  return (dir / lock_path.filename()).string();
}

std::string HolderText(int fd) {
  char buf[256] = {};
  const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
  std::string text = n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string();
  while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.pop_back();
  return text.empty() ? std::string("holder unknown") : Excerpt(text, 120);
}

}  // namespace

fs::path OutputLock::LockPathFor(const fs::path& target) {
  fs::path t = ResolveOutputFile(target).lexically_normal();
  if (!t.has_filename()) t = t.parent_path();
  return DirectoryOf(t) / StrCat(".", t.filename().string(), ".omnicml-lock");
}

bool OutputLock::HeldByThisProcess(const fs::path& target) {
  const std::string key = LockKey(LockPathFor(target));
  std::lock_guard<std::mutex> guard(LockRegistryMutex());
  return LockRegistry().count(key) > 0;
}

OutputLock::OutputLock(const fs::path& target, std::string_view flag) {
  const fs::path lock_path = LockPathFor(target);
  key_ = LockKey(lock_path);
  std::lock_guard<std::mutex> guard(LockRegistryMutex());
  auto& registry = LockRegistry();
  if (auto it = registry.find(key_); it != registry.end()) {
    ++it->second.count;
    return;
  }
  // A directory output may be made with its parents: they are made now, to hold the lock.
  std::error_code ec;
  fs::create_directories(DirectoryOf(lock_path), ec);
  for (int attempt = 0; attempt < 100; ++attempt) {
    const int fd =
        ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_NOFOLLOW | O_CLOEXEC | O_NOCTTY, 0666);
    if (fd < 0) {
      throw Error(StrCat(flag, " '", target.string(), "': cannot create the lock file '",
                         lock_path.string(), "': ", ErrnoText(errno)));
    }
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      const int err = errno;
      const std::string holder = HolderText(fd);
      ::close(fd);
      if (err == EWOULDBLOCK) {
        throw Error(StrCat(flag, " '", target.string(), "': in use by another writer (", holder,
                           "; lock file '", lock_path.string(),
                           "'); wait for it to finish or choose another path"));
      }
      throw Error(StrCat(flag, " '", target.string(), "': cannot lock '", lock_path.string(),
                         "': ", ErrnoText(err)));
    }
    // The previous holder may have removed the file between our open and our lock: then
    // we hold a lock on a file nobody else can find; start again.
    struct stat opened {
    }, named{};
    if (::fstat(fd, &opened) != 0 || ::lstat(lock_path.c_str(), &named) != 0 ||
        opened.st_ino != named.st_ino || opened.st_dev != named.st_dev) {
      ::close(fd);
      continue;
    }
    char host[256] = {};
    ::gethostname(host, sizeof host - 1);
    const std::string holder =
        StrCat("pid ", static_cast<long>(::getpid()), " on host ", host, "\n");
    if (::ftruncate(fd, 0) == 0) {
      [[maybe_unused]] const ssize_t n = ::pwrite(fd, holder.data(), holder.size(), 0);
    }
    registry[key_] = HeldLock{fd, 1, lock_path};
    return;
  }
  throw Error(StrCat(flag, " '", target.string(), "': cannot lock '", lock_path.string(),
                     "': the lock file keeps changing"));
}

OutputLock::~OutputLock() {
  std::lock_guard<std::mutex> guard(LockRegistryMutex());
  auto& registry = LockRegistry();
  auto it = registry.find(key_);
  if (it == registry.end() || --it->second.count > 0) return;
  // Unlink while holding the lock; a waiter that opened the old file sees the inode
  // change and starts again.
  ::unlink(it->second.lock_path.c_str());
  ::close(it->second.fd);
  registry.erase(it);
}

// ---------------------------------------------------------------------------------------
// Staged directories

void CheckReplaceableDirectory(const fs::path& target, std::string_view flag,
                               const std::vector<std::string>& markers) {
  const std::string problem = OutputNodeProblem(target, /*directory=*/true);
  if (!problem.empty()) throw Error(StrCat(flag, " '", target.string(), "': ", problem));
  std::error_code ec;
  if (!fs::exists(fs::symlink_status(target, ec)) || fs::is_empty(target, ec)) return;
  for (const std::string& marker : markers) {
    if (fs::exists(fs::symlink_status(target / marker, ec))) return;
  }
  std::string names;
  for (const std::string& m : markers) names += (names.empty() ? "" : ", ") + m;
  throw Error(StrCat(flag, " '", target.string(),
                     "': exists, is not empty and is not an output of this kind (none of ", names,
                     "); the whole directory would be replaced: choose a new or empty directory"));
}

StagedDirectory::StagedDirectory(fs::path target, std::string_view flag,
                                 std::vector<std::string> markers)
    : target_([&] {
        fs::path t = target.lexically_normal();
        if (!t.has_filename()) t = t.parent_path();
        return t;
      }()),
      flag_(flag),
      lock_(target_, flag) {
  const std::string name = target_.filename().string();
  if (name.empty() || name == "." || name == "..") {
    throw Error(StrCat(flag, " '", target.string(), "': name a directory (not '.' or '..')"));
  }
  // A commit a killed writer left half done is settled first (old or new, never mixed).
  RecoverInterruptedCommits(target_);
  CheckReplaceableDirectory(target_, flag, markers);
  RemoveStaleStagingDirs(target_);
  staging_ = StagingDirFor(target_, ::getpid());
  std::error_code ec;
  fs::create_directories(DirectoryOf(target_), ec);
  if (ec) {
    throw Error(
        StrCat(flag, " '", target_.string(), "': cannot create its parent: ", ec.message()));
  }
  fs::remove_all(staging_, ec);
  if (!fs::create_directory(staging_, ec) || ec) {
    throw Error(StrCat(flag, " '", target_.string(), "': cannot create '", staging_.string(),
                       "': ", ec ? ec.message() : "exists"));
  }
}

StagedDirectory::~StagedDirectory() {
  if (done_) return;
  std::error_code ec;
  fs::remove_all(staging_, ec);
}

namespace {

constexpr const char* kCommitJournal = ".omnicml-commit";

// One companion of a staged commit, as its journal records it.
struct JournalEntry {
  fs::path target;    // absolute
  fs::path previous;  // absolute; its previous version, or empty when it did not exist
  dev_t dev = 0;      // identity of the new file (the companion's temporary, renamed)
  ino_t ino = 0;
};

std::string HexOf(const std::string& bytes) {
  static const char* kHex = "0123456789abcdef";
  std::string out;
  for (unsigned char c : bytes) {
    out += kHex[c >> 4];
    out += kHex[c & 15];
  }
  return out.empty() ? std::string("-") : out;
}

bool FromHex(const std::string& hex, std::string* bytes) {
  bytes->clear();
  if (hex == "-") return true;
  if (hex.size() % 2 != 0) return false;
  const auto nibble = [](char c) {
    return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
  };
  for (std::size_t i = 0; i < hex.size(); i += 2) {
    const int hi = nibble(hex[i]), lo = nibble(hex[i + 1]);
    if (hi < 0 || lo < 0) return false;
    bytes->push_back(static_cast<char>(hi * 16 + lo));
  }
  return true;
}

// "omnicml-commit 1" then one line per entry: hex(target) hex(previous) dev ino (paths
// in hex: any byte may occur in a file name).
std::string JournalText(const std::vector<JournalEntry>& entries) {
  std::string text = "omnicml-commit 1\n";
  for (const JournalEntry& e : entries) {
    text += StrCat(HexOf(e.target.string()), " ", HexOf(e.previous.string()), " ",
                   static_cast<unsigned long long>(e.dev), " ",
                   static_cast<unsigned long long>(e.ino), "\n");
  }
  return text;
}

// The entries of a journal file; false when it is missing or not a journal.
bool ReadJournal(const fs::path& path, std::vector<JournalEntry>* entries) {
  entries->clear();
  std::string text;
  try {
    text = ReadTextFile(path, 1u << 20, "commit journal");
  } catch (const Error&) {
    return false;
  }
  std::istringstream in(text);
  std::string line;
  if (!std::getline(in, line) || line != "omnicml-commit 1") return false;
  while (std::getline(in, line)) {
    std::istringstream fields(line);
    std::string target, previous;
    unsigned long long dev = 0, ino = 0;
    if (!(fields >> target >> previous >> dev >> ino)) return false;
    JournalEntry e;
    std::string bytes;
    if (!FromHex(target, &bytes) || bytes.empty()) return false;
    e.target = bytes;
    if (!FromHex(previous, &bytes)) return false;
    e.previous = bytes;
    e.dev = static_cast<dev_t>(dev);
    e.ino = static_cast<ino_t>(ino);
    entries->push_back(std::move(e));
  }
  return true;
}

// ".<name>.omnicml-prev-<pid>" beside `target`: where its previous version is kept
// while a staged commit is under way.
fs::path PreviousPathFor(const fs::path& target, pid_t pid) {
  return DirectoryOf(target) /
         StrCat(".", target.filename().string(), ".omnicml-prev-", static_cast<long>(pid));
}

// Keeps `target`'s current file as `previous`: a hard link, or a durable copy where the
// file system has no hard links. Throws omnicml::Error naming the target.
void KeepPrevious(const fs::path& target, const fs::path& previous) {
  ::unlink(previous.c_str());
  if (::link(target.c_str(), previous.c_str()) == 0) return;
  std::error_code ec;
  fs::copy_file(target, previous, fs::copy_options::overwrite_existing, ec);
  if (!ec) {
    const int fd = ::open(previous.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd >= 0 && ::fsync(fd) == 0) {
      ::close(fd);
      return;
    }
    if (fd >= 0) ::close(fd);
  }
  ::unlink(previous.c_str());
  Fail("cannot keep the previous version", target, ec ? ec.message() : "fsync failed");
}

bool IsFile(const fs::path& path, dev_t dev, ino_t ino) {
  struct stat st {};
  return ::lstat(path.c_str(), &st) == 0 && st.st_dev == dev && st.st_ino == ino;
}

// Puts every companion that already replaced its target back to its previous version
// (or removes it when there was none); removes previous versions not needed. Never
// throws.
void RollBack(const std::vector<JournalEntry>& entries) {
  for (const JournalEntry& e : entries) {
    struct stat st {};
    const bool has_previous = !e.previous.empty() && ::lstat(e.previous.c_str(), &st) == 0;
    if (IsFile(e.target, e.dev, e.ino)) {
      if (has_previous) {
        ::rename(e.previous.c_str(), e.target.c_str());
      } else if (e.previous.empty()) {
        ::unlink(e.target.c_str());
      }
    }
    if (!e.previous.empty()) ::unlink(e.previous.c_str());
    SyncDirectory(DirectoryOf(e.target));
  }
}

// Removes the previous versions of committed companions. Never throws.
void Settle(const std::vector<JournalEntry>& entries) {
  for (const JournalEntry& e : entries) {
    if (!e.previous.empty() && ::unlink(e.previous.c_str()) == 0) {
      SyncDirectory(DirectoryOf(e.target));
    }
  }
}

}  // namespace

void TestKillPoint(std::string_view point) {
  const char* at = std::getenv("OMNICML_TEST_KILL_AT");
  if (at != nullptr && point == at) ::raise(SIGKILL);
}

int RecoverInterruptedCommits(const fs::path& target) {
  fs::path t;
  std::unique_ptr<OutputLock> lock;
  if (!LockForCleanup(target, &t, &lock)) return 0;
  int settled = 0;
  std::vector<JournalEntry> entries;
  // Committed: the journal moved into the target with the directory.
  if (ReadJournal(t / kCommitJournal, &entries)) {
    Settle(entries);
    ::unlink((t / kCommitJournal).c_str());
    SyncDirectory(t);
    ++settled;
  }
  // Not committed: the journal is still in a staging directory of a dead writer.
  std::error_code ec;
  const std::string prefix = StrCat(t.filename().string(), ".partial-");
  for (fs::directory_iterator it(DirectoryOf(t), ec), end; !ec && it != end; it.increment(ec)) {
    const std::string entry = it->path().filename().string();
    if (entry.size() <= prefix.size() || entry.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string pid_text = entry.substr(prefix.size());
    if (!AllDigits(pid_text) || pid_text.size() > 9) continue;
    if (!ReadJournal(it->path() / kCommitJournal, &entries)) continue;
    RollBack(entries);
    // The old directory moved aside (no RENAME_EXCHANGE) and the new one not renamed in.
    const fs::path old = StrCat(t.string(), ".old-", pid_text);
    struct stat st {};
    if (::lstat(t.c_str(), &st) != 0 && ::lstat(old.c_str(), &st) == 0) {
      ::rename(old.c_str(), t.c_str());
    }
    ::unlink((it->path() / kCommitJournal).c_str());
    SyncDirectory(DirectoryOf(t));
    ++settled;
  }
  return settled;
}

void StagedDirectory::Commit(std::span<AtomicFile* const> companions) {
  if (done_) return;
  SyncFileSystem(staging_);  // every file durable before the directory appears by name
  std::vector<JournalEntry> entries;
  if (!companions.empty()) {
    for (AtomicFile* file : companions) {
      file->Sync();
      JournalEntry e;
      e.target = fs::absolute(file->target()).lexically_normal();
      struct stat st {};
      if (::lstat(file->temp_path().c_str(), &st) != 0) {
        Fail("cannot commit", file->target(),
             StrCat("its temporary file vanished: ", ErrnoText(errno)));
      }
      e.dev = st.st_dev;
      e.ino = st.st_ino;
      if (::lstat(e.target.c_str(), &st) == 0) e.previous = PreviousPathFor(e.target, ::getpid());
      entries.push_back(std::move(e));
    }
    WriteFileAtomic(staging_ / kCommitJournal, JournalText(entries));
    try {
      for (const JournalEntry& e : entries) {
        if (!e.previous.empty()) KeepPrevious(e.target, e.previous);
      }
      for (AtomicFile* file : companions) file->Commit();
      TestKillPoint("staged-commit-swap");
      SwapIntoPlace();
    } catch (...) {
      RollBack(entries);
      throw;
    }
    TestKillPoint("staged-commit-settle");
    Settle(entries);
    ::unlink((target_ / kCommitJournal).c_str());
    SyncDirectory(target_);
    return;
  }
  SwapIntoPlace();
}

void StagedDirectory::SwapIntoPlace() {
  const fs::path parent = DirectoryOf(target_);
  std::error_code ec;
  if (fs::exists(fs::symlink_status(target_, ec))) {
    const std::string problem = OutputNodeProblem(target_, /*directory=*/true);
    if (!problem.empty()) throw Error(StrCat(flag_, " '", target_.string(), "': ", problem));
    // Swap the new directory in atomically, then delete the old one (now under the
    // staging name).
    if (::renameat2(AT_FDCWD, staging_.c_str(), AT_FDCWD, target_.c_str(), RENAME_EXCHANGE) == 0) {
      done_ = true;
      SyncDirectory(parent);
      fs::remove_all(staging_, ec);
      return;
    }
    // File systems without RENAME_EXCHANGE: move the old directory aside first.
    const fs::path old = StrCat(target_.string(), ".old-", static_cast<long>(::getpid()));
    fs::remove_all(old, ec);
    fs::rename(target_, old, ec);
    if (ec) {
      throw Error(StrCat(flag_, " '", target_.string(),
                         "': cannot move the old directory aside: ", ec.message()));
    }
    fs::rename(staging_, target_, ec);
    if (ec) {
      std::error_code back;
      fs::rename(old, target_, back);  // keep the old directory where it was
      throw Error(StrCat(flag_, " '", target_.string(), "': cannot rename '", staging_.string(),
                         "' onto it: ", ec.message()));
    }
    done_ = true;
    SyncDirectory(parent);
    fs::remove_all(old, ec);
    return;
  }
  fs::rename(staging_, target_, ec);
  if (ec) {
    throw Error(StrCat(flag_, " '", target_.string(), "': cannot rename '", staging_.string(),
                       "' onto it: ", ec.message()));
  }
  done_ = true;
  SyncDirectory(parent);
}

namespace {

std::string HexDigest(const unsigned char* digest, unsigned int size) {
  static const char* kHex = "0123456789abcdef";
  std::string out;
  for (unsigned int i = 0; i < size; ++i) {
    out += kHex[digest[i] >> 4];
    out += kHex[digest[i] & 15];
  }
  return out;
}

}  // namespace

std::string Sha256Hex(std::span<const std::uint8_t> bytes) {
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int size = 0;
  if (::EVP_Digest(bytes.data(), bytes.size(), digest, &size, ::EVP_sha256(), nullptr) != 1) {
    throw InternalError("SHA-256 failed");
  }
  return HexDigest(digest, size);
}

std::string Sha256OfFile(const fs::path& path) {
  const int fd = OpenRegularFile(path, "file");
  std::unique_ptr<EVP_MD_CTX, void (*)(EVP_MD_CTX*)> ctx(::EVP_MD_CTX_new(), ::EVP_MD_CTX_free);
  if (!ctx || ::EVP_DigestInit_ex(ctx.get(), ::EVP_sha256(), nullptr) != 1) {
    ::close(fd);
    throw InternalError("SHA-256 failed");
  }
  std::vector<unsigned char> buffer(1 << 20);
  for (;;) {
    const ssize_t n = ::read(fd, buffer.data(), buffer.size());
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int err = errno;
      ::close(fd);
      ReadFail("file", path, StrCat("read error: ", ErrnoText(err)));
    }
    if (n == 0) break;
    ::EVP_DigestUpdate(ctx.get(), buffer.data(), static_cast<std::size_t>(n));
  }
  ::close(fd);
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int size = 0;
  ::EVP_DigestFinal_ex(ctx.get(), digest, &size);
  return HexDigest(digest, size);
}

void SyncDirectory(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

void SyncFileSystem(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) Fail("cannot sync", path, ErrnoText(errno));
  const int rc = ::syncfs(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) Fail("cannot sync", path, ErrnoText(err));
}

namespace {

// Creates the temporary of `temp` locked before it has a name: an O_TMPFILE file is
// locked, then linked under `temp`, so a sweeper never sees it unlocked. On file systems
// without O_TMPFILE the named file is created and locked at once. Returns the open,
// locked descriptor, or -1 with errno set.
int CreateLockedTemporary(const fs::path& dir, const fs::path& temp) {
  const int anon = ::open(dir.c_str(), O_TMPFILE | O_WRONLY | O_CLOEXEC, 0666);
  if (anon >= 0) {
    if (::flock(anon, LOCK_EX) == 0) {
      const std::string proc = StrCat("/proc/self/fd/", anon);
      if (::linkat(AT_FDCWD, proc.c_str(), AT_FDCWD, temp.c_str(), AT_SYMLINK_FOLLOW) == 0) {
        return anon;
      }
      const int err = errno;
      if (err == EEXIST) {
        ::close(anon);
        errno = EEXIST;
        return -1;
      }
    }
    ::close(anon);  // no /proc or no link support: the named way below
  }
  const int fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd < 0) return -1;
  ::flock(fd, LOCK_EX);
  return fd;
}

}  // namespace

AtomicFile::AtomicFile(fs::path target, FileSync sync)
    : target_(ResolveOutputFile(target)), sync_(sync) {
  done_ = true;  // nothing to remove until the temporary exists
  if (const std::string problem = OutputNodeProblem(target_, false); !problem.empty()) {
    Fail("cannot create", target_, problem);
  }
  const fs::path dir = DirectoryOf(target_);
  SweepDirectoryOnce(dir);
  int err = 0;
  for (int attempt = 0; attempt < 100; ++attempt) {
    temp_ = TempPathFor(target_, ::getpid(), temp_counter.fetch_add(1));
    fd_ = CreateLockedTemporary(dir, temp_);
    if (fd_ >= 0) {
      err = 0;
      break;
    }
    err = errno;
    if (err != EEXIST) break;
  }
  if (err != 0) Fail("cannot create", target_, ErrnoText(err));
  done_ = false;
  out_.open(temp_, std::ios::binary | std::ios::trunc);
  if (!out_) {
    Discard();
    Fail("cannot create", target_, "cannot open the temporary file");
  }
}

AtomicFile::~AtomicFile() { Discard(); }

void AtomicFile::Close() {
  if (closed_) return;
  out_.flush();
  bool ok = static_cast<bool>(out_);
  out_.close();
  ok = ok && !out_.fail();
  closed_ = true;
  if (!ok) {
    Discard();
    Fail("write error", target_, "the data could not be written (disk full?)");
  }
}

void AtomicFile::Sync() {
  if (done_ || synced_) return;
  Close();
  if (::fsync(fd_) != 0) {
    const int err = errno;
    Discard();
    Fail("cannot write", target_, StrCat("fsync failed: ", ErrnoText(err)));
  }
  synced_ = true;
}

void AtomicFile::Commit() {
  if (done_) return;
  // Make the data durable before the rename makes it visible under the target name.
  if (sync_ == FileSync::kFsync) {
    Sync();
  } else {
    Close();
  }
  // The target may have been replaced by a device, FIFO or link since the start.
  if (const std::string problem = OutputNodeProblem(target_, false); !problem.empty()) {
    Discard();
    Fail("cannot replace", target_, problem);
  }
  if (::rename(temp_.c_str(), target_.c_str()) != 0) {
    const int err = errno;
    Discard();
    Fail("cannot rename the temporary file onto it", target_, ErrnoText(err));
  }
  done_ = true;
  ::close(fd_);
  fd_ = -1;
  if (sync_ == FileSync::kFsync) SyncDirectory(DirectoryOf(target_));
}

void AtomicFile::Discard() {
  if (done_) return;
  done_ = true;
  if (out_.is_open()) out_.close();
  ::unlink(temp_.c_str());  // before the lock goes, so no sweeper races for it
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void WriteFileAtomic(const fs::path& path, std::string_view content, FileSync sync) {
  AtomicFile file(path, sync);
  file.stream().write(content.data(), static_cast<std::streamsize>(content.size()));
  file.Commit();
}

void WriteFileAtomic(const fs::path& path, std::span<const std::uint8_t> bytes, FileSync sync) {
  WriteFileAtomic(path, std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()),
                  sync);
}

// ---------------------------------------------------------------------------------------
// Reading

int OpenRegularFile(const fs::path& path, std::string_view what, std::uintmax_t* size) {
  // stat() first: a device or FIFO is rejected without being opened at all.
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    const int err = errno;
    ReadFail(what, path,
             err == ENOENT ? std::string("does not exist (missing file)") : ErrnoText(err));
  }
  CheckMode(what, path, st.st_mode);
  // O_NONBLOCK: should a FIFO have been swapped in meanwhile, open() does not wait for
  // a writer; the fstat() below then rejects it.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) ReadFail(what, path, ErrnoText(errno));
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    const mode_t mode = st.st_mode;
    ::close(fd);
    CheckMode(what, path, mode);
    ReadFail(what, path, "cannot be examined");
  }
  const int flags = ::fcntl(fd, F_GETFL);
  if (flags >= 0) ::fcntl(fd, F_SETFL, flags & ~O_NONBLOCK);
  if (size != nullptr) *size = static_cast<std::uintmax_t>(st.st_size);
  return fd;
}

std::uintmax_t CheckRegularFile(const fs::path& path, std::string_view what) {
  std::uintmax_t size = 0;
  ::close(OpenRegularFile(path, what, &size));
  return size;
}

namespace {

// Reads all of a regular file into a std::string or std::vector<std::uint8_t>.
template <typename Buffer>
Buffer ReadAll(const fs::path& path, std::uintmax_t max_bytes, std::string_view what) {
  std::uintmax_t size = 0;
  const int fd = OpenRegularFile(path, what, &size);
  Buffer out;
  try {
    if (size > max_bytes) {
      ReadFail(what, path, StrCat("too large (", size, " bytes; the limit is ", max_bytes, ")"));
    }
    out.resize(static_cast<std::size_t>(size));
    std::size_t used = 0;
    for (;;) {
      if (used == out.size()) {
        // The file may have grown since fstat(); read on, within the limit.
        if (out.size() >= max_bytes + 1) break;
        out.resize(static_cast<std::size_t>(
            std::min<std::uintmax_t>(max_bytes + 1, std::max<std::size_t>(4096, 2 * out.size()))));
      }
      const ssize_t n = ::read(fd, reinterpret_cast<char*>(out.data()) + used, out.size() - used);
      if (n < 0) {
        if (errno == EINTR) continue;
        ReadFail(what, path, StrCat("read error: ", ErrnoText(errno)));
      }
      if (n == 0) break;
      used += static_cast<std::size_t>(n);
    }
    if (used > max_bytes) {
      ReadFail(what, path, StrCat("too large (more than ", max_bytes, " bytes)"));
    }
    out.resize(used);
  } catch (...) {
    ::close(fd);
    throw;
  }
  ::close(fd);
  return out;
}

}  // namespace

std::string ReadTextFile(const fs::path& path, std::uintmax_t max_bytes, std::string_view what) {
  return ReadAll<std::string>(path, max_bytes, what);
}

std::vector<std::uint8_t> ReadBinaryFile(const fs::path& path, std::uintmax_t max_bytes,
                                         std::string_view what) {
  return ReadAll<std::vector<std::uint8_t>>(path, max_bytes, what);
}

std::string Excerpt(std::string_view text, std::size_t max_chars) {
  const std::string_view cut = text.substr(0, std::min(text.size(), max_chars));
  std::string out;
  out.reserve(cut.size());
  // Valid UTF-8 sequences are kept; control characters and every byte that is not part of
  // a valid sequence become '?', so no raw binary reaches a terminal or a log.
  for (std::size_t i = 0; i < cut.size();) {
    const auto u = static_cast<unsigned char>(cut[i]);
    if (u < 0x80) {
      out += (u < 0x20 || u == 0x7f) ? '?' : static_cast<char>(u);
      ++i;
      continue;
    }
    const std::size_t length = u >= 0xF0 ? 4 : u >= 0xE0 ? 3 : u >= 0xC2 ? 2 : 0;
    if (length > 0 && i + length <= cut.size() && FirstNonUtf8Line(cut.substr(i, length)) == 0) {
      out.append(cut.substr(i, length));
      i += length;
    } else {
      out += '?';
      ++i;
    }
  }
  if (text.size() > max_chars) out += "...";
  return out;
}

LineReader::LineReader(const fs::path& path, std::string_view what, std::size_t max_line_bytes)
    : path_(path), what_(what), max_line_bytes_(max_line_bytes) {
  fd_ = OpenRegularFile(path_, what_);
}

LineReader::~LineReader() {
  if (fd_ >= 0) ::close(fd_);
}

bool LineReader::Fill() {
  if (eof_) return false;
  if (pos_ > 0) {
    buffer_.erase(0, pos_);
    pos_ = 0;
  }
  constexpr std::size_t kChunk = 64 << 10;
  const std::size_t old = buffer_.size();
  buffer_.resize(old + kChunk);
  for (;;) {
    const ssize_t n = ::read(fd_, buffer_.data() + old, kChunk);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int err = errno;
      buffer_.resize(old);
      ReadFail(what_, path_, StrCat("read error: ", ErrnoText(err)));
    }
    buffer_.resize(old + static_cast<std::size_t>(n));
    if (n == 0) eof_ = true;
    return n > 0;
  }
}

bool LineReader::Next(std::string* line) {
  std::size_t searched = pos_;
  for (;;) {
    const std::size_t nl = buffer_.find('\n', searched);
    std::size_t end = nl;
    if (nl == std::string::npos) {
      const std::size_t pending = buffer_.size() - pos_;
      if (pending > max_line_bytes_ + 1) {
        end = buffer_.size();  // too long; reported below
      } else if (eof_ || !Fill()) {
        if (pos_ >= buffer_.size()) return false;
        end = buffer_.size();  // last line without a line break
      } else {
        searched = pos_ + pending;  // Fill() moved the pending bytes to the front
        continue;
      }
    }
    std::size_t stop = end;
    if (stop > pos_ && buffer_[stop - 1] == '\r') --stop;
    ++line_number_;
    if (stop - pos_ > max_line_bytes_) {
      throw Error(StrCat(path_.string(), ":", line_number_, ": line longer than ", max_line_bytes_,
                         " bytes (", what_, ")"));
    }
    line->assign(buffer_, pos_, stop - pos_);
    pos_ = (nl == std::string::npos) ? buffer_.size() : nl + 1;
    return true;
  }
}

// ---------------------------------------------------------------------------------------
// Output checks

namespace {

// The status of `path` (following links); throws naming flag and path when it cannot be
// determined (a link loop, a file as a parent directory) or `path` is a dangling link.
fs::file_status StatusOrThrow(const fs::path& path, std::string_view flag) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec && ec != std::errc::no_such_file_or_directory) {
    throw Error(StrCat(flag, " '", path.string(), "': ", ec.message()));
  }
  if (!fs::exists(st)) {
    std::error_code lec;
    if (fs::is_symlink(fs::symlink_status(path, lec))) {
      throw Error(StrCat(flag, " '", path.string(), "': dangling symbolic link"));
    }
  }
  return st;
}

void CheckWritableDirectory(const fs::path& dir, const fs::path& path, std::string_view flag) {
  if (::access(dir.c_str(), W_OK | X_OK) != 0) {
    throw Error(StrCat(flag, " '", path.string(), "': directory '", dir.string(),
                       "' is not writable: ", std::strerror(errno)));
  }
}

fs::path OutputParentOf(const fs::path& path) {
  fs::path p = path.lexically_normal();
  if (!p.has_filename()) p = p.parent_path();
  fs::path parent = p.parent_path();
  return parent.empty() ? fs::path(".") : parent;
}

}  // namespace

void CheckOutputNode(const fs::path& path, std::string_view flag, bool directory) {
  if (path.empty()) return;
  const std::string problem = OutputNodeProblem(path, directory);
  if (!problem.empty()) throw Error(StrCat(flag, " '", path.string(), "': ", problem));
}

void CheckOutputFile(const fs::path& path, std::string_view flag, const fs::path& will_create_dir) {
  if (path.empty()) return;
  CheckOutputNode(path, flag);
  const fs::file_status st = StatusOrThrow(path, flag);
  if (fs::is_directory(st)) throw Error(StrCat(flag, " '", path.string(), "': is a directory"));
  if (fs::exists(st) && !fs::is_regular_file(st)) {
    throw Error(StrCat(flag, " '", path.string(), "': exists and is not a regular file"));
  }
  const fs::path dir = OutputParentOf(ResolveOutputFile(path));
  if (!will_create_dir.empty()) {
    std::error_code ec;
    const fs::path a = fs::weakly_canonical(fs::absolute(dir), ec);
    const fs::path b = fs::weakly_canonical(fs::absolute(will_create_dir), ec);
    if (!ec && a == b) {
      CheckOutputDirectory(will_create_dir, flag);
      return;
    }
  }
  const fs::file_status dst = StatusOrThrow(dir, flag);
  if (!fs::exists(dst)) {
    throw Error(
        StrCat(flag, " '", path.string(), "': directory '", dir.string(), "' does not exist"));
  }
  if (!fs::is_directory(dst)) {
    throw Error(StrCat(flag, " '", path.string(), "': '", dir.string(), "' is not a directory"));
  }
  CheckWritableDirectory(dir, path, flag);
}

void CheckOutputDirectory(const fs::path& path, std::string_view flag) {
  if (path.empty()) return;
  CheckOutputNode(path, flag, /*directory=*/true);
  const fs::file_status st = StatusOrThrow(path, flag);
  if (fs::exists(st)) {
    if (!fs::is_directory(st)) {
      throw Error(StrCat(flag, " '", path.string(), "': exists and is not a directory"));
    }
    CheckWritableDirectory(path, path, flag);
    return;
  }
  // The nearest existing ancestor must be a writable directory.
  fs::path ancestor = OutputParentOf(path);
  for (int depth = 0; depth < 256; ++depth) {
    const fs::file_status ast = StatusOrThrow(ancestor, flag);
    if (fs::exists(ast)) {
      if (!fs::is_directory(ast)) {
        throw Error(
            StrCat(flag, " '", path.string(), "': '", ancestor.string(), "' is not a directory"));
      }
      CheckWritableDirectory(ancestor, path, flag);
      return;
    }
    const fs::path up = OutputParentOf(ancestor);
    if (up == ancestor) break;
    ancestor = up;
  }
  throw Error(StrCat(flag, " '", path.string(), "': no existing parent directory"));
}

}  // namespace omnicml
