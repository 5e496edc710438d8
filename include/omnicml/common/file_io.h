// File input and output shared by every module: the one atomic writer, the output-path
// checks, the output locks and the bounded, regular-file-only readers.
//
// Writing. Every output file goes through AtomicFile (or WriteFileAtomic, which wraps it):
// the bytes go to a temporary file in the target's directory named
//   ".<name>.omnicml-tmp-<pid>-<n>"            (TempPathFor(target, pid, n))
// which is flushed, fsync'ed, renamed over the target, and then the directory is
// fsync'ed. A reader therefore sees either the old file or the complete new one, and
// after a crash the target is one of the two. On any failure, or when the AtomicFile is
// destroyed without Commit() (an exception unwound the stack), the temporary is removed
// and the target is untouched. The writer holds an flock on its temporary from before the
// file has a name (O_TMPFILE, then linked) until it is renamed; temporaries left by a
// process killed with SIGKILL are recognisable by IsAtomicTempName() and by a lock nobody
// holds, and the next AtomicFile in the same directory removes them. Liveness is decided
// by the lock, never by the pid, which may belong to another PID namespace or host.
// Readers open files by their exact names, so they never pick a temporary up.
//
// What an output may be. An output path is a regular file or nothing (a new name in an
// existing, writable directory); a directory output is a directory or nothing. Devices,
// FIFOs, sockets, symbolic links (also to a regular file) and, for files, directories are
// refused with an omnicml::Error naming the path: CheckOutputNode() before any work, and
// AtomicFile again when it opens and when it renames, so nothing is ever renamed over a
// device (/dev/null) or through a link. One process-wide exception, off by default
// (SetFollowOutputSymlinks, the CLI's --follow-output-symlinks): an output file that is
// a symbolic link to a regular file is then written through, i.e. the file the link
// resolves to is replaced atomically and the link stays; links to anything else (a
// device, a directory, nothing) are still refused, and directory outputs never follow.
//
// Two writers. OutputLock takes an advisory lock (flock) on ".<name>.omnicml-lock"
// beside an output; a second process asking for the same output refuses at once with an
// Error naming the path and the holder's pid and host. The lock file is removed on
// release. The directories above the output are created when missing (a run directory
// may be made with its parents).
//
// Directory outputs (a log, a run directory) are assembled in a staging directory
// "<target>.partial-<pid>" (StagingDirFor, StagedDirectory) next to the target and
// renamed onto it when complete (exchanged with an existing target, which is then
// removed); the writer holds the target's OutputLock throughout, so a staging or
// ".old-<pid>" sibling found by a writer holding that lock belongs to a dead process and
// RemoveStaleStagingDirs() removes it.
//
// Reading. Inputs are read only when they are regular files: OpenRegularFile() opens
// without blocking (a FIFO does not hang), then rejects directories, FIFOs, sockets,
// devices (/dev/zero, also through a symbolic link) and symbolic-link loops with an
// omnicml::Error naming the path; apps map that Error to exit code 2. Reads are bounded:
// a whole file by a byte limit checked against its size before anything is allocated,
// a line-oriented file (CSV) by a per-line limit.
//
// Error messages are one line and start with the path: "<path>: cannot read <what>:
// <reason>", "<path>:<line>: line longer than N bytes (<what>)", "<path>: cannot
// create: <reason>". Excerpt() shortens a quoted piece of bad input.
//
// Thread-safety: the free functions are thread-safe; AtomicFile, StagedDirectory and
// LineReader are thread-compatible (one thread at a time per object); OutputLock is
// thread-safe (a process holds one lock per output, shared by its OutputLock objects).
#ifndef OMNICML_COMMON_FILE_IO_H_
#define OMNICML_COMMON_FILE_IO_H_

