#include "omnicml/engine/calibration.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>
#include <sstream>

#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/tracking/motion_noise_identification.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

// x > 0 rounded to the nearest of 2^(n / steps_per_octave), n an integer.
double RoundToOctaveSteps(double x, double steps_per_octave) {
  return std::exp2(std::round(std::log2(x) * steps_per_octave) / steps_per_octave);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const std::size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  return v[mid];
}

// The curve's median distance at odometry path `path_m` (linear between lags; 0 at 0 m).
double DistanceAtPath(const std::vector<CalibrationPoint>& curve, double path_m) {
  double previous_path = 0.0, previous_e = 0.0;
  for (const CalibrationPoint& p : curve) {
    if (p.median_path_m >= path_m) {
      const double dp = p.median_path_m - previous_path;
      const double f = dp > 0 ? (path_m - previous_path) / dp : 1.0;
      return previous_e + f * (p.median_distance - previous_e);
    }
    previous_path = p.median_path_m;
    previous_e = p.median_distance;
  }
  return previous_e;
}

// A frame read for the loop pairs.
struct LoopFrame {
  int session = 0;
  int index = 0;        // in its session
  double path_m = 0.0;  // odometry path from its session's start
};

// For every frame t, its nearest frame s in appearance among the earlier frames that may
// pair with it (the same session at least min_path_m of odometry path earlier, or an
// earlier session when both start at a known pose), when closer than e_loop; evenly
// subsampled to max_pairs.
std::vector<SessionLoopPair> FindLoopPairs(const DescriptorExtractor& extractor,
                                           const std::vector<Descriptor>& y,
                                           const std::vector<LoopFrame>& frames,
                                           const std::vector<OdometrySession>& sessions,
                                           double min_path_m, double e_loop, int max_pairs,
                                           bool use_heading) {
  std::vector<SessionLoopPair> pairs;
  const int n = static_cast<int>(y.size());
  for (int t = 1; t < n; ++t) {
    const LoopFrame& ft = frames[t];
    int best = -1;
    double best_e = e_loop;
    for (int s = 0; s < t; ++s) {
      const LoopFrame& fs = frames[s];
      if (fs.session == ft.session) {
        if (ft.path_m - fs.path_m < min_path_m) continue;
      } else if (!(sessions[fs.session].known_start && sessions[ft.session].known_start)) {
        continue;
      }
      const double e = extractor.Distance(y[s], y[t]);
      if (e < best_e) {
        best_e = e;
        best = s;
      }
    }
    // The descriptor's relative heading: the robot's heading at t minus at s (nullopt for
    // descriptors without rotation information; the pair then constrains x, y only).
    if (best >= 0) {
      pairs.push_back(
          SessionLoopPair{frames[best].session, frames[best].index, ft.session, ft.index,
                          use_heading ? extractor.RelativeHeading(y[t], y[best]) : std::nullopt});
    }
  }
  if (static_cast<int>(pairs.size()) <= max_pairs) return pairs;
  std::vector<SessionLoopPair> kept;
  for (int i = 0; i < max_pairs; ++i) {
    kept.push_back(
        pairs[static_cast<std::size_t>(i) * pairs.size() / static_cast<std::size_t>(max_pairs)]);
  }
  return kept;
}

// The spatial thresholds a match length scales (ScaleSpatialThresholds), times s.
void MultiplySpatialThresholds(double s, CmlEngineOptions* options) {
  options->appearance_sigma_m *= s;
  options->anchor_max_sigma_m *= s;
  options->map_update_spacing_m *= s;
  options->model.forgetting.d_for_m *= s;
  options->model.index.spatial_cell_m *= s;
}

}  // namespace

void CalibrationOptions::Validate() const {
  if (max_frames < 2)
    throw Error(StrCat("CalibrationOptions.max_frames must be > 1, got ", max_frames));
  if (max_lag_frames < 1) {
    throw Error(StrCat("CalibrationOptions.max_lag_frames must be >= 1, got ", max_lag_frames));
  }
  if (!(std::isfinite(reference_match_length_m) && reference_match_length_m > 0)) {
    throw Error(StrCat("CalibrationOptions.reference_match_length_m must be > 0, got ",
                       reference_match_length_m));
  }
  if (!(min_scale > 0 && min_scale <= max_scale && std::isfinite(max_scale))) {
    throw Error("CalibrationOptions.min_scale/max_scale must satisfy 0 < min <= max");
  }
  if (scale_steps_per_octave < 0) {
    throw Error(StrCat("CalibrationOptions.scale_steps_per_octave must be >= 0, got ",
                       scale_steps_per_octave));
  }
  if (!(std::isfinite(loop_min_path_match_lengths) && loop_min_path_match_lengths > 0)) {
    throw Error(StrCat("CalibrationOptions.loop_min_path_match_lengths must be > 0, got ",
                       loop_min_path_match_lengths));
  }
  if (max_loop_pairs < 1) {
    throw Error(StrCat("CalibrationOptions.max_loop_pairs must be >= 1, got ", max_loop_pairs));
  }
  identification.Validate();
}

