#include "omnicml/engine/trajectory_reconstruction.h"

#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/LU>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// A path of n+1 true poses driven by a sequence of increments from `start`.
std::vector<Pose2> DeadReckon(const Pose2& start, const std::vector<OdometryIncrement>& us) {
  std::vector<Pose2> poses{start};
  for (const OdometryIncrement& u : us)
    poses.push_back(Compose(poses.back(), IncrementToRelativePose(u)));
  return poses;
}

Gaussian Anchor(const Pose2& mean, double sigma_xy_m, double sigma_phi_rad) {
  Gaussian g;
  g.mean = mean;
  g.covariance = Eigen::Vector3d(sigma_xy_m * sigma_xy_m, sigma_xy_m * sigma_xy_m,
                                 sigma_phi_rad * sigma_phi_rad)
                     .asDiagonal();
  return g;
}

std::vector<OdometryIncrement> CurvyIncrements(int n) {
  std::vector<OdometryIncrement> us;
  for (int i = 0; i < n; ++i) us.push_back({0.1 * std::sin(0.3 * i), 0.2 + 0.02 * (i % 3), 0.15});
  return us;
}

// Noiseless odometry between exact anchors reconstructs every pose exactly.
TEST(TrajectoryReconstruction, NoiselessOdometryIsExact) {
  const std::vector<OdometryIncrement> us = CurvyIncrements(25);
  const std::vector<Pose2> truth = DeadReckon(MakePose(1.0, -2.0, 0.4), us);
  ReconstructionOptions options;
  const ReconstructionResult r = ReconstructTrajectory(Anchor(truth.front(), 0.05, 0.02), us,
                                                       Anchor(truth.back(), 0.05, 0.02), options);
  ASSERT_EQ(r.nodes.size(), truth.size());
  for (std::size_t i = 0; i < truth.size(); ++i) {
    const Eigen::Vector3d d = PoseDifference(r.nodes[i].mean, truth[i]);
    EXPECT_LT(d.norm(), 1e-7) << "node " << i;
  }
}

// Headings that cross +-pi are handled by the wrapped angle residuals.
TEST(TrajectoryReconstruction, HeadingAcrossPiIsExact) {
  std::vector<OdometryIncrement> us(30, OdometryIncrement{0.0, 0.1, 0.05});
  const std::vector<Pose2> truth =
      DeadReckon(MakePose(0.0, 0.0, 2.5), us);  // ends near 4 rad -> wraps
  ReconstructionOptions options;
  const ReconstructionResult r = ReconstructTrajectory(Anchor(truth.front(), 0.1, 0.05), us,
                                                       Anchor(truth.back(), 0.1, 0.05), options);
  for (std::size_t i = 0; i < truth.size(); ++i) {
    EXPECT_LT(PoseDifference(r.nodes[i].mean, truth[i]).norm(), 1e-7) << "node " << i;
    EXPECT_LE(std::abs(r.nodes[i].mean[2]), kPi);
  }
}

// With biased odometry the solution spreads the closure error along the chain: it beats
// dead reckoning everywhere, matches both anchors, and is most uncertain mid-way.
TEST(TrajectoryReconstruction, DriftIsDistributedAndCovarianceLargestMidway) {
  const int n = 40;
  std::vector<OdometryIncrement> truth_us(n, OdometryIncrement{0.0, 0.25, 0.02});
  std::vector<OdometryIncrement> odo_us = truth_us;
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.005);
  for (OdometryIncrement& u : odo_us) {
    u.trans_m *= 1.06;  // 6 % scale error
    u.rot2_rad += 0.004 + noise(rng);
  }
  const std::vector<Pose2> truth = DeadReckon(MakePose(2.0, 1.0, -0.3), truth_us);
  const std::vector<Pose2> dead = DeadReckon(truth.front(), odo_us);
  ReconstructionOptions options;
  const ReconstructionResult r = ReconstructTrajectory(Anchor(truth.front(), 0.02, 0.01), odo_us,
                                                       Anchor(truth.back(), 0.02, 0.01), options);
  ASSERT_EQ(static_cast<int>(r.nodes.size()), n + 1);

  // Anchors are held, error is spread: the reconstruction's worst error is well below
  // dead reckoning's.
  EXPECT_LT(PoseDifference(r.nodes.back().mean, truth.back()).head<2>().norm(), 0.1);
  double worst_rec = 0.0, worst_dead = 0.0;
  for (int i = 0; i <= n; ++i) {
    worst_rec = std::max(worst_rec, PoseDifference(r.nodes[i].mean, truth[i]).head<2>().norm());
    worst_dead = std::max(worst_dead, PoseDifference(dead[i], truth[i]).head<2>().norm());
  }
  EXPECT_LT(worst_rec, 0.5 * worst_dead);

  // Positional uncertainty rises towards the middle and falls towards the end anchor.
  auto pos_var = [&](int i) { return r.nodes[i].covariance.topLeftCorner<2, 2>().trace(); };
  int argmax = 0;
  for (int i = 0; i <= n; ++i) {
    if (pos_var(i) > pos_var(argmax)) argmax = i;
  }
  EXPECT_GT(argmax, n / 4);
  EXPECT_LT(argmax, 3 * n / 4);
  EXPECT_GT(pos_var(n / 2), 2.0 * pos_var(1));
  EXPECT_GT(pos_var(n / 2), 2.0 * pos_var(n - 1));
  for (const Gaussian& g : r.nodes) {
    EXPECT_GT(g.covariance.determinant(), 0.0);
    EXPECT_TRUE(g.covariance.isApprox(g.covariance.transpose()));
  }
}

