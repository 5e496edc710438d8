// Subcommands of the single `omnicml` binary register themselves here, one source file
// each (apps/cmd_<name>.cc), listed in the omnicml_cli sources of apps/CMakeLists.txt.
//
//   static const omnicml::app::CommandRegistration kRegistration{
//       "describe", [](CLI::App& app) {
//         CLI::App* cmd = app.add_subcommand("describe", "Describe panoramas");
//         ... cmd->callback([...] { ...; });   // throw omnicml::Error on bad input
//       }};
//
// Exit codes (apps/omnicml_main.cc): 0 success; 2 bad usage or bad input (CLI11 parse
// errors, omnicml::Error, std::filesystem::filesystem_error naming its path and
// YAML::Exception; one line on stderr, at most 1000 characters); 1 internal error.
#ifndef OMNICML_APPS_COMMAND_REGISTRY_H_
#define OMNICML_APPS_COMMAND_REGISTRY_H_

#include <functional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

namespace omnicml::app {

using CommandSetup = std::function<void(CLI::App&)>;

struct RegisteredCommand {
  std::string name;
  CommandSetup setup;
};

// All registrations, in no particular order (main sorts them by name).
std::vector<RegisteredCommand>& CommandRegistry();

struct CommandRegistration {
  CommandRegistration(std::string name, CommandSetup setup) {
    CommandRegistry().push_back({std::move(name), std::move(setup)});
  }
};

}  // namespace omnicml::app

#endif  // OMNICML_APPS_COMMAND_REGISTRY_H_
