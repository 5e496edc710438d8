#include "omnicml/experiments/change_detection.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <utility>

#include "omnicml/common/common.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/run/run_report.h"
#include "omnicml/sim/renderer.h"

#include <opencv2/core.hpp>

namespace omnicml {

void ChangeDetectionOptions::Validate() const {
  if (!(cell_m > 0) || !std::isfinite(cell_m)) throw Error("change detection: cell_m must be > 0");
  if (!(radius_m >= 0) || !std::isfinite(radius_m)) {
    throw Error("change detection: radius_m must be >= 0");
  }
  if (!(min_changed_fraction > 0 && min_changed_fraction <= 1)) {
    throw Error("change detection: min_changed_fraction must be in (0, 1]");
  }
  if (!(pixel_threshold_sigmas > 0) || !std::isfinite(pixel_threshold_sigmas)) {
    throw Error("change detection: pixel_threshold_sigmas must be > 0");
  }
  if (points_per_cell < 1) throw Error("change detection: points_per_cell must be >= 1");
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
    const bool placed = before.present[i] != after.present[i];
    if (!moved && !retextured && !cleared && !placed) continue;
    std::string what = placed    ? (after.present[i] ? "placed" : "taken away")
                       : moved   ? "moved"
                       : cleared ? (after.cleared[i] ? "cleared" : "refilled")
                                 : "restocked";
    out.items.push_back(StrCat(ToString(o.kind), " ", o.name, " ", what));
    out.outlines.push_back({ObstacleOutline(world, after, static_cast<int>(i)), o.closed});
    if (moved) {
      out.outlines.push_back({ObstacleOutline(world, before, static_cast<int>(i)), o.closed});
    }
  }
  for (std::size_t i = 0; i < world.lights.size(); ++i) {
    if (before.light_on[i] == after.light_on[i] && before.light_scale[i] == after.light_scale[i])
      continue;
    out.items.push_back(StrCat("light ", world.lights[i].name,
                               before.light_on[i] != after.light_on[i]
                                   ? (after.light_on[i] ? " on" : " off")
                                   : " re-lit"));
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
  for (std::size_t i = 0; i + 1 < pts.size(); ++i)
    d = std::min(d, SegmentDistance(p, pts[i], pts[i + 1]));
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

struct VisibleChanges::Impl {
  std::unique_ptr<Renderer> before;    // state of day d - 1
  std::unique_ptr<Renderer> surfaces;  // day d - 1's lights, day d's surfaces
  std::unique_ptr<Renderer> after;     // state of day d; null when no light was switched
  double threshold_gray = 0.0;

  // Share of pixels of which some channel differs by more than threshold_gray.
  double Fraction(const Renderer& a, const Renderer& b, const Eigen::Vector2d& p) const {
    const Pose2 pose = MakePose(p.x(), p.y(), 0.0);
    const cv::Mat pa = a.RenderPanorama(pose);
    const cv::Mat pb = b.RenderPanorama(pose);
    cv::Mat diff;
    cv::absdiff(pa, pb, diff);
    int changed = 0;
    for (int r = 0; r < diff.rows; ++r) {
      const cv::Vec3b* row = diff.ptr<cv::Vec3b>(r);
      for (int c = 0; c < diff.cols; ++c) {
        const cv::Vec3b& d = row[c];
        changed += std::max({d[0], d[1], d[2]}) > threshold_gray;
      }
    }
    return diff.total() > 0 ? static_cast<double>(changed) / static_cast<double>(diff.total())
                            : 0.0;
  }
};

VisibleChanges::VisibleChanges(const World& world, int day, std::uint64_t seed,
                               const ChangeDetectionOptions& options)
    : impl_(std::make_unique<Impl>()) {
  options.Validate();
  if (day < 2) throw Error(StrCat("change detection: the visible truth needs day >= 2, got ", day));
  const WorldState before = StateAtDayStart(world, day - 1, seed);
  const WorldState after = StateAtDayStart(world, day, seed);
  WorldState surfaces = after;
  surfaces.light_on = before.light_on;
  surfaces.light_scale = before.light_scale;
  impl_->threshold_gray =
      options.pixel_threshold_sigmas * std::sqrt(2.0) * world.camera.noise_sigma_gray;
  impl_->before = std::make_unique<Renderer>(world);
  impl_->before->SetState(before);
  impl_->surfaces = std::make_unique<Renderer>(world);
  impl_->surfaces->SetState(surfaces);
  if (after.light_on != before.light_on || after.light_scale != before.light_scale) {
    impl_->after = std::make_unique<Renderer>(world);
    impl_->after->SetState(after);
  }
}

VisibleChanges::~VisibleChanges() = default;

double VisibleChanges::SurfaceFraction(const Eigen::Vector2d& p_m) const {
  return impl_->Fraction(*impl_->before, *impl_->surfaces, p_m);
}

double VisibleChanges::LitFraction(const Eigen::Vector2d& p_m) const {
  return impl_->after ? impl_->Fraction(*impl_->surfaces, *impl_->after, p_m) : 0.0;
}

namespace {

ChangeScore MakeScore(int truly, int tp, int detected) {
  ChangeScore s;
  s.truly_changed = truly;
  s.true_positives = tp;
  s.precision = Ratio(tp, detected);
  s.recall = Ratio(tp, truly);
  return s;
}

}  // namespace

ChangeDetectionDay ScoreChangeDetection(const MapHealth& health, const WorldDayChanges& changes,
                                        const std::vector<Eigen::Vector2d>& path_m,
                                        const ChangedSharesFn& shares,
                                        const ChangeDetectionOptions& options) {
  options.Validate();
  ChangeDetectionDay out;
  out.day = changes.day;
  out.session = health.latest_session;
  out.changed_items = static_cast<int>(changes.items.size());
  // The day's path points per cell (ix, iy) of the health map's grid, in path order.
  std::map<std::pair<int, int>, std::vector<Eigen::Vector2d>> crossed;
  for (const Eigen::Vector2d& p : path_m) {
    crossed[{static_cast<int>(std::floor(p.x() / options.cell_m)),
             static_cast<int>(std::floor(p.y() / options.cell_m))}]
        .push_back(p);
  }
  int geometric_truly = 0, geometric_tp = 0, visible_truly = 0, visible_tp = 0;
  for (const MapCell& cell : health.cells) {
    const auto it = crossed.find({cell.ix, cell.iy});
    if (it == crossed.end()) continue;
    ++out.cells_scored;
    ScoredCell s;
    s.cell = cell;
    const Eigen::Vector2d centre((cell.ix + 0.5) * options.cell_m,
                                 (cell.iy + 0.5) * options.cell_m);
    s.distance_m = DistanceToChanges(changes, centre);
    s.geometric_changed = s.distance_m <= options.radius_m;
    if (shares) {
      // points_per_cell points spread evenly over the cell's path points (first and last
      // included when there are enough).
      const std::vector<Eigen::Vector2d>& pts = it->second;
      const int n = static_cast<int>(pts.size());
      const int k = std::min(n, options.points_per_cell);
      for (int j = 0; j < k; ++j) {
        const int index =
            k == 1 ? n / 2
                   : static_cast<int>(std::lround(static_cast<double>(j) * (n - 1) / (k - 1)));
        const ChangedShares c = shares(pts[static_cast<std::size_t>(index)]);
        s.surface_fraction = std::max(s.surface_fraction, c.surface);
        s.lit_fraction = std::max(s.lit_fraction, c.lit);
      }
    }
    s.visible_changed = s.surface_fraction >= options.min_changed_fraction;
    s.detected = cell.health == CellHealth::kChanged || cell.health == CellHealth::kNew;
    out.cells_detected += s.detected;
    geometric_truly += s.geometric_changed;
    geometric_tp += s.geometric_changed && s.detected;
    visible_truly += s.visible_changed;
    visible_tp += s.visible_changed && s.detected;
    out.cells.push_back(s);
  }
  out.geometric = MakeScore(geometric_truly, geometric_tp, out.cells_detected);
  out.visible = MakeScore(visible_truly, visible_tp, out.cells_detected);
  return out;
}

void WriteChangeDetectionCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days) {
  os << "day,session,changed_items,cells_scored,cells_detected,"
        "visible_truly_changed,visible_true_positives,visible_precision,visible_recall,"
        "geometric_truly_changed,geometric_true_positives,geometric_precision,"
        "geometric_recall\n";
  auto score = [&](const ChangeScore& s) {
    os << s.truly_changed << "," << s.true_positives << "," << Number(s.precision) << ","
       << Number(s.recall);
  };
  int items = 0, scored = 0, detected = 0, vt = 0, vtp = 0, gt = 0, gtp = 0;
  for (const ChangeDetectionDay& d : days) {
    os << d.day << "," << d.session << "," << d.changed_items << "," << d.cells_scored << ","
       << d.cells_detected << ",";
    score(d.visible);
    os << ",";
    score(d.geometric);
    os << "\n";
    items += d.changed_items;
    scored += d.cells_scored;
    detected += d.cells_detected;
    vt += d.visible.truly_changed;
    vtp += d.visible.true_positives;
    gt += d.geometric.truly_changed;
    gtp += d.geometric.true_positives;
  }
  os << "all,," << items << "," << scored << "," << detected << ",";
  score(MakeScore(vt, vtp, detected));
  os << ",";
  score(MakeScore(gt, gtp, detected));
  os << "\n";
}

void WriteChangeCellsCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days,
                         double cell_m) {
  os << "day,ix,iy,x_m,y_m,health,views,insertions,removals,expected,missed,forgotten,"
        "changed_neighbours,distance_to_change_m,geometric_changed,surface_fraction,lit_fraction,"
        "visible_changed,"
        "detected\n";
  for (const ChangeDetectionDay& d : days) {
    for (const ScoredCell& s : d.cells) {
      const MapCell& c = s.cell;
      os << d.day << "," << c.ix << "," << c.iy << "," << Number((c.ix + 0.5) * cell_m) << ","
         << Number((c.iy + 0.5) * cell_m) << "," << ToString(c.health) << "," << c.views << ","
         << c.insertions_recent << "," << c.removals_recent << "," << c.expected_recent << ","
         << c.missed_recent << "," << c.forgotten_recent << "," << c.changed_neighbours << ","
         << Number(s.distance_m) << "," << s.geometric_changed << "," << Number(s.surface_fraction)
         << "," << Number(s.lit_fraction) << "," << s.visible_changed << "," << s.detected << "\n";
    }
  }
}

