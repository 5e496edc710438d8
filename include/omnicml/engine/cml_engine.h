// The omniview-based CML engine [G]: one call per frame runs the whole pipeline of
// docs/design.md "Data flow" — unwrap, describe, p(x|u), p(x|y), fuse, estimate, and the
// delayed, concurrent map update with reconstruction of multimodal stretches.
//
// Per frame t (ProcessFrame):
//   1. u_t = ComputeIncrement(odom_{t-1}, odom_t)              (zero on a session's first frame)
//   2. the map updater starts applying the updates due at t    (background worker, threads >= 2)
//   3. panorama = Unwrap(raw) with the session camera's calibration, or PreparePanorama
//   4. y_t = descriptor of the panorama
//   5. barrier: exactly the updates of frames <= t - update_delay_frames are in the map
//   6. p(x|y) = model.Hypothesis(y_t); p(x|u) = Propagate(p(x_{t-1}), u_t);
//      p(x_t) = Fuse(p(x|u), {p(x|y)})                          (MixtureTracker::Step)
//   7. unimodal p(x_t) that is a confident anchor (fixed by appearance, or position
//      sigma <= anchor_max_sigma_m): (y_t, N(mu_t, C_t)) is queued, preceded by the
//      reconstructed states of the frames waiting since the previous anchor
//      (ReconstructTrajectory); multimodal, or unimodal but dead-reckoned beyond
//      anchor_max_sigma_m: y_t waits in the pending list. So a loop closure (appearance
//      pinning the robot down again after a dead-reckoned stretch) corrects the whole
//      stretch before it reaches the map, instead of the map storing its drift.
// Queued updates reach the map update_delay_frames frames later (map_updater.h), so the
// map never feeds back into the estimate it came from.
//
// Sessions (docs/design.md "Sessions"): BeginSession starts each day.
//  - kKnownPose: p(x) := N(start pose, start covariance).
//  - kContinue:  p(x) and the map go on. Odometry is assumed to be restarted by the log
//    between sessions, so the first frame of the new session has a zero increment, unless
//    CmlEngineOptions::continue_odometry_across_sessions is set, in which case the
//    increment from the previous session's last odometry pose is applied.
//  - kGlobal:    p(x) is unknown; the first p(x|y) whose best view has similarity >=
//    global_seed_min_similarity seeds the mixture. Until then ProcessFrame returns no
//    estimate and the frames neither update the map nor wait for reconstruction. If the
//    map is empty (no view and no queued update) when the session begins, localization
//    from it is impossible and the engine falls back to N(initial_pose,
//    initial_covariance) — the configured p(x_0) of an empty map.
// Frames still pending when a session begins with kKnownPose or kGlobal, or when Finish
// is called, cannot be anchored: multimodal ones are dropped (counted in the statistics),
// unimodal ones update the map with their filtered estimate.
//
// Determinism: same options and frames => bit-identical estimates and map, with
// threads = 1 or 2 and from run to run. Only the timing fields of FrameStats vary.
//
// Thread-safety: thread-compatible (one thread calls the engine). With threads >= 2 the
// engine owns one worker thread that applies map updates during ProcessFrame; between
// calls the worker is idle, so model() and SaveEngine may read the state.
#ifndef OMNICML_ENGINE_CML_ENGINE_H_
#define OMNICML_ENGINE_CML_ENGINE_H_

#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "omnicml/descriptors/descriptor.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/engine/map_updater.h"
#include "omnicml/engine/pose_graph.h"
#include "omnicml/engine/trajectory_reconstruction.h"
#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/mapping/environment_model.h"
#include "omnicml/sensor/frame.h"
#include "omnicml/tracking/motion_noise_identification.h"
#include "omnicml/tracking/tracker.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {

// Pose-gated matching (an engine-level addition to [G]): while p(x_t) is one
// Gaussian (confident tracking), p(x|y) is computed from the views that have a component
// inside the gate of the propagated prior p(x|u) only, so the exact descriptor distance
// is computed for the views near the robot instead of for the whole map. A match outside
// that gate could only enter the fusion as a new hypothesis at the floor weight
// hypothesis_weight_scale; such hypotheses (kidnapping, loop closure after long drift)
// are still found by the full search, which runs whenever p(x_t) is multimodal or
// empty (global localization) and on every frame whose index is a multiple of
// full_search_every_frames. The map update (Update: insertion iff no view of the whole
// map matches) is never gated.
struct GatedMatchingOptions {
  bool enabled = false;
  // Gate radius around the prior's mean: gate_sigmas x sqrt(largest eigenvalue of its xy
  // covariance + appearance_sigma_m^2 + the appearance offset at e_max) (the largest
  // spread a match's component gets in p(x|y)).
  // Dimensionless, > 0.
  double gate_sigmas = 4.0;
  // Frames, >= 1: every frame index that is a multiple of this searches the whole map.
  int full_search_every_frames = 10;
  // Views, >= 0: the gate applies only to maps of at least this many views (below, the
  // scan of every view costs no more than the spatial query: map_scale_benchmark,
  // FindMatchesNear against FindMatches).
  int min_views = 1000;