// Only an end anchor: the chain is recovered backwards from it.
TEST(TrajectoryReconstruction, EndAnchorOnly) {
  const std::vector<OdometryIncrement> us = CurvyIncrements(10);
  const std::vector<Pose2> truth = DeadReckon(MakePose(-1.0, 3.0, 3.0), us);
  const ReconstructionResult r = ReconstructTrajectory(
      std::nullopt, us, Anchor(truth.back(), 0.05, 0.02), ReconstructionOptions{});
  for (std::size_t i = 0; i < truth.size(); ++i) {
    EXPECT_LT(PoseDifference(r.nodes[i].mean, truth[i]).norm(), 1e-7) << "node " << i;
  }
  // Uncertainty grows away from the only anchor.
  EXPECT_GT(r.nodes.front().covariance.trace(), r.nodes.back().covariance.trace());
}

// Same input, same bits.
TEST(TrajectoryReconstruction, Deterministic) {
  std::vector<OdometryIncrement> us = CurvyIncrements(50);
  for (OdometryIncrement& u : us) u.trans_m *= 1.03;
  const std::vector<Pose2> truth = DeadReckon(MakePose(0.0, 0.0, 0.0), CurvyIncrements(50));
  const auto run = [&] {
    return ReconstructTrajectory(Anchor(truth.front(), 0.03, 0.01), us,
                                 Anchor(truth.back(), 0.03, 0.01), ReconstructionOptions{});
  };
  const ReconstructionResult a = run();
  const ReconstructionResult b = run();
  for (std::size_t i = 0; i < a.nodes.size(); ++i) {
    EXPECT_EQ(a.nodes[i].mean, b.nodes[i].mean);
    EXPECT_EQ(a.nodes[i].covariance, b.nodes[i].covariance);
  }
}

// Bad input is reported as omnicml::Error.
TEST(TrajectoryReconstruction, RejectsMissingAnchorsAndEmptyChain) {
  const std::vector<OdometryIncrement> us = CurvyIncrements(3);
  EXPECT_THROW(ReconstructTrajectory(std::nullopt, us, std::nullopt, ReconstructionOptions{}),
               Error);
  EXPECT_THROW(ReconstructTrajectory(Anchor(Pose2::Zero(), 0.1, 0.1), {}, std::nullopt,
                                     ReconstructionOptions{}),
               Error);
  ReconstructionOptions bad;
  bad.max_iterations = 0;
  EXPECT_THROW(bad.Validate(), Error);
}

// The pose-space covariance of an increment is the motion noise mapped through J_u.
TEST(TrajectoryReconstruction, IncrementCovarianceMatchesNumericJacobian) {
  const OdometryIncrement u{0.3, 0.8, -0.2};
  ReconstructionOptions options;
  const Eigen::Matrix3d sigma = IncrementCovariance(u, options);
  Eigen::Matrix3d j;
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    OdometryIncrement up = u, dn = u;
    double* pu[3] = {&up.rot1_rad, &up.trans_m, &up.rot2_rad};
    double* pd[3] = {&dn.rot1_rad, &dn.trans_m, &dn.rot2_rad};
    *pu[k] += h;
    *pd[k] -= h;
    j.col(k) = PoseDifference(IncrementToRelativePose(up), IncrementToRelativePose(dn)) / (2 * h);
  }
  Eigen::Matrix3d expected = j * MotionNoiseCovariance(u, options.motion) * j.transpose();
  expected.diagonal() +=
      Eigen::Vector3d(options.min_translation_variance_m2, options.min_translation_variance_m2,
                      options.min_rotation_variance_rad2);
  EXPECT_TRUE(sigma.isApprox(expected, 1e-6)) << sigma << "\nvs\n" << expected;
}

}  // namespace
}  // namespace omnicml