#include <sys/types.h>

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace omnicml {

// Limits of the bounded readers.
inline constexpr std::uintmax_t kMaxTextFileBytes = 16u << 20;    // YAML and config files
inline constexpr std::size_t kMaxCsvLineBytes = 64u << 10;        // one line of a CSV file
inline constexpr std::uintmax_t kMaxMapFileBytes = 4ull << 30;    // a saved engine/map
inline constexpr std::uintmax_t kMaxImageFileBytes = 512u << 20;  // one image file
inline constexpr std::uint64_t kMaxImagePixels = 100'000'000;     // width * height of an image

// ---------------------------------------------------------------------------------------
// Writing

// When the data of an AtomicFile is made durable.
enum class FileSync {
  kFsync,     // fsync the file before the rename and the directory after it (default)
  kDeferred,  // no fsync: for the many files of a staging directory, which its writer
              // makes durable at once with SyncFileSystem() before publishing it
              // (an fsync per file costs ~7 ms on ext4; a 5000-image log would take 35 s)
};

// A file written under a temporary name and renamed into place on Commit().
// Lifecycle: open (constructor) -> write through stream() -> Commit() or Discard();
// the destructor discards an uncommitted file.
class AtomicFile {
 public:
  // Creates the temporary (binary mode, exclusive create, mode 0666 & ~umask) after
  // removing stale temporaries of the same target left by dead processes. Throws
  // omnicml::Error naming the target when it cannot be created (missing directory, no
  // permission).
  explicit AtomicFile(std::filesystem::path target, FileSync sync = FileSync::kFsync);
  ~AtomicFile();  // removes the temporary unless committed
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  std::ofstream& stream() { return out_; }
  const std::filesystem::path& target() const { return target_; }
  const std::filesystem::path& temp_path() const { return temp_; }

  // Flushes, closes and fsyncs the temporary (whatever the FileSync) without renaming
  // it: the data is durable, the target untouched. Throws omnicml::Error naming the
  // target on a write or fsync failure (the temporary is then removed). Idempotent;
  // nothing can be written after it.
  void Sync();
  // Flushes, closes, fsyncs (FileSync::kFsync, unless Sync() did) and renames onto the
  // target, then fsyncs the directory (kFsync).
  // Throws omnicml::Error naming the target on a write, fsync or rename failure (the
  // temporary is then removed, the target untouched). Idempotent.
  void Commit();
  // Closes and removes the temporary without touching the target. Idempotent.
  void Discard();

 private:
  // Flushes and closes the stream once; on a write error discards the temporary and throws.
  void Close();

  std::filesystem::path target_;
  std::filesystem::path temp_;
  std::ofstream out_;
  int fd_ = -1;  // the temporary, holding the flock that marks it as in use
  FileSync sync_ = FileSync::kFsync;
  bool done_ = false;
  bool closed_ = false;  // the stream is flushed and closed (Sync or Commit)
  bool synced_ = false;  // Sync() made the data durable
};

// Writes `content` to `path` atomically (AtomicFile + Commit). Throws omnicml::Error.
void WriteFileAtomic(const std::filesystem::path& path, std::string_view content,
                     FileSync sync = FileSync::kFsync);
void WriteFileAtomic(const std::filesystem::path& path, std::span<const std::uint8_t> bytes,
                     FileSync sync = FileSync::kFsync);

// The temporary name AtomicFile uses for `target` in process `pid`, n-th file.
std::filesystem::path TempPathFor(const std::filesystem::path& target, pid_t pid, std::uint64_t n);
// True for a file name (no directory) of the form ".<name>.omnicml-tmp-<pid>-<n>";
// when `name` is non-empty, only for temporaries of a target with that file name.
// Stores the pid in *pid when given.
bool IsAtomicTempName(std::string_view file_name, std::string_view name = {}, pid_t* pid = nullptr);
// Removes temporaries of `target` (same directory, same name) whose writer is gone (their
// lock is free). Returns how many were removed; never throws.
int RemoveStaleTemporaries(const std::filesystem::path& target);

// "<target>.partial-<pid>": where a directory output is assembled before the rename.
std::filesystem::path StagingDirFor(const std::filesystem::path& target, pid_t pid);
// Removes "<target>.partial-<pid>" and "<target>.old-<pid>" directories (siblings of
// `target`) when this process holds, or can take, the target's OutputLock: every writer
// of `target` holds that lock, so such a directory belongs to a dead writer. Does nothing
// while another process holds the lock. Returns how many were removed; never throws.
int RemoveStaleStagingDirs(const std::filesystem::path& target);

// An advisory lock on one output (a file or a directory), held from construction to
// destruction: flock on "<dir>/.<name>.omnicml-lock", which records "pid <pid> host
// <host>" of the holder and is removed on release. Several OutputLock objects of one
// process on the same output share the lock. Throws omnicml::Error "<flag> '<target>': in
// use by another writer (pid P on host H; lock file L)" when another process holds it,
// or naming the lock file when it cannot be created. Locks are advisory: they order
// omnicml writers, not other programs.
class OutputLock {
 public:
  OutputLock(const std::filesystem::path& target, std::string_view flag);
  ~OutputLock();
  OutputLock(const OutputLock&) = delete;
  OutputLock& operator=(const OutputLock&) = delete;

  // The lock file of `target`.
  static std::filesystem::path LockPathFor(const std::filesystem::path& target);
  // True when this process holds the lock of `target`.
  static bool HeldByThisProcess(const std::filesystem::path& target);

 private:
  std::string key_;
};

// A directory output assembled under "<target>.partial-<pid>" and renamed onto `target`
// by Commit(), optionally together with files outside it (companions: a run's map and
// trajectory beside its run directory). Lifecycle: construct (takes the target's OutputLock,
// removes stale staging directories, creates the staging directory) -> write files into path()
// (with FileSync::kDeferred: Commit makes them durable at once) -> Commit() or destruction (removes
// the staging directory). An existing target is replaced whole (exchanged atomically where the file
// system can, then removed), so it must be empty or hold one of `markers` (a file an earlier output
// of the same kind wrote, e.g. "frames.csv"): an unrelated non-empty directory is refused rather
// than deleted. Throws omnicml::Error "<flag> '<target>': ..." (not a directory, a symbolic link,
// an unrelated directory, cannot create, rename failure).
class StagedDirectory {
 public:
  StagedDirectory(std::filesystem::path target, std::string_view flag,
                  std::vector<std::string> markers);
  ~StagedDirectory();
  StagedDirectory(const StagedDirectory&) = delete;
  StagedDirectory& operator=(const StagedDirectory&) = delete;

  const std::filesystem::path& path() const { return staging_; }
  const std::filesystem::path& target() const { return target_; }
  // Makes every file under path() durable (syncfs), renames the staging directory onto
  // the target and removes the old target. Throws omnicml::Error; the target is then the
  // old one. Idempotent.
  //
  // With `companions` (AtomicFiles written completely but not committed, each outside
  // the staging directory) they commit with the directory as one unit, old or new:
  //   1. every companion's data is made durable (AtomicFile::Sync);
  //   2. a journal ".omnicml-commit" is written (fsync'ed) into the staging directory:
  //      each companion's target, the name of its previous version and the identity
  //      (device, inode) of its new file;
  //   3. each existing target is kept under its previous-version name
  //      ".<name>.omnicml-prev-<pid>" (a hard link, or a copy where the file system has
  //      none), then the companions are renamed onto their targets;
  //   4. the staging directory is renamed onto the target (the commit point);
  //   5. the previous versions and the journal (now inside the target) are removed.
  // A failure in 3-4 restores the previous versions before the Error propagates. A kill
  // anywhere leaves a journal that the next writer of the target (holding its lock)
  // finds: before the commit point (journal in a stale staging directory) it rolls the
  // companions back to their previous versions, after it (journal in the target) it
  // completes step 5 (RecoverInterruptedCommits). Companions must not lie in path().
  void Commit(std::span<AtomicFile* const> companions = {});

 private:
  // Step 4 of Commit: the staging directory renamed onto the target (exchanged with an
  // existing one, which is then removed). Throws omnicml::Error; the target is then the
  // old one.
  void SwapIntoPlace();

  std::filesystem::path target_;
  std::filesystem::path staging_;
  std::string flag_;
  OutputLock lock_;
  bool done_ = false;
};

// Completes or undoes StagedDirectory commits of `target` that a killed writer left
// half done (see StagedDirectory::Commit): a journal inside `target` (the directory was
// committed) has its previous versions and itself removed; a journal in a stale
// "<target>.partial-<pid>" (not committed) has every companion that already replaced
// its target put back to its previous version (or removed, when there was none) and,
// when the old directory had been moved aside to "<target>.old-<pid>" but the new one
// not yet renamed in, the old directory put back. A companion target whose file is no
// longer the one the journal names (another writer replaced it since) is left alone.
// Does nothing unless this process holds, or can take, the target's OutputLock; the
// StagedDirectory constructor calls it. Returns how many journals were settled; never
// throws.
int RecoverInterruptedCommits(const std::filesystem::path& target);

// A test hook in a commit sequence: when the environment variable OMNICML_TEST_KILL_AT
// equals `point`, the process sends itself SIGKILL (tests of crash recovery; the
// StagedDirectory commit names "staged-commit-swap": companions renamed, the directory
// not yet; and "staged-commit-settle": the directory swapped in, journal and previous
// versions not yet removed). Otherwise nothing.
void TestKillPoint(std::string_view point);

// Throws omnicml::Error "<flag> '<target>': ..." unless an existing `target` is a
// directory that is empty or holds one of `markers` (what StagedDirectory replaces).
void CheckReplaceableDirectory(const std::filesystem::path& target, std::string_view flag,
                               const std::vector<std::string>& markers);

// Whether output files that are symbolic links to regular files are written through
// (see the file comment). Process-wide, off by default; set once at start-up (the CLI's
// global --follow-output-symlinks), before any output is checked. Thread-safe.
void SetFollowOutputSymlinks(bool follow);
bool FollowOutputSymlinks();
// The file an output file path writes: `path` itself, or, when FollowOutputSymlinks()
// and `path` is a symbolic link (or a chain of them) to a regular file, that file's
// canonical path. Never throws.
std::filesystem::path ResolveOutputFile(const std::filesystem::path& path);

// The type check of every output path, before any work: throws omnicml::Error
// "<flag> '<path>': is a symbolic link" / "...: is a character device (not a regular
// file)" / ... unless `path` does not exist or is (without following a final symbolic
// link) a regular file, or a directory when `directory`; with FollowOutputSymlinks() a
// file output may also be a symbolic link to a regular file. Creates nothing.
void CheckOutputNode(const std::filesystem::path& path, std::string_view flag,
                     bool directory = false);
// What CheckOutputNode refuses, as text ("is a symbolic link", "is a FIFO (not a regular
// file)", ...), or empty when `path` may be written.
std::string OutputNodeProblem(const std::filesystem::path& path, bool directory = false);

// Checks, before any work starts, that an output file can be written: CheckOutputNode,
// and its directory exists and is writable. `flag` names the output in the
// message ("--map-out"): "--map-out 'x': is a directory". Creates nothing. When the
// directory is `will_create_dir` (a run directory that is made later), only that
// directory's creatability is checked (CheckOutputDirectory). Throws omnicml::Error.
void CheckOutputFile(const std::filesystem::path& path, std::string_view flag,
                     const std::filesystem::path& will_create_dir = {});
// Checks, before any work starts, that `path` can be an output directory: an existing
// writable directory, or a path whose nearest existing ancestor is a writable directory
// (so that it can be created); never a file, a dangling link or a link loop. Creates
// nothing; refuses a symbolic link as the directory itself. Throws omnicml::Error
// "<flag> '<path>': ...".
void CheckOutputDirectory(const std::filesystem::path& path, std::string_view flag);

// SHA-256 of `bytes` as 64 lowercase hex digits (what `sha256sum` prints).
std::string Sha256Hex(std::span<const std::uint8_t> bytes);
// SHA-256 of a regular file (read in pieces; OpenRegularFile's checks). Throws
// omnicml::Error naming the path.
std::string Sha256OfFile(const std::filesystem::path& path);

// fsyncs a directory so that a rename or a new entry in it is durable. Best effort.
void SyncDirectory(const std::filesystem::path& dir);
// Flushes all written data of the file system holding `path` (syncfs): one call makes
// the FileSync::kDeferred files of a staging directory durable. Throws omnicml::Error
// naming the path on failure.
void SyncFileSystem(const std::filesystem::path& path);

// ---------------------------------------------------------------------------------------
// Reading

// Throws omnicml::Error ("<path>: cannot read <what>: not a regular file (a FIFO)",
// "...: does not exist", "...: Too many levels of symbolic links", ...) unless `path` is, after
// following symbolic links, a readable regular file. Returns its size in bytes. Never
// blocks (FIFOs are opened non-blocking). `what` names the file's role ("log frames").
std::uintmax_t CheckRegularFile(const std::filesystem::path& path, std::string_view what = "file");

// Opens a regular file for reading as a file descriptor (O_CLOEXEC, blocking mode),
// after the checks of CheckRegularFile done on the opened descriptor itself (no race
// between check and open). *size receives the size. The caller closes the descriptor.
int OpenRegularFile(const std::filesystem::path& path, std::string_view what,
                    std::uintmax_t* size = nullptr);

// Reads a whole regular file; throws omnicml::Error naming the path when it cannot be
// read, is not a regular file or is larger than `max_bytes` (checked before reading).
std::string ReadTextFile(const std::filesystem::path& path,
                         std::uintmax_t max_bytes = kMaxTextFileBytes,
                         std::string_view what = "file");

// The same for binary data (a saved map): the size is checked against `max_bytes`
// before the buffer is allocated.
std::vector<std::uint8_t> ReadBinaryFile(const std::filesystem::path& path,
                                         std::uintmax_t max_bytes = kMaxMapFileBytes,
                                         std::string_view what = "file");

// Cuts `text` to at most `max_chars` characters (appending "...") and replaces control
// characters by '?', so that an excerpt of a bad input fits in a one-line message.
std::string Excerpt(std::string_view text, std::size_t max_chars = 80);

// Reads a regular text file line by line with a bound on the line length. Line endings
// "\n" and "\r\n" are stripped. Not copyable.
class LineReader {
 public:
  // Opens `path` (OpenRegularFile). Throws omnicml::Error.
  LineReader(const std::filesystem::path& path, std::string_view what = "file",
             std::size_t max_line_bytes = kMaxCsvLineBytes);
  ~LineReader();
  LineReader(const LineReader&) = delete;
  LineReader& operator=(const LineReader&) = delete;

  // Reads the next line into *line; false at the end of the file. Throws omnicml::Error
  // "<path>:<N>: line longer than M bytes (<what>)" or on a read error.
  bool Next(std::string* line);
  // 1-based number of the line returned last (0 before the first).
  std::size_t line_number() const { return line_number_; }
  const std::filesystem::path& path() const { return path_; }

 private:
  bool Fill();

  std::filesystem::path path_;
  std::string what_;
  std::size_t max_line_bytes_;
  int fd_ = -1;
  std::string buffer_;
  std::size_t pos_ = 0;
  bool eof_ = false;
  std::size_t line_number_ = 0;
};

}  // namespace omnicml

#endif  // OMNICML_COMMON_FILE_IO_H_