std::string FormatChangeDetection(const std::vector<ChangeDetectionDay>& days) {
  std::ostringstream os;
  for (const ChangeDetectionDay& d : days) {
    os << "change detection day " << d.day << ": " << d.changed_items << " items changed, "
       << d.cells_scored << " cells crossed, " << d.cells_detected
       << " detected; visible truth: " << d.visible.truly_changed << " changed, precision "
       << Percent(d.visible.precision) << " recall " << Percent(d.visible.recall)
       << "; geometric truth: " << d.geometric.truly_changed << " changed, precision "
       << Percent(d.geometric.precision) << " recall " << Percent(d.geometric.recall) << "\n";
  }
  if (!days.empty()) os << "change detection all days: " << ChangeDetectionTotals(days) << "\n";
  return os.str();
}

std::string ChangeDetectionTotals(const std::vector<ChangeDetectionDay>& days) {
  int det = 0, vt = 0, vtp = 0, gt = 0, gtp = 0;
  for (const ChangeDetectionDay& d : days) {
    det += d.cells_detected;
    vt += d.visible.truly_changed;
    vtp += d.visible.true_positives;
    gt += d.geometric.truly_changed;
    gtp += d.geometric.true_positives;
  }
  auto part = [&](const char* name, int tp, int truly) {
    return StrCat(name, " truth: precision ", Percent(Ratio(tp, det)), " (", tp, "/", det,
                  "), recall ", Percent(Ratio(tp, truly)), " (", tp, "/", truly, ")");
  };
  return StrCat(part("visible", vtp, vt), "; ", part("geometric", gtp, gt), " over ", days.size(),
                " day(s)");
}

