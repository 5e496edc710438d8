// `omnicml collect DIR`: every run of a sweep directory (omnicml sweep) into one CSV
// (DIR/summary.csv: errors, coverage, views, time, peak memory) and an HTML report
// (DIR/summary.html); prints the CSV.
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/experiments/sweep.h"

namespace omnicml::app {
namespace {

const CommandRegistration kRegistration{
    "collect", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "collect", "Gather the runs of a sweep directory into summary.csv and summary.html");
      auto dir = std::make_shared<std::string>();
      cmd->add_option("dir", *dir, "Sweep directory written by omnicml sweep")->required();
      cmd->callback([dir] {
        const std::vector<SweepRow> rows = CollectSweep(*dir);
        std::cout << SweepRowsToCsv(rows);
        std::cout << "collected " << rows.size() << " run(s) into " << *dir << "/summary.csv and "
                  << *dir << "/summary.html\n";
      });
    }};

}  // namespace
}  // namespace omnicml::app
