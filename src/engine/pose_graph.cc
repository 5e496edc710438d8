#include "omnicml/engine/pose_graph.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <optional>
#include <string>

#include <ceres/ceres.h>
#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "engine/internal/pose_factors.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/trajectory_reconstruction.h"
#include "omnicml/geometry/pose_io.h"

namespace omnicml {
namespace {

using internal::BetweenFactor;
using internal::PriorFactor;
using internal::SqrtInformation;

using internal::ReadMatrix3;
using internal::ReadPose;
using internal::WriteMatrix3;
using internal::WritePose;

}  // namespace

void PoseGraphOptions::Validate() const {
  auto fail = [](const char* field, const char* rule, auto value) {
    throw Error(StrCat("PoseGraphOptions.", field, " must be ", rule, ", got ", value));
  };
  if (min_loop_frames < 1) fail("min_loop_frames", ">= 1", min_loop_frames);
  if (closure_every_frames < 1) fail("closure_every_frames", ">= 1", closure_every_frames);
  if (optimize_every_frames < 1) fail("optimize_every_frames", ">= 1", optimize_every_frames);
  if (window_nodes < 2) fail("window_nodes", ">= 2", window_nodes);
  if (!(closure_sigma_m >= 0) || !std::isfinite(closure_sigma_m))
    fail("closure_sigma_m", "finite and >= 0", closure_sigma_m);
  if (!(closure_sigma_rad > 0) || !std::isfinite(closure_sigma_rad))
    fail("closure_sigma_rad", "finite and > 0", closure_sigma_rad);
  if (!(loss_scale > 0) || !std::isfinite(loss_scale))
    fail("loss_scale", "finite and > 0", loss_scale);
  if (max_iterations < 1) fail("max_iterations", ">= 1", max_iterations);
  if (!(reject_chi2 > 0)) fail("reject_chi2", "> 0", reject_chi2);
}

namespace {

// Marginal covariance of each free block of `x` in the solved `problem` for which
// `wanted(i)` holds (Ceres' Covariance, sparse QR, the robust loss applied); nullopt for
// the others, constant blocks, and every block when the information is rank deficient.
template <typename Wanted>
std::vector<std::optional<Eigen::Matrix3d>> MarginalCovariances(
    ceres::Problem& problem, std::vector<std::array<double, 3>>* x, const Wanted& wanted) {
  std::vector<std::optional<Eigen::Matrix3d>> out(x->size());
  std::vector<std::size_t> free;
  std::vector<std::pair<const double*, const double*>> blocks;
  for (std::size_t i = 0; i < x->size(); ++i) {
    double* b = (*x)[i].data();
    if (!wanted(i) || !problem.HasParameterBlock(b) || problem.IsParameterBlockConstant(b))
      continue;
    free.push_back(i);
    blocks.emplace_back(b, b);
  }
  ceres::Covariance::Options co;
  co.algorithm_type = ceres::SPARSE_QR;
  co.num_threads = 1;
  co.apply_loss_function = true;
  ceres::Covariance covariance(co);
  if (blocks.empty() || !covariance.Compute(blocks, &problem)) return out;
  for (const std::size_t i : free) {
    Eigen::Matrix<double, 3, 3, Eigen::RowMajor> c;
    const double* b = (*x)[i].data();
    if (covariance.GetCovarianceBlock(b, b, c.data()))
      out[i] = Eigen::Matrix3d(0.5 * (c + c.transpose()));
  }
  return out;
}

}  // namespace

const NodeCorrection* FindCorrection(const std::vector<NodeCorrection>& corrections,
                                     std::int64_t frame) {
  const auto it =
      std::lower_bound(corrections.begin(), corrections.end(), frame,
                       [](const NodeCorrection& c, std::int64_t f) { return c.frame < f; });
  return it != corrections.end() && it->frame == frame ? &*it : nullptr;
}

const NodeCorrection* TrackerCorrection(const std::vector<NodeCorrection>& corrections,
                                        PoseGraphOptions::TrackerFollows follows,
                                        std::optional<std::int64_t> fixed_by) {
  if (corrections.empty()) return nullptr;
  if (follows == PoseGraphOptions::TrackerFollows::kNewestNode) return &corrections.back();
  return fixed_by ? FindCorrection(corrections, *fixed_by) : nullptr;
}

PoseGraph::PoseGraph(const PoseGraphOptions& options, const MotionNoise& motion,
                     double min_translation_variance_m2, double min_rotation_variance_rad2,
                     std::size_t max_recent_frames)
    : options_(options),
      motion_(motion),
      min_translation_variance_m2_(min_translation_variance_m2),
      min_rotation_variance_rad2_(min_rotation_variance_rad2),
      max_recent_frames_(std::max<std::size_t>(max_recent_frames, 1)) {}

void PoseGraph::BeginSession(bool continue_segment, std::int64_t first_frame,
                             const std::optional<Gaussian>& known_start) {
  if (!continue_segment) new_segment_ = true;
  start_prior_ = known_start;
  start_prior_frame_ = known_start ? first_frame : -1;
}

void PoseGraph::AddFrameOdometry(std::int64_t frame, const OdometryIncrement& u) {
  if (new_segment_) {
    // A new segment starts at its own origin: its first frame's increment is not used.
    segment_ += 1;
    new_segment_ = false;
    odom_ = Pose2::Zero();
    odom_cov_ = Eigen::Matrix3d::Zero();
  } else {
    ReconstructionOptions r;
    r.motion = motion_;
    r.min_translation_variance_m2 = min_translation_variance_m2_;
    r.min_rotation_variance_rad2 = min_rotation_variance_rad2_;
    odom_ = Compose(odom_, IncrementToRelativePose(u));
    odom_cov_ += IncrementCovariance(u, r);
  }
  recent_.push_back(FrameOdometry{frame, segment_, odom_, odom_cov_});
  // Frames older than the longest wait for reconstruction can no longer become nodes.
  while (recent_.size() > max_recent_frames_) recent_.pop_front();
}

void PoseGraph::AddNode(std::int64_t frame, const Pose2& pose,
                        const std::optional<Gaussian>& prior) {
  if (!nodes_.empty() && frame <= nodes_.back().frame) return;
  PoseGraphNode n;
  n.frame = frame;
  n.pose = pose;
  n.prior = prior;
  if (!n.prior && start_prior_ && frame == start_prior_frame_) n.prior = start_prior_;
  while (!recent_.empty() && recent_.front().frame < frame) recent_.pop_front();
  if (!recent_.empty() && recent_.front().frame == frame) {
    n.segment = recent_.front().segment;
    n.odom = recent_.front().odom;
    n.odom_cov = recent_.front().cov;
    recent_.pop_front();
  }
  nodes_.push_back(std::move(n));
}

std::size_t PoseGraph::IndexOf(std::int64_t frame) const {
  const auto it =
      std::lower_bound(nodes_.begin(), nodes_.end(), frame,
                       [](const PoseGraphNode& n, std::int64_t f) { return n.frame < f; });
  if (it == nodes_.end() || it->frame != frame) return nodes_.size();
  return static_cast<std::size_t>(it - nodes_.begin());
}

const PoseGraphNode* PoseGraph::FindNode(std::int64_t frame) const {
  const std::size_t i = IndexOf(frame);
  return i < nodes_.size() ? &nodes_[i] : nullptr;
}

bool PoseGraph::AddClosure(std::int64_t view_created_frame, std::int64_t frame, const Pose2& m,
                           const Eigen::Matrix3d& component_covariance) {
  const PoseGraphNode* from = FindNode(view_created_frame);
  if (from == nullptr) return false;
  const Eigen::Matrix2d cxy = 0.5 * (component_covariance.topLeftCorner<2, 2>() +
                                     component_covariance.topLeftCorner<2, 2>().transpose());
  // Largest eigenvalue of the symmetric 2x2 block (closed form): an isotropic bound, so
  // the covariance needs no rotation into the creator's frame.
  const double half_trace = 0.5 * (cxy(0, 0) + cxy(1, 1));
  const double half_diff = 0.5 * (cxy(0, 0) - cxy(1, 1));
  const double largest = half_trace + std::sqrt(half_diff * half_diff + cxy(0, 1) * cxy(0, 1));
  const double s2 = options_.closure_sigma_m * options_.closure_sigma_m + std::max(largest, 0.0);
  const double sphi2 = options_.closure_sigma_rad * options_.closure_sigma_rad +
                       std::max(component_covariance(2, 2), 0.0);
  return AddRelativeClosure(view_created_frame, frame, Between(from->pose, m),
                            Eigen::Vector3d(s2, s2, sphi2).asDiagonal());
}

bool PoseGraph::AddRelativeClosure(std::int64_t from_frame, std::int64_t frame, const Pose2& z,
                                   const Eigen::Matrix3d& covariance) {
  if (frame - from_frame < options_.min_loop_frames) return false;
  if (frame - last_closure_frame_ < options_.closure_every_frames) return false;
  if (FindNode(from_frame) == nullptr || FindNode(frame) == nullptr) return false;
  // Standard deviations below 1 mm and 0.1 mrad are raised to them: a zero neighbourhood
  // (appearance_sigma_m 0) would make the factor's information infinite.
  constexpr double kMinClosureVarianceM2 = 1e-6;
  constexpr double kMinClosureVarianceRad2 = 1e-8;
  PoseGraphClosure c;
  c.from_frame = from_frame;
  c.to_frame = frame;
  c.z = z;
  c.covariance = 0.5 * (covariance + covariance.transpose());
  c.covariance(0, 0) = std::max(c.covariance(0, 0), kMinClosureVarianceM2);
  c.covariance(1, 1) = std::max(c.covariance(1, 1), kMinClosureVarianceM2);
  c.covariance(2, 2) = std::max(c.covariance(2, 2), kMinClosureVarianceRad2);
  closures_.push_back(c);
  last_closure_frame_ = frame;
  closure_since_optimize_ = true;
  return true;
}

bool PoseGraph::ShouldOptimize(std::int64_t frame) const {
  return closure_since_optimize_ && frame - last_optimized_frame_ >= options_.optimize_every_frames;
}

std::vector<NodeCorrection> PoseGraph::Optimize(std::int64_t frame,
                                                const std::vector<std::int64_t>* marginal_frames) {
  closure_since_optimize_ = false;
  last_optimized_frame_ = frame;
  std::vector<NodeCorrection> out;
  if (nodes_.size() < 2) return out;
  std::size_t first = nodes_.size() > static_cast<std::size_t>(options_.window_nodes)
                          ? nodes_.size() - static_cast<std::size_t>(options_.window_nodes)
                          : 0;
  if (options_.hold_earlier_sessions && nodes_.back().segment >= 0) {
    // The latest odometry segment's nodes only: earlier sessions' poses are constants
    // that its closures and its start prior tie it to.
    std::size_t own = nodes_.size() - 1;
    while (own > first && nodes_[own - 1].segment == nodes_.back().segment) --own;
    first = std::max(first, own);
  }
  // Parameter blocks: the window's poses, plus copies of older nodes a factor touches
  // (held constant).
  std::vector<std::array<double, 3>> x(nodes_.size() - first);
  std::map<std::size_t, std::array<double, 3>> constants;  // node index -> pose (stable addresses)
  // Closure covariances are multiplied by this while solving (1 except during the
  // graduated start below).
  double closure_inflation = 1.0;
  // Where each solve starts: the nodes' poses, or the graduated start's last solution.
  std::vector<std::array<double, 3>> staged;
  // The last solve's problem (its parameter blocks are x and constants), for the
  // marginal covariances of the final solution.
  std::unique_ptr<ceres::Problem> last_problem;
  const auto solve = [&]() -> bool {
    if (!staged.empty()) {
      x = staged;
    } else {
      for (std::size_t i = first; i < nodes_.size(); ++i) {
        for (int k = 0; k < 3; ++k) x[i - first][static_cast<std::size_t>(k)] = nodes_[i].pose[k];
      }
    }
    constants.clear();
    auto block = [&](std::size_t i) -> double* {
      if (i >= first) return x[i - first].data();
      auto [it, inserted] = constants.try_emplace(i);
      if (inserted) it->second = {nodes_[i].pose[0], nodes_[i].pose[1], nodes_[i].pose[2]};
      return it->second.data();
    };

    ceres::Problem::Options problem_options;
    last_problem = std::make_unique<ceres::Problem>(problem_options);
    ceres::Problem& problem = *last_problem;
    bool gauge = false;
    // Odometry factors between consecutive nodes of one segment (the first links the
    // window to its constant predecessor).
    for (std::size_t i = std::max<std::size_t>(first, 1); i < nodes_.size(); ++i) {
      const PoseGraphNode& a = nodes_[i - 1];
      const PoseGraphNode& b = nodes_[i];
      if (a.segment < 0 || a.segment != b.segment) continue;
      Eigen::Matrix3d sigma = b.odom_cov - a.odom_cov;
      sigma = 0.5 * (sigma + sigma.transpose());
      sigma(0, 0) += min_translation_variance_m2_;
      sigma(1, 1) += min_translation_variance_m2_;
      sigma(2, 2) += min_rotation_variance_rad2_;
      const Pose2 z = Between(a.odom, b.odom);
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<BetweenFactor, 3, 3, 3>(
                                   new BetweenFactor(z, SqrtInformation(sigma))),
                               nullptr, block(i - 1), block(i));
      if (i - 1 < first) gauge = true;
    }
    for (std::size_t i = first; i < nodes_.size(); ++i) {
      if (!nodes_[i].prior) continue;
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<PriorFactor, 3, 3>(
              new PriorFactor(nodes_[i].prior->mean, SqrtInformation(nodes_[i].prior->covariance))),
          nullptr, block(i));
      gauge = true;
    }
    for (const PoseGraphClosure& c : closures_) {
      const std::size_t a = IndexOf(c.from_frame);
      const std::size_t b = IndexOf(c.to_frame);
      if (a >= nodes_.size() || b >= nodes_.size() || (a < first && b < first)) continue;
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<BetweenFactor, 3, 3, 3>(
              new BetweenFactor(c.z, SqrtInformation(closure_inflation * c.covariance))),
          new ceres::CauchyLoss(options_.loss_scale), block(a), block(b));
      if (a < first || b < first) gauge = true;
    }
    for (auto& c : constants) problem.SetParameterBlockConstant(c.second.data());
    if (!gauge && problem.HasParameterBlock(x[0].data()))
      problem.SetParameterBlockConstant(x[0].data());

    ceres::Solver::Options so;
    so.linear_solver_type = x.size() <= 32 ? ceres::DENSE_QR : ceres::SPARSE_NORMAL_CHOLESKY;
    so.num_threads = 1;
    so.max_num_iterations = options_.max_iterations;
    so.function_tolerance = 1e-10;
    so.logging_type = ceres::SILENT;
    so.minimizer_progress_to_stdout = false;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    return summary.IsSolutionUsable();
  };
  optimizations_ += 1;
  // Squared whitened residual of closure c with its end poses given by pose_of(node
  // index); nullopt when c is outside the window (both ends constant).
  const auto closure_chi2 = [&](const PoseGraphClosure& c,
                                const auto& pose_of) -> std::optional<double> {
    const std::size_t a = IndexOf(c.from_frame);
    const std::size_t b = IndexOf(c.to_frame);
    if (a >= nodes_.size() || b >= nodes_.size() || (a < first && b < first)) return std::nullopt;
    const Pose2 pa = pose_of(a);
    const Pose2 pb = pose_of(b);
    double r[3];
    BetweenFactor(c.z, SqrtInformation(c.covariance))(pa.data(), pb.data(), r);
    return r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
  };
  // Graduated start: when a closure disagrees with the current poses by far more than
  // its covariance allows (a long loop closing), Levenberg-Marquardt from those poses
  // can fold the loop (lap-bound on store_large, 100 realisations of one exact lap
  // closure: worst mean error 37.5 m, rms 8.5 m against the closed form's 5.4 m). The
  // window is first solved with the closures' covariances inflated 100 and 10 times, each
  // solution starting the next: the loop bends in stages (worst 14.5 m, rms 5.7 m). The
  // last solve is the unchanged problem, so only its starting point differs.
  {
    double worst = 0.0;
    const auto node_pose = [&](std::size_t i) { return nodes_[i].pose; };
    for (const PoseGraphClosure& c : closures_)
      worst = std::max(worst, closure_chi2(c, node_pose).value_or(0.0));
    // Squared whitened residual beyond which a closure counts as far off: 1000 (about 30
    // standard deviations in one of the 3 dimensions); below it LM starts close enough.
    constexpr double kGraduatedStartChi2 = 1000.0;
    if (worst > kGraduatedStartChi2) {
      for (const double inflation : {100.0, 10.0}) {
        closure_inflation = inflation;
        if (!solve()) break;
        staged = x;
      }
      closure_inflation = 1.0;
    }
  }
  bool usable = solve();
  // Closure verification (as RTAB-Map's maximum optimisation error): a closure whose
  // squared whitened residual after the robust optimisation exceeds reject_chi2 is
  // inconsistent with the rest of the graph (aliasing); it is removed and the window
  // solved again without it.
  if (usable) {
    const auto pose_of = [&](std::size_t i) -> Pose2 {
      if (i >= first) return Pose2(x[i - first][0], x[i - first][1], x[i - first][2]);
      return nodes_[i].pose;
    };
    std::vector<PoseGraphClosure> kept;
    bool rejected = false;
    for (const PoseGraphClosure& c : closures_) {
      if (closure_chi2(c, pose_of).value_or(0.0) > options_.reject_chi2) {
        rejected = true;
        rejected_closures_ += 1;
        continue;
      }
      kept.push_back(c);
    }
    if (rejected) {
      closures_ = std::move(kept);
      usable = solve();
    }
  }
  if (!usable) return out;
  const auto wanted = [&](std::size_t k) {
    return marginal_frames == nullptr ||
           std::binary_search(marginal_frames->begin(), marginal_frames->end(),
                              nodes_[first + k].frame);
  };
  const std::vector<std::optional<Eigen::Matrix3d>> marginals =
      options_.marginal_covariances ? MarginalCovariances(*last_problem, &x, wanted)
                                    : std::vector<std::optional<Eigen::Matrix3d>>(x.size());
  for (std::size_t i = first; i < nodes_.size(); ++i) {
    const Pose2 after = MakePose(x[i - first][0], x[i - first][1], x[i - first][2]);
    if (after == nodes_[i].pose) continue;
    out.push_back({nodes_[i].frame, nodes_[i].pose, after, marginals[i - first]});
    nodes_[i].pose = after;
  }
  return out;
}

