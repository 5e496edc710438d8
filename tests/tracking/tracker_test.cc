#include "omnicml/tracking/tracker.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/QR>

#include "omnicml/common/common.h"
#include "omnicml/tracking/motion_noise_identification.h"

namespace omnicml {
namespace {

using ::testing::HasSubstr;

Eigen::Matrix3d RandomSpd(std::mt19937_64& rng, double min_eig = 1e-3, double max_eig = 1.0) {
  std::normal_distribution<double> n(0.0, 1.0);
  std::uniform_real_distribution<double> log_eig(std::log(min_eig), std::log(max_eig));
  Eigen::Matrix3d a;
  for (int i = 0; i < 9; ++i) a(i) = n(rng);
  const Eigen::Matrix3d q = Eigen::HouseholderQR<Eigen::Matrix3d>(a).householderQ();
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

Mixture RandomMixture(std::mt19937_64& rng, int n, double extent_m) {
  std::uniform_real_distribution<double> w(0.05, 1.0);
  Mixture m;
  for (int i = 0; i < n; ++i)
    m.push_back({RandomPose(rng, extent_m), RandomSpd(rng, 1e-2, 1.0), w(rng)});
  return m;
}

bool IsSymmetricPositiveDefinite(const Eigen::Matrix3d& c) {
  if (!c.allFinite() || (c - c.transpose()).cwiseAbs().maxCoeff() > 1e-12 * c.cwiseAbs().maxCoeff())
    return false;
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(c).eigenvalues().minCoeff() > 0;
}

// Invariants of every cleaned-up state mixture: non-empty, weights sum to one and each at
// least w_min, at most max_components, SPD covariances, wrapped headings.
void ExpectValidState(const Mixture& m, const TrackerOptions& options) {
  ASSERT_FALSE(m.empty());
  EXPECT_NEAR(TotalWeight(m), 1.0, 1e-12);
  EXPECT_LE(static_cast<int>(m.size()), options.max_components);
  for (const Gaussian& g : m) {
    EXPECT_GE(g.weight, options.w_min);
    EXPECT_TRUE(IsSymmetricPositiveDefinite(g.covariance)) << g.covariance;
    EXPECT_GT(g.mean.z(), -kPi);
    EXPECT_LE(g.mean.z(), kPi);
  }
}

Eigen::Matrix3d Diag(double a, double b, double c) { return Eigen::Vector3d(a, b, c).asDiagonal(); }

// ---------------------------------------------------------------- options

// The defaults are valid; every invalid field is named in the error.
TEST(TrackerOptions, ValidateNamesTheField) {
  EXPECT_NO_THROW(TrackerOptions{}.Validate());
  EXPECT_NO_THROW(MotionNoise{}.Validate());
  auto expect_field = [](TrackerOptions o, const char* field) {
    try {
      o.Validate();
      ADD_FAILURE() << "no throw for " << field;
    } catch (const Error& e) {
      EXPECT_THAT(e.what(), HasSubstr(field));
    }
  };
  TrackerOptions o;
  o.gamma = 0;
  expect_field(o, "gamma");
  o = {};
  o.gamma = std::numeric_limits<double>::infinity();
  expect_field(o, "gamma");
  o = {};
  o.w_min = 1.0;
  expect_field(o, "w_min");
  o = {};
  o.w_min = std::numeric_limits<double>::quiet_NaN();
  expect_field(o, "w_min");
  o = {};
  o.delta = -1;
  expect_field(o, "delta");
  o = {};
  o.max_components = 0;
  expect_field(o, "max_components");
  o = {};
  o.unimodal_min_weight = 1.5;
  expect_field(o, "unimodal_min_weight");
  o = {};
  o.min_covariance_eigenvalue = 0;
  expect_field(o, "min_covariance_eigenvalue");
  o = {};
  o.motion.a3 = -0.1;
  expect_field(o, "motion.a3");
  MotionNoise n;
  n.a2 = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(n.Validate(), Error);
  EXPECT_THROW(MixtureTracker{o}, Error);
}

// ---------------------------------------------------------------- motion model

// The analytic Jacobians G and V match central differences at random poses/increments.
TEST(MotionModel, AnalyticJacobiansMatchNumeric) {
  std::mt19937_64 rng(10);
  std::uniform_real_distribution<double> rot(-kPi / 2, kPi / 2), trans(-2.0, 2.0);
  const double h = 1e-6;
  for (int trial = 0; trial < 200; ++trial) {
    const Pose2 mu = RandomPose(rng);
    const OdometryIncrement u{rot(rng), trans(rng), rot(rng)};
    Eigen::Matrix3d g_num, v_num;
    for (int k = 0; k < 3; ++k) {
      Pose2 plus = mu, minus = mu;
      plus(k) += h;
      minus(k) -= h;
      g_num.col(k) = PoseDifference(ApplyIncrement(plus, u), ApplyIncrement(minus, u)) / (2 * h);
      OdometryIncrement up = u, um = u;
      double* fields_p[3] = {&up.rot1_rad, &up.trans_m, &up.rot2_rad};
      double* fields_m[3] = {&um.rot1_rad, &um.trans_m, &um.rot2_rad};
      *fields_p[k] += h;
      *fields_m[k] -= h;
      v_num.col(k) = PoseDifference(ApplyIncrement(mu, up), ApplyIncrement(mu, um)) / (2 * h);
    }
    EXPECT_LT((MotionJacobianState(mu, u) - g_num).cwiseAbs().maxCoeff(), 1e-7)
        << "trial " << trial;
    EXPECT_LT((MotionJacobianControl(mu, u) - v_num).cwiseAbs().maxCoeff(), 1e-7)
        << "trial " << trial;
  }
}

// M follows the a1..a4 model of docs/design.md "Motion model".
TEST(MotionModel, NoiseCovarianceFollowsModel) {
  const MotionNoise n{0.1, 0.2, 0.3, 0.4};
  const OdometryIncrement u{0.5, 2.0, -0.25};
  const Eigen::Matrix3d m = MotionNoiseCovariance(u, n);
  EXPECT_NEAR(m(0, 0), 0.1 * 0.25 + 0.2 * 4.0, 1e-15);
  EXPECT_NEAR(m(1, 1), 0.3 * 4.0 + 0.4 * (0.25 + 0.0625), 1e-15);
  EXPECT_NEAR(m(2, 2), 0.1 * 0.0625 + 0.2 * 4.0, 1e-15);
  EXPECT_EQ(m(0, 1), 0.0);
  EXPECT_EQ(m(1, 2), 0.0);
}

// Driving a closed square returns every component to its start, with weights unchanged
// and the covariance grown (trace, determinant and the position variances).
TEST(MotionModel, ClosedSquareReturnsToStartWithGrownCovariance) {
  const Eigen::Matrix3d c0 = Diag(1e-4, 2e-4, 1e-5);
  const Mixture start = {{MakePose(1.0, 2.0, 0.3), c0, 0.7},
                         {MakePose(-4.0, 0.5, kPi - 0.01), c0, 0.3}};
  Mixture m = start;
  const OdometryIncrement side{0.0, 2.0, kPi / 2};
  for (int i = 0; i < 4; ++i) m = Propagate(m, side, MotionNoise{});
  ASSERT_EQ(m.size(), start.size());
  for (std::size_t k = 0; k < m.size(); ++k) {
    EXPECT_LT(PoseDifference(m[k].mean, start[k].mean).norm(), 1e-9);
    EXPECT_EQ(m[k].weight, start[k].weight);
    EXPECT_TRUE(IsSymmetricPositiveDefinite(m[k].covariance));
    EXPECT_GT(m[k].covariance.trace(), 10 * c0.trace());
    EXPECT_GT(m[k].covariance.determinant(), c0.determinant());
    EXPECT_GT(m[k].covariance(0, 0), c0(0, 0));
    EXPECT_GT(m[k].covariance(1, 1), c0(1, 1));
    EXPECT_GT(m[k].covariance(2, 2), c0(2, 2));
  }
}

// Without motion (and so without noise) nothing changes; NaN covariances are rejected.
TEST(MotionModel, ZeroIncrementAndInvalidInput) {
  std::mt19937_64 rng(11);
  const Mixture m = RandomMixture(rng, 5, 5.0);
  const Mixture p = Propagate(m, OdometryIncrement{}, MotionNoise{});
  for (std::size_t k = 0; k < m.size(); ++k) {
    EXPECT_LT(PoseDifference(p[k].mean, m[k].mean).norm(), 1e-15);
    EXPECT_LT((p[k].covariance - m[k].covariance).cwiseAbs().maxCoeff(), 1e-15);
  }
  Mixture bad = m;
  bad[2].covariance(1, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(Propagate(bad, OdometryIncrement{0.1, 1.0, 0.0}, MotionNoise{}), Error);
  EXPECT_THROW(Propagate(m, OdometryIncrement{0.1, std::numeric_limits<double>::infinity(), 0.0},
                         MotionNoise{}),
               Error);
}

// ---------------------------------------------------------------- covariance intersection

// On random SPD pairs: alpha follows (5), C is symmetric PD, C^-1 equals the alpha-weighted
// sum of the inverses (3) and the mean satisfies (4).
TEST(CovarianceIntersection, InformationFormOnRandomSpd) {
  std::mt19937_64 rng(20);
  std::uniform_real_distribution<double> w(0.01, 1.0), small(-0.5, 0.5);
  for (int trial = 0; trial < 500; ++trial) {
    Gaussian a{RandomPose(rng), RandomSpd(rng), w(rng)};
    Gaussian b{MakePose(a.mean.x() + small(rng), a.mean.y() + small(rng), a.mean.z() + small(rng)),
               RandomSpd(rng), w(rng)};
    const double alpha = CovarianceIntersectionAlpha(a, b);
    const double det_a = a.covariance.determinant(), det_b = b.covariance.determinant();
    EXPECT_NEAR(alpha, b.weight * det_a / (b.weight * det_a + a.weight * det_b), 1e-12);  // (5)
    ASSERT_GE(alpha, 0.0);
    ASSERT_LE(alpha, 1.0);
    const Gaussian f = CovarianceIntersection(a, b, alpha);
    EXPECT_TRUE(IsSymmetricPositiveDefinite(f.covariance));
    const Eigen::Matrix3d info =
        (1 - alpha) * a.covariance.inverse() + alpha * b.covariance.inverse();
    EXPECT_LT((f.covariance.inverse() - info).norm(), 1e-8 * info.norm());  // (3)
    const Pose2 mu_b = a.mean + PoseDifference(b.mean, a.mean);  // unwrapped next to mu_a
    const Eigen::Vector3d rhs =
        (1 - alpha) * a.covariance.inverse() * a.mean + alpha * b.covariance.inverse() * mu_b;
    const Eigen::Vector3d lhs = info * (a.mean + PoseDifference(f.mean, a.mean));
    EXPECT_LT((lhs - rhs).norm(), 1e-7 * (1 + rhs.norm()));  // (4)
    EXPECT_EQ(f.weight, 0.0);
  }
}

// alpha = 0 returns a, alpha = 1 returns b; equal covariances give alpha = w_b / (w_a + w_b)
// and a larger w_b gives a larger alpha.
TEST(CovarianceIntersection, AlphaFollowsWeights) {
  const Gaussian a{MakePose(0, 0, 0), Diag(0.2, 0.3, 0.05), 0.25};
  Gaussian b{MakePose(0.5, -0.2, 0.1), Diag(0.2, 0.3, 0.05), 0.75};
  EXPECT_NEAR(CovarianceIntersectionAlpha(a, b), 0.75, 1e-12);
  double previous = 0.0;
  for (double wb : {0.1, 0.5, 1.0, 5.0}) {
    b.weight = wb;
    const double alpha = CovarianceIntersectionAlpha(a, b);
    EXPECT_GT(alpha, previous);
    previous = alpha;
  }
  EXPECT_LT(PoseDifference(CovarianceIntersection(a, b, 0.0).mean, a.mean).norm(), 1e-12);
  EXPECT_LT(PoseDifference(CovarianceIntersection(a, b, 1.0).mean, b.mean).norm(), 1e-12);
  EXPECT_THROW(CovarianceIntersection(a, b, 1.5), Error);
}

// A far more certain b dominates: the result sits at b with b's covariance.
TEST(CovarianceIntersection, FarMoreCertainBDominates) {
  const Gaussian a{MakePose(0, 0, 0), Diag(1.0, 1.0, 0.5), 0.5};
  const Gaussian b{MakePose(0.8, -0.6, 0.4), Diag(1e-4, 1e-4, 1e-5), 0.5};
  const double alpha = CovarianceIntersectionAlpha(a, b);
  EXPECT_GT(alpha, 1.0 - 1e-9);
  const Gaussian f = CovarianceIntersection(a, b, alpha);
  EXPECT_LT(PoseDifference(f.mean, b.mean).norm(), 1e-6);
  EXPECT_LT((f.covariance - b.covariance).cwiseAbs().maxCoeff(), 1e-8);
}

// Headings either side of +-pi fuse to a heading near pi, not 0.
TEST(CovarianceIntersection, AcrossPi) {
  const Gaussian a{MakePose(0, 0, kPi - 0.05), Diag(0.1, 0.1, 0.01), 0.5};
  const Gaussian b{MakePose(0, 0, -kPi + 0.05), Diag(0.1, 0.1, 0.01), 0.5};
  const Gaussian f = CovarianceIntersection(a, b, CovarianceIntersectionAlpha(a, b));
  EXPECT_NEAR(std::abs(f.mean.z()), kPi, 1e-9);
}

// ---------------------------------------------------------------- fusion (2)-(8)

// The configuration of [G] Fig. 2: a1 in p(x|u) has two counterparts b1, b2 in p(x|y);
// a2 and b3 have none and are copied. Weights of (8) computed by hand:
//   hat_w_a1 = w_b1 + w_b2 = 0.8; hat_w_b1 = hat_w_b2 = w_a1 = 0.6 (6)-(7)
//   w(a1,b1) = 0.6*0.5/0.8 + 0.5*0.6/0.6 = 0.375 + 0.5 = 0.875
//   w(a1,b2) = 0.6*0.3/0.8 + 0.3*0.6/0.6 = 0.225 + 0.3 = 0.525
TEST(Fusion, WeightsOfFigure2) {
  const Eigen::Matrix3d c = Diag(0.01, 0.01, 0.01);
  const Gaussian a1{MakePose(0, 0, 0), c, 0.6}, a2{MakePose(10, 0, 0), c, 0.4};
  const Gaussian b1{MakePose(0.3, 0, 0), c, 0.5}, b2{MakePose(-0.3, 0, 0), c, 0.3},
      b3{MakePose(20, 0, 0), c, 0.2};
  TrackerOptions
      options;  // [G]'s 99 % gate 11.34: a1-b1 and a1-b2 at 0.3^2 / 0.02 = 4.5 are gated in
  options.gamma = 11.34;
  const Mixture out = FuseOnce({a1, a2}, {b1, b2, b3}, options);
  ASSERT_EQ(out.size(), 4u);
  // Order: a1's pairs, a2 copied, then the unmatched b3.
  EXPECT_NEAR(out[0].weight, 0.875, 1e-12);
  EXPECT_NEAR(out[1].weight, 0.525, 1e-12);
  EXPECT_DOUBLE_EQ(out[2].weight, 0.4);
  EXPECT_DOUBLE_EQ(out[3].weight, 0.2);
  const Gaussian f11 = CovarianceIntersection(a1, b1, CovarianceIntersectionAlpha(a1, b1));
  EXPECT_LT(PoseDifference(out[0].mean, f11.mean).norm(), 1e-12);
  EXPECT_LT((out[0].covariance - f11.covariance).norm(), 1e-12);
  EXPECT_NEAR(out[0].mean.x(), 0.3 * 0.5 / (0.5 + 0.6),
              1e-12);               // equal C: alpha = w_b / (w_a + w_b)
  EXPECT_EQ(out[2].mean, a2.mean);  // copied unchanged
  EXPECT_EQ(out[3].mean, b3.mean);
  EXPECT_EQ(out[3].covariance, b3.covariance);
  // After normalisation (total 2.0): 0.4375, 0.2625, 0.2, 0.1.
  const Mixture fused = Fuse({a1, a2}, {{b1, b2, b3}}, [&] {
    TrackerOptions o = options;
    o.delta = 0.0;  // no merging, to see the raw weights
    return o;
  }());
  ASSERT_EQ(fused.size(), 4u);
  EXPECT_NEAR(fused[0].weight, 0.4375, 1e-12);
  EXPECT_NEAR(fused[1].weight, 0.2625, 1e-12);
  EXPECT_NEAR(fused[2].weight, 0.2, 1e-12);
  EXPECT_NEAR(fused[3].weight, 0.1, 1e-12);
}

// The mirror case: b1 with two counterparts a1, a2 shares its weight by (7).
TEST(Fusion, WeightsOfOneBWithTwoCounterparts) {
  const Eigen::Matrix3d c = Diag(0.01, 0.01, 0.01);
  const Gaussian a1{MakePose(0.3, 0, 0), c, 0.2}, a2{MakePose(-0.3, 0, 0), c, 0.6};
  const Gaussian b1{MakePose(0, 0, 0), c, 1.0};
  TrackerOptions options;
  options.gamma = 11.34;  // both pairs at 0.3^2 / 0.02 = 4.5 are gated in
  const Mixture out = FuseOnce({a1, a2}, {b1}, options);
  ASSERT_EQ(out.size(), 2u);
  // hat_w_a1 = hat_w_a2 = 1.0; hat_w_b1 = 0.8.
  EXPECT_NEAR(out[0].weight, 0.2 * 1.0 / 1.0 + 1.0 * 0.2 / 0.8, 1e-12);
  EXPECT_NEAR(out[1].weight, 0.6 * 1.0 / 1.0 + 1.0 * 0.6 / 0.8, 1e-12);
}

// (8) shares each side's weight among its counterparts, so a single fusion keeps the
// total weight of both sides; every output covariance is SPD (random, seeded).
TEST(Fusion, FuseOnceKeepsTotalWeight) {
  std::mt19937_64 rng(30);
  for (int trial = 0; trial < 50; ++trial) {
    const Mixture a = RandomMixture(rng, 1 + trial % 7, 2.0);
    const Mixture b = RandomMixture(rng, 1 + trial % 5, 2.0);
    const Mixture out = FuseOnce(a, b, TrackerOptions{});
    EXPECT_NEAR(TotalWeight(out), TotalWeight(a) + TotalWeight(b), 1e-12);
    for (const Gaussian& g : out) EXPECT_TRUE(IsSymmetricPositiveDefinite(g.covariance));
  }
}

// FusionRule::kIndependent fuses a gated pair by the information-filter update,
// C = (C_a^-1 + C_b^-1)^-1 and mu = C (C_a^-1 mu_a + C_b^-1 mu_b), narrower than both
// inputs; covariance intersection of two equal covariances keeps that covariance.
TEST(Fusion, IndependentRuleIsTheKalmanUpdate) {
  std::mt19937_64 rng(41);
  TrackerOptions independent;
  independent.fusion = FusionRule::kIndependent;
  independent.gamma = 1e6;  // every pair gated
  for (int trial = 0; trial < 20; ++trial) {
    const Gaussian a{MakePose(1.0, 2.0, 0.3), RandomSpd(rng, 1e-2, 1.0), 1.0};
    const Gaussian b{MakePose(1.4, 1.7, 0.5), RandomSpd(rng, 1e-2, 1.0), 1.0};
    const Mixture out = FuseOnce({a}, {b}, independent);
    ASSERT_EQ(out.size(), 1u);
    const Eigen::Matrix3d c = (a.covariance.inverse() + b.covariance.inverse()).inverse();
    EXPECT_TRUE(out[0].covariance.isApprox(c, 1e-9));
    const Pose2 mu = c * (a.covariance.inverse() * a.mean + b.covariance.inverse() * b.mean);
    EXPECT_NEAR((out[0].mean - mu).norm(), 0.0, 1e-9);
    // Narrower than either input: C_a - C and C_b - C are positive semi-definite.
    EXPECT_GT((a.covariance - out[0].covariance).eigenvalues().real().minCoeff(), -1e-12);
    EXPECT_GT((b.covariance - out[0].covariance).eigenvalues().real().minCoeff(), -1e-12);
  }
  const Gaussian a{MakePose(0, 0, 0), Eigen::Matrix3d::Identity() * 0.04, 1.0};
  const Gaussian b{MakePose(0.1, 0, 0), Eigen::Matrix3d::Identity() * 0.04, 1.0};
  TrackerOptions ci;
  ci.gamma = 1e6;
  EXPECT_TRUE(FuseOnce({a}, {b}, ci)[0].covariance.isApprox(a.covariance, 1e-12));
  EXPECT_TRUE(FuseOnce({a}, {b}, independent)[0].covariance.isApprox(0.5 * a.covariance, 1e-12));
}

// Several sources are fused one after the other before a single final clean-up, and the
// result is a valid state mixture.
TEST(Fusion, SeveralSourcesBeforeNormalisation) {
  std::mt19937_64 rng(31);
  const TrackerOptions options;
  for (int trial = 0; trial < 20; ++trial) {
    Mixture p = RandomMixture(rng, 6, 3.0);
    NormalizeWeights(&p);
    const Mixture s1 = RandomMixture(rng, 4, 3.0), s2 = RandomMixture(rng, 3, 3.0);
    const Mixture fused = Fuse(p, {s1, Mixture{}, s2}, options);
    const Mixture expected = Simplify(FuseOnce(FuseOnce(p, s1, options), s2, options), options);
    ASSERT_EQ(fused.size(), expected.size());
    for (std::size_t k = 0; k < fused.size(); ++k) {
      EXPECT_DOUBLE_EQ(fused[k].weight, expected[k].weight);
      EXPECT_EQ(fused[k].mean, expected[k].mean);
    }
    ExpectValidState(fused, options);
  }
}

// With no (or only empty) sources the result is the cleaned-up p(x|u).
TEST(Fusion, EmptySourcesGivePxu) {
  std::mt19937_64 rng(32);
  Mixture p = RandomMixture(rng, 5, 10.0);
  const TrackerOptions options;
  const Mixture expected = Simplify(p, options);
  for (const auto& sources : {std::vector<Mixture>{}, std::vector<Mixture>{Mixture{}, Mixture{}}}) {
    const Mixture fused = Fuse(p, sources, options);
    ASSERT_EQ(fused.size(), expected.size());
    for (std::size_t k = 0; k < fused.size(); ++k) EXPECT_EQ(fused[k].mean, expected[k].mean);
  }
}

// A NaN in a source's covariance or weight is rejected with an Error naming the side.
TEST(Fusion, RejectsInvalidSources) {
  const Mixture p = {{Pose2::Zero(), Eigen::Matrix3d::Identity(), 1.0}};
  Mixture bad = p;
  bad[0].covariance(0, 0) = std::numeric_limits<double>::quiet_NaN();
  try {
    Fuse(p, {bad}, TrackerOptions{});
    FAIL() << "no throw";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("b_side[0]"));
  }
  bad = p;
  bad[0].weight = -1.0;
  EXPECT_THROW(Fuse(p, {bad}, TrackerOptions{}), Error);
}

// Random fusions of many components always leave a valid state mixture.
TEST(Fusion, RandomFusionsStayValid) {
  std::mt19937_64 rng(33);
  TrackerOptions options;
  options.max_components = 10;
  for (int trial = 0; trial < 30; ++trial) {
    Mixture p = RandomMixture(rng, 20, 4.0);
    NormalizeWeights(&p);
    const Mixture fused = Fuse(p, {RandomMixture(rng, 20, 4.0)}, options);
    ExpectValidState(fused, options);
  }
}

// ---------------------------------------------------------------- simplification

// Simplify normalises, prunes below w_min, merges close components (also across +-pi)
// and caps by weight.
TEST(Simplify, PruneMergeCap) {
  TrackerOptions options;
  options.w_min = 0.05;
  const Eigen::Matrix3d c = Diag(0.04, 0.04, 0.01);
  const Mixture m = {
      {MakePose(0, 0, kPi - 0.02), c, 4.0},  // merges with the next (across +-pi)
      {MakePose(0.05, 0, -kPi + 0.02), c, 4.0},
      {MakePose(5, 0, 0), c, 1.5},
      {MakePose(-5, 0, 0), c, 0.6},
      {MakePose(9, 9, 0), c, 0.2},  // 0.2 / 10.3 < w_min: pruned
  };
  const Mixture s = Simplify(m, options);
  ASSERT_EQ(s.size(), 3u);
  EXPECT_NEAR(TotalWeight(s), 1.0, 1e-12);
  EXPECT_NEAR(s[0].weight, 8.0 / 10.1, 1e-12);
  EXPECT_NEAR(std::abs(s[0].mean.z()), kPi, 1e-9);
  EXPECT_NEAR(s[0].mean.x(), 0.025, 1e-12);
  EXPECT_NEAR(s[1].weight, 1.5 / 10.1, 1e-12);
  EXPECT_NEAR(s[2].weight, 0.6 / 10.1, 1e-12);

  options.max_components = 2;
  const Mixture capped = Simplify(m, options);
  ASSERT_EQ(capped.size(), 2u);
  EXPECT_NEAR(capped[0].weight, 8.0 / 9.5, 1e-12);
  EXPECT_NEAR(capped[1].weight, 1.5 / 9.5, 1e-12);
  ExpectValidState(capped, options);
}

// If pruning would empty the mixture, the strongest component is kept; an all-zero
// weight vector counts as uniform; an empty mixture stays empty.
TEST(Simplify, NeverEmptiesANonEmptyMixture) {
  TrackerOptions options;
  options.w_min = 0.5;
  options.delta = 0.0;
  const Eigen::Matrix3d c = Diag(0.01, 0.01, 0.01);
  const Mixture m = {
      {MakePose(0, 0, 0), c, 0.3}, {MakePose(5, 0, 0), c, 0.35}, {MakePose(-5, 0, 0), c, 0.35}};
  const Mixture s = Simplify(m, options);
  ASSERT_EQ(s.size(), 1u);
  EXPECT_EQ(s[0].mean, m[1].mean);
  EXPECT_DOUBLE_EQ(s[0].weight, 1.0);
  options.w_min = 0.1;
  Mixture zero = m;
  for (Gaussian& g : zero) g.weight = 0.0;
  const Mixture z = Simplify(zero, options);
  ASSERT_EQ(z.size(), 3u);
  for (const Gaussian& g : z) EXPECT_NEAR(g.weight, 1.0 / 3.0, 1e-12);
  EXPECT_TRUE(Simplify(Mixture{}, options).empty());
}

// ---------------------------------------------------------------- unimodality, summary

// Unimodal iff all components of non-negligible weight lie within gamma of the strongest.
TEST(Summary, UnimodalityAndEstimate) {
  const TrackerOptions options;
  const Eigen::Matrix3d c = Diag(0.04, 0.04, 0.01);
  Mixture m = {
      {MakePose(0, 0, 0), c, 0.6}, {MakePose(0.2, 0, 0.05), c, 0.3}, {MakePose(6, 0, 0), c, 0.1}};
  EXPECT_FALSE(IsUnimodal(m, options));  // the far one has weight 0.1 >= 0.05
  m[2].weight = 0.01;
  EXPECT_TRUE(IsUnimodal(m, options));  // now negligible
  EXPECT_FALSE(IsUnimodal(Mixture{}, options));

  const Estimate e = Summarize(m, options);
  EXPECT_TRUE(e.unimodal);
  EXPECT_EQ(e.num_components, 3);
  EXPECT_EQ(e.strongest.mean, m[0].mean);
  EXPECT_NEAR(e.strongest.weight, 0.6 / 0.91, 1e-12);
  EXPECT_NEAR(e.mean.weight, 1.0, 1e-12);
  EXPECT_NEAR(e.mean.mean.x(), (0.3 * 0.2 + 0.01 * 6) / 0.91, 1e-12);
  EXPECT_TRUE(IsSymmetricPositiveDefinite(e.mean.covariance));
  EXPECT_GT(e.mean.covariance(0, 0), c(0, 0));  // spread of the means adds to C_t
  EXPECT_THROW(Summarize(Mixture{}, options), Error);
}

// ---------------------------------------------------------------- tracker

// Reset / ResetUnknown / Step: a known start propagates by odometry; an unknown state
// stays unknown until a non-empty source seeds it (odometry ignored for the seed).
TEST(MixtureTracker, ResetAndStepSemantics) {
  MixtureTracker tracker{TrackerOptions{}};
  EXPECT_FALSE(tracker.HasState());
  EXPECT_FALSE(tracker.Step(OdometryIncrement{0, 1, 0}, {}).has_value());
  EXPECT_FALSE(tracker.Step(OdometryIncrement{0, 1, 0}, {Mixture{}}).has_value());

  const Gaussian start{MakePose(1, 2, 0), Diag(0.01, 0.01, 0.001), 0.3};
  tracker.Reset(start);
  ASSERT_EQ(tracker.state().size(), 1u);
  EXPECT_DOUBLE_EQ(tracker.state()[0].weight, 1.0);
  const std::optional<Estimate> e = tracker.Step(OdometryIncrement{0, 1, 0}, {});
  ASSERT_TRUE(e.has_value());
  EXPECT_LT(PoseDifference(e->strongest.mean, MakePose(2, 2, 0)).norm(), 1e-12);
  EXPECT_GT(e->strongest.covariance(0, 0), 0.01);
  EXPECT_TRUE(e->unimodal);

  tracker.ResetUnknown();
  EXPECT_FALSE(tracker.HasState());
  const Mixture seed = {{MakePose(5, 5, 1), Diag(0.1, 0.1, 0.01), 2.0},
                        {MakePose(-5, 5, 1), Diag(0.1, 0.1, 0.01), 2.0}};
  const std::optional<Estimate> seeded =
      tracker.Step(OdometryIncrement{0, 3, 0}, {Mixture{}, seed});
  ASSERT_TRUE(seeded.has_value());
  ASSERT_EQ(tracker.state().size(), 2u);
  EXPECT_EQ(tracker.state()[0].mean, seed[0].mean);  // not moved by the odometry
  EXPECT_DOUBLE_EQ(tracker.state()[0].weight, 0.5);
  EXPECT_FALSE(seeded->unimodal);
  EXPECT_EQ(seeded->num_components, 2);

  Gaussian bad = start;
  bad.covariance(0, 0) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(tracker.Reset(bad), Error);
}

// Kidnapping: the tracker is confident at A while p(x|y) keeps pointing at a far place B
// with a fixed covariance and weight 0.3. One observation must not override the track,
// but B's component gains weight every step (its weight b follows b' = (b + 0.3) / 1.3)
// and becomes the strongest after a bounded number of fusions.
TEST(MixtureTracker, RecoversFromKidnapping) {
  TrackerOptions options;
  MixtureTracker tracker(options);
  tracker.Reset({MakePose(0, 0, 0), Diag(0.01, 0.01, 0.001), 1.0});
  const Pose2 b = MakePose(8, 5, 1.0);
  const Mixture p_x_y = {{b, Diag(0.25, 0.25, 0.05), 0.3}};
  // The robot stands still (odometry says so); the place it sees is B.
  int fusions = 0;
  for (; fusions < 50; ++fusions) {
    const std::optional<Estimate> e = tracker.Step(OdometryIncrement{}, {p_x_y});
    ASSERT_TRUE(e.has_value());
    ExpectValidState(tracker.state(), options);
    if (PoseDifference(e->strongest.mean, b).head<2>().norm() < 0.5) break;
  }
  ++fusions;  // count of fusions performed
  // Measured: 3 fusions (weights of B: 0.23, 0.41, 0.55). Bound slightly above that.
  EXPECT_GE(fusions, 2) << "a single observation overrode a confident track";
  EXPECT_LE(fusions, 4);
  // The estimate at B is at least as certain as p(x|y) (CI never inflates).
  const Gaussian& strongest = tracker.state()[StrongestComponent(tracker.state())];
  EXPECT_LE(strongest.covariance.determinant(), p_x_y[0].covariance.determinant() * (1 + 1e-9));
}

// gate_confidence states the gate as the chi-square quantile (3 dof) of a probability;
// 0 keeps gamma; a pair at squared distance 5 fuses under the 99 % gate, not under 3.
TEST(TrackerOptions, GateConfidenceIsTheChiSquareQuantile) {
  TrackerOptions o;
  EXPECT_EQ(o.Gate(), o.gamma);
  o.gate_confidence = 0.99;
  EXPECT_NEAR(o.Gate(), 11.3449, 1e-3);
  const Gaussian a{Pose2::Zero(), Eigen::Matrix3d::Identity(), 1.0};
  const Gaussian b{MakePose(std::sqrt(5.0 * 2.0), 0.0, 0.0), Eigen::Matrix3d::Identity(), 1.0};
  EXPECT_EQ(FuseOnce({a}, {b}, o).size(), 1u);  // fused into one component
  o.gate_confidence = 0.0;
  EXPECT_EQ(FuseOnce({a}, {b}, o).size(), 2u);  // gamma 3: both copied
  o.gate_confidence = 1.0;
  EXPECT_THROW(o.Validate(), Error);
}

// One step of odometry noise: Thrun's sample_motion_model_odometry, as
// SampleOdometryIncrement (geometry/motion_model.h) but drawn with std::normal_distribution:
// the identification tests' stated factors were measured on these draws.
OdometryIncrement SampleIncrement(const OdometryIncrement& u, const MotionNoise& noise,
                                  std::normal_distribution<double>& n, std::mt19937_64& rng) {
  const Eigen::Matrix3d m = MotionNoiseCovariance(u, noise);
  return OdometryIncrement{u.rot1_rad + std::sqrt(m(0, 0)) * n(rng),
                           u.trans_m + std::sqrt(m(1, 1)) * n(rng),
                           u.rot2_rad + std::sqrt(m(2, 2)) * n(rng)};
}

// A log driven `laps` times around the same closed lap of true increments: the true poses
// and the dead-reckoned odometry (noise `noise`). Frames t and t + k * lap.size() are at
// the same place with the same heading.
struct LapLog {
  std::vector<Pose2> truth;
  std::vector<Pose2> odometry;
  int per_lap = 0;
};

LapLog DriveLaps(const std::vector<OdometryIncrement>& lap, const MotionNoise& noise, int laps,
                 std::mt19937_64& rng) {
  LapLog log;
  log.per_lap = static_cast<int>(lap.size());
  std::normal_distribution<double> n(0.0, 1.0);
  log.truth.push_back(Pose2::Zero());
  log.odometry.push_back(Pose2::Zero());
  for (int k = 0; k < laps; ++k) {
    for (const OdometryIncrement& u : lap) {
      log.truth.push_back(ApplyIncrement(log.truth.back(), u));
      log.odometry.push_back(
          ApplyIncrement(log.odometry.back(), SampleIncrement(u, noise, n, rng)));
    }
  }
  return log;
}

// A rounded square: 0.2 m steps, turns spread over corner steps.
std::vector<OdometryIncrement> RoundedSquare() {
  std::vector<OdometryIncrement> lap;
  for (int side = 0; side < 4; ++side) {
    for (int i = 0; i < 10; ++i) lap.push_back(OdometryIncrement{0.0, 0.2, 0.0});
    for (int i = 0; i < 3; ++i) lap.push_back(OdometryIncrement{kPi / 12, 0.1, kPi / 12});
  }
  return lap;
}

// A lap that excites every parameter: straight runs of two lengths, turns in place at the
// corners (rotation without translation: a1, a4), and a slalom (rotation with translation).
std::vector<OdometryIncrement> RichLap() {
  std::vector<OdometryIncrement> lap;
  for (int side = 0; side < 4; ++side) {
    const int steps = side % 2 == 0 ? 12 : 8;
    for (int i = 0; i < steps; ++i) {
      const double wiggle = (side == 2 ? 0.25 : 0.0) * (i % 2 == 0 ? 1.0 : -1.0);
      // Slalom steps are longer so that every side advances 0.25 m a step: the lap closes.
      lap.push_back(OdometryIncrement{wiggle, 0.25 / std::cos(wiggle), -wiggle});
    }
    lap.push_back(OdometryIncrement{kPi / 4, 0.0, kPi / 4});  // turn in place
  }
  return lap;
}

std::vector<Pose2> NoisyLaps(const MotionNoise& noise, int laps, std::mt19937_64& rng,
                             int* steps_per_lap) {
  LapLog log = DriveLaps(RoundedSquare(), noise, laps, rng);
  *steps_per_lap = log.per_lap;
  return log.odometry;
}

// Pairs one and two laps apart (every `stride`-th frame), with the descriptor's relative
// heading (the true heading change plus N(0, heading_sd^2) noise) when heading_sd >= 0.
std::vector<LoopPair> LapPairs(const LapLog& log, int stride, double heading_sd,
                               std::mt19937_64& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<LoopPair> pairs;
  const int size = static_cast<int>(log.odometry.size());
  for (int t = log.per_lap; t < size; t += stride) {
    const int laps_back = (t / stride) % 2 == 0 || t < 2 * log.per_lap ? 1 : 2;
    LoopPair p{t - laps_back * log.per_lap, t};
    if (heading_sd >= 0) {
      p.heading_rad = WrapAngle(log.truth[t].z() - log.truth[p.first].z() + heading_sd * n(rng));
    }
    pairs.push_back(p);
  }
  return pairs;
}

std::array<double, 4> Parameters(const MotionNoise& m) { return {m.a1, m.a2, m.a3, m.a4}; }

// The prefix-sum drift bases (x, y, phi) equal the covariance Propagate accumulates from a
// known pose along the same odometry with unit noise in each parameter.
TEST(MotionNoiseIdentification, DriftBasesEqualPropagation) {
  std::mt19937_64 rng(3);
  const LapLog log = DriveLaps(RichLap(), MotionNoise{0.01, 0.002, 0.005, 0.001}, 3, rng);
  const std::vector<Pose2>& odometry = log.odometry;
  const std::vector<LoopPair> pairs{
      {0, 50}, {7, 7}, {20, 100}, {3, static_cast<int>(odometry.size()) - 1}};
  const auto bases = LoopDriftBases(odometry, pairs);
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    for (int j = 0; j < 4; ++j) {
      MotionNoise unit{0, 0, 0, 0};
      (j == 0 ? unit.a1 : j == 1 ? unit.a2 : j == 2 ? unit.a3 : unit.a4) = 1.0;
      Mixture m{Gaussian{odometry[pairs[k].first], 1e-12 * Eigen::Matrix3d::Identity(), 1.0}};
      for (int i = pairs[k].first + 1; i <= pairs[k].second; ++i) {
        m = Propagate(m, ComputeIncrement(odometry[i - 1], odometry[i]), unit);
      }
      EXPECT_NEAR(m[0].mean.x(), odometry[pairs[k].second].x(), 1e-9);
      const Eigen::Matrix3d& expected = m[0].covariance;
      EXPECT_LT((bases[k][j] - expected).norm(), 1e-8 * (1.0 + expected.norm())) << k << " " << j;
    }
  }
}

// Loop innovations of a noisy multi-lap log without heading identify a noise whose
// predicted loop drift matches the true one, and whose NIS on held-out laps is consistent.
TEST(MotionNoiseIdentification, RecoversTheDriftOfTheTrueNoise) {
  const MotionNoise truth{0.01, 0.002, 0.005, 0.001};
  std::mt19937_64 rng(11);
  int per_lap = 0;
  const std::vector<Pose2> odometry = NoisyLaps(truth, 80, rng, &per_lap);
  std::vector<LoopPair> pairs;  // each frame against the same place one lap earlier
  for (int t = per_lap; t < static_cast<int>(odometry.size()); t += 4) {
    pairs.push_back(LoopPair{t - per_lap, t});
  }
  const MotionNoiseIdentification id = IdentifyMotionNoise(odometry, pairs);
  ASSERT_TRUE(id.identified);
  EXPECT_EQ(id.pairs_with_heading, 0);
  EXPECT_GT(id.pairs_used, static_cast<int>(0.95 * pairs.size()));
  // The predicted drift variance over a lap (xy trace, summed over pairs) against the truth's.
  const auto bases = LoopDriftBases(odometry, pairs);
  double predicted = 0.0, expected = 0.0;
  const std::array<double, 4> a_hat = Parameters(id.noise), a_true = Parameters(truth);
  for (const auto& b : bases) {
    for (int j = 0; j < 4; ++j) {
      predicted += a_hat[j] * b[j].block<2, 2>(0, 0).trace();
      expected += a_true[j] * b[j].block<2, 2>(0, 0).trace();
    }
  }
  EXPECT_GT(predicted / expected, 0.6);
  EXPECT_LT(predicted / expected, 1.6);
  EXPECT_LT(id.appearance_variance_m2, 0.01);  // the pairs are exact revisits
  // Held out: a new log with the same noise; the NIS of its lap pairs under the estimate.
  std::mt19937_64 rng2(12);
  const std::vector<Pose2> fresh = NoisyLaps(truth, 40, rng2, &per_lap);
  std::vector<LoopPair> fresh_pairs;
  for (int t = per_lap; t < static_cast<int>(fresh.size()); t += per_lap) {
    fresh_pairs.push_back(LoopPair{t - per_lap, t});
  }
  const auto fresh_bases = LoopDriftBases(fresh, fresh_pairs);
  double nis_sum = 0.0;
  for (std::size_t k = 0; k < fresh_pairs.size(); ++k) {
    Eigen::Matrix2d s = id.appearance_variance_m2 * Eigen::Matrix2d::Identity();
    for (int j = 0; j < 4; ++j) s += a_hat[j] * fresh_bases[k][j].block<2, 2>(0, 0);
    const Pose2& a = fresh[fresh_pairs[k].first];
    const Pose2& b = fresh[fresh_pairs[k].second];
    const Eigen::Vector2d r(b.x() - a.x(), b.y() - a.y());
    nis_sum += r.dot(s.inverse() * r);
  }
  const double mean_nis = nis_sum / static_cast<double>(fresh_pairs.size());
  EXPECT_GT(mean_nis, 1.0);  // consistent: 2 (40 independent laps)
  EXPECT_LT(mean_nis, 3.2);
}

// With the descriptor's relative heading (3-dof innovations) on a lap that turns in place,
// slaloms and drives straight, each of a1..a4 is recovered within a stated factor on every
// one of 8 logs (a1 2, a3 and a4 2.5, a2 4: a2 moves the heading a fifth as much as a1 does
// on this lap) and within a factor 2 in the geometric mean over the logs (no bias), the
// heading offset variance within a factor 5, and the loops, not the prior, carry a1..a3.
// The noise is a tenth of the simulator's so that a lap's drift stays in the range where
// the linearised drift model holds; the shape prior is widened to sd 1 so that the loops,
// not the prior, must do the recovering.
TEST(MotionNoiseIdentification, RecoversEachParameterWithHeading) {
  MotionNoiseIdentificationOptions options;
  options.shape_prior_log_sd = 1.0;
  options.joint_pairs = 0;  // the pairwise fit: lap pairs one or two laps apart
  const MotionNoise truth{0.001, 0.0002, 0.0005, 0.0001};
  const double heading_sd = 0.01;  // rad, the descriptor's relative-heading noise
  const std::array<double, 4> a_true = Parameters(truth), factor{2.0, 4.0, 2.5, 2.5};
  std::array<double, 4> log_ratio_sum{};
  constexpr int kLogs = 8;
  for (int seed = 21; seed < 21 + kLogs; ++seed) {
    std::mt19937_64 rng(seed);
    const LapLog log = DriveLaps(RichLap(), truth, 200, rng);
    const std::vector<LoopPair> pairs = LapPairs(log, 7, heading_sd, rng);
    const MotionNoiseIdentification id = IdentifyMotionNoise(log.odometry, pairs, options);
    ASSERT_TRUE(id.identified);
    EXPECT_EQ(id.pairs_with_heading, id.pairs_used);
    const std::array<double, 4> a_hat = Parameters(id.noise);
    for (int j = 0; j < 4; ++j) {
      EXPECT_GT(a_hat[j], a_true[j] / factor[j]) << "a" << j + 1 << " seed " << seed;
      EXPECT_LT(a_hat[j], a_true[j] * factor[j]) << "a" << j + 1 << " seed " << seed;
      log_ratio_sum[j] += std::log(a_hat[j] / a_true[j]);
    }
    for (int j = 0; j < 3; ++j) EXPECT_GT(id.data_share[j], 0.5) << "a" << j + 1;
    EXPECT_GT(id.heading_variance_rad2, heading_sd * heading_sd / 5) << seed;
    EXPECT_LT(id.heading_variance_rad2, heading_sd * heading_sd * 5) << seed;
    EXPECT_NEAR(id.median_nis_ratio, 1.0, 0.2) << seed;
  }
  for (int j = 0; j < 4; ++j) {
    EXPECT_LT(std::abs(log_ratio_sum[j] / kLogs), std::log(2.0)) << "a" << j + 1;
  }
}

// A rotation-poor session (a rounded square, no heading): the loops barely see a1 and a4.
// Without the prior (a flat one) a parameter collapses to its bound; with the default prior
// every parameter keeps a physical value (within a factor 10 of the truth) and the result
// says which ones the prior holds.
TEST(MotionNoiseIdentification, PriorKeepsUnseenParametersOffTheirBounds) {
  const MotionNoise truth{0.01, 0.002, 0.005, 0.001};
  std::mt19937_64 rng(31);
  const LapLog log = DriveLaps(RoundedSquare(), truth, 40, rng);
  const std::vector<LoopPair> pairs = LapPairs(log, 4, -1.0, rng);
  MotionNoiseIdentificationOptions flat;
  flat.shape_prior_log_sd = 1e3;
  flat.offset_prior_log_sd = 1e3;
  const MotionNoiseIdentification free_fit = IdentifyMotionNoise(log.odometry, pairs, flat);
  ASSERT_TRUE(free_fit.identified);
  const std::array<double, 4> a_free = Parameters(free_fit.noise);
  EXPECT_LT(*std::min_element(a_free.begin(), a_free.end()), 100 * flat.min_parameter);
  const MotionNoiseIdentification id = IdentifyMotionNoise(log.odometry, pairs);
  ASSERT_TRUE(id.identified);
  const std::array<double, 4> a_hat = Parameters(id.noise), a_true = Parameters(truth);
  for (int j = 0; j < 4; ++j) {
    EXPECT_GT(a_hat[j], a_true[j] / 10) << "a" << j + 1;
    EXPECT_LT(a_hat[j], a_true[j] * 10) << "a" << j + 1;
  }
  EXPECT_GT(id.appearance_variance_m2, 100 * flat.min_appearance_variance_m2);
  EXPECT_LT(*std::min_element(id.data_share.begin(), id.data_share.end()), 0.5);
}

// Aliased pairs (two different places that look alike, or the right place with a wrong
// relative heading) are rejected, not fitted.
TEST(MotionNoiseIdentification, RejectsAliasedPairs) {
  std::mt19937_64 rng(5);
  const LapLog log = DriveLaps(RoundedSquare(), MotionNoise{0.01, 0.002, 0.005, 0.001}, 60, rng);
  const int per_lap = log.per_lap;
  std::vector<LoopPair> pairs = LapPairs(log, 4, 0.02, rng);
  const MotionNoiseIdentification clean = IdentifyMotionNoise(log.odometry, pairs);
  const std::size_t good = pairs.size();
  // 5 % aliases: a frame against the opposite side of the square one lap earlier, and 3 %
  // heading aliases: the right place with the heading turned by half a turn.
  for (std::size_t k = 0; k < good; k += 20) {
    const int t = pairs[k].second;
    if (t >= 2 * per_lap) pairs.push_back({t - per_lap / 2 - per_lap, t, 0.0});
  }
  for (std::size_t k = 7; k < good; k += 33) {
    LoopPair p = pairs[k];
    p.heading_rad = WrapAngle(*p.heading_rad + kPi);
    pairs.push_back(p);
  }
  const MotionNoiseIdentification id = IdentifyMotionNoise(log.odometry, pairs);
  ASSERT_TRUE(clean.identified && id.identified);
  EXPECT_EQ(id.pairs_used, clean.pairs_used);
  for (int j = 0; j < 4; ++j) {
    EXPECT_NEAR(Parameters(id.noise)[j], Parameters(clean.noise)[j],
                0.05 * Parameters(clean.noise)[j]);
  }
}

// Pairs matched a few steps along the path (a corridor whose view changes slowly: the
// right place up to an offset of 0.4-0.8 m, not an alias far away) are too many and too
// mild for the NIS rejection. Under the Gaussian likelihood they widen the appearance
// offset of every pair about fourfold; from the Student t refit (offset_dof 4) it widens
// by clearly less (a quarter less at least). a1..a4 stay the Gaussian fit's, bit for bit.
TEST(MotionNoiseIdentification, StudentTOffsetKeepsTheCoreUnderAlongPathMatches) {
  std::mt19937_64 rng(7);
  const LapLog log = DriveLaps(RoundedSquare(), MotionNoise{0.01, 0.002, 0.005, 0.001}, 60, rng);
  std::vector<LoopPair> pairs = LapPairs(log, 4, 0.01, rng);
  MotionNoiseIdentificationOptions gaussian, t4;
  gaussian.offset_dof = 0.0;
  t4.offset_dof = 4.0;
  const MotionNoiseIdentification clean_g = IdentifyMotionNoise(log.odometry, pairs, gaussian);
  const MotionNoiseIdentification clean_t = IdentifyMotionNoise(log.odometry, pairs, t4);
  // 20 % of the pairs: the first frame 2-4 steps (0.4-0.8 m) earlier or later on its lap.
  const std::size_t good = pairs.size();
  for (std::size_t k = 0; k < good; k += 5) {
    const int shift = (k % 2 == 0 ? 1 : -1) * (2 + static_cast<int>(k % 3));
    LoopPair& p = pairs[k];
    p.first = std::clamp(p.first + shift, 0, p.second - 1);
    p.heading_rad = WrapAngle(log.truth[p.second].z() - log.truth[p.first].z());
  }
  const MotionNoiseIdentification g = IdentifyMotionNoise(log.odometry, pairs, gaussian);
  const MotionNoiseIdentification t = IdentifyMotionNoise(log.odometry, pairs, t4);
  ASSERT_TRUE(clean_g.identified && clean_t.identified && g.identified && t.identified);
  EXPECT_GT(g.pairs_used, static_cast<int>(0.95 * good));  // mild: the rejection keeps them
  const double widen_g = std::sqrt(g.appearance_variance_m2 / clean_g.appearance_variance_m2);
  const double widen_t = std::sqrt(t.appearance_variance_m2 / clean_t.appearance_variance_m2);
  EXPECT_GT(widen_g, 3.0);
  EXPECT_LT(widen_t, 0.75 * widen_g);
  EXPECT_EQ(Parameters(t.noise), Parameters(g.noise));
  EXPECT_EQ(t.heading_variance_rad2, g.heading_variance_rad2);
  EXPECT_EQ(t.pairs_used, g.pairs_used);
}

// The estimate is a function of the input only: the same pairs give the same bits.
TEST(MotionNoiseIdentification, IsDeterministic) {
  std::mt19937_64 rng(41);
  const LapLog log = DriveLaps(RichLap(), MotionNoise{0.01, 0.002, 0.005, 0.001}, 20, rng);
  const std::vector<LoopPair> pairs = LapPairs(log, 5, 0.02, rng);
  const MotionNoiseIdentification a = IdentifyMotionNoise(log.odometry, pairs);
  const MotionNoiseIdentification b = IdentifyMotionNoise(log.odometry, pairs);
  EXPECT_EQ(Parameters(a.noise), Parameters(b.noise));
  EXPECT_EQ(a.heading_variance_rad2, b.heading_variance_rad2);
  EXPECT_EQ(a.log_sd, b.log_sd);
}

// Too few pairs leave the noise unidentified; bad pairs and options are errors.
TEST(MotionNoiseIdentification, RefusesTooLittleDataAndBadInput) {
  std::vector<Pose2> odometry(10, Pose2::Zero());
  EXPECT_FALSE(IdentifyMotionNoise(odometry, {{0, 5}}).identified);
  EXPECT_THROW(LoopDriftBases(odometry, {{5, 2}}), Error);
  EXPECT_THROW(LoopDriftBases(odometry, {{0, 10}}), Error);
  EXPECT_THROW(IdentifyMotionNoise(odometry, {{0, 5, std::nan("")}}), Error);
  MotionNoiseIdentificationOptions bad;
  bad.outlier_confidence = 1.0;
  EXPECT_THROW(IdentifyMotionNoise(odometry, {}, bad), Error);
  MotionNoiseIdentificationOptions bad_dof;
  bad_dof.offset_dof = -1.0;
  EXPECT_THROW(IdentifyMotionNoise(odometry, {}, bad_dof), Error);
  MotionNoiseIdentificationOptions no_shape;
  no_shape.shape_prior.a3 = 0.0;
  EXPECT_THROW(no_shape.Validate(), Error);
  MotionNoiseIdentificationOptions no_width;
  no_width.offset_prior_log_sd = 0.0;
  EXPECT_THROW(no_width.Validate(), Error);
  MotionNoiseIdentificationOptions negative_joint;
  negative_joint.joint_pairs = -1;
  EXPECT_THROW(negative_joint.Validate(), Error);
}

// Loop pairs that all reach back to the first lap share its dead reckoning, and every pair
// of one lap shares the laps between: the pairs hold one realisation of the heading drift,
// not one per pair. At the simulator's noise (a lap's heading drift reaches tenths of a
// radian), the joint likelihood of the heading innovations recovers a1 and a2 within a
// factor 2 on every one of 8 logs, unbiased over the logs, with most of a1's curvature
// and at least a third of a2's from the loops (the rest from the shape prior);
// the fit that treats the pairs as independent follows each log's realisation and
// scatters several times more from log to log.
TEST(MotionNoiseIdentification, JointHeadingFitHoldsWherePairsShareTheirDrift) {
  const MotionNoise truth{0.01, 0.002, 0.005, 0.001};
  const double heading_sd = 0.01;  // rad, the descriptor's relative-heading noise
  MotionNoiseIdentificationOptions independent;
  independent.joint_pairs = 0;
  std::array<double, 2> joint_log_sum{};
  double joint_lo = 1e9, joint_hi = 0, independent_lo = 1e9, independent_hi = 0;
  constexpr int kLogs = 8;
  for (int seed = 21; seed < 21 + kLogs; ++seed) {
    std::mt19937_64 rng(seed);
    const LapLog log = DriveLaps(RoundedSquare(), truth, 20, rng);
    std::normal_distribution<double> n(0.0, 1.0);
    std::vector<LoopPair> pairs;
    for (int t = log.per_lap; t < static_cast<int>(log.odometry.size()); t += 3) {
      LoopPair p{t % log.per_lap, t};
      p.heading_rad = WrapAngle(log.truth[t].z() - log.truth[p.first].z() + heading_sd * n(rng));
      pairs.push_back(p);
    }
    const MotionNoiseIdentification joint = IdentifyMotionNoise(log.odometry, pairs);
    ASSERT_TRUE(joint.identified);
    EXPECT_EQ(joint.joint_pairs_used, std::min(150, joint.pairs_with_heading));
    const std::array<double, 2> a_hat{joint.noise.a1, joint.noise.a2};
    const std::array<double, 2> a_true{truth.a1, truth.a2};
    for (int j = 0; j < 2; ++j) {
      EXPECT_GT(a_hat[j], a_true[j] / 2) << "a" << j + 1 << " seed " << seed;
      EXPECT_LT(a_hat[j], a_true[j] * 2) << "a" << j + 1 << " seed " << seed;
      EXPECT_GT(joint.data_share[j], j == 0 ? 0.5 : 0.3) << "a" << j + 1 << " seed " << seed;
      joint_log_sum[j] += std::log(a_hat[j] / a_true[j]);
    }
    const MotionNoiseIdentification pairwise =
        IdentifyMotionNoise(log.odometry, pairs, independent);
    ASSERT_TRUE(pairwise.identified);
    EXPECT_EQ(pairwise.joint_pairs_used, 0);
    joint_lo = std::min(joint_lo, joint.noise.a1);
    joint_hi = std::max(joint_hi, joint.noise.a1);
    independent_lo = std::min(independent_lo, pairwise.noise.a1);
    independent_hi = std::max(independent_hi, pairwise.noise.a1);
  }
  for (int j = 0; j < 2; ++j) {
    EXPECT_LT(std::abs(joint_log_sum[j] / kLogs), std::log(1.5)) << "a" << j + 1;
  }
  EXPECT_GT(independent_hi / independent_lo, 3.0 * joint_hi / joint_lo);
}

}  // namespace
}  // namespace omnicml
