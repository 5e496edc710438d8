// `omnicml inspect MAP`: views, components, memory, sessions covered and map health by
// area (stale, changed, new) of a saved map.
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "cli_common.h"
#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/report/map_export.h"

namespace omnicml::app {

namespace {

struct InspectFlags {
  std::string map;
  double cell_m = 2.0;
  int stale_days = 1;
  int changed_neighbours = MapHealthOptions{}.min_changed_neighbours;
};

const CommandRegistration kRegistration{
    "inspect", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand("inspect", "Summary and health by area of a saved map");
      auto flags = std::make_shared<InspectFlags>();
      cmd->add_option("map", flags->map, "Map (engine) file written by omnicml run --map-out")
          ->required();
      cmd->add_option("--cell", flags->cell_m, "Cell size of the health grid, metres")
          ->capture_default_str();
      cmd->add_option("--stale-days", flags->stale_days,
                      "A cell is stale when not seen in this many last days")
          ->capture_default_str();
      cmd->add_option("--changed-neighbours", flags->changed_neighbours,
                      "A cell without evidence of its own is changed when this many of its 8 "
                      "neighbours have some (0 = off)")
          ->capture_default_str();
      cmd->callback([flags] {
        if (!(flags->cell_m > 0))
          throw Error(StrCat("--cell must be > 0 (got ", flags->cell_m, ")"));
        if (flags->stale_days < 1)
          throw Error(StrCat("--stale-days must be >= 1 (got ", flags->stale_days, ")"));
        if (flags->changed_neighbours < 0 || flags->changed_neighbours > 8)
          throw Error(
              StrCat("--changed-neighbours must be in 0..8 (got ", flags->changed_neighbours, ")"));
        const std::unique_ptr<CmlEngine> engine = LoadMapForReading(flags->map);
        MapHealthOptions options;
        options.cell_m = flags->cell_m;
        options.stale_sessions = flags->stale_days;
        options.min_changed_neighbours = flags->changed_neighbours;
        std::cout << "map file: " << flags->map << "\n" << InspectText(*engine, options);
      });
    }};

}  // namespace
}  // namespace omnicml::app
