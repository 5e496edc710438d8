// The multi-day log format (docs/design.md "Logs", "Sessions"): a streaming, validating
// reader, a crash-safe writer and a whole-log validator. The format is documented with
// an example in datasets/README.md; in short:
//
//   <log>/                     a multi-day log: one directory per session, sorted by name
//     <session>/session.yaml   format_version: 1, day_label, start_time_s, camera, start
//     <session>/frames.csv stamp_s,image,odom_x_m,odom_y_m,odom_phi_rad,gt_x_m,gt_y_m,gt_phi_rad
//     <session>/000000.png     images, named in frames.csv relative to the session directory
//                              (or frames of a video: `<video>#<index>`, logs/video.h)
//
// Images stay inside the log: a name in frames.csv that is absolute, climbs out with
// "..", or leads out through a symbolic link is refused (the log directory given to the
// reader, after following links, must contain the image), with one message that does not
// depend on whether the outside path exists. A log that deliberately keeps its images
// elsewhere (a symbolic link to a data disk, absolute paths) is read with
// LogReaderOptions::allow_images_outside_log or the CLI's global
// --allow-images-outside-log (SetAllowImagesOutsideLog).
//
// session.yaml:
//   format_version: 1
//   day_label: "day 1"                  free text
//   start_time_s: 0                     seconds, any epoch
//   camera:
//     model: panorama                   panorama | omni_ring
//     image_width: 720                  pixels of every image of the session
//     image_height: 150
//     calibration: {...}                omni_ring only: the OmniCalibration keys
//   start:
//     mode: known                       known | continue | global
//     pose: [x_m, y_m, phi_rad]         map_T_robot, mode known only
//     covariance_diagonal: [m^2, m^2, rad^2]   mode known only
//
// frames.csv has that exact header line and one row per frame: stamp_s strictly
// increasing within the session, the image file name, the odometry pose odom_T_robot and
// the ground truth map_T_robot; the three gt columns are either all empty (no ground
// truth for that frame) or all numbers. Numbers are written in the shortest form that
// round-trips (std::to_chars), so writing the same data twice gives byte-identical files
// and reading them back gives bit-identical doubles. Unknown YAML keys are errors.
//
// The image column may name a frame of a video file instead (`day1.avi#17`, video.h):
// such frames are decoded in order with the video kept open (a seek only on a jump) and
// are 8-bit BGR; a reference past the video's end is an error naming the row.
//
// Errors: every problem in the input is an omnicml::Error whose message starts with
// "<file>:<line>: " (the file is the full path of the session.yaml or frames.csv; for a
// bad image it is the frames.csv row that names it, and the image path follows).
#ifndef OMNICML_LOGS_LOG_FORMAT_H_
#define OMNICML_LOGS_LOG_FORMAT_H_

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "omnicml/common/file_io.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {

// The session layout version this code reads and writes.
inline constexpr int kLogFormatVersion = 1;
// The exact header line of frames.csv.
inline constexpr const char* kFramesCsvHeader =
    "stamp_s,image,odom_x_m,odom_y_m,odom_phi_rad,gt_x_m,gt_y_m,gt_phi_rad";

struct LogReaderOptions {
  // Decode images in Next(). With false, Frame::image stays empty and image files are
  // not even checked for existence (fast pose-only passes: trajectories, statistics).
  bool load_images = true;
  // With false (the default) a frame row that cannot be used (unparsable or non-finite
  // number, wrong column count, non-increasing stamp, missing or undecodable image, image
  // of the wrong size or channel count) throws omnicml::Error. With true such a frame is
  // skipped, counted (LogReader::NumSkippedFrames) and its message kept
  // (LogReader::SkippedFrameMessages). Problems of session.yaml or of the frames.csv
  // header are always errors.
  bool skip_unreadable_frames = false;
  // With false (the default) an image named in frames.csv must lie inside the log
  // directory the reader was given, after following symbolic links (see the file
  // comment); with true any readable path is taken. The process-wide
  // SetAllowImagesOutsideLog(true) turns it on for every reader.
  bool allow_images_outside_log = false;
  // Nothing can be invalid today; kept for the house style (throws omnicml::Error).
  void Validate() const {}
};

// Process-wide opt-in to images outside the log for every LogReader (the CLI's global
// --allow-images-outside-log), in addition to LogReaderOptions::allow_images_outside_log.
// Off by default; set at start-up. Thread-safe.
void SetAllowImagesOutsideLog(bool allow);
bool AllowImagesOutsideLog();

