#include "omnicml/common/file_io.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <mutex>
#include <set>
#include <system_error>

#include "omnicml/common/common.h"

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

bool ProcessIsDead(pid_t pid) { return pid > 0 && ::kill(pid, 0) == -1 && errno == ESRCH; }

fs::path DirectoryOf(const fs::path& target) {
  const fs::path dir = target.parent_path();
  return dir.empty() ? fs::path(".") : dir;
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
    pid_t pid = 0;
    if (IsAtomicTempName(it->path().filename().string(), {}, &pid) && ProcessIsDead(pid)) {
      std::error_code rm;
      fs::remove(it->path(), rm);
    }
  }
}

}  // namespace

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
    pid_t pid = 0;
    if (IsAtomicTempName(it->path().filename().string(), name, &pid) && ProcessIsDead(pid)) {
      std::error_code rm;
      if (fs::remove(it->path(), rm)) ++removed;
    }
  }
  return removed;
}

fs::path StagingDirFor(const fs::path& target, pid_t pid) {
  fs::path t = target.lexically_normal();
  if (!t.has_filename()) t = t.parent_path();
  return fs::path(StrCat(t.string(), ".partial-", static_cast<long>(pid)));
}

int RemoveStaleStagingDirs(const fs::path& target) {
  fs::path t = target.lexically_normal();
  if (!t.has_filename()) t = t.parent_path();
  const std::string name = t.filename().string();
  if (name.empty()) return 0;
  int removed = 0;
  std::error_code ec;
  for (fs::directory_iterator it(DirectoryOf(t), ec), end; !ec && it != end; it.increment(ec)) {
    const std::string entry = it->path().filename().string();
    for (const std::string_view suffix : {".partial-", ".old-"}) {
      const std::string prefix = StrCat(name, suffix);
      if (entry.size() <= prefix.size() || entry.compare(0, prefix.size(), prefix) != 0) continue;
      const std::string pid_text = entry.substr(prefix.size());
      if (!AllDigits(pid_text) || pid_text.size() > 9) continue;
      const auto pid = static_cast<pid_t>(std::stol(pid_text));
      if (pid != ::getpid() && !ProcessIsDead(pid)) continue;
      std::error_code rm;
      if (fs::remove_all(it->path(), rm) > 0 && !rm) ++removed;
    }
  }
  return removed;
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

AtomicFile::AtomicFile(fs::path target, FileSync sync) : target_(std::move(target)), sync_(sync) {
  SweepDirectoryOnce(DirectoryOf(target_));
  int err = 0;
  for (int attempt = 0; attempt < 100; ++attempt) {
    temp_ = TempPathFor(target_, ::getpid(), temp_counter.fetch_add(1));
    const int fd = ::open(temp_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd >= 0) {
      ::close(fd);
      err = 0;
      break;
    }
    err = errno;
    if (err != EEXIST) break;
  }
  if (err != 0) {
    done_ = true;  // nothing to remove
    Fail("cannot create", target_, ErrnoText(err));
  }
  out_.open(temp_, std::ios::binary | std::ios::trunc);
  if (!out_) {
    Discard();
    Fail("cannot create", target_, "cannot open the temporary file");
  }
}

AtomicFile::~AtomicFile() { Discard(); }

void AtomicFile::Commit() {
  if (done_) return;
  out_.flush();
  bool ok = static_cast<bool>(out_);
  out_.close();
  ok = ok && !out_.fail();
  if (!ok) {
    Discard();
    Fail("write error", target_, "the data could not be written (disk full?)");
  }
  // Make the data durable before the rename makes it visible under the target name.
  if (sync_ == FileSync::kFsync) {
    const int fd = ::open(temp_.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0 || ::fsync(fd) != 0) {
      const int err = errno;
      if (fd >= 0) ::close(fd);
      Discard();
      Fail("cannot write", target_, StrCat("fsync failed: ", ErrnoText(err)));
    }
    ::close(fd);
  }
  if (::rename(temp_.c_str(), target_.c_str()) != 0) {
    const int err = errno;
    Discard();
    Fail("cannot rename the temporary file onto it", target_, ErrnoText(err));
  }
  done_ = true;
  if (sync_ == FileSync::kFsync) SyncDirectory(DirectoryOf(target_));
}

void AtomicFile::Discard() {
  if (done_) return;
  done_ = true;
  if (out_.is_open()) out_.close();
  ::unlink(temp_.c_str());
}

void WriteFileAtomic(const fs::path& path, std::string_view content, FileSync sync) {
  AtomicFile file(path, sync);
  file.stream().write(content.data(), static_cast<std::streamsize>(content.size()));
  file.Commit();
}

void WriteFileAtomic(const fs::path& path, std::span<const std::uint8_t> bytes, FileSync sync) {
  WriteFileAtomic(
      path, std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()), sync);
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
  std::string out(text.substr(0, std::min(text.size(), max_chars)));
  for (char& c : out) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20 || u == 0x7f) c = '?';
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

void CheckOutputFile(const fs::path& path, std::string_view flag,
                     const fs::path& will_create_dir) {
  if (path.empty()) return;
  const fs::file_status st = StatusOrThrow(path, flag);
  if (fs::is_directory(st)) throw Error(StrCat(flag, " '", path.string(), "': is a directory"));
  if (fs::exists(st) && !fs::is_regular_file(st)) {
    throw Error(StrCat(flag, " '", path.string(), "': exists and is not a regular file"));
  }
  const fs::path dir = OutputParentOf(path);
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
    throw Error(StrCat(flag, " '", path.string(), "': directory '", dir.string(),
                       "' does not exist"));
  }
  if (!fs::is_directory(dst)) {
    throw Error(StrCat(flag, " '", path.string(), "': '", dir.string(), "' is not a directory"));
  }
  CheckWritableDirectory(dir, path, flag);
}

void CheckOutputDirectory(const fs::path& path, std::string_view flag) {
  if (path.empty()) return;
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
        throw Error(StrCat(flag, " '", path.string(), "': '", ancestor.string(),
                           "' is not a directory"));
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
