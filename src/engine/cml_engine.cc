#include "omnicml/engine/cml_engine.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <utility>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include "omnicml/common/common.h"
#include "omnicml/common/limits.h"
#include "omnicml/tracking/fixed_lag_smoother.h"

namespace omnicml {
namespace {

using Clock = std::chrono::steady_clock;

double MicrosSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
}

bool IsFinitePose(const Pose2& p) { return p.allFinite(); }

}  // namespace

void GatedMatchingOptions::Validate() const {
  if (!(gate_sigmas > 0.0) || !std::isfinite(gate_sigmas)) {
    throw Error(StrCat("gate_sigmas must be finite and > 0, got ", gate_sigmas));
  }
  if (full_search_every_frames < 1) {
    throw Error(StrCat("full_search_every_frames must be >= 1, got ", full_search_every_frames));
  }
  if (min_views < 0) throw Error(StrCat("min_views must be >= 0, got ", min_views));
}

void CmlEngineOptions::Validate() const {
  auto nested = [](const char* prefix, auto&& validate) {
    try {
      validate();
    } catch (const Error& e) {
      throw Error(StrCat("CmlEngineOptions.", prefix, ": ", e.what()));
    }
  };
  nested("descriptor", [&] { descriptor.Validate(); });
  nested("tracker", [&] { tracker.Validate(); });
  nested("model", [&] { model.Validate(); });
  nested("reconstruction", [&] { reconstruction.Validate(); });
  nested("pose_graph", [&] { pose_graph.Validate(); });
  nested("gated_matching", [&] { gated_matching.Validate(); });
  double travel = 0.0;
  for (std::size_t i = 0; i < appearance_offset_curve.size(); ++i) {
    const auto& [m, e] = appearance_offset_curve[i];
    if (!std::isfinite(m) || !std::isfinite(e) || !(e >= 0) || !(m > travel)) {
      throw Error(StrCat("CmlEngineOptions.appearance_offset_curve[", i,
                         "] must be finite with travel increasing from > 0 m and E >= 0, got ", m,
                         ", ", e));
    }
    travel = m;
  }
  if (update_delay_frames < 1) {
    throw Error(
        StrCat("CmlEngineOptions.update_delay_frames must be >= 1, got ", update_delay_frames));
  }
  if (threads < 1 || threads > kMaxThreads) {
    throw Error(
        StrCat("CmlEngineOptions.threads must lie in [1, ", kMaxThreads, "], got ", threads));
  }
  if (max_pending_multimodal_frames < 1) {
    throw Error(StrCat("CmlEngineOptions.max_pending_multimodal_frames must be >= 1, got ",
                       max_pending_multimodal_frames));
  }
  if (!(anchor_max_sigma_m >= 0.0) || !std::isfinite(anchor_max_sigma_m)) {
    throw Error(StrCat("CmlEngineOptions.anchor_max_sigma_m must be finite and >= 0, got ",
                       anchor_max_sigma_m));
  }
  if (panorama_width < 0 || panorama_height < 0 ||
      ((panorama_width > 0) != (panorama_height > 0))) {
    throw Error(
        StrCat("CmlEngineOptions.panorama_width/panorama_height must both be 0 or both > 0, got ",
               panorama_width, " x ", panorama_height));
  }
  if (panorama_width > kMaxPanoramaSidePx || panorama_height > kMaxPanoramaSidePx) {
    throw Error(StrCat("CmlEngineOptions.panorama_width/panorama_height must be at most ",
                       kMaxPanoramaSidePx, ", got ", panorama_width, " x ", panorama_height));
  }
  if (!IsFinitePose(initial_pose)) throw Error("CmlEngineOptions.initial_pose must be finite");
  try {
    RepairCovariance(initial_covariance, 1e-12, "CmlEngineOptions.initial_covariance");
  } catch (const Error& e) {
    throw Error(StrCat("CmlEngineOptions.initial_covariance: ", e.what()));
  }
  if (initial_covariance.determinant() <= 0.0) {
    throw Error("CmlEngineOptions.initial_covariance must be positive definite");
  }
  if (!(hypothesis_min_similarity >= 0.0 && hypothesis_min_similarity <= 1.0)) {
    throw Error(StrCat("CmlEngineOptions.hypothesis_min_similarity must be in [0, 1], got ",
                       hypothesis_min_similarity));
  }
  if (!(hypothesis_weight_scale > 0.0 && hypothesis_weight_scale <= 1.0)) {
    throw Error(StrCat("CmlEngineOptions.hypothesis_weight_scale must be in (0, 1], got ",
                       hypothesis_weight_scale));
  }
  if (!(motion_noise_offset_dof >= 0.0 && std::isfinite(motion_noise_offset_dof))) {
    throw Error(StrCat("CmlEngineOptions.motion_noise_offset_dof must be finite and >= 0, got ",
                       motion_noise_offset_dof));
  }
  if (motion_noise_joint_pairs < 0) {
    throw Error(StrCat("CmlEngineOptions.motion_noise_joint_pairs must be >= 0, got ",
                       motion_noise_joint_pairs));
  }
  if (!(map_update_spacing_m >= 0.0 && std::isfinite(map_update_spacing_m))) {
    throw Error(StrCat("CmlEngineOptions.map_update_spacing_m must be finite and >= 0, got ",
                       map_update_spacing_m));
  }
  if (!(hypothesis_evidence_scale > 0.0 && hypothesis_evidence_scale <= 1.0)) {
    throw Error(StrCat("CmlEngineOptions.hypothesis_evidence_scale must be in (0, 1], got ",
                       hypothesis_evidence_scale));
  }
  if (!(reference_frame_step_m >= 0.0 && std::isfinite(reference_frame_step_m))) {
    throw Error(StrCat("CmlEngineOptions.reference_frame_step_m must be finite and >= 0, got ",
                       reference_frame_step_m));
  }
  if (!(appearance_sigma_m >= 0.0) || !std::isfinite(appearance_sigma_m)) {
    throw Error(StrCat("CmlEngineOptions.appearance_sigma_m must be finite and >= 0, got ",
                       appearance_sigma_m));
  }
  if (!(global_seed_min_similarity >= 0.0 && global_seed_min_similarity <= 1.0)) {
    throw Error(StrCat("CmlEngineOptions.global_seed_min_similarity must be in [0, 1], got ",
                       global_seed_min_similarity));
  }
}