  void Validate() const;  // throws omnicml::Error naming the field
};
template <class V>
void VisitFields(V& v, GatedMatchingOptions& o) {
  v("enabled", o.enabled);
  v("gate_sigmas", o.gate_sigmas);
  v("full_search_every_frames", o.full_search_every_frames);
  v("min_views", o.min_views);
}

// kConfigured: tracker.motion and appearance_sigma_m as configured. kIdentified: at the
// start of a new map, the run first reads the log's first session and sets them to the
// maximum-likelihood values of its appearance loop innovations (engine/calibration.h
// Calibrate, tracking/motion_noise_identification.h); values given explicitly in the
// configuration file still win. A run that loads a map keeps the map's values.
enum class MotionNoiseSource { kConfigured, kIdentified };

// kCalibrated: at the start of a new map, the run first reads the log's first session,
// measures the match length L (the odometry path over which the descriptor distance to a
// frame reaches e_max, engine/calibration.h) and multiplies the spatial thresholds
// (appearance_sigma_m, anchor_max_sigma_m, map_update_spacing_m, model.forgetting.d_for_m,
// model.index.spatial_cell_m) by s = L / L_ref rounded to a half octave (docs/design.md
// "Spatial thresholds scaled to the log"; on the simulated worlds the defaults were
// measured on, s rounds to 1). A first session whose appearance never changes by e_max
// keeps the configured values. Values given explicitly in the configuration file or by
// flags still win; a run that loads a map keeps the map's. kConfigured (the default):
// the thresholds as configured.
enum class SpatialScaleSource { kConfigured, kCalibrated };

// kCalibrated: at the start of a new map, the run first reads the log's first session and
// sets appearance_offset_curve to its appearance curve (engine/calibration.h
// AppearanceOffsetCurve); a curve given explicitly in the configuration file still wins,
// and a run that loads a map keeps the map's. kConfigured (the default): the curve as
// configured (empty: none).
enum class AppearanceOffsetSource { kConfigured, kCalibrated };

