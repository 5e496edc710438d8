// Trajectory error figures as evo (github.com/MichaelGrupp/evo) reports them, computed on
// the records of a run (evaluation.h), and the association of a reference trajectory
// whose stamps differ from the run's.
//
// APE (evo_ape, translation part): the position error |est - truth| of every localized
// frame with ground truth, after the run's alignment (evaluation.h Align); the headline
// figure is its root mean square, RMSE = sqrt(mean(e^2)), next to mean, median, standard
// deviation (population, as numpy.std), min and max.
//
// RPE (evo_rpe --delta D --delta_unit m, default pairs): within each session, over the
// localized frames with ground truth in order, the frames at which the path length of
// the ground truth since the previous chosen frame first reaches D metres (the path
// starts counting at the session's first such frame, which is not itself chosen); every
// two consecutive chosen frames (i, j) form a pair. Relative error of a pair:
//   E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)       Q = ground truth, P = estimate, SE(2)
// translation part |E.t| (metres per D metres of path) and rotation part |E.phi| (degrees
// per D metres). Pairs never cross a session (each day the robot may start elsewhere and
// the estimate restarts), so on a multi-day run the figures differ from evo run on the
// run's TUM files, which joins the days; on one session they are evo's.
// Normalised drift: translation RMSE / D (metres per metre, shown in %) and rotation
// RMSE / D (degrees per metre).
//
// Stamp association (evo's associate_trajectories with --t_max_diff): every record takes
// the reference pose whose stamp is nearest to its own (ties: the earlier reference
// pose); when |difference| <= max_time_diff_s the record has that ground truth, otherwise
// it has none (counted among the frames without ground truth, never dropped).
//
// Pure functions; thread-safe.
#ifndef OMNICML_EVALUATION_TRAJECTORY_METRICS_H_
#define OMNICML_EVALUATION_TRAJECTORY_METRICS_H_

#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/map_export.h"

namespace omnicml {

// evo's statistics of one error series (NaN when count is 0).
struct EvoStats {
  int count = 0;
  double rmse = kNaN;
  double mean = kNaN;
  double median = kNaN;
  double std = kNaN;  // population standard deviation (divides by count)
  double min = kNaN;
  double max = kNaN;
};
// Of the finite values (NaN and inf ignored).
EvoStats ComputeEvoStats(const std::vector<double>& values);

struct TrajectoryMetricsOptions {
  // Path length of ground truth between the two frames of an RPE pair, metres, > 0.
  double rpe_delta_m = 1.0;
  // Throws omnicml::Error naming the field when out of range.
  void Validate() const;
};

struct TrajectoryMetrics {
  double rpe_delta_m = 1.0;
  int frames = 0;            // records evaluated (localized or not)
  int frames_evaluated = 0;  // of them, localized with ground truth (APE count)
  EvoStats ape_m;            // position error, metres
  EvoStats ape_heading_deg;  // |heading error|, degrees
  int rpe_pairs = 0;
  EvoStats rpe_translation_m;              // per pair: metres per rpe_delta_m of path
  EvoStats rpe_rotation_deg;               // per pair: degrees per rpe_delta_m of path
  double drift_percent = kNaN;             // 100 * rpe_translation_m.rmse / rpe_delta_m
  double rotation_drift_deg_per_m = kNaN;  // rpe_rotation_deg.rmse / rpe_delta_m
};

// RPE pairs (indices into `positions`) of one sequence by evo's default rule (file
// comment): path lengths accumulated from `positions` (metres).
std::vector<std::pair<std::size_t, std::size_t>> RpePairsByPath(
    const std::vector<Eigen::Vector2d>& positions, double delta_m);

// The figures of the file comment over `records` (already aligned; session -1 = every
// session, otherwise only that session's records).
TrajectoryMetrics ComputeTrajectoryMetrics(const std::vector<FrameRecord>& records,
                                           const TrajectoryMetricsOptions& options,
                                           int session = -1);

// Replaces the ground truth of every record by the reference pose associated by stamp
// (file comment), using run_stamp_s (stamp_s when NaN) as the record's stamp, then
// recomputes errors (the odometry-only error is cleared: its anchor was the old truth).
// Returns the number of records that received ground truth. `reference` need not be
// sorted. max_time_diff_s >= 0 (throws omnicml::Error otherwise).
int AssociateGroundTruth(std::vector<FrameRecord>* records, const std::vector<TimedPose>& reference,
                         double max_time_diff_s);

// Records of a TUM trajectory file read as a run of one session: frame i = line i, the
// pose as the (strongest) estimate, no ground truth.
std::vector<FrameRecord> RecordsFromTum(const std::vector<TimedPose>& estimate);

// Text block: APE RMSE/mean/median/std/min/max, RPE translation and rotation with the
// pair count and the normalised drift, each saying how many frames or pairs it covers.
std::string FormatTrajectoryMetrics(const TrajectoryMetrics& metrics);

// The same as (header, rows) for HTML tables: one row per series (APE position, APE
// heading, RPE translation, RPE rotation) with count, rmse, mean, median, std, min, max.
std::pair<std::vector<std::string>, std::vector<std::vector<std::string>>> TrajectoryMetricsTable(
    const TrajectoryMetrics& metrics);

}  // namespace omnicml

#endif  // OMNICML_EVALUATION_TRAJECTORY_METRICS_H_
