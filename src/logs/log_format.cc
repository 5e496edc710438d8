#include "omnicml/logs/log_format.h"

#include <fcntl.h>  // AT_FDCWD
#include <stdio.h>  // renameat2 (glibc, _GNU_SOURCE)
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <sstream>
#include <system_error>

#include <yaml-cpp/yaml.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "logs/internal/csv_util.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/common/yaml_io.h"
#include "omnicml/logs/video.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace fs = std::filesystem;

namespace {

constexpr std::size_t kMaxSkippedMessages = 1000;
constexpr int kFramesCsvColumns = 8;

// ---------------------------------------------------------------------------------
// session.yaml parsing. Every error is "path:line: what" with the 1-based line of the
// offending node.

class YamlFile {
 public:
  explicit YamlFile(std::string path) : path_(std::move(path)) {}
  const std::string& path() const { return path_; }

  // Throws "<path>:<line>: <what>", `what` cut to one short line (it may quote the input).
  [[noreturn]] void Fail(const YAML::Node& node, const std::string& what) const {
    const int line = node.IsDefined() ? node.Mark().line + 1 : 0;
    if (line > 0) throw Error(StrCat(path_, ":", line, ": ", Excerpt(what, 300)));
    throw Error(StrCat(path_, ": ", Excerpt(what, 300)));
  }

  // Checks that `node` is a map whose keys are all in `allowed`.
  void CheckMap(const YAML::Node& node, const std::string& where,
                std::initializer_list<const char*> allowed) const {
    if (!node.IsMap()) Fail(node, StrCat("'", where, "' must be a map"));
    for (const auto& kv : node) {
      const std::string key = kv.first.Scalar();
      if (std::none_of(allowed.begin(), allowed.end(), [&](const char* a) { return key == a; })) {
        Fail(kv.first, StrCat("unknown key '", key, "' in '", where, "'"));
      }
    }
  }

  YAML::Node Required(const YAML::Node& map, const std::string& key,
                      const std::string& where) const {
    YAML::Node child = map[key];
    if (!child.IsDefined() || child.IsNull()) {
      Fail(map, StrCat("missing key '", key, "' in '", where, "'"));
    }
    return child;
  }

  std::string String(const YAML::Node& node, const std::string& key) const {
    if (!node.IsScalar()) Fail(node, StrCat("'", key, "' must be a scalar"));
    return node.Scalar();
  }

  double Double(const YAML::Node& node, const std::string& key) const {
    if (!node.IsScalar()) Fail(node, StrCat("'", key, "' must be a number"));
    const auto value = internal::ParseFiniteDouble(internal::Trim(node.Scalar()));
    if (!value) Fail(node, StrCat("'", key, "': '", node.Scalar(), "' is not a finite number"));
    return *value;
  }

  int Int(const YAML::Node& node, const std::string& key) const {
    if (!node.IsScalar()) Fail(node, StrCat("'", key, "' must be an integer"));
    const std::string& s = node.Scalar();
    int value = 0;
    const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), value);
    if (ec != std::errc() || ptr != s.data() + s.size()) {
      Fail(node, StrCat("'", key, "': '", s, "' is not an integer"));
    }
    return value;
  }

  Eigen::Vector3d Vector3(const YAML::Node& node, const std::string& key) const {
    if (!node.IsSequence() || node.size() != 3)
      Fail(node, StrCat("'", key, "' must be a list of 3 numbers"));
    Eigen::Vector3d v;
    for (int i = 0; i < 3; ++i) v[i] = Double(node[i], key);
    return v;
  }

 private:
  std::string path_;
};

// Validates a camera model; `fail` prefixes the message with the place of the problem.
template <typename Fail>
void CheckCamera(const CameraModel& camera, Fail fail) {
  if (camera.image_width < 2 || camera.image_height < 1) {
    fail(StrCat("camera image size ", camera.image_width, "x", camera.image_height, " is invalid"));
  }
  if (camera.kind == ImageKind::kRawRing) {
    try {
      camera.calibration.Validate();
      camera.calibration.ValidateFor(camera.image_width, camera.image_height);
    } catch (const Error& e) {
      fail(StrCat("camera.calibration: ", e.what()));
    }
  }
}

template <typename Fail>
void CheckStart(const SessionStart& start, Fail fail) {
  if (start.mode != SessionStartMode::kKnownPose) return;
  if (!start.map_T_robot.allFinite()) fail("start.pose is not finite");
  if (std::abs(start.map_T_robot.x()) > kMaxPositionM ||
      std::abs(start.map_T_robot.y()) > kMaxPositionM ||
      std::abs(start.map_T_robot.z()) > kMaxHeadingRad) {
    fail(StrCat("start.pose is out of range (|x|, |y| at most ", kMaxPositionM,
                " m, |phi| at most ", kMaxHeadingRad, " rad)"));
  }
  // A diagonal covariance is symmetric positive definite iff its diagonal is positive.
  for (int i = 0; i < 3; ++i) {
    const double v = start.covariance(i, i);
    if (!std::isfinite(v) || v <= 0.0)
      fail("start.covariance_diagonal must be positive and finite");
    const double max = i < 2 ? kMaxPositionVarianceM2 : kMaxHeadingVarianceRad2;
    if (v > max) {
      fail(StrCat("start.covariance_diagonal[", i, "] = ", v, " is too large (at most ", max,
                  i < 2 ? " m^2)" : " rad^2)"));
    }
  }
}

