// Gaussians and mixtures over planar poses, with angle-aware arithmetic.
//
// A component is (mean, covariance, weight) with mean = (x_m, y_m, phi_rad) and a 3x3
// symmetric positive definite covariance in (m^2, m^2, rad^2). Angle differences are
// wrapped wherever they enter a distance, a mean or a merge (docs/design.md "State and
// Gaussians"): two components either side of +-pi merge to a mean near pi, not 0.
// Plain value types; no shared state; thread-compatible.
#ifndef OMNICML_GEOMETRY_GAUSSIAN_MIXTURE_H_
#define OMNICML_GEOMETRY_GAUSSIAN_MIXTURE_H_

#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/pose.h"

namespace omnicml {

struct Gaussian {
  Pose2 mean = Pose2::Zero();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  double weight = 1.0;
};

using Mixture = std::vector<Gaussian>;

// Squared Mahalanobis distance (a - b)^T S^-1 (a - b) with the angle difference wrapped.
// S must be SPD; throws omnicml::Error if it is not.
double SquaredMahalanobis(const Pose2& a, const Pose2& b, const Eigen::Matrix3d& s);

// Largest eigenvalue of a symmetric 2x2 matrix (e.g. the xy block of a pose covariance:
// its square root is the position's largest standard deviation), in closed form, so the
// result is the same bits on every machine.
double LargestEigenvalue2(const Eigen::Matrix2d& m);

// Checks that a covariance is finite and SPD. If it is only slightly off (asymmetric by
// rounding, eigenvalues below min_eigenvalue), returns the repaired matrix: symmetrised,
// eigenvalues clamped to at least min_eigenvalue. Throws omnicml::Error naming `what`
// when it has NaN/inf entries or an eigenvalue below -1e-6 * its largest magnitude, and
// also when it is asymmetric beyond rounding (an entry of |C - C^T| above 1e-6 * max |C|).
Eigen::Matrix3d RepairCovariance(const Eigen::Matrix3d& c, double min_eigenvalue = 1e-12,
                                 const std::string& what = "covariance");

// How MomentMatch averages the heading.
enum class HeadingMean {
  // atan2 of the weighted sums of sin and cos (the circular mean).
  kCircular,
  // The first component's mean plus the weighted mean of the wrapped differences
  // PoseDifference(mean_i, mean_0) (all three coordinates): for a pair, the first mean
  // moves toward the second by its weight share along the shorter arc, [G] (13) read
  // literally. The environment model's component merge (12)-(14) uses it.
  kAnchored,
};

// Moment-matched single Gaussian of weighted components (weights need not sum to one,
// must have a positive sum; the result's weight is their sum). The heading mean follows
// `heading`; spread terms use wrapped differences to the merged mean. [G] eqs. (13)-(14)
// for a pair.
Gaussian MomentMatch(std::span<const Gaussian> components,
                     HeadingMean heading = HeadingMean::kCircular);

// Convex combination of information (Julier & Uhlmann's covariance intersection; [G]
// (3)-(4)): C = (share_a C_a^-1 + share_b C_b^-1)^-1 and mu = mu_a + C share_b C_b^-1 d
// with d = PoseDifference(mu_b, mu_a), i.e. (4) with mu_b's heading unwrapped next to
// mu_a's. share_a + share_b = 1 is covariance intersection, consistent whatever the
// correlation of a and b; share_a = share_b = 1 is the information-filter (Kalman) update
// for independent a and b. info_a, info_b are C_a^-1, C_b^-1 (callers that fuse one
// component with many pass them precomputed). Throws omnicml::Error naming `what` when
// the combined information is not positive definite. The result's weight is 0; its
// covariance is repaired with min_eigenvalue.
Gaussian CombineInformation(const Gaussian& a, const Eigen::Matrix3d& info_a, double share_a,
                            const Gaussian& b, const Eigen::Matrix3d& info_b, double share_b,
                            double min_eigenvalue, const char* what);

// Covariance intersection of a and b with weight omega on b (share_a = 1 - omega,
// share_b = omega; CombineInformation). Both covariances are repaired first; omega must
// be in [0, 1].
Gaussian CovarianceIntersection(const Gaussian& a, const Gaussian& b, double omega);

// A covariance of the error of share_a x_a + share_b x_b that holds whatever the
// correlation of x_a and x_b (covariances c_a, c_b): for every k > 0,
// Cov <= (1 + k) share_a^2 c_a + (1 + 1/k) share_b^2 c_b (expand (sqrt(k) share_a e_a -
// share_b e_b / sqrt(k)) (...)^T >= 0); returns the member of smallest determinant (its
// log determinant is convex in log k). Equals c when c_a = c_b = c and share_a + share_b =
// 1, never exceeds share_a c_a + share_b c_b (the member k = share_b / share_a) in
// determinant; a zero share returns the other side's covariance scaled by its share
// squared. Shares must be >= 0 and not both 0; c_a, c_b symmetric positive
// semi-definite.
Eigen::Matrix3d LinearCombinationBound(const Eigen::Matrix3d& c_a, double share_a,
                                       const Eigen::Matrix3d& c_b, double share_b);

// Sum of weights.
double TotalWeight(const Mixture& m);

// Divides all weights by their sum (no-op on an empty mixture or zero sum).
void NormalizeWeights(Mixture* m);

// Index of the component with the largest weight; -1 when empty.
int StrongestComponent(const Mixture& m);

}  // namespace omnicml

#endif  // OMNICML_GEOMETRY_GAUSSIAN_MIXTURE_H_
