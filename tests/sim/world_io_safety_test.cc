// World file input safety: only regular files of bounded size are read.
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;

std::string LoadWorldError(const fs::path& path) {
  try {
    LoadWorld(path.string());
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// A world path that is a FIFO, a link to /dev/zero, a directory or too large is an
// Error naming it (no hang, no unbounded read); a missing one lists the built-ins.
TEST(WorldIoSafety, OnlyBoundedRegularFiles) {
  const fs::path dir = fs::path(OMNICML_BINARY_DIR) / "test_output" / "world_io_safety";
  fs::remove_all(dir);
  fs::create_directories(dir);
  const fs::path fifo = dir / "world.yaml";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_THAT(LoadWorldError(fifo), HasSubstr("FIFO"));
  const fs::path zero = dir / "zero.yaml";
  fs::create_symlink("/dev/zero", zero);
  EXPECT_THAT(LoadWorldError(zero), HasSubstr("character device"));
  EXPECT_THAT(LoadWorldError(dir), HasSubstr("directory"));
  const fs::path big = dir / "big.yaml";
  {
    std::ofstream out(big, std::ios::binary);
    out.seekp(static_cast<std::streamoff>(kMaxTextFileBytes));
    out.put('\n');  // sparse: one byte over the limit
  }
  const std::string message = LoadWorldError(big);
  EXPECT_THAT(message, HasSubstr(big.string()));
  EXPECT_THAT(message, HasSubstr("too large"));
  EXPECT_THAT(LoadWorldError(dir / "missing.yaml"), HasSubstr("built-in"));
}

}  // namespace
}  // namespace omnicml