struct CmlEngineOptions {
  // Which descriptor and its parameters (descriptor_factory.h).
  DescriptorOptions descriptor;
  // The multi-hypothesis tracker; tracker.motion is also the motion noise of the
  // reconstruction's odometry factors.
  TrackerOptions tracker;
  // The adaptive appearance map. e_max is in the descriptor's distance units: the
  // default suits the default Fourier signature (4 bands x 16 harmonics, L2, normalised
  // bands) on the simulator's panoramas.
  EnvironmentModelOptions model;
  // Reconstruction of multimodal stretches; its `motion` field is ignored (tracker.motion
  // is used).
  ReconstructionOptions reconstruction;
  // An update of frame t becomes visible to the map at frame t + update_delay_frames.
  // Frames, >= 1. It should span more than the distance over which one place's
  // descriptors stay within e_max (else fresh views drag the estimate back); the default
  // suits frames 0.2-0.3 m apart.
  int update_delay_frames = 8;
  // 1: map updates are applied on the calling thread at the barrier; >= 2: one
  // background worker applies them while the next frame is unwrapped and described.
  // Results are identical either way. Must lie in [1, kMaxThreads = 64] (common/limits.h).
  int threads = 1;
  // Reconstruct multimodal stretches at the next unimodal estimate and update the map
  // with them; false: multimodal frames never update the map.
  bool reconstruct_multimodal = true;
  // At most this many frames wait for reconstruction; older ones are dropped or, when
  // unimodal, go to the map with their filtered estimate (and the stretch loses its start
  // anchor). Frames, >= 1. It bounds the loop a closure can correct, and the damage a
  // wrong closure does. Memory about 1 kB per waiting frame.
  int max_pending_multimodal_frames = 1000;
  // Confident anchors (engine-level addition to [G 2.1]/[PK]): a unimodal estimate
  // anchors the trajectory and updates the map at once only when appearance fixed it
  // (p(x|y) was non-empty and fused into a unimodal p(x_t)) or the standard deviation of
  // its position (square root of the largest eigenvalue of the xy block of C_t) is
  // <= anchor_max_sigma_m. Otherwise (dead reckoning since the last fix) its frame waits
  // like a multimodal one and reaches the map through the reconstruction between the
  // previous and the next anchor, so the drift of a stretch without fixes is corrected
  // when appearance pins the robot down again (a loop closure) instead of being stored
  // in the map and relearned by every later lap. A waiting unimodal frame that cannot be
  // reconstructed (session start, Finish, overflow of max_pending_multimodal_frames, where
  // it becomes the anchor of the rest) updates the map with its own filtered estimate.
  // Metres, >= 0; 0 disables (every unimodal estimate is an anchor, as in [G]). Only
  // with reconstruct_multimodal.
  double anchor_max_sigma_m = 0.5;
  // Map updates spaced by travel (a motion filter, as Cartographer's before it inserts a
  // scan): a frame's (y_t, N(mu_t, C_t)) reaches the map (EnvironmentModel::Update and,
  // with the pose graph, a node) only when mu_t lies at least map_update_spacing_m from
  // the position of the session's previous map update; a session's first update always
  // does. Every frame is still localized. The phases of [G 2.3] (insertion, the mixture
  // update, rules (16)-(19)) act once per update, so without spacing a camera twice as
  // fast confirms, decays and forgets twice per metre of travel and the map depends on the
  // frame rate (docs/results.md "The map against the frame rate"); with it, on the path.
  // A spacing below the distance between frames changes nothing; a parked robot stops
  // updating the map. Metres, finite, >= 0; 0: every localized frame updates the map. A
  // spatial threshold (spatial_scale_source scales it).
  double map_update_spacing_m = 0.0;
  // Map updates smoothed over their delay (docs/design.md "Map updates smoothed over the
  // delay"): an update made from a unimodal frame's filtered estimate reaches the map
  // update_delay_frames later; with this option it then carries the Rauch-Tung-Striebel
  // smoothed estimate of its frame given the filtered estimates of the frames since, as
  // long as they stay unimodal in the same session (tracking/fixed_lag_smoother.h). The
  // map sees the update at the same frame as without it, so it still never feeds back
  // into the estimates it came from. Reconstructed states (already smoothed between
  // anchors) and survey frames are not changed. false: the filtered estimate ([G]).
  bool smooth_map_updates = true;
  // Panoramas (delivered or unwrapped) are resized to this size when both are > 0
  // (PreparePanorama); 0 keeps the size. Pixels.
  int panorama_width = 0;
  int panorama_height = 0;
  // p(x_0) when a global session starts on an empty map (map frame: m, m, rad; m^2, rad^2).
  Pose2 initial_pose = Pose2::Zero();
  Eigen::Matrix3d initial_covariance = Eigen::Vector3d(0.01, 0.01, 0.001).asDiagonal();
  // Shaping of p(x|y) before fusion (engine-level additions to [G], documented in
  // README/DESIGN notes of the engine): the model's p(x|y) is normalised to weight 1 even
  // for a single weak match, which would let one faint, possibly false, match create a
  // competing hypothesis as heavy as the whole odometry prior.
  //  - p(x|y) is ignored when its best view's similarity is below this. [0, 1].
  double hypothesis_min_similarity = 0.2;
  //  - Its weights are multiplied by the best view's similarity S_max (<= 1), so the
  //    unmatched components it contributes to Fuse (new hypotheses) carry at most S_max.
  bool hypothesis_weight_by_similarity = true;
  //  - ... and by its prior: the weight of p(x|u) within its gate (2) (normalised), but at
  //    least this factor in (0, 1]: the prior odds that an appearance match far from
  //    every current hypothesis is a new place hypothesis (kidnapping, loop closure)
  //    rather than aliasing. Repeated matches there raise its weight by [G] (8), in
  //    proportion to its prior.
  double hypothesis_weight_scale = 0.1;
  //  - appearance_sigma_m^2 is added to the x and y variances of every component: a view
  //    matches over a neighbourhood of its place, not only at its exact pose. Metres, >= 0.
  double appearance_sigma_m = 0.5;
  //  - ... plus the match's appearance offset: with a non-empty appearance_offset_curve,
  //    (d(E) / 2)^2 is added to the x and y variances of the components of a view
  //    matched at descriptor distance E (and to a pose-graph closure from it), d(E) the
  //    travel at which the curve first reaches E (AppearanceOffsetVariance).
  //    appearance_sigma_m is the spread of the closest matches (the identification's
  //    loop pairs, E < E(L / 2)); a view still matches up to e_max, and a match that far
  //    in appearance lies on median d(E) of travel from the view's place. An offset
  //    uniform on a disc of radius d has per-axis variance d^2 / 4, the identification's
  //    prior rho_0 = (L / 4)^2 at E(L / 2) (docs/design.md "Appearance offset of a
  //    match"). The curve: (travel in metres, median descriptor distance E in the
  //    extractor's units) points, travel increasing from > 0, E >= 0, as the first
  //    session's calibration measures it (appearance_offset_source). Empty: none.
  std::vector<std::array<double, 2>> appearance_offset_curve;
  //  - ... and, when true, the part of each matched component's spread
  //    (ViewComponent::spread, the scatter of the positions merged into it) that neither
  //    its own covariance nor appearance_sigma_m^2 explains (per principal axis,
  //    SpreadBeyond): a component merged from matches along 3 m of aisle says where the
  //    view matches, not where in those 3 m the robot stands. Also added to a pose-graph
  //    closure from the match (its largest axis). docs/design.md "Spread of a component".
  bool appearance_offset_spread = false;
  //  - ... and, while tracking, by this factor in (0, 1]: the weight one frame's
  //    appearance evidence adds to the hypotheses it supports ([G] (8): w_a + w_b) and
  //    gives a new one, and its pull in covariance intersection ((5)). Neighbouring
  //    frames match the same views, so their evidence is not independent; at frames k
  //    times denser than the step the defaults were chosen at, 1 / k keeps the evidence
  //    per metre of travel (reference_frame_step_m sets it so at a new map). 1: [G]'s
  //    per-frame evidence.
  double hypothesis_evidence_scale = 1.0;
  // Global start: the smallest similarity S of the best matching view for p(x|y) to seed
  // the mixture. Dimensionless, in [0, 1].
  double global_seed_min_similarity = 0.3;
  // kContinue sessions: apply the odometry increment from the previous session's last
  // frame to the new session's first frame (the log's odometry runs on across sessions).
  bool continue_odometry_across_sessions = false;
  // Global pose graph (pose_graph.h, docs/design.md "Global pose graph"): anchor poses,
  // odometry and appearance loop closures optimised under a robust loss when a loop
  // closes; the views move with the nodes that created them. Off by default.
  PoseGraphOptions pose_graph;
  // Pose-gated matching while tracking (above). Off by default.
  GatedMatchingOptions gated_matching;
  // Where tracker.motion (and appearance_sigma_m) come from when a run starts a new map
  // (MotionNoiseSource); read by the run layer, which calibrates before the first frame.
  MotionNoiseSource motion_noise_source = MotionNoiseSource::kConfigured;
  // Where the spatial thresholds come from when a run starts a new map
  // (SpatialScaleSource); read by the run layer with the motion noise above.
  SpatialScaleSource spatial_scale_source = SpatialScaleSource::kConfigured;
  // Where appearance_offset_curve comes from when a run starts a new map
  // (AppearanceOffsetSource); read by the run layer with the motion noise above.
  AppearanceOffsetSource appearance_offset_source = AppearanceOffsetSource::kConfigured;
  // The frame step the per-frame quantities of the options are stated for: the motion
  // noise a1..a4 and the weight of one frame's appearance evidence
  // (hypothesis_evidence_scale). Metres, finite, >= 0; 0: both are used per frame as
  // configured. When a run starts a new map it first reads the odometry of the log's
  // first session (no images), takes the median step d of its moving frames (steps above
  // 1 % of this reference) and k = reference / d rounded to a half octave
  // (FrameStepScale, engine/calibration.h), then
  //  - multiplies a1..a4 by k: Thrun's variances grow with the square of an increment
  //    (motion_model.h), so the same a's give frames twice as dense half the variance per
  //    metre, while odometry errors do not depend on how often the camera takes a frame
  //    (not with motion_noise_source identified, whose a's are measured at the log's own
  //    step);
  //  - multiplies hypothesis_evidence_scale by min(1, 1 / k): neighbouring frames match
  //    the same views, so k times as many frames per metre would count the same
  //    evidence k times.
  // (docs/design.md "Per-frame quantities restated per metre of travel"). The default is
  // the simulator's step, at which the defaults were chosen; k rounds to 1 for steps
  // within about 19 % of it, so those logs run as configured. Values given explicitly in
  // the configuration file or by flags are not scaled; a run that loads a map keeps the
  // map's.
  double reference_frame_step_m = 0.2;
  // With motion_noise_source identified: the degrees of freedom of the Student t refit
  // that gives appearance_sigma_m (MotionNoiseIdentificationOptions::offset_dof; 0 takes
  // it from the Gaussian fit). Finite, >= 0.
  double motion_noise_offset_dof = MotionNoiseIdentificationOptions{}.offset_dof;
  // With motion_noise_source identified: a1..a4 from the joint likelihood of the heading
  // innovations of up to this many loop pairs (MotionNoiseIdentificationOptions::
  // joint_pairs; 0 treats the pairs as independent). Pairs, >= 0.
  int motion_noise_joint_pairs = MotionNoiseIdentificationOptions{}.joint_pairs;

