// The omnicml command-line tool: parses flags, calls the library, maps errors to exit
// codes. Subcommands live in apps/cmd_*.cc (see command_registry.h).
#include <algorithm>
#include <exception>
#include <iostream>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"

namespace omnicml::app {
std::vector<RegisteredCommand>& CommandRegistry() {
  static std::vector<RegisteredCommand> registry;
  return registry;
}
}  // namespace omnicml::app

int main(int argc, char** argv) {
  CLI::App app{"omnicml: omniview-based concurrent map building and localization"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "omnicml 0.1.0");
  auto& registry = omnicml::app::CommandRegistry();
  std::sort(registry.begin(), registry.end(),
            [](const auto& a, const auto& b) { return a.name < b.name; });
  for (const auto& command : registry) command.setup(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return 2;
  } catch (const omnicml::Error& e) {
    std::cerr << "omnicml: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "omnicml: internal error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
