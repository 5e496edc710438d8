// 2.5-D simulated worlds (docs/design.md "Simulator"): the static description read from YAML
// (walls, shelves, boxes, windows, light zones, people, robot route, camera, odometry
// noise, schedule of appearance events) and the mutable appearance state that the
// schedule changes from day to day and from step to step.
//
// World files (datasets/worlds/*.yaml, documented in datasets/worlds/README.md) use the
// member names below as keys; every quantity carries its unit in the key name. An
// unknown key, a missing required key or a bad value is an omnicml::Error naming the file,
// the line and the key. The built-in worlds are compiled into the library, so they load
// from any working directory.
//
// Coordinates: the map frame, x to the right and y up on the floor plan, metres; the
// floor is z = 0. Everything here is a plain value type: thread-compatible.
#ifndef OMNICML_SIM_WORLD_H_
#define OMNICML_SIM_WORLD_H_

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/motion_model.h"
#include "omnicml/geometry/pose.h"

namespace omnicml {

// Procedural, seeded surface textures. All are functions of the position on the surface
// (u = metres along the surface outline, z = metres above the floor), so a world point
// looks the same from every pose.
enum class TextureKind {
  kPlain,   // base colour only
  kGoods,   // shelf boards every shelf_spacing_m, goods of random widths and colours
  kLabels,  // base colour with coloured rectangles (posters, signs, labels) on a grid
  kNoise,   // base colour modulated by blocky value noise of cell size cell_m
  kTiles,   // floor tiles of size cell_m with grout lines and per-tile variation
};
std::string ToString(TextureKind kind);                   // plain|goods|labels|noise|tiles
TextureKind TextureKindFromString(const std::string& s);  // throws omnicml::Error

struct TextureSpec {
  TextureKind kind = TextureKind::kPlain;             // YAML `kind`
  std::uint64_t seed = 0;                             // picks colours, widths, rectangles
  std::array<double, 3> color_rgb = {170, 170, 170};  // base colour, 0..255 per channel
  double cell_m = 0.25;           // feature size (goods width scale, label/noise/tile cell)
  double shelf_spacing_m = 0.45;  // kGoods: vertical distance between shelf boards
  double contrast = 1.0;          // 0..1: strength of the pattern against the base colour
};

enum class ObstacleKind { kWall, kShelf, kBox };
std::string ToString(ObstacleKind kind);

// A vertical prism standing on the floor: a closed polygon (shelves, boxes, closed walls)
// or an open polyline (walls given by `polyline_m`). Textures run along the outline.
struct Obstacle {
  std::string name;  // unique among obstacles; events refer to it
  ObstacleKind kind = ObstacleKind::kBox;
  std::vector<Eigen::Vector2d> points_m;  // outline vertices, at least 2 (3 if closed)
  bool closed = true;                     // false: open polyline (a wall of zero thickness)
  double height_m = 1.0;                  // top above the floor
  TextureSpec texture;
  // False for the promotional-display spots the layout change model adds (LayoutChanges):
  // they stand on the floor only while the state says so. Not a YAML key.
  bool initially_present = true;
};

// A window in a wall: a vertical rectangle from `from_m` to `to_m` between bottom_m and
// top_m above the floor, drawn just in front of the wall on both sides. Open curtains
// show the bright outside, closed ones the curtain fabric.
struct WindowSpec {
  std::string name;
  Eigen::Vector2d from_m = Eigen::Vector2d::Zero();
  Eigen::Vector2d to_m = Eigen::Vector2d::Zero();
  double bottom_m = 0.9;
  double top_m = 2.1;
  bool curtains_closed = false;                         // YAML `curtains: open|closed`
  std::array<double, 3> outside_rgb = {235, 225, 200};  // daylight seen through the glass
  std::array<double, 3> curtain_rgb = {150, 60, 60};
};

// A region lit by ceiling lamps. The light at a point is ambient_light of the world plus
// the intensity of every switched-on zone that contains it; colours are multiplied by it.
struct LightZone {
  std::string name;
  std::vector<Eigen::Vector2d> polygon_m;  // YAML `rectangle_m: [x0, y0, x1, y1]` or `polygon_m`
  double intensity = 0.6;                  // added light, 1 = full brightness
  bool on = true;                          // initial state
  double lamp_spacing_m = 2.5;  // lamps drawn on the ceiling on this grid inside the zone
};

// People walking seeded random straight paths between free points (drawn as cylinders).
struct PeopleSpec {
  int count = 0;
  double speed_mps = 0.8;
  double radius_m = 0.25;
  double height_m = 1.75;
};

// The robot's route: a closed loop through the waypoints driven at constant speed with
// corners rounded by arcs of turn_radius_m (shortened where the legs are short).
struct RouteSpec {
  std::vector<Eigen::Vector2d> waypoints_m;  // at least 3, the loop closes itself
  double speed_mps = 0.5;
  double turn_radius_m = 0.6;
};

// The camera: a catadioptric sensor at height_m delivering a ring image of
// ring_width_px x ring_height_px whose panorama is panorama_width_px x panorama_height_px,
// rows spanning elevations elevation_max_deg (row 0) down to elevation_min_deg.
struct CameraSpec {
  double height_m = 1.2;
  int ring_width_px = 640;
  int ring_height_px = 480;
  double inner_radius_px = 40.0;
  double outer_radius_px = 220.0;
  double elevation_min_deg = -35.0;
  double elevation_max_deg = 25.0;
  double noise_sigma_gray = 2.0;  // std. dev. of additive sensor noise, grey levels
  int panorama_width_px = 720;
  int panorama_height_px = 120;
};

// Appearance events (docs/design.md "Simulator"). Timing, exactly one of:
//   day: k            once, at the start of day k (1-based)
//   every_days: n     at the start of days first_day, first_day + n, ... (first_day >= 2)
//   every_steps: n    within every day, before frames n, 2n, 3n, ...
// With `probability` p < 1 each target is affected independently with probability p,
// drawn from the simulation seed, the day, the step and the event's index (so the same
// seed gives the same world, and a continuously changing world like `institute` is a few
// lines). Types:
//   lights_off | lights_on | lights_toggle        targets: light zones
//   curtains_closed | curtains_open | curtains_toggle   targets: windows
//   shelf_moved (by dx_m, dy_m) | shelf_cleared | shelf_restocked (texture seed `seed`;
//   with a repeating timing the new seed is derived from `seed` and the day/step)
//                                                   targets: shelves or boxes
enum class EventType {
  kLightsOff,
  kLightsOn,
  kLightsToggle,
  kCurtainsClosed,
  kCurtainsOpen,
  kCurtainsToggle,
  kShelfMoved,
  kShelfCleared,
  kShelfRestocked,
};
std::string ToString(EventType type);
EventType EventTypeFromString(const std::string& s);  // throws omnicml::Error

struct WorldEvent {
  EventType type = EventType::kLightsOff;
  std::vector<std::string> targets;  // YAML `target`: a name or a list of names
  int day = 0;                       // > 0: once at the start of that day
  int every_days = 0;                // > 0: repeating over days, from first_day
  int first_day = 2;
  int every_steps = 0;  // > 0: repeating over the steps of every day
  double probability = 1.0;
  double dx_m = 0.0;  // kShelfMoved
  double dy_m = 0.0;
  std::uint64_t seed = 0;  // kShelfRestocked
};

// The layout change model (docs/design.md "Layout changes"): from session 2 on, between
// sessions, every layout element of the store changes independently with probability
// layout_intensity, cumulatively and on top of the `events`:
//   a gondola or box (shelves, boxes, shelf_blocks) is moved (a random shift, with new
//     goods) or taken away; one taken away comes back elsewhere, with new goods;
//   a promotional-display spot (one of `display_spots` free places next to the robot's
//     route, generated from `seed`) gets a display, or loses or swaps its display;
//   a light zone is re-lit to a new level (its intensity times U(0.4, 1.6)).
// Every shifted or placed outline keeps route_clearance_m from the robot's path (the route
// with its rounded corners) and 0.2 m from every other present outline; a draw that
// violates this is redrawn (at most 4 times, then the element stays).
// The expected fraction of layout elements that differ from session 1 after N sessions is
// 1 - (1 - layout_intensity)^(N - 1) (less the few that return to their first state); the
// fraction of the panorama that differs is measured (ChangedPanoramaFraction, `omnicml
// simulate --change-report`; docs/results.md "Layout changes").
// YAML: `changes: {layout_intensity: 0.1, seed: 0, display_spots: 0, route_clearance_m: 0.5}`.
struct LayoutChanges {
  double layout_intensity = 0.0;   // per-session change probability of each element, [0, 1]
  std::uint64_t seed = 0;          // places the display spots (a property of the store)
  int display_spots = 0;           // 0: one per 10 m of route; >= 0
  double route_clearance_m = 0.5;  // free distance kept between the robot's path and outlines
};

// The static description of a world.
struct World {
  std::string name;
  std::string description;
  std::string source;  // file path or "builtin:<name>" (for error messages)
  Eigen::Vector2d size_m = Eigen::Vector2d(10, 10);  // floor spans [0, size_m]
  double ceiling_height_m = 3.0;
  double ambient_light = 0.35;       // light everywhere, 1 = full brightness
  double days_between_sessions = 1;  // only for day labels and start times
  TextureSpec floor;
  TextureSpec ceiling;
  std::vector<Obstacle> obstacles;  // YAML lists `walls`, `shelves`, `boxes`, `shelf_blocks`
  std::vector<WindowSpec> windows;
  std::vector<LightZone> lights;
  PeopleSpec people;
  RouteSpec route;
  CameraSpec camera;
  MotionNoise odometry_noise;
  std::vector<WorldEvent> events;
  LayoutChanges changes;  // YAML `changes`

