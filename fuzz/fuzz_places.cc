// Fuzzes the places YAML reader of the topological baseline (ParseAdjacencyMap) and the
// dump + re-read of an accepted map.
#include "fuzz_util.h"
#include "omnicml/baselines/topo/topological.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  return omnicml::fuzz::ExpectOnlyErrors([&] {
    const omnicml::AdjacencyMap map = omnicml::ParseAdjacencyMap(text, "fuzz_places.yaml");
    (void)omnicml::ParseAdjacencyMap(omnicml::AdjacencyMapYaml(map), "dumped.yaml");
  });
}
