// Fixed-lag smoothing of a filtered estimate by the frames that follow it (docs/design.md
// "Map updates smoothed over the delay"): the Rauch-Tung-Striebel backward pass over a
// chain of filtered Gaussians linked by odometry increments, with the tracker's own
// prediction (tracker.h Propagate: Thrun's odometry model, Jacobians at the filtered
// mean).
//
// Pure functions; thread-safe.
#ifndef OMNICML_TRACKING_FIXED_LAG_SMOOTHER_H_
#define OMNICML_TRACKING_FIXED_LAG_SMOOTHER_H_

#include <vector>

#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

// The smoothed estimate of the first state of a chain: filtered[k] = N(x_k|k, P_k|k) for
// k = 0..N (map frame; weights ignored), increments[k] the odometry increment from frame
// k to frame k + 1 (increments.size() == N). With the prediction of the tracker,
//   x_k+1|k = g(x_k|k, u_k),  P_k+1|k = G_k P_k|k G_k^T + V_k M(u_k) V_k^T,
// the backward pass (Rauch, Tung and Striebel 1965; Saerkkae, Bayesian Filtering and
// Smoothing, eq. 8.6) is, from x_N|N = x_N|N down to k = 0,
//   C_k = P_k|k G_k^T P_k+1|k^-1,
//   x_k|N = x_k|k + C_k (x_k+1|N - x_k+1|k)   (heading difference wrapped),
//   P_k|N = P_k|k + C_k (P_k+1|N - P_k+1|k) C_k^T.
// Returns N(x_0|N, P_0|N) with weight 1; filtered[0] itself when N = 0. Exact for a
// linear-Gaussian chain; for filters that are not Kalman updates (covariance
// intersection) the same pass with their posteriors. Throws omnicml::Error when sizes
// disagree or a covariance is not positive definite.
Gaussian SmoothFirstOfChain(const std::vector<Gaussian>& filtered,
                            const std::vector<OdometryIncrement>& increments,
                            const MotionNoise& noise);

}  // namespace omnicml

#endif  // OMNICML_TRACKING_FIXED_LAG_SMOOTHER_H_