CmlEngine::CmlEngine(const CmlEngineOptions& options)
    : options_(options), tracker_(options.tracker) {
  options_.Validate();
  options_.reconstruction.motion = options_.tracker.motion;
  extractor_ = MakeDescriptorExtractor(options_.descriptor);
  model_ = std::make_unique<EnvironmentModel>(options_.model, extractor_);
  updater_ = MakeUpdater(options_.threads);
  pose_graph_ = std::make_unique<PoseGraph>(
      options_.pose_graph, options_.tracker.motion,
      options_.reconstruction.min_translation_variance_m2,
      options_.reconstruction.min_rotation_variance_rad2,
      static_cast<std::size_t>(options_.max_pending_multimodal_frames) + 1);
}

CmlEngine::~CmlEngine() = default;

std::unique_ptr<MapUpdater> CmlEngine::MakeUpdater(int threads) {
  // The worker only ever touches model_ through this function, between Schedule and the
  // barrier of a frame (see map_updater.h).
  return std::make_unique<MapUpdater>(
      [this](const MapUpdate& u) {
        model_->Update(u.descriptor, u.state, UpdateContext{u.frame, u.session_index});
      },
      options_.update_delay_frames, threads >= 2);
}

void CmlEngine::SetThreads(int threads) {
  if (threads < 1 || threads > kMaxThreads) {
    throw Error(
        StrCat("CmlEngineOptions.threads must lie in [1, ", kMaxThreads, "], got ", threads));
  }
  if (threads == options_.threads) return;
  // Between calls the worker holds no batch (every call ends at a barrier or a flush), so
  // the queue is all the work not yet applied. Build the new updater first: a failure to
  // start its worker leaves the engine unchanged.
  std::unique_ptr<MapUpdater> updater = MakeUpdater(threads);
  for (const MapUpdate& u : updater_->queued()) updater->PushRaw(u);
  updater_ = std::move(updater);  // the old one joins its (idle) worker
  options_.threads = threads;
}

