#include "omnicml/mapping/view_persistence.h"

#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// (P1) against the hidden states enumerated one by one: the place changes for good after
// j survived intervals (prior (1 - h)^j h; misses while it exists, P_M each; a changed
// place is always missed) or survives all m (prior (1 - h)^m, likelihood P_M^m).
double EnumeratedExistence(int m, double h, double p_miss) {
  double survive = std::pow(1.0 - h, m) * std::pow(p_miss, m);
  double changed = 0.0;
  for (int j = 0; j < m; ++j) changed += std::pow(1.0 - h, j) * h * std::pow(p_miss, j);
  return survive / (survive + changed);
}

TEST(ViewPersistence, ExistenceEqualsTheEnumeratedPosterior) {
  for (const double h : {0.01, 0.1, 0.3, 0.7}) {
    for (const double p_miss : {0.05, 0.3, 0.6, 0.95}) {
      for (int m = 0; m <= 12; ++m) {
        EXPECT_NEAR(PersistenceProbability(m, h, p_miss), EnumeratedExistence(m, h, p_miss), 1e-12)
            << "h " << h << " P_M " << p_miss << " m " << m;
      }
    }
  }
  EXPECT_EQ(PersistenceProbability(0, 0.5, 0.5), 1.0);
  EXPECT_EQ(PersistenceProbability(3, 0.0, 0.5), 1.0) << "no hazard: a miss is only a miss";
  EXPECT_EQ(PersistenceProbability(1, 0.2, 0.0), 0.0) << "no misses: a miss proves a change";
}

// Views simulated as the model says (geometric lifetimes, misses while they exist): the
// pass outcomes recorded as the engine records them.
ViewPersistence SimulatedHistory(double h, double p_miss, int views, int passes, std::uint32_t seed,
                                 double* returned_after_one = nullptr) {
  std::mt19937_64 rng(seed);
  std::bernoulli_distribution dies(h), missed(p_miss);
  ViewPersistence p;
  std::int64_t after_one = 0, returned = 0;
  for (int v = 0; v < views; ++v) {
    bool exists = true;
    int run = 0;  // missed passes since the last match (the creation pass matched)
    for (int k = 0; k < passes; ++k) {
      if (exists && dies(rng)) exists = false;
      const bool matched = exists && !missed(rng);
      p.Record(run, matched);
      if (run == 1) {
        ++after_one;
        returned += matched;
      }
      run = matched ? 0 : run + 1;
    }
  }
  if (returned_after_one != nullptr) *returned_after_one = double(returned) / double(after_one);
  return p;
}

// (P2) is what the simulated views do: the share of views that match again after one
// missed pass is P(exists | 1) (1 - h) (1 - P_M).
TEST(ViewPersistence, NextPassMatchesAsThePosteriorSays) {
  const double h = 0.2, p_miss = 0.3;
  double share = 0.0;
  SimulatedHistory(h, p_miss, 20000, 6, 5, &share);
  const double expected = PersistenceProbability(1, h, p_miss) * (1 - h) * (1 - p_miss);
  // Tens of thousands of outcomes: the binomial standard error is below 0.005.
  EXPECT_NEAR(share, expected, 0.015);
}

// The fit recovers the hazard and the miss probability from the pass outcomes alone, and
// its upper bound lies above the true belief and close to it.
TEST(ViewPersistence, FitRecoversHazardAndMissProbability) {
  for (const auto& [h, p_miss] : {std::pair{0.2, 0.3}, std::pair{0.05, 0.5}}) {
    ViewPersistence p = SimulatedHistory(h, p_miss, 3000, 6, 11);
    p.Refit();
    EXPECT_NEAR(p.hazard(), h, 0.03) << "h " << h << " P_M " << p_miss;
    EXPECT_NEAR(p.miss_probability(), p_miss, 0.04) << "h " << h << " P_M " << p_miss;
    for (int m = 1; m <= 4; ++m) {
      const double truth = PersistenceProbability(m, h, p_miss);
      EXPECT_GE(p.UpperExistence(m), truth - 0.03) << "m " << m;
      EXPECT_LE(p.UpperExistence(m), truth + 0.12) << "m " << m;
    }
    EXPECT_EQ(p.UpperExistence(0), 1.0);
  }
}

// A map that has not yet seen what follows a miss removes nothing after a few misses:
// before the first fit the belief is 1, and passes after matches only leave it above one
// half for runs of up to four missed passes.
TEST(ViewPersistence, LittleHistoryKeepsEveryView) {
  ViewPersistence p;
  for (int m = 0; m < 20; ++m) EXPECT_EQ(p.UpperExistence(m), 1.0);
  for (int k = 0; k < 12; ++k) p.Record(0, true);
  for (int k = 0; k < 4; ++k) p.Record(0, false);
  EXPECT_TRUE(p.MaybeRefit());
  for (int m = 1; m <= 4; ++m) EXPECT_GT(p.UpperExistence(m), 0.5) << "m " << m;
}

// Places whose misses come back (a light that toggles) keep a high belief after several
// misses; places that change for good lose it after two.
TEST(ViewPersistence, ReturningChangesAreNotForgotten) {
  ViewPersistence toggling = SimulatedHistory(0.01, 0.6, 2000, 8, 3);
  ViewPersistence changing = SimulatedHistory(0.35, 0.15, 2000, 8, 3);
  toggling.Refit();
  changing.Refit();
  EXPECT_GT(toggling.UpperExistence(3), 0.7);
  EXPECT_LT(changing.UpperExistence(2), 0.2);
}

// The refit schedule depends on the counts only: max(16, 2 %) new passes.
TEST(ViewPersistence, RefitsOnAScheduleOfTheCounts) {
  ViewPersistence p;
  for (int k = 0; k < 15; ++k) p.Record(0, true);
  EXPECT_FALSE(p.MaybeRefit());
  p.Record(1, false);
  EXPECT_TRUE(p.MaybeRefit());
  EXPECT_EQ(p.passes_at_fit(), 16);
  for (int k = 0; k < 15; ++k) p.Record(0, true);
  EXPECT_FALSE(p.MaybeRefit());
  p.Record(0, true);
  EXPECT_TRUE(p.MaybeRefit());
}

TEST(ViewPersistence, RestoreRejectsInconsistentState) {
  const ViewPersistence fitted = [] {
    ViewPersistence p = SimulatedHistory(0.2, 0.3, 100, 4, 1);
    p.Refit();
    return p;
  }();
  ViewPersistence copy;
  copy.Restore(fitted.passes_by_run(), fitted.matched_by_run(), fitted.passes_at_fit(),
               fitted.upper_existence(), fitted.hazard(), fitted.miss_probability(), "map.bin");
  EXPECT_EQ(copy, fitted);
  auto matched = fitted.matched_by_run();
  matched[0] = fitted.passes_by_run()[0] + 1;
  try {
    copy.Restore(fitted.passes_by_run(), matched, 0, fitted.upper_existence(), 0.1, 0.1, "map.bin");
    FAIL() << "more matched than passes accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("map.bin"), std::string::npos) << e.what();
  }
  auto upper = fitted.upper_existence();
  upper[2] = 1.5;
  EXPECT_THROW(
      copy.Restore(fitted.passes_by_run(), fitted.matched_by_run(), 0, upper, 0.1, 0.1, "map.bin"),
      Error);
}

}  // namespace
}  // namespace omnicml
