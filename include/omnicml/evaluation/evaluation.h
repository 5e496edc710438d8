// Per-frame run records (the RUNDIR/frames.csv schema), error statistics against
// ground truth, trajectory alignment and the evaluation report of `omnicml evaluate`.
//
// frames.csv has a header line naming its columns; readers locate columns by name so
// columns may be added later. Columns (units in the names; empty cell = not available):
//   session, frame, global_frame, stamp_s,
//   est_x_m, est_y_m, est_phi_rad            strongest component of p(x_t)
//   mean_x_m, mean_y_m, mean_phi_rad         moment-matched summary of p(x_t)
//   unimodal                                 0/1 ([G] 2.1 unimodality test)
//   truth_x_m, truth_y_m, truth_phi_rad      ground truth, when the log has it
//   position_error_m, heading_error_rad      strongest estimate vs truth (|wrapped|)
//   odometry_error_m                         dead reckoning (anchored at the session's
//                                            first ground-truth pose) vs truth
//   views, map_components, hypotheses, mixture_components
//   time_<stage>_us ...                      wall time of each engine stage, microseconds
// Errors are computed from the strongest component (what a robot would act on).
//
// All functions are pure; thread-compatible.
#ifndef OMNICML_EVALUATION_H_
#define OMNICML_EVALUATION_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <ostream>
#include <string>
#include <vector>

#include "omnicml/geometry/pose.h"

