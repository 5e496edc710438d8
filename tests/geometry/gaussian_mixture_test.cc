#include "omnicml/geometry/gaussian_mixture.h"

#include <cmath>
#include <limits>
#include <random>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>
#include <Eigen/QR>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

using ::testing::HasSubstr;

// A random SPD matrix with eigenvalues spread over [1e-3, 1] (m^2 / rad^2).
Eigen::Matrix3d RandomSpd(std::mt19937_64& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  std::uniform_real_distribution<double> log_eig(std::log(1e-3), 0.0);
  Eigen::Matrix3d a;
  for (int i = 0; i < 9; ++i) a(i) = n(rng);
  const Eigen::HouseholderQR<Eigen::Matrix3d> qr(a);
  const Eigen::Matrix3d q = qr.householderQ();
  const Eigen::Vector3d lambda(std::exp(log_eig(rng)), std::exp(log_eig(rng)),
                               std::exp(log_eig(rng)));
  const Eigen::Matrix3d c = q * lambda.asDiagonal() * q.transpose();
  return 0.5 * (c + c.transpose());
}

Pose2 RandomPose(std::mt19937_64& rng, double extent_m = 10.0) {
  std::uniform_real_distribution<double> xy(-extent_m, extent_m);
  std::uniform_real_distribution<double> phi(-kPi, kPi);
  return MakePose(xy(rng), xy(rng), phi(rng));
}

bool IsSymmetricPositiveDefinite(const Eigen::Matrix3d& c) {
  if (!c.allFinite() || (c - c.transpose()).cwiseAbs().maxCoeff() > 1e-12 * c.cwiseAbs().maxCoeff())
    return false;
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(c).eigenvalues().minCoeff() > 0;
}

// The squared Mahalanobis distance wraps the heading difference and is never negative.
TEST(SquaredMahalanobis, WrapsAngleAndIsNonNegative) {
  const Eigen::Matrix3d s = Eigen::Matrix3d::Identity();
  // 3.1 and -3.1 rad are 0.083 rad apart, not 6.2.
  const double d = SquaredMahalanobis(MakePose(0, 0, 3.1), MakePose(0, 0, -3.1), s);
  EXPECT_NEAR(d, std::pow(kTwoPi - 6.2, 2), 1e-12);
  std::mt19937_64 rng(1);
  for (int i = 0; i < 500; ++i) {
    const Pose2 a = RandomPose(rng), b = RandomPose(rng);
    const Eigen::Matrix3d c = RandomSpd(rng);
    const double dab = SquaredMahalanobis(a, b, c);
    EXPECT_GE(dab, 0.0);
    EXPECT_NEAR(dab, SquaredMahalanobis(b, a, c), 1e-9 * (1 + dab));  // symmetric
    EXPECT_EQ(SquaredMahalanobis(a, a, c), 0.0);
  }
}

// A matrix that is not SPD is rejected, not silently used.
TEST(SquaredMahalanobis, ThrowsOnNonSpd) {
  const Eigen::Matrix3d s = Eigen::Vector3d(1.0, -1.0, 1.0).asDiagonal();
  EXPECT_THROW(SquaredMahalanobis(Pose2::Zero(), Pose2::Ones(), s), Error);
  Eigen::Matrix3d nan = Eigen::Matrix3d::Identity();
  nan(1, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(SquaredMahalanobis(Pose2::Zero(), Pose2::Ones(), nan), Error);
}

// NaN/inf entries throw an Error that names the matrix.
TEST(RepairCovariance, NanThrowsNamingWhat) {
  Eigen::Matrix3d c = Eigen::Matrix3d::Identity();
  c(0, 2) = std::numeric_limits<double>::quiet_NaN();
  try {
    RepairCovariance(c, 1e-12, "initial pose covariance");
    FAIL() << "no throw";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("initial pose covariance"));
  }
  c(0, 2) = std::numeric_limits<double>::infinity();
  EXPECT_THROW(RepairCovariance(c), Error);
}

