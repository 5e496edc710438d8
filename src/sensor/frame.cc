#include "omnicml/sensor/frame.h"

#include "omnicml/common/common.h"

namespace omnicml {

std::string ToString(SessionStartMode mode) {
  switch (mode) {
    case SessionStartMode::kKnownPose:
      return "known";
    case SessionStartMode::kContinue:
      return "continue";
    case SessionStartMode::kGlobal:
      return "global";
  }
  return "unknown";
}

SessionStartMode SessionStartModeFromString(const std::string& s) {
  if (s == "known") return SessionStartMode::kKnownPose;
  if (s == "continue") return SessionStartMode::kContinue;
  if (s == "global") return SessionStartMode::kGlobal;
  throw Error(StrCat("unknown session start mode '", s, "' (expected known, continue or global)"));
}

}  // namespace omnicml
