// Recording of a CML run into a run directory, and the loop that drives the engine over
// a frame source with progress output.
//
// RUNDIR layout (all files written atomically: temporary name, renamed on Commit()):
//   frames.csv       one row per frame (schema in evaluation.h), written as frames come
//   events.csv       every map event of the run (run_report.h WriteEventsCsvRow), written
//                    as the run goes (RecordEvents), so it is complete although the
//                    model keeps only its most recent model.events.max_events events
//   config.yaml, days.csv, report.html
//                    written at Commit from the engine's final state (run_report.h)
//   trajectory.tum   the strongest estimate, TUM (stamp x y z qx qy qz qw; z = 0, yaw
//                    quaternion), written at Commit
//   groundtruth.tum  ground truth on the same stamps (when the input has ground truth)
//   odometry.tum     the input's odometry on the same stamps (each session in its own
//                    odometry frame)
//   change_detection.csv
//                    simulated input only (`omnicml run --world`): the map's health by
//                    area scored per day against the day events (change_detection.h)
// The TUM files hold the localized frames only (frames without an estimate are left
// out of all three) and use run-unique stamps (evaluation.h RunStampClock; frames.csv
// keeps stamp_s and adds run_stamp_s), so `evo_ape tum groundtruth.tum trajectory.tum`
// works on a multi-day run. A TUM file not written (no ground truth) is removed from
// an existing run directory so it never belongs to an earlier run. When asked, the
// estimate goes to a further TUM file (trajectory_path, same content as trajectory.tum).
//
//   outputs.yaml     the files the run wrote outside its own set (--map-out,
//                    --trajectory-out: AddOutput, trajectory_path) with their size and
//                    SHA-256, so a run directory proves which map it wrote
//                    (`sha256sum MAP` equals its sha256)
//
// A run commits as one unit. The run directory is assembled in a staging directory
// beside it (StagedDirectory, "<run_dir>.partial-<pid>") and renamed into place by
// Commit(), replacing an earlier run directory whole; an output file that lies directly
// in the run directory is staged with it, one elsewhere is written under a temporary
// name beside it. Commit() writes everything first (a full disk fails here, leaving the
// old state), then renames the outside files, then the run directory: a run directory
// that exists always names, in outputs.yaml, files that were completely written. The
// recorder holds the outputs' locks (OutputLock) from construction, so a second writer
// of the same run directory or file refuses at its start. If the recorder is destroyed
// without Commit() (an error unwound the stack), the staging directory and every
// temporary are removed: nothing partial remains, the old outputs are untouched.
//
// Thread-compatible: one thread drives the recorder.
#ifndef OMNICML_EXPERIMENTS_RUN_RECORDER_H_
#define OMNICML_EXPERIMENTS_RUN_RECORDER_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/common/file_io.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/report.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {

// Names of the per-frame stage timings (FrameStats fields without "_us"), in the order
// of the time_<stage>_us columns of frames.csv.
const std::vector<std::string>& StageNames();
// The FrameStats timings in StageNames() order.
std::vector<double> StageTimes(const FrameStats& stats);

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

struct RunRecorderOptions {
  std::filesystem::path run_dir;          // "" = no run directory
  std::filesystem::path trajectory_path;  // "" = no TUM file
  std::string title = "omnicml run";      // report title
  std::string input_description;          // RunInput::Describe(), for config.yaml and the report
  bool write_report = true;               // report.html in run_dir
  // true: run_dir is staged and committed whole (see the file comment); false: files
  // go straight into run_dir, which the caller stages (compare's per-mode directories
  // inside its own staging directory).
  bool stage = true;
};

class RunRecorder {
 public:
  // Creates run_dir (and parents) when missing and opens the temporary files. Throws
  // omnicml::Error naming the path when it cannot.
  explicit RunRecorder(RunRecorderOptions options);
  ~RunRecorder();
  RunRecorder(const RunRecorder&) = delete;
  RunRecorder& operator=(const RunRecorder&) = delete;

  // Records one processed frame (the frame as delivered and the engine's result).
  void Record(const Frame& frame, const FrameResult& result);
  // Reserves room for `frames` records (the run's frame count when known), so the record
  // array is allocated once instead of growing by doubling: a long run then holds one
  // block of records (sizeof(FrameRecord) plus the stage times, about 0.25 KB a frame)
  // and no freed halves of earlier ones.
  void Reserve(std::size_t frames) { records_.reserve(frames); }
  // Input frames of engine session `session` that the source skipped as unreadable
  // (added to what was recorded for it before); for days.csv and the report.
  void RecordSkippedFrames(int session, std::int64_t count);
  // Appends the map events logged since the last call to events.csv (the first call
  // starts at the oldest event the model holds). Call after every engine call that can
  // change the map (RunEngineOverSource does, after each frame; Commit does too). Events
  // the ring dropped before they were read are counted (events_lost()).
  void RecordEvents(const EnvironmentModel& model);
  std::uint64_t events_lost() const { return events_lost_; }

