// `omnicml compare`: the [G] Table 1 experiment (experiments/compare_experiment.h): the
// same input under passive, active and static forgetting, in parallel with --jobs > 1
// (same results as one after the other); prints the table of reference views at the
// given steps with the errors and writes RUNDIR/{passive,active,static}/, table.txt and
// report.html, replay.html (experiments/replay.h); --map-out DIR saves each mode's map.
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "cli_common.h"
#include "command_registry.h"
#include "omnicml/experiments/compare_experiment.h"
#include "omnicml/experiments/replay.h"

namespace omnicml::app {
namespace {

const CommandRegistration kRegistration{
    "compare", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "compare",
          "The [G] Table 1 experiment: the same input under passive, active and static forgetting");
      auto options = std::make_shared<CompareExperimentOptions>();
      auto steps = std::make_shared<std::string>("2000,4000,6000,8000");
      AddRunInputFlags(cmd, &options->settings, /*with_forgetting=*/false);
      cmd->add_option("--steps", *steps,
                      "Steps (frames) at which to report the number of reference views")
          ->capture_default_str();
      cmd->add_option(
             "--jobs", options->jobs,
             "Modes run in parallel (0 = one per core, at most 3); results do not depend on it")
          ->capture_default_str()
          ->check(CLI::Range(0, 64));
      AddOutputDirectory(cmd, "--map-out", &options->map_out_dir,
                         "Directory receiving each mode's final engine/map as <mode>.omap "
                         "(loadable with run --map-in, export, inspect)");
      cmd->callback([options, steps] {
        options->steps = ParseSteps(*steps);
        const CompareExperimentResult result = RunCompareExperiment(*options);
        std::cout << FormatCompareExperimentResult(result);
        std::cout << "replay: " << WriteReplay(result.out_dir).string() << "\n";
        if (!options->map_out_dir.empty())
          std::cout << "maps: " << options->map_out_dir << "/{passive,active,static}.omap\n";
      });
    }};

}  // namespace
}  // namespace omnicml::app
