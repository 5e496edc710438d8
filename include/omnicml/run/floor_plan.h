// The floor plan under the map pictures (report/map_export.h): a simulated world's walls,
// shelves and boxes, and which world a run directory was made from.
//
// Pure functions; thread-safe.
#ifndef OMNICML_RUN_FLOOR_PLAN_H_
#define OMNICML_RUN_FLOOR_PLAN_H_

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include "omnicml/report/map_export.h"
#include "omnicml/sim/world.h"

namespace omnicml {

// The obstacles of `world` as they stand at the start of `day` (1-based; shelves moved
// by day events are drawn where they are then), the floor [0, size_m] as extent.
FloorPlan FloorPlanFromWorld(const World& world, int day = 1, std::uint64_t seed = 1);

// The simulated input of a run directory, read from the "# input: world NAME, days A-B,
// F frames/day, seed S" line of RUNDIR/config.yaml.
struct RunWorld {
  std::string world;  // built-in name or world file
  int last_day = 1;   // B
  std::uint64_t seed = 1;
};
// From a RunInput::Describe() text; std::nullopt when it names logs.
std::optional<RunWorld> ParseRunWorld(const std::string& input_description);
// From RUNDIR/config.yaml; std::nullopt when the run was on logs or config.yaml has no
// input line. Throws omnicml::Error when config.yaml cannot be read.
std::optional<RunWorld> ReadRunWorld(const std::filesystem::path& run_dir);
// The floor plan of the world a run describes (state at its last day), or an empty
// plan when it ran on logs or the world cannot be loaded any more (a moved world file):
// the picture then has no floor plan rather than failing the report.
FloorPlan FloorPlanForRunInput(const std::string& input_description);

}  // namespace omnicml

#endif  // OMNICML_RUN_FLOOR_PLAN_H_
