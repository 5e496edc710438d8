// CmlEngine's use of the global pose graph (pose_graph.h, docs/design.md "Global pose
// graph"): loop closures from appearance matches, optimisation, and moving the map, the
// queued updates and the tracker with the corrected nodes. Kept apart from
// cml_engine.cc so the CML pipeline and the graph can change independently.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <optional>
#include <utility>

#include <Eigen/Cholesky>

#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/geometry/gaussian_mixture.h"

namespace omnicml {
namespace {

// g moved rigidly from `before` to `after` (the correction of the node it hangs from):
// mean xy' = after.xy + R(dphi) (xy - before.xy), phi' = phi + dphi, C' = J C J^T with
// J = diag(R(dphi), 1) — the transformation of EnvironmentModel::MoveViewRigidly.
Gaussian MoveRigidly(const Gaussian& g, const Pose2& before, const Pose2& after) {
  const double dphi = WrapAngle(after.z() - before.z());
  const double c = std::cos(dphi);
  const double s = std::sin(dphi);
  Eigen::Matrix3d j = Eigen::Matrix3d::Identity();
  j(0, 0) = c;
  j(0, 1) = -s;
  j(1, 0) = s;
  j(1, 1) = c;
  const Eigen::Vector2d xy =
      after.head<2>() + j.topLeftCorner<2, 2>() * (g.mean.head<2>() - before.head<2>());
  Gaussian out = g;
  out.mean = MakePose(xy.x(), xy.y(), g.mean.z() + dphi);
  const Eigen::Matrix3d cov = j * g.covariance * j.transpose();
  out.covariance = 0.5 * (cov + cov.transpose());
  return out;
}

// The view's component of largest weight (the first of equal ones).
const ViewComponent& StrongestOf(const ReferenceView& view) {
  const ViewComponent* strongest = &view.components.front();
  for (const ViewComponent& c : view.components) {
    if (c.weight > strongest->weight) strongest = &c;
  }
  return *strongest;
}

}  // namespace

void CmlEngine::UpdatePoseGraph(std::int64_t t, const std::vector<ViewMatch>& matches,
                                FrameStats* stats) {
  if (matches.empty()) return;
  const auto t0 = std::chrono::steady_clock::now();
  // The best match (matches are sorted by distance, ties by view id).
  const ViewMatch& best = matches.front();
  const ReferenceView* matched =
      best.view_index < model_->NumViews() ? &model_->views()[best.view_index] : nullptr;
  std::optional<std::int64_t> fixed_by;
  if (matched != nullptr) fixed_by = matched->stats.created_frame;
  if (matched != nullptr && best.relative_heading_rad) {
    const ReferenceView& view = *matched;
    const PoseGraphOptions& g = options_.pose_graph;
    // How far from the view's place a match this far in appearance lies.
    const double offset_variance =
        AppearanceOffsetVariance(options_.appearance_offset_curve, best.distance);
    if (g.closure_model == PoseGraphOptions::ClosureModel::kViewFrame) {
      // The view's panorama was taken at its creator's pose: the current frame is at that
      // place, turned by the relative heading (design.md "Global pose graph").
      const double s = g.closure_sigma_m > 0.0 ? g.closure_sigma_m : options_.appearance_sigma_m;
      // A component's spread is in the map frame and the closure in the creator's: the
      // strongest component's largest axis beyond the neighbourhood, in every direction
      // (the closure holds no component covariance that could explain part of it).
      const double spread =
          options_.appearance_offset_spread
              ? LargestEigenvalue2(SpreadBeyond(StrongestOf(view).spread,
                                                SpreadFloor() * Eigen::Matrix2d::Identity()))
              : 0.0;
      const double v = s * s + offset_variance + spread;
      pose_graph_->AddRelativeClosure(
          view.stats.created_frame, t, MakePose(0.0, 0.0, *best.relative_heading_rad),
          Eigen::Vector3d(v, v, g.closure_sigma_rad * g.closure_sigma_rad).asDiagonal());
    } else {
      // The pose the view says the robot is at, as in p(x|y): its strongest component
      // rotated by the relative heading.
      const ViewComponent& strongest = StrongestOf(view);
      const Pose2 m = MakePose(strongest.mean.x(), strongest.mean.y(),
                               strongest.mean.z() + *best.relative_heading_rad);
      Eigen::Matrix3d covariance = strongest.covariance;
      covariance(0, 0) += offset_variance;
      covariance(1, 1) += offset_variance;
      // (S2), as p(x|y) takes it.
      if (options_.appearance_offset_spread)
        covariance.topLeftCorner<2, 2>() += SpreadExcess(strongest, SpreadFloor());
      pose_graph_->AddClosure(view.stats.created_frame, t, m, covariance);
    }
  }
  if (pose_graph_->ShouldOptimize(t))
    ApplyPoseGraphCorrections(OptimizePoseGraph(t), fixed_by, stats);
  stats->pose_graph_us +=
      std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
}

std::vector<NodeCorrection> CmlEngine::OptimizePoseGraph(std::int64_t t) {
  if (!options_.pose_graph.marginal_covariances) return pose_graph_->Optimize(t);
  // Marginals are wanted only where a view can take them: at the nodes that created one.
  std::vector<std::int64_t> creators;
  creators.reserve(model_->NumViews());
  for (const ReferenceView& v : model_->views()) creators.push_back(v.stats.created_frame);
  std::sort(creators.begin(), creators.end());
  creators.erase(std::unique(creators.begin(), creators.end()), creators.end());
  return pose_graph_->Optimize(t, &creators);
}

void CmlEngine::GiveMarginalToComponentsAtTheNode(std::size_t view_index, const NodeCorrection& c) {
  // A component is at the node's place when the node's position lies inside its 99 %
  // ellipse with the marginal added (chi-square, 2 dof); components of the same view
  // elsewhere (aliasing) keep their covariance.
  constexpr double kChi2TwoDof99 = 9.2103;
  // A marginal Ceres returned that is not positive definite (numerically) is not used.
  if (!c.covariance->allFinite() || c.covariance->llt().info() != Eigen::Success) return;
  const std::vector<ViewComponent>& components = model_->views()[view_index].components;
  for (std::size_t k = 0; k < components.size(); ++k) {
    const Eigen::Vector2d d = components[k].mean.head<2>() - c.after.head<2>();
    const Eigen::Matrix2d s =
        components[k].covariance.topLeftCorner<2, 2>() + c.covariance->topLeftCorner<2, 2>();
    if (d.dot(s.ldlt().solve(d)) < kChi2TwoDof99)
      model_->SetComponentCovariance(view_index, k, *c.covariance);
  }
}

void CmlEngine::ApplyPoseGraphCorrections(std::vector<NodeCorrection> corrections,
                                          std::optional<std::int64_t> fixed_by, FrameStats* stats) {
  if (corrections.empty()) return;
  // The filtered estimates behind the smoothing are in the frame before the correction.
  smoothing_history_.clear();
  // Sorted by frame (Optimize returns them in node order).
  const auto find = [&](std::int64_t frame) { return FindCorrection(corrections, frame); };
  // Views move with the node of the update that created them: later components were
  // localized against the view, so they share its error (docs/design.md).
  int moved = 0;
  for (std::size_t i = 0; i < model_->NumViews(); ++i) {
    if (const NodeCorrection* c = find(model_->views()[i].stats.created_frame)) {
      model_->MoveViewRigidly(i, c->before, c->after);
      if (c->covariance) GiveMarginalToComponentsAtTheNode(i, *c);
      ++moved;
    }
  }
  // Updates queued but not yet applied carry their node's old pose.
  for (MapUpdate& u : updater_->mutable_queued()) {
    if (const NodeCorrection* c = find(u.frame))
      u.state = MoveRigidly(u.state, c->before, c->after);
  }
  // The tracker and the anchor (the newest node's frame) move with the node that created
  // the view they were fixed by, or with the newest node (PoseGraphOptions::tracker_follows).
  const NodeCorrection& newest = corrections.back();
  if (anchor_ && anchor_->first == newest.frame) {
    if (const NodeCorrection* follow =
            TrackerCorrection(corrections, options_.pose_graph.tracker_follows, fixed_by)) {
      anchor_->second = MoveRigidly(anchor_->second, follow->before, follow->after);
      Mixture state = tracker_.state();
      for (Gaussian& g : state) g = MoveRigidly(g, follow->before, follow->after);
      tracker_.set_state(std::move(state));
    }
  }
  if (stats != nullptr) stats->pose_graph_moved_views += moved;
}

}  // namespace omnicml
