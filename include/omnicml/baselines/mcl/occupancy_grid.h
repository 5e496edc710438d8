// Occupancy grids for the Monte Carlo localization baseline [W] (docs/design.md "Baselines
// from the seeds"): a 2-D grid of free / occupied / unknown cells made from a simulated
// world, loadable and savable in the ROS map_server convention (PGM image + YAML), with
// ray casting and the constrained region growing that turns a reference view into its
// visibility area sigma_j.
//
// Frames and indices: the grid lies in the map frame; cell (ix, iy) covers
// [origin_x + ix res, origin_x + (ix + 1) res) x [origin_y + iy res, ...), ix to the right
// (+x), iy upwards (+y). In the PGM image the first row is the top of the map (largest
// iy), as map_server does.
//
// map_server YAML keys (all required except mode): image (path, relative to the YAML's
// directory unless absolute), resolution (m/cell), origin ([x_m, y_m, yaw_rad]; yaw must be
// 0 here), negate (0|1), occupied_thresh, free_thresh (probabilities in [0, 1]); optional
// mode (only "trinary" is supported). A pixel value p in 0..255 gives the occupancy
// probability occ = (255 - p) / 255 (negate 0) or p / 255 (negate 1); occ > occupied_thresh
// is occupied, occ < free_thresh free, anything else unknown. Saving writes 0 (occupied),
// 254 (free) and 205 (unknown), negate 0, occupied_thresh 0.65, free_thresh 0.196, as
// map_saver does.
//
// Thread-safety: a plain value type; const methods may run concurrently.
#ifndef OMNICML_BASELINES_MCL_OCCUPANCY_GRID_H_
#define OMNICML_BASELINES_MCL_OCCUPANCY_GRID_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/geometry/pose.h"
#include "omnicml/sim/world.h"

namespace omnicml {

enum class CellState : std::uint8_t { kFree = 0, kOccupied = 1, kUnknown = 2 };

// An integer cell index.
struct CellIndex {
  int x = 0;
  int y = 0;
  bool operator==(const CellIndex&) const = default;
};

class OccupancyGrid {
 public:
  OccupancyGrid() = default;
  // A width x height grid of `fill` cells. Throws omnicml::Error unless width, height >= 1
  // and resolution_m > 0 (finite).
  OccupancyGrid(int width, int height, double resolution_m, const Eigen::Vector2d& origin_m,
                CellState fill = CellState::kFree);

  int width() const { return width_; }
  int height() const { return height_; }
  double resolution_m() const { return resolution_m_; }
  const Eigen::Vector2d& origin_m() const { return origin_m_; }

  bool InBounds(const CellIndex& c) const {
    return c.x >= 0 && c.y >= 0 && c.x < width_ && c.y < height_;
  }
  // The cell containing a map point (may be out of bounds).
  CellIndex CellOf(const Eigen::Vector2d& p_m) const;
  // The centre of a cell in the map frame, metres.
  Eigen::Vector2d CellCenter(const CellIndex& c) const;
  // Linear index iy * width + ix (c must be in bounds).
  int Linear(const CellIndex& c) const { return c.y * width_ + c.x; }
  CellIndex FromLinear(int i) const { return {i % width_, i / width_}; }

  // State of a cell; out-of-bounds cells are kUnknown.
  CellState At(const CellIndex& c) const;
  void Set(const CellIndex& c, CellState s);  // c must be in bounds (OMNICML_CHECK)
  bool IsFree(const CellIndex& c) const { return At(c) == CellState::kFree; }
  // True when the point lies in a free cell.
  bool IsFreePoint(const Eigen::Vector2d& p_m) const { return IsFree(CellOf(p_m)); }
  // Linear indices of all free cells, ascending.
  std::vector<int> FreeCells() const;
  const std::vector<CellState>& cells() const { return cells_; }

  // Casts a ray from `from_m` along heading_rad (map frame) and returns the first cell that
  // is occupied, stepping cell by cell (Amanatides-Woo traversal) up to max_range_m metres.
  // std::nullopt when no occupied cell is met within range or the ray leaves the grid or
  // enters an unknown cell first.
  std::optional<CellIndex> CastRay(const Eigen::Vector2d& from_m, double heading_rad,
                                   double max_range_m) const;

