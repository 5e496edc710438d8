#include "omnicml/mapping/reference_view.h"

#include <cmath>
#include <cstdlib>
#include <limits>

#include <Eigen/Cholesky>

namespace omnicml {

double ReferenceView::TotalWeight() const {
  double sum = 0.0;
  for (const ViewComponent& c : components) sum += c.weight;
  return sum;
}

void ViewFootprint::Observe(double x_m, double y_m, double w) {
  if (!(w > 0)) return;
  const double total = weight + w;
  const Eigen::Vector2d delta = Eigen::Vector2d(x_m, y_m) - mean;
  mean += (w / total) * delta;
  // Weighted Welford update: w (1 - w / total) delta delta^T, kept exactly symmetric.
  const double k = w * (1.0 - w / total);
  scatter(0, 0) += k * delta.x() * delta.x();
  scatter(1, 1) += k * delta.y() * delta.y();
  scatter(0, 1) += k * delta.x() * delta.y();
  scatter(1, 0) = scatter(0, 1);
  weight = total;
}

Eigen::Matrix2d ViewFootprint::Covariance() const {
  return weight > 0 ? Eigen::Matrix2d(scatter / weight) : Eigen::Matrix2d::Zero();
}

double ViewFootprint::SquaredDistance(const Eigen::Vector2d& p, const Eigen::Matrix2d& s) const {
  const Eigen::Vector2d d = p - mean;
  const Eigen::LLT<Eigen::Matrix2d> llt(s);
  if (llt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return llt.matrixL().solve(d).squaredNorm();
}

bool ViewFootprint::PassEnded(const UpdateContext& context, int gap_frames) const {
  return last_expected_session != context.session ||
         std::abs(context.frame - last_expected_frame) > gap_frames;
}

PassOutcomes ViewFootprint::NoteExpected(const UpdateContext& context, bool matched,
                                         int gap_frames) {
  PassOutcomes out;
  const bool passed_before = last_expected_frame >= 0;
  const bool new_pass = !passed_before || PassEnded(context, gap_frames);
  if (new_pass) {
    if (passed_before && !pass_matched) {
      out.closed_missed_run = missed_passes;
      ++missed_passes;
    }
    pass_matched = false;
  }
  if (matched) {
    if (!pass_matched) {
      ++matched_passes;
      if (passed_before) out.matched_run = missed_passes;
    }
    pass_matched = true;
    missed_passes = 0;
  }
  last_expected_frame = context.frame;
  last_expected_session = context.session;
  return out;
}

bool IsValidSpread(const Eigen::Matrix2d& s) {
  const double scale = s(0, 0) + s(1, 1);
  return s.allFinite() && s(0, 1) == s(1, 0) && s(0, 0) >= 0 && s(1, 1) >= 0 &&
         s(0, 1) * s(0, 1) <= s(0, 0) * s(1, 1) + 1e-12 * scale * scale;
}

ViewFootprint FootprintFromComponents(const std::vector<ViewComponent>& components) {
  ViewFootprint f;
  for (const ViewComponent& c : components) f.Observe(c.mean.x(), c.mean.y(), c.eta);
  return f;
}

Pose2 InViewFrame(const Pose2& mu_t, const std::optional<double>& relative_heading_rad) {
  if (!relative_heading_rad) return mu_t;
  return MakePose(mu_t.x(), mu_t.y(), mu_t.z() - *relative_heading_rad);
}

Eigen::Matrix3d EffectiveCovariance(const Eigen::Matrix3d& c,
                                    const std::optional<double>& relative_heading_rad,
                                    double heading_sigma_rad) {
  if (relative_heading_rad) return c;
  Eigen::Matrix3d out = c;
  out(2, 2) += heading_sigma_rad * heading_sigma_rad;
  return out;
}

}  // namespace omnicml
