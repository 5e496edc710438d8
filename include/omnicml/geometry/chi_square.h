// The chi-square distribution: cumulative distribution function and quantiles, for
// consistency tests of Gaussian estimates (NEES, NIS) and for gates stated as a
// confidence (the squared Mahalanobis distance of a d-dimensional Gaussian error is
// chi-square with d degrees of freedom).
//
// Pure functions; thread-safe.
#ifndef OMNICML_GEOMETRY_CHI_SQUARE_H_
#define OMNICML_GEOMETRY_CHI_SQUARE_H_

namespace omnicml {

// P(X <= x) for X chi-square with `dof` >= 1 degrees of freedom: the regularized lower
// incomplete gamma function P(dof / 2, x / 2) (series for small x, Lentz continued
// fraction for large x; relative accuracy about 1e-14). 0 for x <= 0. Throws
// omnicml::Error when dof < 1 or x is NaN.
double ChiSquareCdf(double x, int dof);

// The p-quantile (0 < p < 1) of the chi-square distribution with `dof` >= 1 degrees of
// freedom, by bisection on ChiSquareCdf to an absolute accuracy of about 1e-10 (closed
// form -2 ln(1 - p) for dof = 2). E.g. dof 2: 0.95 -> 5.991, 0.99 -> 9.210; dof 3:
// 0.99 -> 11.345. Throws omnicml::Error outside those ranges.
double ChiSquareQuantile(double p, int dof);

// The two-sided band [q((1 - c) / 2), q((1 + c) / 2)] that holds a fraction `c` (0 < c < 1)
// of a chi-square variable with `dof` degrees of freedom; a consistent estimator's NEES
// falls inside the 95 % band on 95 % of its frames.
struct ChiSquareBand {
  double lower = 0.0;
  double upper = 0.0;
};
ChiSquareBand ChiSquareTwoSidedBand(double confidence, int dof);

}  // namespace omnicml

#endif  // OMNICML_GEOMETRY_CHI_SQUARE_H_
