// Tests of the motion noise stated per metre of travel (CmlEngineOptions::
// reference_frame_step_m): the scale restores the variance per metre that Thrun's
// per-increment model loses at denser frames, its half-octave rounding, and the median
// odometry step it is measured from.
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Core>

#include "omnicml/common/common.h"
#include "omnicml/engine/calibration.h"
#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {
namespace {

// The EKF prediction of Propagate (tracker.h) along an arc of `length_m` and curvature
// `curvature` (1/m), in increments of `step_m`, from an exact start.
Eigen::Matrix3d PropagatedCovariance(double length_m, double curvature, double step_m,
                                     const MotionNoise& noise) {
  const int steps = static_cast<int>(std::lround(length_m / step_m));
  Pose2 truth = Pose2::Zero();
  Pose2 mu = Pose2::Zero();
  Eigen::Matrix3d c = Eigen::Matrix3d::Zero();
  for (int i = 0; i < steps; ++i) {
    const double turn = curvature * step_m;
    const Pose2 next(truth.x() + step_m * std::cos(truth.z() + turn / 2),
                     truth.y() + step_m * std::sin(truth.z() + turn / 2), truth.z() + turn);
    const OdometryIncrement u = ComputeIncrement(truth, next);
    const Eigen::Matrix3d g = MotionJacobianState(mu, u);
    const Eigen::Matrix3d v = MotionJacobianControl(mu, u);
    c = g * c * g.transpose() + v * MotionNoiseCovariance(u, noise) * v.transpose();
    mu = ApplyIncrement(mu, u);
    truth = next;
  }
  return c;
}

MotionNoise Scaled(MotionNoise m, double k) {
  m.a1 *= k;
  m.a2 *= k;
  m.a3 *= k;
  m.a4 *= k;
  return m;
}

TEST(FrameStep, ScaledNoiseKeepsTheVariancePerMetre) {
  const MotionNoise noise;  // the defaults, stated for frames 0.2 m apart
  for (const double curvature : {0.0, 0.5}) {
    SCOPED_TRACE(StrCat("curvature ", curvature));
    const Eigen::Matrix3d reference = PropagatedCovariance(6.0, curvature, 0.2, noise);
    const double k = FrameStepScale(0.2, 0.05);
    ASSERT_EQ(k, 4.0);
    const Eigen::Matrix3d dense = PropagatedCovariance(6.0, curvature, 0.05, noise);
    const Eigen::Matrix3d scaled = PropagatedCovariance(6.0, curvature, 0.05, Scaled(noise, k));
    // Per increment a trans^2: four times the frames of a quarter the length carry a
    // quarter of the variance unless the a's are scaled by four.
    EXPECT_LT(dense.trace(), 0.35 * reference.trace());
    // Scaled, the covariance after the same path is the reference's: exactly along a
    // straight path (variances add), to within the discretisation of the heading's
    // effect on the position along a turn.
    EXPECT_NEAR(scaled(2, 2), reference(2, 2), 1e-12 + 0.02 * reference(2, 2));
    EXPECT_LT((scaled - reference).norm(), 0.1 * reference.norm());
    if (curvature == 0.0) {
      EXPECT_NEAR(scaled(0, 0), reference(0, 0), 1e-12);
    }
  }
}

TEST(FrameStep, ScaleRoundsToAHalfOctave) {
  EXPECT_EQ(FrameStepScale(0.2, 0.199), 1.0);  // the simulator's frames
  EXPECT_EQ(FrameStepScale(0.2, 0.17), 1.0);
  EXPECT_EQ(FrameStepScale(0.2, 0.23), 1.0);
  EXPECT_EQ(FrameStepScale(0.2, 0.1), 2.0);
  EXPECT_EQ(FrameStepScale(0.2, 0.0496), 4.0);
  EXPECT_DOUBLE_EQ(FrameStepScale(0.2, 0.0099), std::exp2(4.5));  // AntWorld
  EXPECT_EQ(FrameStepScale(0.2, 0.4), 0.5);                       // sparser frames: less per frame
  EXPECT_DOUBLE_EQ(FrameStepScale(0.2, 0.14), std::sqrt(2.0));
  EXPECT_EQ(FrameStepScale(0.0, 0.05), 1.0);  // off
  EXPECT_EQ(FrameStepScale(0.2, 0.0), 1.0);   // not measured
}

// Frames from a list of (session, odometry pose).
class PoseListSource : public FrameSource {
 public:
  explicit PoseListSource(std::vector<std::pair<int, Pose2>> frames) : frames_(std::move(frames)) {
    for (const auto& f : frames_) sessions_.resize(static_cast<std::size_t>(f.first) + 1);
  }
  int NumSessions() const override { return static_cast<int>(sessions_.size()); }
  const SessionInfo& Session(int index) const override {
    return sessions_[static_cast<std::size_t>(index)];
  }
  bool Next(Frame* frame) override {
    if (next_ >= frames_.size()) return false;
    frame->session_index = frames_[next_].first;
    frame->odom_T_robot = frames_[next_].second;
    frame->global_index = static_cast<std::int64_t>(next_);
    ++next_;
    return true;
  }

 private:
  std::vector<std::pair<int, Pose2>> frames_;
  std::vector<SessionInfo> sessions_;
  std::size_t next_ = 0;
};

TEST(FrameStep, MedianOdometryStepCountsMovingFramesOfTheFirstSession) {
  std::vector<std::pair<int, Pose2>> frames;
  // Parked for 20 frames (odometry jitter of 0.1 mm), turning on the spot for 5, then
  // 7 steps of 0.05 m and 2 of 0.3 m; the second session drives 1 m steps.
  for (int i = 0; i < 20; ++i) frames.push_back({0, Pose2(1e-4 * (i % 2), 0, 0)});
  for (int i = 0; i < 5; ++i) frames.push_back({0, Pose2(0, 0, 0.3 * i)});
  double x = 0;
  for (int i = 0; i < 7; ++i) frames.push_back({0, Pose2(x += 0.05, 0, 1.2)});
  for (int i = 0; i < 2; ++i) frames.push_back({0, Pose2(x += 0.3, 0, 1.2)});
  for (int i = 0; i < 10; ++i) frames.push_back({1, Pose2(1.0 * i, 0, 0)});
  {
    PoseListSource source(frames);
    EXPECT_DOUBLE_EQ(MedianOdometryStep(source, 1000, 0.002), 0.05);
  }
  {
    PoseListSource parked(frames);  // only the parked and turning frames are read
    EXPECT_EQ(MedianOdometryStep(parked, 25, 0.002), 0.0);
  }
  {
    PoseListSource jitter(frames);  // a threshold below the jitter counts it as motion
    EXPECT_LT(MedianOdometryStep(jitter, 1000, 1e-5), 0.01);
  }
  PoseListSource bad(frames);
  EXPECT_THROW(MedianOdometryStep(bad, 1, 0.002), Error);
}

}  // namespace
}  // namespace omnicml