void CmlEngine::SetForgettingMode(ForgettingMode mode) {
  options_.model.forgetting.mode = mode;
  model_->SetForgettingMode(mode);
}

void CmlEngine::MakeUnwrapper() {
  unwrapper_.reset();
  if (session_.camera.kind == ImageKind::kRawRing) {
    unwrapper_ =
        std::make_unique<OmniUnwrapper>(session_.camera.calibration, session_.camera.image_width,
                                        session_.camera.image_height, session_.camera.mask);
  }
}

void CmlEngine::PushUpdate(std::int64_t t, std::int64_t frame, int session, const Descriptor& d,
                           const Gaussian& g, bool reconstructed, FrameStats* stats) {
  const double spacing = options_.map_update_spacing_m;
  if (spacing > 0.0) {
    if (last_map_update_ && last_map_update_->session == session &&
        std::hypot(g.mean.x() - last_map_update_->x_m, g.mean.y() - last_map_update_->y_m) <
            spacing) {
      return;
    }
    last_map_update_ = LastMapUpdate{session, g.mean.x(), g.mean.y()};
  }
  MapUpdate u;
  u.frame = frame;
  u.session_index = session;
  u.descriptor = d;
  u.state = g;
  u.reconstructed = reconstructed;
  updater_->Push(std::move(u), t);
  if (options_.pose_graph.enabled) {  // global pose graph: one node per map update
    const bool survey = survey_prior_ && survey_prior_->first == frame;
    pose_graph_->AddNode(frame, g.mean,
                         survey ? std::optional<Gaussian>(survey_prior_->second) : std::nullopt);
  }
  if (stats != nullptr) stats->updates_queued += 1;
  counters_.updates_queued += 1;
}

void CmlEngine::DropPending(std::int64_t t, FrameStats* stats) {
  int dropped = 0;
  for (const PendingFrame& p : pending_) {
    if (p.filtered) {
      PushUpdate(t, p.frame, p.session, p.descriptor, *p.filtered, false, stats);
    } else {
      ++dropped;
    }
  }
  counters_.dropped_pending_frames += dropped;
  if (stats != nullptr) stats->dropped_pending += dropped;
  pending_.clear();
}

bool CmlEngine::IsConfidentAnchor(const Estimate& estimate, bool appearance_fix) const {
  if (appearance_fix || !(options_.anchor_max_sigma_m > 0.0) || !options_.reconstruct_multimodal) {
    return true;
  }
  const double largest = LargestEigenvalue2(estimate.mean.covariance.topLeftCorner<2, 2>());
  return largest <= options_.anchor_max_sigma_m * options_.anchor_max_sigma_m;
}

