// Fuzzes the world YAML reader (sim/world.h ParseWorld) and the world's initial state.
#include "fuzz_util.h"
#include "omnicml/sim/world.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  return omnicml::fuzz::ExpectOnlyErrors([&] {
    const omnicml::World world = omnicml::ParseWorld(text, "fuzz_world.yaml");
    (void)omnicml::InitialWorldState(world);
  });
}
