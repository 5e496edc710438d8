#include "cli_common.h"

#include <filesystem>
#include <string>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/engine/engine_io.h"

namespace omnicml::app {

void AddRunInputFlags(CLI::App* cmd, RunSettings* f, bool with_forgetting) {
  cmd->add_option(
      "logdirs", f->input.log_dirs,
      "Multi-day log directories (or single sessions), their sessions processed in order");
  cmd->add_option("--world", f->input.world,
                  "Built-in simulated world (home_store, institute, store_large) "
                  "or a world YAML file, instead of LOGDIR");
  cmd->add_option("--days", f->input.days,
                  StrCat("Simulated days (with --world), at most ", kMaxDays))
      ->capture_default_str();
  cmd->add_option("--first-day", f->input.first_day,
                  "First simulated day, 0-based (with --world; resume with --map-in)")
      ->capture_default_str();
  cmd->add_option(
         "--frames-per-day", f->input.frames_per_day,
         StrCat("Simulated frames per day (0 = the simulator default, 300; one lap is "
                "about 285 on home_store, 180 on institute, 1425 on store_large), at most ",
                kMaxFramesPerDay, "; days x frames at most ", kMaxSimulatedFrames))
      ->capture_default_str();
  cmd->add_option("--seed", f->input.seed, "Simulator seed")->capture_default_str();
  cmd->add_option_function<std::string>(
      "--sim-image",
      [f](const std::string& s) {
        if (s == "raw_ring") {
          f->input.sim_image = ImageKind::kRawRing;
        } else if (s == "panorama") {
          f->input.sim_image = ImageKind::kPanorama;
        } else {
          throw CLI::ValidationError("--sim-image", "'" + s + "' (raw_ring | panorama)");
        }
      },
      "Simulated images (with --world): raw_ring (default; the engine unwraps the rendered "
      "ring) | panorama (the rendered panorama itself, no ring and no unwrap: about 2x "
      "faster; mean errors measured 2-5 % higher, docs/results.md)");
  cmd->add_flag("--skip-unreadable-frames", f->input.skip_unreadable_frames,
                "Logs: skip (and count) frames that cannot be read instead of failing");
  cmd->add_option(
      "--config", f->overrides.config_path,
      "Engine configuration YAML (keys = option names; see RUNDIR/config.yaml of any run)");
  if (with_forgetting) {
    cmd->add_option_function<std::string>(
        "--forgetting", [f](const std::string& s) { f->overrides.forgetting = s; },
        "Forgetting mode: active | passive | static");
  }
  cmd->add_option_function<double>(
      "--e-max", [f](double v) { f->overrides.e_max = v; },
      "Descriptor distance at which a view stops matching (model.retrieval.e_max)");
  cmd->add_option_function<int>(
      "--update-delay", [f](int v) { f->overrides.update_delay_frames = v; },
      "Frames before an observation reaches the map (update_delay_frames)");
  cmd->add_option_function<std::string>(
      "--descriptor", [f](const std::string& s) { f->overrides.descriptor = s; },
      "Descriptor: fourier | ifh | color (set --e-max to suit it)");
  cmd->add_option_function<int>(
      "--threads", [f](int v) { f->overrides.threads = v; },
      StrCat("Engine threads: 1 = no worker, 2 = map updates on a background worker "
             "(default 2 on a multi-core machine unless --config sets it), at most ",
             kMaxThreads));
  cmd->add_option("--survey-days", f->survey.days,
                  "Survey mapping ([G]'s old map): the first N days build the map from trusted "
                  "poses (the input's ground truth, or --survey-poses), CML runs on it from day "
                  "N+1; the error tables then cover days N+1 on only (compare: static = the "
                  "survey map frozen after day N)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--survey-poses", f->survey.poses_path,
                  "Trusted poses of the survey days as a TUM file (stamp x y z qx qy qz qw per "
                  "line), matched to frames by stamp; default: the input's ground truth");
  AddOutputDirectory(cmd, "--out", &f->out_dir,
                     "Run directory (default runs/<command>-<date>-<time>); checked, with every "
                     "other output, before the first frame");
  cmd->add_flag("--quiet", f->quiet, "No progress output");
  cmd->add_flag("--no-progress-bar", f->no_progress_bar, "Plain log lines even on a terminal");
  cmd->add_option("--log-every", f->log_every_frames, "Frames between plain progress lines")
      ->capture_default_str();
}

std::unique_ptr<CmlEngine> LoadMapForReading(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw Error(StrCat("map file '", path, "' ",
                       ec ? ec.message() : "does not exist or is not a regular file"));
  }
  std::unique_ptr<CmlEngine> engine = LoadEngine(path);
  engine->Finish();
  return engine;
}

}  // namespace omnicml::app
