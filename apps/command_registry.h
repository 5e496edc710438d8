// Subcommands of the single `omnicml` binary register themselves here, one source file
// each (apps/cmd_<name>.cc), listed in the omnicml_cli sources of apps/CMakeLists.txt.
//
//   static const omnicml::app::CommandRegistration kRegistration{
//       "describe", [](CLI::App& app) {
//         CLI::App* cmd = app.add_subcommand("describe", "Describe panoramas");
//         ... cmd->callback([...] { ...; });   // throw omnicml::Error on bad input
//       }};
//
// Output flags: every option naming a file or directory that a command writes is added
// with AddOutputFile or AddOutputDirectory. They refuse, while the command line is parsed
// and so before any work, a path that is a device, FIFO, socket, symbolic link or (for a
// file) a directory (common/file_io.h CheckOutputNode); OutputFlags() lists them, and
// tests/apps/output_flags_test.cc runs every one against each kind of such path and fails
// on an option that looks like an output (LooksLikeOutputFlag) but was added otherwise.
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

// Adds the options of `omnicml` itself (given before the subcommand) to `app`:
//   --follow-output-symlinks  an output file that is a symbolic link to a regular file
//                             is written through (common/file_io.h
//                             SetFollowOutputSymlinks) instead of refused.
//   --allow-images-outside-log  frames.csv may name images outside its log
//                             (logs/log_format.h SetAllowImagesOutsideLog).
// Resets those process-wide settings to their defaults first, so every parse starts from it.
void AddGlobalOptions(CLI::App& app);

// The kind of path an output flag names.
enum class OutputKind { kFile, kDirectory };

// Adds option `name` (e.g. "--out") storing into *target, checked as an output file /
// directory (see above). Returns the option for further settings (->required()).
CLI::Option* AddOutputFile(CLI::App* cmd, const std::string& name, std::string* target,
                           const std::string& description);
CLI::Option* AddOutputDirectory(CLI::App* cmd, const std::string& name, std::string* target,
                                const std::string& description);

struct OutputFlag {
  std::vector<std::string> command;  // subcommand path, e.g. {"import", "antworld"}
  std::string flag;                  // the option's long name, e.g. "--map-out"
  OutputKind kind = OutputKind::kFile;
};
// Every output flag of every (nested) subcommand of `app`.
std::vector<OutputFlag> OutputFlags(const CLI::App& app);
// True for an option name whose words (split at '-') name an output: out, save, csv,
// html, preview, sample, png, svg, json, report, export, write, dump.
bool LooksLikeOutputFlag(const std::string& name);

}  // namespace omnicml::app

#endif  // OMNICML_APPS_COMMAND_REGISTRY_H_
