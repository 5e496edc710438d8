// `omnicml calibrate LOG [--config ENGINE.yaml] [--out CALIBRATION.yaml]`: measures how
// fast appearance changes with travelled distance over the first session of a log and
// derives the engine's spatial thresholds from it, and identifies the odometry noise
// a1..a4 from the session's appearance loop pairs (engine/calibration.h; what a run with
// motion_noise_source: identified does by itself). Prints the measurements and the derived
// values; --out saves them as an engine configuration that `omnicml run --config` loads
// (explicit values in a later --config still win).
#include <iostream>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "command_registry.h"
#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/engine/calibration.h"
#include "omnicml/run/run_config.h"

namespace omnicml::app {
namespace {

struct CalibrateFlags {
  RunInput input;
  std::string config_path;
  std::string out;
  CalibrationOptions calibration;
};

const CommandRegistration kRegistration{
    "calibrate", [](CLI::App& app) {
      CLI::App* cmd = app.add_subcommand(
          "calibrate",
          "Derive the spatial thresholds from how appearance changes with travel, and "
          "identify the odometry noise from the first session's loops");
      auto f = std::make_shared<CalibrateFlags>();
      cmd->add_option("logs", f->input.log_dirs, "Log (its first session is used)");
      cmd->add_option("--world", f->input.world, "Built-in simulated world instead of a log");
      cmd->add_option("--frames-per-day", f->input.frames_per_day,
                      "Simulated frames (with --world)");
      cmd->add_option(
             "--days", f->input.days,
             "Simulated days (with --world): later days add loop pairs for the motion noise")
          ->capture_default_str();
      cmd->add_option("--seed", f->input.seed, "Simulator seed")->capture_default_str();
      cmd->add_option("--config", f->config_path, "Engine configuration (descriptor, e_max)");
      AddOutputFile(cmd, "--out", &f->out, "Write the derived values as engine YAML");
      cmd->add_option("--max-frames", f->calibration.max_frames, "Frames used")
          ->capture_default_str();
      cmd->add_option("--max-lag", f->calibration.max_lag_frames, "Largest frame lag")
          ->capture_default_str();
      cmd->add_flag("!--no-relative-heading", f->calibration.use_relative_heading,
                    "Loop pairs without the descriptor's relative heading (x, y innovations only)");
      cmd->add_option("--shape-prior-log-sd", f->calibration.identification.shape_prior_log_sd,
                      "Motion noise prior: sd of ln a_j about the prior shape (> 0)")
          ->capture_default_str();
      cmd->add_option("--offset-prior-log-sd", f->calibration.identification.offset_prior_log_sd,
                      "Motion noise prior: sd of ln rho and ln rho_phi about their centres (> 0)")
          ->capture_default_str();
      CLI::Option* offset_dof =
          cmd->add_option("--offset-dof", f->calibration.identification.offset_dof,
                          "Appearance offset from a Student t fit with this many degrees of "
                          "freedom (0: from the Gaussian fit with a1..a4); without the flag, "
                          "the configuration's motion_noise_offset_dof, as a run uses it")
              ->capture_default_str();
      CLI::Option* joint_pairs =
          cmd->add_option("--joint-pairs", f->calibration.identification.joint_pairs,
                          "a1..a4 from the joint likelihood of the heading innovations of up to "
                          "this many loop pairs (0: pairs as independent); without the flag, the "
                          "configuration's "
                          "motion_noise_joint_pairs, as a run uses it")
              ->capture_default_str()
              ->check(CLI::NonNegativeNumber);
      cmd->callback([f, offset_dof, joint_pairs] {
        f->input.Validate();
        OptionOverrides overrides;
        overrides.config_path = f->config_path;
        const CmlEngineOptions options = ResolveEngineOptions(overrides);
        // What a run with this configuration identifies, unless a flag says otherwise.
        MotionNoiseIdentificationOptions& identification = f->calibration.identification;
        const MotionNoiseIdentificationOptions flags = identification;
        UseEngineIdentificationOptions(options, &identification);
        if (offset_dof->count() > 0) identification.offset_dof = flags.offset_dof;
        if (joint_pairs->count() > 0) identification.joint_pairs = flags.joint_pairs;
        const std::unique_ptr<FrameSource> source = OpenFrameSource(f->input);
        const Calibration c = Calibrate(*source, options, f->calibration);
        const std::string yaml = c.ToYaml();
        std::cout << yaml;
        if (!f->out.empty()) {
          WriteFileAtomic(f->out, yaml);
          std::cout << "written: " << f->out << "\n";
        }
      });
    }};

}  // namespace
}  // namespace omnicml::app
