#include "omnicml/run/run_config.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <mutex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/common/options.h"
#include "omnicml/common/yaml_io.h"
#include "omnicml/engine/calibration.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/report/report.h"
#include "omnicml/run/frame_sources.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {

// Engine options in YAML through the schema of cml_engine.h (VisitFields, common/options.h).
CmlEngineOptions ParseEngineOptionsYaml(const std::string& yaml_text, const std::string& source,
                                        const CmlEngineOptions& base) {
  return ParseOptionsYaml<CmlEngineOptions>(yaml_text, source, base);
}

CmlEngineOptions ParseEngineOptionsYaml(const std::string& yaml_text, const std::string& source) {
  const CmlEngineOptions defaults;
  return ParseEngineOptionsYaml(yaml_text, source, defaults);
}

CmlEngineOptions LoadEngineOptionsYaml(const std::string& path) {
  return ParseEngineOptionsYaml(ReadOptionFile(path), path);
}

std::string EngineOptionsToYaml(const CmlEngineOptions& options) { return OptionsToYaml(options); }

bool SameEngineOptions(const CmlEngineOptions& a, const CmlEngineOptions& b) {
  return SameOptions(a, b);
}

CmlEngineOptions ResolveEngineOptions(const OptionOverrides& overrides,
                                      const CmlEngineOptions& base) {
  CmlEngineOptions options = overrides.config_path.empty()
                                 ? base
                                 : ParseEngineOptionsYaml(ReadOptionFile(overrides.config_path),
                                                          overrides.config_path, base);
  if (overrides.descriptor) {
    options.descriptor.kind = DescriptorKindFromString(*overrides.descriptor);
  }
  if (overrides.forgetting)
    options.model.forgetting.mode = ForgettingModeFromString(*overrides.forgetting);
  if (overrides.e_max) options.model.retrieval.e_max = *overrides.e_max;
  if (overrides.update_delay_frames) options.update_delay_frames = *overrides.update_delay_frames;
  if (overrides.threads) options.threads = *overrides.threads;
  try {
    options.Validate();
  } catch (const Error& e) {
    throw Error(StrCat("invalid options: ", e.what()));
  }
  return options;
}

std::string ReadRunForgetting(const std::filesystem::path& run_dir) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_regular_file(run_dir / "config.yaml", ec)) return "";
  YAML::Node root;
  try {
    root = YAML::Load(ReadTextFile(run_dir / "config.yaml", 1 << 20));
  } catch (const YAML::Exception&) {
    return "";
  } catch (const Error&) {
    return "";
  }
  std::function<std::string(const YAML::Node&)> find = [&](const YAML::Node& n) -> std::string {
    if (!n.IsMap()) return "";
    for (const auto& kv : n) {
      if (kv.first.as<std::string>() == "forgetting" && kv.second.IsScalar())
        return kv.second.as<std::string>();
      // model.forgetting is a section whose `mode` is the forgetting mode.
      if (kv.first.as<std::string>() == "forgetting" && kv.second.IsMap() && kv.second["mode"] &&
          kv.second["mode"].IsScalar())
        return kv.second["mode"].as<std::string>();
      const std::string inner = find(kv.second);
      if (!inner.empty()) return inner;
    }
    return "";
  };
  return find(root);
}

namespace {

// The frame-step part of ResolveNewMapOptions: `calibrated`'s a1..a4 (unless identified)
// and hypothesis_evidence_scale restated for frames step_m apart; the note through
// add_note.
void RestateForFrameStep(const CmlEngineOptions& resolved, double step_m,
                         CmlEngineOptions* calibrated,
                         const std::function<void(const std::string&)>& add_note) {
  const double reference_step = resolved.reference_frame_step_m;
  if (!(reference_step > 0.0)) return;
  const double k = FrameStepScale(reference_step, step_m);
  if (step_m <= 0.0) {
    add_note(
        StrCat("motion noise and appearance evidence per frame as configured (the "
               "first session's odometry has fewer than two steps above ",
               0.01 * reference_step, " m)"));
    return;
  }
  if (k == 1.0) return;
  std::string what;
  if (resolved.motion_noise_source != MotionNoiseSource::kIdentified) {
    MotionNoise& m = calibrated->tracker.motion;
    m.a1 *= k;
    m.a2 *= k;
    m.a3 *= k;
    m.a4 *= k;
    what = StrCat("motion noise a1..a4 x ", k);
  }
  if (k > 1.0) {
    calibrated->hypothesis_evidence_scale /= k;
    what += StrCat(what.empty() ? "" : ", ", "appearance evidence per frame x ", 1.0 / k);
  }
  if (!what.empty()) {
    add_note(StrCat(what, " for frames ", step_m,
                    " m apart (median step of the first session; the options are stated for ",
                    reference_step, " m)"));
  }
}

}  // namespace