namespace omnicml {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// One row of frames.csv.
struct FrameRecord {
  int session = 0;                // 0-based session (day) index
  std::int64_t frame = 0;         // index within the session
  std::int64_t global_frame = 0;  // index over the whole run
  double stamp_s = 0.0;
  bool has_estimate = false;            // false while a global start has not localized yet
  Pose2 estimate = Pose2::Zero();       // strongest component's mean
  Pose2 mean_estimate = Pose2::Zero();  // moment-matched mean
  bool unimodal = false;
  bool has_truth = false;
  Pose2 truth = Pose2::Zero();
  double position_error_m = kNaN;   // NaN without estimate or truth
  double heading_error_rad = kNaN;  // |WrapAngle(est - truth)|
  double odometry_error_m = kNaN;
  int views = 0;                       // reference views in the map after this frame
  int map_components = 0;              // components over all views
  int hypotheses = 0;                  // components of p(x|y)
  int mixture_components = 0;          // components of p(x_t)
  std::vector<double> stage_times_us;  // parallel to the stage names of the file
};

// Writes the header (with one time_<name>_us column per stage) and rows.
void WriteFramesCsvHeader(std::ostream& os, const std::vector<std::string>& stage_names);
void WriteFramesCsvRow(std::ostream& os, const FrameRecord& record);

// A parsed frames.csv.
struct FramesTable {
  std::vector<std::string> stage_names;
  std::vector<FrameRecord> records;
};
// Throws omnicml::Error naming file and line on a missing column, a short row or an
// unparsable number.
FramesTable ReadFramesCsv(const std::filesystem::path& path);

// Recomputes position and heading errors of records with estimate and truth.
void RecomputeErrors(std::vector<FrameRecord>* records);

// How the estimated trajectory is aligned to ground truth before errors are taken.
enum class Alignment {
  kNone,   // errors as estimated (the map frame is the truth frame)
  kStart,  // per session, the rigid transform putting its first estimate onto truth
  kSe2,    // one best rigid 2-D transform (Umeyama/Horn least squares on x, y) over the run
};
std::string ToString(Alignment alignment);            // none|start|se2
Alignment AlignmentFromString(const std::string& s);  // throws omnicml::Error

// Applies the alignment to the estimates (strongest and mean) and recomputes errors.
// Returns the transform used for kSe2 (identity otherwise) as (tx, ty, theta), applied
// as Compose(T, estimate). kSe2 needs at least two records with estimate and truth at
// distinct positions, otherwise throws omnicml::Error.
Pose2 Align(std::vector<FrameRecord>* records, Alignment alignment);

// Summary statistics of a sample; NaN values are ignored.
struct ErrorStats {
  int count = 0;
  double mean = kNaN;
  double median = kNaN;
  double p95 = kNaN;  // linear interpolation between order statistics
  double max = kNaN;
};
ErrorStats ComputeStats(std::vector<double> values);
// The q-quantile (0 <= q <= 1) of sorted finite values, linear interpolation; NaN if empty.
double Quantile(const std::vector<double>& sorted, double q);

// Counts of values in bins [edges[i], edges[i+1]); the last bin is closed and values
// beyond the last edge are counted in it (so nothing is lost). NaN ignored.
std::vector<double> HistogramCounts(const std::vector<double>& values,
                                    const std::vector<double>& edges);

struct DayEvaluation {
  int session = 0;
  int frames = 0;
  int frames_with_truth = 0;
  int frames_with_estimate = 0;
  double unimodal_fraction = kNaN;
  ErrorStats position_m;
  ErrorStats heading_rad;
  ErrorStats odometry_m;
  int views_at_end = 0;
  int map_components_at_end = 0;
  double mean_frame_time_us = kNaN;  // of the time_total_us column when present
};

struct EvaluationResult {
  Alignment alignment = Alignment::kNone;
  Pose2 alignment_transform = Pose2::Zero();
  std::vector<DayEvaluation> days;
  DayEvaluation overall;  // session = -1
  // Histograms of position error (metres) and heading error (radians) per day, on
  // common bins so days can be compared ([G] Fig. 5 and 6).
  std::vector<double> position_bin_edges_m;
  std::vector<std::vector<double>> position_histograms;  // per day
  std::vector<double> heading_bin_edges_rad;
  std::vector<std::vector<double>> heading_histograms;  // per day
};

// Per-day statistics of already aligned records.
DayEvaluation EvaluateDay(const std::vector<FrameRecord>& records, int session,
                          const std::vector<std::string>& stage_names);

// days.csv of a run directory: a header, then one row per session of `records` in order
// of appearance (EvaluateDay with stage_names): session, frames, frames_with_truth,
// unimodal_fraction, position_error_{mean,median,p95,max}_m, heading_error_mean_rad,
// odometry_error_mean_m, views_at_end, map_components_at_end, then `extra_columns`
// (values from extra_values(session), as many as columns), then mean_frame_time_us.
void WriteDaysCsv(std::ostream& os, const std::vector<FrameRecord>& records,
                  const std::vector<std::string>& stage_names,
                  const std::vector<std::string>& extra_columns = {},
                  const std::function<std::vector<std::string>(int session)>& extra_values = {});

// Aligns (a copy of) the records and evaluates every day and the whole run.
EvaluationResult Evaluate(const FramesTable& table, Alignment alignment, int histogram_bins = 20);

// Shortest decimal text that reads back to exactly v ("%.17g" at most); "" for NaN/inf.
std::string ShortestDouble(double v);

// A plain-text table: columns padded to their widest cell and separated by two spaces,
// right-aligned (the first column left-aligned when left_align_first). Rows may be
// shorter than the header (missing cells are blank).
std::string FormatTextTable(const std::vector<std::string>& header,
                            const std::vector<std::vector<std::string>>& rows,
                            bool left_align_first = false);

// Text table: one line per day (frames, mean/median/p95/max position error, heading
// error, odometry-only mean, change of the mean from the previous day), then the run,
// then (with_histogram) the position histogram as counts per bin and day.
std::string FormatEvaluation(const EvaluationResult& result, bool with_histogram = true);

// Inline SVG of the position-error histogram, one series per day (steps when there are
// several days), on the result's common bins.
std::string RenderPositionHistogramSvg(const EvaluationResult& result,
                                       const std::string& title = "Position error histogram");

// Self-contained HTML page (tables and inline SVG histograms and error-over-time plot).
std::string RenderEvaluationHtml(const EvaluationResult& result, const FramesTable& table,
                                 const std::string& title);

}  // namespace omnicml

#endif  // OMNICML_EVALUATION_H_