void CmlEngine::BeginSession(const SessionInfo& info) {
  const Eigen::Matrix3d start_cov =
      info.start.mode == SessionStartMode::kKnownPose
          ? RepairCovariance(info.start.covariance, options_.tracker.min_covariance_eigenvalue,
                             StrCat("session '", info.name, "' start covariance"))
          : Eigen::Matrix3d::Identity();
  if (info.start.mode == SessionStartMode::kKnownPose && !IsFinitePose(info.start.map_T_robot)) {
    throw Error(StrCat("session '", info.name, "': start pose is not finite"));
  }
  // Build the unwrapper first: a bad calibration must leave the engine unchanged.
  std::unique_ptr<OmniUnwrapper> unwrapper;
  if (info.camera.kind == ImageKind::kRawRing) {
    unwrapper = std::make_unique<OmniUnwrapper>(info.camera.calibration, info.camera.image_width,
                                                info.camera.image_height, info.camera.mask);
  }
  // Bring the model up to date with what the next frame's query would see anyway, so the
  // emptiness test below reads a settled model (same result with or without worker).
  updater_->WaitUntilApplied(next_frame_);

  const bool first = !session_.in_session;
  session_.session += 1;
  session_.in_session = true;
  session_.camera = info.camera;
  session_.start_mode = info.start.mode;
  session_.awaiting_global_seed = false;
  unwrapper_ = std::move(unwrapper);

  switch (info.start.mode) {
    case SessionStartMode::kKnownPose: {
      Gaussian g;
      g.mean =
          MakePose(info.start.map_T_robot[0], info.start.map_T_robot[1], info.start.map_T_robot[2]);
      g.covariance = start_cov;
      g.weight = 1.0;
      tracker_.Reset(g);
      DropPending(next_frame_ - 1, nullptr);
      anchor_.reset();
      session_.has_prev_odom = false;
      break;
    }
    case SessionStartMode::kContinue: {
      if (!first && !tracker_.HasState()) {
        // The previous (global) session never found the robot: keep looking.
        session_.awaiting_global_seed = true;
        session_.has_prev_odom = false;
      } else if (first) {
        // Nothing to continue from: the configured p(x_0).
        Gaussian g;
        g.mean = options_.initial_pose;
        g.covariance = options_.initial_covariance;
        tracker_.Reset(g);
        DropPending(next_frame_ - 1, nullptr);
        anchor_.reset();
        session_.has_prev_odom = false;
      } else if (!options_.continue_odometry_across_sessions) {
        session_.has_prev_odom = false;  // first frame: zero increment
      }
      break;
    }
    case SessionStartMode::kGlobal: {
      DropPending(next_frame_ - 1, nullptr);
      anchor_.reset();
      session_.has_prev_odom = false;
      if (model_->NumViews() == 0 && updater_->queued().empty()) {
        // [G 2.1]: with an empty map p(x_0) is the configured initial pose.
        Gaussian g;
        g.mean = options_.initial_pose;
        g.covariance = options_.initial_covariance;
        tracker_.Reset(g);
        counters_.global_fallbacks += 1;
      } else {
        tracker_.ResetUnknown();
        session_.awaiting_global_seed = true;
      }
      break;
    }
  }
  if (options_.pose_graph.enabled) {
    // Global pose graph: kContinue goes on with the odometry segment; a known start pose
    // is a prior on the session's first node.
    const bool continues = info.start.mode == SessionStartMode::kContinue && !first;
    if (options_.pose_graph.hold_earlier_sessions && !continues &&
        pose_graph_->HasUnoptimizedClosures()) {
      // The ending session's last closures, solved while its nodes are still free: from
      // the new session on they are held.
      ApplyPoseGraphCorrections(OptimizePoseGraph(next_frame_ - 1), std::nullopt, nullptr);
    }
    std::optional<Gaussian> known;
    if (info.start.mode == SessionStartMode::kKnownPose) known = tracker_.state().front();
    pose_graph_->BeginSession(continues, next_frame_, known);
  }
}

cv::Mat CmlEngine::PreparePanoramaOf(const Frame& frame) const {
  if (session_.camera.kind == ImageKind::kRawRing) {
    OMNICML_CHECK(unwrapper_ != nullptr) << "raw ring session without unwrapper";
    return PreparePanorama(unwrapper_->Unwrap(frame.image), options_.panorama_width,
                           options_.panorama_height);
  }
  return PreparePanorama(frame.image, options_.panorama_width, options_.panorama_height);
}

void CmlEngine::QueueUnimodal(std::int64_t t, const Descriptor& y, const Estimate& estimate,
                              FrameResult* result) {
  // (mu_t, C_t): the moment-matched merge of the unimodal p(x_t).
  Gaussian state = estimate.mean;
  state.weight = 1.0;
  result->map_state = state;
  const auto push = [&](std::int64_t frame, int session, const Descriptor& d, const Gaussian& g,
                        bool rec) { PushUpdate(t, frame, session, d, g, rec, &result->stats); };

  // Reconstruction of the multimodal stretch since the previous unimodal anchor
  // ([G 2.1, PK]; docs/design.md "Unimodality, reconstruction, delayed update").
  if (!pending_.empty()) {
    const auto t0 = Clock::now();
    // Chain: [anchor ->] pending_0 -> ... -> pending_{k-1} -> t.
    std::vector<OdometryIncrement> increments;
    std::optional<Gaussian> start;
    std::size_t first_increment = 1;
    if (anchor_) {
      start = anchor_->second;
      first_increment = 0;
    }
    for (std::size_t i = first_increment; i < pending_.size(); ++i)
      increments.push_back(pending_[i].increment);
    // The current frame's increment is the one the tracker just used.
    increments.push_back(current_increment_);
    const ReconstructionResult rec =
        ReconstructTrajectory(start, increments, state, options_.reconstruction);
    const std::size_t offset = anchor_ ? 1 : 0;
    for (std::size_t i = 0; i < pending_.size(); ++i) {
      const Gaussian& g = rec.nodes[i + offset];
      push(pending_[i].frame, pending_[i].session, pending_[i].descriptor, g, true);
      result->reconstructed.emplace_back(pending_[i].frame, g);
    }
    counters_.reconstructed_frames += static_cast<std::int64_t>(pending_.size());
    pending_.clear();
    result->stats.reconstruct_us = MicrosSince(t0);
  }
  push(t, session_.session, y, state, false);
  anchor_ = std::make_pair(t, state);
}