Calibration Calibrate(FrameSource& source, const CmlEngineOptions& options,
                      const CalibrationOptions& calibration_options) {
  calibration_options.Validate();
  if (source.NumSessions() < 1) throw Error("calibrate: the log has no session");
  const std::unique_ptr<DescriptorExtractor> extractor =
      MakeDescriptorExtractor(options.descriptor);
  // Every frame read (sessions in order, up to max_frames): descriptor, session, index in
  // its session, odometry path from its session's start; per session the dead reckoning.
  std::vector<Descriptor> y;
  std::vector<LoopFrame> frames;
  std::vector<OdometrySession> sessions;
  std::unique_ptr<OmniUnwrapper> unwrapper;
  int panorama_columns = 0;
  Frame frame;
  Pose2 last_odom = Pose2::Zero();
  while (static_cast<int>(y.size()) < calibration_options.max_frames && source.Next(&frame)) {
    if (frame.session_index != static_cast<int>(sessions.size()) - 1) {
      const SessionInfo& info = source.Session(frame.session_index);
      unwrapper.reset();
      if (info.camera.kind == ImageKind::kRawRing) {
        unwrapper =
            std::make_unique<OmniUnwrapper>(info.camera.calibration, info.camera.image_width,
                                            info.camera.image_height, info.camera.mask);
      }
      sessions.resize(static_cast<std::size_t>(frame.session_index) + 1);
      OdometrySession& s = sessions.back();
      s.known_start = info.start.mode == SessionStartMode::kKnownPose;
      s.start_covariance = s.known_start ? info.start.covariance : Eigen::Matrix3d::Zero();
      s.poses.push_back(s.known_start ? info.start.map_T_robot : Pose2::Zero());
    } else {
      OdometrySession& s = sessions.back();
      s.poses.push_back(
          ApplyIncrement(s.poses.back(), ComputeIncrement(last_odom, frame.odom_T_robot)));
    }
    const cv::Mat panorama =
        unwrapper ? PreparePanorama(unwrapper->Unwrap(frame.image), options.panorama_width,
                                    options.panorama_height)
                  : PreparePanorama(frame.image, options.panorama_width, options.panorama_height);
    panorama_columns = panorama.cols;
    // Pixels outside a clipped ring or under the user mask do not count (descriptor.h).
    y.push_back(extractor->ComputeMasked(
        panorama, unwrapper ? unwrapper->MaskFor(panorama.cols, panorama.rows) : cv::Mat()));
    const bool first_of_session = frames.empty() || frames.back().session != frame.session_index;
    LoopFrame f;
    f.session = frame.session_index;
    f.index = static_cast<int>(sessions.back().poses.size()) - 1;
    f.path_m = first_of_session
                   ? 0.0
                   : frames.back().path_m + std::hypot(frame.odom_T_robot.x() - last_odom.x(),
                                                       frame.odom_T_robot.y() - last_odom.y());
    frames.push_back(f);
    last_odom = frame.odom_T_robot;
  }
  if (sessions.empty()) throw Error("calibrate: the first session has fewer than two frames");
  const int n = static_cast<int>(sessions[0].poses.size());  // the first session's frames
  if (n < 2) throw Error("calibrate: the first session has fewer than two frames");
  std::vector<double> path_m;
  for (int t = 0; t < n; ++t) path_m.push_back(frames[static_cast<std::size_t>(t)].path_m);

  Calibration c;
  c.frames_used = n;
  c.e_max = options.model.retrieval.e_max;
  {
    std::vector<double> steps;
    for (int t = 1; t < n; ++t) steps.push_back(path_m[t] - path_m[t - 1]);
    c.median_step_m = Median(steps);
  }
  const int max_lag = std::min(calibration_options.max_lag_frames, n - 1);
  bool found = false;
  double previous_path = 0.0, previous_e = 0.0;
  for (int lag = 1; lag <= max_lag; ++lag) {
    std::vector<double> e, p;
    for (int t = 0; t + lag < n; ++t) {
      e.push_back(extractor->Distance(y[t], y[t + lag]));
      p.push_back(path_m[t + lag] - path_m[t]);
    }
    CalibrationPoint point{lag, static_cast<int>(e.size()), Median(p), Median(e)};
    c.curve.push_back(point);
    if (!found && point.median_distance >= c.e_max) {
      // Linear interpolation between the previous lag (or zero path at E = 0) and this one.
      const double de = point.median_distance - previous_e;
      const double f = de > 0 ? (c.e_max - previous_e) / de : 1.0;
      c.match_length_m = previous_path + f * (point.median_path_m - previous_path);
      found = true;
    }
    previous_path = point.median_path_m;
    previous_e = point.median_distance;
  }
  if (!found) {
    c.saturated = true;
    c.match_length_m = c.curve.back().median_path_m;
  }
  c.measured_scale = c.match_length_m / calibration_options.reference_match_length_m;
  c.scale =
      std::clamp(c.measured_scale, calibration_options.min_scale, calibration_options.max_scale);
  if (calibration_options.scale_steps_per_octave > 0) {
    c.scale = RoundToOctaveSteps(c.scale, calibration_options.scale_steps_per_octave);
  }

  c.loop_e_max = DistanceAtPath(c.curve, 0.5 * c.match_length_m);
  const std::vector<SessionLoopPair> pairs = FindLoopPairs(
      *extractor, y, frames, sessions,
      calibration_options.loop_min_path_match_lengths * c.match_length_m, c.loop_e_max,
      calibration_options.max_loop_pairs, calibration_options.use_relative_heading);
  // Prior centres of the offsets from the log: a pair is accepted within about L / 2 of
  // travel, i.e. a position offset of up to about L / 2 (per-axis variance (L / 4)^2 for
  // an offset uniform on that disc), and the relative heading resolves about one
  // panorama column.
  MotionNoiseIdentificationOptions identification = calibration_options.identification;
  if (c.match_length_m > 0) {
    identification.appearance_variance_prior_m2 = std::pow(0.25 * c.match_length_m, 2);
    // Frames that match lie within about L / 2 of each other, so an offset sd beyond L is
    // not an offset: it would absorb aliased pairs, which the gate must reject instead.
    identification.max_appearance_variance_m2 =
        std::min(identification.max_appearance_variance_m2,
                 std::max(c.match_length_m * c.match_length_m,
                          2.0 * identification.min_appearance_variance_m2));
  }
  if (panorama_columns > 0) {
    identification.heading_variance_prior_rad2 = std::pow(2.0 * kPi / panorama_columns, 2);
  }
  c.motion = IdentifyMotionNoise(sessions, pairs, identification);
  c.loop_frames = static_cast<int>(y.size());
  c.loop_sessions = static_cast<int>(sessions.size());
  return c;
}