  // Throws omnicml::Error naming the first invalid field (including nested options,
  // prefixed "descriptor.", "tracker.", "model.", "reconstruction.").
  void Validate() const;
};

// The options schema (common/options.h): YAML keys (run/run_config.h), dump, and the options
// section of engine files (engine_io.h).
template <class V>
void VisitFields(V& v, CmlEngineOptions& o) {
  v("update_delay_frames", o.update_delay_frames);
  v("threads", o.threads);
  v("reconstruct_multimodal", o.reconstruct_multimodal);
  v("max_pending_multimodal_frames", o.max_pending_multimodal_frames);
  v("anchor_max_sigma_m", o.anchor_max_sigma_m);
  v("panorama_width", o.panorama_width);
  v("panorama_height", o.panorama_height);
  v("initial_pose", o.initial_pose);
  v("initial_covariance", o.initial_covariance);
  v("global_seed_min_similarity", o.global_seed_min_similarity);
  v("hypothesis_min_similarity", o.hypothesis_min_similarity);
  v("hypothesis_weight_by_similarity", o.hypothesis_weight_by_similarity);
  v("hypothesis_weight_scale", o.hypothesis_weight_scale);
  v("appearance_sigma_m", o.appearance_sigma_m);
  v("continue_odometry_across_sessions", o.continue_odometry_across_sessions);
  v.Section("descriptor", o.descriptor);
  v.Section("tracker", o.tracker);
  v.Section("model", o.model);
  v.Section("reconstruction", o.reconstruction);
  v.Section("pose_graph", o.pose_graph);
  v.Section("gated_matching", o.gated_matching);
  // After engine file format 14: stored only when not the default (common/options.h).
  v.Since(15, [&](auto& w) {
    w.NamedEnum("motion_noise_source", o.motion_noise_source,
                {{MotionNoiseSource::kConfigured, "configured"},
                 {MotionNoiseSource::kIdentified, "identified"}});
    w.NamedEnum("spatial_scale_source", o.spatial_scale_source,
                {{SpatialScaleSource::kConfigured, "configured"},
                 {SpatialScaleSource::kCalibrated, "calibrated"}});
    w("motion_noise_offset_dof", o.motion_noise_offset_dof);
    w("motion_noise_joint_pairs", o.motion_noise_joint_pairs);
    w("appearance_offset_curve", o.appearance_offset_curve);
    w.NamedEnum("appearance_offset_source", o.appearance_offset_source,
                {{AppearanceOffsetSource::kConfigured, "configured"},
                 {AppearanceOffsetSource::kCalibrated, "calibrated"}});
    w("appearance_offset_spread", o.appearance_offset_spread);
  });
  // Engine file format 16 (added after 15 without a bump, then made part of 16).
  v.Since(16, [&](auto& w) {
    w("map_update_spacing_m", o.map_update_spacing_m);
    w("reference_frame_step_m", o.reference_frame_step_m);
    w("hypothesis_evidence_scale", o.hypothesis_evidence_scale);
  });
  // Engine file format 17.
  v.Since(17, [&](auto& w) { w("smooth_map_updates", o.smooth_map_updates); });
}

