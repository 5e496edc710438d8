#include "omnicml/common/binary_io.h"

#include <array>

namespace omnicml {
namespace {

// Table of the reflected CRC-32 polynomial 0xEDB88320, built at compile time.
constexpr std::array<std::uint32_t, 256> MakeCrcTable() {
  std::array<std::uint32_t, 256> table{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? (0xEDB88320u ^ (c >> 1)) : (c >> 1);
    table[i] = c;
  }
  return table;
}
constexpr std::array<std::uint32_t, 256> kCrcTable = MakeCrcTable();

}  // namespace

std::uint32_t Crc32(std::span<const std::uint8_t> bytes, std::uint32_t previous) {
  std::uint32_t c = previous ^ 0xFFFFFFFFu;
  for (const std::uint8_t b : bytes) c = kCrcTable[(c ^ b) & 0xFFu] ^ (c >> 8);
  return c ^ 0xFFFFFFFFu;
}

void BinaryWriter::WriteString(std::string_view s) {
  Write<std::uint64_t>(s.size());
  bytes_.insert(bytes_.end(), s.begin(), s.end());
}

void BinaryWriter::WriteBytes(std::span<const std::uint8_t> bytes) {
  bytes_.insert(bytes_.end(), bytes.begin(), bytes.end());
}

std::vector<std::uint8_t> BinaryWriter::Release() {
  std::vector<std::uint8_t> out = std::move(bytes_);
  bytes_.clear();
  return out;
}

BinaryReader::BinaryReader(std::span<const std::uint8_t> bytes, std::string source)
    : data_(bytes.data()), size_(bytes.size()), source_(std::move(source)) {}

void BinaryReader::Require(std::size_t n, const char* what) const {
  if (n > size_ - pos_) {
    throw Error(StrCat(source_, ": truncated at byte ", pos_, " reading ", what, " (need ", n,
                       " bytes, ", size_ - pos_, " left)"));
  }
}

std::string BinaryReader::ReadString(const char* what) {
  const std::size_t n = ReadCount(what, 1);
  std::string s(reinterpret_cast<const char*>(data_ + pos_), n);
  pos_ += n;
  return s;
}

std::size_t BinaryReader::ReadCount(const char* what, std::size_t min_element_bytes) {
  const std::size_t count_pos = pos_;
  const std::uint64_t n = Read<std::uint64_t>(what);
  const std::size_t left = size_ - pos_;
  if (min_element_bytes > 0 && n > left / min_element_bytes) {
    throw Error(StrCat(source_, ": truncated at byte ", count_pos, " reading ", what, " (count ", n,
                       " of ", min_element_bytes, "-byte elements, ", left, " bytes left)"));
  }
  return static_cast<std::size_t>(n);
}

std::vector<std::uint8_t> BinaryReader::ReadBytes(std::size_t n, const char* what) {
  Require(n, what);
  std::vector<std::uint8_t> out(data_ + pos_, data_ + pos_ + n);
  pos_ += n;
  return out;
}

void BinaryReader::Fail(const char* what, const std::string& message) const {
  throw Error(StrCat(source_, ": ", message, " at byte ", pos_, " reading ", what));
}

void BinaryReader::ExpectEnd(const char* what) const {
  if (pos_ != size_) {
    throw Error(StrCat(source_, ": ", size_ - pos_, " unexpected trailing bytes at byte ", pos_,
                       " after ", what));
  }
}

}  // namespace omnicml
