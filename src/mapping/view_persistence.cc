#include "omnicml/mapping/view_persistence.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Grid of the posterior of (h, P_M), kGrid points per axis, each of equal prior mass:
// h log-uniform on [kMinHazard, 1) (no preferred rate of change, as the general-purpose
// survival prior of Rosen et al. is log-uniform in the rate), P_M uniform on (0, 1).
constexpr int kGrid = 64;
constexpr double kMinHazard = 1e-4;

double Midpoint(int i) { return (i + 0.5) / kGrid; }
double HazardAt(int i) { return std::exp(std::log(kMinHazard) * (1.0 - Midpoint(i))); }

}  // namespace

double PersistenceProbability(int missed_passes, double h, double p_miss) {
  OMNICML_CHECK(missed_passes >= 0) << "PersistenceProbability: negative run " << missed_passes;
  if (missed_passes == 0) return 1.0;
  // (P1) with the sum in closed form, divided through by r^m: 1 / (1 + h sum_j r^(j - m)).
  const double r = (1.0 - h) * p_miss;
  if (r <= 0.0) return h > 0.0 ? 0.0 : 1.0;
  double sum = 0.0, term = 1.0 / r;  // r^(-1), r^(-2), ... for j = m - 1 down to 0
  for (int j = 0; j < missed_passes; ++j, term /= r) {
    sum += term;
    if (!std::isfinite(sum)) return 0.0;
  }
  return 1.0 / (1.0 + h * sum);
}

void ViewPersistence::Record(int missed_before, bool matched) {
  OMNICML_CHECK(missed_before >= 0) << "ViewPersistence::Record: negative run";
  const int bin = std::min(missed_before, kRunBins - 1);
  ++passes_[bin];
  if (matched) ++matched_[bin];
}

std::int64_t ViewPersistence::passes() const {
  std::int64_t n = 0;
  for (const std::int64_t c : passes_) n += c;
  return n;
}

bool ViewPersistence::MaybeRefit() {
  const std::int64_t n = passes();
  const std::int64_t due = passes_at_fit_ + std::max<std::int64_t>(16, passes_at_fit_ / 50);
  if (n < due) return false;
  Refit();
  return true;
}

void ViewPersistence::Refit() {
  // (P3): log posterior of (h, P_M) on the grid from the binomial counts of (P2).
  std::vector<double> log_post(kGrid * kGrid);
  std::vector<std::array<double, kRunBins>> existence(kGrid * kGrid);
  double best = -std::numeric_limits<double>::infinity();
  for (int a = 0; a < kGrid; ++a) {
    for (int b = 0; b < kGrid; ++b) {
      const double h = HazardAt(a), p_miss = Midpoint(b);
      const int g = a * kGrid + b;
      double ll = 0.0;
      for (int m = 0; m < kRunBins; ++m) {
        const double e = PersistenceProbability(m, h, p_miss);
        existence[g][m] = e;
        const double q = std::clamp(e * (1.0 - h) * (1.0 - p_miss), 1e-300, 1.0 - 1e-16);
        const auto k = static_cast<double>(matched_[m]);
        const auto n = static_cast<double>(passes_[m]);
        ll += k * std::log(q) + (n - k) * std::log1p(-q);
      }
      log_post[g] = ll;
      best = std::max(best, ll);
    }
  }
  std::vector<double> weight(kGrid * kGrid);
  double total = 0.0, mean_h = 0.0, mean_m = 0.0;
  for (int a = 0; a < kGrid; ++a) {
    for (int b = 0; b < kGrid; ++b) {
      const int g = a * kGrid + b;
      weight[g] = std::exp(log_post[g] - best);
      total += weight[g];
      mean_h += weight[g] * HazardAt(a);
      mean_m += weight[g] * Midpoint(b);
    }
  }
  mean_hazard_ = mean_h / total;
  mean_miss_ = mean_m / total;
  // The kQuantile upper quantile of P(exists | m) under the grid posterior.
  std::vector<std::pair<double, double>> values(kGrid * kGrid);
  upper_[0] = 1.0;
  for (int m = 1; m < kRunBins; ++m) {
    for (int g = 0; g < kGrid * kGrid; ++g) values[g] = {existence[g][m], weight[g] / total};
    std::sort(values.begin(), values.end());
    double cumulative = 0.0;
    double quantile = values.back().first;
    for (const auto& [value, w] : values) {
      cumulative += w;
      if (cumulative >= kQuantile) {
        quantile = value;
        break;
      }
    }
    upper_[m] = quantile;
  }
  passes_at_fit_ = passes();
}

double ViewPersistence::UpperExistence(int missed_passes) const {
  OMNICML_CHECK(missed_passes >= 0) << "ViewPersistence::UpperExistence: negative run";
  return upper_[std::min(missed_passes, kRunBins - 1)];
}

void ViewPersistence::Restore(const std::array<std::int64_t, kRunBins>& passes,
                              const std::array<std::int64_t, kRunBins>& matched,
                              std::int64_t passes_at_fit, const std::array<double, kRunBins>& upper,
                              double hazard, double miss, const char* source) {
  std::int64_t n = 0;
  for (int m = 0; m < kRunBins; ++m) {
    if (passes[m] < 0 || matched[m] < 0 || matched[m] > passes[m]) {
      throw Error(StrCat(source, ": view persistence counts of run ", m, " are inconsistent (",
                         matched[m], " matched of ", passes[m], " passes)"));
    }
    if (!(upper[m] >= 0.0 && upper[m] <= 1.0)) {
      throw Error(StrCat(source, ": view persistence belief of run ", m, " is ", upper[m],
                         ", not in [0, 1]"));
    }
    n += passes[m];
  }
  if (passes_at_fit < 0 || passes_at_fit > n || !(hazard >= 0.0 && hazard <= 1.0) ||
      !(miss >= 0.0 && miss <= 1.0)) {
    throw Error(StrCat(source, ": view persistence fit state is inconsistent"));
  }
  passes_ = passes;
  matched_ = matched;
  passes_at_fit_ = passes_at_fit;
  upper_ = upper;
  mean_hazard_ = hazard;
  mean_miss_ = miss;
}

}  // namespace omnicml