double MedianOdometryStep(FrameSource& source, int max_frames, double min_step_m) {
  if (max_frames < 2)
    throw Error(StrCat("MedianOdometryStep: max_frames must be >= 2, got ", max_frames));
  std::vector<Pose2> odometry;
  Frame frame;
  for (int read = 0; read < max_frames && source.Next(&frame); ++read) {
    if (frame.session_index != 0) break;
    odometry.push_back(frame.odom_T_robot);
  }
  return MedianOdometryStep(odometry, min_step_m);
}

double MedianOdometryStep(const std::vector<Pose2>& odometry, double min_step_m) {
  std::vector<double> steps;
  for (std::size_t k = 1; k < odometry.size(); ++k) {
    const double step =
        std::hypot(odometry[k].x() - odometry[k - 1].x(), odometry[k].y() - odometry[k - 1].y());
    if (step > min_step_m) steps.push_back(step);
  }
  return steps.size() < 2 ? 0.0 : Median(steps);
}

double FrameStepScale(double reference_step_m, double step_m) {
  if (!(reference_step_m > 0.0) || !(step_m > 0.0)) return 1.0;
  return RoundToOctaveSteps(reference_step_m / step_m, 2.0);
}

bool ScaleSpatialThresholds(const Calibration& calibration, CmlEngineOptions* options) {
  if (calibration.saturated || !(calibration.match_length_m > 0)) return false;
  MultiplySpatialThresholds(calibration.scale, options);
  return true;
}

void UseEngineIdentificationOptions(const CmlEngineOptions& options,
                                    MotionNoiseIdentificationOptions* identification) {
  identification->offset_dof = options.motion_noise_offset_dof;
  identification->joint_pairs = options.motion_noise_joint_pairs;
}