// Rounding-level asymmetry is symmetrised and the matrix otherwise kept.
TEST(RepairCovariance, RepairsSlightAsymmetry) {
  std::mt19937_64 rng(2);
  for (int i = 0; i < 100; ++i) {
    Eigen::Matrix3d c = RandomSpd(rng);
    const Eigen::Matrix3d original = c;
    c(0, 1) += 1e-13;
    c(2, 1) -= 1e-13;
    const Eigen::Matrix3d r = RepairCovariance(c);
    EXPECT_EQ((r - r.transpose()).cwiseAbs().maxCoeff(), 0.0);
    EXPECT_LT((r - original).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_TRUE(IsSymmetricPositiveDefinite(r));
  }
}

// Slightly negative or tiny eigenvalues are clamped up to min_eigenvalue.
TEST(RepairCovariance, ClampsSmallEigenvalues) {
  const Eigen::Matrix3d c = Eigen::Vector3d(1.0, 1e-15, -1e-9).asDiagonal();
  const Eigen::Matrix3d r = RepairCovariance(c, 1e-6);
  const Eigen::Vector3d lambda = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(r).eigenvalues();
  EXPECT_NEAR(lambda(0), 1e-6, 1e-12);
  EXPECT_NEAR(lambda(1), 1e-6, 1e-12);
  EXPECT_NEAR(lambda(2), 1.0, 1e-12);
}

// A clearly negative eigenvalue or a clearly asymmetric matrix throws naming `what`.
TEST(RepairCovariance, RejectsClearlyInvalid) {
  const Eigen::Matrix3d negative = Eigen::Vector3d(1.0, 1.0, -0.01).asDiagonal();
  try {
    RepairCovariance(negative, 1e-12, "C_b");
    FAIL() << "no throw";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("C_b"));
  }
  Eigen::Matrix3d asymmetric = Eigen::Matrix3d::Identity();
  asymmetric(0, 1) = 0.5;
  EXPECT_THROW(RepairCovariance(asymmetric, 1e-12, "C"), Error);
}

// Random SPD matrices pass through unchanged (up to rounding).
TEST(RepairCovariance, KeepsValidMatrices) {
  std::mt19937_64 rng(3);
  for (int i = 0; i < 500; ++i) {
    const Eigen::Matrix3d c = RandomSpd(rng);
    EXPECT_LT((RepairCovariance(c) - c).cwiseAbs().maxCoeff(), 1e-15);
  }
}

// Moment matching a single component returns it unchanged, with its weight.
TEST(MomentMatch, SingleComponentIsIdentity) {
  std::mt19937_64 rng(4);
  for (int i = 0; i < 100; ++i) {
    Gaussian g{RandomPose(rng), RandomSpd(rng), 0.37};
    const Gaussian m = MomentMatch(std::span<const Gaussian>(&g, 1));
    EXPECT_LT(PoseDifference(m.mean, g.mean).norm(), 1e-12);
    EXPECT_LT((m.covariance - g.covariance).norm(), 1e-12);
    EXPECT_DOUBLE_EQ(m.weight, 0.37);
  }
}

// The merge keeps the total weight, its mean lies between the inputs and its covariance
// is SPD and at least the weighted average of the input covariances.
TEST(MomentMatch, PreservesWeightAndIsConsistent) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> w(0.01, 1.0);
  for (int i = 0; i < 300; ++i) {
    const Pose2 base = RandomPose(rng);
    Mixture m;
    double total = 0.0;
    Eigen::Matrix3d avg = Eigen::Matrix3d::Zero();
    for (int k = 0; k < 4; ++k) {
      Gaussian g{MakePose(base.x() + w(rng), base.y() - w(rng), base.z() + 0.5 * w(rng)),
                 RandomSpd(rng), w(rng)};
      total += g.weight;
      m.push_back(g);
    }
    for (const Gaussian& g : m) avg += (g.weight / total) * g.covariance;
    const Gaussian merged = MomentMatch(m);
    EXPECT_NEAR(merged.weight, total, 1e-12);
    EXPECT_TRUE(IsSymmetricPositiveDefinite(merged.covariance));
    const double min_eig =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(merged.covariance - avg).eigenvalues()(0);
    EXPECT_GE(min_eig, -1e-12);
    EXPECT_GE(merged.mean.x(), base.x());
    EXPECT_LE(merged.mean.x(), base.x() + 1.0);
    EXPECT_GE(PoseDifference(merged.mean, base).z(), 0.0);
    EXPECT_LE(PoseDifference(merged.mean, base).z(), 0.5);
  }
}