double AppearanceOffsetVariance(const std::vector<std::array<double, 2>>& curve, double e) {
  if (curve.empty() || !(e > 0)) return 0.0;
  double m0 = 0.0;
  double e0 = 0.0;
  double d = curve.back()[0];
  for (const auto& [m1, e1] : curve) {
    if (e1 >= e) {  // e0 < e <= e1
      d = m0 + (m1 - m0) * (e - e0) / (e1 - e0);
      break;
    }
    m0 = m1;
    e0 = e1;
  }
  return 0.25 * d * d;
}

void AddAppearanceOffsets(const EnvironmentModel& model, const std::vector<ViewMatch>& matches,
                          const std::vector<std::array<double, 2>>& curve, Mixture* p_x_y) {
  if (curve.empty() || p_x_y->empty()) return;
  std::size_t k = 0;
  for (const ViewMatch& m : matches) {
    const double v = AppearanceOffsetVariance(curve, m.distance);
    const std::size_t n = model.views()[m.view_index].components.size();
    for (std::size_t j = 0; j < n && k < p_x_y->size(); ++j, ++k) {
      (*p_x_y)[k].covariance(0, 0) += v;
      (*p_x_y)[k].covariance(1, 1) += v;
    }
  }
}

Eigen::Matrix2d SpreadBeyond(const Eigen::Matrix2d& spread, const Eigen::Matrix2d& floor) {
  const Eigen::Matrix2d d = spread - floor;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(0.5 * (d + d.transpose()));
  const Eigen::Vector2d excess = es.eigenvalues().cwiseMax(0.0);
  const Eigen::Matrix2d out =
      es.eigenvectors() * excess.asDiagonal() * es.eigenvectors().transpose();
  return 0.5 * (out + out.transpose());
}

Eigen::Matrix2d SpreadExcess(const ViewComponent& c, double neighbourhood_m2) {
  return SpreadBeyond(c.spread - c.covariance.topLeftCorner<2, 2>(),
                      neighbourhood_m2 * Eigen::Matrix2d::Identity());
}

void AddSpreadOffsets(const EnvironmentModel& model, const std::vector<ViewMatch>& matches,
                      double neighbourhood_m2, Mixture* p_x_y) {
  std::size_t k = 0;
  for (const ViewMatch& m : matches) {
    for (const ViewComponent& c : model.views()[m.view_index].components) {
      if (k >= p_x_y->size()) return;
      (*p_x_y)[k++].covariance.topLeftCorner<2, 2>() += SpreadExcess(c, neighbourhood_m2);
    }
  }
}

double CmlEngine::SpreadFloor() const {
  // (S2): the identified neighbourhood, which ShapeHypothesis adds to every component.
  return options_.appearance_sigma_m * options_.appearance_sigma_m;
}

void CmlEngine::ShapeHypothesis(double best_similarity, Mixture* p_x_y) const {
  if (p_x_y->empty()) return;
  if (best_similarity < options_.hypothesis_min_similarity) {
    p_x_y->clear();
    return;
  }
  const double var = options_.appearance_sigma_m * options_.appearance_sigma_m;
  for (Gaussian& g : *p_x_y) {
    if (options_.hypothesis_weight_by_similarity) g.weight *= best_similarity;
    g.covariance(0, 0) += var;
    g.covariance(1, 1) += var;
  }
}