struct LogReaderRoot;  // where a session's images may lie (log_format.cc)

// Reads one or more logs as one stream of sessions. Lifecycle: the constructor lists the
// sessions and validates every session.yaml and every frames.csv header (it throws
// omnicml::Error for the first problem); Next() then reads frames.csv line by line and
// loads each image only when its frame is delivered, so memory does not grow with the
// log. Frame::index_in_session and Frame::global_index count delivered frames. Images
// are CV_8UC1 or CV_8UC3 (BGR); within a session all images share one channel count
// (that of its first image). Not thread-safe: one consumer.
class VideoReader;
struct VideoFrameRef;

class LogReader : public FrameSource {
 public:
  // log_dir: a multi-day log (a directory whose sub-directories are sessions, taken in
  // name order; directories whose name starts with '.' and plain files are ignored, every
  // other sub-directory must hold a session.yaml) or a single session directory (it holds
  // session.yaml itself). Throws omnicml::Error naming file (and line or key) of the first
  // problem, or when there is no session at all.
  explicit LogReader(const std::string& log_dir, LogReaderOptions options = {});
  // Several logs, their sessions concatenated in the given order (a multi-day run
  // assembled from several directories).
  explicit LogReader(const std::vector<std::string>& log_dirs, LogReaderOptions options = {});
  ~LogReader() override;

  int NumSessions() const override;
  const SessionInfo& Session(int index) const override;
  bool Next(Frame* frame) override;

  // The directory of session `index`.
  const std::string& SessionDirectory(int index) const;
  // Frames skipped so far (only with skip_unreadable_frames) and their error messages
  // (the first 1000 are kept).
  std::int64_t NumSkippedFrames() const { return num_skipped_; }
  // Frames of session `index` skipped so far (0 for a session not read yet).
  std::int64_t NumSkippedFrames(int session) const {
    return session >= 0 && session < static_cast<int>(skipped_per_session_.size())
               ? skipped_per_session_[static_cast<std::size_t>(session)]
               : 0;
  }
  const std::vector<std::string>& SkippedFrameMessages() const { return skipped_messages_; }

 private:
  // Opens frames.csv of session_ and checks its header; false when past the last session.
  bool OpenSession();
  // Parses and loads the row just read; throws omnicml::Error "file:line: what".
  void ParseRow(const std::string& line, Frame* frame);

  LogReaderOptions options_;
  std::vector<SessionInfo> sessions_;
  std::vector<std::string> session_dirs_;
  // Per session: where its images may lie (null when images outside the log are
  // allowed); log_format.cc.
  std::vector<std::shared_ptr<const LogReaderRoot>> session_roots_;
  int session_ = -1;                 // session being read; -1 before the first
  std::unique_ptr<LineReader> csv_;  // frames.csv of session_; null between sessions
  std::string csv_path_;
  std::int64_t line_number_ = 0;  // of the last line read from csv_
  std::int64_t index_in_session_ = 0;
  std::int64_t global_index_ = 0;
  double last_stamp_s_ = 0.0;
  bool have_last_stamp_ = false;
  int session_channels_ = 0;  // channel count of the session's first image
  // The video of the last video frame read (one open at a time; closed between sessions).
  std::unique_ptr<VideoReader> video_;
  std::int64_t num_skipped_ = 0;
  std::vector<std::int64_t> skipped_per_session_;
  std::vector<std::string> skipped_messages_;
};

// What ValidateLog found.
struct LogSessionSummary {
  std::string name;
  std::string directory;
  std::string day_label;
  std::int64_t frames = 0;
  std::int64_t frames_with_truth = 0;
  double first_stamp_s = 0.0;  // 0 when the session has no frame
  double last_stamp_s = 0.0;
};
struct LogSummary {
  std::vector<LogSessionSummary> sessions;
  std::int64_t total_frames = 0;
};

// Reads a whole log (every row; every image must exist, decode and have the declared
// size) and throws omnicml::Error "file:line: what" on the first problem. Returns a
// per-session summary (the return value may be ignored).
LogSummary ValidateLog(const std::string& log_dir);

// Reads the session.yaml at `path` (throws omnicml::Error "path:line: what"); `name` is
// left empty. Exposed for tools and tests.
SessionInfo ReadSessionYaml(const std::string& path);
// The text of a session.yaml for `info` (deterministic, full-precision numbers).
std::string SessionYamlText(const SessionInfo& info);

