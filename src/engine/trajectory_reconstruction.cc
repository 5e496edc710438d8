#include "omnicml/engine/trajectory_reconstruction.h"

#include <array>
#include <cmath>
#include <memory>

#include <ceres/ceres.h>
#include <ceres/covariance.h>
#include <Eigen/Cholesky>

#include "engine/internal/pose_factors.h"
#include "omnicml/common/common.h"

namespace omnicml {
namespace {

using internal::PriorFactor;
using internal::SqrtInformation;
using OdometryFactor = internal::BetweenFactor;  // between consecutive frames

}  // namespace

void ReconstructionOptions::Validate() const {
  motion.Validate();
  if (!(min_translation_variance_m2 > 0.0) || !std::isfinite(min_translation_variance_m2)) {
    throw Error(StrCat(
        "ReconstructionOptions.min_translation_variance_m2 must be positive and finite, got ",
        min_translation_variance_m2));
  }
  if (!(min_rotation_variance_rad2 > 0.0) || !std::isfinite(min_rotation_variance_rad2)) {
    throw Error(
        StrCat("ReconstructionOptions.min_rotation_variance_rad2 must be positive and finite, got ",
               min_rotation_variance_rad2));
  }
  if (max_iterations < 1) {
    throw Error(StrCat("ReconstructionOptions.max_iterations must be >= 1, got ", max_iterations));
  }
  if (!(function_tolerance > 0.0)) {
    throw Error(StrCat("ReconstructionOptions.function_tolerance must be positive, got ",
                       function_tolerance));
  }
}

Pose2 IncrementToRelativePose(const OdometryIncrement& u) {
  return MakePose(u.trans_m * std::cos(u.rot1_rad), u.trans_m * std::sin(u.rot1_rad),
                  u.rot1_rad + u.rot2_rad);
}

Eigen::Matrix3d IncrementCovariance(const OdometryIncrement& u,
                                    const ReconstructionOptions& options) {
  // J_u = d(trans cos rot1, trans sin rot1, rot1 + rot2) / d(rot1, trans, rot2).
  Eigen::Matrix3d j;
  const double c = std::cos(u.rot1_rad);
  const double s = std::sin(u.rot1_rad);
  j << -u.trans_m * s, c, 0.0,  //
      u.trans_m * c, s, 0.0,    //
      1.0, 0.0, 1.0;
  Eigen::Matrix3d sigma = j * MotionNoiseCovariance(u, options.motion) * j.transpose();
  sigma(0, 0) += options.min_translation_variance_m2;
  sigma(1, 1) += options.min_translation_variance_m2;
  sigma(2, 2) += options.min_rotation_variance_rad2;
  return 0.5 * (sigma + sigma.transpose());
}

ReconstructionResult ReconstructTrajectory(const std::optional<Gaussian>& start,
                                           const std::vector<OdometryIncrement>& increments,
                                           const std::optional<Gaussian>& end,
                                           const ReconstructionOptions& options) {
  options.Validate();
  if (!start && !end) {
    throw Error("ReconstructTrajectory: at least one anchor (start or end) is required");
  }
  if (increments.empty()) {
    throw Error("ReconstructTrajectory: no odometry increments between the anchors");
  }
  const int n = static_cast<int>(increments.size()) + 1;

  // Initial guess: dead reckoning from the start anchor, or backwards from the end one.
  std::vector<std::array<double, 3>> x(n);
  std::vector<Pose2> guess(n);
  if (start) {
    guess[0] = MakePose(start->mean[0], start->mean[1], start->mean[2]);
    for (int i = 1; i < n; ++i)
      guess[i] = Compose(guess[i - 1], IncrementToRelativePose(increments[i - 1]));
  } else {
    guess[n - 1] = MakePose(end->mean[0], end->mean[1], end->mean[2]);
    for (int i = n - 2; i >= 0; --i) {
      const Pose2 rel = IncrementToRelativePose(increments[i]);
      guess[i] = Compose(guess[i + 1], Between(rel, Pose2::Zero()));
    }
  }
  for (int i = 0; i < n; ++i) x[i] = {guess[i][0], guess[i][1], guess[i][2]};

  ceres::Problem::Options problem_options;
  ceres::Problem problem(problem_options);
  for (int i = 0; i < n; ++i) problem.AddParameterBlock(x[i].data(), 3);
  for (int i = 0; i + 1 < n; ++i) {
    const Eigen::Matrix3d w = SqrtInformation(IncrementCovariance(increments[i], options));
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<OdometryFactor, 3, 3, 3>(
                                 new OdometryFactor(IncrementToRelativePose(increments[i]), w)),
                             nullptr, x[i].data(), x[i + 1].data());
  }
  auto add_prior = [&](const Gaussian& g, double* block, const char* what) {
    const Eigen::Matrix3d c = RepairCovariance(g.covariance, 1e-12, what);
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<PriorFactor, 3, 3>(
                                 new PriorFactor(g.mean, SqrtInformation(c))),
                             nullptr, block);
  };
  if (start) add_prior(*start, x[0].data(), "start anchor covariance");
  if (end) add_prior(*end, x[n - 1].data(), "end anchor covariance");

  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = n <= 32 ? ceres::DENSE_QR : ceres::SPARSE_NORMAL_CHOLESKY;
  solver_options.num_threads = 1;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = options.function_tolerance;
  solver_options.gradient_tolerance = 1e-14;
  solver_options.parameter_tolerance = 1e-12;
  solver_options.logging_type = ceres::SILENT;
  solver_options.minimizer_progress_to_stdout = false;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &problem, &summary);

  ReconstructionResult result;
  result.iterations = static_cast<int>(summary.iterations.size());
  result.final_cost = summary.final_cost;
  result.converged = summary.termination_type == ceres::CONVERGENCE;
  result.nodes.resize(n);
  for (int i = 0; i < n; ++i) {
    result.nodes[i].mean = MakePose(x[i][0], x[i][1], x[i][2]);
    result.nodes[i].covariance = Eigen::Matrix3d::Identity();
    result.nodes[i].weight = 1.0;
  }
  if (!options.compute_covariances) return result;

  ceres::Covariance::Options cov_options;
  cov_options.num_threads = 1;
  cov_options.algorithm_type = ceres::SPARSE_QR;
  cov_options.apply_loss_function = false;
  ceres::Covariance covariance(cov_options);
  std::vector<std::pair<const double*, const double*>> blocks;
  blocks.reserve(n);
  for (int i = 0; i < n; ++i) blocks.emplace_back(x[i].data(), x[i].data());
  bool ok = covariance.Compute(blocks, &problem);
  if (!ok) {
    ceres::Covariance::Options dense_options = cov_options;
    dense_options.algorithm_type = ceres::DENSE_SVD;
    ceres::Covariance dense(dense_options);
    ok = dense.Compute(blocks, &problem);
    OMNICML_CHECK(ok) << "pose-graph covariance is rank deficient";
    for (int i = 0; i < n; ++i) {
      double c[9];
      dense.GetCovarianceBlock(x[i].data(), x[i].data(), c);
      result.nodes[i].covariance =
          RepairCovariance(Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(c));
    }
    return result;
  }
  for (int i = 0; i < n; ++i) {
    double c[9];
    covariance.GetCovarianceBlock(x[i].data(), x[i].data(), c);
    result.nodes[i].covariance =
        RepairCovariance(Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(c));
  }
  return result;
}

}  // namespace omnicml
