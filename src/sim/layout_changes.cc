// The layout change model of world.h (LayoutChanges; docs/design.md "Layout changes"):
// display spots at parse time, the per-session changes, and the measure of their effect
// on the panorama.
#include "sim/internal/layout_changes.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <opencv2/core.hpp>

#include "omnicml/common/common.h"
#include "omnicml/geometry/planar_geometry.h"
#include "omnicml/sim/renderer.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"

namespace omnicml {
namespace {

using geometry::DistancePointSegment;
using geometry::PointInPolygon;
using geometry::SegmentsIntersect;

// Sub-seed domains (arbitrary distinct constants, distinct from the simulator's).
constexpr std::uint64_t kLayoutDomain = 0x1A70ULL;
constexpr std::uint64_t kSpotDomain = 0x5B07ULL;
constexpr std::uint64_t kLightKey = 1ULL << 40;  // element keys of light zones
// Gaps kept between a changed outline and every other outline (wall shelves stand 0.2 m
// off the wall, back-to-back gondolas 0.2 m apart), and around a new display spot.
constexpr double kMinGapM = 0.15;
constexpr double kSpotGapM = 0.3;
constexpr double kRouteSampleM = 0.25;  // spacing of the path samples of the clearance test
constexpr int kMaxRedraws = 4;
constexpr char kSpotPrefix[] = "changes_display_";

double Uniform(std::mt19937_64& rng) { return static_cast<double>(rng() >> 11) * 0x1.0p-53; }
double Uniform(std::mt19937_64& rng, double lo, double hi) { return lo + (hi - lo) * Uniform(rng); }
double Sign(std::mt19937_64& rng) { return (rng() & 1) ? 1.0 : -1.0; }

// Distance between two outlines (0 when they cross or one holds a vertex of the other).
double OutlineDistance(const std::vector<Eigen::Vector2d>& a, bool a_closed,
                       const std::vector<Eigen::Vector2d>& b, bool b_closed) {
  if (a_closed && a.size() >= 3 && PointInPolygon(a, b.front())) return 0.0;
  if (b_closed && b.size() >= 3 && PointInPolygon(b, a.front())) return 0.0;
  const std::size_t na = a_closed ? a.size() : a.size() - 1;
  const std::size_t nb = b_closed ? b.size() : b.size() - 1;
  double d = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i < na; ++i) {
    const Eigen::Vector2d& p = a[i];
    const Eigen::Vector2d& q = a[(i + 1) % a.size()];
    for (std::size_t k = 0; k < nb; ++k) {
      const Eigen::Vector2d& r = b[k];
      const Eigen::Vector2d& s = b[(k + 1) % b.size()];
      if (SegmentsIntersect(p, q, r, s)) return 0.0;
      d = std::min({d, DistancePointSegment(p, r, s), DistancePointSegment(q, r, s),
                    DistancePointSegment(r, p, q), DistancePointSegment(s, p, q)});
    }
  }
  return d;
}

// Whether a closed outline keeps `clearance_m` from every path sample.
bool ClearOfPath(const std::vector<Eigen::Vector2d>& outline,
                 const std::vector<Eigen::Vector2d>& path, double clearance_m) {
  for (const Eigen::Vector2d& p : path) {
    if (PointInPolygon(outline, p)) return false;
    for (std::size_t k = 0; k < outline.size(); ++k) {
      if (DistancePointSegment(p, outline[k], outline[(k + 1) % outline.size()]) < clearance_m)
        return false;
    }
  }
  return true;
}

bool InsideFloor(const World& world, const std::vector<Eigen::Vector2d>& outline, double margin) {
  for (const auto& p : outline) {
    if (p.x() < margin || p.y() < margin || p.x() > world.size_m.x() - margin ||
        p.y() > world.size_m.y() - margin)
      return false;
  }
  return true;
}

std::vector<Eigen::Vector2d> PathSamples(const World& world) {
  return RoutePath(world.route.waypoints_m, world.route.turn_radius_m).Sample(kRouteSampleM);
}

// Whether obstacle `index` may stand at outline `outline` in `state`: on the floor, clear
// of the robot's path and kMinGapM from every other present obstacle.
bool Placeable(const World& world, const WorldState& state, int index,
               const std::vector<Eigen::Vector2d>& outline,
               const std::vector<Eigen::Vector2d>& path) {
  if (!InsideFloor(world, outline, 0.1)) return false;
  if (!ClearOfPath(outline, path, world.changes.route_clearance_m)) return false;
  for (std::size_t j = 0; j < world.obstacles.size(); ++j) {
    if (static_cast<int>(j) == index || !state.present[j]) continue;
    if (OutlineDistance(outline, true, ObstacleOutline(world, state, static_cast<int>(j)),
                        world.obstacles[j].closed) < kMinGapM)
      return false;
  }
  return true;
}

// A shift of a gondola: along its long side by 0.5-2 m and across by 0.2-0.8 m, each
// direction random (the axis-aligned bounding box decides which side is long).
Eigen::Vector2d GondolaShift(const Obstacle& o, std::mt19937_64& rng) {
  Eigen::Vector2d lo = o.points_m.front(), hi = o.points_m.front();
  for (const auto& p : o.points_m) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  const Eigen::Vector2d size = hi - lo;
  const Eigen::Vector2d along =
      size.x() >= size.y() ? Eigen::Vector2d(1, 0) : Eigen::Vector2d(0, 1);
  const Eigen::Vector2d across(along.y(), along.x());
  const double a = Sign(rng) * Uniform(rng, 0.5, 2.0);
  const double c = Sign(rng) * Uniform(rng, 0.2, 0.8);
  return a * along + c * across;
}

// Puts obstacle `i` at its current offset + a fresh shift (present, new goods) if some of
// kMaxRedraws draws is placeable; returns whether it moved.
bool ShiftObstacle(const World& world, int i, std::mt19937_64& rng,
                   const std::vector<Eigen::Vector2d>& path, WorldState* s) {
  const Obstacle& o = world.obstacles[i];
  for (int attempt = 0; attempt < kMaxRedraws; ++attempt) {
    const Eigen::Vector2d offset = s->obstacle_offset_m[i] + GondolaShift(o, rng);
    std::vector<Eigen::Vector2d> outline = o.points_m;
    for (auto& p : outline) p += offset;
    if (!Placeable(world, *s, i, outline, path)) continue;
    s->obstacle_offset_m[i] = offset;
    s->present[i] = 1;
    s->cleared[i] = 0;
    s->texture_seed[i] = rng();
    return true;
  }
  return false;
}

bool IsDisplaySpot(const Obstacle& o) { return !o.initially_present; }

}  // namespace

