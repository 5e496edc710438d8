#include "omnicml/sim/world.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include <yaml-cpp/yaml.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/limits.h"
#include "omnicml/common/yaml_io.h"
#include "omnicml/geometry/planar_geometry.h"
#include "sim/internal/layout_changes.h"
#include "sim/internal/sim_builtin_worlds.h"

namespace omnicml {
namespace {

using geometry::DistancePointSegment;
using geometry::PointInPolygon;
using geometry::SegmentsIntersect;

// Reads one YAML mapping, remembering which keys were used so that unknown keys are
// reported (STYLE.md: an unknown key is an error, not a silent default).
class MapReader {
 public:
  MapReader(const YAML::Node& node, std::string source, std::string path)
      : node_(node), source_(std::move(source)), path_(std::move(path)) {
    if (!node_.IsMap()) Fail(path_, "expected a mapping");
  }

  [[noreturn]] void Fail(const std::string& key, const std::string& what) const {
    throw Error(StrCat(source_, ":", node_.Mark().line + 1, ": ", key, ": ", what));
  }
  [[noreturn]] void FailAt(const YAML::Node& n, const std::string& key,
                           const std::string& what) const {
    throw Error(StrCat(source_, ":", n.Mark().line + 1, ": ", key, ": ", what));
  }

  std::string Path(const std::string& key) const { return path_.empty() ? key : path_ + "." + key; }
  const std::string& source() const { return source_; }

  bool Has(const std::string& key) {
    used_.insert(key);
    return static_cast<bool>(node_[key]);
  }
  YAML::Node Get(const std::string& key) {
    used_.insert(key);
    return node_[key];
  }

  template <typename T>
  T Scalar(const YAML::Node& n, const std::string& key) const {
    if (!n.IsScalar()) FailAt(n, Path(key), "expected a scalar");
    try {
      return n.as<T>();
    } catch (const YAML::Exception&) {
      FailAt(n, Path(key), StrCat("cannot read '", n.Scalar(), "' as a value of this key"));
    }
  }

  double Double(const std::string& key, double fallback, double min_value = -1e300,
                double max_value = 1e300) {
    const YAML::Node n = Get(key);
    if (!n) return fallback;
    const double v = Scalar<double>(n, key);
    if (!std::isfinite(v) || v < min_value || v > max_value) {
      FailAt(n, Path(key), StrCat("value ", v, " outside [", min_value, ", ", max_value, "]"));
    }
    return v;
  }
  double RequiredDouble(const std::string& key, double min_value = -1e300,
                        double max_value = 1e300) {
    if (!Has(key)) Fail(Path(key), "missing required key");
    return Double(key, 0.0, min_value, max_value);
  }
  int Int(const std::string& key, int fallback, int min_value = -2147483647,
          int max_value = 2147483647) {
    const YAML::Node n = Get(key);
    if (!n) return fallback;
    const long long v = Scalar<long long>(n, key);
    if (v < min_value || v > max_value) {
      FailAt(n, Path(key), StrCat("value ", v, " outside [", min_value, ", ", max_value, "]"));
    }
    return static_cast<int>(v);
  }
  std::uint64_t Uint64(const std::string& key, std::uint64_t fallback) {
    const YAML::Node n = Get(key);
    if (!n) return fallback;
    return Scalar<std::uint64_t>(n, key);
  }
  bool Bool(const std::string& key, bool fallback) {
    const YAML::Node n = Get(key);
    if (!n) return fallback;
    return Scalar<bool>(n, key);
  }
  std::string String(const std::string& key, const std::string& fallback) {
    const YAML::Node n = Get(key);
    if (!n) return fallback;
    return Scalar<std::string>(n, key);
  }
  std::string RequiredString(const std::string& key) {
    if (!Has(key)) Fail(Path(key), "missing required key");
    return String(key, "");
  }

  std::vector<double> Numbers(const YAML::Node& n, const std::string& key,
                              std::size_t count) const {
    if (!n.IsSequence() || (count > 0 && n.size() != count)) {
      FailAt(n, Path(key), StrCat("expected a list of ", count, " numbers"));
    }
    std::vector<double> out;
    for (const auto& item : n) {
      const double v = Scalar<double>(item, key);
      if (!std::isfinite(v)) FailAt(item, Path(key), "non-finite number");
      out.push_back(v);
    }
    return out;
  }
  Eigen::Vector2d Point(const YAML::Node& n, const std::string& key) const {
    const auto v = Numbers(n, key, 2);
    return Eigen::Vector2d(v[0], v[1]);
  }
  std::vector<Eigen::Vector2d> Points(const YAML::Node& n, const std::string& key) const {
    if (!n.IsSequence()) FailAt(n, Path(key), "expected a list of [x, y] points");
    std::vector<Eigen::Vector2d> out;
    for (const auto& item : n) out.push_back(Point(item, key));
    return out;
  }
  std::array<double, 3> Color(const std::string& key, const std::array<double, 3>& fallback) {
    const YAML::Node n = Get(key);
    if (!n) return fallback;
    const auto v = Numbers(n, key, 3);
    for (double c : v) {
      if (c < 0 || c > 255) FailAt(n, Path(key), "colour components must lie in [0, 255]");
    }
    return {v[0], v[1], v[2]};
  }