// (d(E) / 2)^2 in m^2 (CmlEngineOptions::appearance_offset_curve): d(E) the travel at
// which `curve` first reaches descriptor distance e, interpolated linearly from (0 m,
// E 0) through the points; the last point's travel when the curve never reaches e; 0
// for an empty curve or e <= 0.
double AppearanceOffsetVariance(const std::vector<std::array<double, 2>>& curve, double e);

// Adds each match's appearance offset variance (AppearanceOffsetVariance of its distance)
// to the x and y variances of its view's components in `p_x_y`, which must be
// model.Hypothesis(matches) (match order, then component order). Nothing for an empty
// curve or hypothesis.
void AddAppearanceOffsets(const EnvironmentModel& model, const std::vector<ViewMatch>& matches,
                          const std::vector<std::array<double, 2>>& curve, Mixture* p_x_y);

// The part of a spread (symmetric positive semi-definite, m^2) that `floor` (symmetric,
// m^2) does not explain: the positive part V diag(max(l_i, 0)) V^T of spread - floor =
// V diag(l) V^T.
Eigen::Matrix2d SpreadBeyond(const Eigen::Matrix2d& spread, const Eigen::Matrix2d& floor);

// docs/design.md (S2): the part of component c's spread that neither its covariance C nor
// the appearance neighbourhood (neighbourhood_m2 I, m^2) explains,
// SpreadBeyond(c.spread - C_xy, neighbourhood_m2 I) (m^2, symmetric positive
// semi-definite).
Eigen::Matrix2d SpreadExcess(const ViewComponent& c, double neighbourhood_m2);

// Adds SpreadExcess(c, neighbourhood_m2) of each matched component c to the xy block of
// its Gaussian in `p_x_y`, which must be model.Hypothesis(matches) (match order, then
// component order). Nothing for an empty hypothesis.
void AddSpreadOffsets(const EnvironmentModel& model, const std::vector<ViewMatch>& matches,
                      double neighbourhood_m2, Mixture* p_x_y);

