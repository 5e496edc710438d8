// `omnicml run`: CML over a multi-day log or a simulated world, the map carried from day
// to day; writes a run directory (with replay.html, experiments/replay.h) and optionally the map
// and a TUM trajectory (experiments/run_experiment.h). The input and option flags are shared with
// `omnicml compare` (cli_common.h).
#include <iostream>
#include <memory>

#include <CLI/CLI.hpp>

#include "cli_common.h"
#include "command_registry.h"
#include "omnicml/experiments/replay.h"
#include "omnicml/experiments/run_experiment.h"

namespace omnicml::app {
namespace {

const CommandRegistration kRegistration{
    "run", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "run",
          "Concurrent map building and localization over a multi-day log or a simulated world");
      auto options = std::make_shared<RunExperimentOptions>();
      AddRunInputFlags(cmd, &options->settings, /*with_forgetting=*/true);
      cmd->add_option("--map-in", options->map_in, "Resume from a saved engine/map file");
      AddOutputFile(cmd, "--map-out", &options->map_out,
                    "Save the engine/map at the end (resumable with --map-in)");
      AddOutputFile(cmd, "--trajectory-out", &options->trajectory_out,
                    "Write the estimated trajectory in TUM format (stamp x y z qx qy qz qw)");
      cmd->callback([options] {
        const RunExperimentResult result = RunExperiment(*options);
        std::cout << FormatRunExperimentResult(*options, result);
        std::cout << "replay: " << WriteReplay(result.run_dir).string() << "\n";
      });
    }};

}  // namespace
}  // namespace omnicml::app
