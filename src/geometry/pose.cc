#include "omnicml/geometry/pose.h"

#include <cmath>

#include "omnicml/common/common.h"

namespace omnicml {

Pose2 MakePose(double x_m, double y_m, double phi_rad) {
  return Pose2(x_m, y_m, WrapAngle(phi_rad));
}

Eigen::Vector3d PoseDifference(const Pose2& a, const Pose2& b) {
  return Eigen::Vector3d(a.x() - b.x(), a.y() - b.y(), WrapAngle(a.z() - b.z()));
}

Pose2 Compose(const Pose2& a, const Pose2& b) {
  const double c = std::cos(a.z()), s = std::sin(a.z());
  return MakePose(a.x() + c * b.x() - s * b.y(), a.y() + s * b.x() + c * b.y(), a.z() + b.z());
}

Pose2 Between(const Pose2& a, const Pose2& b) {
  const double c = std::cos(a.z()), s = std::sin(a.z());
  const double dx = b.x() - a.x(), dy = b.y() - a.y();
  return MakePose(c * dx + s * dy, -s * dx + c * dy, b.z() - a.z());
}

OdometryIncrement ComputeIncrement(const Pose2& odom_T_prev, const Pose2& odom_T_curr) {
  OdometryIncrement u;
  const double dx = odom_T_curr.x() - odom_T_prev.x();
  const double dy = odom_T_curr.y() - odom_T_prev.y();
  u.trans_m = std::hypot(dx, dy);
  const double dphi = WrapAngle(odom_T_curr.z() - odom_T_prev.z());
  if (u.trans_m < 1e-9) {
    u.rot1_rad = 0.0;
    u.rot2_rad = dphi;
  } else {
    u.rot1_rad = WrapAngle(std::atan2(dy, dx) - odom_T_prev.z());
    if (std::abs(u.rot1_rad) > kPi / 2) {
      // Driving backwards: a negative translation keeps rot1 small, so the noise model
      // does not mistake reversing for a half turn.
      u.trans_m = -u.trans_m;
      u.rot1_rad = WrapAngle(u.rot1_rad - kPi);
    }
    u.rot2_rad = WrapAngle(dphi - u.rot1_rad);
  }
  return u;
}

Pose2 ApplyIncrement(const Pose2& pose, const OdometryIncrement& u) {
  const double heading = pose.z() + u.rot1_rad;
  return MakePose(pose.x() + u.trans_m * std::cos(heading),
                  pose.y() + u.trans_m * std::sin(heading), heading + u.rot2_rad);
}

}  // namespace omnicml
