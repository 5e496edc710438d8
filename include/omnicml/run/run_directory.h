// The run directory as one unit of output: its files, the output files a run writes
// beside it (--map-out, --trajectory-out), their record in outputs.yaml, the locks, and
// the staged commit.
//
//   outputs.yaml     the files the run wrote outside its own set (AddOutput, OpenOutput)
//                    with their size and SHA-256, so a run directory proves which map it
//                    wrote (`sha256sum MAP` equals its sha256)
//
// The run directory is assembled in a staging directory beside it (StagedDirectory,
// "<run_dir>.partial-<pid>") and renamed into place by Commit(), replacing an earlier
// run directory whole; an output file that lies directly in the run directory is staged
// with it, one elsewhere is written under a temporary name beside it. Commit() writes
// everything first (a full disk fails here, leaving the old state), then renames the
// outside files, then the run directory: a run directory that exists always names, in
// outputs.yaml, files that were completely written. The writer holds the outputs' locks
// (OutputLock) from construction (the run directory) or from AddOutput / OpenOutput
// (outside files), so a second writer of the same output refuses at its start. If the
// writer is destroyed without Commit() (an error unwound the stack), the staging
// directory and every temporary are removed: nothing partial remains, the old outputs
// are untouched.
//
// Thread-compatible: one thread drives the writer.
#ifndef OMNICML_RUN_RUN_DIRECTORY_H_
#define OMNICML_RUN_RUN_DIRECTORY_H_

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "omnicml/common/file_io.h"

namespace omnicml {

// Files whose presence marks an existing directory as an earlier run directory, which a
// new run may replace whole (StagedDirectory); any other non-empty directory is refused.
const std::vector<std::string>& RunDirectoryMarkers();

// Throws omnicml::Error "<flag> '<path>': ..." when output file `path` lies in a
// subdirectory of `run_dir` (which a run replaces whole). Directly in run_dir or outside
// it is fine.
void CheckRunOutputPlacement(const std::string& flag, const std::filesystem::path& path,
                             const std::filesystem::path& run_dir);
// True when output file `path` lies directly in `run_dir`: it is then written into the
// staging directory and committed with it (and locked by the run directory's lock).
bool LiesInRunDirectory(const std::filesystem::path& path, const std::filesystem::path& run_dir);

class RunDirectoryWriter {
 public:
  // run_dir "" = no run directory (only outside outputs). stage: true stages run_dir and
  // commits it whole (the file comment); false writes the files straight into run_dir
  // (created with its parents), which the caller stages (compare's per-mode directories
  // inside its own staging directory). Throws omnicml::Error naming the path when the
  // directory cannot be created or another writer holds it.
  RunDirectoryWriter(std::filesystem::path run_dir, bool stage);
  ~RunDirectoryWriter();
  RunDirectoryWriter(const RunDirectoryWriter&) = delete;
  RunDirectoryWriter& operator=(const RunDirectoryWriter&) = delete;

  // The run directory as given ("" = none), and where its files are written until
  // Commit (the staging directory, or run_dir when not staged).
  const std::filesystem::path& run_dir() const { return run_dir_; }
  const std::filesystem::path& write_dir() const { return write_dir_; }

  // File `name` of the run directory, written under a temporary name (FileSync::kDeferred:
  // the commit makes them durable at once) and renamed at Commit, in the order opened.
  // Precondition: a run directory (write_dir() not empty).
  AtomicFile& OpenFile(const std::string& name);
  // Removes `name` from the directory being written (a file an earlier run left that
  // this run does not write). Never throws.
  void RemoveFile(const std::string& name);

  // A further output file at `path` with `bytes`, written at Commit and recorded in
  // outputs.yaml under `flag`. Takes the file's OutputLock unless it lies directly in the
  // run directory. Throws omnicml::Error when `path` lies in a subdirectory of the run
  // directory or another process holds its lock.
  void AddOutput(const std::string& flag, const std::filesystem::path& path,
                 std::vector<std::uint8_t> bytes);
  // The same for an output the caller writes as the run goes (e.g. the trajectory):
  // the returned file is committed and recorded in outputs.yaml by Commit (an fsync'ed
  // file when it lies outside the run directory).
  AtomicFile& OpenOutput(const std::string& flag, const std::filesystem::path& path);

  // Writes the added outputs and outputs.yaml (when there is a run directory and any
  // output), then renames everything into place as the file comment says. Throws
  // omnicml::Error on I/O failure (temporaries then removed by the destructor). Idempotent.
  void Commit();

 private:
  // An output file beside or inside the run directory (AddOutput, OpenOutput).
  struct Output {
    std::string flag;
    std::filesystem::path path;        // as given
    std::filesystem::path write_path;  // in the staging directory, or `path`
    std::vector<std::uint8_t> bytes;   // AddOutput
    std::unique_ptr<AtomicFile> file;  // OpenOutput
  };
  // Where `path` (an output named by `flag`) is written: inside the staging directory
  // when it lies directly in the run directory, else itself (then locked).
  std::filesystem::path WritePathFor(const std::string& flag, const std::filesystem::path& path);

  std::filesystem::path run_dir_;
  std::unique_ptr<StagedDirectory> staged_;  // when staged
  std::filesystem::path write_dir_;
  std::vector<std::unique_ptr<OutputLock>> locks_;
  std::vector<std::unique_ptr<AtomicFile>> files_;  // OpenFile, in order
  std::vector<Output> outputs_;                     // AddOutput
  std::vector<Output> streamed_;                    // OpenOutput
  bool committed_ = false;
};

}  // namespace omnicml

#endif  // OMNICML_RUN_RUN_DIRECTORY_H_