// Shortest round-trip text of a double (no validation).
std::string ToChars(double value) {
  std::array<char, 64> buffer;
  const auto [ptr, ec] = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  OMNICML_CHECK(ec == std::errc());
  return std::string(buffer.data(), ptr);
}

// A YAML double-quoted string.
std::string YamlQuoted(const std::string& s) {
  std::string out = "\"";
  for (const unsigned char ch : s) {
    if (ch == '"' || ch == '\\') {
      out += '\\';
      out += static_cast<char>(ch);
    } else if (ch < 0x20 || ch == 0x7f) {
      char buf[8];
      std::snprintf(buf, sizeof(buf), "\\x%02x", ch);
      out += buf;
    } else {
      out += static_cast<char>(ch);
    }
  }
  return out + "\"";
}

// Lists the session directories of a log directory, or the directory itself when it is a
// session. Throws omnicml::Error.
std::vector<std::string> ListSessionDirs(const std::string& log_dir) {
  std::error_code ec;
  if (!fs::is_directory(log_dir, ec)) throw Error(StrCat(log_dir, ": not a directory"));
  // A session.yaml that is present but unusable (a symbolic-link loop) is named as such.
  const auto present = [](const fs::path& yaml) {
    std::error_code lec;
    if (!fs::exists(fs::symlink_status(yaml, lec))) return false;
    std::error_code sec;
    (void)fs::status(yaml, sec);
    if (sec && sec != std::errc::no_such_file_or_directory) {
      throw Error(StrCat(yaml.string(), ": ", sec.message()));
    }
    if (sec) throw Error(StrCat(yaml.string(), ": dangling symbolic link"));
    return true;
  };
  if (present(fs::path(log_dir) / "session.yaml")) return {log_dir};
  std::vector<std::string> dirs;
  for (const auto& entry : fs::directory_iterator(log_dir, ec)) {
    if (!entry.is_directory()) continue;
    const std::string name = entry.path().filename().string();
    if (name.empty() || name[0] == '.') continue;
    dirs.push_back(entry.path().string());
  }
  if (ec) throw Error(StrCat(log_dir, ": cannot list directory: ", ec.message()));
  std::sort(dirs.begin(), dirs.end());
  if (dirs.empty()) throw Error(StrCat(log_dir, ": no session directory (and no session.yaml)"));
  for (const auto& dir : dirs) {
    const std::string yaml = (fs::path(dir) / "session.yaml").string();
    if (!present(yaml))
      throw Error(StrCat(yaml, ": missing file (every session directory needs one)"));
  }
  return dirs;
}

// Opens frames.csv (a regular file, lines of at most kMaxCsvLineBytes: a link to
// /dev/zero or a FIFO is an error, not a hang) and checks its header line.
std::unique_ptr<LineReader> OpenFramesCsv(const std::string& path) {
  auto in = std::make_unique<LineReader>(path, "log frames", kMaxCsvLineBytes);
  std::string header;
  if (!in->Next(&header)) throw Error(StrCat(path, ":1: empty file (expected the header line)"));
  if (header != kFramesCsvHeader) {
    // The line itself is not quoted: the file may be anything (a key file given by mistake).
    throw Error(
        StrCat(path, ":1: not a frames.csv file: the header line is not '", kFramesCsvHeader, "'"));
  }
  return in;
}

}  // namespace

std::string FormatRoundTrip(double value) {
  if (!std::isfinite(value)) throw Error(StrCat("cannot write non-finite number ", value));
  return ToChars(value);
}

// -----------------------------------------------------------------------------------
// session.yaml

