#include "omnicml/run/run_directory.h"

#include <system_error>
#include <utility>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace fs = std::filesystem;

const std::vector<std::string>& RunDirectoryMarkers() {
  static const std::vector<std::string> kMarkers = {"frames.csv", "outputs.yaml", "config.yaml",
                                                    "report.html", "table.txt"};
  return kMarkers;
}

namespace {

// Where output `path` lies relative to `run_dir`: 0 outside, 1 directly in it, 2 deeper.
int PlacementIn(const fs::path& path, const fs::path& run_dir) {
  std::error_code ec;
  const fs::path parent = fs::weakly_canonical(fs::absolute(path).parent_path(), ec);
  const fs::path run = fs::weakly_canonical(fs::absolute(run_dir), ec);
  const fs::path rel = parent.lexically_relative(run);
  if (rel.empty() || *rel.begin() == "..") return 0;
  return rel == "." ? 1 : 2;
}

}  // namespace

bool LiesInRunDirectory(const fs::path& path, const fs::path& run_dir) {
  return !path.empty() && !run_dir.empty() && PlacementIn(path, run_dir) == 1;
}

void CheckRunOutputPlacement(const std::string& flag, const fs::path& path,
                             const fs::path& run_dir) {
  if (path.empty() || run_dir.empty()) return;
  if (PlacementIn(path, run_dir) == 2) {
    throw Error(StrCat(flag, " '", path.string(),
                       "': lies in a subdirectory of the run directory '", run_dir.string(),
                       "', which a run replaces whole; write it directly in "
                       "the run directory or outside it"));
  }
}

RunDirectoryWriter::RunDirectoryWriter(fs::path run_dir, bool stage)
    : run_dir_(std::move(run_dir)) {
  if (run_dir_.empty()) return;
  if (stage) {
    staged_ = std::make_unique<StagedDirectory>(run_dir_, "--out", RunDirectoryMarkers());
    write_dir_ = staged_->path();
  } else {
    std::error_code ec;
    fs::create_directories(run_dir_, ec);
    if (ec) {
      throw Error(StrCat("cannot create run directory '", run_dir_.string(), "': ", ec.message()));
    }
    write_dir_ = run_dir_;
  }
}

RunDirectoryWriter::~RunDirectoryWriter() {
  if (committed_) return;
  files_.clear();  // removes the temporaries
  streamed_.clear();
  staged_.reset();  // removes the staging directory
}

AtomicFile& RunDirectoryWriter::OpenFile(const std::string& name) {
  OMNICML_CHECK(!write_dir_.empty()) << "RunDirectoryWriter::OpenFile without a run directory";
  files_.push_back(std::make_unique<AtomicFile>(write_dir_ / name, FileSync::kDeferred));
  return *files_.back();
}

void RunDirectoryWriter::RemoveFile(const std::string& name) {
  std::error_code ec;
  fs::remove(write_dir_ / name, ec);
}

fs::path RunDirectoryWriter::WritePathFor(const std::string& flag, const fs::path& path) {
  CheckRunOutputPlacement(flag, path, run_dir_);
  if (staged_ && PlacementIn(path, run_dir_) == 1) return write_dir_ / path.filename();
  locks_.push_back(std::make_unique<OutputLock>(path, flag));
  return path;
}

void RunDirectoryWriter::AddOutput(const std::string& flag, const fs::path& path,
                                   std::vector<std::uint8_t> bytes) {
  Output o;
  o.flag = flag;
  o.path = path;
  o.write_path = WritePathFor(flag, path);
  o.bytes = std::move(bytes);
  outputs_.push_back(std::move(o));
}

AtomicFile& RunDirectoryWriter::OpenOutput(const std::string& flag, const fs::path& path) {
  Output o;
  o.flag = flag;
  o.path = path;
  o.write_path = WritePathFor(flag, path);
  o.file = std::make_unique<AtomicFile>(
      o.write_path, o.write_path == o.path ? FileSync::kFsync : FileSync::kDeferred);
  streamed_.push_back(std::move(o));
  return *streamed_.back().file;
}

void RunDirectoryWriter::Commit() {
  if (committed_) return;
  std::vector<std::unique_ptr<AtomicFile>> outside;  // beside their own targets
  // Further outputs, and outputs.yaml recording each with its SHA-256.
  YAML::Emitter manifest;
  manifest << YAML::BeginSeq;
  const auto record = [&](const std::string& flag, const fs::path& path, std::uintmax_t bytes,
                          const std::string& sha256, bool staged) {
    manifest << YAML::BeginMap << YAML::Key << "flag" << YAML::Value << flag << YAML::Key << "path"
             << YAML::Value << YAML::DoubleQuoted << path.string() << YAML::Key
             << "in_run_directory" << YAML::Value << staged << YAML::Key << "bytes" << YAML::Value
             << bytes << YAML::Key << "sha256" << YAML::Value << sha256 << YAML::EndMap;
  };
  for (const Output& o : outputs_) {
    const bool staged = o.write_path != o.path;
    auto file =
        std::make_unique<AtomicFile>(o.write_path, staged ? FileSync::kDeferred : FileSync::kFsync);
    file->stream().write(reinterpret_cast<const char*>(o.bytes.data()),
                         static_cast<std::streamsize>(o.bytes.size()));
    record(o.flag, o.path, o.bytes.size(), Sha256Hex(o.bytes), staged);
    (staged ? files_ : outside).push_back(std::move(file));
  }
  for (const Output& o : streamed_) {
    o.file->stream().flush();
    if (!o.file->stream()) {
      throw Error(
          StrCat(o.path.string(), ": write error: the data could not be written (disk full?)"));
    }
    std::error_code ec;
    const std::uintmax_t size = fs::file_size(o.file->temp_path(), ec);
    record(o.flag, o.path, ec ? 0 : size, Sha256OfFile(o.file->temp_path()),
           o.write_path != o.path);
  }
  manifest << YAML::EndSeq;
  if (!write_dir_.empty() && (!outputs_.empty() || !streamed_.empty())) {
    AtomicFile& file = OpenFile("outputs.yaml");
    file.stream() << "# Files this run wrote besides its own (path as given; check one with "
                     "`sha256sum PATH`)\n"
                  << manifest.c_str() << "\n";
  }
  // Everything is written. Rename into place: the run directory's files (inside the
  // staging directory, not yet visible), then the files outside it together with the
  // run directory as one unit (StagedDirectory::Commit with companions: a kill leaves
  // the old state or the new one, settled by the next writer).
  for (auto& f : files_) f->Commit();
  std::vector<AtomicFile*> companions;
  for (auto& o : streamed_) {
    if (o.write_path == o.path) {
      companions.push_back(o.file.get());
    } else {
      o.file->Commit();
    }
  }
  for (auto& f : outside) companions.push_back(f.get());
  if (staged_) {
    staged_->Commit(companions);
  } else {
    for (AtomicFile* f : companions) f->Commit();
  }
  committed_ = true;
}

}  // namespace omnicml