  // True when every cell traversed by the segment from the centre of a to the centre of b
  // is free, except that b itself may be occupied (the target of a line of sight).
  bool LineOfSight(const CellIndex& a, const CellIndex& b) const;

  bool operator==(const OccupancyGrid&) const = default;

 private:
  int width_ = 0;
  int height_ = 0;
  double resolution_m_ = 0.1;
  Eigen::Vector2d origin_m_ = Eigen::Vector2d::Zero();
  std::vector<CellState> cells_;
};

struct OccupancyGridFromWorldOptions {
  // Cell size, metres (> 0).
  double resolution_m = 0.1;
  // Occupied cells are grown by this margin, metres (>= 0): 0 marks exactly the cells an
  // obstacle touches.
  double inflate_m = 0.0;
  // Cells added around the floor on every side (>= 0); they are occupied (outside the
  // floor the robot cannot be).
  int border_cells = 1;
  void Validate() const;  // throws omnicml::Error naming the field
};

// Rasterises a world in the given state: a cell is occupied when an obstacle polygon
// contains its centre, an obstacle edge (walls are open polylines of zero thickness)
// passes within half a cell diagonal (+ inflate_m) of its centre, or its centre lies
// outside the floor [0, size_m]. Windows are part of their walls; people are ignored.
OccupancyGrid MakeOccupancyGrid(const World& world, const WorldState& state,
                                const OccupancyGridFromWorldOptions& options = {});

// Writes `yaml_path` and the PGM image beside it (same stem, ".pgm"), in the map_server
// convention of the file comment. Throws omnicml::Error naming the file on I/O failure.
void SaveOccupancyGrid(const OccupancyGrid& grid, const std::string& yaml_path);
// Reads a map_server YAML and its image. Throws omnicml::Error "<file>: <key>: what" for a
// missing or unreadable file, a missing, unknown or malformed key, a non-zero yaw, an
// unsupported mode, or an image that does not decode as 8-bit grey.
OccupancyGrid LoadOccupancyGrid(const std::string& yaml_path);

// Parameters of the visibility area of a reference view ([W] "visibility areas").
struct VisibilityOptions {
  // Ray length along the optical axis, metres (> 0). Beyond it no wall point is found
  // and the view has an empty visibility area.
  double max_ray_range_m = 12.0;
  // Region growing constraint: cells farther than this from lambda_j are not added, metres.
  double max_distance_m = 6.0;
  // Region growing constraint: the direction from a cell to lambda_j must lie within this
  // angle of the reference's axis, radians in (0, pi] (pi: any direction).
  double max_view_angle_rad = 0.7853981633974483;  // 45 degrees
  // Final constraint for omni views (our addition, not in [W]): keep only cells within
  // this distance of the reference position, metres; 0 = no limit ([W]'s perspective
  // camera). An omni view's appearance is a property of the place, so its area should
  // stay near where it was taken; the axis then only selects which wall point must be in
  // sight.
  double max_distance_from_reference_m = 0.0;
  void Validate() const;  // throws omnicml::Error naming the field
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, VisibilityOptions& o) {
  v("max_ray_range_m", o.max_ray_range_m);
  v("max_distance_m", o.max_distance_m);
  v("max_view_angle_rad", o.max_view_angle_rad);
  v("max_distance_from_reference_m", o.max_distance_from_reference_m);
}

// The visibility area of a view at `position_m` whose (chosen) optical axis points along
// axis_rad: lambda_j is the first occupied cell on the axis (CastRay); the area is grown
// from the free 8-neighbours of lambda_j over 8-connected free cells, adding a cell
// when lambda_j is in line of sight from it, within max_distance_m and within
// max_view_angle_rad of the axis direction. The grown region is therefore connected and
// every cell in it sees lambda_j. Then cells farther than max_distance_from_reference_m
// (when > 0) from position_m are removed. Returns the linear indices, ascending; empty when no wall
// point is found. `lambda_out`, when not null, receives lambda_j (or stays unchanged).
std::vector<int> VisibilityArea(const OccupancyGrid& grid, const Eigen::Vector2d& position_m,
                                double axis_rad, const VisibilityOptions& options,
                                CellIndex* lambda_out = nullptr);

}  // namespace omnicml

#endif  // OMNICML_BASELINES_MCL_OCCUPANCY_GRID_H_
