// How accurate can a map built on dead reckoning become when its lap closes? The accuracy
// that odometry with a given noise model and one loop closure allow on a route, whatever
// the appearance front end (docs/results.md "What one lap closure can correct").
//
// A lap p_0 .. p_T (p_T back at p_0's place) is driven with odometry increments
// u_j = ComputeIncrement(p_j, p_{j+1}) perturbed by the motion model of docs/design.md
// "Motion model": independent zero-mean noise on (rot1, trans, rot2) with variances
// M(u) = diag(a1 rot1^2 + a2 trans^2, a3 trans^2 + a4 (rot1^2 + rot2^2), a1 rot2^2 + a2 trans^2).
//
// Closed form (linearised about the route). To first order the dead-reckoned pose error
// at t is delta_t = sum_{j<t} sum_k a_tjk n_jk with n_jk standard normal and
//   rot1 of step j: a = s1 (-(y_t - y_j), x_t - x_j, 1)          (a turn at p_j swings
//   rot2 of step j: a = s2 (-(y_t - y_j+1), x_t - x_j+1, 1)       everything after it)
//   trans of step j: a = st (cos(phi_j + rot1_j), sin(phi_j + rot1_j), 0)
// so S_ts = E[delta_t delta_s^T] = sum_{j < min(t, s)} sum_k a_tjk a_sjk^T. One exact
// closure of the lap end with its start observes delta_T; conditioning gives
//   C_t|T = S_tt - S_tT (S_TT + R)^-1 S_tT^T                         (Gaussian conditioning)
// with R the closure's covariance. sqrt(tr C_xy) is the position standard deviation a
// perfect smoother (a pose graph at its optimum, no false closures) leaves at t.
//
// Monte Carlo: `samples` realisations of the noisy odometry, each fed to PoseGraph (one
// node per pose at its dead-reckoned pose, a known start, the closure of node T with node
// 0 at p_T's true pose, optimised to convergence): the mean position error over the lap
// before and after, i.e. what the engine's own graph makes of it beyond linearisation.
//
// Thread-compatible; deterministic for the same inputs and seed.
#ifndef OMNICML_EXPERIMENTS_LAP_BOUND_H_
#define OMNICML_EXPERIMENTS_LAP_BOUND_H_

#include <cstdint>
#include <string>
#include <vector>

#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

struct LapBoundOptions {
  // The odometry's noise (sampling and the graph's odometry factors).
  MotionNoise noise;
  // Standard deviations of the closure (position metres, heading radians), >= 0; 0 is an
  // exact closure (the bound).
  double closure_sigma_m = 0.0;
  double closure_sigma_rad = 0.0;
  // Monte Carlo realisations, >= 0 (0: the closed form only), and their seed.
  int samples = 20;
  std::uint64_t seed = 1;
  // Levenberg-Marquardt iterations per realisation, >= 1 (to convergence).
  int max_iterations = 200;

  // Throws omnicml::Error naming the first invalid field ("LapBoundOptions.<field>").
  void Validate() const;
};

// Per pose of the lap, position standard deviations (metres): sqrt(tr C_xy).
struct LapBoundProfile {
  std::vector<double> odometry_std_m;  // dead reckoning alone, S_tt
  std::vector<double> closed_std_m;    // after the closure, C_t|T
};

struct LapBoundSample {
  double odometry_mean_error_m = 0;  // mean over the lap's poses of |dead-reckoned - true|
  double graph_mean_error_m = 0;     // the same after PoseGraph's optimisation
  double odometry_end_error_m = 0;   // at the lap end, before the closure
  // Root mean square over the poses (metres): comparable with the closed form's rms std.
  double odometry_rms_error_m = 0;
  double graph_rms_error_m = 0;
};

struct LapBoundResult {
  int poses = 0;        // T + 1
  double length_m = 0;  // path length of the lap
  LapBoundProfile profile;
  // Summaries of the profile: root mean square over the poses and the largest (metres).
  double odometry_rms_std_m = 0;
  double odometry_end_std_m = 0;
  double closed_rms_std_m = 0;
  double closed_max_std_m = 0;
  std::vector<LapBoundSample> samples;
  // The samples' rms errors pooled over every realisation and pose (metres; 0 without
  // samples): compare with odometry_rms_std_m and closed_rms_std_m.
  double odometry_rms_error_m = 0;
  double graph_rms_error_m = 0;
};

// The closed form and the Monte Carlo for `lap` (p_0 .. p_T, at least 3 poses). Throws
// omnicml::Error on invalid options or a lap with fewer than 3 poses.
LapBoundResult ComputeLapBound(const std::vector<Pose2>& lap, const LapBoundOptions& options);

// The first lap of a trajectory (e.g. a session's ground truth): the poses up to the one
// nearest the start after the trajectory has been farthest from it. Throws omnicml::Error
// naming `what` if the trajectory never comes back within `tolerance_m` of its start.
std::vector<Pose2> ExtractFirstLap(const std::vector<Pose2>& trajectory, double tolerance_m,
                                   const std::string& what);

// The lap of a closed route sampled every step_m from arc length 0 (the simulator's day 1):
// round(length / step_m) + 1 poses, the last at the start again.
std::vector<Pose2> SampleRouteLap(const std::vector<Eigen::Vector2d>& waypoints_m,
                                  double turn_radius_m, double step_m);

// A human-readable summary (the CLI's output).
std::string FormatLapBound(const LapBoundResult& result, const LapBoundOptions& options);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_LAP_BOUND_H_
