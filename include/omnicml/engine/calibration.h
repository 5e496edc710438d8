// Scale calibration from a log (`omnicml calibrate LOG`): how fast appearance changes
// with travelled distance, and the engine's spatial thresholds derived from it.
//
// The engine's spatial defaults (appearance_sigma_m, d_for_m, spatial_cell_m,
// anchor_max_sigma_m) were tuned on the simulator, where views keep matching (descriptor
// distance E below e_max) over about reference_match_length_m of travel. Calibrate reads
// the first session of a log, computes the descriptor of every frame (up to max_frames)
// with the engine's descriptor options, and measures, for frame lags 1..max_lag_frames,
// the median E between frames t and t + lag against the median odometry path length
// between them. The match length L is the path length at which the median E first
// reaches e_max (linear interpolation between lags). Each spatial threshold is then its
// default times s = L / reference_match_length_m, clamped to [min_scale, max_scale] and
// rounded to the nearest 1 / scale_steps_per_octave of an octave (logs of one place differ
// in L by a few percent; rounding gives them the same thresholds, and the worlds the
// defaults were measured on s = 1 exactly).
// Descriptor thresholds (e_max) stay: they are in descriptor units, not the world's.
//
// Motion noise (tracking/motion_noise_identification.h): the log is read on (every
// session, up to max_frames in all); a frame t and its nearest frame in appearance among
// the earlier frames of its session more than loop_min_path_match_lengths * L of odometry
// path back, or of an earlier session when both sessions start at a known pose, form a
// loop pair when closer than E(L / 2) (the curve's median distance at half the match
// length), with the descriptor's relative heading when it has one (use_relative_heading);
// a1..a4 and the appearance offset variance rho are their MAP values
// (tracking/motion_noise_identification.h), with the prior centres of rho and of the
// heading offset variance set from L ((L / 4)^2) and the panorama width (one column
// squared), and rho bounded by L^2. Their innovations need no ground truth. The curve and L
// use the first session.
//
// Pure function of the log and the options; not thread-safe per FrameSource.
#ifndef OMNICML_ENGINE_CALIBRATION_H_
#define OMNICML_ENGINE_CALIBRATION_H_

#include <array>
#include <string>
#include <vector>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/sensor/frame.h"
#include "omnicml/tracking/motion_noise_identification.h"

namespace omnicml {

struct CalibrationOptions {
  // Frames read (from the start; the first session's for the curve). > 1.
  int max_frames = 3000;
  // Largest frame lag measured. >= 1.
  int max_lag_frames = 400;
  // Match length of the world the spatial defaults were tuned on, metres, > 0: measured
  // with the default options on home_store seed 1 (1000 frames, 0.2 m steps: 0.265 m)
  // and institute seed 1 (1500 frames: 0.267 m). AntWorld route 1 gives 0.044 m.
  double reference_match_length_m = 0.27;
  // Clamp of the scale factor s.
  double min_scale = 0.02;
  double max_scale = 16.0;
  // Steps per octave s is rounded to (2: s in [0.841, 1.189) gives 1); 0 leaves s unrounded.
  // >= 0.
  int scale_steps_per_octave = 2;
  // Loop pairs: the earlier frame lies at least this many match lengths L of odometry path
  // back (so that odometry drift, not the appearance offset, dominates). > 0.
  double loop_min_path_match_lengths = 20.0;
  // Largest number of loop pairs used (evenly subsampled by the later frame). >= 1.
  int max_loop_pairs = 2000;
  // Give loop pairs the descriptor's relative heading (3-dof innovations) when the
  // descriptor provides one; false: x, y only (2 dof).
  bool use_relative_heading = true;
  MotionNoiseIdentificationOptions identification;

