// Fuzzes the AntWorld route CSV reader (logs/antworld.h ReadAntWorldCsv).
#include "fuzz_util.h"
#include "omnicml/logs/antworld.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = omnicml::fuzz::ScratchDir() / "route.csv";
  omnicml::fuzz::WriteBytes(path, data, size);
  return omnicml::fuzz::ExpectOnlyErrors([&] { (void)omnicml::ReadAntWorldCsv(path.string()); });
}
