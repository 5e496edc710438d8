#include "omnicml/baselines/mcl/occupancy_grid.h"

#include <filesystem>
#include <fstream>
#include <set>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

// A 40 x 30 room (0.1 m cells) walled all round, with a short free-standing wall segment
// (a pillar row) at x = 20, y = 10..14.
OccupancyGrid CraftedRoom() {
  OccupancyGrid g(40, 30, 0.1, Eigen::Vector2d(0, 0));
  for (int x = 0; x < 40; ++x) {
    g.Set({x, 0}, CellState::kOccupied);
    g.Set({x, 29}, CellState::kOccupied);
  }
  for (int y = 0; y < 30; ++y) {
    g.Set({0, y}, CellState::kOccupied);
    g.Set({39, y}, CellState::kOccupied);
  }
  for (int y = 10; y <= 14; ++y) g.Set({20, y}, CellState::kOccupied);
  return g;
}

fs::path TempDir(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("omnicml_ogrid_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// Ray casting stops at the first occupied cell on the axis.
TEST(OccupancyGrid, CastRayHitsFirstOccupiedCell) {
  const OccupancyGrid g = CraftedRoom();
  const auto hit = g.CastRay(g.CellCenter({5, 12}), 0.0, 10.0);
  ASSERT_TRUE(hit.has_value());
  EXPECT_EQ(*hit, (CellIndex{20, 12}));
  const auto wall = g.CastRay(g.CellCenter({5, 20}), 0.0, 10.0);
  ASSERT_TRUE(wall.has_value());
  EXPECT_EQ(*wall, (CellIndex{39, 20}));
  EXPECT_FALSE(g.CastRay(g.CellCenter({5, 20}), 0.0, 1.0).has_value());  // out of range
}

// The visibility area of a pose facing a wall is exactly the free region that sees the
// wall point (unconstrained angles and distances): compared with a brute-force scan.
TEST(OccupancyGrid, VisibilityAreaIsTheFreeRegionSeeingTheWallPoint) {
  const OccupancyGrid g = CraftedRoom();
  // Facing the right wall (+x) from (30, 12): lambda = (39, 12).
  VisibilityOptions opt{.max_ray_range_m = 10, .max_distance_m = 100, .max_view_angle_rad = kPi};
  CellIndex lambda;
  const std::vector<int> area = VisibilityArea(g, g.CellCenter({30, 12}), 0.0, opt, &lambda);
  EXPECT_EQ(lambda, (CellIndex{39, 12}));
  std::set<int> expected;
  for (int i = 0; i < static_cast<int>(g.cells().size()); ++i) {
    const CellIndex c = g.FromLinear(i);
    if (g.IsFree(c) && g.LineOfSight(c, lambda)) expected.insert(i);
  }
  EXPECT_EQ(std::set<int>(area.begin(), area.end()), expected);
  const std::set<int> got(area.begin(), area.end());
  EXPECT_TRUE(got.count(g.Linear({30, 12})));   // the pose itself sees it
  EXPECT_TRUE(got.count(g.Linear({25, 12})));   // in front of the pillar
  EXPECT_FALSE(got.count(g.Linear({10, 12})));  // in the pillar's shadow
  EXPECT_TRUE(got.count(g.Linear({10, 25})));   // past the pillar's end
  EXPECT_FALSE(got.count(g.Linear({20, 12})));  // the pillar itself (occupied)
}

// The angular and distance constraints of the region growing remove the cells they should.
TEST(OccupancyGrid, VisibilityAreaRespectsConstraints) {
  const OccupancyGrid g = CraftedRoom();
  VisibilityOptions opt{
      .max_ray_range_m = 10, .max_distance_m = 1.0, .max_view_angle_rad = kPi / 4};
  CellIndex lambda;
  const std::vector<int> area = VisibilityArea(g, g.CellCenter({30, 12}), 0.0, opt, &lambda);
  ASSERT_FALSE(area.empty());
  const Eigen::Vector2d lm = g.CellCenter(lambda);
  for (int i : area) {
    const Eigen::Vector2d d = lm - g.CellCenter(g.FromLinear(i));
    EXPECT_LE(d.norm(), 1.0 + 1e-9);
    EXPECT_GE(d.x() / d.norm(), std::cos(kPi / 4) - 1e-9);
  }
  opt.max_distance_from_reference_m = 0.35;
  const std::vector<int> near = VisibilityArea(g, g.CellCenter({36, 12}), 0.0, opt);
  ASSERT_FALSE(near.empty());
  for (int i : near) {
    EXPECT_LE((g.CellCenter(g.FromLinear(i)) - g.CellCenter({36, 12})).norm(), 0.35 + 1e-9);
  }
  // No wall within range: empty area.
  opt.max_ray_range_m = 0.2;
  EXPECT_TRUE(VisibilityArea(g, g.CellCenter({20, 20}), 0.0, opt).empty());
}

// Saving and loading in the map_server convention gives the same grid.
TEST(OccupancyGrid, PgmYamlRoundTrip) {
  OccupancyGrid g(13, 7, 0.05, Eigen::Vector2d(-1.25, 2.5));
  g.Set({0, 0}, CellState::kOccupied);
  g.Set({12, 6}, CellState::kOccupied);
  g.Set({3, 4}, CellState::kUnknown);
  const fs::path dir = TempDir("roundtrip");
  SaveOccupancyGrid(g, (dir / "map.yaml").string());
  EXPECT_TRUE(fs::exists(dir / "map.pgm"));
  const OccupancyGrid back = LoadOccupancyGrid((dir / "map.yaml").string());
  EXPECT_EQ(back, g);
  // Row 0 of the image is the top of the map: cell (12, 6) is the first row's last pixel.
  std::ifstream in(dir / "map.pgm", std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(static_cast<unsigned char>(all[all.size() - 13 * 7 + 12]), 0);
}

// map_server thresholds and negate are honoured on loading (ASCII P2 image).
TEST(OccupancyGrid, LoadsMapServerThresholdsAndNegate) {
  const fs::path dir = TempDir("thresholds");
  std::ofstream(dir / "m.pgm") << "P2\n# comment\n3 1\n255\n0 128 255\n";
  std::ofstream(dir / "a.yaml") << "image: m.pgm\nresolution: 0.5\norigin: [1.0, 2.0, 0.0]\n"
                                   "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n";
  const OccupancyGrid a = LoadOccupancyGrid((dir / "a.yaml").string());
  EXPECT_EQ(a.At({0, 0}), CellState::kOccupied);
  EXPECT_EQ(a.At({1, 0}), CellState::kUnknown);
  EXPECT_EQ(a.At({2, 0}), CellState::kFree);
  EXPECT_DOUBLE_EQ(a.origin_m().x(), 1.0);
  std::ofstream(dir / "b.yaml") << "image: m.pgm\nresolution: 0.5\norigin: [0, 0, 0]\n"
                                   "negate: 1\noccupied_thresh: 0.65\nfree_thresh: 0.196\n";
  const OccupancyGrid b = LoadOccupancyGrid((dir / "b.yaml").string());
  EXPECT_EQ(b.At({0, 0}), CellState::kFree);
  EXPECT_EQ(b.At({2, 0}), CellState::kOccupied);
}

// Bad files are reported with the file and the field.
TEST(OccupancyGrid, BadFilesNameFileAndField) {
  const fs::path dir = TempDir("bad");
  std::ofstream(dir / "m.pgm") << "P2\n2 1\n255\n0 255\n";
  auto expect_error = [&](const std::string& yaml, const std::string& needle) {
    const fs::path p = dir / "bad.yaml";
    std::ofstream(p) << yaml;
    try {
      LoadOccupancyGrid(p.string());
      ADD_FAILURE() << "no error for: " << yaml;
    } catch (const Error& e) {
      EXPECT_THAT(e.what(), HasSubstr(needle));
      EXPECT_THAT(e.what(), HasSubstr("bad.yaml"));
    }
  };
  const std::string ok_tail =
      "origin: [0, 0, 0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.2\n";
  expect_error("image: m.pgm\n" + ok_tail, "resolution");
  expect_error("image: m.pgm\nresolution: -1\n" + ok_tail, "resolution");
  expect_error("image: m.pgm\nresolution: abc\n" + ok_tail, "resolution");
  expect_error("resolution: 0.1\n" + ok_tail, "image");
  expect_error("image: m.pgm\nresolution: 0.1\nextra: 1\n" + ok_tail, "extra");
  expect_error(
      "image: m.pgm\nresolution: 0.1\norigin: [0, 0]\nnegate: 0\noccupied_thresh: 0.65\n"
      "free_thresh: 0.2\n",
      "origin");
  expect_error("image: m.pgm\nresolution: 0.1\nmode: scale\n" + ok_tail, "mode");
  // A missing image names the image file.
  std::ofstream(dir / "noimg.yaml") << "image: nothere.pgm\nresolution: 0.1\n" << ok_tail;
  try {
    LoadOccupancyGrid((dir / "noimg.yaml").string());
    ADD_FAILURE() << "no error for a missing image";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("nothere.pgm"));
  }
  EXPECT_THROW(LoadOccupancyGrid((dir / "absent.yaml").string()), Error);
}

// A world rasterises with its obstacles occupied, its aisles free and a closed border.
TEST(OccupancyGrid, FromBuiltinWorld) {
  const World w = LoadBuiltinWorld("home_store");
  const WorldState s = InitialWorldState(w);
  const OccupancyGrid g = MakeOccupancyGrid(w, s, {.resolution_m = 0.1});
  EXPECT_EQ(g.width(), static_cast<int>(std::ceil(w.size_m.x() / 0.1)) + 2);
  // Every border cell is occupied.
  for (int x = 0; x < g.width(); ++x) {
    EXPECT_EQ(g.At({x, 0}), CellState::kOccupied);
    EXPECT_EQ(g.At({x, g.height() - 1}), CellState::kOccupied);
  }
  // The route's waypoints are free, obstacle centroids occupied.
  for (const auto& p : w.route.waypoints_m) EXPECT_TRUE(g.IsFreePoint(p)) << p.transpose();
  int closed = 0;
  for (std::size_t i = 0; i < w.obstacles.size(); ++i) {
    if (!w.obstacles[i].closed) continue;
    Eigen::Vector2d c = Eigen::Vector2d::Zero();
    const auto pts = ObstacleOutline(w, s, static_cast<int>(i));
    for (const auto& p : pts) c += p;
    c /= static_cast<double>(pts.size());
    EXPECT_FALSE(g.IsFreePoint(c)) << w.obstacles[i].name;
    ++closed;
  }
  EXPECT_GT(closed, 0);
}

}  // namespace
}  // namespace omnicml
