// Reconstruction of a multimodal stretch of the trajectory between two unimodal anchors
// [G 2.1, PK] (docs/design.md "Unimodality, reconstruction, delayed update").
//
// While p(x_t) is multimodal the engine cannot tell where the robot is, so those frames
// wait. At the next unimodal estimate their states are recovered from the odometry
// between the two anchors: a 2-D pose graph with one node per frame (anchors included),
// one odometry factor per increment and a prior on each anchor, solved as a
// least-squares problem with Ceres. The covariance of every node comes from the same
// solution (ceres::Covariance: the marginal of the inverse of J^T J at the optimum).
//
// Factors:
//   odometry i -> i+1:  r = W_i (Between(x_i, x_{i+1}) - z_i),  angle wrapped,
//     z_i = the relative pose of increment u_{i+1} = (trans cos rot1, trans sin rot1,
//     rot1 + rot2); its covariance in pose space is J_u M(u) J_u^T with M the motion noise
//     of geometry/motion_model.h (MotionNoiseCovariance) and J_u = dz/du, plus a small floor so
//     that a zero increment still gives an invertible factor; W_i = Sigma_i^{-1/2}.
//   anchor prior:       r = W_a (x_a - mu_a),  angle wrapped, W_a = C_a^{-1/2}.
// Either anchor may be absent (a stretch at the start of a global session has no start
// anchor); at least one is required.
//
// Deterministic: a single-threaded solver with fixed options, so the same input gives
// the same bits on every run and machine build. Pure function; thread-compatible.
#ifndef OMNICML_ENGINE_TRAJECTORY_RECONSTRUCTION_H_
#define OMNICML_ENGINE_TRAJECTORY_RECONSTRUCTION_H_

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

struct ReconstructionOptions {
  // Odometry error model used to weight the factors; normally the tracker's.
  MotionNoise motion;
  // Variance added to every diagonal entry of an odometry factor's covariance
  // (m^2 for x and y, rad^2 for phi) so that a zero increment stays invertible.
  double min_translation_variance_m2 = 1e-6;
  double min_rotation_variance_rad2 = 1e-6;
  // Levenberg-Marquardt iteration limit.
  int max_iterations = 100;
  // Relative function tolerance of the solver (dimensionless).
  double function_tolerance = 1e-12;
  // Whether to compute node covariances (costs one sparse factorisation).
  bool compute_covariances = true;
  void Validate() const;  // throws omnicml::Error naming the field
};

// The options schema (common/options.h). `motion` is not a key: the engine always sets
// it to tracker.motion.
template <class V>
void VisitFields(V& v, ReconstructionOptions& o) {
  v("min_translation_variance_m2", o.min_translation_variance_m2);
  v("min_rotation_variance_rad2", o.min_rotation_variance_rad2);
  v("max_iterations", o.max_iterations);
  v("function_tolerance", o.function_tolerance);
  v("compute_covariances", o.compute_covariances);
}

// The relative pose (frame of the earlier pose) that odometry increment u produces:
// (trans cos rot1, trans sin rot1, wrap(rot1 + rot2)).
Pose2 IncrementToRelativePose(const OdometryIncrement& u);

// Covariance of IncrementToRelativePose(u) in pose space: J_u M(u) J_u^T plus the floors
// of `options` on the diagonal.
Eigen::Matrix3d IncrementCovariance(const OdometryIncrement& u,
                                    const ReconstructionOptions& options);

struct ReconstructionResult {
  // One Gaussian per node, node 0 = start anchor: nodes.size() == increments.size() + 1.
  // Weights are 1; angles wrapped. Covariances are the marginals of the solution when
  // options.compute_covariances is set, otherwise the identity.
  std::vector<Gaussian> nodes;
  int iterations = 0;
  double final_cost = 0.0;
  bool converged = false;
};

// Reconstructs the chain x_0 .. x_n, where increments[i] moves x_i to x_{i+1} (the
// odometry increments the tracker used). `start` is the prior of x_0, `end` the prior of
// x_n; either may be std::nullopt but not both. Covariances must be SPD (they are
// repaired by RepairCovariance; NaN entries throw omnicml::Error). The initial guess is
// dead reckoning from the start anchor (or backwards from the end anchor). Throws
// omnicml::Error when both anchors are missing or the increments are empty.
ReconstructionResult ReconstructTrajectory(const std::optional<Gaussian>& start,
                                           const std::vector<OdometryIncrement>& increments,
                                           const std::optional<Gaussian>& end,
                                           const ReconstructionOptions& options);

}  // namespace omnicml

#endif  // OMNICML_ENGINE_TRAJECTORY_RECONSTRUCTION_H_
