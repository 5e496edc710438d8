// Survey mapping (`run` / `compare` --survey-days N [--survey-poses FILE]): the map of the
// first N days is built from trusted poses, as [G] built its "old" map, and CML runs on
// that map from day N + 1 on (docs/design.md "Survey mapping", docs/results.md).
//
// Trusted poses come from the input's ground truth (the log's gt columns, or the
// simulator) or from an external corrected trajectory in TUM format ("stamp x y z qx qy
// qz qw" per line, '#' comments and blank lines skipped; yaw from the quaternion),
// matched to frames by the frame's stamp (Frame::stamp_s, the log's stamp_s column)
// within kSurveyStampToleranceS.
//
// Metrics: a survey frame's estimate IS its trusted pose, so its error says nothing
// about localization. The error tables of `run` and `compare` cover the days after the
// survey only and say so (SurveyOptions::ExcludedNote); frames.csv and days.csv still
// hold every frame.
//
// Thread-safety: SurveyPoses is immutable after construction (thread-safe reads); the
// processor returned by MakeSurveyFrameProcessor is thread-compatible (one run).
#ifndef OMNICML_EXPERIMENTS_SURVEY_H_
#define OMNICML_EXPERIMENTS_SURVEY_H_

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/run/engine_driver.h"

namespace omnicml {

// Frame stamps and TUM stamps match when they differ by at most this. Seconds.
inline constexpr double kSurveyStampToleranceS = 1e-6;

// Survey mapping (docs/design.md "Survey mapping"): the first `days` days
// build the map from trusted poses, CML runs on it afterwards.
struct SurveyOptions {
  // Engine sessions (days) 0 .. days - 1 are survey days; 0 = no survey. >= 0.
  int days = 0;
  // TUM file of trusted poses ("" = the input's ground truth).
  std::string poses_path;
  // Standard deviations of a trusted pose: the covariance the survey's map updates carry
  // (and p(x_t) at the survey frames). Metres / radians, > 0.
  double position_sigma_m = 0.05;
  double heading_sigma_rad = 0.02;

  // Throws omnicml::Error naming the flag (--survey-days, --survey-poses).
  void Validate() const;
  bool enabled() const { return days > 0; }
  // diag(sigma_x^2, sigma_y^2, sigma_phi^2).
  Eigen::Matrix3d Covariance() const;
};

// An external trajectory of trusted poses, sorted by stamp.
class SurveyPoses {
 public:
  // Reads a TUM file. Throws omnicml::Error "<file>:<line>: ..." on a malformed line
  // (not 8 finite numbers, zero quaternion) and on a stamp within
  // kSurveyStampToleranceS of an earlier line's (the match would be ambiguous), or when
  // the file holds no pose.
  static SurveyPoses Read(const std::filesystem::path& path);

  // The pose whose stamp lies within kSurveyStampToleranceS of stamp_s (the closest),
  // std::nullopt when none does.
  std::optional<Pose2> Find(double stamp_s) const;
  std::size_t size() const { return stamps_.size(); }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
  std::vector<double> stamps_;  // sorted
  std::vector<Pose2> poses_;    // parallel to stamps_
};

// A FrameProcessor for RunEngineOverSource (run/engine_driver.h): frames of engine sessions <
// options.days go to CmlEngine::ProcessSurveyFrame at their trusted pose, later ones to
// ProcessFrame. `poses` (may be null) is used when options.poses_path is set. A survey frame
// without a trusted pose is an omnicml::Error naming the frame (session, index, stamp) and the TUM
// file, or saying that the input has no ground truth.
FrameProcessor MakeSurveyFrameProcessor(const SurveyOptions& options,
                                        std::shared_ptr<const SurveyPoses> poses);

// Records of the days after the survey (session >= options.days); all of them without
// a survey.
std::vector<FrameRecord> RecordsAfterSurvey(const std::vector<FrameRecord>& records,
                                            const SurveyOptions& options);

// "survey days 1-N (F frames) are excluded from the errors: their estimates are the
// trusted poses (ground truth | FILE)"; "" without a survey.
std::string SurveyExcludedNote(const SurveyOptions& options, std::int64_t survey_frames);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_SURVEY_H_
