// `omnicml replay DIR`: (re)writes DIR/replay.html, the interactive replay of a run
// directory or of a compare directory (experiments/replay.h); `run --out` and
// `compare --out` write it themselves.
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/experiments/replay.h"

namespace omnicml::app {
namespace {

const CommandRegistration kRegistration{
    "replay", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "replay", "Write DIR/replay.html: an interactive replay of a run or compare directory");
      auto dir = std::make_shared<std::string>();
      auto options = std::make_shared<ReplayOptions>();
      cmd->add_option("dir", *dir, "Run directory (omnicml run) or compare directory")->required();
      cmd->add_option("--max-samples", options->max_samples,
                      "Frames kept per run (the slider's positions; evenly spaced)")
          ->capture_default_str();
      cmd->add_option("--max-weakening-events", options->max_weakening_events,
                      "Component removals kept per run (evenly thinned beyond)")
          ->capture_default_str();
      cmd->callback([dir, options] {
        options->Validate();
        std::cout << "replay: " << WriteReplay(*dir, *options).string() << "\n";
      });
    }};

}  // namespace
}  // namespace omnicml::app