void PoseGraph::Write(BinaryWriter& out) const {
  out.Write<std::uint64_t>(nodes_.size());
  for (const PoseGraphNode& n : nodes_) {
    out.Write<std::int64_t>(n.frame);
    out.Write<std::int64_t>(n.segment);
    WritePose(out, n.pose);
    WritePose(out, n.odom);
    WriteMatrix3(out, n.odom_cov);
    out.Write<bool>(n.prior.has_value());
    if (n.prior) {
      WritePose(out, n.prior->mean);
      WriteMatrix3(out, n.prior->covariance);
    }
  }
  out.Write<std::uint64_t>(closures_.size());
  for (const PoseGraphClosure& c : closures_) {
    out.Write<std::int64_t>(c.from_frame);
    out.Write<std::int64_t>(c.to_frame);
    WritePose(out, c.z);
    WriteMatrix3(out, c.covariance);
  }
  out.Write<std::uint64_t>(recent_.size());
  for (const FrameOdometry& f : recent_) {
    out.Write<std::int64_t>(f.frame);
    out.Write<std::int64_t>(f.segment);
    WritePose(out, f.odom);
    WriteMatrix3(out, f.cov);
  }
  out.Write<std::int64_t>(segment_);
  out.Write<bool>(new_segment_);
  WritePose(out, odom_);
  WriteMatrix3(out, odom_cov_);
  out.Write<std::int64_t>(start_prior_frame_);
  out.Write<bool>(start_prior_.has_value());
  if (start_prior_) {
    WritePose(out, start_prior_->mean);
    WriteMatrix3(out, start_prior_->covariance);
  }
  out.Write<std::int64_t>(last_closure_frame_);
  out.Write<std::int64_t>(last_optimized_frame_);
  out.Write<bool>(closure_since_optimize_);
  out.Write<std::int64_t>(optimizations_);
  out.Write<std::int64_t>(rejected_closures_);
}

