#include "omnicml/tracking/tracker.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <optional>
#include <utility>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "omnicml/common/common.h"
#include "omnicml/geometry/chi_square.h"

namespace omnicml {
namespace {

void CheckWeights(const Mixture& m, const char* where) {
  for (std::size_t i = 0; i < m.size(); ++i) {
    const double w = m[i].weight;
    if (!(std::isfinite(w) && w >= 0)) {
      throw Error(StrCat(where, "[", i, "]: weight must be finite and >= 0, got ", w));
    }
    if (!m[i].mean.allFinite()) throw Error(StrCat(where, "[", i, "]: mean has NaN/inf entries"));
  }
}

// Repairs every covariance of m (RepairCovariance), naming the component on failure.
void RepairAll(Mixture* m, double min_eigenvalue, const char* where) {
  static const std::string kWhat = "covariance";
  for (std::size_t i = 0; i < m->size(); ++i) {
    try {
      (*m)[i].covariance = RepairCovariance((*m)[i].covariance, min_eigenvalue, kWhat);
    } catch (const Error& e) {
      throw Error(StrCat(where, "[", i, "]: ", e.what()));
    }
  }
}

// A component prepared for fusion: covariance (repaired), its inverse and determinant.
struct Prepared {
  Eigen::Matrix3d information;
  double det = 0.0;
};

Prepared Prepare(const Gaussian& g) {
  Prepared p;
  p.information = g.covariance.inverse();
  p.det = g.covariance.determinant();
  return p;
}

double Alpha(double w_a, double det_a, double w_b, double det_b) {
  // (5): alpha = w_b det(C_a) / (w_b det(C_a) + w_a det(C_b)). Both weights zero leaves
  // no preference: alpha = 1/2.
  const double num = w_b * det_a;
  const double den = num + w_a * det_b;
  if (!(den > 0)) return 0.5;
  return num / den;
}

// (3)-(4) in information form around mu_a (CombineInformation). `independent` replaces
// the weights (1 - alpha, alpha) by (1, 1): the Kalman update.
Gaussian Intersect(const Gaussian& a, const Prepared& pa, const Gaussian& b, const Prepared& pb,
                   double alpha, double min_eigenvalue, bool independent = false) {
  return CombineInformation(a, pa.information, independent ? 1.0 : 1.0 - alpha, b, pb.information,
                            independent ? 1.0 : alpha, min_eigenvalue, "CovarianceIntersection");
}

// a - b with the heading wrapped; the common case of two wrapped headings needs no fmod.
Eigen::Vector3d Difference(const Pose2& a, const Pose2& b) {
  double dphi = a.z() - b.z();
  if (dphi > kPi || dphi <= -kPi) dphi = WrapAngle(dphi);
  return Eigen::Vector3d(a.x() - b.x(), a.y() - b.y(), dphi);
}

// Squared Mahalanobis distance of a and b under C_a + C_b (SPD) if it is below
// `threshold`; std::nullopt otherwise. Most pairs of a mixture are far apart: since
// d^T S^-1 d >= |d|^2 / lambda_max(S) >= |d|^2 / trace(S), those are rejected without
// forming or factorising S.
std::optional<double> SquaredMahalanobisBelow(const Gaussian& a, const Gaussian& b,
                                              double threshold) {
  const Eigen::Vector3d d = Difference(a.mean, b.mean);
  if (d.squaredNorm() >= threshold * (a.covariance.trace() + b.covariance.trace()))
    return std::nullopt;
  const Eigen::LLT<Eigen::Matrix3d> llt(a.covariance + b.covariance);
  if (llt.info() != Eigen::Success)
    throw Error("squared Mahalanobis distance: C_a + C_b is not positive definite");
  const double d2 = llt.matrixL().solve(d).squaredNorm();
  if (d2 < threshold) return d2;
  return std::nullopt;
}

// True iff a and b lie within the gate (2): squared Mahalanobis under C_a + C_b < gamma.
bool Gated(const Gaussian& a, const Gaussian& b, double gamma) {
  return SquaredMahalanobisBelow(a, b, gamma).has_value();
}

// Indices of m sorted by weight, largest first; ties keep their order.
std::vector<int> ByWeight(const Mixture& m) {
  std::vector<int> order(m.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&m](int i, int j) { return m[i].weight > m[j].weight; });
  return order;
}

// One greedy merging pass: components in decreasing weight join the closest existing
// cluster within delta ([G] (12)), merged by moment matching ((13)-(14)); others start
// a cluster. Returns the clusters, strongest seed first.
Mixture MergePass(const Mixture& m, double delta, double min_eigenvalue) {
  Mixture clusters;
  clusters.reserve(m.size());
  for (int i : ByWeight(m)) {
    const Gaussian& g = m[i];
    int best = -1;
    double best_d = delta;
    for (int k = 0; k < static_cast<int>(clusters.size()); ++k) {
      const std::optional<double> d = SquaredMahalanobisBelow(g, clusters[k], best_d);
      if (d) {
        best_d = *d;
        best = k;
      }
    }
    if (best < 0) {
      clusters.push_back(g);
    } else {
      const Gaussian pair[2] = {clusters[best], g};
      Gaussian merged = MomentMatch(pair);
      static const std::string kWhat = "Simplify: merged covariance";
      merged.covariance = RepairCovariance(merged.covariance, min_eigenvalue, kWhat);
      clusters[best] = merged;
    }
  }
  return clusters;
}

}  // namespace