bool ApplyMotionCalibration(const Calibration& calibration, CmlEngineOptions* options) {
  if (!calibration.motion.identified) return false;
  options->tracker.motion = calibration.motion.noise;
  options->reconstruction.motion = calibration.motion.noise;
  options->appearance_sigma_m = std::sqrt(calibration.motion.appearance_variance_m2);
  return true;
}

std::vector<std::array<double, 2>> AppearanceOffsetCurve(const Calibration& calibration) {
  std::vector<std::array<double, 2>> out;
  for (const CalibrationPoint& p : calibration.curve) {
    if (!(p.median_path_m > (out.empty() ? 0.0 : out.back()[0]))) continue;
    out.push_back({p.median_path_m, p.median_distance});
    if (p.median_distance >= calibration.e_max) break;
  }
  return out;
}

std::string Calibration::ToYaml() const {
  std::ostringstream s;
  s.precision(6);
  s << "# omnicml calibrate: " << frames_used << " frames of the first session, median step "
    << median_step_m << " m\n";
  s << "# descriptor distance E reaches e_max " << e_max << " after " << match_length_m
    << " m of travel" << (saturated ? " (not reached: largest lag measured)" : "") << "; scale "
    << scale << " (measured " << measured_scale << ", clamped and rounded)\n";
  s << "# lag_frames, median path m, median E\n";
  for (std::size_t i = 0; i < curve.size(); ++i) {
    if (i >= 20 && (i + 1) % 20 != 0 && i + 1 != curve.size()) continue;
    s << "#   " << curve[i].lag_frames << ", " << curve[i].median_path_m << ", "
      << curve[i].median_distance << "\n";
  }
  const MotionNoiseIdentification& m = motion;
  s << "# loop pairs (E < " << loop_e_max << ") in " << loop_frames << " frames of "
    << loop_sessions << " session(s): " << m.pairs << ", used " << m.pairs_used;
  if (m.identified) {
    s << "; motion noise identified: a1 " << m.noise.a1 << ", a2 " << m.noise.a2 << ", a3 "
      << m.noise.a3 << ", a4 " << m.noise.a4 << ", appearance offset sigma "
      << std::sqrt(m.appearance_variance_m2) << " m, heading offset sigma "
      << std::sqrt(m.heading_variance_rad2) << " rad; " << m.pairs_with_heading
      << " pairs with heading; NIS / chi-square median: median " << m.median_nis_ratio
      << " (consistent 1), NIS / dof: mean " << m.mean_nis_per_dof;
    if (m.joint_pairs_used > 0) {
      s << "; a1..a4 from the joint likelihood of " << m.joint_pairs_used << " pairs";
    }
    s << "\n";
    // Which parameters the loops identified and which the prior holds.
    const char* names[kIdentifiedParameters] = {"a1", "a2", "a3", "a4", "rho", "rho_phi"};
    s << "#   posterior sd of ln(value) / share of curvature from the loops:";
    for (int j = 0; j < kIdentifiedParameters; ++j) {
      s << (j ? ", " : " ") << names[j] << " " << m.log_sd[j] << " / " << m.data_share[j];
    }
    s << "\n";
  } else {
    s << "; too few to identify the motion noise\n";
  }
  CmlEngineOptions scaled;  // the defaults' spatial thresholds times s
  MultiplySpatialThresholds(scale, &scaled);
  s << "appearance_sigma_m: " << scaled.appearance_sigma_m << "\n";
  s << "anchor_max_sigma_m: " << scaled.anchor_max_sigma_m << "\n";
  // The default spacing is 0 (every frame), so the scaled one is a suggestion only.
  s << "# map updates spaced by travel, for frames closer than this (docs/guide.md \"Your "
       "camera's frame rate\"):\n# map_update_spacing_m: "
    << kReferenceMapUpdateSpacingM * std::min(scale, 1.0) << "\n";
  if (m.identified) {
    s << "tracker:\n  motion: {a1: " << m.noise.a1 << ", a2: " << m.noise.a2
      << ", a3: " << m.noise.a3 << ", a4: " << m.noise.a4 << "}\n";
  }
  s << "model:\n";
  s << "  d_for_m: " << scaled.model.forgetting.d_for_m << "\n";
  s << "  spatial_cell_m: " << scaled.model.index.spatial_cell_m << "\n";
  return s.str();
}

}  // namespace omnicml