void CmlEngine::NoteInnovation(const Mixture& p_x_u, const Mixture& p_x_y,
                               FrameResult* result) const {
  if (p_x_u.empty()) return;
  const Gaussian& prior = p_x_u[StrongestComponent(p_x_u)];
  result->prior = prior;
  double best = std::numeric_limits<double>::infinity();
  for (const Gaussian& b : p_x_y) {
    const double d2 = SquaredMahalanobis(prior.mean, b.mean, prior.covariance + b.covariance);
    if (d2 < best) {
      best = d2;
      result->appearance_fix = b;
    }
  }
  if (result->appearance_fix) result->stats.nis = best;
}

Descriptor CmlEngine::DescribeBehindBarrier(const Frame& frame, std::int64_t t, FrameStats* stats) {
  // 2. Hand the updates due at t to the worker; it runs while we unwrap and describe.
  updater_->Schedule(t);
  Descriptor y;
  try {
    // 3. Unwrap / prepare.
    auto t0 = Clock::now();
    const cv::Mat panorama = PreparePanoramaOf(frame);
    stats->unwrap_us = MicrosSince(t0);
    // 4. Describe.
    t0 = Clock::now();
    // Pixels outside a clipped ring or under the user mask do not count (descriptor.h).
    y = unwrapper_ != nullptr && unwrapper_->valid_fraction() < 1.0
            ? extractor_->ComputeMasked(
                  panorama, PrepareMask(unwrapper_->valid_mask(), panorama.cols, panorama.rows))
            : extractor_->Compute(panorama);
    stats->describe_us = MicrosSince(t0);
  } catch (...) {
    updater_->WaitUntilApplied(t);  // never leave the worker running between calls
    throw;
  }
  // 5. Barrier: exactly the updates of frames <= t - delay are in the map.
  const auto t0 = Clock::now();
  stats->updates_applied = updater_->WaitUntilApplied(t);
  stats->update_us = MicrosSince(t0);
  stats->apply_us = updater_->TakeApplyMicroseconds();
  return y;
}

