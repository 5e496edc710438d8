// Tests of the fixed-lag smoother (tracking/fixed_lag_smoother.h): the Rauch-Tung-Striebel
// pass equals the conditional of the joint Gaussian on a chain the tracker's prediction
// linearises, leaves an estimate alone when the later frames add nothing, and never
// widens it.
#include "omnicml/tracking/fixed_lag_smoother.h"

#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "omnicml/common/common.h"
#include "omnicml/tracking/tracker.h"

namespace omnicml {
namespace {

Gaussian MakeGaussian(const Pose2& mean, const Eigen::Matrix3d& cov) {
  Gaussian g;
  g.mean = mean;
  g.covariance = cov;
  return g;
}

Eigen::Matrix3d Spd(double a, double b, double c, double ab) {
  Eigen::Matrix3d m;
  m << a, ab, 0.001, ab, b, 0.002, 0.001, 0.002, c;
  return m;
}

// A Kalman update of the full state by z with covariance r (heading wrapped).
Gaussian KalmanUpdate(const Gaussian& prior, const Pose2& z, const Eigen::Matrix3d& r) {
  const Eigen::Matrix3d k = prior.covariance * (prior.covariance + r).inverse();
  const Eigen::Vector3d d = k * PoseDifference(z, prior.mean);
  Gaussian out;
  out.mean = MakePose(prior.mean.x() + d.x(), prior.mean.y() + d.y(), prior.mean.z() + d.z());
  out.covariance = (Eigen::Matrix3d::Identity() - k) * prior.covariance;
  out.covariance = 0.5 * (out.covariance + out.covariance.transpose()).eval();
  return out;
}

TEST(FixedLagSmoother, ChainOfOneIsTheFilteredEstimate) {
  const Gaussian f = MakeGaussian(MakePose(1, 2, 0.3), Spd(0.2, 0.3, 0.01, 0.05));
  const Gaussian s = SmoothFirstOfChain({f}, {}, MotionNoise{});
  EXPECT_EQ(s.mean, f.mean);
  EXPECT_EQ(s.covariance, f.covariance);
}

// Later estimates that are the predictions themselves carry no information about x_0:
// the smoothed estimate is the filtered one.
TEST(FixedLagSmoother, PredictionsAloneLeaveTheEstimate) {
  const MotionNoise noise;
  std::vector<Gaussian> chain = {MakeGaussian(MakePose(1, 2, 0.3), Spd(0.2, 0.3, 0.01, 0.05))};
  std::vector<OdometryIncrement> u;
  for (int k = 0; k < 6; ++k) {
    u.push_back({0.05 * k, 0.2, -0.02});
    chain.push_back(Propagate({chain.back()}, u.back(), noise).front());
  }
  const Gaussian s = SmoothFirstOfChain(chain, u, noise);
  EXPECT_LT(PoseDifference(s.mean, chain[0].mean).norm(), 1e-12);
  EXPECT_LT((s.covariance - chain[0].covariance).norm(), 1e-12);
}

// One step with a Kalman update of x_1 by a full-state fix: the smoothed x_0 is the
// conditional of x_0 on the fix in the joint Gaussian of the linearised chain,
// m_0 + P_0 G^T S^-1 (z - g(m_0)), P_0 - P_0 G^T S^-1 G P_0, S = G P_0 G^T + V M V^T + R.
// Two steps with the fix at the end: G = G_2 G_1 (the second Jacobian at the predicted
// x_1, which is the filtered x_1 without a fix).
TEST(FixedLagSmoother, EqualsTheConditionalOfTheJointGaussian) {
  const MotionNoise noise{0.02, 0.01, 0.03, 0.01};
  const Gaussian f0 = MakeGaussian(MakePose(0.5, -1.0, 0.4), Spd(0.09, 0.04, 0.02, 0.01));
  const Pose2 z = MakePose(0.75, -0.8, 0.5);
  const Eigen::Matrix3d r = Spd(0.01, 0.02, 0.004, 0.003);
  for (int steps : {1, 2}) {
    std::vector<OdometryIncrement> u = {{0.1, 0.3, -0.05}, {-0.2, 0.25, 0.1}};
    u.resize(static_cast<std::size_t>(steps));
    std::vector<Gaussian> chain = {f0};
    Eigen::Matrix3d g_total = Eigen::Matrix3d::Identity();
    for (int k = 0; k < steps; ++k) {
      g_total = MotionJacobianState(chain.back().mean, u[static_cast<std::size_t>(k)]) * g_total;
      chain.push_back(Propagate({chain.back()}, u[static_cast<std::size_t>(k)], noise).front());
    }
    const Gaussian predicted = chain.back();
    chain.back() = KalmanUpdate(predicted, z, r);
    const Gaussian s = SmoothFirstOfChain(chain, u, noise);

    const Eigen::Matrix3d cross = f0.covariance * g_total.transpose();  // cov(x_0, x_N)
    const Eigen::Matrix3d gain = cross * (predicted.covariance + r).inverse();
    const Eigen::Vector3d d = gain * PoseDifference(z, predicted.mean);
    const Pose2 expected_mean =
        MakePose(f0.mean.x() + d.x(), f0.mean.y() + d.y(), f0.mean.z() + d.z());
    const Eigen::Matrix3d expected_cov = f0.covariance - gain * cross.transpose();
    EXPECT_LT(PoseDifference(s.mean, expected_mean).norm(), 1e-9) << steps << " steps";
    EXPECT_LT((s.covariance - expected_cov).norm(), 1e-9) << steps << " steps";
    // The fix pulled the estimate and narrowed it.
    EXPECT_GT(PoseDifference(s.mean, f0.mean).norm(), 1e-3);
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> shrink(f0.covariance - s.covariance);
    EXPECT_GT(shrink.eigenvalues().minCoeff(), -1e-12);
  }
}

TEST(FixedLagSmoother, RejectsMismatchedSizes) {
  const Gaussian f = MakeGaussian(MakePose(0, 0, 0), Eigen::Matrix3d::Identity());
  EXPECT_THROW(SmoothFirstOfChain({f, f}, {}, MotionNoise{}), Error);
  EXPECT_THROW(SmoothFirstOfChain({}, {}, MotionNoise{}), Error);
}

}  // namespace
}  // namespace omnicml
