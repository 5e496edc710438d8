#include "omnicml/logs/antworld.h"

#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>

#include "logs/internal/csv_util.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace fs = std::filesystem;

namespace {

constexpr double kDegToRad = kPi / 180.0;

// Lower-case, spaces removed: "X [mm]" -> "x[mm]".
std::string NormalizeHeader(std::string_view s) {
  std::string out;
  for (const char ch : s) {
    if (ch == ' ' || ch == '\t') continue;
    out += static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  }
  return out;
}

}  // namespace

void AntWorldOptions::Validate() const {
  odometry_noise.Validate("AntWorldOptions.odometry_noise.");
  if (stride < 1) throw Error(StrCat("AntWorldOptions.stride = ", stride, " must be >= 1"));
  if (!std::isfinite(row_period_s) || row_period_s <= 0.0) {
    throw Error(StrCat("AntWorldOptions.row_period_s = ", row_period_s, " must be > 0"));
  }
  if (!std::isfinite(start_time_s)) throw Error("AntWorldOptions.start_time_s must be finite");
  if (start.mode == SessionStartMode::kKnownPose) {
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(start.covariance(i, i)) || start.covariance(i, i) <= 0.0) {
        throw Error("AntWorldOptions.start.covariance must have a positive finite diagonal");
      }
    }
    if (!start.map_T_robot.allFinite())
      throw Error("AntWorldOptions.start.map_T_robot must be finite");
  }
}

double AntWorldHeadingToPhi(double heading_deg) {
  return WrapAngle((90.0 - heading_deg) * kDegToRad);
}

cv::Mat AntWorldToOurPanorama(const cv::Mat& antworld_panorama) {
  const int width = antworld_panorama.cols;
  if (antworld_panorama.empty() || width % 2 != 0) {
    throw Error(StrCat("AntWorld panorama must be non-empty with an even width (got ", width, ")"));
  }
  // out[c] = in[(W/2 - c) mod W] as one remap-free column permutation: flipping gives
  // f[c] = in[W - 1 - c]; then out[c] = f[(c + W/2 - 1) mod W], a roll.
  cv::Mat flipped;
  cv::flip(antworld_panorama, flipped, 1);
  cv::Mat out(antworld_panorama.size(), antworld_panorama.type());
  const int shift = width / 2 - 1;  // out[c] = flipped[(c + shift) mod W]
  // Columns [0, W - shift) come from flipped [shift, W), the rest from [0, shift).
  flipped.colRange(shift, width).copyTo(out.colRange(0, width - shift));
  if (shift > 0) flipped.colRange(0, shift).copyTo(out.colRange(width - shift, width));
  return out;
}

std::vector<AntWorldRow> ReadAntWorldCsv(const std::string& csv) {
  // A regular file with lines of at most kMaxCsvLineBytes (a FIFO or /dev/zero is an
  // error, not a hang).
  LineReader in(csv, "AntWorld route", kMaxCsvLineBytes);
  std::string line;
  if (!in.Next(&line)) throw Error(StrCat(csv, ":1: empty file"));
  {
    const auto fields = internal::SplitCsv(line);
    const char* expected[] = {"x[mm]", "y[mm]", "z[mm]", "heading[degrees]", "filename"};
    bool ok = fields.size() == 5;
    for (std::size_t i = 0; ok && i < 5; ++i) ok = NormalizeHeader(fields[i]) == expected[i];
    if (!ok) {
      // The line itself is not quoted: the file may be anything given by mistake.
      throw Error(StrCat(csv,
                         ":1: not an AntWorld CSV: the header line is not 'X [mm], Y [mm], "
                         "Z [mm], Heading [degrees], Filename'"));
    }
  }
  const fs::path dir = fs::path(csv).parent_path();
  std::vector<AntWorldRow> rows;
  std::int64_t line_number = 1;
  while (in.Next(&line)) {
    ++line_number;
    if (internal::Trim(line).empty()) continue;  // tolerate blank lines (e.g. at the end)
    const auto fail = [&](const std::string& what) {
      throw Error(StrCat(csv, ":", line_number, ": ", what));
    };
    const auto fields = internal::SplitCsv(line);
    if (fields.size() != 5) fail(StrCat("wrong column count ", fields.size(), " (expected 5)"));
    double values[4];
    for (int i = 0; i < 4; ++i) {
      const auto v = internal::ParseFiniteDouble(internal::Trim(fields[i]));
      if (!v) fail(StrCat("column ", i + 1, ": '", fields[i], "' is not a finite number"));
      values[i] = *v;
    }
    const std::string filename(internal::Trim(fields[4]));
    if (filename.empty()) fail("empty file name");
    AntWorldRow row;
    row.line = line_number;
    row.image_path = (dir / filename).string();
    row.map_T_robot =
        MakePose(values[0] / 1000.0, values[1] / 1000.0, AntWorldHeadingToPhi(values[3]));
    rows.push_back(std::move(row));
  }
  return rows;  // LineReader::Next throws on a read error
}

