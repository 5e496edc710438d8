// Mixture-of-Gaussians multi-hypothesis tracker [G 2.1]: propagation of a state mixture
// by odometry, fusion of p(x|u) with p(x|y) and further sources by covariance
// intersection, normalisation, pruning, merging, capping; the unimodality test and the
// estimate summary.
//
// All functions are pure (inputs -> outputs); MixtureTracker keeps the current p(x_t)
// and is thread-compatible (one thread at a time).
#ifndef OMNICML_TRACKING_TRACKER_H_
#define OMNICML_TRACKING_TRACKER_H_

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

// How a gated pair (a from p(x|u) or an earlier fusion, b from a source) becomes one
// component (docs/design.md "Fusion of state hypotheses").
enum class FusionRule {
  // [G] (3)-(5): weighted covariance intersection, consistent whatever the (unknown)
  // correlation between a and b; never narrower than the CI bound, so equal covariances
  // fuse to the same covariance.
  kCovarianceIntersection,
  // The information-filter (Kalman) update C = (C_a^-1 + C_b^-1)^-1, mu = C (C_a^-1 mu_a +
  // C_b^-1 mu_b): optimal when a and b are independent, over-confident when they share
  // errors (a map built from the same trajectory).
  kIndependent,
};

struct TrackerOptions {
  // Gate (2): a and b are fused iff their squared Mahalanobis distance under C_a + C_b
  // is below gamma. Dimensionless, on the engine's own covariances. For consistent
  // covariances the 99 % chi-square quantile (3 DOF) is 11.34, [G]'s choice. The default
  // 3.0 is that gate for covariances about four times wider (in the squared distance)
  // than the errors, as the default motion noise and covariance intersection give
  // (docs/results.md "The fusion gate"). Also the unimodality radius (below) and the prior
  // gate of p(x|y). Ignored when gate_confidence > 0.
  double gamma = 3.0;
  // Components with normalised weight below w_min are dropped. Dimensionless.
  double w_min = 1e-3;
  // Components closer than delta (squared Mahalanobis under the sum of covariances,
  // [G] (12)) are merged by moment matching. Dimensionless.
  double delta = 1.0;
  // At most this many components are kept, by weight.
  int max_components = 50;
  // Unimodality: every component with normalised weight >= unimodal_min_weight must lie
  // within gamma (squared Mahalanobis) of the strongest one.
  double unimodal_min_weight = 0.05;
  // Smallest eigenvalue a covariance may have after repair (m^2 / rad^2).
  double min_covariance_eigenvalue = 1e-10;
  // The fusion of a gated pair (FusionRule).
  FusionRule fusion = FusionRule::kCovarianceIntersection;
  // The gate stated as a confidence: when > 0 (and < 1), gamma is the chi-square quantile
  // of this probability with 3 degrees of freedom (0.99 -> 11.34), the textbook gate for
  // a consistent covariance. 0: gamma as given.
  double gate_confidence = 0.0;
  MotionNoise motion;
  void Validate() const;  // throws omnicml::Error naming the field
  // The gate in use: ChiSquareQuantile(gate_confidence, 3) when gate_confidence > 0, else
  // gamma.
  double Gate() const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, TrackerOptions& o) {
  v("gamma", o.gamma);
  v("w_min", o.w_min);
  v("delta", o.delta);
  v("max_components", o.max_components);
  v("unimodal_min_weight", o.unimodal_min_weight);
  v("min_covariance_eigenvalue", o.min_covariance_eigenvalue);
  // Fields after engine file format 14 (engine_io.h): omitted from engine files while
  // they keep their defaults, so default files keep their bytes and older files load.
  v.Since(15, [&](auto& w) {
    w.NamedEnum("fusion", o.fusion,
                {{FusionRule::kCovarianceIntersection, "covariance_intersection"},
                 {FusionRule::kIndependent, "independent"}});
    w("gate_confidence", o.gate_confidence);
  });
  v.Section("motion", o.motion);
}

// p(x|u): mu' = g(mu, u); C' = G C G^T + V M V^T; weights unchanged.
Mixture Propagate(const Mixture& prior, const OdometryIncrement& u, const MotionNoise& noise);

// Weighted covariance intersection of a and b with alpha as in (5):
// alpha = w_b det(C_a) / (w_b det(C_a) + w_a det(C_b)); C = ((1-alpha) C_a^-1 + alpha C_b^-1)^-1
// (3); mu = C ((1-alpha) C_a^-1 mu_a + alpha C_b^-1 mu_b) (4) with mu_b's angle unwrapped next to
// mu_a's. The returned weight is 0 (set by Fuse from (8)).
double CovarianceIntersectionAlpha(const Gaussian& a, const Gaussian& b);
// The fusion itself: CovarianceIntersection(a, b, alpha) (geometry/gaussian_mixture.h).

// Fusion of p(x|u) with one or more other sources [G 2.1, (2)-(8)] followed by
// normalisation, pruning, merging and capping. Sources are fused one after the other,
// the result of one fusion being the `a` side of the next, before the final
// normalisation. Unmatched components of every side are copied. If every source is
// empty the result is the (normalised, pruned, merged) p(x|u).
Mixture Fuse(const Mixture& p_x_u, const std::vector<Mixture>& sources,
             const TrackerOptions& options);

// One fusion step without the final clean-up (exposed for tests of (6)-(8)).
Mixture FuseOnce(const Mixture& a_side, const Mixture& b_side, const TrackerOptions& options);

// Normalise; drop below w_min; merge closer than delta; cap at max_components; normalise.
Mixture Simplify(const Mixture& m, const TrackerOptions& options);

// The tracker's output for one frame.
struct Estimate {
  Gaussian strongest;  // the component of largest weight
  Gaussian mean;       // moment-matched summary of the whole mixture (mu_t, C_t)
  bool unimodal = false;
  int num_components = 0;
};

bool IsUnimodal(const Mixture& m, const TrackerOptions& options);
// Throws omnicml::Error on an empty mixture.
Estimate Summarize(const Mixture& m, const TrackerOptions& options);

// Keeps p(x_t) between frames.
class MixtureTracker {
 public:
  explicit MixtureTracker(const TrackerOptions& options);

  // Sets p(x) to a single Gaussian (known start pose).
  void Reset(const Gaussian& start);
  // Clears p(x): the next Step seeds the mixture from its first non-empty source
  // (global localization); until then the state is unknown.
  void ResetUnknown();
  bool HasState() const { return !state_.empty(); }

  // One frame: p(x|u) = Propagate(p(x_{t-1}), u); p(x_t) = Fuse(p(x|u), sources).
  // With no state yet, p(x_t) = Simplify(first non-empty source). Returns the summary,
  // or std::nullopt while the state is still unknown.
  std::optional<Estimate> Step(const OdometryIncrement& u, const std::vector<Mixture>& sources);

  const Mixture& state() const { return state_; }
  void set_state(Mixture m) { state_ = std::move(m); }
  const TrackerOptions& options() const { return options_; }

 private:
  TrackerOptions options_;
  Mixture state_;
};

}  // namespace omnicml

#endif  // OMNICML_TRACKING_TRACKER_H_