  // Index of the obstacle / light zone / window with this name, or -1.
  int FindObstacle(const std::string& name) const;
  int FindLight(const std::string& name) const;
  int FindWindow(const std::string& name) const;
};

// Parses a world from YAML text; `source` names it in error messages. Throws
// omnicml::Error "<source>:<line>: <key>: what" on any problem, including unknown keys,
// unknown event targets and a route that runs through an obstacle.
// A top-level key `base: NAME` (a built-in world, or a world file relative to the directory
// of `source`) starts from that world's YAML: every other top-level key of this text
// replaces the base's key of the same name (one level of base only), e.g.
//   base: store_large
//   changes: {layout_intensity: 0.2}
World ParseWorld(const std::string& yaml_text, const std::string& source);
// Reads a world file. Throws omnicml::Error naming the file.
World LoadWorldFile(const std::string& path);
// One of the worlds compiled into the library (BuiltinWorldNames()). Throws
// omnicml::Error listing the valid names when `name` is unknown.
World LoadBuiltinWorld(const std::string& name);
std::vector<std::string> BuiltinWorldNames();
// The YAML text of a built-in world (as compiled in). Throws like LoadBuiltinWorld.
std::string BuiltinWorldText(const std::string& name);
// A built-in name, or else a path to a world file.
World LoadWorld(const std::string& name_or_path);

// The part of a world that events change. Indices follow World::obstacles, lights and
// windows.
struct WorldState {
  std::vector<Eigen::Vector2d> obstacle_offset_m;  // displacement of each obstacle
  std::vector<std::uint64_t> texture_seed;         // current texture seed per obstacle
  std::vector<char> cleared;                       // shelf emptied (goods removed)
  std::vector<char> present;                       // obstacle on the floor (else taken away)
  std::vector<char> light_on;
  std::vector<double> light_scale;  // factor on each zone's intensity (re-lit zones), > 0
  std::vector<char> curtains_closed;

