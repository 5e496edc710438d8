// `omnicml mcl`: baseline [W], Monte Carlo localization with image retrieval and
// visibility areas (experiments/mcl_experiment.h), over a simulated world or a log
// (panorama or raw ring sessions).
//
//   omnicml mcl --world home_store --days 2 --frames-per-day 300 --seed 1 --out RUNDIR
//       references: every --ref-every-th frame of --train-day (with ground truth);
//       queries: every frame of --test-day; writes the run directory (frames.csv,
//       days.csv, config.yaml, report.html, summary.txt, map.yaml + map.pgm).
//   omnicml mcl LOGDIR --map map.yaml ...   (sessions with ground truth; raw rings are
//       unwrapped with the session's calibration)
//   omnicml mcl --world home_store --experiment tracking|global|kidnap|noise --runs 20
//       prints the [W] experiment tables (see README "Baselines").
//   --config RUNDIR/config.yaml   the filter's options of an earlier run (MclOptions).
#include <iostream>
#include <memory>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/experiments/mcl_experiment.h"

namespace omnicml::app {
namespace {

void RunMclCommand(const MclExperimentOptions& options) {
  const MclPrepared prepared = PrepareMclExperiment(options);
  std::cerr << DescribeMclPrepared(prepared);
  if (!options.experiment.empty()) {
    std::cout << RunMclExperiment(options, prepared).text;
    return;
  }
  std::cout << RunMclSingle(options, prepared).summary_text;
  if (!options.out_dir.empty()) {
    std::cout << "wrote " << options.out_dir
              << "/{frames.csv,days.csv,config.yaml,report.html,summary.txt,map.yaml,map.pgm}\n";
  }
}

// --config FILE: the filter's options from the file (LoadMclOptions), then the filter
// flags given on the command line.
void ApplyConfig(const std::string& path, const CLI::App& cmd, MclExperimentOptions* a) {
  const MclExperimentOptions given = *a;
  SetMclFilterOptions(LoadMclOptions(path), a);
  const auto keep = [&](const char* flag, auto member) {
    if (cmd.count(flag) > 0) a->*member = given.*member;
  };
  keep("--particles", &MclExperimentOptions::particles);
  keep("--random-samples", &MclExperimentOptions::random_samples);
  keep("--heading-gate-deg", &MclExperimentOptions::heading_gate_deg);
  keep("--top-k", &MclExperimentOptions::top_k);
  keep("--prior-fraction", &MclExperimentOptions::prior_fraction);
  keep("--min-likelihood", &MclExperimentOptions::min_likelihood);
  keep("--visibility-radius", &MclExperimentOptions::max_distance_from_reference_m);
  keep("--mcl-seed", &MclExperimentOptions::mcl_seed);
}

const CommandRegistration kRegistration{
    "mcl", [](CLI::App& app) {
      auto a = std::make_shared<MclExperimentOptions>();
      auto config = std::make_shared<std::string>();
      CLI::App* cmd = app.add_subcommand(
          "mcl", "Monte Carlo localization with image retrieval and visibility areas [W]");
      cmd->add_option("logdirs", a->log_dirs,
                      "Log directories, panorama or raw ring (unwrapped with the session's "
                      "calibration), instead of --world");
      cmd->add_option("--map", a->map_yaml,
                      "Occupancy grid in map_server format (YAML + PGM); default: rasterised "
                      "from the world");
      cmd->add_option("--world", a->world, "Built-in world or world YAML")->capture_default_str();
      cmd->add_option("--config", *config,
                      "MclOptions YAML (keys = option names; RUNDIR/config.yaml of any mcl run "
                      "loads back); the filter flags given override it");
      cmd->add_option("--days", a->days, StrCat("Simulated days, at most ", kMaxDays))
          ->capture_default_str();
      cmd->add_option("--frames-per-day", a->frames_per_day,
                      StrCat("Simulated frames per day, at most ", kMaxFramesPerDay))
          ->capture_default_str();
      cmd->add_option("--seed", a->seed, "Simulator seed")->capture_default_str();
      cmd->add_option("--train-day", a->train_day, "Day of the reference images (1-based)")
          ->capture_default_str();
      cmd->add_option("--test-day", a->test_day, "Day localized (1-based)")->capture_default_str();
      cmd->add_option("--ref-every", a->ref_every, "Every k-th training frame is a reference")
          ->capture_default_str();
      cmd->add_option("--panorama-width", a->panorama_width, "Simulated panorama width, px")
          ->capture_default_str();
      cmd->add_option("--panorama-height", a->panorama_height, "Simulated panorama height, px")
          ->capture_default_str();
      cmd->add_flag("!--no-people", a->people, "Simulate without people");
      cmd->add_option("--descriptor", a->descriptor, "ifh | fourier | color")
          ->capture_default_str();
      cmd->add_flag("--ifh-normalize-columns", a->ifh_normalize_columns,
                    "ifh: divide each panorama column by its mean brightness first (lights "
                    "that switch between the days; docs/results.md)");
      cmd->add_option("--grid-resolution", a->grid_resolution_m, "Occupancy grid cell size, m")
          ->capture_default_str();
      cmd->add_option("--particles", a->particles,
                      StrCat("Number of particles, at most ", kMaxParticles))
          ->capture_default_str();
      cmd->add_option("--random-samples", a->random_samples, "Random samples injected per step")
          ->capture_default_str();
      cmd->add_option("--heading-gate-deg", a->heading_gate_deg,
                      "Half width of d(psi), degrees; 0 = heading independent (omni)")
          ->capture_default_str();
      cmd->add_option("--top-k", a->top_k, "Retrieved references per query (0 = all)")
          ->capture_default_str();
      cmd->add_option("--prior-fraction", a->prior_fraction, "Prior of [W] eq. (8) / mean xi")
          ->capture_default_str();
      cmd->add_option("--min-likelihood", a->min_likelihood, "Lower bound of a particle's weight")
          ->capture_default_str();
      cmd->add_option(
             "--visibility-radius", a->max_distance_from_reference_m,
             "Visibility areas kept within this distance of the reference, m (0 = derived: "
             "visibility_radius_spacings x the references' median spacing)")
          ->capture_default_str();
      cmd->add_flag("--global", a->global, "Start with uniform particles (global localization)");
      cmd->add_option("--mcl-seed", a->mcl_seed, "Seed of the filter")->capture_default_str();
      AddOutputDirectory(cmd, "--out", &a->out_dir, "Run directory (single run)");
      cmd->add_option("--experiment", a->experiment, "tracking | global | kidnap | noise");
      cmd->add_option("--runs", a->runs,
                      StrCat("Runs per experiment (per noise level), at most ", kMaxRuns))
          ->capture_default_str();
      cmd->add_option("--noise-levels", a->noise_levels,
                      "Noise experiment: comma-separated multiples of the world's a1..a4")
          ->capture_default_str();
      cmd->callback([a, config, cmd] {
        if (!config->empty()) ApplyConfig(*config, *cmd, a.get());
        RunMclCommand(*a);
      });
    }};

}  // namespace
}  // namespace omnicml::app
