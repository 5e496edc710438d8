// Planar poses x = (x, y, phi) in metres, metres, radians, and the odometry increment.
//
// A pose is an Eigen::Vector3d; phi is always wrapped to (-pi, pi]. Every difference of
// poses wraps its angle component (PoseDifference) before it enters a distance, a mean
// or a merge. Names carry frames: `map_T_robot` is the robot's pose in the map frame,
// `odom_T_robot` its pose in the odometry frame.
#ifndef OMNICML_GEOMETRY_POSE_H_
#define OMNICML_GEOMETRY_POSE_H_

#include <Eigen/Core>

namespace omnicml {

using Pose2 = Eigen::Vector3d;  // (x_m, y_m, phi_rad)

// Returns (x, y, WrapAngle(phi)).
Pose2 MakePose(double x_m, double y_m, double phi_rad);

// a - b with the angle component wrapped to (-pi, pi].
Eigen::Vector3d PoseDifference(const Pose2& a, const Pose2& b);

// SE(2) composition a * b (b expressed in a's frame).
Pose2 Compose(const Pose2& a, const Pose2& b);

// SE(2) relative pose a^-1 * b: b expressed in a's frame.
Pose2 Between(const Pose2& a, const Pose2& b);

// The odometry increment between two odometry poses, decomposed as in Thrun et al.
// (probabilistic robotics, sample_motion_model_odometry): turn rot1 towards the new
// position, translate trans, turn rot2. Angles in radians, trans in metres. For a pure
// rotation (trans below 1e-9 m) rot1 = 0 and rot2 carries the whole turn. Backward
// motion gives a negative trans with |rot1| <= pi/2.
struct OdometryIncrement {
  double rot1_rad = 0.0;
  double trans_m = 0.0;
  double rot2_rad = 0.0;
};

// Increment that moves odom_T_prev to odom_T_curr.
OdometryIncrement ComputeIncrement(const Pose2& odom_T_prev, const Pose2& odom_T_curr);

// g(mu, u): applies the increment to a pose in any frame (docs/design.md "Motion model").
Pose2 ApplyIncrement(const Pose2& pose, const OdometryIncrement& u);

}  // namespace omnicml

#endif  // OMNICML_GEOMETRY_POSE_H_
