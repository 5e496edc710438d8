// Shared by the tests that run the built `omnicml` binary (cli_end_to_end_test,
// cli_limits_test, output_safety_test): running a command line and capturing its exit
// code and output, scratch directories, and whole-file reads and writes.
#ifndef OMNICML_TESTS_TESTING_CLI_HELPERS_H_
#define OMNICML_TESTS_TESTING_CLI_HELPERS_H_

#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace omnicml::testing {

// What a command printed (stdout and stderr interleaved) and its exit code (-1 when it
// did not exit normally or could not be started).
struct CommandResult {
  int exit_code = -1;
  std::string output;
};

// Runs `<build dir>/omnicml ARGS 2>&1` through the shell; `args` is shell text (quote
// paths yourself). Requires OMNICML_BINARY_DIR (omnicml_add_test defines it).
inline CommandResult RunOmnicml(const std::string& args) {
  const std::string command = std::string(OMNICML_BINARY_DIR "/omnicml ") + args + " 2>&1";
  CommandResult result;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (pipe == nullptr) return result;
  char buf[4096];
  while (std::fgets(buf, sizeof buf, pipe) != nullptr) result.output += buf;
  const int status = ::pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

// A fresh, empty directory `name` under the system's temporary directory, suffixed with
// this process's id so parallel test programs never share it.
inline std::filesystem::path FreshTempDir(const std::string& name) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

// A fresh, empty directory `name` under the build tree's test_scratch/`group`/.
inline std::filesystem::path FreshScratchDir(const std::string& group, const std::string& name) {
  const std::filesystem::path dir =
      std::filesystem::path(OMNICML_BINARY_DIR) / "test_scratch" / group / name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

// The whole file as bytes ("" when it cannot be read).
inline std::string Slurp(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Writes `text` to `path` (replacing it), plainly: test fixtures, not outputs.
inline void Spit(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

}  // namespace omnicml::testing

#endif  // OMNICML_TESTS_TESTING_CLI_HELPERS_H_