namespace internal {

void AddDisplaySpots(World* world) {
  const LayoutChanges& c = world->changes;
  if (c.layout_intensity <= 0) return;
  const RoutePath route(world->route.waypoints_m, world->route.turn_radius_m);
  const std::vector<Eigen::Vector2d> path = route.Sample(kRouteSampleM);
  const int wanted = c.display_spots > 0
                         ? c.display_spots
                         : std::max(1, static_cast<int>(std::lround(route.length_m() / 10.0)));
  std::mt19937_64 rng(MixSeed(c.seed, kSpotDomain));
  const WorldState initial = InitialWorldState(*world);
  std::vector<Obstacle> spots;
  for (int attempt = 0; attempt < 200 * wanted && static_cast<int>(spots.size()) < wanted;
       ++attempt) {
    const Pose2 at = route.PoseAt(Uniform(rng) * route.length_m());
    const Eigen::Vector2d left(-std::sin(at.z()), std::cos(at.z()));
    const Eigen::Vector2d centre = at.head<2>() + Sign(rng) * Uniform(rng, 1.0, 3.0) * left;
    Eigen::Vector2d half(0.5 * Uniform(rng, 0.8, 2.4), 0.5 * Uniform(rng, 0.6, 1.2));
    if (rng() & 1) half = Eigen::Vector2d(half.y(), half.x());
    Obstacle o;
    o.kind = ObstacleKind::kBox;
    o.name = StrCat(kSpotPrefix, spots.size() + 1);
    o.points_m = {centre - half, centre + Eigen::Vector2d(half.x(), -half.y()), centre + half,
                  centre + Eigen::Vector2d(-half.x(), half.y())};
    o.closed = true;
    o.height_m = Uniform(rng, 1.2, 2.2);
    o.texture.kind = TextureKind::kLabels;
    o.texture.cell_m = Uniform(rng, 0.15, 0.35);
    o.texture.color_rgb = {Uniform(rng, 40, 230), Uniform(rng, 40, 230), Uniform(rng, 40, 230)};
    o.texture.seed = rng();
    o.initially_present = false;
    if (world->FindObstacle(o.name) >= 0 || !InsideFloor(*world, o.points_m, 0.3) ||
        !ClearOfPath(o.points_m, path, c.route_clearance_m + 0.2))
      continue;
    bool clear = true;
    for (std::size_t j = 0; j < world->obstacles.size() && clear; ++j) {
      clear =
          OutlineDistance(o.points_m, true, ObstacleOutline(*world, initial, static_cast<int>(j)),
                          world->obstacles[j].closed) >= kSpotGapM;
    }
    for (std::size_t j = 0; j < spots.size() && clear; ++j)
      clear = OutlineDistance(o.points_m, true, spots[j].points_m, true) >= kSpotGapM;
    if (clear) spots.push_back(std::move(o));
  }
  for (auto& o : spots) world->obstacles.push_back(std::move(o));
}

}  // namespace internal

