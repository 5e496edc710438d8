// The odometry motion model (docs/design.md "Motion model", Thrun et al., Probabilistic
// Robotics 5.4): an increment u = (rot1, trans, rot2) moves a planar pose by
// g(mu, u) = (x + trans cos(phi + rot1), y + trans sin(phi + rot1), phi + rot1 + rot2),
// with independent zero-mean noise on (rot1, trans, rot2) whose variances grow with the
// motion (MotionNoise). Used by the tracker's prediction, the simulator's and AntWorld's
// odometry noise, MCL's sampling, the pose graph's odometry factors and the lap bound.
//
// Pure functions; thread-safe.
#ifndef OMNICML_GEOMETRY_MOTION_MODEL_H_
#define OMNICML_GEOMETRY_MOTION_MODEL_H_

#include <random>
#include <string>

#include <Eigen/Core>

#include "omnicml/geometry/pose.h"

namespace omnicml {

// Odometry error model a1..a4 (docs/design.md "Motion model", Thrun et al.):
// M = diag(a1 rot1^2 + a2 trans^2, a3 trans^2 + a4 (rot1^2 + rot2^2), a1 rot2^2 + a2 trans^2).
struct MotionNoise {
  double a1 = 0.05;  // rad^2 of rotation noise per rad^2 of rotation
  double a2 = 0.01;  // rad^2 of rotation noise per m^2 of translation
  double a3 = 0.05;  // m^2 of translation noise per m^2 of translation
  double a4 = 0.01;  // m^2 of translation noise per rad^2 of rotation
  // Throws omnicml::Error naming `prefix` + the field if one is negative or not finite.
  void Validate(const std::string& prefix = "MotionNoise.") const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, MotionNoise& o) {
  v("a1", o.a1);
  v("a2", o.a2);
  v("a3", o.a3);
  v("a4", o.a4);
}

// Jacobians of g(mu, u) = ApplyIncrement(mu, u): G = dg/dmu (3x3), V = dg/du (3x3, u =
// (rot1, trans, rot2)).
Eigen::Matrix3d MotionJacobianState(const Pose2& mu, const OdometryIncrement& u);
Eigen::Matrix3d MotionJacobianControl(const Pose2& mu, const OdometryIncrement& u);

// The control noise M of the model above for increment u.
Eigen::Matrix3d MotionNoiseCovariance(const OdometryIncrement& u, const MotionNoise& noise);

// Thrun's sample_motion_model_odometry: returns u perturbed by zero-mean Gaussian noise
// with the variances M of `noise` (above). Gaussian samples come from Box-Muller on the
// engine's raw output, so the result is the same with any standard library. Used by the
// simulator, the AntWorld and video importers and MCL.
OdometryIncrement SampleOdometryIncrement(const OdometryIncrement& u, const MotionNoise& noise,
                                          std::mt19937_64& rng);

}  // namespace omnicml

#endif  // OMNICML_GEOMETRY_MOTION_MODEL_H_
