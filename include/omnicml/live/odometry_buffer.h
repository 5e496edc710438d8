// A short history of odometry poses odom_T_robot, interpolated to the stamps of camera
// images. Shared by the live engine (odometry and images arrive on separate topics) and
// the rosbag importer (odometry recorded at its own rate).
//
// Interpolation between the two samples around a stamp: x and y linearly, phi along the
// shorter arc (the angle difference is wrapped to (-pi, pi] before it is scaled), so a
// stamp equal to a sample's stamp returns that sample bit for bit.
//
// Thread-safety: thread-compatible.
#ifndef OMNICML_LIVE_ODOMETRY_BUFFER_H_
#define OMNICML_LIVE_ODOMETRY_BUFFER_H_

#include <deque>
#include <optional>
#include <utility>

#include "omnicml/geometry/pose.h"

namespace omnicml {

// The pose between a (at stamp ta_s) and b (at stamp tb_s) at stamp t_s, ta_s < tb_s;
// t_s outside [ta_s, tb_s] extrapolates along the same line.
Pose2 InterpolatePose(double ta_s, const Pose2& a, double tb_s, const Pose2& b, double t_s);

class OdometryBuffer {
 public:
  // history_s: samples older than the newest by more than this are discarded (seconds,
  // > 0; at least two samples are always kept).
  explicit OdometryBuffer(double history_s = 30.0) : history_s_(history_s) {}

  // Appends a sample. Returns false (and keeps the buffer) when stamp_s is not after the
  // newest sample's stamp or a value is not finite.
  bool Add(double stamp_s, const Pose2& odom_T_robot);

  // The pose at stamp_s, interpolated between the samples around it; std::nullopt when
  // stamp_s lies outside [oldest, newest] (nothing to interpolate from).
  std::optional<Pose2> At(double stamp_s) const;
  // True when a sample at or after stamp_s exists (At can answer or stamp_s is too old).
  bool Covers(double stamp_s) const {
    return !samples_.empty() && samples_.back().first >= stamp_s;
  }
  // The newest sample; std::nullopt when empty.
  std::optional<std::pair<double, Pose2>> Newest() const;

  bool empty() const { return samples_.empty(); }
  std::size_t size() const { return samples_.size(); }
  void Clear() { samples_.clear(); }

 private:
  double history_s_;
  std::deque<std::pair<double, Pose2>> samples_;  // (stamp_s, odom_T_robot), increasing stamps
};

}  // namespace omnicml

#endif  // OMNICML_LIVE_ODOMETRY_BUFFER_H_