// Two components either side of +-pi merge to a mean near pi, not near 0, and the
// heading variance reflects their small wrapped spread.
TEST(MomentMatch, MergesAcrossPi) {
  const Eigen::Matrix3d c = Eigen::Vector3d(0.01, 0.01, 0.001).asDiagonal();
  const Mixture m = {{MakePose(1.0, 2.0, kPi - 0.05), c, 0.5},
                     {MakePose(1.0, 2.0, -kPi + 0.05), c, 0.5}};
  const Gaussian merged = MomentMatch(m);
  EXPECT_NEAR(std::abs(merged.mean.z()), kPi, 1e-9);
  EXPECT_NEAR(merged.covariance(2, 2), 0.001 + 0.05 * 0.05, 1e-9);
  // Unequal weights pull towards the heavier side, still near pi.
  const Mixture uneven = {{MakePose(0, 0, kPi - 0.1), c, 0.75},
                          {MakePose(0, 0, -kPi + 0.1), c, 0.25}};
  EXPECT_NEAR(MomentMatch(uneven).mean.z(), kPi - 0.05, 1e-3);
}

// MomentMatch rejects an empty input or weights that sum to zero.
TEST(MomentMatch, RejectsDegenerateInput) {
  EXPECT_THROW(MomentMatch(Mixture{}), Error);
  const Mixture zero = {{Pose2::Zero(), Eigen::Matrix3d::Identity(), 0.0},
                        {Pose2::Ones(), Eigen::Matrix3d::Identity(), 0.0}};
  EXPECT_THROW(MomentMatch(zero), Error);
}

// Weight helpers: total, normalisation to one, strongest index, and the empty cases.
TEST(MixtureWeights, TotalNormalizeStrongest) {
  Mixture m = {{Pose2::Zero(), Eigen::Matrix3d::Identity(), 2.0},
               {Pose2::Ones(), Eigen::Matrix3d::Identity(), 6.0}};
  EXPECT_DOUBLE_EQ(TotalWeight(m), 8.0);
  EXPECT_EQ(StrongestComponent(m), 1);
  NormalizeWeights(&m);
  EXPECT_DOUBLE_EQ(m[0].weight, 0.25);
  EXPECT_DOUBLE_EQ(m[1].weight, 0.75);
  Mixture empty;
  NormalizeWeights(&empty);
  EXPECT_EQ(StrongestComponent(empty), -1);
  Mixture zero = {{Pose2::Zero(), Eigen::Matrix3d::Identity(), 0.0}};
  NormalizeWeights(&zero);
  EXPECT_EQ(zero[0].weight, 0.0);
}

// The closed form agrees with Eigen's eigen-solver on random symmetric 2x2 matrices.
TEST(LargestEigenvalue2, MatchesTheEigenSolver) {
  std::mt19937 rng(12);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (int k = 0; k < 200; ++k) {
    Eigen::Matrix2d m;
    m << n01(rng), n01(rng), 0.0, n01(rng);
    m(1, 0) = m(0, 1);
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> solver(m);
    EXPECT_NEAR(LargestEigenvalue2(m), solver.eigenvalues().maxCoeff(), 1e-12) << m;
  }
  EXPECT_DOUBLE_EQ(LargestEigenvalue2(Eigen::Vector2d(0.04, 0.25).asDiagonal()), 0.25);
}