  // Writes the remaining files from the engine's final state (configuration, events,
  // map drawing) and renames everything into place. `notes` are extra lines for the
  // report's summary. Throws omnicml::Error on I/O failure (temporaries then removed).
  void Commit(const CmlEngine& engine,
              const std::vector<std::pair<std::string, std::string>>& notes = {});

  // A further file `name` of the run directory with `content`, written atomically at
  // Commit with the others (e.g. change_detection.csv). No-op without a run directory.
  void AddFile(const std::string& name, std::string content) {
    extra_files_.emplace_back(name, std::move(content));
  }

  // A further output file at `path` (e.g. the saved map of --map-out, named `flag` in
  // errors), written by Commit with the run directory as the file comment says and
  // recorded in outputs.yaml. Takes the file's OutputLock. Throws omnicml::Error when
  // `path` lies in a subdirectory of the run directory (replaced whole by the commit) or
  // another process holds its lock.
  void AddOutput(const std::string& flag, const std::filesystem::path& path,
                 std::vector<std::uint8_t> bytes);
  // Where the run directory's files are being written until Commit (the staging
  // directory, or run_dir when not staged).
  const std::filesystem::path& write_dir() const { return write_dir_; }

  const std::vector<FrameRecord>& records() const { return records_; }
  const std::map<int, std::int64_t>& skipped_frames() const { return skipped_frames_; }
  const RunRecorderOptions& options() const { return options_; }

 private:
  // An output file beside or inside the run directory (AddOutput, trajectory_path).
  struct Output {
    std::string flag;
    std::filesystem::path path;        // as given
    std::filesystem::path write_path;  // in the staging directory, or `path`
    std::vector<std::uint8_t> bytes;
  };
  // Where `path` (an output named by `flag`) is written: inside the staging directory
  // when it lies directly in the run directory, else itself.
  std::filesystem::path WritePathFor(const std::string& flag, const std::filesystem::path& path);

  RunRecorderOptions options_;
  std::unique_ptr<StagedDirectory> staged_;  // when options_.stage
  std::filesystem::path write_dir_;
  std::vector<std::unique_ptr<OutputLock>> locks_;
  std::vector<Output> outputs_;
  std::filesystem::path trajectory_write_path_;
  bool committed_ = false;
  std::unique_ptr<AtomicFile> frames_csv_;
  std::unique_ptr<AtomicFile> trajectory_;
  std::unique_ptr<AtomicFile> events_csv_;
  std::optional<std::uint64_t> next_event_;  // number of the next event to write
  std::uint64_t events_lost_ = 0;
  std::vector<FrameRecord> records_;
  std::vector<std::pair<std::string, std::string>> extra_files_;  // AddFile
  std::map<int, std::int64_t> skipped_frames_;  // by engine session
  RunStampClock clock_;
  // Dead-reckoning baseline per engine session: anchor (truth, odometry) of its first
  // frame with ground truth.
  int anchor_session_ = -1;
  bool have_anchor_ = false;
  Pose2 anchor_truth_ = Pose2::Zero();
  Pose2 anchor_odom_ = Pose2::Zero();
};

// Progress output of RunEngineOverSource.
struct ProgressOptions {
  // Progress bar on stderr, redrawn in place (frames/s, views, ETA); when false, a plain
  // log line every log_every_frames frames and at the end of each session.
  bool progress_bar = false;
  std::int64_t log_every_frames = 500;
  std::string label;                         // prefix of every line, e.g. "active"
  std::optional<std::int64_t> total_frames;  // for the ETA
  bool quiet = false;                        // no output at all
};
// True when stderr is a terminal (isatty).
bool StderrIsTerminal();

struct RunSummary {
  std::int64_t frames = 0;            // frames delivered and processed
  std::int64_t frames_localized = 0;  // of those, frames with an estimate
  std::int64_t frames_skipped = 0;    // input frames skipped as unreadable (LogReader)
  int sessions = 0;
  double wall_s = 0.0;
};

// Drives `engine` over every frame of `source`: BeginSession at each new session,
// ProcessFrame, recorder->Record (when not null), progress. When `source` is a
// LogReader, its per-session counts of skipped unreadable frames go to the summary and
// recorder->RecordSkippedFrames (a session of which every frame was skipped counts in
// the summary only: it has no engine session). Progress lines show the localized
// fraction next to every mean error. Does not call Finish.
// `on_session_end(engine, session_index)` (optional) runs after the last frame of each
// session but the last, before the next BeginSession, e.g. to change the engine's mode
// (CmlEngine::SetForgettingMode; the engine is between frames there). Throws what the
// engine, the source, the recorder or the hook throw.
// `process` (optional) replaces engine.ProcessFrame(frame) for every frame, e.g. survey
// mapping from trusted poses (survey.h); empty = ProcessFrame.
using SessionEndHook = std::function<void(CmlEngine& engine, int session_index)>;
using FrameProcessor = std::function<FrameResult(CmlEngine& engine, const Frame& frame)>;
RunSummary RunEngineOverSource(CmlEngine& engine, FrameSource& source, RunRecorder* recorder,
                               const ProgressOptions& progress,
                               const SessionEndHook& on_session_end = {},
                               const FrameProcessor& process = {});

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_RUN_RECORDER_H_
