// Binary encoding of poses and 3x3 matrices in the engine file (docs/map_format.md: `Pose`
// = 3 f64 x, y, phi; `Mat3` = 9 f64 row-major), shared by the environment model's
// section (mapping/environment_model_io.cc), engine_io.cc and the pose graph's section
// (pose_graph.cc). Doubles bit for bit.
#ifndef OMNICML_GEOMETRY_POSE_IO_H_
#define OMNICML_GEOMETRY_POSE_IO_H_

#include <Eigen/Core>

#include "omnicml/common/binary_io.h"
#include "omnicml/geometry/pose.h"

namespace omnicml::internal {

inline void WritePose(BinaryWriter& out, const Pose2& p) {
  for (int i = 0; i < 3; ++i) out.Write<double>(p[i]);
}
// `what` names the field in the error of a short input.
inline Pose2 ReadPose(BinaryReader& in, const char* what) {
  Pose2 p;
  for (int i = 0; i < 3; ++i) p[i] = in.Read<double>(what);
  return p;
}
inline void WriteMatrix3(BinaryWriter& out, const Eigen::Matrix3d& m) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) out.Write<double>(m(r, c));
  }
}
inline Eigen::Matrix3d ReadMatrix3(BinaryReader& in, const char* what) {
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m(r, c) = in.Read<double>(what);
  }
  return m;
}

}  // namespace omnicml::internal

#endif  // OMNICML_GEOMETRY_POSE_IO_H_
