// Configuration of a CML run: the engine options from a YAML file (every field of
// CmlEngineOptions and its nested options structs), the dump of the effective
// configuration, command-line overrides, and the run's input (logs or a simulated world).
//
// YAML layout: keys equal member names; nested options structs are nested maps. Every
// key is optional (absent keys keep their default). An excerpt with the defaults (the
// full list: `omnicml run` writes every key to RUNDIR/config.yaml):
//
//   update_delay_frames: 8
//   threads: 1                                    # 2: map updates on a worker thread
//   initial_pose: [0, 0, 0]                       # x_m, y_m, phi_rad
//   initial_covariance: [[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.001]]
//   descriptor:
//     kind: fourier                               # fourier | ifh | color
//     fourier: {bands: 4, coefficients: 16, distance: l2, normalize_bands: true,
//               normalize_columns: true}
//     color: {bins: 32, filter_width: 5, normalized_rgb: false, distance: jeffrey}
//   tracker: {gamma: 3, w_min: 0.001, delta: 1, max_components: 50, unimodal_min_weight: 0.05,
//             min_covariance_eigenvalue: 1e-10, motion: {a1: 0.05, a2: 0.01, a3: 0.05, a4: 0.01}}
//   model:
//     retrieval: {e_max: 0.45, top_k: 8, heading_sigma_no_rotation_rad: 3.141592653589793}
//     update: {beta: 0.2, d_max: 3, w_min: 0.01, merge_delta: 1, look_back_frames: 50}
//     forgetting: {mode: active, d_for_m: 0.5, beta_for: 0.7, d_gain_m: 1, footprint_gate: 2}
//     index: {spatial_cell_m: 1, index_min_views: 1000, ann_min_views: 50000}
//     events: {log_component_events: false, max_events: 10000}
//   reconstruction: {min_translation_variance_m2: 1e-6, min_rotation_variance_rad2: 1e-6,
//                    max_iterations: 100, function_tolerance: 1e-12, compute_covariances: true}
//
// reconstruction.motion is not a key: the engine always uses tracker.motion for it.
// An unknown key, a value of the wrong type or an invalid value is an omnicml::Error
// "<file>:<line>: ..." naming the key with its section path ("tracker.gama").
//
// The dump (EngineOptionsToYaml) writes every key with doubles in their shortest
// round-trip form, so ParseEngineOptionsYaml(EngineOptionsToYaml(o)) == o bit for bit.
//
// Pure functions; thread-safe.
#ifndef OMNICML_EXPERIMENTS_RUN_CONFIG_H_
#define OMNICML_EXPERIMENTS_RUN_CONFIG_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/sensor/frame.h"

namespace omnicml {

// Reads options from YAML text on top of `base`; `source` names the text in errors
// (normally the file path). Validates the result (CmlEngineOptions::Validate, the
// message prefixed with the source). Throws omnicml::Error.
CmlEngineOptions ParseEngineOptionsYaml(const std::string& yaml_text, const std::string& source,
                                        const CmlEngineOptions& base);
// The same on top of the defaults.
CmlEngineOptions ParseEngineOptionsYaml(const std::string& yaml_text, const std::string& source);

// Reads the YAML file at `path` on top of the defaults (ParseEngineOptionsYaml). Throws
// omnicml::Error naming the path when it cannot be read.
CmlEngineOptions LoadEngineOptionsYaml(const std::string& path);

// Every option as YAML (the format above), ending in a newline.
std::string EngineOptionsToYaml(const CmlEngineOptions& options);

// Whether two option sets are equal field by field (exact doubles).
bool SameEngineOptions(const CmlEngineOptions& a, const CmlEngineOptions& b);

// The most used options as command-line flags, applied on top of the configuration file.
struct OptionOverrides {
  std::string config_path;                 // --config FILE.yaml ("" = defaults)
  std::optional<std::string> forgetting;   // --forgetting active|passive|static
  std::optional<double> e_max;             // --e-max (descriptor distance units)
  std::optional<int> update_delay_frames;  // --update-delay (frames)
  std::optional<std::string> descriptor;   // --descriptor fourier|ifh|color
  std::optional<int> threads;              // --threads (1 = no worker)

