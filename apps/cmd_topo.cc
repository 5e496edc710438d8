// `omnicml topo`: the cross-sequence experiment of [UN] (experiments/topo_experiment.h):
// topological localization by colour-histogram place recognition, reference images from
// one day of a simulated world or a log, the other day localized frame by frame.
//
//   omnicml topo --world home_store --days 2 --train-day 1 --test-day 2 --frames-per-day 285
//       --seed 1 [--places places.yaml | --place-length-m 3] --out RUNDIR
//   omnicml topo --log LOGDIR [--world W] --train-day 1 --test-day 2 --places places.yaml
//       --out RUNDIR
//   --config RUNDIR/topo_config.yaml   the localizer's options of an earlier run.
#include <iostream>
#include <memory>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/experiments/topo_experiment.h"

namespace omnicml::app {
namespace {

// --config FILE: the localizer's options from the file (LoadTopologicalOptions), then the
// localizer flags given on the command line.
void ApplyConfig(const std::string& path, const CLI::App& cmd, TopoExperimentOptions* a) {
  const TopoExperimentOptions given = *a;
  SetTopoLocalizerOptions(LoadTopologicalOptions(path), a);
  const auto keep = [&](const char* flag, auto member) {
    if (cmd.count(flag) > 0) a->*member = given.*member;
  };
  keep("--bins", &TopoExperimentOptions::bins);
  keep("--filter-width", &TopoExperimentOptions::filter_width);
  keep("--normalized-rgb", &TopoExperimentOptions::normalized_rgb);
  keep("--distance", &TopoExperimentOptions::distance);
  keep("--band-threshold", &TopoExperimentOptions::band_threshold);
  keep("--action-threshold", &TopoExperimentOptions::action_threshold);
  keep("--all-places", &TopoExperimentOptions::all_places);
  keep("--global-search-after", &TopoExperimentOptions::global_search_after);
}

const CommandRegistration kRegistration{
    "topo", [](CLI::App& app) {
      auto a = std::make_shared<TopoExperimentOptions>();
      auto config = std::make_shared<std::string>();
      CLI::App* cmd =
          app.add_subcommand("topo",
                             "Topological localization by colour-histogram place recognition [UN]: "
                             "train on one day, test on another");
      cmd->add_option("--world", a->world, "Built-in world name or world YAML file");
      cmd->add_option("--log", a->log, "A multi-day log directory instead of simulating");
      cmd->add_option("--config", *config,
                      "TopologicalOptions YAML (keys = option names; RUNDIR/topo_config.yaml of "
                      "any topo run loads back); the localizer flags given override it");
      cmd->add_option("--days", a->days,
                      StrCat("Simulated days (0: max of train and test day), at most ", kMaxDays))
          ->capture_default_str();
      cmd->add_option("--frames-per-day", a->frames_per_day,
                      StrCat("Simulated frames per day, at most ", kMaxFramesPerDay))
          ->capture_default_str();
      cmd->add_option("--seed", a->seed, "Simulator seed")->capture_default_str();
      cmd->add_option("--step-m", a->step_m, "Simulated distance between frames, m")
          ->capture_default_str();
      cmd->add_flag(
          "--no-people", [a](std::int64_t) { a->people = false; },
          "Simulate without walking people");
      cmd->add_option("--train-day", a->train_day, "Day (1-based) of the reference images")
          ->capture_default_str();
      cmd->add_option("--test-day", a->test_day, "Day (1-based) to localize")
          ->capture_default_str();
      auto* places = cmd->add_option("--places", a->places, "Adjacency-map YAML of the places");
      cmd->add_option("--place-length-m", a->place_length_m,
                      "Without --places: places every this many metres along the route")
          ->capture_default_str()
          ->excludes(places);
      AddOutputDirectory(cmd, "--out", &a->out_dir, "Run directory to write");
      cmd->add_option("--bins", a->bins, "Histogram bins per band")->capture_default_str();
      cmd->add_option("--filter-width", a->filter_width, "Low-pass filter width, bins (odd)")
          ->capture_default_str();
      cmd->add_flag("--normalized-rgb", a->normalized_rgb,
                    "Bands 4-6 from r, g, b (default); --normalized-rgb=false: R, G, B")
          ->capture_default_str();
      cmd->add_option("--distance", a->distance, "jeffrey | chi_square | l1 | l2 | intersection")
          ->capture_default_str();
      cmd->add_option("--band-threshold", a->band_threshold,
                      "Smallest confidence with which a band votes (all bands)")
          ->capture_default_str();
      cmd->add_option("--action-threshold", a->action_threshold,
                      "Smallest overall confidence of a confident classification")
          ->capture_default_str();
      cmd->add_flag("--all-places", a->all_places,
                    "Compare with all places, not only the believed one and its neighbours");
      cmd->add_option("--global-search-after", a->global_search_after,
                      "After this many non-confident frames compare with all places (0: never)")
          ->capture_default_str();
      cmd->add_option("--reference-stride", a->reference_stride,
                      "Every k-th labelled training frame is a reference image")
          ->capture_default_str();
      cmd->add_flag("--global-start", a->global_start,
                    "Start the test day with no belief instead of the true first place");
      cmd->callback([a, config, cmd] {
        if (!config->empty()) ApplyConfig(*config, *cmd, a.get());
        const TopoExperimentResult result = RunTopoExperiment(*a);
        std::cout << result.summary << "run directory: " << a->out_dir << "\n";
      });
    }};

}  // namespace
}  // namespace omnicml::app
