// Fuzzes the image reader (unwrap/omni_unwrapper.h ReadImage): its size limits from the
// PNG/JPEG header, the PNG structure check, decoding, channel and depth checks.
#include "fuzz_util.h"
#include "omnicml/unwrap/omni_unwrapper.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto path = omnicml::fuzz::ScratchDir() / "image.png";
  omnicml::fuzz::WriteBytes(path, data, size);
  return omnicml::fuzz::ExpectOnlyErrors([&] { (void)omnicml::ReadImage(path.string()); });
}
