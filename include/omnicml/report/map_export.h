// Export and inspection of a learned appearance map (the EnvironmentModel inside a
// saved engine file): JSON, CSV, SVG and PNG pictures, and a health summary by area.
//
// JSON schema (documented with an example in datasets/map_schema.md; schema version 1):
//   {
//     "schema": "omnicml.map", "schema_version": 1,
//     "engine": {"frames": N, "sessions": S, "counters": {...}},
//     "model": {"views": V, "components": C, "memory_bytes": B, "next_view_id": ...,
//               "next_component_id": ..., "options": {e_max, top_k, beta, d_max, d_for_m,
//               beta_for, d_gain_m, w_min, merge_delta, forgetting, spatial_cell_m}},
//     "descriptor": {"kind": "fourier", "feature_size": F},
//     "views": [ { "id", "total_weight",
//                  "stats": {created_frame, created_session, observations, last_seen_frame,
//                            last_seen_session},
//                  "descriptor": {kind, length, panorama_width, norm, min, max, mean,
//                                 "features": [...] (only with include_features)},
//                  "components": [ { "id", "weight", "eta",
//                                    "mean": [x_m, y_m, phi_rad] (phi relative to the view),
//                                    "covariance": [[..3..],[..3..],[..3..]] (m^2, rad^2),
//                                    "ellipse": {major_m, minor_m, angle_rad} (1 sigma, xy) } ] }
//                                    ],
//     "events": [ {type, frame, session, view_id, component_id, position: [x, y, phi],
//                  weight, reason} ]   (only with include_events)
//   }
// CSV: one row per component with its view's columns repeated (header line first).
// Pictures (MapToSvg, MapToImage; one drawing, two back ends): the floor plan when known
// (walls as dark lines, shelves and boxes as grey blocks), ground truth and the estimated
// trajectory, every view component as a dot coloured by its weight (or by the health of
// its area), 2-sigma covariance ellipses only where they stay readable (the strongest
// components whose ellipse on the page is neither hidden under its dot nor large enough
// to cover the picture), a legend and a metre scale bar; x to the right, y up.
//
// Pure functions of their inputs; thread-safe.
#ifndef OMNICML_REPORT_MAP_EXPORT_H_
#define OMNICML_REPORT_MAP_EXPORT_H_

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "omnicml/engine/cml_engine.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml {

inline constexpr int kMapSchemaVersion = 1;

// A TUM trajectory: stamp and planar pose (yaw from the quaternion).
struct TimedPose {
  double stamp_s = 0.0;
  Pose2 pose = Pose2::Zero();
};
// Reads "stamp x y z qx qy qz qw" lines ('#' comments and blank lines skipped). Throws
// omnicml::Error "<file>:<line>: ..." on a malformed line.
std::vector<TimedPose> ReadTumTrajectory(const std::filesystem::path& path);
// One TUM line for a planar pose (z = 0, rotation about z), full precision, no newline.
std::string TumLine(double stamp_s, const Pose2& pose);

// The xy covariance ellipse at 1 sigma: semi-axes (m) and the major axis angle (rad).
struct Ellipse2 {
  double major_m = 0.0;
  double minor_m = 0.0;
  double angle_rad = 0.0;
};
Ellipse2 CovarianceEllipse(const Eigen::Matrix3d& covariance);

struct MapExportOptions {
  bool include_features = false;  // full descriptor vectors in JSON
  bool include_events = true;     // the event log in JSON
};

nlohmann::ordered_json MapToJson(const CmlEngine& engine, const MapExportOptions& options = {});
std::string MapToCsv(const EnvironmentModel& model);

// A floor plan drawn under the map picture: outlines in the map frame (metres). The
// simulator's worlds give one (run/floor_plan.h); real logs usually have none.
struct FloorPlanShape {
  enum class Kind { kWall, kShelf, kBox };
  Kind kind = Kind::kWall;
  std::vector<Eigen::Vector2d> points_m;  // at least 2 vertices
  bool closed = true;                     // polygon (filled) or open polyline (a wall)
};
struct FloorPlan {
  std::string name;                                 // e.g. the world name, for the legend
  Eigen::Vector2d min_m = Eigen::Vector2d::Zero();  // the floor's extent
  Eigen::Vector2d max_m = Eigen::Vector2d::Zero();  // (max <= min: from the shapes)
  std::vector<FloorPlanShape> shapes;
  bool empty() const { return shapes.empty(); }
};

// What the colour of a component's dot shows.
enum class MapColoring {
  kWeight,  // the component weight, pale (0) to dark blue (1)
  kHealth,  // the health of its area (ComputeMapHealth: ok, changed, new, stale)
};
std::string ToString(MapColoring coloring);                  // weight|health
MapColoring MapColoringFromString(const std::string& text);  // throws omnicml::Error

