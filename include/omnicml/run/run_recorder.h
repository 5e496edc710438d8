// Recording of a CML run: the per-frame records in memory and, when asked, the run
// directory (the engine loop that feeds the recorder is engine_driver.h).
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
//   outputs.yaml     the files the run wrote outside its own set (run_directory.h)
//
// A run commits as one unit (RunDirectoryWriter, run_directory.h): the run directory is
// staged beside its target and renamed into place by Commit(), with the output files
// (AddOutput, trajectory_path) and outputs.yaml; the recorder holds the outputs' locks
// from construction. Destroyed without Commit() (an error unwound the stack), it leaves
// nothing partial: the old outputs are untouched.
//
// Thread-compatible: one thread drives the recorder.
#ifndef OMNICML_RUN_RUN_RECORDER_H_
#define OMNICML_RUN_RUN_RECORDER_H_

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
#include "omnicml/mapping/map_events.h"
#include "omnicml/report/report.h"
#include "omnicml/run/run_directory.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {

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
  // Also keep every map event of the run in memory (events(): what events.csv holds),
  // with or without a run directory.
  bool keep_events = false;
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
  const std::filesystem::path& write_dir() const { return directory_.write_dir(); }

  const std::vector<FrameRecord>& records() const { return records_; }
  // Moves the records out (after Commit; records() is then empty).
  std::vector<FrameRecord> TakeRecords() { return std::move(records_); }
  const std::map<int, std::int64_t>& skipped_frames() const { return skipped_frames_; }
  // The map events recorded so far, oldest first (empty unless options.keep_events).
  const std::vector<MapEvent>& events() const { return events_; }
  // Moves the events out (after Commit; events() is then empty).
  std::vector<MapEvent> TakeEvents() { return std::move(events_); }
  const RunRecorderOptions& options() const { return options_; }

 private:
  RunRecorderOptions options_;
  RunDirectoryWriter directory_;
  bool committed_ = false;
  AtomicFile* frames_csv_ = nullptr;  // owned by directory_
  AtomicFile* trajectory_ = nullptr;
  AtomicFile* events_csv_ = nullptr;
  std::optional<std::uint64_t> next_event_;  // number of the next event to write
  std::uint64_t events_lost_ = 0;
  std::vector<FrameRecord> records_;
  std::vector<MapEvent> events_;                                  // options_.keep_events
  std::vector<std::pair<std::string, std::string>> extra_files_;  // AddFile
  std::map<int, std::int64_t> skipped_frames_;                    // by engine session
  RunStampClock clock_;
  // Dead-reckoning baseline per engine session: anchor (truth, odometry) of its first
  // frame with ground truth.
  int anchor_session_ = -1;
  bool have_anchor_ = false;
  Pose2 anchor_truth_ = Pose2::Zero();
  Pose2 anchor_odom_ = Pose2::Zero();
};

}  // namespace omnicml

#endif  // OMNICML_RUN_RUN_RECORDER_H_