void TrackerOptions::Validate() const {
  auto fail = [](const char* field, const std::string& rule, double value) {
    throw Error(StrCat("TrackerOptions.", field, " must be ", rule, ", got ", value));
  };
  if (!(std::isfinite(gamma) && gamma > 0)) fail("gamma", "finite and > 0", gamma);
  if (!(gate_confidence >= 0 && gate_confidence < 1)) {
    fail("gate_confidence", "in [0, 1) (0: gamma as given)", gate_confidence);
  }
  if (!(w_min >= 0 && w_min < 1)) fail("w_min", "in [0, 1)", w_min);
  if (!(std::isfinite(delta) && delta >= 0)) fail("delta", "finite and >= 0", delta);
  if (max_components < 1) fail("max_components", ">= 1", max_components);
  if (!(unimodal_min_weight >= 0 && unimodal_min_weight <= 1)) {
    fail("unimodal_min_weight", "in [0, 1]", unimodal_min_weight);
  }
  if (!(std::isfinite(min_covariance_eigenvalue) && min_covariance_eigenvalue > 0)) {
    fail("min_covariance_eigenvalue", "finite and > 0", min_covariance_eigenvalue);
  }
  motion.Validate("TrackerOptions.motion.");
}

double TrackerOptions::Gate() const {
  return gate_confidence > 0 ? ChiSquareQuantile(gate_confidence, 3) : gamma;
}

Mixture Propagate(const Mixture& prior, const OdometryIncrement& u, const MotionNoise& noise) {
  noise.Validate();
  if (!(std::isfinite(u.rot1_rad) && std::isfinite(u.trans_m) && std::isfinite(u.rot2_rad))) {
    throw Error(StrCat("Propagate: the odometry increment is not finite (rot1 ", u.rot1_rad,
                       ", trans ", u.trans_m, ", rot2 ", u.rot2_rad, ")"));
  }
  const Eigen::Matrix3d m = MotionNoiseCovariance(u, noise);
  Mixture out;
  out.reserve(prior.size());
  static const std::string kWhat = "covariance";
  for (std::size_t i = 0; i < prior.size(); ++i) {
    const Gaussian& g = prior[i];
    if (!g.mean.allFinite())
      throw Error(StrCat("Propagate: component ", i, ": mean has NaN/inf entries"));
    const Eigen::Matrix3d jg = MotionJacobianState(g.mean, u);
    const Eigen::Matrix3d jv = MotionJacobianControl(g.mean, u);
    Gaussian p;
    p.mean = ApplyIncrement(g.mean, u);
    p.weight = g.weight;
    try {
      p.covariance = RepairCovariance(jg * g.covariance * jg.transpose() + jv * m * jv.transpose(),
                                      1e-12, kWhat);
    } catch (const Error& e) {
      throw Error(StrCat("Propagate: component ", i, ": ", e.what()));
    }
    out.push_back(std::move(p));
  }
  return out;
}

