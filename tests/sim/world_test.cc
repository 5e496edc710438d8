// Tests of world descriptions: built-in worlds, YAML errors, event schedule, routes.
#include "omnicml/sim/world.h"

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {
namespace {

using ::testing::HasSubstr;

// A small valid world; tests splice errors into it.
std::string SmallWorld(const std::string& extra_shelf_key = "",
                       const std::string& extra_top_key = "") {
  return "name: small\n"
         "size_m: [10, 6]\n" +
         extra_top_key +
         "walls:\n"
         "  - {name: outer, polyline_m: [[0, 0], [10, 0], [10, 6], [0, 6], [0, 0]], height_m: 3}\n"
         "shelves:\n"
         "  - name: s1\n"
         "    rectangle_m: [4, 2.5, 6, 3.5]\n"
         "    height_m: 1.5\n" +
         extra_shelf_key +
         "route:\n"
         "  waypoints_m: [[1, 1], [9, 1], [9, 5], [1, 5]]\n";
}

std::string ErrorOf(const std::string& yaml, const std::string& source = "test.yaml") {
  try {
    ParseWorld(yaml, source);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// Every built-in world loads, and its size matches its description.
TEST(World, BuiltinWorldsLoad) {
  const auto names = BuiltinWorldNames();
  ASSERT_EQ(names.size(), 3u);
  for (const auto& name : names) {
    const World w = LoadBuiltinWorld(name);
    EXPECT_EQ(w.name, name);
    EXPECT_FALSE(w.obstacles.empty()) << name;
    EXPECT_FALSE(w.lights.empty()) << name;
  }
  const World home = LoadBuiltinWorld("home_store");
  EXPECT_DOUBLE_EQ(home.size_m.x(), 25.0);
  EXPECT_DOUBLE_EQ(home.size_m.y(), 10.0);
  const World inst = LoadBuiltinWorld("institute");
  EXPECT_DOUBLE_EQ(inst.size_m.x(), 10.0);
  EXPECT_DOUBLE_EQ(inst.size_m.y(), 15.0);
  const World large = LoadBuiltinWorld("store_large");
  EXPECT_DOUBLE_EQ(large.size_m.x(), 50.0);
  EXPECT_DOUBLE_EQ(large.size_m.y(), 80.0);
  EXPECT_DOUBLE_EQ(large.days_between_sessions, 28.0);
  const RoutePath route(large.route.waypoints_m, large.route.turn_radius_m);
  EXPECT_GT(route.length_m(), 270.0);
  EXPECT_LT(route.length_m(), 320.0);
  EXPECT_THROW(LoadBuiltinWorld("no_such_world"), Error);
}

// An unknown top-level key is an error naming the key, the file and the line.
TEST(World, UnknownTopLevelKeyNamesKeyFileAndLine) {
  const std::string msg = ErrorOf(SmallWorld("", "shelvs: []\n"), "worlds/bad.yaml");
  EXPECT_THAT(msg, HasSubstr("worlds/bad.yaml:3"));
  EXPECT_THAT(msg, HasSubstr("shelvs"));
  EXPECT_THAT(msg, HasSubstr("unknown key"));
}

// An unknown nested key names its full path.
TEST(World, UnknownNestedKeyNamesPath) {
  const std::string msg = ErrorOf(SmallWorld("    heigth_m: 2\n"));
  EXPECT_THAT(msg, HasSubstr("test.yaml:"));
  EXPECT_THAT(msg, HasSubstr("shelves[0].heigth_m"));
}

// Bad values, missing keys, unknown event targets and blocked routes are reported.
TEST(World, BadValuesAreReported) {
  std::string yaml = SmallWorld();
  const std::string neg = std::string(yaml).replace(yaml.find("height_m: 1.5"), 13, "height_m: -1");
  EXPECT_THAT(ErrorOf(neg), HasSubstr("shelves[0].height_m"));
  EXPECT_THAT(ErrorOf(SmallWorld("    texture: {kind: marble}\n")),
              HasSubstr("unknown texture kind 'marble'"));
  EXPECT_THAT(ErrorOf(SmallWorld("", "events:\n  - {type: lights_off, day: 2, target: nowhere}\n")),
              HasSubstr("unknown target 'nowhere'"));
  EXPECT_THAT(ErrorOf(SmallWorld("", "events:\n  - {type: lights_of, day: 2, target: x}\n")),
              HasSubstr("unknown event type 'lights_of'"));
  EXPECT_THAT(ErrorOf(SmallWorld("", "events:\n  - {type: shelf_cleared, target: s1}\n")),
              HasSubstr("exactly one timing key"));
  const std::string blocked =
      std::string(yaml).replace(yaml.find("[9, 5], [1, 5]"), 14, "[9, 5], [5, 3]");
  EXPECT_THAT(ErrorOf(blocked), HasSubstr("route.waypoints_m"));
  EXPECT_THAT(ErrorOf("name: x\nsize_m: [10, 6]\n"), HasSubstr("route: missing required key"));
  EXPECT_THAT(ErrorOf("name: [\n"), HasSubstr("YAML syntax error"));
  try {
    LoadWorldFile("/nonexistent/dir/w.yaml");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_THAT(std::string(e.what()), HasSubstr("/nonexistent/dir/w.yaml"));
  }
}

// Every number a world file sets is checked against its range when the file is loaded
// (not late in the renderer or the log writer): a one-line error naming the file and the
// field, for sizes beyond the limits (2^31 pixels, people, shelves) and places far off
// the floor (lights, windows, shelf moves).
TEST(World, EveryNumberIsCheckedWhenLoaded) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"lights:\n  - {name: l, polygon_m: [[0, 0], [1e300, 0], [0, 1]]}\n", "lights[0].polygon_m"},
      {"windows:\n  - {name: w, from_m: [0, 0], to_m: [1e300, 0]}\n", "windows[0].to_m"},
      {"events:\n  - {type: shelf_moved, day: 2, target: s1, dx_m: 1e300}\n", "events[0].dx_m"},
      {"events:\n  - {type: shelf_moved, day: 2, target: s1, dy_m: -7}\n", "events[0].dy_m"},
      {"camera: {panorama_width_px: 2147483648}\n", "camera.panorama_width_px"},
      {"camera: {panorama_width_px: 16385}\n", "camera.panorama_width_px"},
      {"camera: {ring_width_px: -2147483649}\n", "camera.ring_width_px"},
      {"people: {count: 2147483648}\n", "people.count"},
      {"days_between_sessions: 1e300\n", "days_between_sessions"},
      {"shelf_blocks:\n  - {name: b, origin_m: [1, 1], size_m: [1, 1], pitch_m: [0, 0], count: "
       "2147483648, height_m: 1}\n",
       "shelf_blocks[0].count"},
      {"shelf_blocks:\n  - {name: b, origin_m: [1, 1], size_m: [1, 1], pitch_m: [1e305, 0], "
       "count: 3, height_m: 1}\n",
       "b_2"},
  };
  for (const auto& [extra, field] : cases) {
    const std::string msg = ErrorOf(SmallWorld("", extra), "worlds/big.yaml");
    EXPECT_THAT(msg, HasSubstr("worlds/big.yaml")) << extra;
    EXPECT_THAT(msg, HasSubstr(field)) << extra;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
  // The same kinds of values inside the limits load.
  EXPECT_EQ(ErrorOf(SmallWorld("",
                               "lights:\n  - {name: l, polygon_m: [[0, 0], [10, 0], [0, 6]]}\n"
                               "events:\n  - {type: shelf_moved, day: 2, target: s1, dx_m: "
                               "-3}\ncamera: {panorama_width_px: 16384}\n")),
            "");
}

// A simulation's start sigmas become the logs' start covariance: a value whose square
// leaves the logs' variance limits (2^31 m), zero or not a number is refused when the
// options are loaded, naming the file and the field.
TEST(World, SimulationStartSigmasAreCheckedWhenLoaded) {
  for (const std::string& yaml :
       {std::string("start_sigma_xy_m: 2147483648\n"), std::string("start_sigma_xy_m: 0\n"),
        std::string("start_sigma_xy_m: 1e-200\n"), std::string("start_sigma_phi_rad: 11\n"),
        std::string("start_sigma_phi_rad: .nan\n")}) {
    try {
      ParseSimulatorOptionsYaml(yaml, "sims/start.yaml");
      ADD_FAILURE() << "accepted " << yaml;
    } catch (const Error& e) {
      const std::string msg = e.what();
      EXPECT_THAT(msg, HasSubstr("sims/start.yaml"));
      EXPECT_THAT(msg, HasSubstr(yaml.substr(0, yaml.find(':'))));
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
    }
  }
  const SimulatorOptions o =
      ParseSimulatorOptionsYaml("start_sigma_xy_m: 1e6\nstart_sigma_phi_rad: 10\n", "ok.yaml");
  EXPECT_DOUBLE_EQ(o.start_sigma_xy_m, 1e6);
}

// Day events are applied on their day, and the state at a day's start depends only on
// the seed and the day.
TEST(World, DayEventsApplyOnTheirDay) {
  const World w = LoadBuiltinWorld("store_large");
  const int s = w.FindObstacle("S1a_2");
  ASSERT_GE(s, 0);
  const WorldState day1 = StateAtDayStart(w, 1, 5);
  const WorldState day2 = StateAtDayStart(w, 2, 5);
  const WorldState day4 = StateAtDayStart(w, 4, 5);
  EXPECT_EQ(day1, InitialWorldState(w));
  EXPECT_DOUBLE_EQ(day2.obstacle_offset_m[s].x(), 0.6);
  EXPECT_DOUBLE_EQ(day4.obstacle_offset_m[s].x(), 0.0);  // moved back on day 4
  const int ne = w.FindLight("north_east");
  EXPECT_TRUE(StateAtDayStart(w, 2, 5).light_on[ne]);
  EXPECT_FALSE(StateAtDayStart(w, 3, 5).light_on[ne]);
  EXPECT_TRUE(StateAtDayStart(w, 4, 5).light_on[ne]);
  EXPECT_EQ(StateAtDayStart(w, 3, 5), StateAtDayStart(w, 3, 5));
  // About a third of the shelves are restocked per day (probability 0.35 over 60).
  int restocked = 0;
  for (std::size_t i = 0; i < w.obstacles.size(); ++i)
    restocked += day2.texture_seed[i] != day1.texture_seed[i];
  EXPECT_GT(restocked, 8);
  EXPECT_LT(restocked, 35);
  EXPECT_NE(StateAtDayStart(w, 2, 5).texture_seed, StateAtDayStart(w, 2, 6).texture_seed);
}

// `base:` starts from another world and replaces its top-level keys.
TEST(World, BaseWorldKeysAreReplaced) {
  const World base = LoadBuiltinWorld("home_store");
  const World w = ParseWorld("base: home_store\nname: hs2\nambient_light: 0.5\n", "d.yaml");
  EXPECT_EQ(w.name, "hs2");
  EXPECT_DOUBLE_EQ(w.ambient_light, 0.5);
  EXPECT_EQ(w.obstacles.size(), base.obstacles.size());
  EXPECT_EQ(w.events.size(), base.events.size());
  EXPECT_THAT(ErrorOf("base: no_such_world\n"), HasSubstr("base"));
  EXPECT_THAT(ErrorOf("base: home_store\nchanges: {layout_intensity: 1.5}\n"),
              HasSubstr("changes.layout_intensity"));
  EXPECT_THAT(ErrorOf("base: home_store\nchanges: {intensity: 0.1}\n"),
              HasSubstr("changes.intensity: unknown key"));
}

// The home_store world with its own events dropped, at a layout intensity.
World LayoutOnly(double intensity) {
  World w = LoadBuiltinWorld("home_store");
  w.events.clear();
  return WithLayoutIntensity(w, intensity);
}

// Layout changes depend on the seed only, add display spots that start empty, and leave
// day 1 as parsed; intensity 0 changes nothing on any day.
TEST(LayoutChanges, DeterministicPerSeed) {
  const World today = LoadBuiltinWorld("home_store");
  const World zero = WithLayoutIntensity(today, 0.0);
  ASSERT_EQ(zero.obstacles.size(), today.obstacles.size());
  for (int d = 1; d <= 6; ++d)
    EXPECT_EQ(StateAtDayStart(zero, d, 3), StateAtDayStart(today, d, 3)) << d;

  const World w = WithLayoutIntensity(today, 0.3);
  ASSERT_GT(w.obstacles.size(), today.obstacles.size());  // display spots
  const WorldState initial = InitialWorldState(w);
  for (std::size_t i = today.obstacles.size(); i < w.obstacles.size(); ++i)
    EXPECT_FALSE(initial.present[i]) << w.obstacles[i].name;
  EXPECT_EQ(StateAtDayStart(w, 1, 3), StateAtDayStart(WithLayoutIntensity(today, 0.3), 1, 3));
  EXPECT_EQ(StateAtDayStart(w, 5, 3), StateAtDayStart(w, 5, 3));
  EXPECT_NE(StateAtDayStart(w, 5, 3), StateAtDayStart(w, 5, 4));
  // Day d's state is day d - 1's with that day's events and layout changes on top.
  WorldState s = StateAtDayStart(w, 3, 3);
  ApplyDayEvents(w, 4, 3, &s);
  ApplyLayoutChanges(w, 4, 3, &s);
  EXPECT_EQ(s, StateAtDayStart(w, 4, 3));
}

// Whatever moves or appears keeps route_clearance_m from the robot's path, so the
// simulated robot never drives through a display or a moved gondola.
TEST(LayoutChanges, ChangedOutlinesKeepClearOfTheRoute) {
  for (const char* name : {"home_store", "store_large"}) {
    World base = LoadBuiltinWorld(name);
    base.events.clear();
    const World w = WithLayoutIntensity(base, 1.0);
    const RoutePath route(w.route.waypoints_m, w.route.turn_radius_m);
    const std::vector<Eigen::Vector2d> path = route.Sample(0.1);
    const WorldState initial = InitialWorldState(w);
    int changed = 0;
    for (int d = 2; d <= 6; ++d) {
      const WorldState s = StateAtDayStart(w, d, 11);
      for (std::size_t i = 0; i < w.obstacles.size(); ++i) {
        if (!s.present[i] || (initial.present[i] && s.obstacle_offset_m[i].isZero())) continue;
        ++changed;
        World one = w;
        one.obstacles = {w.obstacles[i]};
        WorldState one_state = InitialWorldState(one);
        one_state.obstacle_offset_m[0] = s.obstacle_offset_m[i];
        one_state.present[0] = 1;
        for (const auto& p : path) {
          ASSERT_TRUE(IsFree(one, one_state, p, w.changes.route_clearance_m - 0.02))
              << name << " day " << d << " " << w.obstacles[i].name << " at (" << p.x() << ", "
              << p.y() << ")";
        }
      }
    }
    EXPECT_GT(changed, 10) << name;
  }
}

// The measured share of the panorama that differs from day 1 (ChangedPanoramaFraction)
// is 0 without changes and grows with the intensity and with the sessions.
TEST(LayoutChanges, ChangedFractionGrowsWithIntensityAndSessions) {
  const World probe = LoadBuiltinWorld("home_store");
  const std::vector<Pose2> poses = RoutePoses(probe, 4.0);
  ASSERT_GE(poses.size(), 10u);
  const double threshold = 3.0 * std::sqrt(2.0) * probe.camera.noise_sigma_gray;
  auto fraction = [&](double intensity, int day) {
    double sum = 0;
    for (std::uint64_t seed : {1u, 2u}) {
      const World w = LayoutOnly(intensity);
      sum += ChangedPanoramaFraction(w, StateAtDayStart(w, 1, seed), StateAtDayStart(w, day, seed),
                                     poses, threshold);
    }
    return sum / 2;
  };
  EXPECT_EQ(fraction(0.0, 6), 0.0);
  const double low2 = fraction(0.05, 2), low6 = fraction(0.05, 6);
  const double mid2 = fraction(0.3, 2), mid6 = fraction(0.3, 6);
  const double high6 = fraction(0.8, 6);
  EXPECT_LT(low2, low6);
  EXPECT_LT(mid2, mid6);
  EXPECT_LT(low6, mid6);
  EXPECT_LT(mid6, high6);
  EXPECT_GT(high6, 0.3);
}

// Step events make the institute change continuously within a day.
TEST(World, StepEventsChangeInstituteContinuously) {
  const World w = LoadBuiltinWorld("institute");
  WorldState state = StateAtDayStart(w, 1, 3);
  int changes = 0;
  for (int step = 1; step <= 600; ++step)
    changes += ApplyStepEvents(w, 1, step, 3, &state).any() ? 1 : 0;
  EXPECT_GT(changes, 5);
  WorldState again = StateAtDayStart(w, 1, 3);
  for (int step = 1; step <= 600; ++step) ApplyStepEvents(w, 1, step, 3, &again);
  EXPECT_EQ(state, again);
}

// The route runs at constant speed with a continuous heading.
TEST(RoutePath, ConstantSpeedAndSmoothHeading) {
  for (const auto& name : BuiltinWorldNames()) {
    const World w = LoadBuiltinWorld(name);
    const RoutePath route(w.route.waypoints_m, w.route.turn_radius_m);
    const double ds = 0.05;
    Pose2 prev = route.PoseAt(0);
    for (double s = ds; s <= route.length_m() + 1e-9; s += ds) {
      const Pose2 p = route.PoseAt(s);
      const double step = (p.head<2>() - prev.head<2>()).norm();
      EXPECT_NEAR(step, ds, 1e-3 * ds + 1e-9) << name << " s=" << s;
      // Heading changes at most by ds / r_min (r_min >= 0.3 m in the built-in worlds).
      EXPECT_LE(std::abs(WrapAngle(p.z() - prev.z())), ds / 0.3 + 1e-9) << name << " s=" << s;
      // The position moves along the heading.
      const Eigen::Vector2d d = (p.head<2>() - prev.head<2>()) / step;
      const double mid = prev.z() + 0.5 * WrapAngle(p.z() - prev.z());
      EXPECT_GT(d.dot(Eigen::Vector2d(std::cos(mid), std::sin(mid))), 0.999) << name << " s=" << s;
      prev = p;
    }
    // The loop closes.
    EXPECT_LT(PoseDifference(route.PoseAt(route.length_m()), route.PoseAt(0)).norm(), 1e-9);
  }
}

}  // namespace
}  // namespace omnicml