// Timing (microseconds, wall clock) and sizes of one ProcessFrame call.
struct FrameStats {
  double unwrap_us = 0.0;    // unwrapping / panorama preparation
  double describe_us = 0.0;  // descriptor computation
  double update_us = 0.0;    // time blocked at the map barrier (includes synchronous application)
  double apply_us = 0.0;     // time the map updates took to apply (either thread)
  double match_us = 0.0;     // FindMatches + Hypothesis
  double fuse_us = 0.0;      // propagation, fusion, summary
  double reconstruct_us = 0.0;  // pose-graph reconstruction (0 when none)
  double pose_graph_us = 0.0;   // global pose graph: closure, optimisation, map moved (0 when none)
  int pose_graph_moved_views = 0;       // views moved by the global pose graph in this call
  double total_us = 0.0;                // the whole call
  std::size_t num_views = 0;            // views in the map when it was queried
  std::size_t num_map_components = 0;   // components in the map when it was queried
  int num_matches = 0;                  // views with E < e_max (after top_k)
  double best_similarity = 0.0;         // S of the best matching view, 0 without match
  int hypothesis_components = 0;        // components of p(x|y)
  bool gated_matching = false;          // p(x|y) from the views near p(x|u) only
  std::size_t matching_candidates = 0;  // views whose descriptor distance was computed
                                        // (all views without the gate or the index)
  int mixture_components = 0;           // components of p(x_t)
  int updates_applied = 0;              // map updates applied before this frame's query
  int updates_queued = 0;               // updates pushed by this frame (incl. reconstructed)
  int pending_multimodal = 0;           // multimodal frames waiting after this frame
  int dropped_pending = 0;              // pending frames dropped during this call
  // Normalised innovation squared of the appearance fix: d^T (C_u + C_y)^-1 d between
  // FrameResult::prior and FrameResult::appearance_fix (3 dof, heading wrapped); NaN
  // when either is absent. A consistent filter gives chi-square(3) values on frames
  // whose match is right (docs/design.md "Consistency metrics").
  double nis = std::numeric_limits<double>::quiet_NaN();
};

// The result of one frame.
struct FrameResult {
  std::int64_t frame = 0;  // engine frame index (0-based over all sessions)
  int session = 0;         // engine session index (0-based, counts BeginSession calls)
  // p(x_t) summary; std::nullopt while the state is unknown (global start not yet seeded).
  std::optional<Estimate> estimate;
  // States of earlier multimodal frames reconstructed at this (unimodal) frame:
  // (engine frame index, N(mu, C)).
  std::vector<std::pair<std::int64_t, Gaussian>> reconstructed;
  // Unimodal frames: N(mu_t, C_t) queued for the map (the moment-matched merge of
  // p(x_t), weight 1). Unset otherwise.
  std::optional<Gaussian> map_state;
  // Consistency diagnostics: the strongest component of the prior p(x|u) (unset without
  // a state) and the component of the shaped p(x|y) nearest to it in squared Mahalanobis
  // distance (unset without a prior or without p(x|y)), both in the map frame.
  std::optional<Gaussian> prior;
  std::optional<Gaussian> appearance_fix;
  FrameStats stats;
};

// Counters over the engine's life (persisted).
struct EngineCounters {
  std::int64_t frames = 0;
  std::int64_t unimodal_frames = 0;
  std::int64_t multimodal_frames = 0;
  std::int64_t unknown_frames = 0;  // no estimate (global start not yet seeded)
  std::int64_t reconstructed_frames = 0;
  std::int64_t dropped_pending_frames = 0;
  std::int64_t updates_queued = 0;
  std::int64_t global_seeds = 0;      // global sessions that found the robot
  std::int64_t global_fallbacks = 0;  // global sessions on an empty map
  bool operator==(const EngineCounters&) const = default;
};

// A multimodal frame waiting for its reconstruction.
struct PendingFrame {
  std::int64_t frame = 0;
  int session = 0;
  Descriptor descriptor;
  OdometryIncrement increment;  // from the previous frame to this one (what the tracker used)
  // Unimodal frames waiting for lack of confidence (anchor_max_sigma_m): the filtered
  // N(mu_t, C_t), used if the frame cannot be reconstructed. Unset for multimodal frames.
  std::optional<Gaussian> filtered;
};

// The state of the engine between frames that SaveEngine writes (besides options and
// the model); exposed for persistence and tests.
struct EngineSessionState {
  int session = -1;  // index of the current session, -1 before the first
  bool in_session = false;
  CameraModel camera;  // current session's camera
  SessionStartMode start_mode = SessionStartMode::kKnownPose;
  bool has_prev_odom = false;
  Pose2 prev_odom = Pose2::Zero();  // odom_T_robot of the previous frame
  bool awaiting_global_seed = false;
};

class CmlEngine {
 public:
  // Validates options (throws omnicml::Error), builds the extractor and an empty map.
  explicit CmlEngine(const CmlEngineOptions& options);
  ~CmlEngine();
  CmlEngine(const CmlEngine&) = delete;
  CmlEngine& operator=(const CmlEngine&) = delete;

  // Starts a session (see the file comment). Throws omnicml::Error on an invalid camera
  // (bad calibration for raw ring images) or a non-SPD start covariance.
  void BeginSession(const SessionInfo& info);