FrameResult CmlEngine::ProcessFrame(const Frame& frame) {
  const auto t_start = Clock::now();
  if (!session_.in_session) throw Error("CmlEngine::ProcessFrame called before BeginSession");
  if (!IsFinitePose(frame.odom_T_robot)) {
    throw Error(StrCat("frame ", frame.global_index, " (session ", frame.session_index, ", index ",
                       frame.index_in_session, "): odometry is not finite"));
  }
  const std::int64_t t = next_frame_;
  FrameResult result;
  result.frame = t;
  result.session = session_.session;

  // 2.-5. Unwrap and describe while the worker applies the updates due at t; barrier.
  const Descriptor y = DescribeBehindBarrier(frame, t, &result.stats);

  // 1. Odometry increment (zero on a session's first frame, see BeginSession), and the
  // prior p(x|u) = Propagate(p(x_{t-1}), u_t) (empty without a state).
  current_increment_ = session_.has_prev_odom
                           ? ComputeIncrement(session_.prev_odom, frame.odom_T_robot)
                           : OdometryIncrement{};
  const Mixture p_x_u =
      tracker_.HasState() ? Propagate(tracker_.state(), current_increment_, options_.tracker.motion)
                          : Mixture{};

  // 6a. p(x|y) from the map (distributed coding), gated while tracking confidently.
  auto t0 = Clock::now();
  result.stats.num_views = model_->NumViews();
  result.stats.num_map_components = model_->NumComponents();
  std::vector<ViewMatch> matches;
  const GatedMatchingOptions& gm = options_.gated_matching;
  if (gm.enabled && p_x_u.size() == 1 && t % gm.full_search_every_frames != 0 &&
      model_->NumViews() >= static_cast<std::size_t>(gm.min_views)) {
    const double variance =
        LargestEigenvalue2(p_x_u[0].covariance.topLeftCorner<2, 2>()) +
        options_.appearance_sigma_m * options_.appearance_sigma_m +
        AppearanceOffsetVariance(options_.appearance_offset_curve, options_.model.retrieval.e_max);
    const EnvironmentModel::Disc gate{p_x_u[0].mean.x(), p_x_u[0].mean.y(),
                                      gm.gate_sigmas * std::sqrt(variance)};
    matches = model_->FindMatchesNear(y, {gate}, &result.stats.matching_candidates);
    result.stats.gated_matching = true;
  } else {
    matches = model_->FindMatches(y);
    result.stats.matching_candidates = model_->NumViews();
  }
  Mixture p_x_y = model_->Hypothesis(matches);
  AddAppearanceOffsets(*model_, matches, options_.appearance_offset_curve, &p_x_y);
  // docs/design.md (S2).
  if (options_.appearance_offset_spread) AddSpreadOffsets(*model_, matches, SpreadFloor(), &p_x_y);
  result.stats.num_matches = static_cast<int>(matches.size());
  for (const ViewMatch& m : matches)
    result.stats.best_similarity = std::max(result.stats.best_similarity, m.similarity);
  result.stats.hypothesis_components = static_cast<int>(p_x_y.size());
  ShapeHypothesis(result.stats.best_similarity, &p_x_y);
  result.stats.match_us = MicrosSince(t0);
  NoteInnovation(p_x_u, p_x_y, &result);

  if (options_.pose_graph.enabled) pose_graph_->AddFrameOdometry(t, current_increment_);

  // 6b. p(x_t) = Fuse(Propagate(p(x_{t-1}), u_t), p(x|y)).
  t0 = Clock::now();
  std::vector<Mixture> sources;
  bool seeding = false;
  if (!tracker_.HasState()) {
    // Global start: only a confident p(x|y) may seed the mixture.
    if (!p_x_y.empty() && result.stats.best_similarity >= options_.global_seed_min_similarity) {
      sources.push_back(std::move(p_x_y));
      seeding = true;
    }
  } else if (!p_x_y.empty()) {
    // Prior of each appearance hypothesis: the p(x|u) mass within its gate (2), floored
    // by hypothesis_weight_scale (a place no current hypothesis covers: kidnapping, loop
    // closure after long drift). With [G] (8) alone a matched component gains w_b in
    // full whatever its own weight, so an aliased match (symmetric rooms, heading off by
    // ~180 deg) that once entered as a new hypothesis won within two or three frames
    // against a confident p(x|u); with the prior, evidence there grows multiplicatively.
    double total_u = 0.0;
    for (const Gaussian& a : p_x_u) total_u += a.weight;
    const double gate = options_.tracker.Gate();
    for (Gaussian& b : p_x_y) {
      double prior = 0.0;
      for (const Gaussian& a : p_x_u) {
        if (SquaredMahalanobis(a.mean, b.mean, a.covariance + b.covariance) < gate) {
          prior += a.weight;
        }
      }
      if (total_u > 0.0) prior /= total_u;
      b.weight *=
          std::max(prior, options_.hypothesis_weight_scale) * options_.hypothesis_evidence_scale;
    }
    sources.push_back(std::move(p_x_y));
  }
  // A unimodal estimate fused with a non-empty p(x|y) was fixed by appearance (a p(x|y)
  // component far from p(x|u) would have made it multimodal).
  const bool appearance_fix = !sources.empty();
  result.estimate = tracker_.Step(current_increment_, sources);
  result.stats.fuse_us = MicrosSince(t0);
  result.stats.mixture_components = static_cast<int>(tracker_.state().size());
  if (seeding && result.estimate) {
    counters_.global_seeds += 1;
    session_.awaiting_global_seed = false;
  }

  // 7. Map update (delayed) or wait for reconstruction.
  if (!result.estimate) {
    counters_.unknown_frames += 1;
  } else if (result.estimate->unimodal && IsConfidentAnchor(*result.estimate, appearance_fix)) {
    counters_.unimodal_frames += 1;
    QueueUnimodal(t, y, *result.estimate, &result);
    if (options_.pose_graph.enabled && appearance_fix) UpdatePoseGraph(t, matches, &result.stats);
  } else {
    const bool unimodal = result.estimate->unimodal;  // but not confident enough to anchor
    (unimodal ? counters_.unimodal_frames : counters_.multimodal_frames) += 1;
    if (options_.reconstruct_multimodal) {
      PendingFrame p;
      p.frame = t;
      p.session = session_.session;
      p.descriptor = std::move(y);
      p.increment = current_increment_;
      if (unimodal) {
        Gaussian g = result.estimate->mean;
        g.weight = 1.0;
        p.filtered = g;
      }
      pending_.push_back(std::move(p));
      if (static_cast<int>(pending_.size()) > options_.max_pending_multimodal_frames) {
        PendingFrame& oldest = pending_.front();
        if (oldest.filtered) {
          // It updates the map with its filtered estimate and anchors the rest.
          PushUpdate(t, oldest.frame, oldest.session, oldest.descriptor, *oldest.filtered, false,
                     &result.stats);
          anchor_ = std::make_pair(oldest.frame, *oldest.filtered);
        } else {
          // The oldest frame goes, and with it the link to the anchor.
          anchor_.reset();
          counters_.dropped_pending_frames += 1;
          result.stats.dropped_pending += 1;
        }
        pending_.erase(pending_.begin());
      }
    }
  }
  if (options_.smooth_map_updates) {
    RecordForSmoothing(t, result);
    SmoothQueuedUpdates(t + 1);  // handed over before the next frame queries the map
  }
  EndFrame(frame, t_start, &result);
  return result;
}