AntWorldReader::AntWorldReader(const std::string& csv, const AntWorldOptions& options)
    : csv_path_(csv) {
  options.Validate();
  const std::vector<AntWorldRow> all = ReadAntWorldCsv(csv);
  if (all.empty()) throw Error(StrCat(csv, ": no rows"));
  for (std::size_t i = 0; i < all.size(); i += static_cast<std::size_t>(options.stride)) {
    rows_.push_back(all[i]);
    stamps_s_.push_back(options.start_time_s + static_cast<double>(i) * options.row_period_s);
  }
  // Odometry: true increments between used rows, perturbed (sample_motion_model_odometry).
  std::mt19937_64 rng(options.seed);
  odometry_.reserve(rows_.size());
  odometry_.push_back(rows_[0].map_T_robot);
  for (std::size_t i = 1; i < rows_.size(); ++i) {
    const OdometryIncrement u = ComputeIncrement(rows_[i - 1].map_T_robot, rows_[i].map_T_robot);
    odometry_.push_back(
        ApplyIncrement(odometry_.back(), SampleOdometryIncrement(u, options.odometry_noise, rng)));
  }

  session_.name =
      options.session_name.empty() ? fs::path(csv).stem().string() : options.session_name;
  session_.day_label = options.day_label;
  session_.start_time_s = options.start_time_s;
  session_.start = options.start;
  if (session_.start.mode == SessionStartMode::kKnownPose && options.start_pose_from_truth) {
    session_.start.map_T_robot = rows_[0].map_T_robot;
  }
  cv::Mat first;
  try {
    first = ReadImage(rows_[0].image_path);
  } catch (const Error& e) {
    throw Error(StrCat(csv, ":", rows_[0].line, ": ", e.what()));  // ReadImage names the file
  }
  session_.camera.kind = ImageKind::kPanorama;
  session_.camera.image_width = first.cols;
  session_.camera.image_height = first.rows;
  if (first.cols % 2 != 0) {
    throw Error(StrCat(csv, ":", rows_[0].line, ": image ", rows_[0].image_path,
                       " has an odd width ", first.cols));
  }
}

const SessionInfo& AntWorldReader::Session(int index) const {
  OMNICML_CHECK(index == 0) << "AntWorldReader has one session, asked for " << index;
  return session_;
}

bool AntWorldReader::Next(Frame* frame) {
  OMNICML_CHECK(frame != nullptr);
  if (next_ >= NumFrames()) return false;
  const AntWorldRow& row = rows_[next_];
  const auto fail = [&](const std::string& what) {
    throw Error(StrCat(csv_path_, ":", row.line, ": image ", row.image_path, ": ", what));
  };
  cv::Mat image;
  try {
    image = ReadImage(row.image_path);
  } catch (const Error& e) {
    throw Error(StrCat(csv_path_, ":", row.line, ": ", e.what()));  // ReadImage names the file
  }
  if (image.cols != session_.camera.image_width || image.rows != session_.camera.image_height) {
    fail(StrCat("size ", image.cols, "x", image.rows, " differs from the first image's ",
                session_.camera.image_width, "x", session_.camera.image_height));
  }
  frame->session_index = 0;
  frame->index_in_session = next_;
  frame->global_index = next_;
  frame->stamp_s = stamps_s_[next_];
  frame->image = AntWorldToOurPanorama(image);
  frame->odom_T_robot = odometry_[next_];
  frame->map_T_robot_truth = row.map_T_robot;
  ++next_;
  return true;
}

std::int64_t ImportAntWorld(const std::string& csv, const std::string& out_dir,
                            const AntWorldOptions& options) {
  AntWorldReader reader(csv, options);
  LogWriter writer(out_dir);
  writer.BeginSession(reader.Session(0));
  Frame frame;
  std::int64_t written = 0;
  while (reader.Next(&frame)) {
    writer.Write(frame);
    ++written;
  }
  writer.Finish();
  return written;
}

}  // namespace omnicml
