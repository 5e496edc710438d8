// Configuration of a CML run: the engine options from a YAML file (every field of
// CmlEngineOptions and its nested options structs), the dump of the effective
// configuration, command-line overrides, and reading a run directory's configuration
// back. The run's input is frame_sources.h.
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
#ifndef OMNICML_RUN_RUN_CONFIG_H_
#define OMNICML_RUN_RUN_CONFIG_H_

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/run/frame_sources.h"

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

// `base` (the defaults unless given) <- config file <- flags; validated. Throws
// omnicml::Error naming the flag or key.
CmlEngineOptions ResolveEngineOptions(const OptionOverrides& overrides,
                                      const CmlEngineOptions& base = {});

// The forgetting mode a run directory's config.yaml names (model.forgetting.mode, or a
// flat `forgetting: MODE` of older configurations): "active", "passive", "static", or
// "" when config.yaml is missing, unreadable or names none. Never throws.
std::string ReadRunForgetting(const std::filesystem::path& run_dir);

struct RunInput;  // frame_sources.h

// The options of a run that starts a new map: ResolveEngineOptions(overrides, base), with
// the values derived from the first session of `input` (engine/calibration.h Calibrate)
// under the configuration file and the flags (explicit values win): with k =
// FrameStepScale(reference_frame_step_m, the first session's MedianOdometryStep) (a
// pose-only read; nothing when the reference is 0), tracker.motion's a1..a4 times k
// unless the motion noise is identified, and hypothesis_evidence_scale times 1 / k when
// k > 1; when they say
// spatial_scale_source: calibrated, base's spatial thresholds times the
// calibrated scale (ScaleSpatialThresholds); when they say motion_noise_source:
// identified, the identified motion noise and appearance_sigma_m (ApplyMotionCalibration);
// when they say appearance_offset_source: calibrated, the first session's appearance
// curve as appearance_offset_curve (AppearanceOffsetCurve).
// *note (if not null) gets one line on what was derived, or "" when nothing was asked or
// changed. Reads the first session once more (a second FrameSource). Throws
// omnicml::Error.
CmlEngineOptions ResolveNewMapOptions(const OptionOverrides& overrides, const RunInput& input,
                                      std::string* note, const CmlEngineOptions& base = {});

// The frame-step part of ResolveNewMapOptions for a median step measured elsewhere (a
// live node's first frames, LiveEngine): ResolveEngineOptions(overrides, base) with
// a1..a4 and hypothesis_evidence_scale restated for frames step_m apart, as
// ResolveNewMapOptions does for the log's first session (explicit values win; step_m <= 0
// keeps them as configured). *note (if not null) gets the line ResolveNewMapOptions would
// write for it, or "" when nothing changed. Throws omnicml::Error.
CmlEngineOptions ResolveFrameStepOptions(const OptionOverrides& overrides, double step_m,
                                         std::string* note, const CmlEngineOptions& base = {});

}  // namespace omnicml

#endif  // OMNICML_RUN_RUN_CONFIG_H_