CmlEngineOptions ResolveFrameStepOptions(const OptionOverrides& overrides, double step_m,
                                         std::string* note, const CmlEngineOptions& base) {
  const CmlEngineOptions resolved = ResolveEngineOptions(overrides, base);
  CmlEngineOptions calibrated = base;
  std::string joined;
  RestateForFrameStep(resolved, step_m, &calibrated,
                      [&joined](const std::string& line) { joined = line; });
  if (note != nullptr) *note = joined;
  return joined.empty() ? resolved : ResolveEngineOptions(overrides, calibrated);
}

CmlEngineOptions ResolveNewMapOptions(const OptionOverrides& overrides, const RunInput& input,
                                      std::string* note, const CmlEngineOptions& base) {
  if (note != nullptr) note->clear();
  const CmlEngineOptions resolved = ResolveEngineOptions(overrides, base);
  const bool scale = resolved.spatial_scale_source == SpatialScaleSource::kCalibrated;
  const bool identify = resolved.motion_noise_source == MotionNoiseSource::kIdentified;
  const bool offsets = resolved.appearance_offset_source == AppearanceOffsetSource::kCalibrated;
  const double reference_step = resolved.reference_frame_step_m;
  CmlEngineOptions calibrated = base;  // with the derived values
  std::string joined;                  // "; "-separated notes
  const auto add_note = [&joined](const std::string& line) {
    joined += (joined.empty() ? "" : "; ") + line;
  };
  if (reference_step > 0.0) {
    // The median of a few hundred steps is stable.
    const std::unique_ptr<FrameSource> poses = OpenPoseOnlySource(input);
    RestateForFrameStep(resolved,
                        MedianOdometryStep(*poses, kFrameStepSampleFrames, 0.01 * reference_step),
                        &calibrated, add_note);
  }
  if (!scale && !identify && !offsets) {
    if (note != nullptr) *note = joined;
    return joined.empty() ? resolved : ResolveEngineOptions(overrides, calibrated);
  }
  const std::unique_ptr<FrameSource> source = OpenFrameSource(input);
  // The match length's median over a few hundred frames is stable; the motion noise needs
  // the whole first session's loops.
  CalibrationOptions calibration;
  if (!identify) calibration.max_frames = 600;
  UseEngineIdentificationOptions(resolved, &calibration.identification);
  const Calibration c = Calibrate(*source, resolved, calibration);
  if (scale) {
    if (ScaleSpatialThresholds(c, &calibrated)) {
      add_note(StrCat("spatial scale ", c.scale, " (match length ", c.match_length_m, " m over ",
                      c.frames_used, " frames of the first session)"));
    } else {
      add_note(
          StrCat("spatial scale not measured (appearance changed by less than e_max "
                 "over ",
                 c.match_length_m, " m): configured thresholds kept"));
    }
  }
  if (identify) {
    if (ApplyMotionCalibration(c, &calibrated)) {
      const MotionNoise& m = c.motion.noise;
      add_note(StrCat("motion noise identified from ", c.motion.pairs_used, " loop pairs in ",
                      c.loop_frames, " frames of ", c.loop_sessions, " session(s): a1 ", m.a1,
                      ", a2 ", m.a2, ", a3 ", m.a3, ", a4 ", m.a4, ", appearance_sigma_m ",
                      calibrated.appearance_sigma_m, " (loop NIS / chi-square median: median ",
                      c.motion.median_nis_ratio, ")"));
    } else {
      add_note(StrCat("motion noise not identified (", c.motion.pairs_used, " loop pairs in ",
                      c.loop_frames, " frames): configured values kept"));
    }
  }
  if (offsets) {
    calibrated.appearance_offset_curve = AppearanceOffsetCurve(c);
    if (calibrated.appearance_offset_curve.empty()) {
      add_note("appearance offsets not measured (no appearance curve): none");
    } else {
      add_note(StrCat("appearance offsets from the first session's appearance curve up to ",
                      calibrated.appearance_offset_curve.back()[0], " m"));
    }
  }
  if (note != nullptr) *note = joined;
  // Explicit values of the configuration file and the flags win over the derived ones.
  return ResolveEngineOptions(overrides, calibrated);
}

}  // namespace omnicml
