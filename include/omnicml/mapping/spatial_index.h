// A uniform grid over planar positions, for "which map components lie near this point"
// without scanning the whole map (docs/design.md "Environment model", rule 3).
//
// Entries are (view id, component id, x_m, y_m); the pair of ids is the key. The grid is
// a hash from integer cell (floor(x / cell), floor(y / cell)) to the entries in that cell;
// only non-empty cells are stored, so memory grows with the entries, not the area.
// A radius query visits the cells overlapping the query disc (or every occupied cell
// when that is fewer), so its cost grows with the entries near the point.
//
// Determinism: query results are sorted by (view id, component id) whatever the history
// of insertions and removals.
//
// Thread-safety: thread-compatible (concurrent const queries are fine).
#ifndef OMNICML_MAPPING_SPATIAL_INDEX_H_
#define OMNICML_MAPPING_SPATIAL_INDEX_H_

#include <cstddef>
#include <cstdint>
#include <unordered_map>
#include <vector>

namespace omnicml {

struct SpatialEntry {
  std::uint64_t view_id = 0;
  std::uint64_t component_id = 0;
  double x_m = 0.0;
  double y_m = 0.0;

  bool operator==(const SpatialEntry&) const = default;
};

class SpatialIndex {
 public:
  // cell_size_m > 0 (throws omnicml::Error otherwise).
  explicit SpatialIndex(double cell_size_m = 1.0);

  // Adds an entry. Precondition: its (view_id, component_id) is not in the index.
  // Positions must be finite (throws omnicml::Error otherwise).
  void Insert(const SpatialEntry& entry);

  // Removes the entry with these ids, which must have been inserted at exactly (x_m, y_m)
  // (its cell is found from the position). Returns false when it is not there.
  bool Remove(std::uint64_t view_id, std::uint64_t component_id, double x_m, double y_m);

  // Moves an entry from (old_x_m, old_y_m) to (new_x_m, new_y_m). Throws
  // omnicml::InternalError when it is not found at the old position.
  void Move(std::uint64_t view_id, std::uint64_t component_id, double old_x_m, double old_y_m,
            double new_x_m, double new_y_m);

  // All entries with Euclidean distance to (x_m, y_m) strictly below radius_m, sorted by
  // (view_id, component_id). radius_m <= 0 gives nothing.
  std::vector<SpatialEntry> QueryRadius(double x_m, double y_m, double radius_m) const;

  // Every entry, sorted by (view_id, component_id).
  std::vector<SpatialEntry> All() const;

  std::size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  std::size_t NumCells() const { return cells_.size(); }
  void Clear();
  double cell_size_m() const { return cell_size_m_; }
  // Approximate heap bytes.
  std::size_t MemoryBytes() const;

 private:
  std::int64_t CellKey(double x_m, double y_m) const;
  static std::int64_t PackKey(std::int64_t ix, std::int64_t iy);

  double cell_size_m_;
  std::unordered_map<std::int64_t, std::vector<SpatialEntry>> cells_;
  std::size_t size_ = 0;
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_SPATIAL_INDEX_H_
