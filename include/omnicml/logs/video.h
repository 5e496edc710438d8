// Video input: frames of a session taken from a video file instead of one image file per
// frame (docs/outputs.md "Video frames"), and `omnicml import video`, which turns a video
// and a poses CSV into a log.
//
// In frames.csv the image column names a video frame as `<file>#<index>`: <file> is a
// video file relative to the session directory whose name ends in .avi, .mkv, .mp4, .mov
// or .webm (any case), <index> the 0-based frame index in decimal. Any other value is an
// image file name, so logs written before video input load unchanged. Frames are decoded
// with OpenCV's FFmpeg backend (libopencv-videoio) as 8-bit BGR; lossless FFV1 in .avi
// (what the writer of the tests uses) or any codec FFmpeg decodes.
//
// Poses CSV of `import video` (docs/guide.md "Importing a video"): a header line, then one
// row per frame of the log, in increasing order. The first column is `frame` (0-based
// video frame index; stamp = start_time_s + frame / fps) or `stamp_s` (seconds from the
// video's first frame; the frame is the nearest one, round(stamp_s * fps)). The other
// columns, in any order, are the groups gt_x_m,gt_y_m,gt_phi_rad (ground truth map_T_robot;
// all three empty on a row without truth) and odom_x_m,odom_y_m,odom_phi_rad (odometry
// odom_T_robot), at least one group. Without odometry columns the odometry is sampled from
// the ground-truth increments with seeded noise, as `import antworld` does (antworld.h).
#ifndef OMNICML_LOGS_VIDEO_H_
#define OMNICML_LOGS_VIDEO_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include <opencv2/core.hpp>

#include "omnicml/sensor/frame.h"
#include "omnicml/tracking/tracker.h"

namespace cv {
class VideoCapture;
}

namespace omnicml {

// A frame of a video as named in frames.csv.
struct VideoFrameRef {
  std::string file;        // relative to the session directory
  std::int64_t index = 0;  // 0-based
};

// Whether a file name has one of the video extensions above.
bool IsVideoFileName(std::string_view name);
// `<file>#<index>` with a video file name and a decimal index, else std::nullopt (an image
// file name). An index with more than 18 digits is not a video reference either.
std::optional<VideoFrameRef> ParseVideoFrameRef(std::string_view image_column);
// The frames.csv text of a reference ("<file>#<index>").
std::string FormatVideoFrameRef(const VideoFrameRef& ref);

// Reads frames of one video file by index. Decodes sequentially while the indices asked
// for increase by small steps (it keeps the capture open and skips frames by decoding
// them); seeks only on a jump backwards or far ahead. Lifecycle: open in the constructor,
// Read any number of times, close in the destructor. Not thread-safe.
class VideoReader {
 public:
  // Throws omnicml::Error naming the file when it is missing, not a regular file, cannot
  // be opened by the FFmpeg backend, declares a frame larger than kMaxImagePixels or a
  // frame count above kMaxVideoFrames (common/limits.h), both checked before decoding.
  explicit VideoReader(const std::string& path);
  ~VideoReader();
  VideoReader(const VideoReader&) = delete;
  VideoReader& operator=(const VideoReader&) = delete;

  const std::string& path() const { return path_; }
  int width() const { return width_; }
  int height() const { return height_; }
  // Frames per second as declared by the container; 0 when it declares none.
  double fps() const { return fps_; }
  // Frame count as declared by the container; 0 when unknown (some streams).
  std::int64_t frame_count() const { return frame_count_; }

  // Frame `index` (>= 0) as CV_8UC3 BGR of width() x height(). Throws omnicml::Error naming
  // the file when the index is negative, at or past frame_count() (when known) or past the
  // end of the stream, or the frame cannot be decoded or has another size.
  cv::Mat Read(std::int64_t index);
  // Seeks done so far (a sequential pass does none).
  std::int64_t seeks() const { return seeks_; }

 private:
  std::string path_;
  std::unique_ptr<cv::VideoCapture> capture_;
  int width_ = 0;
  int height_ = 0;
  double fps_ = 0.0;
  std::int64_t frame_count_ = 0;
  std::int64_t next_index_ = 0;  // index of the frame the next read decodes
  std::int64_t seeks_ = 0;
};

struct VideoImportOptions {
  // Odometry error model when the poses CSV has no odometry columns (as AntWorldOptions):
  // variances a1 rot1^2 + a2 trans^2, a3 trans^2 + a4 (rot1^2 + rot2^2), a1 rot2^2 + a2
  // trans^2 of docs/design.md "Motion model".
  MotionNoise odometry_noise{.a1 = 1e-3, .a2 = 3e-4, .a3 = 1e-3, .a4 = 1e-4};
  // Seed of that noise (std::mt19937_64).
  std::uint64_t seed = 1;
  // Frames per second, overriding the container's (needed when it declares none); 0 = the
  // container's. Frames/s.
  double fps = 0.0;
  // Stamp of the video's first frame, seconds (the session's start_time_s).
  double start_time_s = 0.0;
  // Calibration YAML of a raw camera (camera_model.h, any model). "" = the frames are
  // panoramas when at least twice as wide as high, else the ring is auto-calibrated on
  // the first frame (as `import rosbag`).
  std::string calibration_yaml;
  // Session directory name ("" = the video's file stem) and day label.
  std::string session_name;
  std::string day_label = "video";
  // Replace an existing log (LogWriter's overwrite).
  bool overwrite = false;

  // Throws omnicml::Error naming the field (negative or non-finite a1..a4, negative or
  // non-finite fps, non-finite start time).
  void Validate() const;
};

struct VideoImportSummary {
  std::int64_t frames = 0;
  std::int64_t frames_with_truth = 0;
  bool odometry_sampled = false;  // no odometry columns: sampled from ground truth
};

// Writes a one-session log at `log_dir`: the video is placed in the session directory
// (hard-linked when the file system allows, else copied) and frames.csv names its frames
// (`<video>#<index>`), one row per row of `poses_csv`. The log appears atomically (LogWriter).
// Throws omnicml::Error naming the file and line of the first problem: a bad header, a
// number that is not finite, a frame index or stamp that does not increase or lies past the
// video's end, a row without ground truth when the odometry must be sampled from it.
VideoImportSummary ImportVideo(const std::string& video_path, const std::string& poses_csv,
                               const std::string& log_dir, const VideoImportOptions& options);

}  // namespace omnicml

#endif  // OMNICML_LOGS_VIDEO_H_