void CmlEngine::RecordForSmoothing(std::int64_t t, const FrameResult& result) {
  SmoothingFrame s;
  s.frame = t;
  s.session = result.session;
  s.increment = current_increment_;
  if (result.estimate && result.estimate->unimodal) {
    s.filtered = result.estimate->mean;
    s.filtered->weight = 1.0;
  }
  smoothing_history_.push_back(std::move(s));
  while (smoothing_history_.size() > static_cast<std::size_t>(options_.update_delay_frames) + 1)
    smoothing_history_.pop_front();
}

void CmlEngine::SmoothQueuedUpdates(std::int64_t due_by) {
  const std::deque<SmoothingFrame>& h = smoothing_history_;
  for (MapUpdate& u : updater_->mutable_queued()) {
    if (u.due_frame > due_by) break;  // due frames never decrease in the queue
    if (u.reconstructed) continue;
    std::size_t i = 0;
    while (i < h.size() && h[i].frame != u.frame) ++i;
    // Only an update that carries its frame's filtered estimate (not a survey frame's
    // trusted pose, not one already smoothed or moved by the pose graph).
    if (i == h.size() || !h[i].filtered || h[i].filtered->mean != u.state.mean) continue;
    std::vector<Gaussian> chain = {*h[i].filtered};
    std::vector<OdometryIncrement> increments;
    for (std::size_t j = i + 1; j < h.size(); ++j) {
      if (h[j].frame != h[j - 1].frame + 1 || h[j].session != h[i].session || !h[j].filtered) break;
      chain.push_back(*h[j].filtered);
      increments.push_back(h[j].increment);
    }
    if (increments.empty()) continue;
    u.state = SmoothFirstOfChain(chain, increments, options_.tracker.motion);
  }
}

void CmlEngine::EndFrame(const Frame& frame, Clock::time_point t_start, FrameResult* result) {
  result->stats.pending_multimodal = static_cast<int>(pending_.size());
  session_.prev_odom = frame.odom_T_robot;
  session_.has_prev_odom = true;
  next_frame_ = result->frame + 1;
  counters_.frames += 1;
  result->stats.total_us = MicrosSince(t_start);
}

void CmlEngine::ReplaceModel(EnvironmentModel model) {
  if (model.extractor_ptr() != extractor_) {
    throw Error(
        "CmlEngine::ReplaceModel: the model must be built with the engine's extractor "
        "(extractor_ptr())");
  }
  model_ = std::make_unique<EnvironmentModel>(std::move(model));
}

int CmlEngine::Finish() {
  DropPending(next_frame_ - 1, nullptr);
  if (options_.smooth_map_updates) SmoothQueuedUpdates(std::numeric_limits<std::int64_t>::max());
  return updater_->Flush();
}

}  // namespace omnicml