void PoseGraph::Read(BinaryReader& in) {
  nodes_.clear();
  closures_.clear();
  recent_.clear();
  const std::size_t n = in.ReadCount("pose_graph.nodes", 8 + 8 + 48 + 72 + 1);
  for (std::size_t i = 0; i < n; ++i) {
    PoseGraphNode node;
    node.frame = in.Read<std::int64_t>("pose_graph.node.frame");
    node.segment = in.Read<std::int64_t>("pose_graph.node.segment");
    node.pose = ReadPose(in, "pose_graph.node.pose");
    node.odom = ReadPose(in, "pose_graph.node.odom");
    node.odom_cov = ReadMatrix3(in, "pose_graph.node.odom_cov");
    if (in.Read<bool>("pose_graph.node.prior")) {
      Gaussian g;
      g.mean = ReadPose(in, "pose_graph.node.prior");
      g.covariance = ReadMatrix3(in, "pose_graph.node.prior");
      node.prior = g;
    }
    if (!nodes_.empty() && node.frame <= nodes_.back().frame)
      in.Fail("pose_graph.node.frame", "frames not increasing");
    nodes_.push_back(std::move(node));
  }
  const std::size_t c = in.ReadCount("pose_graph.closures", 8 + 8 + 24 + 72);
  for (std::size_t i = 0; i < c; ++i) {
    PoseGraphClosure cl;
    cl.from_frame = in.Read<std::int64_t>("pose_graph.closure.from");
    cl.to_frame = in.Read<std::int64_t>("pose_graph.closure.to");
    cl.z = ReadPose(in, "pose_graph.closure.z");
    cl.covariance = ReadMatrix3(in, "pose_graph.closure.covariance");
    if (Eigen::LLT<Eigen::Matrix3d>(cl.covariance).info() != Eigen::Success ||
        !cl.covariance.allFinite()) {
      in.Fail("pose_graph.closure.covariance", "not symmetric positive definite");
    }
    closures_.push_back(cl);
  }
  const std::size_t r = in.ReadCount("pose_graph.recent", 8 + 8 + 24 + 72);
  for (std::size_t i = 0; i < r; ++i) {
    FrameOdometry f;
    f.frame = in.Read<std::int64_t>("pose_graph.recent.frame");
    f.segment = in.Read<std::int64_t>("pose_graph.recent.segment");
    f.odom = ReadPose(in, "pose_graph.recent.odom");
    f.cov = ReadMatrix3(in, "pose_graph.recent.cov");
    recent_.push_back(f);
  }
  segment_ = in.Read<std::int64_t>("pose_graph.segment");
  new_segment_ = in.Read<bool>("pose_graph.new_segment");
  odom_ = ReadPose(in, "pose_graph.odom");
  odom_cov_ = ReadMatrix3(in, "pose_graph.odom_cov");
  start_prior_frame_ = in.Read<std::int64_t>("pose_graph.start_prior_frame");
  start_prior_.reset();
  if (in.Read<bool>("pose_graph.start_prior")) {
    Gaussian g;
    g.mean = ReadPose(in, "pose_graph.start_prior");
    g.covariance = ReadMatrix3(in, "pose_graph.start_prior");
    start_prior_ = g;
  }
  last_closure_frame_ = in.Read<std::int64_t>("pose_graph.last_closure_frame");
  last_optimized_frame_ = in.Read<std::int64_t>("pose_graph.last_optimized_frame");
  closure_since_optimize_ = in.Read<bool>("pose_graph.closure_since_optimize");
  optimizations_ = in.Read<std::int64_t>("pose_graph.optimizations");
  rejected_closures_ = in.Read<std::int64_t>("pose_graph.rejected_closures");
}

