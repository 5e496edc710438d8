// Change detection scored against the simulator's ground truth (issue 15): the map's
// health by area (report/map_export.h ComputeMapHealth: a cell is "changed" when views
// were inserted there in the latest session or views of earlier sessions expected there
// failed to match, "new" when all its views are from the latest session) compared, day by day, with the places the world's
// day events changed.
//
// Ground truth of day d (1-based, d >= 2): the items whose state differs between
// StateAtDayStart(d - 1) and StateAtDayStart(d), i.e. what the day events changed
// overnight: obstacles moved (old and new outline), restocked or cleared (outline),
// light zones switched (polygon), curtains drawn (window segment). Step events (lights
// and curtains toggled during a day, people) are not changes of the place and are not
// in the truth. A grid cell (cell_m, the same grid as the health map) is truly changed
// when its centre lies within radius_m of a changed item's outline (or inside a switched
// light zone).
//
// Scored cells: the cells the robot's true path crossed that day and the map holds
// views in (or lost all of them in) at the end of the day: change can only be seen where
// the robot went. Detected = health changed or new. precision = true positives /
// detected, recall = true positives / truly changed (NaN when the denominator is 0).
// Day 1 of a map (nothing to compare with) is not scored.
//
// Thread-compatible value functions.
#ifndef OMNICML_EXPERIMENTS_CHANGE_DETECTION_H_
#define OMNICML_EXPERIMENTS_CHANGE_DETECTION_H_

#include <cstdint>
#include <ostream>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/report/map_export.h"
#include "omnicml/sim/world.h"

namespace omnicml {

struct ChangeDetectionOptions {
  double cell_m = 2.0;    // health grid cell, metres (as `omnicml inspect --cell`), > 0
  double radius_m = 2.0;  // a cell within this distance of a changed item is changed, metres, >= 0
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

// One scored cell of a day: the map's evidence there and the truth.
struct ScoredCell {
  MapCell cell;                // the health map's cell (health and evidence)
  double distance_m = 0.0;     // from the cell centre to the nearest change (inf: none)
  bool truly_changed = false;  // distance_m <= radius_m
  bool detected = false;       // health changed or new
};

struct ChangeDetectionDay {
  int day = 0;                // 1-based simulated day
  int session = 0;            // engine session of that day
  int changed_items = 0;      // items the day events changed
  int cells_scored = 0;       // cells crossed that day with map content
  int cells_truly_changed = 0;
  int cells_detected = 0;     // health changed or new
  int true_positives = 0;
  double precision = 0.0;     // NaN without detections
  double recall = 0.0;        // NaN without truly changed cells
  std::vector<ScoredCell> cells;  // the scored cells, in the health map's order
};

// Scores `health` (the map's health at the end of the day, latest session = that day's)
// against `changes` over the cells of the day's true positions `path_m`.
ChangeDetectionDay ScoreChangeDetection(const MapHealth& health, const WorldDayChanges& changes,
                                        const std::vector<Eigen::Vector2d>& path_m,
                                        const ChangeDetectionOptions& options);

// change_detection.csv: a header and one row per scored day; then the totals row
// (day "all", precision and recall of the summed counts).
void WriteChangeDetectionCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days);
// change_cells.csv: one row per scored cell and day (the evidence behind the scores).
void WriteChangeCellsCsv(std::ostream& os, const std::vector<ChangeDetectionDay>& days,
                         double cell_m);
// One line per day plus the totals, for the console and the report.
std::string FormatChangeDetection(const std::vector<ChangeDetectionDay>& days);
// "precision P % (tp/detected), recall R % (tp/changed) over N day(s)" of the summed counts.
std::string ChangeDetectionTotals(const std::vector<ChangeDetectionDay>& days);

}  // namespace omnicml

#endif  // OMNICML_EXPERIMENTS_CHANGE_DETECTION_H_
