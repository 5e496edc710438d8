// `omnicml run`: CML over a multi-day log or a simulated world, the map carried from day
// to day; writes a run directory (run_recorder.h) and optionally the map and a TUM
// trajectory. The input and option flags are shared with `omnicml compare`.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/run_config.h"
#include "omnicml/experiments/run_recorder.h"

namespace omnicml::app {

// Helpers shared with cmd_compare.cc (declared there).
using RunFlags = RunSettings;

void AddRunInputFlags(CLI::App* cmd, RunFlags* f, bool with_forgetting) {
  cmd->add_option(
      "logdirs", f->input.log_dirs,
      "Multi-day log directories (or single sessions), their sessions processed in order");
  cmd->add_option("--world", f->input.world,
                  "Built-in simulated world (home_store, institute, store_large) "
                  "or a world YAML file, instead of LOGDIR");
  cmd->add_option("--days", f->input.days, "Simulated days (with --world)")->capture_default_str();
  cmd->add_option("--first-day", f->input.first_day,
                  "First simulated day, 0-based (with --world; resume with --map-in)")
      ->capture_default_str();
  cmd->add_option("--frames-per-day", f->input.frames_per_day,
                  "Simulated frames per day (0 = the simulator default, 300; one lap is about 285 on home_store, 180 on institute, 1425 on store_large)")
      ->capture_default_str();
  cmd->add_option("--seed", f->input.seed, "Simulator seed")->capture_default_str();
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
      "Descriptor distance at which a view stops matching (model.e_max)");
  cmd->add_option_function<int>(
      "--update-delay", [f](int v) { f->overrides.update_delay_frames = v; },
      "Frames before an observation reaches the map (update_delay_frames)");
  cmd->add_option_function<std::string>(
      "--descriptor", [f](const std::string& s) { f->overrides.descriptor = s; },
      "Descriptor: fourier | ifh | color (set --e-max to suit it)");
  cmd->add_option_function<int>(
      "--threads", [f](int v) { f->overrides.threads = v; },
      "Engine threads: 1 = no worker, 2 = map updates on a background worker "
      "(default 2 on a multi-core machine unless --config sets it)");
  cmd->add_option("--out", f->out_dir, "Run directory (default runs/<command>-<date>-<time>)");
  cmd->add_flag("--quiet", f->quiet, "No progress output");
  cmd->add_flag("--no-progress-bar", f->no_progress_bar, "Plain log lines even on a terminal");
  cmd->add_option("--log-every", f->log_every_frames, "Frames between plain progress lines")
      ->capture_default_str();
}

std::string DefaultRunDir(const std::string& command) {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[64];
  std::strftime(buf, sizeof buf, "%Y%m%d-%H%M%S", &tm);
  return "runs/" + command + "-" + buf;
}

ProgressOptions MakeProgress(const RunFlags& f, const std::string& label,
                             std::optional<std::int64_t> total) {
  ProgressOptions p;
  p.progress_bar = !f.no_progress_bar && StderrIsTerminal();
  p.log_every_frames = f.log_every_frames;
  p.label = label;
  p.total_frames = total;
  p.quiet = f.quiet;
  return p;
}

// Without --threads and --config, use the engine's map-update worker when the machine
// has a second core (results are identical with 1 or 2 threads).
OptionOverrides WithDefaultThreads(OptionOverrides overrides) {
  if (!overrides.threads && overrides.config_path.empty() &&
      std::thread::hardware_concurrency() >= 2) {
    overrides.threads = 2;
  }
  return overrides;
}

// Fails early (before a long run) when an output's directory does not exist and is not
// the run directory (which the run creates).
void CheckOutputParent(const std::string& path, const char* flag, const std::string& run_dir = "") {
  if (path.empty()) return;
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  if (!run_dir.empty() && !parent.empty() &&
      std::filesystem::weakly_canonical(parent) == std::filesystem::weakly_canonical(run_dir)) {
    return;
  }
  if (!parent.empty() && !std::filesystem::is_directory(parent)) {
    throw Error(StrCat(flag, " '", path, "': directory '", parent.string(), "' does not exist"));
  }
}