  bool operator==(const WorldState&) const = default;
};

// The state before any event.
WorldState InitialWorldState(const World& world);

// What applying events changed (so renderers rebuild only what is needed).
struct WorldChange {
  bool geometry = false;    // an obstacle moved
  bool appearance = false;  // textures, lights or curtains
  bool any() const { return geometry || appearance; }
};

// Applies every event scheduled at the start of `day` (1-based; day 1 has none unless an
// event names day 1). Random draws depend only on (seed, day, event index, target).
WorldChange ApplyDayEvents(const World& world, int day, std::uint64_t seed, WorldState* state);
// Applies every event scheduled before frame `step` (0-based within the day; step 0 has
// none). Random draws depend only on (seed, day, step, event index, target).
WorldChange ApplyStepEvents(const World& world, int day, std::int64_t step, std::uint64_t seed,
                            WorldState* state);

// Applies the layout change model (LayoutChanges) between day - 1 and `day` (nothing for
// day < 2 or layout_intensity 0). Random draws come from a stream of their own, a
// function of (seed, day, element) only, so the events, odometry, people and sensor noise
// draw the same numbers with and without it.
WorldChange ApplyLayoutChanges(const World& world, int day, std::uint64_t seed, WorldState* state);

// The state at the start of `day`: the initial state with, for each day 1..day in order,
// that day's events and then its layout changes applied (step events do not carry over
// from one day to the next).
WorldState StateAtDayStart(const World& world, int day, std::uint64_t seed);

// Fraction (0..1) of panorama pixels whose colour differs between states `a` and `b` of
// `world`, averaged over `poses`: a pixel differs when some channel differs by more than
// threshold_gray grey levels; panoramas rendered without people and sensor noise. The
// measure of layout_intensity's effect (LayoutChanges). Throws omnicml::Error on no poses.
double ChangedPanoramaFraction(const World& world, const WorldState& a, const WorldState& b,
                               const std::vector<Pose2>& poses, double threshold_gray);

// `world` with changes.layout_intensity set to `intensity` (in [0, 1]) and its display
// spots regenerated (none for 0), as if the world file said so. Throws omnicml::Error
// on an intensity outside [0, 1].
World WithLayoutIntensity(World world, double intensity);

// Poses every spacing_m along the world's route loop, heading along the route (> 0).
std::vector<Pose2> RoutePoses(const World& world, double spacing_m);

// The outline of obstacle `index` in `state` (moved by its offset; also for an obstacle
// that is not present).
std::vector<Eigen::Vector2d> ObstacleOutline(const World& world, const WorldState& state,
                                             int index);

// True when the disc of radius_m around p_m is inside the floor and touches no obstacle
// present in `state` (windows are part of their walls and ignored).
bool IsFree(const World& world, const WorldState& state, const Eigen::Vector2d& p_m,
            double radius_m);
// True when a disc of radius_m moved along the segment a_m -> b_m stays free.
bool IsPathFree(const World& world, const WorldState& state, const Eigen::Vector2d& a_m,
                const Eigen::Vector2d& b_m, double radius_m);

// Deterministic 64-bit mixing (splitmix64 finaliser) used to derive sub-seeds.
std::uint64_t MixSeed(std::uint64_t a, std::uint64_t b);

}  // namespace omnicml

#endif  // OMNICML_SIM_WORLD_H_
