// Ceres residuals on planar poses (x, y, phi) shared by the engine's two pose graphs: the
// reconstruction of a multimodal stretch between anchors (trajectory_reconstruction.cc)
// and the global pose graph (pose_graph.cc). docs/design.md "Unimodality, reconstruction,
// delayed update" and "Global pose graph". Private to src/engine.
#ifndef OMNICML_ENGINE_INTERNAL_POSE_FACTORS_H_
#define OMNICML_ENGINE_INTERNAL_POSE_FACTORS_H_

#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>

#include "omnicml/common/common.h"
#include "omnicml/geometry/pose.h"

namespace omnicml::internal {

// atan2(sin a, cos a): wraps to (-pi, pi] and differentiates cleanly for ceres::Jet.
template <typename T>
T WrapT(const T& a) {
  using std::atan2;
  using std::cos;
  using std::sin;
  return atan2(sin(a), cos(a));
}

// Upper-triangular W with W^T W = sigma^-1 (square-root information). sigma must be
// symmetric positive definite (checked).
inline Eigen::Matrix3d SqrtInformation(const Eigen::Matrix3d& sigma) {
  const Eigen::Matrix3d information = sigma.inverse();
  const Eigen::Matrix3d sym = 0.5 * (information + information.transpose());
  Eigen::LLT<Eigen::Matrix3d> llt(sym);
  OMNICML_CHECK(llt.info() == Eigen::Success) << "pose factor: information matrix not SPD";
  return llt.matrixL().transpose();
}

// Relative-pose factor between nodes a and b (odometry, loop closure):
// r = W (Between(x_a, x_b) - z), angle wrapped.
struct BetweenFactor {
  BetweenFactor(const Pose2& z, const Eigen::Matrix3d& w) : z_(z), w_(w) {}

  template <typename T>
  bool operator()(const T* a, const T* b, T* residual) const {
    using std::cos;
    using std::sin;
    const T dx = b[0] - a[0];
    const T dy = b[1] - a[1];
    const T c = cos(a[2]);
    const T s = sin(a[2]);
    T e[3];
    e[0] = c * dx + s * dy - T(z_[0]);
    e[1] = -s * dx + c * dy - T(z_[1]);
    e[2] = WrapT(b[2] - a[2] - T(z_[2]));
    for (int r = 0; r < 3; ++r) {
      residual[r] = T(w_(r, 0)) * e[0] + T(w_(r, 1)) * e[1] + T(w_(r, 2)) * e[2];
    }
    return true;
  }

  Pose2 z_;
  Eigen::Matrix3d w_;
};

// Prior on one node (anchor, survey pose, known start): r = W (x - mu), angle wrapped.
struct PriorFactor {
  PriorFactor(const Pose2& mu, const Eigen::Matrix3d& w) : mu_(mu), w_(w) {}

  template <typename T>
  bool operator()(const T* x, T* residual) const {
    T e[3];
    e[0] = x[0] - T(mu_[0]);
    e[1] = x[1] - T(mu_[1]);
    e[2] = WrapT(x[2] - T(mu_[2]));
    for (int r = 0; r < 3; ++r) {
      residual[r] = T(w_(r, 0)) * e[0] + T(w_(r, 1)) * e[1] + T(w_(r, 2)) * e[2];
    }
    return true;
  }

  Pose2 mu_;
  Eigen::Matrix3d w_;
};

}  // namespace omnicml::internal

#endif  // OMNICML_ENGINE_INTERNAL_POSE_FACTORS_H_
