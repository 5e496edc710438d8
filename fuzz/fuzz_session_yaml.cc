// Fuzzes the session.yaml reader (logs/log_format.h ReadSessionYaml).
#include "fuzz_util.h"
#include "omnicml/logs/log_format.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = omnicml::fuzz::ScratchDir() / "session.yaml";
  omnicml::fuzz::WriteBytes(path, data, size);
  return omnicml::fuzz::ExpectOnlyErrors([&] { (void)omnicml::ReadSessionYaml(path.string()); });
}
