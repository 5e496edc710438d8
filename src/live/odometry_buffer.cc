#include "omnicml/live/odometry_buffer.h"

#include <cmath>

#include "omnicml/common/common.h"

namespace omnicml {

Pose2 InterpolatePose(double ta_s, const Pose2& a, double tb_s, const Pose2& b, double t_s) {
  if (t_s == ta_s) return a;
  if (t_s == tb_s) return b;
  const double s = (t_s - ta_s) / (tb_s - ta_s);
  const Eigen::Vector3d d = PoseDifference(b, a);
  return MakePose(a.x() + s * d.x(), a.y() + s * d.y(), a.z() + s * d.z());
}

bool OdometryBuffer::Add(double stamp_s, const Pose2& odom_T_robot) {
  if (!std::isfinite(stamp_s) || !odom_T_robot.allFinite()) return false;
  if (!samples_.empty() && stamp_s <= samples_.back().first) return false;
  samples_.emplace_back(stamp_s, odom_T_robot);
  while (samples_.size() > 2 && samples_.front().first < stamp_s - history_s_) samples_.pop_front();
  return true;
}

std::optional<Pose2> OdometryBuffer::At(double stamp_s) const {
  if (samples_.empty() || stamp_s < samples_.front().first || stamp_s > samples_.back().first)
    return std::nullopt;
  // The first sample at or after stamp_s (binary search over increasing stamps).
  std::size_t lo = 0, hi = samples_.size() - 1;
  while (lo < hi) {
    const std::size_t mid = (lo + hi) / 2;
    if (samples_[mid].first < stamp_s)
      lo = mid + 1;
    else
      hi = mid;
  }
  if (samples_[lo].first == stamp_s || lo == 0) return samples_[lo].second;
  const auto& [ta, a] = samples_[lo - 1];
  const auto& [tb, b] = samples_[lo];
  return InterpolatePose(ta, a, tb, b, stamp_s);
}

std::optional<std::pair<double, Pose2>> OdometryBuffer::Newest() const {
  if (samples_.empty()) return std::nullopt;
  return samples_.back();
}

}  // namespace omnicml
