#include "omnicml/mapping/spatial_index.h"

#include <algorithm>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

std::vector<SpatialEntry> BruteForce(const std::vector<SpatialEntry>& all, double x, double y,
                                     double r) {
  std::vector<SpatialEntry> out;
  for (const SpatialEntry& e : all) {
    const double dx = e.x_m - x, dy = e.y_m - y;
    if (dx * dx + dy * dy < r * r) out.push_back(e);
  }
  std::sort(out.begin(), out.end(), [](const SpatialEntry& a, const SpatialEntry& b) {
    return a.view_id != b.view_id ? a.view_id < b.view_id : a.component_id < b.component_id;
  });
  return out;
}

// Radius queries return exactly the brute-force neighbour set, sorted, through inserts,
// removals and moves, for small and large radii and negative coordinates.
TEST(SpatialIndex, MatchesBruteForceOnRandomData) {
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> pos(-30.0, 30.0);
  std::uniform_real_distribution<double> radius(0.0, 8.0);
  for (const double cell : {0.37, 1.0, 5.0}) {
    SpatialIndex index(cell);
    std::vector<SpatialEntry> all;
    std::uint64_t next = 1;
    for (int step = 0; step < 3000; ++step) {
      const int op = static_cast<int>(rng() % 10);
      if (op < 5 || all.empty()) {
        SpatialEntry e{rng() % 50 + 1, next++, pos(rng), pos(rng)};
        index.Insert(e);
        all.push_back(e);
      } else if (op < 7) {
        const std::size_t k = rng() % all.size();
        EXPECT_TRUE(index.Remove(all[k].view_id, all[k].component_id, all[k].x_m, all[k].y_m));
        all.erase(all.begin() + static_cast<std::ptrdiff_t>(k));
      } else {
        const std::size_t k = rng() % all.size();
        // Small moves (often the same cell) and large ones.
        const double nx = (op == 7) ? all[k].x_m + 0.01 : pos(rng);
        const double ny = (op == 7) ? all[k].y_m - 0.01 : pos(rng);
        index.Move(all[k].view_id, all[k].component_id, all[k].x_m, all[k].y_m, nx, ny);
        all[k].x_m = nx;
        all[k].y_m = ny;
      }
      if (step % 7 == 0) {
        const double x = pos(rng), y = pos(rng);
        const double r = (step % 70 == 0) ? 200.0 : radius(rng);
        EXPECT_EQ(index.QueryRadius(x, y, r), BruteForce(all, x, y, r))
            << "cell " << cell << " step " << step;
      }
    }
    EXPECT_EQ(index.size(), all.size());
    EXPECT_EQ(index.All(), BruteForce(all, 0, 0, 1e9));
  }
}

// Removing an entry that is not there reports false and changes nothing; Move of a
// missing entry is an internal error.
TEST(SpatialIndex, MissingEntries) {
  SpatialIndex index(1.0);
  index.Insert({1, 2, 0.5, 0.5});
  EXPECT_FALSE(index.Remove(1, 3, 0.5, 0.5));
  EXPECT_FALSE(index.Remove(1, 2, 5.5, 0.5));
  EXPECT_EQ(index.size(), 1u);
  EXPECT_THROW(index.Move(9, 9, 0.5, 0.5, 1.0, 1.0), InternalError);
  EXPECT_TRUE(index.Remove(1, 2, 0.5, 0.5));
  EXPECT_TRUE(index.empty());
  EXPECT_EQ(index.NumCells(), 0u);
}

// Bad cell sizes and non-finite positions are rejected.
TEST(SpatialIndex, RejectsBadInput) {
  EXPECT_THROW(SpatialIndex(0.0), Error);
  EXPECT_THROW(SpatialIndex(-1.0), Error);
  SpatialIndex index(1.0);
  EXPECT_THROW(index.Insert({1, 1, std::numeric_limits<double>::quiet_NaN(), 0.0}), Error);
  EXPECT_TRUE(index.QueryRadius(0, 0, 0.0).empty());
}

}  // namespace
}  // namespace omnicml