  // Throws omnicml::Error naming the first invalid field.
  void Validate() const;
};

// CmlEngineOptions::map_update_spacing_m at the reference match length
// (CalibrationOptions::reference_match_length_m), metres: the spacing measured in
// docs/results.md "Map updates spaced by travel". Calibration::ToYaml suggests it times s
// for s < 1 and as it is otherwise: a spacing wider than the frame step the defaults were
// chosen at costs accuracy at any match length (docs/results.md "The spacing is not a
// fraction of the match length").
inline constexpr double kReferenceMapUpdateSpacingM = 0.15;

// The median odometry step of `source`'s first session (it must be at its start), over
// its moving frames: consecutive frames whose odometry positions lie more than
// min_step_m apart (a parked robot's frames do not count). Reads at most max_frames
// frames (>= 2); images are not looked at, so a pose-only source will do. 0 when fewer
// than two moving steps were read. Throws omnicml::Error on a bad frame.
double MedianOdometryStep(FrameSource& source, int max_frames, double min_step_m);
// The same over the odometry poses of consecutive frames (a live node's first frames).
double MedianOdometryStep(const std::vector<Pose2>& odometry, double min_step_m);
// How many frames of the first session a new map reads for its frame step
// (CmlEngineOptions::reference_frame_step_m): the run's pose-only read and the live
// node's held first frames.
inline constexpr int kFrameStepSampleFrames = 300;

// The factor k for CmlEngineOptions::reference_frame_step_m: reference / step rounded to
// a half octave (2^(round(2 log2 x) / 2); 1 for x in [0.841, 1.189)). Thrun's
// per-increment variances times k (a trans^2 per frame, motion_model.h) give the same
// variance per metre at frames `step` apart as the unscaled a's at frames `reference`
// apart, and k frames then share one frame's appearance evidence. 1 when either is <= 0.
double FrameStepScale(double reference_step_m, double step_m);

// One point of the distance-versus-travel curve.
struct CalibrationPoint {
  int lag_frames = 0;
  int pairs = 0;
  double median_path_m = 0.0;    // odometry path length between the frames of a pair
  double median_distance = 0.0;  // descriptor distance E, extractor units
};

struct Calibration {
  int frames_used = 0;
  double e_max = 0.0;           // the threshold the match length refers to
  double median_step_m = 0.0;   // median odometry step between consecutive frames
  double match_length_m = 0.0;  // L; the largest measured path if E never reaches e_max
  bool saturated = false;       // E stayed below e_max up to max_lag_frames
  double measured_scale = 1.0;  // L / reference_match_length_m, before clamping and rounding
  double scale = 1.0;           // s: measured_scale clamped and rounded (CalibrationOptions)
  std::vector<CalibrationPoint> curve;
  // Loop pairs and the motion noise identified from them.
  double loop_e_max = 0.0;  // E(L / 2): the descriptor distance a loop pair is below
  int loop_frames = 0;      // frames searched for loop pairs (every session read)
  int loop_sessions = 0;
  MotionNoiseIdentification motion;

  // The derived values as an engine configuration (YAML, loadable with --config): the
  // spatial thresholds of the default CmlEngineOptions times s, and the identified motion
  // noise; the measurements as comments above them, and, as a comment, the map update
  // spacing kReferenceMapUpdateSpacingM times min(s, 1).
  std::string ToYaml() const;
};

// Sets the identification options that engine options choose (motion_noise_offset_dof,
// motion_noise_joint_pairs), so that a calibration identifies what a run with `options`
// identifies; the other fields of `identification` stay.
void UseEngineIdentificationOptions(const CmlEngineOptions& options,
                                    MotionNoiseIdentificationOptions* identification);

// Reads the first session of `source` (it must be at its start). Throws omnicml::Error
// when the session has fewer than two frames or on a bad frame.
Calibration Calibrate(FrameSource& source, const CmlEngineOptions& options,
                      const CalibrationOptions& calibration_options = {});

// Multiplies the spatial thresholds of `options` (appearance_sigma_m, anchor_max_sigma_m,
// map_update_spacing_m, model.forgetting.d_for_m, model.index.spatial_cell_m) by
// calibration.scale; returns false and leaves them when the match length was not
// measured (saturated).
bool ScaleSpatialThresholds(const Calibration& calibration, CmlEngineOptions* options);

// Writes the identified motion noise into options->tracker.motion (and
// reconstruction.motion), and rho as appearance_sigma_m = sqrt(rho), when identified;
// returns whether it was.
bool ApplyMotionCalibration(const Calibration& calibration, CmlEngineOptions* options);

// The appearance curve as CmlEngineOptions::appearance_offset_curve: (median travel m,
// median E) of calibration.curve up to and including its first point at or beyond
// e_max (a match's E is at most e_max; later points are not read), points whose travel
// does not increase skipped. Empty when the curve is.
std::vector<std::array<double, 2>> AppearanceOffsetCurve(const Calibration& calibration);

}  // namespace omnicml

#endif  // OMNICML_ENGINE_CALIBRATION_H_
