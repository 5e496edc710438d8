#include "omnicml/experiments/survey.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"

namespace omnicml {

void SurveyOptions::Validate() const {
  if (days < 0) throw Error(StrCat("--survey-days must be >= 0, got ", days));
  if (!poses_path.empty() && days == 0) {
    throw Error(StrCat("--survey-poses '", poses_path, "' needs --survey-days N >= 1"));
  }
  if (!(position_sigma_m > 0.0) || !std::isfinite(position_sigma_m) || !(heading_sigma_rad > 0.0) ||
      !std::isfinite(heading_sigma_rad)) {
    throw Error(StrCat("survey pose sigmas must be finite and > 0, got ", position_sigma_m, " m, ",
                       heading_sigma_rad, " rad"));
  }
}

Eigen::Matrix3d SurveyOptions::Covariance() const {
  return Eigen::Vector3d(position_sigma_m * position_sigma_m, position_sigma_m * position_sigma_m,
                         heading_sigma_rad * heading_sigma_rad)
      .asDiagonal();
}

SurveyPoses SurveyPoses::Read(const std::filesystem::path& path) {
  LineReader in(path, "survey trajectory (TUM)");
  struct Row {
    double stamp;
    Pose2 pose;
    std::size_t line;
  };
  std::vector<Row> rows;
  std::string line;
  while (in.Next(&line)) {
    const std::size_t line_no = in.line_number();
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream is(line);
    double v[8];
    for (int k = 0; k < 8; ++k) {
      double& x = v[k];
      if (!(is >> x)) {
        // The line itself is not quoted: the file may be anything given by mistake.
        throw Error(StrCat(path.string(), ":", line_no,
                           ": expected 8 numbers: stamp x y z qx qy qz qw (number ", k + 1,
                           " is missing or not a number)"));
      }
      if (!std::isfinite(x))
        throw Error(StrCat(path.string(), ":", line_no, ": non-finite number"));
    }
    std::string rest;
    if (is >> rest) throw Error(StrCat(path.string(), ":", line_no, ": more than 8 values"));
    const double qx = v[4], qy = v[5], qz = v[6], qw = v[7];
    if (std::sqrt(qx * qx + qy * qy + qz * qz + qw * qw) < 1e-9) {
      throw Error(StrCat(path.string(), ":", line_no, ": zero quaternion"));
    }
    // Yaw of the rotation (ZYX convention), as report/map_export.h ReadTumTrajectory.
    const double yaw = std::atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz));
    rows.push_back({v[0], MakePose(v[1], v[2], yaw), line_no});
  }
  if (rows.empty()) throw Error(StrCat(path.string(), ": no pose (survey trajectory, TUM)"));
  std::stable_sort(rows.begin(), rows.end(),
                   [](const Row& a, const Row& b) { return a.stamp < b.stamp; });
  SurveyPoses out;
  out.path_ = path.string();
  for (std::size_t i = 0; i < rows.size(); ++i) {
    if (i > 0 && rows[i].stamp - rows[i - 1].stamp <= kSurveyStampToleranceS) {
      const std::size_t a = std::min(rows[i].line, rows[i - 1].line);
      const std::size_t b = std::max(rows[i].line, rows[i - 1].line);
      throw Error(StrCat(path.string(), ":", b, ": stamp ", ShortestDouble(rows[i].stamp),
                         " repeats the stamp of line ", a, " (frames are matched by stamp)"));
    }
    out.stamps_.push_back(rows[i].stamp);
    out.poses_.push_back(rows[i].pose);
  }
  return out;
}

std::optional<Pose2> SurveyPoses::Find(double stamp_s) const {
  const auto it = std::lower_bound(stamps_.begin(), stamps_.end(), stamp_s);
  std::optional<std::size_t> best;
  double best_d = kSurveyStampToleranceS;
  for (auto c : {it, it == stamps_.begin() ? stamps_.end() : it - 1}) {
    if (c == stamps_.end()) continue;
    const double d = std::abs(*c - stamp_s);
    if (d <= best_d) {
      best_d = d;
      best = static_cast<std::size_t>(c - stamps_.begin());
    }
  }
  if (!best) return std::nullopt;
  return poses_[*best];
}

FrameProcessor MakeSurveyFrameProcessor(const SurveyOptions& options,
                                        std::shared_ptr<const SurveyPoses> poses) {
  options.Validate();
  if (!options.poses_path.empty() && poses == nullptr) {
    poses = std::make_shared<const SurveyPoses>(SurveyPoses::Read(options.poses_path));
  }
  const Eigen::Matrix3d covariance = options.Covariance();
  const int days = options.days;
  const bool from_file = !options.poses_path.empty();
  return
      [days, from_file, poses, covariance](CmlEngine& engine, const Frame& frame) -> FrameResult {
        if (engine.session_state().session >= days) return engine.ProcessFrame(frame);
        std::optional<Pose2> pose;
        if (from_file) {
          pose = poses->Find(frame.stamp_s);
          if (!pose) {
            throw Error(StrCat(poses->path(), ": no pose with stamp ",
                               ShortestDouble(frame.stamp_s), " (survey day ",
                               frame.session_index + 1, ", frame ", frame.index_in_session,
                               "; --survey-poses needs a pose for every frame "
                               "of the survey days, matched by stamp within ",
                               kSurveyStampToleranceS, " s)"));
          }
        } else {
          pose = frame.map_T_robot_truth;
          if (!pose) {
            throw Error(StrCat(
                "--survey-days: frame ", frame.index_in_session, " of day ",
                frame.session_index + 1, " (stamp ", ShortestDouble(frame.stamp_s),
                ") has no ground-truth pose; give the trusted poses with --survey-poses FILE"));
          }
        }
        Gaussian g;
        g.mean = *pose;
        g.covariance = covariance;
        return engine.ProcessSurveyFrame(frame, g);
      };
}

std::vector<FrameRecord> RecordsAfterSurvey(const std::vector<FrameRecord>& records,
                                            const SurveyOptions& options) {
  std::vector<FrameRecord> out;
  for (const FrameRecord& r : records) {
    if (r.session >= options.days) out.push_back(r);
  }
  return out;
}

std::string SurveyExcludedNote(const SurveyOptions& options, std::int64_t survey_frames) {
  if (!options.enabled()) return "";
  return StrCat("survey day", options.days > 1 ? "s 1-" : " ", options.days, " (", survey_frames,
                " frames) excluded from the errors: their estimates are the trusted poses (",
                options.poses_path.empty() ? "ground truth of the input" : options.poses_path, ")");
}

}  // namespace omnicml
