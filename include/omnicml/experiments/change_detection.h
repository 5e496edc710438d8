// Change detection scored against the simulator's ground truth: the map's
// health by area (report/map_export.h ComputeMapHealth: a cell is "changed" when the
// latest session saw appearance evidence there, "new" when all its views are from the
// latest session) compared, day by day, with the places the world's day events changed.
//
// What changed overnight on day d (1-based, d >= 2): the items whose state differs
// between StateAtDayStart(d - 1) and StateAtDayStart(d): obstacles moved (old and new
// outline), restocked or cleared, light zones switched, curtains drawn. Step events
// (lights and curtains toggled within a day) and people are transient: not changes of
// the place, never in either truth.
//
// Two truths are scored side by side (docs/design.md "Change detection against the
// simulator's truth"):
//  - visible (the primary one, since 2026-11-24): a place changed for an appearance map
//    when the change is observable from there. The renderer (the simulator's own 2.5-D
//    ray caster, so occlusion by walls and shelves, and tall things seen over low ones,
//    are exactly the simulator's) draws the noise-free panorama at the cell's sample
//    points of the day's true path before and after the overnight surface changes, under
//    the same lights and without people; a pixel changed when some channel differs by
//    more than pixel_threshold_sigmas x sqrt(2) x the camera's sensor-noise sigma (the
//    noise of a difference of two frames). The cell is truly changed when, at one of its
//    sample points, at least min_changed_fraction of the panorama's pixels changed.
//    Lights switched between days change no surface; they are not changes of the place
//    (the descriptor is built to be invariant to them, fourier_signature.h); their share
//    of the panorama is reported per cell (lit_fraction) but not in this truth.
//  - geometric (the truth before 2026-11-24): the cell centre lies within radius_m of a
//    changed outline or inside a switched light zone.
//
// Scored cells: the cells the robot's true path crossed that day and the map holds
// views in (or lost all of them in) at the end of the day: change can only be seen where
// the robot went. Detected = health changed or new. precision = true positives /
// detected, recall = true positives / truly changed (NaN when the denominator is 0).
// Day 1 of a map (nothing to compare with) is not scored.
//
// Value functions are thread-compatible; VisibleChanges renders (const, thread-safe
// after construction, like Renderer).
#ifndef OMNICML_EXPERIMENTS_CHANGE_DETECTION_H_
#define OMNICML_EXPERIMENTS_CHANGE_DETECTION_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/report/map_export.h"
#include "omnicml/run/engine_driver.h"
#include "omnicml/sim/world.h"

namespace omnicml {

struct ChangeDetectionOptions {
  double cell_m = 2.0;  // health grid cell, metres (as `omnicml inspect --cell`), > 0
  // Geometric truth: a cell within this distance of a changed item is changed, metres, >= 0.
  double radius_m = 2.0;
  // Visible truth: the share of the panorama's pixels a change must alter to count, in
  // (0, 1]. 1/32: a full-height sector of 360/32 = 11.25 degrees, half the shortest
  // azimuth period the engine's descriptor stores (16 harmonics, fourier_signature.h),
  // and about what one person 2 m away covers (0.5 m x 1.75 m: 14 x 46 of 360 x 60
  // degrees, 3.0 %), clutter the map is meant to tolerate. Chosen from these two
  // figures before any score was measured.
  double min_changed_fraction = 1.0 / 32.0;
  // A pixel changed when a channel differs by more than this many standard deviations
  // of the difference of two noisy frames (sqrt(2) x CameraSpec::noise_sigma_gray). > 0.
  double pixel_threshold_sigmas = 3.0;
  // Points of the day's true path in a cell at which the panoramas are compared (spread
  // evenly over the path's points in the cell), >= 1.
  int points_per_cell = 3;
  void Validate() const;  // throws omnicml::Error
};

// What the day events of `day` (1-based) changed in `world` (simulator seed `seed`).
struct WorldDayChanges {
  int day = 0;
  std::vector<std::string> items;  // "shelf S1a_2 moved", "light north_east off", ...
  // Geometry of the changes: polylines (closed ones repeat no vertex; `closed` says) and
  // areas (light zones).
  struct Outline {
    std::vector<Eigen::Vector2d> points_m;
    bool closed = false;
  };
  std::vector<Outline> outlines;
  std::vector<std::vector<Eigen::Vector2d>> areas_m;
};
WorldDayChanges ChangesOfDay(const World& world, int day, std::uint64_t seed);

// Distance from p to the changes (0 inside an area or on an outline); +infinity when
// there are none.
double DistanceToChanges(const WorldDayChanges& changes, const Eigen::Vector2d& p_m);

// The visible truth of one day (file comment): renders the world before and after the
// overnight changes. Construction prepares two renderers (the day-(d-1) state, and that
// state with day d's obstacle offsets, textures, cleared shelves and curtains); the
// lighting of day d is kept for the lit share. Throws omnicml::Error on a bad day or
// options. Thread-safe after construction (Renderer's const methods).
class VisibleChanges {
 public:
  VisibleChanges(const World& world, int day, std::uint64_t seed,
                 const ChangeDetectionOptions& options = {});
  ~VisibleChanges();
  VisibleChanges(const VisibleChanges&) = delete;
  VisibleChanges& operator=(const VisibleChanges&) = delete;

