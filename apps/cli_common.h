// Helpers shared by the subcommands of apps/ (one definition each, declared here).
#ifndef OMNICML_APPS_CLI_COMMON_H_
#define OMNICML_APPS_CLI_COMMON_H_

#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/experiments/run_experiment.h"

namespace omnicml::app {

// The input, engine-option, run-directory and progress flags of `run` and `compare`
// (LOGDIR..., --world, --days, --first-day, --frames-per-day, --seed,
// --skip-unreadable-frames, --config, [--forgetting], --e-max, --update-delay,
// --descriptor, --threads, --out, --quiet, --no-progress-bar, --log-every), stored into
// *settings, which must outlive the parse.
void AddRunInputFlags(CLI::App* cmd, RunSettings* settings, bool with_forgetting);

// Loads a saved engine/map for reading (export, inspect) and applies every queued update
// (CmlEngine::Finish on the in-memory copy), so what is shown is the whole map. Throws
// omnicml::Error naming the path when it does not exist or does not load.
std::unique_ptr<CmlEngine> LoadMapForReading(const std::string& path);

}  // namespace omnicml::app

#endif  // OMNICML_APPS_CLI_COMMON_H_