WorldChange ApplyLayoutChanges(const World& world, int day, std::uint64_t seed, WorldState* state) {
  OMNICML_CHECK(state != nullptr);
  WorldChange change;
  const double p = world.changes.layout_intensity;
  if (day < 2 || p <= 0) return change;
  const std::vector<Eigen::Vector2d> path = PathSamples(world);
  const std::uint64_t day_seed =
      MixSeed(MixSeed(seed, kLayoutDomain), static_cast<std::uint64_t>(day));
  WorldState& s = *state;
  for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
    const Obstacle& o = world.obstacles[i];
    if (o.kind == ObstacleKind::kWall) continue;
    std::mt19937_64 rng(MixSeed(day_seed, i));
    if (Uniform(rng) >= p) continue;
    const int index = static_cast<int>(i);
    if (IsDisplaySpot(o)) {
      // Empty spot: a new display. Occupied: taken away or swapped for another display.
      if (s.present[i] && (rng() & 1)) {
        s.present[i] = 0;
        change.geometry = true;
      } else if (Placeable(world, s, index, ObstacleOutline(world, s, index), path)) {
        s.present[i] = 1;
        s.texture_seed[i] = rng();
        change.geometry = true;
      }
    } else if (s.present[i] && Uniform(rng) < 0.35) {
      s.present[i] = 0;  // gondola or box taken away (an aisle opens)
      change.geometry = true;
    } else {
      // Moved with new goods, or one taken away comes back elsewhere.
      change.geometry |= ShiftObstacle(world, index, rng, path, &s);
    }
  }
  for (std::size_t z = 0; z < world.lights.size(); ++z) {
    std::mt19937_64 rng(MixSeed(day_seed, kLightKey + z));
    if (Uniform(rng) >= p) continue;
    s.light_scale[z] = Uniform(rng, 0.4, 1.6);  // re-lit: new lamps, another level
    change.appearance = true;
  }
  return change;
}

World WithLayoutIntensity(World world, double intensity) {
  if (!(intensity >= 0 && intensity <= 1))
    throw Error(StrCat("changes.layout_intensity: ", intensity, " outside [0, 1]"));
  world.obstacles.erase(std::remove_if(world.obstacles.begin(), world.obstacles.end(),
                                       [](const Obstacle& o) { return IsDisplaySpot(o); }),
                        world.obstacles.end());
  world.changes.layout_intensity = intensity;
  internal::AddDisplaySpots(&world);
  return world;
}

std::vector<Pose2> RoutePoses(const World& world, double spacing_m) {
  if (!(spacing_m > 0) || !std::isfinite(spacing_m))
    throw Error(StrCat("route poses: spacing_m must be > 0, got ", spacing_m));
  const RoutePath route(world.route.waypoints_m, world.route.turn_radius_m);
  std::vector<Pose2> poses;
  const int n = std::max(1, static_cast<int>(std::floor(route.length_m() / spacing_m)));
  for (int k = 0; k < n; ++k) poses.push_back(route.PoseAt(k * spacing_m));
  return poses;
}

double ChangedPanoramaFraction(const World& world, const WorldState& a, const WorldState& b,
                               const std::vector<Pose2>& poses, double threshold_gray) {
  if (poses.empty()) throw Error("changed panorama fraction: no poses");
  Renderer ra(world), rb(world);
  ra.SetState(a);
  rb.SetState(b);
  cv::Mat pa, pb, diff;
  double sum = 0;
  for (const Pose2& pose : poses) {
    ra.RenderPanorama(pose, {}, &pa);
    rb.RenderPanorama(pose, {}, &pb);
    cv::absdiff(pa, pb, diff);
    std::int64_t changed = 0;
    for (int r = 0; r < diff.rows; ++r) {
      const cv::Vec3b* row = diff.ptr<cv::Vec3b>(r);
      for (int c = 0; c < diff.cols; ++c)
        changed += std::max({row[c][0], row[c][1], row[c][2]}) > threshold_gray;
    }
    sum += static_cast<double>(changed) / static_cast<double>(diff.total());
  }
  return sum / static_cast<double>(poses.size());
}

}  // namespace omnicml