ChangeDetectionObserver::ChangeDetectionObserver(std::string world_name, int first_day,
                                                 std::uint64_t seed, ChangeDetectionOptions options)
    : world_name_(std::move(world_name)), first_day_(first_day), seed_(seed), options_(options) {}

void ChangeDetectionObserver::OnSessionEnd(const CmlEngine& engine, int source_session,
                                           const std::vector<FrameRecord>& records) {
  if (!world_) world_ = LoadWorld(world_name_);
  const int session = engine.session_state().session;
  MapHealthOptions ho;
  ho.cell_m = options_.cell_m;
  const MapHealth health = ComputeMapHealth(engine.model(), session, ho);
  if (health.first_session < 0 || health.first_session >= session) return;  // a first map
  std::vector<Eigen::Vector2d> path;
  for (const FrameRecord& r : records) {
    if (r.session == session && r.has_truth) path.push_back(r.truth.head<2>());
  }
  const int day = first_day_ + source_session + 1;
  const WorldDayChanges changes = ChangesOfDay(*world_, day, seed_);
  ChangedSharesFn shares;
  std::unique_ptr<VisibleChanges> visible;
  if (day >= 2) {
    visible = std::make_unique<VisibleChanges>(*world_, day, seed_, options_);
    shares = [&visible](const Eigen::Vector2d& p) {
      return ChangedShares{visible->SurfaceFraction(p), visible->LitFraction(p)};
    };
  }
  days_.push_back(ScoreChangeDetection(health, changes, path, shares, options_));
}

void ChangeDetectionObserver::OnCommit(RunRecorder& recorder,
                                       std::vector<std::pair<std::string, std::string>>* notes) {
  std::ostringstream csv;
  WriteChangeDetectionCsv(csv, days_);
  recorder.AddFile("change_detection.csv", csv.str());
  std::ostringstream cells_csv;
  WriteChangeCellsCsv(cells_csv, days_, options_.cell_m);
  recorder.AddFile("change_cells.csv", cells_csv.str());
  notes->emplace_back(
      "change detection (health changed/new vs the day events)",
      days_.empty() ? std::string("no day after the map's first") : ChangeDetectionTotals(days_));
}

}  // namespace omnicml
