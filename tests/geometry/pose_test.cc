#include "omnicml/geometry/pose.h"

#include <random>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// WrapAngle maps into (-pi, pi] and preserves the angle modulo 2 pi.
TEST(WrapAngle, RangeAndEquivalence) {
  EXPECT_DOUBLE_EQ(WrapAngle(kPi), kPi);
  EXPECT_DOUBLE_EQ(WrapAngle(-kPi), kPi);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-50.0, 50.0);
  for (int i = 0; i < 1000; ++i) {
    const double a = u(rng);
    const double w = WrapAngle(a);
    EXPECT_GT(w, -kPi);
    EXPECT_LE(w, kPi);
    EXPECT_NEAR(std::remainder(a - w, kTwoPi), 0.0, 1e-9);
  }
}

// Between inverts Compose, and the odometry increment reproduces the motion it came from.
TEST(Pose, IncrementRoundTrip) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int i = 0; i < 500; ++i) {
    const Pose2 a = MakePose(u(rng), u(rng), u(rng));
    const Pose2 b = MakePose(u(rng), u(rng), u(rng));
    const Pose2 ab = Between(a, b);
    EXPECT_LT(PoseDifference(Compose(a, ab), b).norm(), 1e-9);
    const OdometryIncrement inc = ComputeIncrement(a, b);
    EXPECT_LE(std::abs(inc.rot1_rad), kPi / 2 + 1e-12);
    EXPECT_LT(PoseDifference(ApplyIncrement(a, inc), b).norm(), 1e-9);
    // The increment is frame-independent: applied to another start it yields the same relative
    // motion.
    const Pose2 c = MakePose(u(rng), u(rng), u(rng));
    EXPECT_LT(PoseDifference(Between(c, ApplyIncrement(c, inc)), ab).norm(), 1e-9);
  }
}

// A failed check throws InternalError naming the file.
TEST(Check, ThrowsWithLocation) {
  try {
    OMNICML_CHECK(1 + 1 == 3) << "arithmetic";
    FAIL() << "no throw";
  } catch (const InternalError& e) {
    EXPECT_NE(std::string(e.what()).find("pose_test.cc"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("arithmetic"), std::string::npos);
  }
}

}  // namespace
}  // namespace omnicml
