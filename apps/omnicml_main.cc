// The omnicml command-line tool: parses flags, calls the library, maps errors to exit
// codes. Subcommands live in apps/cmd_*.cc (see command_registry.h).
#include <stdlib.h>  // setenv

#include <algorithm>
#include <exception>
#include <filesystem>
#include <iostream>
#include <string>

#include <yaml-cpp/exceptions.h>
#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"

namespace {

// Longest error message printed; longer ones (an excerpt of a huge bad input) are cut.
constexpr std::size_t kMaxMessageChars = 1000;

std::string FilesystemMessage(const std::filesystem::filesystem_error& e) {
  std::string message = e.code().message();
  if (!e.path1().empty()) message = "'" + e.path1().string() + "': " + message;
  if (!e.path2().empty()) message += " ('" + e.path2().string() + "')";
  return message;
}

}  // namespace

int main(int argc, char** argv) {
  // A video FFmpeg cannot decode is reported as one line naming the file (logs/video.h);
  // OpenCV's and FFmpeg's own log lines would precede it on stderr. Set either variable
  // beforehand to see them.
  ::setenv("OPENCV_FFMPEG_LOGLEVEL", "-8", /*overwrite=*/0);  // AV_LOG_QUIET
  ::setenv("OPENCV_LOG_LEVEL", "SILENT", /*overwrite=*/0);
  CLI::App app{"omnicml: omniview-based concurrent map building and localization"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "omnicml 0.1.0");
  omnicml::app::AddGlobalOptions(app);
  auto& registry = omnicml::app::CommandRegistry();
  std::sort(registry.begin(), registry.end(),
            [](const auto& a, const auto& b) { return a.name < b.name; });
  for (const auto& command : registry) command.setup(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // One line, like every other error (CLI11 would add "Run with --help ...").
    std::cerr << "omnicml: error: " << omnicml::Excerpt(e.what(), kMaxMessageChars)
              << " (see --help)\n";
    return 2;
  } catch (const omnicml::Error& e) {
    std::cerr << "omnicml: error: " << omnicml::Excerpt(e.what(), kMaxMessageChars) << "\n";
    return 2;
  } catch (const std::filesystem::filesystem_error& e) {
    // A file system call on a path the user gave (a symbolic-link loop, a directory where
    // a file belongs, permissions): bad input, named by its path.
    std::cerr << "omnicml: error: " << omnicml::Excerpt(FilesystemMessage(e), kMaxMessageChars)
              << "\n";
    return 2;
  } catch (const YAML::Exception& e) {
    // yaml-cpp only ever parses user files (configurations, worlds, places, sessions).
    std::cerr << "omnicml: error: YAML: " << omnicml::Excerpt(e.what(), kMaxMessageChars) << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "omnicml: internal error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