SessionInfo ReadSessionYaml(const std::string& path) {
  YamlFile file(path);
  // A regular file of at most kMaxTextFileBytes (no FIFO, device or directory).
  const std::string text = ReadTextFile(path, kMaxTextFileBytes, "session file");
  YAML::Node root;
  try {
    root = LoadYaml(text, path);
  } catch (const YAML::Exception& e) {
    throw Error(StrCat(path, ":", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  }
  if (!root.IsMap()) throw Error(StrCat(path, ":1: expected a map of session keys"));
  file.CheckMap(root, "session",
                {"format_version", "day_label", "start_time_s", "camera", "start"});

  const YAML::Node version = file.Required(root, "format_version", "session");
  if (file.Int(version, "format_version") != kLogFormatVersion) {
    file.Fail(version, StrCat("unsupported format_version ", version.Scalar(),
                              " (this reader knows ", kLogFormatVersion, ")"));
  }
  SessionInfo info;
  if (root["day_label"]) info.day_label = file.String(root["day_label"], "day_label");
  if (root["start_time_s"]) info.start_time_s = file.Double(root["start_time_s"], "start_time_s");

  const YAML::Node camera = file.Required(root, "camera", "session");
  file.CheckMap(camera, "camera",
                {"model", "image_width", "image_height", "calibration", "mask_image"});
  const YAML::Node model = file.Required(camera, "model", "camera");
  const std::string model_name = file.String(model, "model");
  CameraModelType model_type = CameraModelType::kRing;
  if (model_name == "panorama") {
    info.camera.kind = ImageKind::kPanorama;
  } else {
    info.camera.kind = ImageKind::kRawRing;
    try {
      model_type = CameraModelTypeFromString(model_name);
    } catch (const Error&) {
      file.Fail(model, StrCat("unknown camera model '", model_name,
                              "' (expected panorama, omni_ring, fisheye or equirectangular)"));
    }
  }
  info.camera.image_width = file.Int(file.Required(camera, "image_width", "camera"), "image_width");
  info.camera.image_height =
      file.Int(file.Required(camera, "image_height", "camera"), "image_height");
  if (info.camera.kind == ImageKind::kRawRing) {
    // Every key of the model is required in session.yaml (camera_model.h).
    info.camera.calibration =
        ParseCameraCalibration(model_type, path, file.Required(camera, "calibration", "camera"),
                               "camera.calibration", true);
  } else {
    for (const char* key : {"calibration", "mask_image"}) {
      if (camera[key]) {
        file.Fail(camera[key], StrCat("'", key, "' is only meaningful for a raw camera model"));
      }
    }
  }
  CheckCamera(info.camera, [&](const std::string& what) { file.Fail(camera, what); });
  if (camera["mask_image"]) {
    info.camera.mask_image = file.String(camera["mask_image"], "mask_image");
    const fs::path mask_path = fs::path(path).parent_path() / info.camera.mask_image;
    cv::Mat mask;
    try {
      mask = ReadImage(mask_path.string());
    } catch (const Error& e) {
      file.Fail(camera["mask_image"], StrCat("camera.mask_image: ", e.what()));
    }
    if (mask.channels() == 3) cv::cvtColor(mask, mask, cv::COLOR_BGR2GRAY);
    if (mask.cols != info.camera.image_width || mask.rows != info.camera.image_height) {
      file.Fail(camera["mask_image"],
                StrCat("camera.mask_image: '", mask_path.string(), "' is ", mask.cols, "x",
                       mask.rows, ", the camera's images are ", info.camera.image_width, "x",
                       info.camera.image_height));
    }
    info.camera.mask = mask;
  }

  const YAML::Node start = file.Required(root, "start", "session");
  file.CheckMap(start, "start", {"mode", "pose", "covariance_diagonal"});
  const YAML::Node mode = file.Required(start, "mode", "start");
  try {
    info.start.mode = SessionStartModeFromString(file.String(mode, "mode"));
  } catch (const Error& e) {
    file.Fail(mode, e.what());
  }
  if (info.start.mode == SessionStartMode::kKnownPose) {
    const YAML::Node pose = file.Required(start, "pose", "start");
    const Eigen::Vector3d p = file.Vector3(pose, "pose");
    info.start.map_T_robot = MakePose(p.x(), p.y(), p.z());
    const YAML::Node cov = file.Required(start, "covariance_diagonal", "start");
    info.start.covariance = file.Vector3(cov, "covariance_diagonal").asDiagonal();
    CheckStart(info.start, [&](const std::string& what) { file.Fail(cov, what); });
  } else {
    info.start.map_T_robot = Pose2::Zero();
    for (const char* key : {"pose", "covariance_diagonal"}) {
      if (start[key])
        file.Fail(start[key], StrCat("'", key, "' is only meaningful for mode known"));
    }
  }
  return info;
}

std::string SessionYamlText(const SessionInfo& info) {
  std::ostringstream os;
  os << "format_version: " << kLogFormatVersion << "\n";
  os << "day_label: " << YamlQuoted(info.day_label) << "\n";
  os << "start_time_s: " << FormatRoundTrip(info.start_time_s) << "\n";
  os << "camera:\n";
  os << "  model: "
     << (info.camera.kind == ImageKind::kRawRing ? ToString(info.camera.calibration.model)
                                                 : std::string("panorama"))
     << "\n";
  os << "  image_width: " << info.camera.image_width << "\n";
  os << "  image_height: " << info.camera.image_height << "\n";
  if (info.camera.kind == ImageKind::kRawRing) {
    os << "  calibration:\n" << info.camera.calibration.YamlFields("    ");
    if (!info.camera.mask_image.empty())
      os << "  mask_image: " << YamlQuoted(info.camera.mask_image) << "\n";
  }
  os << "start:\n";
  os << "  mode: " << ToString(info.start.mode) << "\n";
  if (info.start.mode == SessionStartMode::kKnownPose) {
    const Pose2& p = info.start.map_T_robot;
    os << "  pose: [" << FormatRoundTrip(p.x()) << ", " << FormatRoundTrip(p.y()) << ", "
       << FormatRoundTrip(WrapAngle(p.z())) << "]\n";
    const Eigen::Matrix3d& c = info.start.covariance;
    os << "  covariance_diagonal: [" << FormatRoundTrip(c(0, 0)) << ", " << FormatRoundTrip(c(1, 1))
       << ", " << FormatRoundTrip(c(2, 2)) << "]\n";
  }
  return os.str();
}

// -----------------------------------------------------------------------------------
// LogReader

// Where the images of one session may lie (ImageInsideLog); absolute paths.
struct LogReaderRoot {
  fs::path lexical_root;           // the log directory as given, absolute and normalized
  fs::path session_dir;            // the session directory, absolute and normalized
  fs::path canonical_root;         // the log directory with links resolved
  fs::path canonical_session_dir;  // the session directory with links resolved
};

namespace {

std::atomic<bool> allow_images_outside_log{false};

// True when `path` (absolute, normalized) is `root` or lies below it.
bool LiesUnder(const fs::path& path, const fs::path& root) {
  const fs::path rel = path.lexically_relative(root);
  return !rel.empty() && *rel.begin() != ".." && !rel.is_absolute();
}

// `start` (absolute) with every symbolic link resolved the way the kernel resolves a
// path: component by component, ".." taken physically after the links before it. A link
// that leads nowhere is still followed by its text, and from the first component that
// does not exist the rest is taken as written, so the result names where the path leads
// whether or not that place exists. Empty after too many links (a loop).
fs::path ResolveLinks(const fs::path& start) {
  std::deque<fs::path> rest(start.begin(), start.end());
  if (rest.empty()) return {};
  fs::path done = rest.front();  // the root directory
  rest.pop_front();
  int links = 0;
  while (!rest.empty()) {
    const fs::path part = rest.front();
    rest.pop_front();
    if (part.empty() || part == ".") continue;
    if (part == "..") {
      done = done.parent_path();
      continue;
    }
    const fs::path next = done / part;
    struct stat st {};
    if (::lstat(next.c_str(), &st) != 0) {
      fs::path out = next;
      for (const fs::path& p : rest) out /= p;
      return out.lexically_normal();
    }
    if (!S_ISLNK(st.st_mode)) {
      done = next;
      continue;
    }
    std::error_code ec;
    const fs::path target = fs::read_symlink(next, ec);
    if (ec || ++links > 40) return {};
    std::vector<fs::path> parts;
    for (const fs::path& p : target.relative_path()) parts.push_back(p);
    rest.insert(rest.begin(), parts.begin(), parts.end());
    if (target.is_absolute()) done = target.root_path();
  }
  return done;
}

// Whether image `name` of frames.csv lies inside the log: first by its text alone
// against the log directory as given (an absolute name or one climbing out with ".." is
// refused without touching the outside path), then with its links resolved
// (ResolveLinks) against the canonical log directory or the canonical session directory
// (a session directory may itself be a link).
bool ImageInsideLog(const std::string& name, const LogReaderRoot& root) {
  const fs::path relative(name);
  if (relative.is_absolute() || relative.has_root_name() || relative.has_root_directory()) {
    return false;
  }
  const fs::path joined = (root.session_dir / relative).lexically_normal();
  if (!LiesUnder(joined, root.lexical_root)) return false;
  const fs::path resolved = ResolveLinks(root.session_dir / relative);
  return !resolved.empty() && (LiesUnder(resolved, root.canonical_root) ||
                               LiesUnder(resolved, root.canonical_session_dir));
}

}  // namespace

void SetAllowImagesOutsideLog(bool allow) { allow_images_outside_log.store(allow); }
bool AllowImagesOutsideLog() { return allow_images_outside_log.load(); }

LogReader::LogReader(const std::string& log_dir, LogReaderOptions options)
    : LogReader(std::vector<std::string>{log_dir}, options) {}

LogReader::LogReader(const std::vector<std::string>& log_dirs, LogReaderOptions options)
    : options_(options) {
  options_.Validate();
  if (log_dirs.empty()) throw Error("LogReader: no log directory given");
  const bool confine = !options_.allow_images_outside_log && !AllowImagesOutsideLog();
  const auto resolve = [](const std::string& dir) {
    std::error_code ec;
    fs::path resolved = fs::canonical(dir, ec);
    if (ec) throw Error(StrCat(dir, ": cannot resolve the directory: ", ec.message()));
    return resolved;
  };
  for (const auto& log_dir : log_dirs) {
    for (const auto& dir : ListSessionDirs(log_dir)) {
      SessionInfo info = ReadSessionYaml((fs::path(dir) / "session.yaml").string());
      info.name = fs::path(dir).filename().string();
      if (info.name.empty()) info.name = fs::path(dir).parent_path().filename().string();
      {
        // A session without a single row is an error here, not an empty day later.
        const std::string csv = (fs::path(dir) / "frames.csv").string();
        std::unique_ptr<LineReader> in = OpenFramesCsv(csv);
        std::string line;
        bool any = false;
        while (!any && in->Next(&line)) any = !internal::Trim(line).empty();
        if (!any) throw Error(StrCat(csv, ": no frames (only the header line): an empty session"));
      }
      sessions_.push_back(std::move(info));
      session_dirs_.push_back(dir);
      auto root = std::make_shared<LogReaderRoot>();
      if (confine) {
        root->lexical_root = fs::absolute(log_dir).lexically_normal();
        root->session_dir = fs::absolute(dir).lexically_normal();
        root->canonical_root = resolve(log_dir);
        root->canonical_session_dir = resolve(dir);
      }
      session_roots_.push_back(confine ? std::move(root) : nullptr);
    }
  }
}

LogReader::~LogReader() = default;

int LogReader::NumSessions() const { return static_cast<int>(sessions_.size()); }

const SessionInfo& LogReader::Session(int index) const {
  OMNICML_CHECK(index >= 0 && index < NumSessions()) << "session index " << index;
  return sessions_[index];
}

const std::string& LogReader::SessionDirectory(int index) const {
  OMNICML_CHECK(index >= 0 && index < NumSessions()) << "session index " << index;
  return session_dirs_[index];
}

bool LogReader::OpenSession() {
  if (session_ >= NumSessions()) return false;
  csv_path_ = (fs::path(session_dirs_[session_]) / "frames.csv").string();
  csv_ = OpenFramesCsv(csv_path_);
  video_.reset();
  line_number_ = 1;
  index_in_session_ = 0;
  have_last_stamp_ = false;
  session_channels_ = 0;
  return true;
}

bool LogReader::Next(Frame* frame) {
  OMNICML_CHECK(frame != nullptr);
  while (true) {
    if (session_ < 0 || csv_ == nullptr) {
      ++session_;
      if (session_ >= NumSessions()) {
        session_ = NumSessions();
        return false;
      }
      OpenSession();
    }
    std::string line;
    if (!csv_->Next(&line)) {  // throws on a read error or an overlong line
      csv_.reset();
      continue;
    }
    ++line_number_;
    try {
      ParseRow(line, frame);
    } catch (const Error& e) {
      if (!options_.skip_unreadable_frames) throw;
      ++num_skipped_;
      if (skipped_per_session_.size() <= static_cast<std::size_t>(session_))
        skipped_per_session_.resize(static_cast<std::size_t>(session_) + 1, 0);
      ++skipped_per_session_[static_cast<std::size_t>(session_)];
      if (skipped_messages_.size() < kMaxSkippedMessages) skipped_messages_.push_back(e.what());
      continue;
    }
    frame->session_index = session_;
    frame->index_in_session = index_in_session_++;
    frame->global_index = global_index_++;
    return true;
  }
}

void LogReader::ParseRow(const std::string& line, Frame* frame) {
  const auto fail = [&](const std::string& what) {
    throw Error(StrCat(csv_path_, ":", line_number_, ": ", what));
  };
  const std::vector<std::string_view> fields = internal::SplitCsv(line);
  if (static_cast<int>(fields.size()) != kFramesCsvColumns) {
    fail(StrCat("wrong column count ", fields.size(), " (expected ", kFramesCsvColumns, ")"));
  }
  static constexpr std::array<const char*, kFramesCsvColumns> kNames = {
      "stamp_s", "image", "odom_x_m", "odom_y_m", "odom_phi_rad", "gt_x_m", "gt_y_m", "gt_phi_rad"};
  const auto number = [&](int column) {
    const auto value = internal::ParseFiniteDouble(internal::Trim(fields[column]));
    if (!value) {
      fail(StrCat("column ", kNames[column], ": '", Excerpt(fields[column]),
                  "' is not a finite number"));
    }
    return *value;
  };
  const double stamp_s = number(0);
  if (have_last_stamp_ && !(stamp_s > last_stamp_s_)) {
    fail(StrCat("stamp_s ", Excerpt(fields[0]), " does not increase (previous ",
                FormatRoundTrip(last_stamp_s_), ")"));
  }
  const std::string image_name(internal::Trim(fields[1]));
  if (image_name.empty()) fail("empty image file name");
  // Poses within kMaxPositionM / kMaxHeadingRad (common/limits.h): 1e300 is finite but
  // breaks every later computation.
  const auto in_range = [&](int first_column) {
    const double x = number(first_column), y = number(first_column + 1),
                 phi = number(first_column + 2);
    for (int k = 0; k < 3; ++k) {
      const double v = k == 0 ? x : k == 1 ? y : phi;
      const double max = k < 2 ? kMaxPositionM : kMaxHeadingRad;
      if (std::abs(v) > max) {
        fail(StrCat("column ", kNames[first_column + k], ": ", Excerpt(fields[first_column + k]),
                    " is out of range (at most ", max, k < 2 ? " m)" : " rad)"));
      }
    }
    return MakePose(x, y, phi);
  };
  const Pose2 odom = in_range(2);
  std::optional<Pose2> truth;
  const int empty_gt = static_cast<int>(internal::Trim(fields[5]).empty()) +
                       internal::Trim(fields[6]).empty() + internal::Trim(fields[7]).empty();
  if (empty_gt == 0) {
    truth = in_range(5);
  } else if (empty_gt != 3) {
    fail("ground truth columns must be all empty or all numbers");
  }

  cv::Mat image;
  if (options_.load_images) {
    const std::optional<VideoFrameRef> video_frame = ParseVideoFrameRef(image_name);
    const std::string& file_name = video_frame ? video_frame->file : image_name;
    const LogReaderRoot* root = session_roots_[session_].get();
    if (root != nullptr && !ImageInsideLog(file_name, *root)) {
      // The same words whether or not the outside path exists.
      fail(StrCat("image '", Excerpt(image_name), "' lies outside the log directory '",
                  root->lexical_root.string(),
                  "' (an absolute path, '..' or a symbolic link leading out); images outside "
                  "the log are read only with --allow-images-outside-log"));
    }
    const std::string path = (fs::path(session_dirs_[session_]) / file_name).string();
    try {
      if (video_frame) {
        if (video_ == nullptr || video_->path() != path) {
          video_.reset();
          video_ = std::make_unique<VideoReader>(path);
        }
        image = video_->Read(video_frame->index);
      } else {
        image = ReadImage(path);
      }
    } catch (const Error& e) {
      fail(e.what());  // ReadImage and VideoReader name the file
    }
    const CameraModel& camera = sessions_[session_].camera;
    if (image.cols != camera.image_width || image.rows != camera.image_height) {
      fail(StrCat("image ", path, " is ", image.cols, "x", image.rows, ", session.yaml declares ",
                  camera.image_width, "x", camera.image_height));
    }
    if (image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3)) {
      fail(StrCat("image ", path, " is not 8-bit grey or colour"));
    }
    if (session_channels_ != 0 && image.channels() != session_channels_) {
      fail(StrCat("image ", path, " has ", image.channels(),
                  " channels, the session's first image ", session_channels_));
    }
  }
  // Commit (nothing above changed the reader's state).
  if (options_.load_images && session_channels_ == 0) session_channels_ = image.channels();
  last_stamp_s_ = stamp_s;
  have_last_stamp_ = true;
  frame->stamp_s = stamp_s;
  frame->image = image;
  frame->odom_T_robot = odom;
  frame->map_T_robot_truth = truth;
}

LogSummary ValidateLog(const std::string& log_dir) {
  LogReader reader(log_dir);
  LogSummary summary;
  for (int s = 0; s < reader.NumSessions(); ++s) {
    LogSessionSummary session;
    session.name = reader.Session(s).name;
    session.directory = reader.SessionDirectory(s);
    session.day_label = reader.Session(s).day_label;
    summary.sessions.push_back(session);
  }
  Frame frame;
  while (reader.Next(&frame)) {
    LogSessionSummary& session = summary.sessions[frame.session_index];
    if (session.frames == 0) session.first_stamp_s = frame.stamp_s;
    session.last_stamp_s = frame.stamp_s;
    ++session.frames;
    if (frame.map_T_robot_truth) ++session.frames_with_truth;
    ++summary.total_frames;
  }
  return summary;
}

// -----------------------------------------------------------------------------------
// LogWriter

LogWriter::LogWriter(const std::string& log_dir, bool overwrite) : overwrite_(overwrite) {
  fs::path dir = fs::path(log_dir).lexically_normal();
  if (dir.has_filename() == false) dir = dir.parent_path();  // "a/b/" -> "a/b"
  log_dir_ = dir.string();
  if (log_dir_.empty() || dir.filename() == "." || dir.filename() == "..") {
    throw Error(StrCat("LogWriter: invalid log directory '", log_dir, "'"));
  }
  std::error_code ec;
  if (fs::exists(log_dir_, ec) && !overwrite_) {
    throw Error(StrCat(log_dir_, ": already exists (remove it or ask to overwrite)"));
  }
  lock_ = std::make_unique<OutputLock>(log_dir_, "--out");
  // Staging directories of killed writers of the same log (we hold its lock).
  RemoveStaleStagingDirs(log_dir_);
  partial_dir_ = StagingDirFor(log_dir_, ::getpid()).string();
  fs::create_directories(partial_dir_, ec);
  if (ec) throw Error(StrCat(partial_dir_, ": cannot create directory: ", ec.message()));
}

LogWriter::~LogWriter() {
  if (finished_) return;
  csv_.reset();  // discards the uncommitted frames.csv
  std::error_code ec;
  fs::remove_all(partial_dir_, ec);
}

void LogWriter::CloseSession() {
  if (csv_ == nullptr) return;
  std::unique_ptr<AtomicFile> csv = std::move(csv_);
  csv->Commit();  // throws "<path>: write error: ..."
}

void LogWriter::BeginSession(const SessionInfo& info) {
  if (finished_) throw Error("LogWriter: BeginSession after Finish");
  const std::string& name = info.name;
  if (name.empty() || name[0] == '.' || name.find('/') != std::string::npos ||
      name.find('\\') != std::string::npos) {
    throw Error(StrCat("LogWriter: invalid session name '", name, "'"));
  }
  if (!session_names_.empty() && !(session_names_.back() < name)) {
    throw Error(StrCat("LogWriter: session '", name, "' must sort after the previous session '",
                       session_names_.back(), "' (readers take sessions in name order)"));
  }
  const auto fail = [&](const std::string& what) {
    throw Error(StrCat("LogWriter: session '", name, "': ", what));
  };
  CheckCamera(info.camera, fail);
  CheckStart(info.start, fail);
  if (!std::isfinite(info.start_time_s)) fail("start_time_s is not finite");
  SessionInfo stored = info;
  // A mask is stored next to session.yaml as mask.png.
  stored.camera.mask_image = stored.camera.mask.empty() ? "" : "mask.png";
  const std::string yaml = SessionYamlText(stored);

  CloseSession();
  session_dir_ = (fs::path(partial_dir_) / name).string();
  std::error_code ec;
  fs::create_directory(session_dir_, ec);
  if (ec) throw Error(StrCat(session_dir_, ": cannot create directory: ", ec.message()));
  WriteFileAtomic(fs::path(session_dir_) / "session.yaml", yaml, FileSync::kDeferred);
  if (!stored.camera.mask.empty()) {
    std::vector<std::uint8_t> png;
    cv::imencode(".png", stored.camera.mask, png);
    WriteFileAtomic(fs::path(session_dir_) / stored.camera.mask_image, png, FileSync::kDeferred);
  }
  csv_ = std::make_unique<AtomicFile>(fs::path(session_dir_) / "frames.csv", FileSync::kDeferred);
  csv_->stream() << kFramesCsvHeader << "\n";
  if (!csv_->stream()) throw Error(StrCat(session_dir_, "/frames.csv: cannot write"));
  session_names_.push_back(name);
  session_ = info;
  frames_in_session_ = 0;
  session_channels_ = 0;
  session_videos_.clear();
}

void LogWriter::CheckRow(const Frame& frame) const {
  if (finished_) throw Error("LogWriter: Write after Finish");
  if (csv_ == nullptr) throw Error("LogWriter: Write before BeginSession");
  const auto fail = [&](const std::string& what) {
    throw Error(
        StrCat("LogWriter: session '", session_.name, "' frame ", frames_in_session_, ": ", what));
  };
  if (!std::isfinite(frame.stamp_s)) fail("stamp_s is not finite");
  if (frames_in_session_ > 0 && !(frame.stamp_s > last_stamp_s_)) {
    fail(StrCat("stamp_s ", frame.stamp_s, " does not increase (previous ", last_stamp_s_, ")"));
  }
  if (!frame.odom_T_robot.allFinite()) fail("odom_T_robot is not finite");
  if (frame.map_T_robot_truth && !frame.map_T_robot_truth->allFinite())
    fail("map_T_robot_truth is not finite");
}

void LogWriter::AppendRow(const Frame& frame, const std::string& image_column) {
  std::ostream& csv = csv_->stream();
  const Pose2& o = frame.odom_T_robot;
  csv << FormatRoundTrip(frame.stamp_s) << ',' << image_column << ',' << FormatRoundTrip(o.x())
      << ',' << FormatRoundTrip(o.y()) << ',' << FormatRoundTrip(WrapAngle(o.z())) << ',';
  if (frame.map_T_robot_truth) {
    const Pose2& t = *frame.map_T_robot_truth;
    csv << FormatRoundTrip(t.x()) << ',' << FormatRoundTrip(t.y()) << ','
        << FormatRoundTrip(WrapAngle(t.z()));
  } else {
    csv << ",,";
  }
  csv << '\n';
  if (!csv) throw Error(StrCat(session_dir_, "/frames.csv: write error"));
  last_stamp_s_ = frame.stamp_s;
  ++frames_in_session_;
}

void LogWriter::Write(const Frame& frame) {
  CheckRow(frame);
  const auto fail = [&](const std::string& what) {
    throw Error(
        StrCat("LogWriter: session '", session_.name, "' frame ", frames_in_session_, ": ", what));
  };
  const cv::Mat& image = frame.image;
  if (image.empty()) fail("empty image");
  if (image.type() != CV_8UC1 && image.type() != CV_8UC3) fail("image is not CV_8UC1 or CV_8UC3");
  if (image.cols != session_.camera.image_width || image.rows != session_.camera.image_height) {
    fail(StrCat("image is ", image.cols, "x", image.rows, ", the session's camera ",
                session_.camera.image_width, "x", session_.camera.image_height));
  }
  if (session_channels_ != 0 && image.channels() != session_channels_) {
    fail(StrCat("image has ", image.channels(), " channels, the session's first image ",
                session_channels_));
  }

  char name[32];
  std::snprintf(name, sizeof(name), "%06lld.png", static_cast<long long>(frames_in_session_));
  const std::string path = (fs::path(session_dir_) / name).string();
  // Lossless PNG with fixed settings, so the bytes are deterministic. Run-length deflate
  // after PNG's row filters was as small as level 3-6 and faster on rendered rings and on
  // AntWorld panoramas. Written like every file (WriteFileAtomic); made durable all at
  // once by Finish() (SyncFileSystem) before it renames the staging directory.
  std::vector<std::uint8_t> png;
  bool encoded = false;
  try {
    encoded = cv::imencode(
        ".png", image, png,
        {cv::IMWRITE_PNG_COMPRESSION, 1, cv::IMWRITE_PNG_STRATEGY, cv::IMWRITE_PNG_STRATEGY_RLE});
  } catch (const cv::Exception& e) {
    throw Error(StrCat(path, ": cannot encode image: ", e.what()));
  }
  if (!encoded) throw Error(StrCat(path, ": cannot encode image"));
  WriteFileAtomic(path, png, FileSync::kDeferred);
  AppendRow(frame, name);
  if (session_channels_ == 0) session_channels_ = image.channels();
}

std::string LogWriter::AddSessionVideo(const std::string& video_path) {
  if (finished_) throw Error("LogWriter: AddSessionVideo after Finish");
  if (csv_ == nullptr) throw Error("LogWriter: AddSessionVideo before BeginSession");
  const std::string name = fs::path(video_path).filename().string();
  if (name.empty() || name[0] == '.' || !IsVideoFileName(name) ||
      name.find('#') != std::string::npos) {
    throw Error(StrCat(video_path,
                       ": not a video file name (.avi, .mkv, .mp4, .mov or .webm, "
                       "without '#' and not starting with '.')"));
  }
  CheckRegularFile(video_path, "video file");
  const fs::path target = fs::path(session_dir_) / name;
  std::error_code ec;
  if (fs::exists(target, ec)) throw Error(StrCat(target.string(), ": exists already"));
  // A hard link costs nothing and the staging directory's removal on failure leaves the
  // original alone; across file systems the video is copied.
  fs::create_hard_link(video_path, target, ec);
  if (ec) {
    ec.clear();
    fs::copy_file(video_path, target, ec);
    if (ec) throw Error(StrCat(video_path, ": cannot copy into the log: ", ec.message()));
  }
  session_videos_.push_back(name);
  return name;
}

void LogWriter::WriteVideoFrame(const Frame& frame, const VideoFrameRef& ref) {
  CheckRow(frame);
  if (std::find(session_videos_.begin(), session_videos_.end(), ref.file) == session_videos_.end())
    throw Error(StrCat("LogWriter: session '", session_.name, "': video '", ref.file,
                       "' was not added to the session (AddSessionVideo)"));
  if (ref.index < 0) throw Error(StrCat("LogWriter: negative video frame index ", ref.index));
  AppendRow(frame, FormatVideoFrameRef(ref));
}

void LogWriter::AddFile(const std::string& file_name, const std::string& contents) {
  if (finished_) throw Error("LogWriter: AddFile after Finish");
  if (file_name.empty() || file_name[0] == '.' || file_name.find('/') != std::string::npos ||
      file_name.find('\\') != std::string::npos) {
    throw Error(StrCat("LogWriter: invalid file name '", file_name, "'"));
  }
  const std::string path = (fs::path(partial_dir_) / file_name).string();
  std::error_code ec;
  if (fs::is_directory(path, ec)) throw Error(StrCat(path, ": a session has that name"));
  WriteFileAtomic(path, contents, FileSync::kDeferred);
}

std::int64_t WriteFrames(FrameSource& source, LogWriter& writer,
                         const std::function<void(const Frame&)>& on_frame) {
  Frame frame;
  int session = -1;
  std::int64_t frames = 0;
  while (source.Next(&frame)) {
    if (frame.session_index != session) {
      session = frame.session_index;
      writer.BeginSession(source.Session(session));
    }
    writer.Write(frame);
    ++frames;
    if (on_frame) on_frame(frame);
  }
  return frames;
}

void LogWriter::Finish() {
  if (finished_) throw Error("LogWriter: Finish called twice");
  if (session_names_.empty()) throw Error(StrCat(log_dir_, ": no session was written"));
  CloseSession();
  SyncFileSystem(partial_dir_);  // every file durable before the log appears under its name
  std::error_code ec;
  const fs::path parent =
      fs::path(log_dir_).has_parent_path() ? fs::path(log_dir_).parent_path() : fs::path(".");
  struct SyncParentOnReturn {
    const fs::path& dir;
    ~SyncParentOnReturn() { SyncDirectory(dir); }
  } sync_parent{parent};
  if (fs::exists(log_dir_, ec)) {
    if (!overwrite_) throw Error(StrCat(log_dir_, ": appeared while writing; not replaced"));
    // Swap the new log in atomically, then delete the old one (now under the partial name).
    if (::renameat2(AT_FDCWD, partial_dir_.c_str(), AT_FDCWD, log_dir_.c_str(), RENAME_EXCHANGE) ==
        0) {
      fs::remove_all(partial_dir_, ec);
      finished_ = true;
      return;
    }
    // Fallback (file systems without RENAME_EXCHANGE): move the old log aside first.
    const std::string old_dir = StrCat(log_dir_, ".old-", ::getpid());
    fs::remove_all(old_dir, ec);
    fs::rename(log_dir_, old_dir, ec);
    if (ec) throw Error(StrCat(log_dir_, ": cannot move the old log aside: ", ec.message()));
    fs::rename(partial_dir_, log_dir_, ec);
    if (ec) {
      std::error_code back;
      fs::rename(old_dir, log_dir_, back);  // keep the old log where it was
      throw Error(StrCat(log_dir_, ": cannot rename ", partial_dir_, ": ", ec.message()));
    }
    fs::remove_all(old_dir, ec);
    finished_ = true;
    return;
  }
  fs::rename(partial_dir_, log_dir_, ec);
  if (ec) throw Error(StrCat(log_dir_, ": cannot rename ", partial_dir_, ": ", ec.message()));
  finished_ = true;
}

}  // namespace omnicml
