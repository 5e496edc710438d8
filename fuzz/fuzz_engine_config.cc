// Fuzzes the engine configuration YAML: the common/options.h schema reader of
// CmlEngineOptions (what run/run_config.cc ParseEngineOptionsYaml calls), and a
// dump + re-read of what it accepted (an accepted configuration must load back).
#include "fuzz_util.h"
#include "omnicml/common/options.h"
#include "omnicml/engine/cml_engine.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  omnicml::CmlEngineOptions options;
  try {
    options = omnicml::ParseOptionsYaml<omnicml::CmlEngineOptions>(text, "fuzz.yaml");
  } catch (const omnicml::Error&) {
    return 0;
  }
  // Accepted: its dump must be accepted again and give the same options.
  const std::string dumped = omnicml::OptionsToYaml(options);
  const auto again = omnicml::ParseOptionsYaml<omnicml::CmlEngineOptions>(dumped, "dumped.yaml");
  if (!omnicml::SameOptions(options, again)) __builtin_trap();
  return 0;
}
