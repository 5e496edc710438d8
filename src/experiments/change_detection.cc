#include "omnicml/experiments/change_detection.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>
#include <sstream>
#include <utility>

#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/run_report.h"

namespace omnicml {

void ChangeDetectionOptions::Validate() const {
  if (!(cell_m > 0) || !std::isfinite(cell_m)) throw Error("change detection: cell_m must be > 0");
  if (!(radius_m >= 0) || !std::isfinite(radius_m)) {
    throw Error("change detection: radius_m must be >= 0");
  }
}

WorldDayChanges ChangesOfDay(const World& world, int day, std::uint64_t seed) {
  if (day < 1) throw Error(StrCat("change detection: day must be >= 1, got ", day));
  WorldDayChanges out;
  out.day = day;
  const WorldState before = StateAtDayStart(world, day - 1, seed);
  const WorldState after = StateAtDayStart(world, day, seed);
  for (std::size_t i = 0; i < world.obstacles.size(); ++i) {
    const Obstacle& o = world.obstacles[i];
    const bool moved = before.obstacle_offset_m[i] != after.obstacle_offset_m[i];
    const bool retextured = before.texture_seed[i] != after.texture_seed[i];
    const bool cleared = before.cleared[i] != after.cleared[i];
    if (!moved && !retextured && !cleared) continue;
    std::string what = moved ? "moved" : cleared ? (after.cleared[i] ? "cleared" : "refilled")
                                                 : "restocked";
    out.items.push_back(StrCat(ToString(o.kind), " ", o.name, " ", what));
    out.outlines.push_back(
        {ObstacleOutline(world, after, static_cast<int>(i)), o.closed});
    if (moved) {
      out.outlines.push_back(
          {ObstacleOutline(world, before, static_cast<int>(i)), o.closed});
    }
  }
  for (std::size_t i = 0; i < world.lights.size(); ++i) {
    if (before.light_on[i] == after.light_on[i]) continue;
    out.items.push_back(
        StrCat("light ", world.lights[i].name, after.light_on[i] ? " on" : " off"));
    out.areas_m.push_back(world.lights[i].polygon_m);
  }
  for (std::size_t i = 0; i < world.windows.size(); ++i) {
    if (before.curtains_closed[i] == after.curtains_closed[i]) continue;
    const WindowSpec& w = world.windows[i];
    out.items.push_back(
        StrCat("curtains ", w.name, after.curtains_closed[i] ? " closed" : " opened"));
    out.outlines.push_back({{w.from_m, w.to_m}, false});
  }
  return out;
}

namespace {

double SegmentDistance(const Eigen::Vector2d& p, const Eigen::Vector2d& a,
                       const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

// Even-odd rule; points on the boundary may go either way (their distance is 0 anyway).
bool InsidePolygon(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  bool inside = false;
  for (std::size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const Eigen::Vector2d& a = poly[i];
    const Eigen::Vector2d& b = poly[j];
    if ((a.y() > p.y()) != (b.y() > p.y()) &&
        p.x() < (b.x() - a.x()) * (p.y() - a.y()) / (b.y() - a.y()) + a.x()) {
      inside = !inside;
    }
  }
  return inside;
}

double PolylineDistance(const std::vector<Eigen::Vector2d>& pts, bool closed,
                        const Eigen::Vector2d& p) {
  double d = std::numeric_limits<double>::infinity();
  if (pts.size() == 1) return (pts[0] - p).norm();
  for (std::size_t i = 0; i + 1 < pts.size(); ++i) d = std::min(d, SegmentDistance(p, pts[i], pts[i + 1]));
  if (closed && pts.size() > 2) d = std::min(d, SegmentDistance(p, pts.back(), pts.front()));
  return d;
}

double Ratio(int num, int den) {
  return den > 0 ? static_cast<double>(num) / static_cast<double>(den) : kNaN;
}

// "12.3 %", or "-" when undefined (NaN).
std::string Percent(double v) {
  return std::isfinite(v) ? FormatFixed(100.0 * v, 1) + " %" : std::string("-");
}

std::string Number(double v) {
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return std::isfinite(v) ? ShortestDouble(v) : "nan";
}

}  // namespace

double DistanceToChanges(const WorldDayChanges& changes, const Eigen::Vector2d& p_m) {
  double d = std::numeric_limits<double>::infinity();
  for (const auto& area : changes.areas_m) {
    if (area.size() >= 3 && InsidePolygon(area, p_m)) return 0.0;
    if (!area.empty()) d = std::min(d, PolylineDistance(area, true, p_m));
  }
  for (const auto& o : changes.outlines) {
    if (o.closed && o.points_m.size() >= 3 && InsidePolygon(o.points_m, p_m)) return 0.0;
    if (!o.points_m.empty()) d = std::min(d, PolylineDistance(o.points_m, o.closed, p_m));
  }
  return d;
}

ChangeDetectionDay ScoreChangeDetection(const MapHealth& health, const WorldDayChanges& changes,
                                        const std::vector<Eigen::Vector2d>& path_m,
                                        const ChangeDetectionOptions& options) {
  options.Validate();
  ChangeDetectionDay out;
  out.day = changes.day;
  out.session = health.latest_session;
  out.changed_items = static_cast<int>(changes.items.size());
  std::set<std::pair<int, int>> crossed;  // (ix, iy), the health map's grid
  for (const Eigen::Vector2d& p : path_m) {
    crossed.insert({static_cast<int>(std::floor(p.x() / options.cell_m)),
                    static_cast<int>(std::floor(p.y() / options.cell_m))});
  }
  for (const MapCell& cell : health.cells) {
    if (!crossed.count({cell.ix, cell.iy})) continue;
    ++out.cells_scored;
    const Eigen::Vector2d centre((cell.ix + 0.5) * options.cell_m, (cell.iy + 0.5) * options.cell_m);
    const double distance = DistanceToChanges(changes, centre);
    const bool truly = distance <= options.radius_m;
    const bool detected = cell.health == CellHealth::kChanged || cell.health == CellHealth::kNew;
    out.cells.push_back(ScoredCell{cell, distance, truly, detected});
    out.cells_truly_changed += truly;
    out.cells_detected += detected;
    out.true_positives += truly && detected;
  }
  out.precision = Ratio(out.true_positives, out.cells_detected);
  out.recall = Ratio(out.true_positives, out.cells_truly_changed);
  return out;
}

void WriteChangeDetectionCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days) {
  os << "day,session,changed_items,cells_scored,cells_truly_changed,cells_detected,"
        "true_positives,precision,recall\n";
  ChangeDetectionDay total;
  for (const ChangeDetectionDay& d : days) {
    os << d.day << "," << d.session << "," << d.changed_items << "," << d.cells_scored << ","
       << d.cells_truly_changed << "," << d.cells_detected << "," << d.true_positives << ","
       << Number(d.precision) << "," << Number(d.recall) << "\n";
    total.changed_items += d.changed_items;
    total.cells_scored += d.cells_scored;
    total.cells_truly_changed += d.cells_truly_changed;
    total.cells_detected += d.cells_detected;
    total.true_positives += d.true_positives;
  }
  os << "all,," << total.changed_items << "," << total.cells_scored << ","
     << total.cells_truly_changed << "," << total.cells_detected << "," << total.true_positives
     << "," << Number(Ratio(total.true_positives, total.cells_detected)) << ","
     << Number(Ratio(total.true_positives, total.cells_truly_changed)) << "\n";
}

void WriteChangeCellsCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days,
                         double cell_m) {
  os << "day,ix,iy,x_m,y_m,health,views,insertions,removals,expected,missed,forgotten,"
        "distance_to_change_m,truly_changed,detected\n";
  for (const ChangeDetectionDay& d : days) {
    for (const ScoredCell& s : d.cells) {
      const MapCell& c = s.cell;
      os << d.day << "," << c.ix << "," << c.iy << "," << Number((c.ix + 0.5) * cell_m) << ","
         << Number((c.iy + 0.5) * cell_m) << "," << ToString(c.health) << "," << c.views << ","
         << c.insertions_recent << "," << c.removals_recent << "," << c.expected_recent << ","
         << c.missed_recent << "," << c.forgotten_recent << "," << Number(s.distance_m) << ","
         << s.truly_changed << "," << s.detected << "\n";
    }
  }
}

std::string FormatChangeDetection(const std::vector<ChangeDetectionDay>& days) {
  std::ostringstream os;
  for (const ChangeDetectionDay& d : days) {
    os << "change detection day " << d.day << ": " << d.changed_items << " items changed, "
       << d.cells_scored << " cells crossed, " << d.cells_truly_changed << " truly changed, "
       << d.cells_detected << " detected, precision " << Percent(d.precision) << " recall "
       << Percent(d.recall) << "\n";
  }
  if (!days.empty()) os << "change detection all days: " << ChangeDetectionTotals(days) << "\n";
  return os.str();
}

std::string ChangeDetectionTotals(const std::vector<ChangeDetectionDay>& days) {
  int tp = 0, det = 0, truly = 0;
  for (const ChangeDetectionDay& d : days) {
    tp += d.true_positives;
    det += d.cells_detected;
    truly += d.cells_truly_changed;
  }
  return StrCat("precision ", Percent(Ratio(tp, det)), " (", tp, "/", det, "), recall ",
                Percent(Ratio(tp, truly)), " (", tp, "/", truly, ") over ", days.size(), " day(s)");
}

}  // namespace omnicml
