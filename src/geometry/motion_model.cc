#include "omnicml/geometry/motion_model.h"

#include <cmath>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Throws naming `prefix.field` unless value is finite and >= 0.
void CheckNonNegative(const char* prefix, const char* field, double value) {
  if (!(std::isfinite(value) && value >= 0)) {
    throw Error(StrCat(prefix, field, " must be finite and >= 0, got ", value));
  }
}

}  // namespace

void MotionNoise::Validate() const {
  CheckNonNegative("MotionNoise.", "a1", a1);
  CheckNonNegative("MotionNoise.", "a2", a2);
  CheckNonNegative("MotionNoise.", "a3", a3);
  CheckNonNegative("MotionNoise.", "a4", a4);
}

// g(mu, u) = (x + t cos(phi + r1), y + t sin(phi + r1), phi + r1 + r2).
Eigen::Matrix3d MotionJacobianState(const Pose2& mu, const OdometryIncrement& u) {
  const double h = mu.z() + u.rot1_rad;
  const double t = u.trans_m;
  Eigen::Matrix3d g = Eigen::Matrix3d::Identity();
  g(0, 2) = -t * std::sin(h);
  g(1, 2) = t * std::cos(h);
  return g;
}

Eigen::Matrix3d MotionJacobianControl(const Pose2& mu, const OdometryIncrement& u) {
  const double h = mu.z() + u.rot1_rad;
  const double t = u.trans_m;
  const double c = std::cos(h), s = std::sin(h);
  Eigen::Matrix3d v;
  v << -t * s, c, 0.0,  //
      t * c, s, 0.0,    //
      1.0, 0.0, 1.0;
  return v;
}

Eigen::Matrix3d MotionNoiseCovariance(const OdometryIncrement& u, const MotionNoise& noise) {
  const double r1 = u.rot1_rad * u.rot1_rad;
  const double t2 = u.trans_m * u.trans_m;
  const double r2 = u.rot2_rad * u.rot2_rad;
  return Eigen::Vector3d(noise.a1 * r1 + noise.a2 * t2, noise.a3 * t2 + noise.a4 * (r1 + r2),
                         noise.a1 * r2 + noise.a2 * t2)
      .asDiagonal();
}

}  // namespace omnicml
