// Automatic calibration of ring (catadioptric) and circular fisheye images: the image
// circle's centre and radius from the image alone (docs/design.md "Automatic
// calibration").
//
// Method, in three stages, all deterministic:
//  1. Search (on a copy shrunk to at most search_max_side_px): for candidate centres on
//     a grid over the middle of the image, rays are cast and, along each, edge evidence is
//     collected: samples where the gradient is strong (above a percentile of the image's
//     gradient magnitudes), points along the ray (radial, not tangential) and is a local
//     maximum along it. The support of a circle (centre, radius) is the fraction of its
//     rays lying inside the image that have such an edge within a small tolerance of the
//     radius. Only circles with at least half their length inside the image compete (a
//     ring clipped by the image border still wins; a mirror holder mostly outside the
//     image does not). The rim is the best-supported circle; the grid is refined twice.
//     Text overlays, field lines and a bright or cluttered centre give edges that are not
//     radial or not on one circle, so they add little support to any circle.
//  2. Refinement at full resolution: along 720 rays the strongest radial edge near the
//     rim gives one sub-pixel point per ray; a RANSAC circle (3-point samples, seeded)
//     keeps the points of one circle (an irregular rim, reflections and overlays are
//     outliers) and a Huber-loss least-squares fit of its inliers (Ceres) gives centre
//     and radius.
//  3. Ring only: the inner boundary (the hole, the robot's own body or the camera's
//     reflection) is the best-supported concentric circle between 8 % and 75 % of the
//     rim's radius, refined the same way with the centre kept.
// Several frames of one camera can be given: evidence is pooled, so a rim that one frame
// shows weakly is carried by the others while the changing scene averages out.
// Confidence: the fraction of the rim's visible rays with an edge point within the
// inlier tolerance of the fitted circle. Refusal (omnicml::Error, one line, naming why):
// no circle with enough support, too few points agree with a circle, or the fitted circle
// is not round enough.
#ifndef OMNICML_UNWRAP_AUTO_CALIBRATION_H_
#define OMNICML_UNWRAP_AUTO_CALIBRATION_H_

#include <vector>

#include <opencv2/core.hpp>

#include "omnicml/unwrap/camera_model.h"

namespace omnicml {

struct AutoCalibrationOptions {
  // Longest side of the shrunk image the search runs on, pixels (64..2048).
  int search_max_side_px = 400;
  // Minimum confidence of the rim (fraction of its visible rays supported), (0, 1].
  double min_rim_confidence = 0.35;
  // Minimum support of the ring's inner boundary, (0, 1].
  double min_inner_confidence = 0.2;
  // Search the inner boundary (rings); false for fisheye images, which have none.
  bool find_inner = true;

  void Validate() const;
};

// Result of estimating the image circle(s).
struct AutoCalibrationResult {
  OmniCalibration calibration;   // the input template with centre and radii replaced
  double inner_residual_px = 0;  // RMS distance of inner-boundary inliers to their circle
  double outer_residual_px = 0;  // RMS distance of rim inliers to the fitted circle
  int inner_inliers = 0;
  int outer_inliers = 0;
  double confidence = 0;        // rim support after the fit, in [0, 1]
  double inner_confidence = 0;  // inner boundary's search support, in [0, 1] (0: not searched)
  double visible_fraction = 0;  // fraction of the rim's length inside the image
  int frames_used = 0;
};

// Ring calibration from one image (CV_8UC1 or CV_8UC3). `initial` gives the panorama
// size, direction and the other fields carried over. Throws omnicml::Error (one line,
// "no ring found (...)" with the reason) when unsure; also on an empty, tiny or wrongly
// typed image.
AutoCalibrationResult AutoCalibrate(const cv::Mat& raw, const OmniCalibration& initial = {},
                                    const AutoCalibrationOptions& options = {});
// The same from several frames of one camera (all of one size); evidence is pooled.
AutoCalibrationResult AutoCalibrate(const std::vector<cv::Mat>& frames,
                                    const OmniCalibration& initial = {},
                                    const AutoCalibrationOptions& options = {});

// Fisheye: the image circle's centre and radius (AutoCalibrate without the inner
// boundary) written into a copy of `initial`; `result` (optional) receives the fit report.
FisheyeCalibration AutoCalibrateFisheye(const std::vector<cv::Mat>& frames,
                                        const FisheyeCalibration& initial,
                                        AutoCalibrationResult* result = nullptr);

// A BGR copy of `raw` with the calibration drawn on it for a person to check: ring
// circles (green outer, yellow inner) or the fisheye image circle and its elevation band,
// the centre as a cross, and the direction of panorama column 0 as a line.
cv::Mat DrawCalibrationOverlay(const cv::Mat& raw, const CameraCalibration& calibration);

}  // namespace omnicml

#endif  // OMNICML_UNWRAP_AUTO_CALIBRATION_H_