  // Share of the panorama's pixels (in [0, 1]) at p_m (camera height, any heading: the
  // share does not depend on it) that the overnight surface changes altered.
  double SurfaceFraction(const Eigen::Vector2d& p_m) const;
  // Share altered by the switched lights alone (the surfaces of day d under the lights
  // of day d - 1 against day d's lights); 0 when no light was switched.
  double LitFraction(const Eigen::Vector2d& p_m) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// What the scorer asks of a truth at a point of the path: the changed shares there.
struct ChangedShares {
  double surface = 0.0;  // VisibleChanges::SurfaceFraction
  double lit = 0.0;      // VisibleChanges::LitFraction
};
using ChangedSharesFn = std::function<ChangedShares(const Eigen::Vector2d& p_m)>;

// One scored cell of a day: the map's evidence there and both truths.
struct ScoredCell {
  MapCell cell;                    // the health map's cell (health and evidence)
  double distance_m = 0.0;         // from the cell centre to the nearest change (inf: none)
  bool geometric_changed = false;  // distance_m <= radius_m
  double surface_fraction = 0.0;   // largest surface share over the cell's sample points
  double lit_fraction = 0.0;       // largest lit share over the cell's sample points
  bool visible_changed = false;    // surface_fraction >= min_changed_fraction
  bool detected = false;           // health changed or new
};

// Counts of one truth.
struct ChangeScore {
  int truly_changed = 0;
  int true_positives = 0;
  double precision = 0.0;  // NaN without detections
  double recall = 0.0;     // NaN without truly changed cells
};

struct ChangeDetectionDay {
  int day = 0;                    // 1-based simulated day
  int session = 0;                // engine session of that day
  int changed_items = 0;          // items the day events changed
  int cells_scored = 0;           // cells crossed that day with map content
  int cells_detected = 0;         // health changed or new
  ChangeScore visible;            // against the visible truth
  ChangeScore geometric;          // against the geometric truth
  std::vector<ScoredCell> cells;  // the scored cells, in the health map's order
};

// Scores `health` (the map's health at the end of the day, latest session = that day's)
// against `changes` (geometric truth) and `shares` (visible truth; e.g. a lambda over a
// VisibleChanges; null: every share 0) over the cells of the day's true positions
// `path_m`. Throws omnicml::Error on bad options.
ChangeDetectionDay ScoreChangeDetection(const MapHealth& health, const WorldDayChanges& changes,
                                        const std::vector<Eigen::Vector2d>& path_m,
                                        const ChangedSharesFn& shares,
                                        const ChangeDetectionOptions& options);

// change_detection.csv: a header and one row per scored day; then the totals row
// (day "all", precision and recall of the summed counts).
void WriteChangeDetectionCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days);
// change_cells.csv: one row per scored cell and day (the evidence behind the scores).
void WriteChangeCellsCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days,
                         double cell_m);
// One line per day plus the totals, for the console and the report.
std::string FormatChangeDetection(const std::vector<ChangeDetectionDay>& days);
// "visible truth: precision P % (tp/detected), recall R % (tp/changed); geometric truth:
// ... over N day(s)" of the summed counts.
std::string ChangeDetectionTotals(const std::vector<ChangeDetectionDay>& days);

// Change detection as a run observer (run/engine_driver.h): at the end of each
// simulated day after the map's first it scores the map's health (ComputeMapHealth)
// against the day events of `world_name` (loaded at the first session end), along the
// day's ground-truth path; at the commit it adds change_detection.csv and
// change_cells.csv to the run directory and a totals line to the report.
// `first_day` is the run's first simulated day (RunInput::first_day, 0-based), `seed`
// the simulator's seed. Thread-compatible.
class ChangeDetectionObserver : public RunObserver {
 public:
  ChangeDetectionObserver(std::string world_name, int first_day, std::uint64_t seed,
                          ChangeDetectionOptions options = {});
  void OnSessionEnd(const CmlEngine& engine, int source_session,
                    const std::vector<FrameRecord>& records) override;
  void OnCommit(RunRecorder& recorder,
                std::vector<std::pair<std::string, std::string>>* notes) override;
  // The days scored so far, in order.
  const std::vector<ChangeDetectionDay>& days() const { return days_; }

 private:
  std::string world_name_;
  int first_day_;
  std::uint64_t seed_;
  ChangeDetectionOptions options_;
  std::optional<World> world_;
  std::vector<ChangeDetectionDay> days_;
};

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_CHANGE_DETECTION_H_
