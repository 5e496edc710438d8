#include "omnicml/geometry/chi_square.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// The CDF against closed forms: dof 1 erf(sqrt(x/2)), dof 2 1 - exp(-x/2), dof 3 and 4.
TEST(ChiSquare, CdfMatchesClosedForms) {
  constexpr double kPi = 3.14159265358979323846;
  for (double x : {1e-6, 0.01, 0.3, 1.0, 2.5, 6.0, 11.0, 30.0, 80.0}) {
    const double s = std::sqrt(0.5 * x);
    EXPECT_NEAR(ChiSquareCdf(x, 1), std::erf(s), 1e-13) << x;
    EXPECT_NEAR(ChiSquareCdf(x, 2), 1 - std::exp(-0.5 * x), 1e-14) << x;
    EXPECT_NEAR(ChiSquareCdf(x, 3), std::erf(s) - std::sqrt(2 * x / kPi) * std::exp(-0.5 * x),
                1e-13)
        << x;
    EXPECT_NEAR(ChiSquareCdf(x, 4), 1 - std::exp(-0.5 * x) * (1 + 0.5 * x), 1e-13) << x;
  }
  EXPECT_EQ(ChiSquareCdf(0.0, 3), 0.0);
  EXPECT_EQ(ChiSquareCdf(-1.0, 3), 0.0);
}

// Quantiles against the printed tables (e.g. Bar-Shalom et al., Table 1.5.4-1) and as the
// inverse of the CDF.
TEST(ChiSquare, QuantilesMatchTables) {
  EXPECT_NEAR(ChiSquareQuantile(0.95, 1), 3.8415, 1e-4);
  EXPECT_NEAR(ChiSquareQuantile(0.95, 2), 5.9915, 1e-4);
  EXPECT_NEAR(ChiSquareQuantile(0.99, 2), 9.2103, 1e-4);
  EXPECT_NEAR(ChiSquareQuantile(0.99, 3), 11.3449, 1e-4);
  EXPECT_NEAR(ChiSquareQuantile(0.5, 2), 1.3863, 1e-4);
  EXPECT_NEAR(ChiSquareQuantile(0.5, 1), 0.4549, 1e-4);
  EXPECT_NEAR(ChiSquareQuantile(0.025, 1), 0.000982, 1e-6);
  for (int dof : {1, 2, 3, 5}) {
    for (double p : {0.001, 0.025, 0.5, 0.975, 0.999}) {
      EXPECT_NEAR(ChiSquareCdf(ChiSquareQuantile(p, dof), dof), p, 1e-9) << dof << " " << p;
    }
  }
  const ChiSquareBand band = ChiSquareTwoSidedBand(0.95, 2);
  EXPECT_NEAR(band.lower, 0.0506, 1e-4);
  EXPECT_NEAR(band.upper, 7.3778, 1e-4);
}

// The CDF of sampled sums of squared standard normals agrees with ChiSquareCdf.
TEST(ChiSquare, CdfAgreesWithSampledSums) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  const int kSamples = 20000;
  int below = 0;
  const double x = ChiSquareQuantile(0.8, 3);
  for (int i = 0; i < kSamples; ++i) {
    double s = 0;
    for (int k = 0; k < 3; ++k) {
      const double z = n(rng);
      s += z * z;
    }
    if (s <= x) ++below;
  }
  EXPECT_NEAR(static_cast<double>(below) / kSamples, 0.8, 0.01);
}

// Bad arguments are errors, not silent NaN.
TEST(ChiSquare, RejectsBadArguments) {
  EXPECT_THROW(ChiSquareCdf(1.0, 0), Error);
  EXPECT_THROW(ChiSquareCdf(std::nan(""), 2), Error);
  EXPECT_THROW(ChiSquareQuantile(1.0, 2), Error);
  EXPECT_THROW(ChiSquareQuantile(0.0, 2), Error);
  EXPECT_THROW(ChiSquareQuantile(0.5, 0), Error);
  EXPECT_THROW(ChiSquareTwoSidedBand(1.5, 2), Error);
}

}  // namespace
}  // namespace omnicml
