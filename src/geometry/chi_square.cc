#include "omnicml/geometry/chi_square.h"

#include <cmath>
#include <limits>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Regularized lower incomplete gamma P(a, x), a > 0, x > 0 (Numerical Recipes 6.2):
// the series converges quickly for x < a + 1, the continued fraction of Q = 1 - P for
// larger x.
double RegularizedLowerGamma(double a, double x) {
  const double log_prefactor = a * std::log(x) - x - std::lgamma(a);
  constexpr int kMaxIterations = 1000;
  constexpr double kEps = 1e-16;
  if (x < a + 1.0) {
    double term = 1.0 / a, sum = term, ap = a;
    for (int n = 0; n < kMaxIterations; ++n) {
      ap += 1.0;
      term *= x / ap;
      sum += term;
      if (std::abs(term) < std::abs(sum) * kEps) break;
    }
    return std::min(1.0, sum * std::exp(log_prefactor));
  }
  // Modified Lentz for Q(a, x) = exp(log_prefactor) / (x + 1 - a - 1 (1 - a) / (x + 3 - a - ...)).
  constexpr double kTiny = std::numeric_limits<double>::min() / kEps;
  double b = x + 1.0 - a, c = 1.0 / kTiny, d = 1.0 / b, h = d;
  for (int i = 1; i < kMaxIterations; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < kEps) break;
  }
  return std::max(0.0, 1.0 - std::exp(log_prefactor) * h);
}

}  // namespace

double ChiSquareCdf(double x, int dof) {
  if (dof < 1) throw Error(StrCat("ChiSquareCdf: dof must be >= 1, got ", dof));
  if (std::isnan(x)) throw Error("ChiSquareCdf: x is NaN");
  if (x <= 0.0) return 0.0;
  if (std::isinf(x)) return 1.0;
  if (dof == 2) return -std::expm1(-0.5 * x);
  return RegularizedLowerGamma(0.5 * dof, 0.5 * x);
}

double ChiSquareQuantile(double p, int dof) {
  if (dof < 1) throw Error(StrCat("ChiSquareQuantile: dof must be >= 1, got ", dof));
  if (!(p > 0.0 && p < 1.0)) throw Error(StrCat("ChiSquareQuantile: p must be in (0, 1), got ", p));
  if (dof == 2) return -2.0 * std::log1p(-p);
  // Bracket: the CDF is increasing; double the upper end until it holds p.
  double lo = 0.0, hi = std::max(1.0, 2.0 * dof);
  while (ChiSquareCdf(hi, dof) < p) hi *= 2.0;
  for (int i = 0; i < 200 && hi - lo > 1e-12 * std::max(1.0, hi); ++i) {
    const double mid = 0.5 * (lo + hi);
    (ChiSquareCdf(mid, dof) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

ChiSquareBand ChiSquareTwoSidedBand(double confidence, int dof) {
  if (!(confidence > 0.0 && confidence < 1.0)) {
    throw Error(StrCat("ChiSquareTwoSidedBand: confidence must be in (0, 1), got ", confidence));
  }
  const double tail = 0.5 * (1.0 - confidence);
  return {ChiSquareQuantile(tail, dof), ChiSquareQuantile(1.0 - tail, dof)};
}

}  // namespace omnicml
