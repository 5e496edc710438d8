// The built-in world files, compiled into the library by cmake/modules/sim.cmake (the
// definition is generated into the build tree from datasets/worlds/*.yaml). Private.
#ifndef OMNICML_SIM_INTERNAL_SIM_BUILTIN_WORLDS_H_
#define OMNICML_SIM_INTERNAL_SIM_BUILTIN_WORLDS_H_

#include <vector>

namespace omnicml::internal {

struct BuiltinWorldText {
  const char* name;  // file name without .yaml
  const char* text;  // the YAML text
};

// In name order.
const std::vector<BuiltinWorldText>& BuiltinWorldTexts();

}  // namespace omnicml::internal

#endif  // OMNICML_SIM_INTERNAL_SIM_BUILTIN_WORLDS_H_
