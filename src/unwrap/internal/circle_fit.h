// Robust circle fitting for the ring auto-calibration (private to omnicml_unwrap).
//
// Circles are fitted to 2-D edge points in pixel coordinates with Ceres: each point
// contributes the geometric residual |p - c| - r (pixels) under a robust loss. Several
// point sets can share one centre (concentric circles: the inner and outer boundary of a
// catadioptric ring). Single-threaded and deterministic.
#ifndef OMNICML_UNWRAP_INTERNAL_CIRCLE_FIT_H_
#define OMNICML_UNWRAP_INTERNAL_CIRCLE_FIT_H_

#include <vector>

#include <opencv2/core.hpp>

namespace omnicml::internal {

enum class RobustLoss { kNone, kHuber, kCauchy };

// Concentric circles: one centre, one radius per point set.
struct ConcentricCircles {
  cv::Point2d center_px;
  std::vector<double> radii_px;
};

// Per point set: which points are inliers and their RMS residual.
struct CircleFitReport {
  ConcentricCircles circles;
  std::vector<double> rms_px;                // RMS geometric residual of the inliers
  std::vector<int> inliers;                  // number of inliers per set
  std::vector<std::vector<char>> is_inlier;  // per set, per point
};

// Minimises sum_s sum_i rho((|p_si - c| - r_s)^2) over c and r_s, starting from
// `initial`. `loss_scale_px` is the residual (pixels) where the robust loss starts to
// down-weight. After the fit, a point is an inlier when its absolute residual is at most
// max(min_inlier_threshold_px, 3 * 1.4826 * MAD) of its set. Each set needs at least 3
// points (OMNICML_CHECK).
CircleFitReport FitConcentricCircles(const std::vector<std::vector<cv::Point2d>>& sets,
                                     const ConcentricCircles& initial, RobustLoss loss,
                                     double loss_scale_px, double min_inlier_threshold_px);

}  // namespace omnicml::internal

#endif  // OMNICML_UNWRAP_INTERNAL_CIRCLE_FIT_H_
