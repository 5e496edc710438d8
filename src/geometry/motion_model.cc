#include "omnicml/geometry/motion_model.h"

#include <cmath>
#include <string>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Throws naming `prefix.field` unless value is finite and >= 0.
void CheckNonNegative(const std::string& prefix, const char* field, double value) {
  if (!(std::isfinite(value) && value >= 0)) {
    throw Error(StrCat(prefix, field, " must be finite and >= 0, got ", value));
  }
}

// A uniform double in (0, 1) from 53 random bits (never 0, so log() is finite).
double UniformOpen(std::mt19937_64& rng) {
  return (static_cast<double>(rng() >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

// A standard normal sample by Box-Muller (one sample per call, two uniforms).
double StandardNormal(std::mt19937_64& rng) {
  const double u1 = UniformOpen(rng);
  const double u2 = UniformOpen(rng);
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(kTwoPi * u2);
}

}  // namespace

void MotionNoise::Validate(const std::string& prefix) const {
  CheckNonNegative(prefix, "a1", a1);
  CheckNonNegative(prefix, "a2", a2);
  CheckNonNegative(prefix, "a3", a3);
  CheckNonNegative(prefix, "a4", a4);
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

OdometryIncrement SampleOdometryIncrement(const OdometryIncrement& u, const MotionNoise& noise,
                                          std::mt19937_64& rng) {
  const double r1 = u.rot1_rad * u.rot1_rad, r2 = u.rot2_rad * u.rot2_rad,
               t = u.trans_m * u.trans_m;
  // Thrun et al., sample_motion_model_odometry; variances as M of docs/design.md "Motion model".
  const double sd_rot1 = std::sqrt(noise.a1 * r1 + noise.a2 * t);
  const double sd_trans = std::sqrt(noise.a3 * t + noise.a4 * (r1 + r2));
  const double sd_rot2 = std::sqrt(noise.a1 * r2 + noise.a2 * t);
  OdometryIncrement out;
  out.rot1_rad = u.rot1_rad + sd_rot1 * StandardNormal(rng);
  out.trans_m = u.trans_m + sd_trans * StandardNormal(rng);
  out.rot2_rad = u.rot2_rad + sd_rot2 * StandardNormal(rng);
  return out;
}

}  // namespace omnicml