  // Throws for the first key that was never asked for.
  void CheckNoUnknownKeys() const {
    for (const auto& kv : node_) {
      // A list or map as a key ("{kind: goods}:" in flow style) is no name.
      if (!kv.first.IsScalar()) FailAt(kv.first, Path("?"), "a key must be a name");
      const std::string key = kv.first.Scalar();
      if (!used_.count(key)) FailAt(kv.first, Path(key), "unknown key");
    }
  }

  const YAML::Node& node() const { return node_; }

 private:
  YAML::Node node_;
  std::string source_;
  std::string path_;
  std::set<std::string> used_;
};

std::string Indexed(const std::string& list, std::size_t i) { return StrCat(list, "[", i, "]"); }

TextureSpec ParseTexture(const YAML::Node& n, const std::string& source, const std::string& path,
                         const TextureSpec& fallback) {
  if (!n) return fallback;
  MapReader r(n, source, path);
  TextureSpec t = fallback;
  if (r.Has("kind")) {
    try {
      t.kind = TextureKindFromString(r.String("kind", ""));
    } catch (const Error& e) {
      r.FailAt(r.Get("kind"), r.Path("kind"), e.what());
    }
  }
  t.seed = r.Uint64("seed", t.seed);
  t.color_rgb = r.Color("color_rgb", t.color_rgb);
  t.cell_m = r.Double("cell_m", t.cell_m, 0.01, 100.0);
  t.shelf_spacing_m = r.Double("shelf_spacing_m", t.shelf_spacing_m, 0.1, 10.0);
  t.contrast = r.Double("contrast", t.contrast, 0.0, 1.0);
  r.CheckNoUnknownKeys();
  return t;
}

// rectangle_m: [x0, y0, x1, y1] or polygon_m: [[x, y], ...]; returns the outline.
std::vector<Eigen::Vector2d> ParseArea(MapReader& r, bool allow_polyline, bool* closed) {
  int given = 0;
  std::vector<Eigen::Vector2d> pts;
  if (closed) *closed = true;
  if (r.Has("rectangle_m")) {
    ++given;
    const YAML::Node n = r.Get("rectangle_m");
    const auto v = r.Numbers(n, "rectangle_m", 4);
    const double x0 = std::min(v[0], v[2]), x1 = std::max(v[0], v[2]);
    const double y0 = std::min(v[1], v[3]), y1 = std::max(v[1], v[3]);
    if (x1 - x0 <= 0 || y1 - y0 <= 0) r.FailAt(n, r.Path("rectangle_m"), "empty rectangle");
    pts = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
  }
  if (r.Has("polygon_m")) {
    ++given;
    const YAML::Node n = r.Get("polygon_m");
    pts = r.Points(n, "polygon_m");
    if (pts.size() < 3) r.FailAt(n, r.Path("polygon_m"), "a polygon needs at least 3 points");
  }
  if (allow_polyline && r.Has("polyline_m")) {
    ++given;
    const YAML::Node n = r.Get("polyline_m");
    pts = r.Points(n, "polyline_m");
    if (pts.size() < 2) r.FailAt(n, r.Path("polyline_m"), "a polyline needs at least 2 points");
    if (closed) *closed = false;
  }
  if (given != 1) {
    r.Fail(r.Path(allow_polyline ? "rectangle_m|polygon_m|polyline_m" : "rectangle_m|polygon_m"),
           "exactly one outline key is required");
  }
  return pts;
}

Obstacle ParseObstacle(const YAML::Node& n, const std::string& source, const std::string& path,
                       ObstacleKind kind, const TextureSpec& default_texture) {
  MapReader r(n, source, path);
  Obstacle o;
  o.kind = kind;
  o.name = r.RequiredString("name");
  o.points_m = ParseArea(r, kind == ObstacleKind::kWall, &o.closed);
  o.height_m = r.RequiredDouble("height_m", 0.01, 100.0);
  o.texture = ParseTexture(r.Get("texture"), source, r.Path("texture"), default_texture);
  r.CheckNoUnknownKeys();
  return o;
}

// shelf_blocks: `count` shelves of size_m at origin_m + i * pitch_m, named <name>_<i>
// (1-based), texture seeds texture.seed + i.
std::vector<Obstacle> ParseShelfBlock(const YAML::Node& n, const std::string& source,
                                      const std::string& path) {
  MapReader r(n, source, path);
  const std::string name = r.RequiredString("name");
  if (!r.Has("origin_m")) r.Fail(r.Path("origin_m"), "missing required key");
  if (!r.Has("size_m")) r.Fail(r.Path("size_m"), "missing required key");
  if (!r.Has("pitch_m")) r.Fail(r.Path("pitch_m"), "missing required key");
  const Eigen::Vector2d origin = r.Point(r.Get("origin_m"), "origin_m");
  const Eigen::Vector2d size = r.Point(r.Get("size_m"), "size_m");
  const Eigen::Vector2d pitch = r.Point(r.Get("pitch_m"), "pitch_m");
  if (size.x() <= 0 || size.y() <= 0)
    r.FailAt(r.Get("size_m"), r.Path("size_m"), "sizes must be positive");
  const int count = r.Int("count", 1, 1, 10000);
  const double height = r.RequiredDouble("height_m", 0.01, 100.0);
  TextureSpec tex;
  tex.kind = TextureKind::kGoods;
  tex = ParseTexture(r.Get("texture"), source, r.Path("texture"), tex);
  const std::string kind_name = r.String("kind", "shelf");
  ObstacleKind kind = ObstacleKind::kShelf;
  if (kind_name == "box") {
    kind = ObstacleKind::kBox;
  } else if (kind_name != "shelf") {
    r.FailAt(r.Get("kind"), r.Path("kind"), "expected shelf or box");
  }
  r.CheckNoUnknownKeys();
  std::vector<Obstacle> out;
  for (int i = 0; i < count; ++i) {
    Obstacle o;
    o.kind = kind;
    o.name = StrCat(name, "_", i + 1);
    const Eigen::Vector2d p0 = origin + static_cast<double>(i) * pitch;
    o.points_m = {p0, p0 + Eigen::Vector2d(size.x(), 0), p0 + size,
                  p0 + Eigen::Vector2d(0, size.y())};
    o.closed = true;
    o.height_m = height;
    o.texture = tex;
    o.texture.seed = tex.seed + static_cast<std::uint64_t>(i);
    out.push_back(std::move(o));
  }
  return out;
}

template <typename Fn>
void ForEachItem(MapReader& r, const std::string& key, Fn fn) {
  const YAML::Node list = r.Get(key);
  if (!list) return;
  if (!list.IsSequence()) r.FailAt(list, key, "expected a list");
  for (std::size_t i = 0; i < list.size(); ++i) fn(list[i], Indexed(key, i));
}

void CheckWorld(const World& w) {
  const auto fail = [&](const std::string& key, const std::string& what) {
    throw Error(StrCat(w.source, ": ", key, ": ", what));
  };
  std::set<std::string> names;
  for (const auto& o : w.obstacles) {
    if (!names.insert(o.name).second)
      fail("obstacles", StrCat("duplicate obstacle name '", o.name, "'"));
    for (const auto& p : o.points_m) {
      if (p.x() < -1e-9 || p.y() < -1e-9 || p.x() > w.size_m.x() + 1e-9 ||
          p.y() > w.size_m.y() + 1e-9) {
        fail(o.name, StrCat("point (", p.x(), ", ", p.y(), ") outside the floor [0, size_m]"));
      }
    }
  }
  // Every point a world places lies on its floor: an outline far outside it (1e300) would
  // make the renderer place lamps or draw windows without end.
  const auto check_on_floor = [&](const std::string& key, const Eigen::Vector2d& p) {
    if (p.x() < -1e-9 || p.y() < -1e-9 || p.x() > w.size_m.x() + 1e-9 ||
        p.y() > w.size_m.y() + 1e-9) {
      fail(key, StrCat("point (", p.x(), ", ", p.y(), ") outside the floor [0, size_m]"));
    }
  };
  names.clear();
  for (std::size_t i = 0; i < w.lights.size(); ++i) {
    const LightZone& l = w.lights[i];
    if (!names.insert(l.name).second)
      fail("lights", StrCat("duplicate light zone name '", l.name, "'"));
    for (const auto& p : l.polygon_m) check_on_floor(StrCat(Indexed("lights", i), ".polygon_m"), p);
  }
  names.clear();
  for (std::size_t i = 0; i < w.windows.size(); ++i) {
    const WindowSpec& win = w.windows[i];
    if (!names.insert(win.name).second)
      fail("windows", StrCat("duplicate window name '", win.name, "'"));
    check_on_floor(StrCat(Indexed("windows", i), ".from_m"), win.from_m);
    check_on_floor(StrCat(Indexed("windows", i), ".to_m"), win.to_m);
  }
  for (std::size_t i = 0; i < w.events.size(); ++i) {
    const WorldEvent& e = w.events[i];
    for (const auto& t : e.targets) {
      int found = -1;
      switch (e.type) {
        case EventType::kLightsOff:
        case EventType::kLightsOn:
        case EventType::kLightsToggle:
          found = w.FindLight(t);
          break;
        case EventType::kCurtainsClosed:
        case EventType::kCurtainsOpen:
        case EventType::kCurtainsToggle:
          found = w.FindWindow(t);
          break;
        default:
          found = w.FindObstacle(t);
          if (found >= 0 && w.obstacles[found].kind == ObstacleKind::kWall) {
            fail(Indexed("events", i),
                 StrCat("target '", t, "' is a wall; only shelves and boxes change"));
          }
          break;
      }
      if (found < 0)
        fail(Indexed("events", i), StrCat("unknown target '", t, "' for ", ToString(e.type)));
    }
  }
  // The route must keep clear of obstacles (a world file error, caught early).
  const auto& wp = w.route.waypoints_m;
  const WorldState state = InitialWorldState(w);
  for (std::size_t i = 0; i < wp.size(); ++i) {
    const Eigen::Vector2d& a = wp[i];
    const Eigen::Vector2d& b = wp[(i + 1) % wp.size()];
    if (!IsPathFree(w, state, a, b, 0.2)) {
      fail(StrCat("route.waypoints_m[", i, "]"),
           StrCat("the leg (", a.x(), ", ", a.y(), ") -> (", b.x(), ", ", b.y(),
                  ") passes within 0.2 m of an obstacle or leaves the floor"));
    }
  }
}

// The text of a base world: a built-in name, else a file relative to the directory of
// `source` (when that is a file path).
std::string BaseWorldText(const std::string& name, const std::string& source) {
  for (const auto& w : internal::BuiltinWorldTexts()) {
    if (w.name == name) return w.text;
  }
  std::filesystem::path path(name);
  if (path.is_relative() && source.rfind("builtin:", 0) != 0)
    path = std::filesystem::path(source).parent_path() / path;
  return ReadTextFile(path.string(), kMaxTextFileBytes, "base world file");
}

// A mapping with `base: NAME` becomes the base world's mapping with every other key of
// `root` replacing the base's key of that name.
YAML::Node ResolveBase(const YAML::Node& root, const std::string& source) {
  const YAML::Node base_key = root["base"];
  if (!base_key) return root;
  if (!base_key.IsScalar())
    throw Error(StrCat(source, ":", base_key.Mark().line + 1, ": base: expected a world name"));
  const std::string name = base_key.Scalar();
  YAML::Node base;
  try {
    base = LoadYaml(BaseWorldText(name, source), name);
  } catch (const YAML::ParserException& e) {
    throw Error(
        StrCat(source, ": base '", name, "':", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  } catch (const Error& e) {
    throw Error(StrCat(source, ":", base_key.Mark().line + 1, ": base: ", e.what()));
  }
  if (!base || !base.IsMap())
    throw Error(StrCat(source, ": base '", name, "' is not a YAML mapping"));
  if (base["base"])
    throw Error(StrCat(source, ": base '", name, "' has a base of its own (one level only)"));
  YAML::Node merged(YAML::NodeType::Map);
  for (const auto& kv : base) {
    const std::string key = kv.first.Scalar();
    if (!root[key]) merged[kv.first] = kv.second;
  }
  for (const auto& kv : root) {
    if (kv.first.IsScalar() && kv.first.Scalar() == "base") continue;
    merged[kv.first] = kv.second;
  }
  return merged;
}

}  // namespace

std::string ToString(TextureKind kind) {
  switch (kind) {
    case TextureKind::kPlain:
      return "plain";
    case TextureKind::kGoods:
      return "goods";
    case TextureKind::kLabels:
      return "labels";
    case TextureKind::kNoise:
      return "noise";
    case TextureKind::kTiles:
      return "tiles";
  }
  return "unknown";
}

TextureKind TextureKindFromString(const std::string& s) {
  for (TextureKind k : {TextureKind::kPlain, TextureKind::kGoods, TextureKind::kLabels,
                        TextureKind::kNoise, TextureKind::kTiles}) {
    if (ToString(k) == s) return k;
  }
  throw Error(
      StrCat("unknown texture kind '", s, "' (expected plain, goods, labels, noise or tiles)"));
}

std::string ToString(ObstacleKind kind) {
  switch (kind) {
    case ObstacleKind::kWall:
      return "wall";
    case ObstacleKind::kShelf:
      return "shelf";
    case ObstacleKind::kBox:
      return "box";
  }
  return "unknown";
}

std::string ToString(EventType type) {
  switch (type) {
    case EventType::kLightsOff:
      return "lights_off";
    case EventType::kLightsOn:
      return "lights_on";
    case EventType::kLightsToggle:
      return "lights_toggle";
    case EventType::kCurtainsClosed:
      return "curtains_closed";
    case EventType::kCurtainsOpen:
      return "curtains_open";
    case EventType::kCurtainsToggle:
      return "curtains_toggle";
    case EventType::kShelfMoved:
      return "shelf_moved";
    case EventType::kShelfCleared:
      return "shelf_cleared";
    case EventType::kShelfRestocked:
      return "shelf_restocked";
  }
  return "unknown";
}

EventType EventTypeFromString(const std::string& s) {
  for (int i = 0; i <= static_cast<int>(EventType::kShelfRestocked); ++i) {
    if (ToString(static_cast<EventType>(i)) == s) return static_cast<EventType>(i);
  }
  throw Error(
      StrCat("unknown event type '", s,
             "' (expected lights_off, lights_on, lights_toggle, curtains_closed, curtains_open, "
             "curtains_toggle, shelf_moved, shelf_cleared or shelf_restocked)"));
}

int World::FindObstacle(const std::string& n) const {
  for (std::size_t i = 0; i < obstacles.size(); ++i) {
    if (obstacles[i].name == n) return static_cast<int>(i);
  }
  return -1;
}
int World::FindLight(const std::string& n) const {
  for (std::size_t i = 0; i < lights.size(); ++i) {
    if (lights[i].name == n) return static_cast<int>(i);
  }
  return -1;
}
int World::FindWindow(const std::string& n) const {
  for (std::size_t i = 0; i < windows.size(); ++i) {
    if (windows[i].name == n) return static_cast<int>(i);
  }
  return -1;
}

World ParseWorld(const std::string& yaml_text, const std::string& source) {
  YAML::Node root;
  try {
    root = LoadYaml(yaml_text, source);
  } catch (const YAML::ParserException& e) {
    throw Error(StrCat(source, ":", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  }
  if (!root || !root.IsMap())
    throw Error(StrCat(source, ":1: a world file must be a YAML mapping"));
  root = ResolveBase(root, source);
  MapReader r(root, source, "");
  World w;
  w.source = source;
  w.name = r.RequiredString("name");
  w.description = r.String("description", "");
  if (!r.Has("size_m")) r.Fail("size_m", "missing required key");
  w.size_m = r.Point(r.Get("size_m"), "size_m");
  if (w.size_m.x() <= 0 || w.size_m.y() <= 0 || w.size_m.x() > 10000 || w.size_m.y() > 10000) {
    r.FailAt(r.Get("size_m"), "size_m", "sizes must lie in (0, 10000]");
  }
  w.ceiling_height_m = r.Double("ceiling_height_m", w.ceiling_height_m, 0.5, 100.0);
  w.ambient_light = r.Double("ambient_light", w.ambient_light, 0.0, 4.0);
  w.days_between_sessions = r.Double("days_between_sessions", w.days_between_sessions, 0.0, 3650.0);
  TextureSpec floor_default;
  floor_default.kind = TextureKind::kTiles;
  floor_default.cell_m = 0.5;
  floor_default.color_rgb = {150, 145, 135};
  w.floor = ParseTexture(r.Get("floor"), source, "floor", floor_default);
  TextureSpec ceiling_default;
  ceiling_default.color_rgb = {200, 200, 195};
  w.ceiling = ParseTexture(r.Get("ceiling"), source, "ceiling", ceiling_default);

  TextureSpec wall_tex;
  wall_tex.color_rgb = {190, 185, 170};
  TextureSpec shelf_tex;
  shelf_tex.kind = TextureKind::kGoods;
  TextureSpec box_tex;
  box_tex.kind = TextureKind::kLabels;
  box_tex.color_rgb = {160, 120, 80};
  ForEachItem(r, "walls", [&](const YAML::Node& n, const std::string& path) {
    w.obstacles.push_back(ParseObstacle(n, source, path, ObstacleKind::kWall, wall_tex));
  });
  ForEachItem(r, "shelves", [&](const YAML::Node& n, const std::string& path) {
    w.obstacles.push_back(ParseObstacle(n, source, path, ObstacleKind::kShelf, shelf_tex));
  });
  ForEachItem(r, "shelf_blocks", [&](const YAML::Node& n, const std::string& path) {
    for (auto& o : ParseShelfBlock(n, source, path)) w.obstacles.push_back(std::move(o));
  });
  ForEachItem(r, "boxes", [&](const YAML::Node& n, const std::string& path) {
    w.obstacles.push_back(ParseObstacle(n, source, path, ObstacleKind::kBox, box_tex));
  });
  ForEachItem(r, "windows", [&](const YAML::Node& n, const std::string& path) {
    MapReader wr(n, source, path);
    WindowSpec win;
    win.name = wr.RequiredString("name");
    if (!wr.Has("from_m")) wr.Fail(wr.Path("from_m"), "missing required key");
    if (!wr.Has("to_m")) wr.Fail(wr.Path("to_m"), "missing required key");
    win.from_m = wr.Point(wr.Get("from_m"), "from_m");
    win.to_m = wr.Point(wr.Get("to_m"), "to_m");
    win.bottom_m = wr.Double("bottom_m", win.bottom_m, 0.0, 100.0);
    win.top_m = wr.Double("top_m", win.top_m, 0.0, 100.0);
    if (win.top_m <= win.bottom_m) wr.Fail(wr.Path("top_m"), "must exceed bottom_m");
    const std::string curtains = wr.String("curtains", "open");
    if (curtains != "open" && curtains != "closed") {
      wr.FailAt(wr.Get("curtains"), wr.Path("curtains"), "expected open or closed");
    }
    win.curtains_closed = curtains == "closed";
    win.outside_rgb = wr.Color("outside_rgb", win.outside_rgb);
    win.curtain_rgb = wr.Color("curtain_rgb", win.curtain_rgb);
    wr.CheckNoUnknownKeys();
    w.windows.push_back(win);
  });
  ForEachItem(r, "lights", [&](const YAML::Node& n, const std::string& path) {
    MapReader lr(n, source, path);
    LightZone z;
    z.name = lr.RequiredString("name");
    z.polygon_m = ParseArea(lr, false, nullptr);
    z.intensity = lr.Double("intensity", z.intensity, 0.0, 4.0);
    z.on = lr.Bool("on", z.on);
    z.lamp_spacing_m = lr.Double("lamp_spacing_m", z.lamp_spacing_m, 0.5, 100.0);
    lr.CheckNoUnknownKeys();
    w.lights.push_back(z);
  });
  if (r.Has("people")) {
    MapReader pr(r.Get("people"), source, "people");
    w.people.count = pr.Int("count", w.people.count, 0, 1000);
    w.people.speed_mps = pr.Double("speed_mps", w.people.speed_mps, 0.0, 10.0);
    w.people.radius_m = pr.Double("radius_m", w.people.radius_m, 0.05, 2.0);
    w.people.height_m = pr.Double("height_m", w.people.height_m, 0.1, 5.0);
    pr.CheckNoUnknownKeys();
  }
  if (!r.Has("route")) r.Fail("route", "missing required key");
  {
    MapReader rr(r.Get("route"), source, "route");
    if (!rr.Has("waypoints_m")) rr.Fail("route.waypoints_m", "missing required key");
    w.route.waypoints_m = rr.Points(rr.Get("waypoints_m"), "waypoints_m");
    if (w.route.waypoints_m.size() < 3)
      rr.Fail("route.waypoints_m", "a loop needs at least 3 waypoints");
    w.route.speed_mps = rr.Double("speed_mps", w.route.speed_mps, 0.01, 20.0);
    w.route.turn_radius_m = rr.Double("turn_radius_m", w.route.turn_radius_m, 0.0, 100.0);
    rr.CheckNoUnknownKeys();
  }
  if (r.Has("camera")) {
    MapReader cr(r.Get("camera"), source, "camera");
    CameraSpec& c = w.camera;
    c.height_m = cr.Double("height_m", c.height_m, 0.05, 50.0);
    c.ring_width_px = cr.Int("ring_width_px", c.ring_width_px, 16, 8192);
    c.ring_height_px = cr.Int("ring_height_px", c.ring_height_px, 16, 8192);
    c.inner_radius_px = cr.Double("inner_radius_px", c.inner_radius_px, 0.0, 8192.0);
    c.outer_radius_px = cr.Double("outer_radius_px", c.outer_radius_px, 1.0, 8192.0);
    c.elevation_min_deg = cr.Double("elevation_min_deg", c.elevation_min_deg, -89.0, 89.0);
    c.elevation_max_deg = cr.Double("elevation_max_deg", c.elevation_max_deg, -89.0, 89.0);
    c.noise_sigma_gray = cr.Double("noise_sigma_gray", c.noise_sigma_gray, 0.0, 50.0);
    c.panorama_width_px = cr.Int("panorama_width_px", c.panorama_width_px, 8, kMaxPanoramaSidePx);
    c.panorama_height_px = cr.Int("panorama_height_px", c.panorama_height_px, 2, 4096);
    if (c.elevation_max_deg <= c.elevation_min_deg)
      cr.Fail("camera.elevation_max_deg", "must exceed elevation_min_deg");
    if (c.outer_radius_px <= c.inner_radius_px)
      cr.Fail("camera.outer_radius_px", "must exceed inner_radius_px");
    if (2 * c.outer_radius_px > std::min(c.ring_width_px, c.ring_height_px) - 1) {
      cr.Fail("camera.outer_radius_px", "the ring does not fit into the ring image");
    }
    if (c.height_m >= w.ceiling_height_m)
      cr.Fail("camera.height_m", "must be below ceiling_height_m");
    cr.CheckNoUnknownKeys();
  }
  if (r.Has("odometry_noise")) {
    MapReader nr(r.Get("odometry_noise"), source, "odometry_noise");
    w.odometry_noise.a1 = nr.Double("a1", w.odometry_noise.a1, 0.0, 100.0);
    w.odometry_noise.a2 = nr.Double("a2", w.odometry_noise.a2, 0.0, 100.0);
    w.odometry_noise.a3 = nr.Double("a3", w.odometry_noise.a3, 0.0, 100.0);
    w.odometry_noise.a4 = nr.Double("a4", w.odometry_noise.a4, 0.0, 100.0);
    nr.CheckNoUnknownKeys();
  }
  ForEachItem(r, "events", [&](const YAML::Node& n, const std::string& path) {
    MapReader er(n, source, path);
    WorldEvent e;
    const YAML::Node type = er.Get("type");
    if (!type) er.Fail(er.Path("type"), "missing required key");
    try {
      e.type = EventTypeFromString(er.Scalar<std::string>(type, "type"));
    } catch (const Error& ex) {
      er.FailAt(type, er.Path("type"), ex.what());
    }
    const YAML::Node target = er.Get("target");
    if (!target) er.Fail(er.Path("target"), "missing required key");
    if (target.IsSequence()) {
      for (const auto& t : target) e.targets.push_back(er.Scalar<std::string>(t, "target"));
    } else {
      e.targets.push_back(er.Scalar<std::string>(target, "target"));
    }
    if (e.targets.empty()) er.Fail(er.Path("target"), "no target");
    e.day = er.Int("day", 0, 0, 1000000);
    e.every_days = er.Int("every_days", 0, 0, 1000000);
    e.first_day = er.Int("first_day", 2, 1, 1000000);
    e.every_steps = er.Int("every_steps", 0, 0, 1000000000);
    if ((e.day > 0) + (e.every_days > 0) + (e.every_steps > 0) != 1) {
      er.Fail(er.Path("day|every_days|every_steps"),
              "exactly one timing key (positive) is required");
    }
    e.probability = er.Double("probability", 1.0, 0.0, 1.0);
    // A shelf moves at most across the floor.
    e.dx_m = er.Double("dx_m", 0.0, -w.size_m.x(), w.size_m.x());
    e.dy_m = er.Double("dy_m", 0.0, -w.size_m.y(), w.size_m.y());
    e.seed = er.Uint64("seed", 0);
    er.CheckNoUnknownKeys();
    w.events.push_back(e);
  });
  if (r.Has("changes")) {
    MapReader cr(r.Get("changes"), source, "changes");
    LayoutChanges& c = w.changes;
    c.layout_intensity = cr.Double("layout_intensity", c.layout_intensity, 0.0, 1.0);
    c.seed = cr.Uint64("seed", c.seed);
    c.display_spots = cr.Int("display_spots", c.display_spots, 0, 10000);
    c.route_clearance_m = cr.Double("route_clearance_m", c.route_clearance_m, 0.0, 10.0);
    cr.CheckNoUnknownKeys();
  }
  r.CheckNoUnknownKeys();
  if (w.route.waypoints_m.empty()) r.Fail("route", "missing");
  CheckWorld(w);
  internal::AddDisplaySpots(&w);
  return w;
}

World LoadWorldFile(const std::string& path) {
  // A regular file of at most kMaxTextFileBytes (no FIFO, device or directory).
  return ParseWorld(ReadTextFile(path, kMaxTextFileBytes, "world file"), path);
}

std::vector<std::string> BuiltinWorldNames() {
  std::vector<std::string> names;
  for (const auto& w : internal::BuiltinWorldTexts()) names.push_back(w.name);
  return names;
}

std::string BuiltinWorldText(const std::string& name) {
  for (const auto& w : internal::BuiltinWorldTexts()) {
    if (w.name == name) return w.text;
  }
  std::string list;
  for (const auto& n : BuiltinWorldNames()) list += (list.empty() ? "" : ", ") + n;
  throw Error(StrCat("unknown built-in world '", name, "' (built-in worlds: ", list, ")"));
}

World LoadBuiltinWorld(const std::string& name) {
  return ParseWorld(BuiltinWorldText(name), StrCat("builtin:", name, ".yaml"));
}

World LoadWorld(const std::string& name_or_path) {
  for (const auto& n : BuiltinWorldNames()) {
    if (n == name_or_path) return LoadBuiltinWorld(n);
  }
  // Not opened here: opening a FIFO would block. LoadWorldFile rejects what is there but
  // is not a regular file (directory, FIFO, device, symbolic-link loop).
  std::error_code ec;
  if (std::filesystem::symlink_status(name_or_path, ec).type() ==
      std::filesystem::file_type::not_found) {
    std::string list;
    for (const auto& n : BuiltinWorldNames()) list += (list.empty() ? "" : ", ") + n;
    throw Error(StrCat("world '", name_or_path, "' is neither a built-in world (", list,
                       ") nor a readable file"));
  }
  return LoadWorldFile(name_or_path);
}

// ---------------------------------------------------------------------------------------
// State and events.

std::uint64_t MixSeed(std::uint64_t a, std::uint64_t b) {
  std::uint64_t z = a + 0x9e3779b97f4a7c15ULL * (b + 1);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

WorldState InitialWorldState(const World& world) {
  WorldState s;
  s.obstacle_offset_m.assign(world.obstacles.size(), Eigen::Vector2d::Zero());
  s.cleared.assign(world.obstacles.size(), 0);
  for (const auto& o : world.obstacles) {
    s.texture_seed.push_back(o.texture.seed);
    s.present.push_back(o.initially_present ? 1 : 0);
  }
  for (const auto& l : world.lights) s.light_on.push_back(l.on ? 1 : 0);
  s.light_scale.assign(world.lights.size(), 1.0);
  for (const auto& w : world.windows) s.curtains_closed.push_back(w.curtains_closed ? 1 : 0);
  return s;
}

namespace {

// Uniform in [0, 1) from a hash.
double UnitFromHash(std::uint64_t h) { return static_cast<double>(h >> 11) * 0x1.0p-53; }

WorldChange ApplyEvent(const World& world, const WorldEvent& e, std::uint64_t draw_seed,
                       WorldState* s) {
  WorldChange change;
  for (std::size_t t = 0; t < e.targets.size(); ++t) {
    const std::uint64_t h = MixSeed(draw_seed, t);
    if (e.probability < 1.0 && UnitFromHash(h) >= e.probability) continue;
    const std::string& name = e.targets[t];
    switch (e.type) {
      case EventType::kLightsOff:
      case EventType::kLightsOn:
      case EventType::kLightsToggle: {
        const int i = world.FindLight(name);
        OMNICML_CHECK(i >= 0) << name;
        const char before = s->light_on[i];
        s->light_on[i] = e.type == EventType::kLightsOn    ? 1
                         : e.type == EventType::kLightsOff ? 0
                                                           : !before;
        change.appearance |= s->light_on[i] != before;
        break;
      }
      case EventType::kCurtainsClosed:
      case EventType::kCurtainsOpen:
      case EventType::kCurtainsToggle: {
        const int i = world.FindWindow(name);
        OMNICML_CHECK(i >= 0) << name;
        const char before = s->curtains_closed[i];
        s->curtains_closed[i] = e.type == EventType::kCurtainsClosed ? 1
                                : e.type == EventType::kCurtainsOpen ? 0
                                                                     : !before;
        change.appearance |= s->curtains_closed[i] != before;
        break;
      }
      case EventType::kShelfMoved: {
        const int i = world.FindObstacle(name);
        OMNICML_CHECK(i >= 0) << name;
        s->obstacle_offset_m[i] += Eigen::Vector2d(e.dx_m, e.dy_m);
        change.geometry = true;
        break;
      }
      case EventType::kShelfCleared: {
        const int i = world.FindObstacle(name);
        OMNICML_CHECK(i >= 0) << name;
        change.appearance |= !s->cleared[i];
        s->cleared[i] = 1;
        break;
      }
      case EventType::kShelfRestocked: {
        const int i = world.FindObstacle(name);
        OMNICML_CHECK(i >= 0) << name;
        // A one-off restock uses the given seed; a repeating one derives a new seed.
        const bool once = e.day > 0;
        s->texture_seed[i] = once ? e.seed : MixSeed(e.seed, h);
        s->cleared[i] = 0;
        change.appearance = true;
        break;
      }
    }
  }
  return change;
}

}  // namespace

WorldChange ApplyDayEvents(const World& world, int day, std::uint64_t seed, WorldState* state) {
  OMNICML_CHECK(state != nullptr);
  WorldChange change;
  for (std::size_t i = 0; i < world.events.size(); ++i) {
    const WorldEvent& e = world.events[i];
    bool due = false;
    if (e.day > 0) due = e.day == day;
    if (e.every_days > 0) due = day >= e.first_day && (day - e.first_day) % e.every_days == 0;
    if (!due) continue;
    const std::uint64_t draw =
        MixSeed(MixSeed(MixSeed(seed, 0xDA7ULL), static_cast<std::uint64_t>(day)), i);
    const WorldChange c = ApplyEvent(world, e, draw, state);
    change.geometry |= c.geometry;
    change.appearance |= c.appearance;
  }
  return change;
}

WorldChange ApplyStepEvents(const World& world, int day, std::int64_t step, std::uint64_t seed,
                            WorldState* state) {
  OMNICML_CHECK(state != nullptr);
  WorldChange change;
  if (step <= 0) return change;
  for (std::size_t i = 0; i < world.events.size(); ++i) {
    const WorldEvent& e = world.events[i];
    if (e.every_steps <= 0 || step % e.every_steps != 0) continue;
    const std::uint64_t draw =
        MixSeed(MixSeed(MixSeed(MixSeed(seed, 0x57E9ULL), static_cast<std::uint64_t>(day)),
                        static_cast<std::uint64_t>(step)),
                i);
    const WorldChange c = ApplyEvent(world, e, draw, state);
    change.geometry |= c.geometry;
    change.appearance |= c.appearance;
  }
  return change;
}

WorldState StateAtDayStart(const World& world, int day, std::uint64_t seed) {
  WorldState s = InitialWorldState(world);
  for (int d = 1; d <= day; ++d) {
    ApplyDayEvents(world, d, seed, &s);
    ApplyLayoutChanges(world, d, seed, &s);
  }
  return s;
}

std::vector<Eigen::Vector2d> ObstacleOutline(const World& world, const WorldState& state,
                                             int index) {
  std::vector<Eigen::Vector2d> pts = world.obstacles[index].points_m;
  for (auto& p : pts) p += state.obstacle_offset_m[index];
  return pts;
}

bool IsFree(const World& world, const WorldState& state, const Eigen::Vector2d& p,
            double radius_m) {
  if (p.x() < radius_m || p.y() < radius_m || p.x() > world.size_m.x() - radius_m ||
      p.y() > world.size_m.y() - radius_m) {
    return false;
  }
  for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
    if (!state.present[i]) continue;
    const auto pts = ObstacleOutline(world, state, static_cast<int>(i));
    const bool closed = world.obstacles[i].closed;
    if (closed && PointInPolygon(pts, p)) return false;
    const std::size_t n = closed ? pts.size() : pts.size() - 1;
    for (std::size_t k = 0; k < n; ++k) {
      if (DistancePointSegment(p, pts[k], pts[(k + 1) % pts.size()]) < radius_m) return false;
    }
  }
  return true;
}

bool IsPathFree(const World& world, const WorldState& state, const Eigen::Vector2d& a,
                const Eigen::Vector2d& b, double radius_m) {
  if (!IsFree(world, state, a, radius_m) || !IsFree(world, state, b, radius_m)) return false;
  for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
    if (!state.present[i]) continue;
    const auto pts = ObstacleOutline(world, state, static_cast<int>(i));
    const std::size_t n = world.obstacles[i].closed ? pts.size() : pts.size() - 1;
    for (std::size_t k = 0; k < n; ++k) {
      const Eigen::Vector2d& p = pts[k];
      const Eigen::Vector2d& q = pts[(k + 1) % pts.size()];
      if (SegmentsIntersect(a, b, p, q)) return false;
      if (DistancePointSegment(p, a, b) < radius_m || DistancePointSegment(q, a, b) < radius_m ||
          DistancePointSegment(a, p, q) < radius_m || DistancePointSegment(b, p, q) < radius_m) {
        return false;
      }
    }
  }
  return true;
}

}  // namespace omnicml
