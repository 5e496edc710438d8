#include "omnicml/tracking/fixed_lag_smoother.h"

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "omnicml/common/common.h"
#include "omnicml/tracking/tracker.h"

namespace omnicml {

Gaussian SmoothFirstOfChain(const std::vector<Gaussian>& filtered,
                            const std::vector<OdometryIncrement>& increments,
                            const MotionNoise& noise) {
  if (filtered.empty()) throw Error("SmoothFirstOfChain: no filtered estimate");
  if (increments.size() + 1 != filtered.size()) {
    throw Error(StrCat("SmoothFirstOfChain: ", filtered.size(), " estimates need ",
                       filtered.size() - 1, " increments, got ", increments.size()));
  }
  Pose2 mean = filtered.back().mean;  // x_k+1|N
  Eigen::Matrix3d cov = filtered.back().covariance;
  for (std::size_t k = filtered.size() - 1; k-- > 0;) {
    const Gaussian& f = filtered[k];
    const Gaussian predicted = Propagate({f}, increments[k], noise).front();  // x_k+1|k
    const Eigen::Matrix3d g = MotionJacobianState(f.mean, increments[k]);
    const Eigen::LLT<Eigen::Matrix3d> llt(predicted.covariance);
    if (llt.info() != Eigen::Success)
      throw Error(StrCat("SmoothFirstOfChain: predicted covariance ", k + 1, " is not SPD"));
    // C_k = P_k|k G^T P_k+1|k^-1 (P symmetric: C^T = P_k+1|k^-1 G P_k|k).
    const Eigen::Matrix3d gain = llt.solve(g * f.covariance).transpose();
    const Eigen::Vector3d step = gain * PoseDifference(mean, predicted.mean);
    mean = MakePose(f.mean.x() + step.x(), f.mean.y() + step.y(), f.mean.z() + step.z());
    cov = RepairCovariance(f.covariance + gain * (cov - predicted.covariance) * gain.transpose(),
                           1e-12, "SmoothFirstOfChain: smoothed covariance");
  }
  Gaussian out;
  out.mean = mean;
  out.covariance = cov;
  out.weight = 1.0;
  return out;
}

}  // namespace omnicml
