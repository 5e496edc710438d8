#include "omnicml/common/binary_io.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace omnicml {
namespace {

// Every value type round-trips bit for bit, including NaN payloads, -0 and extremes.
TEST(BinaryIo, RoundTripIsExact) {
  BinaryWriter w;
  w.Write<std::uint8_t>(0xAB);
  w.Write<std::int32_t>(-123456789);
  w.Write<std::uint64_t>(std::numeric_limits<std::uint64_t>::max());
  w.Write<std::int64_t>(std::numeric_limits<std::int64_t>::min());
  w.Write(true);
  w.Write(-0.0);
  w.Write(std::numeric_limits<double>::quiet_NaN());
  w.Write(1.0f / 3.0f);
  w.Write(std::numeric_limits<double>::denorm_min());
  w.WriteString("hello\0world");
  w.WriteString(std::string("a\0b", 3));
  w.WriteVector(std::vector<float>{1.5f, -2.25f, 1e-30f});

  BinaryReader r(w.bytes(), "test");
  EXPECT_EQ(r.Read<std::uint8_t>("u8"), 0xAB);
  EXPECT_EQ(r.Read<std::int32_t>("i32"), -123456789);
  EXPECT_EQ(r.Read<std::uint64_t>("u64"), std::numeric_limits<std::uint64_t>::max());
  EXPECT_EQ(r.Read<std::int64_t>("i64"), std::numeric_limits<std::int64_t>::min());
  EXPECT_TRUE(r.Read<bool>("bool"));
  const double neg_zero = r.Read<double>("neg zero");
  EXPECT_TRUE(std::signbit(neg_zero) && neg_zero == 0.0);
  const double nan = r.Read<double>("nan");
  const double expected_nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(std::memcmp(&nan, &expected_nan, sizeof(double)), 0);
  EXPECT_EQ(r.Read<float>("float"), 1.0f / 3.0f);
  EXPECT_EQ(r.Read<double>("denorm"), std::numeric_limits<double>::denorm_min());
  EXPECT_EQ(r.ReadString("s1"), "hello");
  EXPECT_EQ(r.ReadString("s2"), std::string("a\0b", 3));
  EXPECT_EQ(r.ReadVector<float>("floats"), (std::vector<float>{1.5f, -2.25f, 1e-30f}));
  EXPECT_EQ(r.remaining(), 0u);
  EXPECT_NO_THROW(r.ExpectEnd("all"));
}

// Integers are little-endian whatever the host.
TEST(BinaryIo, LittleEndianLayout) {
  BinaryWriter w;
  w.Write<std::uint32_t>(0x11223344u);
  ASSERT_EQ(w.size(), 4u);
  EXPECT_EQ(w.bytes()[0], 0x44);
  EXPECT_EQ(w.bytes()[3], 0x11);
}

// Every truncation of a buffer throws Error naming the byte and the field, never reads past the
// end.
TEST(BinaryIo, TruncationThrowsWithPosition) {
  BinaryWriter w;
  w.Write<std::uint32_t>(7);
  w.WriteString("abcdef");
  w.Write(2.5);
  const std::vector<std::uint8_t> bytes = w.bytes();
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    std::vector<std::uint8_t> cut(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(n));
    BinaryReader r(cut, "cut");
    EXPECT_THROW(
        {
          r.Read<std::uint32_t>("count");
          r.ReadString("name");
          r.Read<double>("value");
        },
        Error)
        << "prefix " << n;
  }
  std::vector<std::uint8_t> cut(bytes.begin(), bytes.begin() + 6);
  BinaryReader r(cut, "file.bin");
  r.Read<std::uint32_t>("count");
  try {
    r.ReadString("name");
    FAIL() << "no throw";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("file.bin"), std::string::npos) << msg;
    EXPECT_NE(msg.find("truncated at byte 4"), std::string::npos) << msg;
    EXPECT_NE(msg.find("name"), std::string::npos) << msg;
  }
}

// A corrupted huge element count is rejected before any allocation.
TEST(BinaryIo, HugeCountRejected) {
  BinaryWriter w;
  w.Write<std::uint64_t>(std::numeric_limits<std::uint64_t>::max() / 2);
  w.Write<float>(1.0f);
  BinaryReader r(w.bytes());
  EXPECT_THROW(r.ReadVector<double>("values"), Error);
}

// Invalid bool bytes and trailing bytes are reported.
TEST(BinaryIo, MalformedContent) {
  const std::vector<std::uint8_t> bytes = {2, 0};
  BinaryReader r(bytes);
  EXPECT_THROW(r.Read<bool>("flag"), Error);
  BinaryReader r2(bytes);
  r2.Read<std::uint8_t>("x");
  EXPECT_THROW(r2.ExpectEnd("x"), Error);
}

// CRC-32 matches the standard check value and chains over pieces.
TEST(Crc32, StandardCheckValueAndChaining) {
  const std::string s = "123456789";
  const std::span<const std::uint8_t> bytes(reinterpret_cast<const std::uint8_t*>(s.data()),
                                            s.size());
  EXPECT_EQ(Crc32(bytes), 0xCBF43926u);
  EXPECT_EQ(Crc32(bytes.subspan(4), Crc32(bytes.first(4))), 0xCBF43926u);
  EXPECT_EQ(Crc32({}), 0u);
  // Any single flipped bit changes the checksum.
  std::vector<std::uint8_t> copy(bytes.begin(), bytes.end());
  for (std::size_t i = 0; i < copy.size() * 8; ++i) {
    copy[i / 8] ^= static_cast<std::uint8_t>(1u << (i % 8));
    EXPECT_NE(Crc32(copy), 0xCBF43926u);
    copy[i / 8] ^= static_cast<std::uint8_t>(1u << (i % 8));
  }
}

}  // namespace
}  // namespace omnicml
