// Shared helpers of the libFuzzer harnesses (fuzz/README.md).
//
// Every harness feeds the fuzzer's bytes to one parser. An omnicml::Error is the expected
// answer to bad input and is swallowed; anything else -- another exception (it escapes
// LLVMFuzzerTestOneInput and aborts), a crash, an ASan/UBSan report, a timeout or an
// allocation above -rss_limit_mb -- is a finding.
//
// Parsers that only take a path get the bytes through a file in a per-process scratch
// directory (under $TMPDIR, /dev/shm preferred), removed when the process exits normally.
#ifndef OMNICML_FUZZ_FUZZ_UTIL_H_
#define OMNICML_FUZZ_FUZZ_UTIL_H_

#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include "omnicml/common/common.h"

namespace omnicml::fuzz {

// The scratch directory of this process (created on first use).
inline const std::filesystem::path& ScratchDir() {
  static const std::filesystem::path dir = [] {
    std::filesystem::path base = "/dev/shm";
    if (const char* t = std::getenv("TMPDIR"); t != nullptr && *t != '\0') base = t;
    std::error_code ec;
    if (!std::filesystem::is_directory(base, ec)) base = std::filesystem::temp_directory_path();
    // Remove the scratch directories of fuzzer processes that died (a finding aborts
    // before the atexit handler below runs).
    std::error_code list_ec;
    for (const auto& e : std::filesystem::directory_iterator(base, list_ec)) {
      const std::string name = e.path().filename().string();
      if (name.rfind("omnicml-fuzz-", 0) != 0) continue;
      const long pid = std::strtol(name.c_str() + 13, nullptr, 10);
      if (pid > 0 && ::kill(static_cast<pid_t>(pid), 0) != 0 && errno == ESRCH) {
        std::filesystem::remove_all(e.path(), ec);
      }
    }
    std::filesystem::path d = base / ("omnicml-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    std::atexit([] {
      std::error_code ignored;
      std::filesystem::remove_all(ScratchDir(), ignored);
    });
    return d;
  }();
  return dir;
}

// Writes `bytes` to `path` (truncating). Aborts on failure: that is the harness's fault.
inline void WriteBytes(const std::filesystem::path& path, const std::uint8_t* data,
                       std::size_t size) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  out.close();
  if (!out) std::abort();
}

inline void WriteText(const std::filesystem::path& path, std::string_view text) {
  WriteBytes(path, reinterpret_cast<const std::uint8_t*>(text.data()), text.size());
}

// Runs `f`; an omnicml::Error (bad input, reported as such) is the expected outcome.
template <typename F>
int ExpectOnlyErrors(F&& f) {
  try {
    f();
  } catch (const omnicml::Error&) {
  }
  return 0;
}

}  // namespace omnicml::fuzz

#endif  // OMNICML_FUZZ_FUZZ_UTIL_H_
