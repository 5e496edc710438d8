// Little-endian binary encoding for persistence (the environment model, the engine
// state): a writer that appends plain values to a byte vector and a bounds-checked reader.
//
// Encoding: integers and floating-point values are written as their little-endian bytes
// (floats/doubles bit for bit, so a round trip is exact, NaN payloads included); bool is
// one byte 0/1; strings and vectors are a u64 element count followed by the elements.
// The bytes do not depend on the host's byte order.
//
// BinaryReader never reads past its buffer: a read that would throws omnicml::Error
// "<source>: truncated at byte N reading <what> (need k bytes, m left)"; counts that
// cannot fit into the rest of the buffer are reported the same way before anything is
// allocated, so a corrupted length cannot make the reader allocate gigabytes.
//
// Both classes are plain values, thread-compatible (one thread per object).
#ifndef OMNICML_COMMON_BINARY_IO_H_
#define OMNICML_COMMON_BINARY_IO_H_

#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "omnicml/common/common.h"

namespace omnicml {

// CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320, initial value and final xor
// 0xFFFFFFFF: the checksum of zlib and PNG). Crc32 of "123456789" is 0xCBF43926.
// `previous` continues a running checksum over several pieces:
// Crc32(b, Crc32(a)) == Crc32(a followed by b).
std::uint32_t Crc32(std::span<const std::uint8_t> bytes, std::uint32_t previous = 0);

class BinaryWriter {
 public:
  BinaryWriter() = default;

  // Any integer, bool, float or double, little-endian.
  template <typename T>
  void Write(T value) {
    static_assert(std::is_arithmetic_v<T> || std::is_enum_v<T>,
                  "Write takes arithmetic or enum values");
    if constexpr (std::is_enum_v<T>) {
      Write(static_cast<std::underlying_type_t<T>>(value));
    } else if constexpr (std::is_same_v<T, bool>) {
      bytes_.push_back(value ? 1 : 0);
    } else if constexpr (std::is_floating_point_v<T>) {
      using U = std::conditional_t<sizeof(T) == 4, std::uint32_t, std::uint64_t>;
      Write(std::bit_cast<U>(value));
    } else {
      using U = std::make_unsigned_t<T>;
      U u = static_cast<U>(value);
      for (std::size_t i = 0; i < sizeof(T); ++i) {
        bytes_.push_back(static_cast<std::uint8_t>(u & 0xFF));
        if constexpr (sizeof(T) > 1) u = static_cast<U>(u >> 8);
      }
    }
  }

  // u64 length followed by the characters (no terminator).
  void WriteString(std::string_view s);

  // u64 count followed by the elements.
  template <typename T>
  void WriteVector(std::span<const T> values) {
    Write<std::uint64_t>(values.size());
    for (const T& v : values) Write<T>(v);
  }
  template <typename T>
  void WriteVector(const std::vector<T>& values) {
    WriteVector(std::span<const T>(values));
  }

  // Raw bytes, no length prefix.
  void WriteBytes(std::span<const std::uint8_t> bytes);

  std::size_t size() const { return bytes_.size(); }
  const std::vector<std::uint8_t>& bytes() const { return bytes_; }
  // Moves the bytes out; the writer is empty afterwards.
  std::vector<std::uint8_t> Release();

 private:
  std::vector<std::uint8_t> bytes_;
};

class BinaryReader {
 public:
  // `bytes` must outlive the reader. `source` names the buffer in error messages
  // (e.g. a file path).
  explicit BinaryReader(std::span<const std::uint8_t> bytes, std::string source = "buffer");

  // Reads one value written by BinaryWriter::Write<T>. `what` names it in errors.
  template <typename T>
  T Read(const char* what) {
    static_assert(std::is_arithmetic_v<T> || std::is_enum_v<T>,
                  "Read returns arithmetic or enum values");
    if constexpr (std::is_enum_v<T>) {
      return static_cast<T>(Read<std::underlying_type_t<T>>(what));
    } else if constexpr (std::is_same_v<T, bool>) {
      const std::uint8_t b = Read<std::uint8_t>(what);
      if (b > 1) Fail(what, "invalid bool value");
      return b == 1;
    } else if constexpr (std::is_floating_point_v<T>) {
      using U = std::conditional_t<sizeof(T) == 4, std::uint32_t, std::uint64_t>;
      return std::bit_cast<T>(Read<U>(what));
    } else {
      Require(sizeof(T), what);
      using U = std::make_unsigned_t<T>;
      U u = 0;
      for (std::size_t i = 0; i < sizeof(T); ++i)
        u |= static_cast<U>(static_cast<U>(data_[pos_ + i]) << (8 * i));
      pos_ += sizeof(T);
      return static_cast<T>(u);
    }
  }

  std::string ReadString(const char* what);

  template <typename T>
  std::vector<T> ReadVector(const char* what) {
    const std::size_t n = ReadCount(what, std::is_same_v<T, bool> ? 1 : sizeof(T));
    std::vector<T> out;
    out.reserve(n);
    for (std::size_t i = 0; i < n; ++i) out.push_back(Read<T>(what));
    return out;
  }

  // Reads a u64 element count and checks that `count * min_element_bytes` bytes remain
  // (throws the truncation Error otherwise). Use before reading `count` records.
  std::size_t ReadCount(const char* what, std::size_t min_element_bytes);

  // Raw bytes, no length prefix.
  std::vector<std::uint8_t> ReadBytes(std::size_t n, const char* what);

  // Throws Error "<source>: <message> at byte N reading <what>" (for malformed content
  // found by the caller, e.g. a bad enum value or magic number).
  [[noreturn]] void Fail(const char* what, const std::string& message) const;

  // Throws Error unless every byte has been read.
  void ExpectEnd(const char* what) const;

  std::size_t position() const { return pos_; }
  std::size_t remaining() const { return size_ - pos_; }
  const std::string& source() const { return source_; }

 private:
  // Throws the truncation Error unless n bytes remain.
  void Require(std::size_t n, const char* what) const;

  const std::uint8_t* data_;
  std::size_t size_;
  std::size_t pos_ = 0;
  std::string source_;
};

}  // namespace omnicml

#endif  // OMNICML_COMMON_BINARY_IO_H_