struct MapPictureOptions {
  int width_px = 900;               // picture width; height follows the map's aspect ratio
  double ellipse_sigma = 2.0;       // ellipses drawn at this many standard deviations
  std::string title;                // drawn at the top when not empty
  FloorPlan floor_plan;             // drawn under everything when not empty
  std::vector<Pose2> ground_truth;  // drawn under the estimate when not empty
  // Places where views were removed from the map (MapEvent positions of view_removed
  // events, metres), drawn as red crosses over the dots; empty = none drawn.
  std::vector<Eigen::Vector2d> removed_m;
  MapColoring coloring = MapColoring::kWeight;
  // kHealth: the session the health refers to; -1 = the latest session a view was
  // created or seen in. Cells of health_cell_m metres.
  int latest_session = -1;
  double health_cell_m = 2.0;
  // Ellipses: at most max_ellipses (0 = none), strongest components first, only of
  // components of weight >= min_ellipse_weight whose major semi-axis on the page is
  // within [min_ellipse_px, max_ellipse_fraction x picture width].
  int max_ellipses = 40;
  double min_ellipse_weight = 0.2;
  double min_ellipse_px = 4.0;
  double max_ellipse_fraction = 0.08;
};
// SVG element of the map over the estimated trajectory (may be empty).
std::string MapToSvg(const EnvironmentModel& model, const std::vector<Pose2>& trajectory,
                     const MapPictureOptions& options = {});
// The same picture as a BGR image (for PNG).
cv::Mat MapToImage(const EnvironmentModel& model, const std::vector<Pose2>& trajectory,
                   const MapPictureOptions& options = {});

// Map health by area (grid cells over component positions).
struct MapHealthOptions {
  double cell_m = 2.0;     // grid cell size, metres, > 0
  int stale_sessions = 1;  // a cell is stale if none of its views was seen in the last N sessions
  // A cell without evidence of its own is changed when at least this many of its 8
  // neighbouring cells have some (a change seen from there is usually in view from here
  // too: on store_large a restocked or moved shelf alters the panorama over several
  // cells). 0 disables; 0..8. Chosen on seeds 1-3 among spatial rules, confirmed on
  // seeds 4-5 (docs/results.md).
  int min_changed_neighbours = 2;
};
enum class CellHealth { kOk, kStale, kChanged, kNew };
std::string ToString(CellHealth health);  // ok|stale|changed|new
struct MapCell {
  int ix = 0, iy = 0;  // cell indices; the cell covers [ix, ix+1) * cell_m in x, same in y
  int views = 0;       // views with at least one component in the cell
  int components = 0;
  double total_weight = 0.0;
  int last_seen_session = -1;  // latest last_seen_session of its views
  int insertions_recent = 0;   // view insertions in the cell during the latest session
  int removals_recent = 0;     // component/view removals in the cell during the latest session
  // Evidence of change (active forgetting's pass bookkeeping, docs/forgetting.md): views
  // of earlier sessions the latest session expected to match here (the estimate passed
  // confidently through their footprint, or they matched), those of them that never
  // matched in it, and components removed here by active forgetting (18)-(19) in it.
  int expected_recent = 0;
  int missed_recent = 0;
  int forgotten_recent = 0;
  // Neighbouring cells (of 8) with evidence of their own (new, or an insertion, a missed
  // view or active forgetting there).
  int changed_neighbours = 0;
  CellHealth health = CellHealth::kOk;
};
struct MapHealth {
  int latest_session = -1;     // the latest session the map knows (engine session index)
  int first_session = -1;      // earliest created_session of a view
  std::vector<MapCell> cells;  // sorted by (iy, ix)
  int stale = 0, changed = 0, fresh = 0, ok = 0;
};
// `latest_session`: the engine's current session (session_state().session).
// Definitions: new = every view in the cell was created in the latest session;
// changed (otherwise) = in the latest session a view was inserted there (nothing
// matched), or a view of an earlier session expected there never matched (missed_recent),
// or active forgetting removed a component there (forgotten_recent); removals by passive
// forgetting or merges alone do not make a cell changed (they happen where nothing did);
// stale (otherwise) = no view seen in the last stale_sessions sessions; changed
// (otherwise) = at least min_changed_neighbours neighbouring cells with evidence of their
// own; ok otherwise.
MapHealth ComputeMapHealth(const EnvironmentModel& model, int latest_session,
                           const MapHealthOptions& options = {});

// A text summary for `omnicml inspect`: views, components, memory, sessions covered,
// per-session view creations and events, the health table and an ASCII map of cells.
std::string InspectText(const CmlEngine& engine, const MapHealthOptions& options = {});

}  // namespace omnicml

#endif  // OMNICML_REPORT_MAP_EXPORT_H_
