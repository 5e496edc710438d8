// Change detection scored against the simulator's day events (change_detection.h).
#include "omnicml/experiments/change_detection.h"

#include <array>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/mapping/environment_model.h"
#include "omnicml/report/map_export.h"
#include "omnicml/sim/world.h"
#include "testing/fake_descriptor.h"

namespace omnicml {
namespace {

bool HasItem(const WorldDayChanges& c, const std::string& text) {
  for (const std::string& item : c.items) {
    if (item.find(text) != std::string::npos) return true;
  }
  return false;
}

int ObstacleIndex(const World& w, const std::string& name) {
  for (std::size_t i = 0; i < w.obstacles.size(); ++i) {
    if (w.obstacles[i].name == name) return static_cast<int>(i);
  }
  return -1;
}

Eigen::Vector2d Centroid(const std::vector<Eigen::Vector2d>& pts) {
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (const auto& p : pts) c += p;
  return c / static_cast<double>(pts.size());
}

// store_large's schedule (datasets/worlds/store_large.yaml): day 2 moves S1a_2 and S3b_7
// by 0.6 m and pallet_2 by 4 m; day 3 switches the north_east lights off and clears S1b_6.
TEST(ChangeDetection, ChangesOfDayFollowTheSchedule) {
  const World w = LoadBuiltinWorld("store_large");
  const WorldDayChanges day2 = ChangesOfDay(w, 2, 1);
  EXPECT_TRUE(HasItem(day2, "S1a_2 moved"));
  EXPECT_TRUE(HasItem(day2, "pallet_2 moved"));
  EXPECT_FALSE(HasItem(day2, "north_east"));
  const WorldDayChanges day3 = ChangesOfDay(w, 3, 1);
  EXPECT_TRUE(HasItem(day3, "light north_east off"));
  EXPECT_TRUE(HasItem(day3, "S1b_6 cleared"));
  EXPECT_FALSE(HasItem(day3, "S1a_2 moved"));
  const WorldDayChanges day4 = ChangesOfDay(w, 4, 1);
  EXPECT_TRUE(HasItem(day4, "light north_east on"));

  // pallet_2 moved 4 m: both its old and its new place are changed places.
  const int pallet = ObstacleIndex(w, "pallet_2");
  ASSERT_GE(pallet, 0);
  const Eigen::Vector2d old_centre = Centroid(ObstacleOutline(w, StateAtDayStart(w, 1, 1), pallet));
  const Eigen::Vector2d new_centre = Centroid(ObstacleOutline(w, StateAtDayStart(w, 2, 1), pallet));
  EXPECT_NEAR((new_centre - old_centre).norm(), 4.0, 1e-9);
  EXPECT_EQ(DistanceToChanges(day2, old_centre), 0.0);
  EXPECT_EQ(DistanceToChanges(day2, new_centre), 0.0);

  // Inside the switched light zone on day 3, and nowhere near a change far outside the store.
  const LightZone* ne = nullptr;
  for (const LightZone& z : w.lights) {
    if (z.name == "north_east") ne = &z;
  }
  ASSERT_NE(ne, nullptr);
  EXPECT_EQ(DistanceToChanges(day3, Centroid(ne->polygon_m)), 0.0);
  EXPECT_GT(DistanceToChanges(day2, Eigen::Vector2d(-500, -500)), 400.0);
  EXPECT_TRUE(std::isinf(DistanceToChanges(WorldDayChanges{}, Eigen::Vector2d(0, 0))));
  // The truth depends on the seed only through the random events, never on the day order.
  const WorldDayChanges again = ChangesOfDay(w, 2, 1);
  EXPECT_EQ(again.items, day2.items);
  EXPECT_THROW(ChangesOfDay(w, 0, 1), Error);
}

MapCell Cell(int ix, int iy, CellHealth health) {
  MapCell c;
  c.ix = ix;
  c.iy = iy;
  c.views = 1;
  c.health = health;
  return c;
}

// Counts by hand: a wall along y = 1 from x = 0 to x = 4 changed; 2-m cells, radius 1 m.
// Cells crossed: (0,0), (1,0), (2,0), (3,0) [centres (1,1), (3,1), (5,1), (7,1)];
// geometric truth: (0,0), (1,0) are within 1 m of the wall (distance 0), (2,0) is 1 m
// from its end (within), (3,0) 3 m (not). Visible truth from a stand-in for the renderer:
// half the panorama changed for x < 4 and just before x = 6 (only the last path point of
// cell (2,0) sees it), nothing elsewhere. (9,9) is not crossed and not scored.
TEST(ChangeDetection, ScoreCountsCellsCrossedByThePath) {
  WorldDayChanges changes;
  changes.day = 2;
  changes.items = {"wall w moved"};
  changes.outlines.push_back({{Eigen::Vector2d(0, 1), Eigen::Vector2d(4, 1)}, false});
  MapHealth health;
  health.latest_session = 1;
  health.first_session = 0;
  health.cells = {Cell(0, 0, CellHealth::kChanged), Cell(1, 0, CellHealth::kOk),
                  Cell(2, 0, CellHealth::kNew), Cell(3, 0, CellHealth::kChanged),
                  Cell(9, 9, CellHealth::kChanged)};
  std::vector<Eigen::Vector2d> path;
  for (int k = 0; k < 40; ++k) path.emplace_back(0.1 + 0.2 * k, 1.0);
  const ChangedSharesFn shares = [](const Eigen::Vector2d& p) {
    const bool seen = p.x() < 4.0 || (p.x() > 5.85 && p.x() < 6.0);
    return ChangedShares{seen ? 0.5 : 0.0, p.x() > 6.0 ? 0.9 : 0.0};
  };
  ChangeDetectionOptions o;
  o.cell_m = 2.0;
  o.radius_m = 1.0;
  const ChangeDetectionDay d = ScoreChangeDetection(health, changes, path, shares, o);
  EXPECT_EQ(d.day, 2);
  EXPECT_EQ(d.session, 1);
  EXPECT_EQ(d.changed_items, 1);
  EXPECT_EQ(d.cells_scored, 4);
  EXPECT_EQ(d.cells_detected, 3);            // (0,0) changed, (2,0) new, (3,0) changed
  EXPECT_EQ(d.geometric.truly_changed, 3);   // (0,0) (1,0) (2,0)
  EXPECT_EQ(d.geometric.true_positives, 2);  // (0,0) (2,0)
  EXPECT_DOUBLE_EQ(d.geometric.precision, 2.0 / 3.0);
  EXPECT_DOUBLE_EQ(d.geometric.recall, 2.0 / 3.0);
  EXPECT_EQ(d.visible.truly_changed, 3);   // (0,0) (1,0) (2,0), the last by its last point
  EXPECT_EQ(d.visible.true_positives, 2);  // (0,0) (2,0)
  ASSERT_EQ(d.cells.size(), 4u);
  EXPECT_DOUBLE_EQ(d.cells[3].lit_fraction, 0.9);
  EXPECT_FALSE(d.cells[3].visible_changed) << "switched lights alone are no change of the place";

  // One sample point per cell (the middle one) misses the glimpse at the end of (2,0).
  ChangeDetectionOptions one = o;
  one.points_per_cell = 1;
  const ChangeDetectionDay m = ScoreChangeDetection(health, changes, path, shares, one);
  EXPECT_EQ(m.visible.truly_changed, 2);
  EXPECT_EQ(m.visible.true_positives, 1);
  EXPECT_DOUBLE_EQ(m.visible.precision, 1.0 / 3.0);
  EXPECT_DOUBLE_EQ(m.visible.recall, 1.0 / 2.0);

  // Nothing changed: recall undefined (NaN), every detection is a false positive.
  const ChangeDetectionDay none = ScoreChangeDetection(health, WorldDayChanges{}, path, {}, o);
  EXPECT_EQ(none.geometric.truly_changed, 0);
  EXPECT_EQ(none.visible.truly_changed, 0);
  EXPECT_TRUE(std::isnan(none.visible.recall));
  EXPECT_TRUE(std::isnan(none.geometric.recall));
  EXPECT_DOUBLE_EQ(none.visible.precision, 0.0);

  // The CSV totals are the sums of the rows: 8 cells scored, 6 detected, 3 truly changed
  // under each truth, 2 true positives under each.
  std::ostringstream csv;
  WriteChangeDetectionCsv(csv, {d, none});
  const std::string text = csv.str();
  EXPECT_NE(text.find("\nall,,1,8,6,3,2,0.3333333333333333,0.6666666666666666,"
                      "3,2,0.3333333333333333,0.6666666666666666\n"),
            std::string::npos)
      << text;
  o.cell_m = 0;
  EXPECT_THROW(ScoreChangeDetection(health, changes, path, shares, o), Error);
  one.min_changed_fraction = 0;
  EXPECT_THROW(ScoreChangeDetection(health, changes, path, shares, one), Error);
}

// A 40 m x 6 m hall whose west end (x < 5) is a room behind a ceiling-high wall. Day 2
// moves a box in the hall 1.5 m from the observer; day 3 moves only the same box at the
// hall's far end; day 4 switches the west room's lights off.
World Hall() {
  const std::string yaml =
      "name: hall\nsize_m: [40, 6]\nceiling_height_m: 3\n"
      "walls:\n"
      "  - {name: outer, polyline_m: [[0, 0], [40, 0], [40, 6], [0, 6], [0, 0]], height_m: 3,\n"
      "     texture: {kind: labels, seed: 4}}\n"
      "  - {name: middle, polyline_m: [[5, 0], [5, 6]], height_m: 3, texture: {kind: noise, "
      "seed: 5}}\n"
      "boxes:\n"
      "  - {name: near, rectangle_m: [10.0, 2.5, 11.0, 3.5], height_m: 1.5,\n"
      "     texture: {kind: labels, seed: 6, color_rgb: [200, 60, 40]}}\n"
      "  - {name: far, rectangle_m: [37.0, 2.5, 38.0, 3.5], height_m: 1.5,\n"
      "     texture: {kind: labels, seed: 7, color_rgb: [40, 60, 200]}}\n"
      "lights:\n"
      "  - {name: west, rectangle_m: [0, 0, 5, 6], intensity: 0.7}\n"
      "  - {name: hall, rectangle_m: [5, 0, 40, 6], intensity: 0.7}\n"
      "events:\n"
      "  - {type: shelf_moved, day: 2, target: near, dy_m: 1.2}\n"
      "  - {type: shelf_moved, day: 3, target: far, dy_m: 1.2}\n"
      "  - {type: lights_off, day: 4, target: west}\n"
      "route:\n  waypoints_m: [[7, 0.8], [30, 0.8], [30, 5.4], [7, 5.4]]\n";
  return ParseWorld(yaml, "hall.yaml");
}

// The visible truth: a change behind a wall is not visible (not one pixel), one in open
// view 1.5 m away covers far more than min_changed_fraction of the panorama, the same
// change 28 m away is seen but too small to count, and 1.5 m away it counts; switched
// lights change no surface but are reported as the lit share.
TEST(ChangeDetection, VisibleTruthFollowsLineOfSightAndSize) {
  const World w = Hall();
  const ChangeDetectionOptions o;
  const Eigen::Vector2d behind_wall(2.5, 3.0), open_view(8.5, 3.0), near_far_box(35.5, 3.0);

  const VisibleChanges day2(w, 2, 1, o);
  EXPECT_EQ(day2.SurfaceFraction(behind_wall), 0.0);
  EXPECT_GT(day2.SurfaceFraction(open_view), 2 * o.min_changed_fraction);
  EXPECT_EQ(day2.LitFraction(open_view), 0.0);

  const VisibleChanges day3(w, 3, 1, o);
  const double far_seen = day3.SurfaceFraction(Eigen::Vector2d(9.0, 3.0));
  EXPECT_GT(far_seen, 0.0) << "in open view: some pixels change";
  EXPECT_LT(far_seen, o.min_changed_fraction) << "28 m away it is too small to count";
  EXPECT_GE(day3.SurfaceFraction(near_far_box), o.min_changed_fraction);
  EXPECT_EQ(day3.SurfaceFraction(behind_wall), 0.0);

  const VisibleChanges day4(w, 4, 1, o);
  EXPECT_EQ(day4.SurfaceFraction(behind_wall), 0.0);
  EXPECT_GT(day4.LitFraction(behind_wall), 0.5);
  EXPECT_EQ(day4.LitFraction(open_view), 0.0) << "the west room's lamps are behind the wall";
  EXPECT_THROW(VisibleChanges(w, 1, 1, o), Error);
}

// A confident estimate at (x, 0.5): 1 cm, 0.05 rad.
Gaussian At(double x) {
  Gaussian g;
  g.mean = MakePose(x, 0.5, 0.0);
  g.covariance = Eigen::Vector3d(0.01 * 0.01, 0.01 * 0.01, 0.05 * 0.05).asDiagonal();
  return g;
}

// The health rule (ComputeMapHealth): a place whose look changed for good is "changed"
// even when no view is inserted there (a view it expected stopped matching while another
// still matches), a place that looks as before is "ok", and the cell counts say why.
TEST(MapHealth, ChangedWhereExpectedViewsStopMatching) {
  auto fx = testing::MakeFakeExtractor(2);
  EnvironmentModelOptions o;
  o.retrieval.e_max = 1.0;
  o.retrieval.top_k = 0;
  o.forgetting.d_for_m = 1.0;
  o.forgetting.mode = ForgettingMode::kActive;
  // Forgetting slow enough that the lamp-on view is still in the map after its two
  // missed passes of session 1 (the health rule, not the forgetting speed, is tested).
  o.forgetting.beta_for = 0.5;
  o.forgetting.forget_unconfirmed_views = false;
  EnvironmentModel m(o, fx);
  std::int64_t frame = 0;
  // A pass: 3 Updates at place P (x = 1, cell (0,0) of 2 m) with look `p`, then 3 at
  // place Q (x = 9, cell (4,0)) with look 0.
  auto pass = [&](float p, int session) {
    for (int k = 0; k < 3; ++k) m.Update(fx->Make({p, 0.0f}), At(1.0), {frame++, session});
    frame += 50;
    for (int k = 0; k < 3; ++k) m.Update(fx->Make({0.0f, 20.0f}), At(9.0), {frame++, session});
    frame += 50;
  };
  // Session 0: P shows two looks on alternate passes (a lamp on and off), so P holds
  // two views; Q one.
  for (int l = 0; l < 4; ++l) pass(l % 2 == 0 ? 0.0f : 5.0f, 0);
  ASSERT_EQ(m.NumViews(), 3u);
  // Session 1: the lamp stays off for good; Q is as before.
  for (int l = 0; l < 2; ++l) pass(0.0f, 1);
  m.CheckInvariants();
  EXPECT_EQ(m.NumViews(), 3u) << "nothing is inserted: every frame matches a view";

  const MapHealth health = ComputeMapHealth(m, /*latest_session=*/1, MapHealthOptions{});
  const MapCell* p = nullptr;
  const MapCell* q = nullptr;
  for (const MapCell& c : health.cells) {
    if (c.ix == 0 && c.iy == 0) p = &c;
    if (c.ix == 4 && c.iy == 0) q = &c;
  }
  ASSERT_NE(p, nullptr);
  ASSERT_NE(q, nullptr);
  EXPECT_EQ(p->insertions_recent, 0);
  EXPECT_EQ(p->expected_recent, 2);
  EXPECT_EQ(p->missed_recent, 1) << "the lamp-on view was expected and never matched";
  EXPECT_EQ(p->health, CellHealth::kChanged);
  EXPECT_EQ(q->expected_recent, 1);
  EXPECT_EQ(q->missed_recent, 0);
  EXPECT_EQ(q->health, CellHealth::kOk);
  EXPECT_EQ(health.changed, 1);
  EXPECT_EQ(health.ok, 1);
}

// The neighbour rule (MapHealthOptions::min_changed_neighbours): three places in a row,
// cells (0,0), (1,0), (2,0); on the second session the outer two look different (new
// views inserted there) and the middle one looks as before. The middle cell has no
// evidence of its own; with two neighbours that have some it is changed under the
// default (2), ok with the rule off (0) or asking for 3.
TEST(MapHealth, NeighbourEvidenceMarksACellBetweenChangedOnes) {
  auto fx = testing::MakeFakeExtractor(2);
  EnvironmentModelOptions o;
  o.retrieval.e_max = 1.0;
  o.retrieval.top_k = 0;
  o.forgetting.mode = ForgettingMode::kPassive;
  EnvironmentModel m(o, fx);
  std::int64_t frame = 0;
  auto pass = [&](const std::array<std::array<float, 2>, 3>& looks, int session) {
    for (int place = 0; place < 3; ++place) {
      for (int k = 0; k < 3; ++k) {
        m.Update(fx->Make({looks[place][0], looks[place][1]}), At(1.0 + 2.0 * place),
                 {frame++, session});
      }
      frame += 50;
    }
  };
  pass({{{0.0f, 0.0f}, {0.0f, 20.0f}, {20.0f, 0.0f}}}, 0);
  pass({{{40.0f, 0.0f}, {0.0f, 20.0f}, {0.0f, 40.0f}}}, 1);
  m.CheckInvariants();
  auto middle = [&](int min_neighbours) {
    MapHealthOptions h;
    h.min_changed_neighbours = min_neighbours;
    for (const MapCell& c : ComputeMapHealth(m, 1, h).cells) {
      if (c.ix == 1 && c.iy == 0) return c;
    }
    ADD_FAILURE() << "no middle cell";
    return MapCell{};
  };
  const MapCell by_default = middle(MapHealthOptions{}.min_changed_neighbours);
  EXPECT_EQ(by_default.insertions_recent, 0);
  EXPECT_EQ(by_default.missed_recent, 0);
  EXPECT_EQ(by_default.changed_neighbours, 2);
  EXPECT_EQ(by_default.health, CellHealth::kChanged);
  EXPECT_EQ(middle(0).health, CellHealth::kOk);
  EXPECT_EQ(middle(3).health, CellHealth::kOk);
  MapHealthOptions bad;
  bad.min_changed_neighbours = 9;
  EXPECT_THROW(ComputeMapHealth(m, 1, bad), Error);
}

}  // namespace
}  // namespace omnicml