double CovarianceIntersectionAlpha(const Gaussian& a, const Gaussian& b) {
  return Alpha(a.weight, a.covariance.determinant(), b.weight, b.covariance.determinant());
}

Mixture FuseOnce(const Mixture& a_side, const Mixture& b_side, const TrackerOptions& options) {
  options.Validate();
  CheckWeights(a_side, "FuseOnce: a_side");
  CheckWeights(b_side, "FuseOnce: b_side");
  Mixture a = a_side, b = b_side;
  RepairAll(&a, options.min_covariance_eigenvalue, "FuseOnce: a_side");
  RepairAll(&b, options.min_covariance_eigenvalue, "FuseOnce: b_side");
  const std::size_t na = a.size(), nb = b.size();
  const double gate = options.Gate();

  // (2): the gate D(a, b); (6), (7): hat_w_a = sum of the weights of a's counterparts in
  // b_side, hat_w_b = sum of the weights of b's counterparts in a_side.
  std::vector<std::pair<int, int>> pairs;
  std::vector<double> hat_w_a(na, 0.0), hat_w_b(nb, 0.0);
  std::vector<char> b_matched(nb, 0);
  for (std::size_t i = 0; i < na; ++i) {
    for (std::size_t j = 0; j < nb; ++j) {
      if (!Gated(a[i], b[j], gate)) continue;
      pairs.emplace_back(static_cast<int>(i), static_cast<int>(j));
      hat_w_a[i] += b[j].weight;
      hat_w_b[j] += a[i].weight;
      b_matched[j] = 1;
    }
  }

  std::vector<Prepared> pa(na), pb(nb);
  for (std::size_t i = 0; i < na; ++i) pa[i] = Prepare(a[i]);
  for (std::size_t j = 0; j < nb; ++j) pb[j] = Prepare(b[j]);

  Mixture out;
  out.reserve(pairs.size() + na + nb);
  // a's components in order: its fused pairs, or itself when unmatched; then unmatched b.
  std::size_t p = 0;
  for (std::size_t i = 0; i < na; ++i) {
    if (p == pairs.size() || pairs[p].first != static_cast<int>(i)) {
      out.push_back(a[i]);  // no counterpart: copied unchanged
      continue;
    }
    for (; p < pairs.size() && pairs[p].first == static_cast<int>(i); ++p) {
      const Gaussian& ga = a[i];
      const Gaussian& gb = b[pairs[p].second];
      const double alpha = Alpha(ga.weight, pa[i].det, gb.weight, pb[pairs[p].second].det);  // (5)
      Gaussian fused =
          Intersect(ga, pa[i], gb, pb[pairs[p].second], alpha, options.min_covariance_eigenvalue,
                    options.fusion == FusionRule::kIndependent);
      // (8): w = w_a w_b / hat_w_a + w_b w_a / hat_w_b. Each side's weight is shared
      // among its counterparts in proportion to theirs, so the total weight is kept.
      const double hat_a = hat_w_a[i], hat_b = hat_w_b[pairs[p].second];
      fused.weight = (hat_a > 0 ? ga.weight * gb.weight / hat_a : 0.0) +
                     (hat_b > 0 ? gb.weight * ga.weight / hat_b : 0.0);
      out.push_back(std::move(fused));
    }
  }
  for (std::size_t j = 0; j < nb; ++j) {
    if (!b_matched[j]) out.push_back(b[j]);
  }
  return out;
}