  // Processes one frame of the current session. Preconditions: BeginSession was called;
  // the image matches the session camera (raw ring of its size, or a panorama); the
  // odometry is finite. Throws omnicml::Error otherwise (the engine state is then
  // unchanged except for the frame's map barrier).
  FrameResult ProcessFrame(const Frame& frame);

  // Survey mapping ([G]'s "old" map, built from trusted poses; docs/design.md "Survey
  // mapping"): processes one frame of the current session whose pose is known from
  // outside the engine (the log's ground truth, or an external corrected trajectory).
  // Like ProcessFrame (the same map barrier, descriptor and delayed update), but the
  // estimate is `trusted` itself: p(x_t) := N(trusted.mean, trusted.covariance), the
  // frame is a confident anchor (frames still pending are reconstructed up to it) and
  // (y_t, N(trusted)) is queued for the map. No appearance matching is done, so views
  // are inserted at the trusted poses. Later ProcessFrame calls go on from this state.
  // `trusted.mean` is (x m, y m, phi rad) in the map frame; the covariance (m^2, rad^2)
  // is repaired (RepairCovariance) and must be finite. Throws omnicml::Error on a
  // non-finite pose or odometry, before BeginSession, or as ProcessFrame.
  FrameResult ProcessSurveyFrame(const Frame& frame, const Gaussian& trusted);

  // End of the run: queues the unimodal frames still pending with their filtered
  // estimates, drops the multimodal ones (no anchor follows them), and applies every
  // queued map update (whatever its due frame). Processing may
  // continue afterwards. Returns the number of updates applied.
  int Finish();

  // Read-only access; valid between calls.
  const EnvironmentModel& model() const { return *model_; }
  const CmlEngineOptions& options() const { return options_; }
  const MixtureTracker& tracker() const { return tracker_; }
  const EngineCounters& counters() const { return counters_; }
  // The global pose graph (empty unless options().pose_graph.enabled).
  const PoseGraph& pose_graph() const { return *pose_graph_; }
  const EngineSessionState& session_state() const { return session_; }
  const std::vector<PendingFrame>& pending_frames() const { return pending_; }
  // The last unimodal estimate the pending frames hang from: (frame, N(mu, C)).
  const std::optional<std::pair<std::int64_t, Gaussian>>& anchor() const { return anchor_; }
  // Map updates queued and not yet applied, in order.
  const std::deque<MapUpdate>& queued_updates() const { return updater_->queued(); }
  // The engine index the next frame will get.
  std::int64_t next_frame() const { return next_frame_; }
  const DescriptorExtractor& extractor() const { return *extractor_; }
  const std::shared_ptr<const DescriptorExtractor>& extractor_ptr() const { return extractor_; }

  // Replaces the map, e.g. with one built offline or loaded for a benchmark. The model
  // must use this engine's extractor (extractor_ptr()) and the engine's model options
  // are NOT changed by it. Queued updates are kept (they apply to the new map).
  // Throws omnicml::Error if the model's extractor is a different object.
  void ReplaceModel(EnvironmentModel model);

  // Mode changes of a running engine: the options that do not change the meaning of the
  // stored state (everything else is fixed at construction). Call between frames, from
  // the engine's thread: after construction, BeginSession, ProcessFrame or Finish (the
  // map-update worker is then idle). The result is bit-identical to saving the engine
  // with EncodeEngine, changing the option in the stored options and decoding it again:
  // map, tracker, queued updates, pending frames and counters are kept, and the engine
  // goes on as one constructed with the new option and fed the same frames would.
  //
  // options().threads := threads (in [1, kMaxThreads], else omnicml::Error and no change). The
  // map-update worker is stopped (joined) and a new updater (with a worker when
  // threads >= 2) takes over the queued updates in order; its applied-updates count
  // restarts at 0, as after LoadEngine. Results do not depend on threads.
  void SetThreads(int threads);
  // options().model.forgetting.mode := mode, for the map's next updates (e.g. learn day 1 in
  // kActive, then freeze the map with kStatic). Queued updates apply under the new mode.
  void SetForgettingMode(ForgettingMode mode);

 private:
  friend class EngineStateAccess;  // engine_io.cc restores the state

