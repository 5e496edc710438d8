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
//   localized                                1 when the frame has an estimate (est_* set)
//   run_stamp_s                              stamp made unique over the run (RunStampClock);
//                                            the stamp of the TUM files
//   odom_x_m, odom_y_m, odom_phi_rad         odometry pose as delivered by the log
//   cov_xx_m2, cov_xy_m2, cov_yy_m2, var_phi_rad2, nees_xy, matches, best_similarity,
//   nees_phi, nis, prior_nees_xy, fix_nees_xy   covariance and consistency (FrameRecord)
// (The columns after the timings were added later; readers accept files without them.)
// Errors are computed from the strongest component (what a robot would act on).
//
// Metrics and frames without an estimate (docs/outputs.md, "Definitions used everywhere"): a frame
// is localized when the engine produced a pose for it (FrameResult::estimate; after a global start
// there is none until the first confident p(x|y) seeds the tracker). Coverage = localized frames /
// frames. Error statistics are over the localized frames with ground truth only and are never
// reported without the coverage next to them. Frames the log reader skipped as unreadable
// (--skip-unreadable-frames) are not frames of the run; they are counted separately
// (frames_skipped).
//
// All functions are pure; thread-compatible.
#ifndef OMNICML_EVALUATION_EVALUATION_H_
#define OMNICML_EVALUATION_EVALUATION_H_

#include <cstdint>
#include <filesystem>
#include <functional>
#include <limits>
#include <map>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/geometry/pose.h"

namespace omnicml {

class SvgPlot;
struct TrajectoryMetrics;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// One row of frames.csv.
struct FrameRecord {
  int session = 0;                      // 0-based session (day) index
  std::int64_t frame = 0;               // index within the session
  std::int64_t global_frame = 0;        // index over the whole run
  double stamp_s = 0.0;                 // as delivered by the source
  double run_stamp_s = kNaN;            // unique over the run (RunStampClock); NaN = stamp_s
  bool has_estimate = false;            // false while a global start has not localized yet
  Pose2 estimate = Pose2::Zero();       // strongest component's mean
  Pose2 mean_estimate = Pose2::Zero();  // moment-matched mean
  bool unimodal = false;
  bool has_truth = false;
  Pose2 truth = Pose2::Zero();
  double position_error_m = kNaN;   // NaN without estimate or truth
  double heading_error_rad = kNaN;  // |WrapAngle(est - truth)|
  double odometry_error_m = kNaN;
  bool has_odometry = false;
  Pose2 odometry = Pose2::Zero();      // odom_T_robot as delivered (the session's odometry frame)
  int views = 0;                       // reference views in the map after this frame
  int map_components = 0;              // components over all views
  int hypotheses = 0;                  // components of p(x|y)
  int mixture_components = 0;          // components of p(x_t)
  std::vector<double> stage_times_us;  // parallel to the stage names of the file
  // Covariance of the strongest component (the estimate's own uncertainty) in the map
  // frame: xy block (m^2) and heading variance (rad^2); NaN when unknown (no estimate,
  // or a frames.csv written before these columns existed).
  double cov_xx_m2 = kNaN;
  double cov_xy_m2 = kNaN;
  double cov_yy_m2 = kNaN;
  double var_phi_rad2 = kNaN;
  // Normalised estimation error squared of the position, e^T C_xy^-1 e with e = estimate
  // - truth: chi-square with 2 degrees of freedom (mean 2, median 1.386) for an estimate
  // whose covariance is consistent with its error; below: under-confident, above:
  // over-confident. NaN without estimate, truth or covariance (RecomputeErrors).
  double nees_xy = kNaN;
  // Heading NEES, WrapAngle(est - truth)^2 / var_phi: chi-square with 1 degree of freedom
  // (mean 1, median 0.455) for a consistent heading variance. NaN like nees_xy.
  double nees_phi = kNaN;
  // Normalised innovation squared of the appearance fix (engine runs; no truth needed):
  // d^T (C_u + C_y)^-1 d between the strongest component of the prior p(x|u) and the
  // p(x|y) component nearest to it, 3 degrees of freedom (x, y, phi; mean 3, median
  // 2.37). NaN on frames without p(x|y) or without a prior.
  double nis = kNaN;
  // Stage diagnostics (engine runs with truth): position NEES of the prior's strongest
  // component (odometry propagation alone) and of the p(x|y) component nearest to it (the
  // map's observation, after the engine's shaping). NaN where the stage has no component.
  double prior_nees_xy = kNaN;
  double fix_nees_xy = kNaN;
  // How the frame matched the map (engine runs; unknown in older files and MCL runs):
  // views with E < e_max (after top_k), -1 unknown; and the similarity S of the best of
  // them, 0 without a match, NaN unknown. p(x|y) enters the fusion only from S >=
  // hypothesis_min_similarity (docs/outputs.md "Definitions used everywhere").
  int matches = -1;
  double best_similarity = kNaN;
};

// Writes the header (with one time_<name>_us column per stage) and rows.
void WriteFramesCsvHeader(std::ostream& os, const std::vector<std::string>& stage_names);
void WriteFramesCsvRow(std::ostream& os, const FrameRecord& record);

// A parsed frames.csv.
struct FramesTable {
  std::vector<std::string> stage_names;
  std::vector<FrameRecord> records;
  // Input frames skipped as unreadable, per session (from days.csv, see
  // ReadSkippedFrames); sessions absent = none or unknown.
  std::map<int, std::int64_t> skipped_frames;
};
// Throws omnicml::Error naming file and line on a missing column, a short row or an
// unparsable number.
FramesTable ReadFramesCsv(const std::filesystem::path& path);
// Fills table->skipped_frames from the frames_skipped column of a run's days.csv. A
// missing file or a file without that column (older runs) leaves it empty; an
// unparsable cell throws omnicml::Error naming file and line.
void ReadSkippedFrames(const std::filesystem::path& days_csv, FramesTable* table);

// Run-unique stamps. Sessions of a log may each start at 0 (two imported days), so raw
// stamps repeat over a multi-day run. The clock keeps each stamp as it is while the run
// stays strictly increasing; when the first stamp of a session is not after the last
// run stamp, the whole session is shifted by one offset so its first frame comes one
// frame period after the previous session's last frame. The frame period is that of the
// previous session ((last - first) / (frames - 1)), 1 s when it has one frame.
// Stamps within a session must increase strictly (the log reader and the simulator
// guarantee it); then run stamps increase strictly over the whole run. A run resumed
// with --map-in starts its own clock.
class RunStampClock {
 public:
  // The run stamp of the next frame, delivered in order; `session` changes start a new
  // session (offset chosen from its first stamp).
  double Next(int session, double stamp_s);
  // Offset (seconds) added to the stamps of the current session.
  double offset_s() const { return offset_s_; }