bool PoseGraph::operator==(const PoseGraph& o) const {
  auto same_recent = [&] {
    if (recent_.size() != o.recent_.size()) return false;
    for (std::size_t i = 0; i < recent_.size(); ++i) {
      const FrameOdometry& a = recent_[i];
      const FrameOdometry& b = o.recent_[i];
      if (a.frame != b.frame || a.segment != b.segment || a.odom != b.odom || a.cov != b.cov)
        return false;
    }
    return true;
  };
  const bool same_prior =
      start_prior_.has_value() == o.start_prior_.has_value() &&
      (!start_prior_ || (start_prior_->mean == o.start_prior_->mean &&
                         start_prior_->covariance == o.start_prior_->covariance));
  return nodes_ == o.nodes_ && closures_ == o.closures_ && same_recent() &&
         segment_ == o.segment_ && new_segment_ == o.new_segment_ && odom_ == o.odom_ &&
         odom_cov_ == o.odom_cov_ && start_prior_frame_ == o.start_prior_frame_ && same_prior &&
         last_closure_frame_ == o.last_closure_frame_ &&
         last_optimized_frame_ == o.last_optimized_frame_ &&
         closure_since_optimize_ == o.closure_since_optimize_ &&
         optimizations_ == o.optimizations_ && rejected_closures_ == o.rejected_closures_;
}

}  // namespace omnicml