// The bound holds for every correlation of the pair: the exact covariance of
// s_a e_a + s_b e_b, s_a^2 C_a + s_b^2 C_b + s_a s_b (X + X^T) with the cross-covariance
// X = C_a^(1/2) R C_b^(1/2) for a contraction R (rho times a rotation or reflection;
// rho = 1 is perfect correlation, the worst case), never exceeds it. It is no wider in
// determinant than the convex combination of the covariances.
TEST(LinearCombinationBound, HoldsForEveryCorrelationAndIsNoWiderThanTheConvexCombination) {
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> share(0.02, 0.98), rho(-1.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::Matrix3d ca = RandomSpd(rng), cb = RandomSpd(rng);
    const double sb = share(rng), sa = 1.0 - sb;
    const Eigen::Matrix3d bound = LinearCombinationBound(ca, sa, cb, sb);
    const Eigen::Matrix3d root_a =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(ca).operatorSqrt();
    const Eigen::Matrix3d root_b =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cb).operatorSqrt();
    for (int k = 0; k < 20; ++k) {
      Eigen::Matrix3d g;
      for (int i = 0; i < 9; ++i) g(i / 3, i % 3) = rho(rng);
      const Eigen::Matrix3d q = Eigen::HouseholderQR<Eigen::Matrix3d>(g).householderQ();
      const double r = k == 0 ? 1.0 : std::abs(rho(rng));
      const Eigen::Matrix3d x = root_a * (r * q) * root_b;
      const Eigen::Matrix3d cov = sa * sa * ca + sb * sb * cb + sa * sb * (x + x.transpose());
      const double min_gap =
          Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(bound - cov).eigenvalues().minCoeff();
      EXPECT_GT(min_gap, -1e-9 * bound.norm()) << "trial " << trial << " k " << k;
    }
    const Eigen::Matrix3d convex = sa * ca + sb * cb;
    EXPECT_LE(bound.determinant(), convex.determinant() * (1 + 1e-12)) << trial;
  }
}

// Equal covariances: the bound is that covariance whatever the shares (k = s_b / s_a
// gives (s_a + s_b)^2 C). Proportional ones, sigma_a^2 C and sigma_b^2 C: (s_a sigma_a +
// s_b sigma_b)^2 C, the variance of perfectly correlated errors, below the convex
// combination's s_a sigma_a^2 + s_b sigma_b^2. A zero share leaves the other side, scaled
// by its share squared.
TEST(LinearCombinationBound, EqualProportionalAndZeroShares) {
  std::mt19937_64 rng(3);
  for (int trial = 0; trial < 50; ++trial) {
    const Eigen::Matrix3d c = RandomSpd(rng);
    for (const double sb : {0.01, 0.3, 0.5, 0.9}) {
      const Eigen::Matrix3d bound = LinearCombinationBound(c, 1.0 - sb, c, sb);
      EXPECT_LT((bound - c).norm(), 1e-9 * c.norm()) << trial << " " << sb;
    }
  }
  const Eigen::Matrix3d c = RandomSpd(rng);
  const Eigen::Matrix3d proportional = LinearCombinationBound(c, 0.8, 4.0 * c, 0.2);
  EXPECT_LT((proportional - 1.44 * c).norm(), 1e-9 * c.norm()) << proportional;  // (0.8 + 0.4)^2
  const Eigen::Matrix3d a = Eigen::Vector3d(1, 2, 3).asDiagonal();
  const Eigen::Matrix3d b = Eigen::Vector3d(4, 5, 6).asDiagonal();
  EXPECT_EQ(LinearCombinationBound(a, 1.0, b, 0.0), a);
  EXPECT_EQ(LinearCombinationBound(a, 0.0, b, 0.5), 0.25 * b);
  EXPECT_THROW(LinearCombinationBound(a, 0.0, b, 0.0), Error);
  EXPECT_THROW(LinearCombinationBound(a, -0.1, b, 1.1), Error);
}

}  // namespace
}  // namespace omnicml
