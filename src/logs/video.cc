#include "omnicml/logs/video.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <vector>

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "logs/internal/csv_util.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/logs/antworld.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/unwrap/auto_calibration.h"
#include "omnicml/unwrap/camera_model.h"

namespace omnicml {
namespace fs = std::filesystem;

namespace {

// Frames skipped by decoding them rather than seeking (a seek decodes from the previous
// key frame anyway, and is not frame-exact on every container).
constexpr std::int64_t kMaxDecodeAhead = 64;

bool EndsWithNoCase(std::string_view s, std::string_view suffix) {
  if (s.size() < suffix.size()) return false;
  return std::equal(suffix.begin(), suffix.end(),
                    s.end() - static_cast<std::ptrdiff_t>(suffix.size()), [](char a, char b) {
                      return std::tolower(static_cast<unsigned char>(a)) ==
                             std::tolower(static_cast<unsigned char>(b));
                    });
}

}  // namespace

bool IsVideoFileName(std::string_view name) {
  for (const char* ext : {".avi", ".mkv", ".mp4", ".mov", ".webm"}) {
    const std::string_view e(ext);
    if (name.size() > e.size() && EndsWithNoCase(name, e)) return true;
  }
  return false;
}

std::optional<VideoFrameRef> ParseVideoFrameRef(std::string_view image_column) {
  const std::size_t hash = image_column.rfind('#');
  if (hash == std::string_view::npos) return std::nullopt;
  const std::string_view file = image_column.substr(0, hash);
  const std::string_view digits = image_column.substr(hash + 1);
  if (!IsVideoFileName(file) || digits.empty() || digits.size() > 18) return std::nullopt;
  if (!std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
    return std::nullopt;
  VideoFrameRef ref;
  ref.file = std::string(file);
  std::from_chars(digits.data(), digits.data() + digits.size(), ref.index);
  return ref;
}

std::string FormatVideoFrameRef(const VideoFrameRef& ref) {
  return StrCat(ref.file, "#", ref.index);
}

// ---------------------------------------------------------------------------------------
// VideoReader

VideoReader::VideoReader(const std::string& path) : path_(path) {
  CheckRegularFile(path, "video file");
  // An absolute path: FFmpeg would read "concat:..." or "http:..." as a protocol.
  const std::string absolute = fs::absolute(path).lexically_normal().string();
  capture_ = std::make_unique<cv::VideoCapture>();
  try {
    capture_->open(absolute, cv::CAP_FFMPEG);
  } catch (const cv::Exception& e) {
    throw Error(StrCat(path, ": cannot open video: ", Excerpt(e.what(), 200)));
  }
  if (!capture_->isOpened()) {
    throw Error(StrCat(path, ": cannot open video (not a file FFmpeg can decode)"));
  }
  const double w = capture_->get(cv::CAP_PROP_FRAME_WIDTH);
  const double h = capture_->get(cv::CAP_PROP_FRAME_HEIGHT);
  if (!(w >= 1 && h >= 1) || w * h > static_cast<double>(kMaxImagePixels)) {
    throw Error(StrCat(path, ": video declares ", w, "x", h, " pixels per frame (at most ",
                       kMaxImagePixels, " pixels)"));
  }
  width_ = static_cast<int>(w);
  height_ = static_cast<int>(h);
  const double count = capture_->get(cv::CAP_PROP_FRAME_COUNT);
  if (std::isfinite(count) && count > static_cast<double>(kMaxVideoFrames)) {
    throw Error(
        StrCat(path, ": video declares ", count, " frames (at most ", kMaxVideoFrames, ")"));
  }
  frame_count_ = std::isfinite(count) && count >= 1 ? static_cast<std::int64_t>(count) : 0;
  const double fps = capture_->get(cv::CAP_PROP_FPS);
  fps_ = std::isfinite(fps) && fps > 0.0 && fps <= 1e4 ? fps : 0.0;
}

VideoReader::~VideoReader() = default;

cv::Mat VideoReader::Read(std::int64_t index) {
  if (index < 0) throw Error(StrCat(path_, ": frame ", index, " is negative"));
  if (frame_count_ > 0 && index >= frame_count_) {
    throw Error(StrCat(path_, ": frame ", index, " asked for, the video has ", frame_count_,
                       " frames (0 to ", frame_count_ - 1, ")"));
  }
  try {
    if (index < next_index_ || index > next_index_ + kMaxDecodeAhead) {
      capture_->set(cv::CAP_PROP_POS_FRAMES, static_cast<double>(index));
      next_index_ = index;
      ++seeks_;
    }
    while (next_index_ < index) {
      if (!capture_->grab()) {
        throw Error(StrCat(path_, ": frame ", index, " asked for, the video ends after frame ",
                           next_index_ - 1));
      }
      ++next_index_;
    }
    cv::Mat frame;
    if (!capture_->read(frame) || frame.empty()) {
      throw Error(StrCat(path_, ": frame ", index,
                         " cannot be decoded (past the end of the stream or damaged)"));
    }
    ++next_index_;
    if (frame.type() == CV_8UC1) cv::cvtColor(frame, frame, cv::COLOR_GRAY2BGR);
    if (frame.type() != CV_8UC3 || frame.cols != width_ || frame.rows != height_) {
      throw Error(StrCat(path_, ": frame ", index, " decodes to ", frame.cols, "x", frame.rows,
                         " with ", frame.channels(), " channels, the video declares ", width_, "x",
                         height_, " 8-bit colour"));
    }
    return frame;
  } catch (const cv::Exception& e) {
    throw Error(StrCat(path_, ": frame ", index, ": ", Excerpt(e.what(), 200)));
  }
}

// ---------------------------------------------------------------------------------------
// import video

void VideoImportOptions::Validate() const {
  odometry_noise.Validate("VideoImportOptions.odometry_noise.");
  if (!std::isfinite(fps) || fps < 0.0 || fps > 1e4)
    throw Error(StrCat("--fps ", fps, " must lie in [0, 10000] (0 = the video's)"));
  if (!std::isfinite(start_time_s)) throw Error("--start-time must be finite");
}

namespace {

// One row of the poses CSV.
struct PoseRow {
  std::int64_t line = 0;
  std::int64_t frame = 0;
  double stamp_s = 0.0;
  std::optional<Pose2> odom;
  std::optional<Pose2> truth;
};

struct PosesCsv {
  bool has_odometry = false;
  bool has_truth = false;
  std::vector<PoseRow> rows;
};

// Reads the poses CSV (video.h): frame indices from `fps` for stamp rows, checked against
// `frame_count` when known (> 0).
PosesCsv ReadPosesCsv(const std::string& path, double fps, double start_time_s,
                      std::int64_t frame_count) {
  LineReader in(path, "poses CSV", kMaxCsvLineBytes);
  std::string line;
  if (!in.Next(&line)) throw Error(StrCat(path, ":1: empty file (expected a header line)"));
  internal::StripCarriageReturn(&line);
  const std::vector<std::string_view> header = internal::SplitCsv(line);
  const auto header_fail = [&](const std::string& what) {
    throw Error(StrCat(path, ":1: ", what,
                       " (expected frame or stamp_s, then gt_x_m,gt_y_m,gt_phi_rad and/or "
                       "odom_x_m,odom_y_m,odom_phi_rad)"));
  };
  const std::string key(internal::Trim(header[0]));
  if (key != "frame" && key != "stamp_s") header_fail(StrCat("first column '", Excerpt(key), "'"));
  const bool by_frame = key == "frame";
  static constexpr std::array<const char*, 6> kNames = {"odom_x_m", "odom_y_m", "odom_phi_rad",
                                                        "gt_x_m",   "gt_y_m",   "gt_phi_rad"};
  std::array<int, 6> column{-1, -1, -1, -1, -1, -1};
  for (std::size_t i = 1; i < header.size(); ++i) {
    const std::string_view name = internal::Trim(header[i]);
    const auto it = std::find(kNames.begin(), kNames.end(), name);
    if (it == kNames.end()) header_fail(StrCat("unknown column '", Excerpt(name), "'"));
    const std::size_t k = static_cast<std::size_t>(it - kNames.begin());
    if (column[k] >= 0) header_fail(StrCat("column '", name, "' given twice"));
    column[k] = static_cast<int>(i);
  }
  PosesCsv out;
  const int odom_given = (column[0] >= 0) + (column[1] >= 0) + (column[2] >= 0);
  const int truth_given = (column[3] >= 0) + (column[4] >= 0) + (column[5] >= 0);
  if (odom_given % 3 != 0 || truth_given % 3 != 0)
    header_fail("a pose needs all three of its columns");
  out.has_odometry = odom_given == 3;
  out.has_truth = truth_given == 3;
  if (!out.has_odometry && !out.has_truth) header_fail("no pose columns");

  while (in.Next(&line)) {
    internal::StripCarriageReturn(&line);
    if (internal::Trim(line).empty()) continue;
    const std::int64_t line_number = static_cast<std::int64_t>(in.line_number());
    const auto fail = [&](const std::string& what) {
      throw Error(StrCat(path, ":", line_number, ": ", what));
    };
    const std::vector<std::string_view> fields = internal::SplitCsv(line);
    if (fields.size() != header.size())
      fail(StrCat("wrong column count ", fields.size(), " (expected ", header.size(), ")"));
    const auto number = [&](int c, const char* name) {
      const auto v =
          internal::ParseFiniteDouble(internal::Trim(fields[static_cast<std::size_t>(c)]));
      if (!v) {
        fail(StrCat("column ", name, ": '", Excerpt(fields[static_cast<std::size_t>(c)]),
                    "' is not a finite number"));
      }
      return *v;
    };
    PoseRow row;
    row.line = line_number;
    const double key_value = number(0, key.c_str());
    if (by_frame) {
      if (key_value < 0 || key_value != std::floor(key_value) ||
          key_value > static_cast<double>(kMaxVideoFrames)) {
        fail(StrCat("frame '", Excerpt(fields[0]), "' is not a frame index in [0, ",
                    kMaxVideoFrames, "]"));
      }
      row.frame = static_cast<std::int64_t>(key_value);
      row.stamp_s = start_time_s + static_cast<double>(row.frame) / fps;
    } else {
      const double frame = std::round(key_value * fps);
      if (frame < 0 || frame > static_cast<double>(kMaxVideoFrames))
        fail(StrCat("stamp_s ", Excerpt(fields[0]), " lies before the video or too far after it"));
      row.frame = static_cast<std::int64_t>(frame);
      row.stamp_s = start_time_s + key_value;
    }
    if (frame_count > 0 && row.frame >= frame_count) {
      fail(StrCat("frame ", row.frame, " lies past the video's end (", frame_count, " frames)"));
    }
    if (!out.rows.empty() && row.frame <= out.rows.back().frame) {
      fail(StrCat("frame ", row.frame, " does not follow the previous row's frame ",
                  out.rows.back().frame, " (rows must go forward, one video frame each)"));
    }
    const auto pose = [&](int first) {
      const double x = number(column[first], kNames[first]);
      const double y = number(column[first + 1], kNames[first + 1]);
      const double phi = number(column[first + 2], kNames[first + 2]);
      if (std::abs(x) > kMaxPositionM || std::abs(y) > kMaxPositionM ||
          std::abs(phi) > kMaxHeadingRad) {
        fail(StrCat("pose (", x, ", ", y, ", ", phi, ") out of range"));
      }
      return MakePose(x, y, phi);
    };
    if (out.has_odometry) row.odom = pose(0);
    if (out.has_truth) {
      int empty = 0;
      for (int k = 3; k < 6; ++k)
        empty += internal::Trim(fields[static_cast<std::size_t>(column[k])]).empty();
      if (empty == 0) {
        row.truth = pose(3);
      } else if (empty != 3) {
        fail("ground truth columns must be all empty or all numbers");
      }
    }
    if (!out.has_odometry && !row.truth) {
      fail(
          "no ground truth on this row, and without odometry columns the odometry is sampled "
          "from the ground truth");
    }
    out.rows.push_back(row);
  }
  if (out.rows.empty()) throw Error(StrCat(path, ": no pose rows"));
  return out;
}

}  // namespace

VideoImportSummary ImportVideo(const std::string& video_path, const std::string& poses_csv,
                               const std::string& log_dir, const VideoImportOptions& options) {
  options.Validate();
  VideoReader video(video_path);
  const double fps = options.fps > 0.0 ? options.fps : video.fps();
  if (!(fps > 0.0)) {
    throw Error(StrCat(video_path, ": the video declares no frame rate; give --fps"));
  }
  PosesCsv poses = ReadPosesCsv(poses_csv, fps, options.start_time_s, video.frame_count());
  VideoImportSummary summary;
  summary.odometry_sampled = !poses.has_odometry;
  if (!poses.has_odometry) {
    // As `import antworld`: true increments perturbed by sample_motion_model_odometry.
    std::mt19937_64 rng(options.seed);
    poses.rows[0].odom = *poses.rows[0].truth;
    for (std::size_t i = 1; i < poses.rows.size(); ++i) {
      const OdometryIncrement u = ComputeIncrement(*poses.rows[i - 1].truth, *poses.rows[i].truth);
      poses.rows[i].odom = ApplyIncrement(*poses.rows[i - 1].odom,
                                          SampleOdometryIncrement(u, options.odometry_noise, rng));
    }
  }
  // The first and the last frame decode (the last one also proves the rows stay inside a
  // stream whose length the container does not declare).
  const cv::Mat first = video.Read(poses.rows.front().frame);
  video.Read(poses.rows.back().frame);

  SessionInfo info;
  info.name =
      options.session_name.empty() ? fs::path(video_path).stem().string() : options.session_name;
  info.day_label = options.day_label;
  info.start_time_s = options.start_time_s;
  info.camera.image_width = video.width();
  info.camera.image_height = video.height();
  if (!options.calibration_yaml.empty()) {
    info.camera.kind = ImageKind::kRawRing;
    info.camera.calibration = CameraCalibration::FromYamlFile(options.calibration_yaml);
  } else if (video.width() >= 2 * video.height()) {
    info.camera.kind = ImageKind::kPanorama;
  } else {
    info.camera.kind = ImageKind::kRawRing;
    try {
      info.camera.calibration = AutoCalibrate(first).calibration;
    } catch (const Error& e) {
      throw Error(StrCat(video_path, ": frame ", poses.rows.front().frame,
                         ": cannot calibrate the camera (give --calibration): ", e.what()));
    }
  }
  info.start.mode = SessionStartMode::kKnownPose;
  info.start.map_T_robot = poses.rows.front().truth.value_or(Pose2::Zero());

  LogWriter writer(log_dir, options.overwrite);
  writer.BeginSession(info);
  const std::string name = writer.AddSessionVideo(video_path);
  for (const PoseRow& row : poses.rows) {
    Frame frame;
    frame.stamp_s = row.stamp_s;
    frame.odom_T_robot = *row.odom;
    frame.map_T_robot_truth = row.truth;
    try {
      writer.WriteVideoFrame(frame, VideoFrameRef{name, row.frame});
    } catch (const Error& e) {
      throw Error(StrCat(poses_csv, ":", row.line, ": ", e.what()));
    }
    ++summary.frames;
    summary.frames_with_truth += row.truth.has_value();
  }
  writer.Finish();
  return summary;
}

}  // namespace omnicml