  // True when only threads and forgetting are set (what may change on a loaded engine).
  bool OnlyThreadsAndForgetting() const {
    return config_path.empty() && !e_max && !update_delay_frames && !descriptor;
  }
};

// Defaults <- config file <- flags; validated. Throws omnicml::Error naming the flag or key.
CmlEngineOptions ResolveEngineOptions(const OptionOverrides& overrides);
// The same on top of `base` instead of the defaults.
CmlEngineOptions ResolveEngineOptions(const OptionOverrides& overrides, const CmlEngineOptions& base);

// Where the frames of a run come from: logs on disk (the sessions of every LOGDIR in
// order) or a built-in simulated world rendered in-process.
struct RunInput {
  std::vector<std::string> log_dirs;    // multi-day logs or single sessions, in order
  std::string world;                    // built-in world name, when log_dirs is empty
  int days = 1;                         // simulated days (world only), >= 1
  int first_day = 0;                    // first simulated day (world only; resume a run), >= 0
  int frames_per_day = 0;               // simulated frames per day; 0 = SimulatorOptions' default (300)
  std::uint64_t seed = 1;               // simulator seed (world only)
  // Simulated images (world only; --sim-image): kRawRing renders the panorama, then the
  // catadioptric ring the engine unwraps (exercises the unwrapper); kPanorama hands the
  // engine the rendered panorama with sensor noise, no ring and no unwrap (faster; the
  // pixels differ by the ring's resampling, so the errors differ a little: docs/results.md
  // "Simulator speed").
  ImageKind sim_image = ImageKind::kRawRing;
  // World only: render the frames on a thread of their own, up to a few frames ahead of
  // the engine (PrefetchFrames); the frames are the same bytes either way.
  bool prefetch_frames = true;
  bool skip_unreadable_frames = false;  // logs only: skip (and count) unreadable frames

  // Exactly one of log_dirs / world; days >= 1; frames_per_day >= 0. Throws
  // omnicml::Error naming the flag; a missing log directory is named too.
  void Validate() const;
  // One line for reports ("logs a, b" or "world home_store, days 1-3, 400 frames/day, seed 1").
  std::string Describe() const;
};

// The options of a run that starts a new map: ResolveEngineOptions, and when they say
// motion_noise_source: identified, the motion noise and appearance_sigma_m identified
// from the first session of `input` (engine/calibration.h ApplyMotionCalibration) under
// the configuration file and the flags (explicit values win). *note (if not null) gets
// one line on what was identified, or "" with configured motion noise. Reads the first
// session once more (a second FrameSource). Throws omnicml::Error.
CmlEngineOptions ResolveNewMapOptions(const OptionOverrides& overrides, const RunInput& input,
                                      std::string* note);

// Opens the input. For logs the constructor of LogReader validates every session.yaml
// and frames.csv header; for worlds the simulator is built. Throws omnicml::Error.
std::unique_ptr<FrameSource> OpenFrameSource(const RunInput& input);

// A source that reads `inner` on a thread of its own, at most `depth` (>= 1) frames
// ahead of the consumer, and delivers exactly inner's frames in inner's order (so the
// output does not depend on whether frames are prefetched). inner's NumSessions and
// Session must be constant (they are called from the consumer's thread while the
// thread reads frames); an exception thrown by inner's Next is rethrown by the Next
// that would have delivered the frame. Destroying the source stops the thread.
std::unique_ptr<FrameSource> PrefetchFrames(std::unique_ptr<FrameSource> inner, int depth = 4);

// Frames the source will deliver (counted from the frames.csv files or days x frames
// per day), or std::nullopt when unknown; for progress and ETA only.
std::optional<std::int64_t> CountFrames(const RunInput& input, const FrameSource& source);

// Survey mapping (survey.h, docs/design.md "Survey mapping"): the first `days` days
// build the map from trusted poses, CML runs on it afterwards.
struct SurveyOptions {
  // Engine sessions (days) 0 .. days - 1 are survey days; 0 = no survey. >= 0.
  int days = 0;
  // TUM file of trusted poses ("" = the input's ground truth).
  std::string poses_path;
  // Standard deviations of a trusted pose: the covariance the survey's map updates carry
  // (and p(x_t) at the survey frames). Metres / radians, > 0.
  double position_sigma_m = 0.05;
  double heading_sigma_rad = 0.02;

  // Throws omnicml::Error naming the flag (--survey-days, --survey-poses).
  void Validate() const;
  bool enabled() const { return days > 0; }
  // diag(sigma_x^2, sigma_y^2, sigma_phi^2).
  Eigen::Matrix3d Covariance() const;
};

// What `omnicml run` and `omnicml compare` share: input, option overrides, output
// directory and progress settings (filled from command-line flags).
struct RunSettings {
  RunInput input;
  OptionOverrides overrides;
  std::string out_dir;                  // run directory ("" = a dated default)
  bool quiet = false;                   // no progress output
  bool no_progress_bar = false;         // plain log lines even on a terminal
  std::int64_t log_every_frames = 500;  // frames between plain progress lines
  SurveyOptions survey;                 // --survey-days, --survey-poses (none by default)
};

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_RUN_CONFIG_H_