 private:
  int session_ = -1;
  bool have_last_ = false;
  double offset_s_ = 0.0;
  double last_run_stamp_s_ = 0.0;
  double session_first_stamp_s_ = 0.0;
  double session_last_stamp_s_ = 0.0;
  std::int64_t session_frames_ = 0;
};

// evo-ready TUM files ("stamp x y z qx qy qz qw", z = 0, yaw quaternion; report/
// map_export.h TumLine) of records in order, on run stamps (run_stamp_s, stamp_s when
// NaN). Only localized frames are written, so all three files share their stamps:
//   kEstimate      the strongest estimate of every localized frame
//   kGroundTruth   the truth of every localized frame that has it (every one when the
//                  log has ground truth throughout)
//   kOdometry      the odometry of every localized frame (in each session's odometry
//                  frame: compare per session or align, e.g. evo_ape ... --align)
enum class TumContent { kEstimate, kGroundTruth, kOdometry };
void WriteTum(std::ostream& os, const std::vector<FrameRecord>& records, TumContent content);
// Whether records hold any line for `content` (ground truth / odometry known somewhere).
bool HasTumContent(const std::vector<FrameRecord>& records, TumContent content);

// FrameRecord::nees_xy of one record from its estimate, truth and covariance (NaN when
// one is missing or the xy covariance is not positive definite).
double PositionNees(const FrameRecord& record);
// e^T C^-1 e of a position error e (metres) under the xy covariance (cxx, cxy, cyy) in
// m^2; NaN when the covariance is not positive definite or an input is not finite.
double PositionNees(double ex_m, double ey_m, double cxx_m2, double cxy_m2, double cyy_m2);
// FrameRecord::nees_phi: WrapAngle(estimate - truth)^2 / var_phi_rad2 (NaN when one is
// missing or the variance is not positive).
double HeadingNees(const FrameRecord& record);

// Sets the position and heading errors and the NEES of one record from its estimate,
// truth and covariance (NaN where one is missing).
void ComputeErrors(FrameRecord* record);
// ComputeErrors on every record.
void RecomputeErrors(std::vector<FrameRecord>* records);

// How the estimated trajectory is aligned to ground truth before errors are taken.
enum class Alignment {
  kNone,   // errors as estimated (the map frame is the truth frame)
  kStart,  // per session, the rigid transform putting its first estimate onto truth
  kSe2,    // one best rigid 2-D transform (Umeyama/Horn least squares on x, y) over the run
};
std::string ToString(Alignment alignment);            // none|start|se2
Alignment AlignmentFromString(const std::string& s);  // throws omnicml::Error

// Applies the alignment to the estimates (strongest and mean; the covariance's xy block is
// rotated with them) and recomputes errors. The estimates of records the alignment moves
// lose their prior_nees_xy and fix_nees_xy (NaN): those compare the prior's and the fix's
// means, which the records do not hold, with the truth, so they cannot be aligned.
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
  double rmse = kNaN;  // sqrt(mean(v^2)): evo's headline APE figure for position errors
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
  int frames = 0;  // frames delivered to the engine (= localized + unlocalized)
  int frames_with_truth = 0;
  int frames_with_estimate = 0;     // localized frames
  int frames_unlocalized = 0;       // frames - frames_with_estimate
  double coverage = kNaN;           // frames_with_estimate / frames; NaN without frames
  std::int64_t frames_skipped = 0;  // input frames skipped as unreadable (not in `frames`)
  double unimodal_fraction = kNaN;
  ErrorStats position_m;
  ErrorStats heading_rad;
  ErrorStats odometry_m;
  // position_m / heading_rad: over localized frames with ground truth (count = those).
  // nees_xy: over those of them with a covariance (FrameRecord::nees_xy).
  ErrorStats nees_xy;
  // Consistency (docs/design.md "Consistency metrics"): heading NEES (1 dof), NIS of the
  // appearance fixes (3 dof, frames with a fix), the stage NEES of the prior and of the
  // fix, and for each the fraction of its frames inside the two-sided 95 % chi-square
  // band of its degrees of freedom (a consistent estimator: about 0.95; NaN when there
  // is no value).
  ErrorStats nees_phi;
  ErrorStats nis;
  ErrorStats prior_nees_xy;
  ErrorStats fix_nees_xy;
  double nees_xy_in_band = kNaN;
  double nees_phi_in_band = kNaN;
  double nis_in_band = kNaN;
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

// Per-day statistics of already aligned records (session -1 = every record);
// frames_skipped from `skipped_frames` (summed over sessions for -1).
DayEvaluation EvaluateDay(const std::vector<FrameRecord>& records, int session,
                          const std::vector<std::string>& stage_names,
                          const std::map<int, std::int64_t>& skipped_frames = {});

// days.csv of a run directory: a header, then one row per session of `records` in order
// of appearance (EvaluateDay with stage_names): session, frames, frames_with_truth,
// unimodal_fraction, position_error_{mean,median,p95,max}_m, heading_error_mean_rad,
// odometry_error_mean_m, views_at_end, map_components_at_end, then `extra_columns`
// (values from extra_values(session), as many as columns), then mean_frame_time_us,
// then the coverage columns frames_localized, frames_unlocalized, coverage (fraction
// 0..1) and frames_skipped (from `skipped_frames`), then the consistency columns:
// nees_xy_{frames,mean,median,p95,in_band}, nees_phi_{frames,mean,median,p95,in_band},
// nis_{frames,mean,median,p95,in_band}, prior_nees_xy_median, fix_nees_xy_median (empty
// where unknown; DayEvaluation). The error columns are over the localized frames with
// ground truth; read them together with coverage.
void WriteDaysCsv(std::ostream& os, const std::vector<FrameRecord>& records,
                  const std::vector<std::string>& stage_names,
                  const std::vector<std::string>& extra_columns = {},
                  const std::function<std::vector<std::string>(int session)>& extra_values = {},
                  const std::map<int, std::int64_t>& skipped_frames = {});

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

// Text table: one line per day (frames, localized frames, coverage %, skipped frames,
// mean/RMSE/median/p95/max position error over the localized frames, heading error,
// odometry-only mean, change of the mean from the previous day), then the run, the
// run's position NEES (consistency of the estimates' covariances) when the frames carry
// covariances, then (with_histogram) the position histogram as counts per bin and day.
std::string FormatEvaluation(const EvaluationResult& result, bool with_histogram = true);

// Per-day consistency table (text and HTML reports): day ("all" for session -1), frames
// with a position NEES, its median / p95 / in-band %, heading NEES median / p95 /
// in-band %, NIS median / in-band % with its frame count, and the medians of the prior's
// and the fix's position NEES ("-" where unknown).
const std::vector<std::string>& ConsistencyPerDayHeader();
std::vector<std::string> ConsistencyPerDayRow(const DayEvaluation& day);

// The two-sided 95 % band of a chi-square variable with `dof` degrees of freedom and the
// fraction of the finite `values` inside it (NaN when none is finite).
double FractionInChiSquareBand(const std::vector<double>& values, int dof);

// Inline SVG of position NEES (2 dof) and heading NEES (1 dof) over the run (one point
// per frame, log scale) against their two-sided 95 % chi-square bands, with the
// moving median over `window` frames.
std::string RenderNeesOverTimeSvg(const std::vector<FrameRecord>& records, int window = 100);

// Inline SVG of the position-error histogram, one series per day (steps when there are
// several days), on the result's common bins.
std::string RenderPositionHistogramSvg(const EvaluationResult& result,
                                       const std::string& title = "Position error histogram");

// The first frame of every session after the first: (global_frame, session), for day
// boundaries on plots over frames.
std::vector<std::pair<std::int64_t, int>> DayStarts(const std::vector<FrameRecord>& records);
// Adds a vertical marker "day N" at the first frame (x = global_frame, or x_offset +
// global_frame) of every session but the first.
void AddDayMarkers(SvgPlot* plot, const std::vector<FrameRecord>& records, double x_offset = 0);

// Self-contained HTML page (tables and inline SVG histograms and error-over-time plot
// with day boundaries); with `metrics`, its APE/RPE table (trajectory_metrics.h) first.
std::string RenderEvaluationHtml(const EvaluationResult& result, const FramesTable& table,
                                 const std::string& title,
                                 const TrajectoryMetrics* metrics = nullptr);

}  // namespace omnicml

#endif  // OMNICML_EVALUATION_EVALUATION_H_