Mixture Simplify(const Mixture& m, const TrackerOptions& options) {
  options.Validate();
  CheckWeights(m, "Simplify: component");
  if (m.empty()) return {};
  Mixture work = m;
  RepairAll(&work, options.min_covariance_eigenvalue, "Simplify: component");
  // A mixture whose weights sum to zero carries no preference: equal weights.
  if (!(TotalWeight(work) > 0)) {
    for (Gaussian& g : work) g.weight = 1.0;
  }
  NormalizeWeights(&work);

  // Prune below w_min; if that would empty the mixture, keep the strongest component.
  Mixture kept;
  kept.reserve(work.size());
  for (const Gaussian& g : work) {
    if (g.weight >= options.w_min) kept.push_back(g);
  }
  if (kept.empty()) kept.push_back(work[StrongestComponent(work)]);

  // Merge ([G] (12)-(14)) until no two clusters lie within delta of each other.
  if (options.delta > 0) {
    while (true) {
      Mixture merged = MergePass(kept, options.delta, options.min_covariance_eigenvalue);
      const bool changed = merged.size() != kept.size();
      kept = std::move(merged);
      if (!changed || kept.size() == 1) break;
    }
  }

  // Cap at max_components by weight.
  if (static_cast<int>(kept.size()) > options.max_components) {
    Mixture capped;
    capped.reserve(options.max_components);
    const std::vector<int> order = ByWeight(kept);
    for (int k = 0; k < options.max_components; ++k) capped.push_back(kept[order[k]]);
    kept = std::move(capped);
  }
  NormalizeWeights(&kept);
  return kept;
}

Mixture Fuse(const Mixture& p_x_u, const std::vector<Mixture>& sources,
             const TrackerOptions& options) {
  options.Validate();
  Mixture fused = p_x_u;
  for (const Mixture& source : sources) {
    if (source.empty()) continue;
    fused = FuseOnce(fused, source, options);
  }
  // A fused mixture with nothing left (no components or no weight) falls back to p(x|u).
  if (fused.empty() || !(TotalWeight(fused) > 0)) return Simplify(p_x_u, options);
  return Simplify(fused, options);
}

bool IsUnimodal(const Mixture& m, const TrackerOptions& options) {
  if (m.empty()) return false;
  const double gate = options.Gate();
  const double total = TotalWeight(m);
  const int s = StrongestComponent(m);
  for (int i = 0; i < static_cast<int>(m.size()); ++i) {
    if (i == s) continue;
    const double w = total > 0 ? m[i].weight / total : 1.0 / static_cast<double>(m.size());
    if (w < options.unimodal_min_weight) continue;
    if (SquaredMahalanobis(m[i].mean, m[s].mean, m[i].covariance + m[s].covariance) >= gate)
      return false;
  }
  return true;
}

Estimate Summarize(const Mixture& m, const TrackerOptions& options) {
  if (m.empty()) throw Error("Summarize: the mixture is empty");
  CheckWeights(m, "Summarize: component");
  Mixture normalized = m;
  if (!(TotalWeight(normalized) > 0)) {
    for (Gaussian& g : normalized) g.weight = 1.0;
  }
  NormalizeWeights(&normalized);
  Estimate e;
  e.strongest = normalized[StrongestComponent(normalized)];
  e.mean = MomentMatch(normalized);
  e.mean.covariance =
      RepairCovariance(e.mean.covariance, options.min_covariance_eigenvalue, "Summarize: C_t");
  e.mean.weight = 1.0;
  e.unimodal = IsUnimodal(normalized, options);
  e.num_components = static_cast<int>(m.size());
  return e;
}

MixtureTracker::MixtureTracker(const TrackerOptions& options) : options_(options) {
  options_.Validate();
}

void MixtureTracker::Reset(const Gaussian& start) {
  if (!start.mean.allFinite())
    throw Error("MixtureTracker::Reset: the start mean has NaN/inf entries");
  Gaussian g = start;
  g.mean = MakePose(start.mean.x(), start.mean.y(), start.mean.z());
  g.covariance = RepairCovariance(start.covariance, options_.min_covariance_eigenvalue,
                                  "MixtureTracker::Reset: start covariance");
  g.weight = 1.0;
  state_ = {g};
}

void MixtureTracker::ResetUnknown() { state_.clear(); }

std::optional<Estimate> MixtureTracker::Step(const OdometryIncrement& u,
                                             const std::vector<Mixture>& sources) {
  if (state_.empty()) {
    // Global localization: seed from the first non-empty source; odometry is ignored
    // because the source describes x_t itself.
    for (const Mixture& source : sources) {
      if (source.empty()) continue;
      state_ = Simplify(source, options_);
      return Summarize(state_, options_);
    }
    return std::nullopt;
  }
  state_ = Fuse(Propagate(state_, u, options_.motion), sources, options_);
  return Summarize(state_, options_);
}

}  // namespace omnicml
