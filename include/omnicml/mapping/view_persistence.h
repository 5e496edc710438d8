// Whether a view's place still looks like the view: a persistence belief in the manner of
// Rosen, Mason and Leonard's persistence filter ("Towards lifelong feature-based mapping
// in semi-static environments", ICRA 2016), over the passes of docs/forgetting.md, with
// its two parameters estimated from the map's own pass history (docs/design.md "View
// persistence").
//
// Model. A view exists (its place looks as it did) at every pass in which it matched.
// Between two passes an existing place changes for good with probability h (a constant
// hazard per pass: the survival time is geometric); at a pass an existing place is missed
// with probability P_M (people in front, a light state, the estimate at the footprint's
// edge); a changed place never matches (P_F = 0: a match inside the footprint proves the
// place). After m consecutive missed passes since the last matched one (P1)
//
//   P(exists | m) = r^m / (r^m + h sum_{j<m} r^j),  r = (1 - h) P_M,
//
// the j-th term of the sum being "changed after j survived intervals". The next pass
// matches with probability (P2)  q_m = P(exists | m) (1 - h) (1 - P_M).
//
// Estimation. Every closed pass of a view that had passed before is one Bernoulli outcome
// (matched or not) with the run m of missed passes before it: the counts N_m (passes) and
// K_m (matched) for m = 0 .. kRunBins - 1 (the last bin pools longer runs). The posterior
// of (h, P_M) is evaluated on a grid from the binomial likelihood of (P2) (P3), under a
// prior log-uniform in h on [1e-4, 1) (no preferred rate of change; Rosen et al.'s
// general-purpose survival prior is log-uniform in the rate) and uniform in P_M; the
// belief for a run m is the posterior's 95 % upper quantile of P(exists | m), so a map
// with little history (a wide posterior, much of it at small h) removes nothing.
//
// Plain values; thread-compatible.
#ifndef OMNICML_MAPPING_VIEW_PERSISTENCE_H_
#define OMNICML_MAPPING_VIEW_PERSISTENCE_H_

#include <array>
#include <cstdint>

namespace omnicml {

// (P1): the probability that a view still exists after `missed_passes` (>= 0) consecutive
// missed passes, for hazard h and miss probability p_miss (both in [0, 1]).
double PersistenceProbability(int missed_passes, double h, double p_miss);

// The counts of (P3) and the belief fitted to them.
class ViewPersistence {
 public:
  static constexpr int kRunBins = 16;
  // The posterior quantile the belief reports (of P(exists | m) over (h, P_M)).
  static constexpr double kQuantile = 0.95;

  // One closed pass: the run of missed passes before it (>= 0) and whether it matched.
  void Record(int missed_before, bool matched);
  // Refits the belief when the counts have grown by at least max(16, 2 %) passes since the
  // last fit (a schedule of the counts only, so a run split by a save and load refits
  // where the whole run does); returns whether it refitted.
  bool MaybeRefit();
  // Refits now.
  void Refit();

  // The belief for a run of m (>= 0) missed passes: the 95 % upper posterior quantile of
  // P(exists | m); 1 before the first fit and for m = 0.
  double UpperExistence(int missed_passes) const;
  // Posterior means of h and P_M at the last fit (0 before it).
  double hazard() const { return mean_hazard_; }
  double miss_probability() const { return mean_miss_; }

  std::int64_t passes() const;  // sum of N_m
  const std::array<std::int64_t, kRunBins>& passes_by_run() const { return passes_; }
  const std::array<std::int64_t, kRunBins>& matched_by_run() const { return matched_; }
  std::int64_t passes_at_fit() const { return passes_at_fit_; }
  const std::array<double, kRunBins>& upper_existence() const { return upper_; }

  // Restores a stored state (engine file); throws omnicml::Error naming `source` when the
  // values are inconsistent (matched > passes, negative counts, beliefs outside [0, 1]).
  void Restore(const std::array<std::int64_t, kRunBins>& passes,
               const std::array<std::int64_t, kRunBins>& matched, std::int64_t passes_at_fit,
               const std::array<double, kRunBins>& upper, double hazard, double miss,
               const char* source);

  bool operator==(const ViewPersistence&) const = default;

 private:
  std::array<std::int64_t, kRunBins> passes_{};
  std::array<std::int64_t, kRunBins> matched_{};
  std::int64_t passes_at_fit_ = 0;
  std::array<double, kRunBins> upper_ = Ones();
  double mean_hazard_ = 0.0;
  double mean_miss_ = 0.0;

  static std::array<double, kRunBins> Ones() {
    std::array<double, kRunBins> a{};
    a.fill(1.0);
    return a;
  }
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_VIEW_PERSISTENCE_H_
