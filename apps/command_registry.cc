#include "command_registry.h"

#include <set>
#include <sstream>

#include "omnicml/common/file_io.h"
#include "omnicml/logs/log_format.h"

namespace omnicml::app {
namespace {

// Validator names marking output options (found again by OutputFlags).
constexpr const char* kOutputFileValidator = "OUTPUT_FILE";
constexpr const char* kOutputDirectoryValidator = "OUTPUT_DIR";

CLI::Validator OutputValidator(OutputKind kind) {
  const bool directory = kind == OutputKind::kDirectory;
  return CLI::Validator(
      [directory](std::string& path) -> std::string {
        const std::string problem = OutputNodeProblem(path, directory);
        return problem.empty() ? std::string() : "'" + path + "': " + problem;
      },
      directory ? "DIR (output)" : "FILE (output)",
      directory ? kOutputDirectoryValidator : kOutputFileValidator);
}

bool HasValidator(CLI::Option* option, const char* name) {
  try {
    option->get_validator(name);
    return true;
  } catch (const CLI::OptionNotFound&) {
    return false;
  }
}

void CollectOutputFlags(const CLI::App& app, std::vector<std::string> path,
                        std::vector<OutputFlag>* out) {
  for (const CLI::Option* option : app.get_options()) {
    auto* o = const_cast<CLI::Option*>(option);
    for (const auto& [validator, kind] :
         {std::pair{kOutputFileValidator, OutputKind::kFile},
          std::pair{kOutputDirectoryValidator, OutputKind::kDirectory}}) {
      if (HasValidator(o, validator)) out->push_back({path, o->get_name(), kind});
    }
  }
  for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; })) {
    if (sub->get_name().empty()) continue;  // option groups: their options are listed above
    std::vector<std::string> sub_path = path;
    sub_path.push_back(sub->get_name());
    CollectOutputFlags(*sub, sub_path, out);
  }
}

}  // namespace

void AddGlobalOptions(CLI::App& app) {
  SetFollowOutputSymlinks(false);
  SetAllowImagesOutsideLog(false);
  app.add_flag_callback(
         "--allow-images-outside-log", [] { SetAllowImagesOutsideLog(true); },
         "Read images that frames.csv names outside the log directory (absolute paths, '..', "
         "symbolic links leading out); by default such a row is refused. Give it before the "
         "command.")
      ->trigger_on_parse();
  // Set while parsing (trigger_on_parse), before the subcommand's output flags are
  // checked.
  app.add_flag_callback(
         "--follow-output-symlinks", [] { SetFollowOutputSymlinks(true); },
         "Write through an output file that is a symbolic link to a regular file (the file "
         "it leads to is replaced atomically, the link stays) instead of refusing it; links to "
         "devices, FIFOs, directories or nothing are still refused. Give it before the command.")
      ->trigger_on_parse();
}

std::vector<RegisteredCommand>& CommandRegistry() {
  static std::vector<RegisteredCommand> registry;
  return registry;
}

CLI::Option* AddOutputFile(CLI::App* cmd, const std::string& name, std::string* target,
                           const std::string& description) {
  return cmd->add_option(name, *target, description)->check(OutputValidator(OutputKind::kFile));
}

CLI::Option* AddOutputDirectory(CLI::App* cmd, const std::string& name, std::string* target,
                                const std::string& description) {
  return cmd->add_option(name, *target, description)
      ->check(OutputValidator(OutputKind::kDirectory));
}

std::vector<OutputFlag> OutputFlags(const CLI::App& app) {
  std::vector<OutputFlag> out;
  CollectOutputFlags(app, {}, &out);
  return out;
}

bool LooksLikeOutputFlag(const std::string& name) {
  static const std::set<std::string> kWords = {"out",    "save",  "csv", "html", "preview",
                                               "sample", "png",   "svg", "json", "report",
                                               "export", "write", "dump"};
  std::istringstream words(name);
  std::string word;
  while (std::getline(words, word, '-')) {
    if (kWords.count(word) > 0) return true;
  }
  return false;
}

}  // namespace omnicml::app
