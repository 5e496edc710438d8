// Fuzzes the engine/map file decoder (engine/engine_io.h DecodeEngine).
//
// A CRC-32 guards the payload, so plain mutation rarely gets past it. The first input
// byte therefore picks the mode: odd -> the rest is a payload, wrapped here in a valid
// header (magic, format version, length) and checksum, which exercises the payload
// parser; even -> the rest is the whole file, as on disk (header and checksum checks).
#include <vector>

#include "fuzz_util.h"
#include "omnicml/common/binary_io.h"
#include "omnicml/engine/engine_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  std::vector<std::uint8_t> bytes;
  if ((data[0] & 1) != 0) {
    const std::vector<std::uint8_t> payload(data + 1, data + size);
    omnicml::BinaryWriter out;
    for (char c : omnicml::kEngineMagic) out.Write<std::uint8_t>(static_cast<std::uint8_t>(c));
    out.Write<std::uint32_t>(omnicml::kEngineFormatVersion);
    out.Write<std::uint64_t>(payload.size());
    bytes = out.bytes();
    bytes.insert(bytes.end(), payload.begin(), payload.end());
    omnicml::BinaryWriter crc;
    crc.Write<std::uint32_t>(omnicml::Crc32(payload));
    bytes.insert(bytes.end(), crc.bytes().begin(), crc.bytes().end());
  } else {
    bytes.assign(data + 1, data + size);
  }
  return omnicml::fuzz::ExpectOnlyErrors([&] { (void)omnicml::DecodeEngine(bytes, "fuzz.omap"); });
}