namespace {

struct RunOnlyFlags {
  std::string map_in;
  std::string map_out;
  std::string trajectory_out;
};

void Run(const RunFlags& f, const RunOnlyFlags& r) {
  f.input.Validate();
  CheckOutputParent(r.map_out, "--map-out", f.out_dir);
  CheckOutputParent(r.trajectory_out, "--trajectory-out", f.out_dir);
  if (f.log_every_frames < 1) throw Error("--log-every must be >= 1");

  std::unique_ptr<CmlEngine> engine;
  if (!r.map_in.empty()) {
    if (!f.overrides.OnlyThreadsAndForgetting()) {
      throw Error(
          StrCat("--map-in '", r.map_in,
                 "': the saved engine's options are used; only --threads and "
                 "--forgetting may change (drop --config, --e-max, --update-delay, --descriptor)"));
    }
    if (!std::filesystem::is_regular_file(r.map_in)) {
      throw Error(StrCat("--map-in '", r.map_in, "' does not exist"));
    }
    engine = LoadEngine(r.map_in);
    if (f.overrides.threads || f.overrides.forgetting) {
      CmlEngineOptions options = engine->options();
      if (f.overrides.threads) options.threads = *f.overrides.threads;
      if (f.overrides.forgetting)
        options.model.forgetting = ForgettingModeFromString(*f.overrides.forgetting);
      engine = RebuildEngineWithOptions(*engine, options);
    }
  } else {
    engine = std::make_unique<CmlEngine>(ResolveEngineOptions(WithDefaultThreads(f.overrides)));
  }
  if (engine->options().model.forgetting == ForgettingMode::kStatic &&
      engine->model().NumViews() == 0 && !f.quiet) {
    std::cerr << "omnicml run: warning: static forgetting on an empty map: the map will stay empty "
                 "(build it first, then resume with --map-in MAP --forgetting static)\n";
  }

  std::unique_ptr<FrameSource> source = OpenFrameSource(f.input);
  const std::string out_dir = f.out_dir.empty() ? DefaultRunDir("run") : f.out_dir;
  RunRecorderOptions ro;
  ro.run_dir = out_dir;
  ro.trajectory_path = r.trajectory_out;
  ro.title = "omnicml run";
  ro.input_description = f.input.Describe() + (r.map_in.empty() ? "" : ", map " + r.map_in);
  RunRecorder recorder(ro);
  const RunSummary summary = RunEngineOverSource(
      engine, *source, &recorder, MakeProgress(f, "run", CountFrames(f.input, *source)));
  if (summary.frames == 0) {
    throw Error(StrCat("the input (", f.input.Describe(), ") has no frames"));
  }
  // The saved engine is the state before Finish(), so a resumed run continues exactly as
  // one uninterrupted run would (queued updates and pending frames included).
  std::vector<std::uint8_t> map_bytes;
  if (!r.map_out.empty()) map_bytes = EncodeEngine(*engine);
  engine->Finish();
  const double fps = static_cast<double>(summary.frames) / std::max(summary.wall_s, 1e-9);
  char timing[96];
  std::snprintf(timing, sizeof timing, "%.1f s (%.1f frames/s)", summary.wall_s, fps);
  recorder.Commit(*engine,
                  {{"wall time", timing}, {"threads", std::to_string(engine->options().threads)}});
  if (!r.map_out.empty()) WriteFileAtomically(r.map_out, map_bytes);

  FramesTable table;
  table.stage_names = StageNames();
  table.records = recorder.records();
  std::cout << FormatEvaluation(Evaluate(table, Alignment::kNone), /*with_histogram=*/false);
  std::cout << "frames: " << summary.frames << " in " << summary.sessions << " session(s), "
            << timing << "\n";
  std::cout << "map: " << engine->model().NumViews() << " views, "
            << engine->model().NumComponents() << " components\n";
  std::cout << "run directory: " << out_dir
            << "\nreport: " << (std::filesystem::path(out_dir) / "report.html").string() << "\n";
  if (!r.map_out.empty()) std::cout << "map saved: " << r.map_out << "\n";
  if (!r.trajectory_out.empty()) std::cout << "trajectory (TUM): " << r.trajectory_out << "\n";
}

const CommandRegistration kRegistration{
    "run", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "run",
          "Concurrent map building and localization over a multi-day log or a simulated world");
      auto flags = std::make_shared<RunFlags>();
      auto run_flags = std::make_shared<RunOnlyFlags>();
      AddRunInputFlags(cmd, flags.get(), /*with_forgetting=*/true);
      cmd->add_option("--map-in", run_flags->map_in, "Resume from a saved engine/map file");
      cmd->add_option("--map-out", run_flags->map_out,
                      "Save the engine/map at the end (resumable with --map-in)");
      cmd->add_option("--trajectory-out", run_flags->trajectory_out,
                      "Write the estimated trajectory in TUM format (stamp x y z qx qy qz qw)");
      cmd->callback([flags, run_flags] { Run(*flags, *run_flags); });
    }};

}  // namespace
}  // namespace omnicml::app