  // A map updater applying to model_ with `threads` (>= 2: background worker).
  std::unique_ptr<MapUpdater> MakeUpdater(int threads);
  void MakeUnwrapper();
  cv::Mat PreparePanoramaOf(const Frame& frame) const;
  // Frame t's descriptor behind the update barrier (ProcessFrame steps 2-5, also used by
  // ProcessSurveyFrame): hands the updates due at t to the worker, unwraps and describes
  // `frame` meanwhile, then waits until exactly the updates of frames <= t - delay are in
  // the map. Fills the unwrap/describe/update/apply timings and updates_applied of
  // `stats`. Never leaves the worker running when it throws.
  Descriptor DescribeBehindBarrier(const Frame& frame, std::int64_t t, FrameStats* stats);
  void QueueUnimodal(std::int64_t frame, const Descriptor& y, const Estimate& estimate,
                     FrameResult* result);
  // The end of ProcessFrame and ProcessSurveyFrame for `frame` (index result->frame):
  // pending count, odometry carried to the next frame, frame counters, and
  // result->stats.total_us from t_start.
  void EndFrame(const Frame& frame, std::chrono::steady_clock::time_point t_start,
                FrameResult* result);
  // Multimodal pending frames are dropped; unimodal ones (waiting for a confident anchor)
  // are queued with their filtered estimate. `t` is the frame producing the updates.
  void DropPending(std::int64_t t, FrameStats* stats);
  bool IsConfidentAnchor(const Estimate& estimate, bool appearance_fix) const;
  // Queues (d, g) of `frame` for the map unless map_update_spacing_m spaces it out.
  void PushUpdate(std::int64_t t, std::int64_t frame, int session, const Descriptor& d,
                  const Gaussian& g, bool reconstructed, FrameStats* stats);
  void ShapeHypothesis(double best_similarity, Mixture* p_x_y) const;
  // The appearance neighbourhood's variance (m^2) that, with a component's own covariance,
  // explains part of its spread (AddSpreadOffsets, docs/design.md (S2)).
  double SpreadFloor() const;
  // Sets result->prior, result->appearance_fix and result->stats.nis (see FrameResult).
  void NoteInnovation(const Mixture& p_x_u, const Mixture& p_x_y, FrameResult* result) const;
  // Global pose graph (cml_engine_pose_graph.cc): after the anchor frame t was queued
  // with an appearance fix, a loop closure from the best match and, when due, the
  // optimisation; the map and the queued updates move with the nodes, the tracker as
  // pose_graph.tracker_follows says. fixed_by: the node (frame) that created the view the
  // current frame was fixed by, if any.
  void UpdatePoseGraph(std::int64_t t, const std::vector<ViewMatch>& matches, FrameStats* stats);
  // Optimize at frame t; with pose_graph.marginal_covariances, marginals for the nodes
  // that created a view in the map.
  std::vector<NodeCorrection> OptimizePoseGraph(std::int64_t t);
  // pose_graph.marginal_covariances: view view_index moved with correction c, which
  // carries its node's marginal covariance; its components at the node take it.
  void GiveMarginalToComponentsAtTheNode(std::size_t view_index, const NodeCorrection& c);
  void ApplyPoseGraphCorrections(std::vector<NodeCorrection> corrections,
                                 std::optional<std::int64_t> fixed_by, FrameStats* stats);

  CmlEngineOptions options_;
  std::shared_ptr<const DescriptorExtractor> extractor_;
  std::unique_ptr<EnvironmentModel> model_;
  MixtureTracker tracker_;
  std::unique_ptr<MapUpdater> updater_;
  std::unique_ptr<OmniUnwrapper> unwrapper_;  // for kRawRing session cameras

  EngineSessionState session_;
  std::int64_t next_frame_ = 0;
  EngineCounters counters_;
  std::vector<PendingFrame> pending_;
  std::optional<std::pair<std::int64_t, Gaussian>> anchor_;
  OdometryIncrement current_increment_;  // u_t of the frame being processed
  std::unique_ptr<PoseGraph> pose_graph_;
  // Set while ProcessSurveyFrame queues its frame: the prior of that frame's node.
  std::optional<std::pair<std::int64_t, Gaussian>> survey_prior_;
  // The last map update pushed (map_update_spacing_m > 0 only): its session and map-frame
  // position (m).
  struct LastMapUpdate {
    int session = 0;
    double x_m = 0.0;
    double y_m = 0.0;
  };
  std::optional<LastMapUpdate> last_map_update_;
  // smooth_map_updates only: the latest frames of ProcessFrame, oldest first, at most
  // update_delay_frames + 1: a unimodal frame's filtered estimate (what its map update
  // carries) and the odometry increment into the frame.
  struct SmoothingFrame {
    std::int64_t frame = 0;
    int session = 0;
    std::optional<Gaussian> filtered;
    OdometryIncrement increment;
  };
  std::deque<SmoothingFrame> smoothing_history_;
  // Appends frame t to smoothing_history_ (dropping the oldest beyond its length).
  void RecordForSmoothing(std::int64_t t, const FrameResult& result);
  // Replaces the state of every queued update due at <= due_by that carries its frame's
  // filtered estimate by the smoothed one (SmoothFirstOfChain over smoothing_history_).
  // Call between a barrier and the next hand-over (end of a frame, Finish).
  void SmoothQueuedUpdates(std::int64_t due_by);
};

}  // namespace omnicml

#endif  // OMNICML_ENGINE_CML_ENGINE_H_
