#include "omnicml/common/common.h"

#include <cmath>

namespace omnicml {
namespace internal {

void FailCheck(const char* file, int line, const char* expr, const std::string& msg) {
  std::string what = StrCat(file, ":", line, ": check failed: ", expr);
  if (!msg.empty()) what += " (" + msg + ")";
  throw InternalError(what);
}

}  // namespace internal

double WrapAngle(double angle_rad) {
  double a = std::fmod(angle_rad, kTwoPi);  // in (-2pi, 2pi)
  if (a <= -kPi) a += kTwoPi;
  if (a > kPi) a -= kTwoPi;
  return a;
}

}  // namespace omnicml