// Writes a log. Lifecycle: construct -> BeginSession -> Write... -> BeginSession -> ...
// -> Finish. Everything is written into "<log_dir>.partial-<pid>" (StagingDirFor) with
// WriteFileAtomic and renamed to log_dir in Finish(), so a crash never leaves a half log
// under log_dir; the destructor removes the staging directory after a failure, and the
// next writer of the same log removes one left by a killed process. Deterministic: the same
// calls give byte-identical files. Not thread-safe.
class LogWriter {
 public:
  // Throws omnicml::Error if log_dir exists and overwrite is false (with overwrite the
  // old log is replaced at Finish(), atomically where the OS allows: renameat2 exchange).
  explicit LogWriter(const std::string& log_dir, bool overwrite = false);
  ~LogWriter();  // without Finish(): removes the partial directory, never throws
  LogWriter(const LogWriter&) = delete;
  LogWriter& operator=(const LogWriter&) = delete;

  // Starts a session directory named info.name (non-empty, no '/', not starting with
  // '.', unique, and sessions must be begun in increasing name order so that the reader
  // sees them in the written order). The camera's image size must be positive; an
  // omni_ring camera's calibration must be valid for it. Throws omnicml::Error.
  void BeginSession(const SessionInfo& info);
  // Appends a frame to the current session: the image as lossless PNG named %06d.png
  // (0-based index in the session) and a row in frames.csv. Frame::session_index and
  // the index fields are ignored. Throws omnicml::Error if no session was begun, the
  // stamp does not increase, a number is not finite, or the image is empty, not
  // CV_8UC1/CV_8UC3, of another size than the session's camera or of another channel
  // count than the session's first image.
  void Write(const Frame& frame);
  // Places the video file at `video_path` in the current session directory under its file
  // name (hard-linked when the file system allows, else copied) and returns that name.
  // Throws omnicml::Error if no session was begun, the name is not a video file name
  // (video.h), the session already holds a file of that name, or the file cannot be read.
  std::string AddSessionVideo(const std::string& video_path);
  // Appends a frame whose image is frame ref.index of a video placed by AddSessionVideo in
  // this session (frame.image is ignored; the index is not checked against the video).
  // Throws omnicml::Error as Write for the stamp and poses, or when ref.file was not added.
  void WriteVideoFrame(const Frame& frame, const VideoFrameRef& ref);
  // Writes an extra file at the top of the log (e.g. the world or run configuration that
  // produced it); readers ignore plain files there. `file_name` must be a plain name (no
  // '/', not starting with '.'). May be called at any time before Finish(). Throws
  // omnicml::Error.
  void AddFile(const std::string& file_name, const std::string& contents);
  // Closes the files and moves the log to log_dir. Throws omnicml::Error if no session
  // was written or on an I/O failure. Calls after Finish() throw.
  void Finish();

  const std::string& partial_dir() const { return partial_dir_; }

 private:
  void CloseSession();
  // Checks the stamp and poses of a frame (Write, WriteVideoFrame); throws via `fail`.
  void CheckRow(const Frame& frame) const;
  // Appends the frames.csv row of `frame` with `image_column`.
  void AppendRow(const Frame& frame, const std::string& image_column);

  std::string log_dir_;
  std::string partial_dir_;
  // Held from construction to destruction: a second writer of the same log refuses.
  std::unique_ptr<OutputLock> lock_;
  bool overwrite_ = false;
  bool finished_ = false;
  std::vector<std::string> session_names_;
  std::string session_dir_;
  SessionInfo session_;
  std::unique_ptr<AtomicFile> csv_;  // frames.csv of the open session, committed on close
  std::int64_t frames_in_session_ = 0;
  double last_stamp_s_ = 0.0;
  int session_channels_ = 0;
  std::vector<std::string> session_videos_;  // added to the open session
};

// Copies every frame of `source` into `writer`: BeginSession(source.Session(k)) where a new
// session starts, then Write. `on_frame` (optional) sees each frame after it was written
// (progress, previews). Does not call Finish. Returns the number of frames written.
// Throws what the source, the writer or on_frame throw.
std::int64_t WriteFrames(FrameSource& source, LogWriter& writer,
                         const std::function<void(const Frame&)>& on_frame = {});

// Formats a double in the shortest form that parses back to the same bits
// (std::to_chars). Throws omnicml::Error on NaN or infinity.
std::string FormatRoundTrip(double value);

}  // namespace omnicml

#endif  // OMNICML_LOGS_LOG_FORMAT_H_
