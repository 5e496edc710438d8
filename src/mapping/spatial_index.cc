#include "omnicml/mapping/spatial_index.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

bool EntryLess(const SpatialEntry& a, const SpatialEntry& b) {
  return a.view_id != b.view_id ? a.view_id < b.view_id : a.component_id < b.component_id;
}

// Cell coordinate of a position; clamped so that absurd coordinates cannot overflow.
std::int64_t CellCoord(double v_m, double cell_m) {
  const double c = std::floor(v_m / cell_m);
  constexpr double kLimit = 1e15;
  return static_cast<std::int64_t>(std::clamp(c, -kLimit, kLimit));
}

}  // namespace

SpatialIndex::SpatialIndex(double cell_size_m) : cell_size_m_(cell_size_m) {
  if (!(cell_size_m > 0.0) || !std::isfinite(cell_size_m)) {
    throw Error(StrCat("SpatialIndex: cell_size_m must be finite and > 0, got ", cell_size_m));
  }
}

std::int64_t SpatialIndex::PackKey(std::int64_t ix, std::int64_t iy) {
  // Mix the two coordinates into one 64-bit key (exact for |ix|, |iy| < 2^31; beyond
  // that two cells may share a key, which only costs extra candidates: queries filter
  // by distance).
  return static_cast<std::int64_t>((static_cast<std::uint64_t>(ix) << 32) ^
                                   (static_cast<std::uint64_t>(iy) & 0xFFFFFFFFull));
}

std::int64_t SpatialIndex::CellKey(double x_m, double y_m) const {
  return PackKey(CellCoord(x_m, cell_size_m_), CellCoord(y_m, cell_size_m_));
}

void SpatialIndex::Insert(const SpatialEntry& entry) {
  if (!std::isfinite(entry.x_m) || !std::isfinite(entry.y_m)) {
    throw Error(StrCat("SpatialIndex::Insert: non-finite position (", entry.x_m, ", ", entry.y_m,
                       ") of view ", entry.view_id, " component ", entry.component_id));
  }
  cells_[CellKey(entry.x_m, entry.y_m)].push_back(entry);
  ++size_;
}

bool SpatialIndex::Remove(std::uint64_t view_id, std::uint64_t component_id, double x_m,
                          double y_m) {
  auto it = cells_.find(CellKey(x_m, y_m));
  if (it == cells_.end()) return false;
  std::vector<SpatialEntry>& cell = it->second;
  for (std::size_t k = 0; k < cell.size(); ++k) {
    if (cell[k].view_id == view_id && cell[k].component_id == component_id) {
      cell[k] = cell.back();
      cell.pop_back();
      if (cell.empty()) cells_.erase(it);
      --size_;
      return true;
    }
  }
  return false;
}

void SpatialIndex::Move(std::uint64_t view_id, std::uint64_t component_id, double old_x_m,
                        double old_y_m, double new_x_m, double new_y_m) {
  if (CellKey(old_x_m, old_y_m) == CellKey(new_x_m, new_y_m) && std::isfinite(new_x_m) &&
      std::isfinite(new_y_m)) {
    auto it = cells_.find(CellKey(old_x_m, old_y_m));
    OMNICML_CHECK(it != cells_.end())
        << "view " << view_id << " component " << component_id << " not indexed";
    for (SpatialEntry& e : it->second) {
      if (e.view_id == view_id && e.component_id == component_id) {
        e.x_m = new_x_m;
        e.y_m = new_y_m;
        return;
      }
    }
    OMNICML_CHECK(false) << "view " << view_id << " component " << component_id << " not indexed";
  }
  const bool removed = Remove(view_id, component_id, old_x_m, old_y_m);
  OMNICML_CHECK(removed) << "view " << view_id << " component " << component_id << " not indexed";
  Insert(SpatialEntry{view_id, component_id, new_x_m, new_y_m});
}

std::vector<SpatialEntry> SpatialIndex::QueryRadius(double x_m, double y_m, double radius_m) const {
  std::vector<SpatialEntry> out;
  if (!(radius_m > 0.0) || cells_.empty()) return out;
  const double r2 = radius_m * radius_m;
  auto consider = [&](const std::vector<SpatialEntry>& cell) {
    for (const SpatialEntry& e : cell) {
      const double dx = e.x_m - x_m, dy = e.y_m - y_m;
      if (dx * dx + dy * dy < r2) out.push_back(e);
    }
  };
  const std::int64_t ix0 = CellCoord(x_m - radius_m, cell_size_m_),
                     ix1 = CellCoord(x_m + radius_m, cell_size_m_);
  const std::int64_t iy0 = CellCoord(y_m - radius_m, cell_size_m_),
                     iy1 = CellCoord(y_m + radius_m, cell_size_m_);
  const double span_cells =
      (static_cast<double>(ix1 - ix0) + 1.0) * (static_cast<double>(iy1 - iy0) + 1.0);
  if (span_cells > static_cast<double>(cells_.size())) {
    // Fewer occupied cells than cells in the disc's box: scan the occupied ones.
    for (const auto& [key, cell] : cells_) consider(cell);
  } else {
    for (std::int64_t ix = ix0; ix <= ix1; ++ix) {
      for (std::int64_t iy = iy0; iy <= iy1; ++iy) {
        auto it = cells_.find(PackKey(ix, iy));
        if (it != cells_.end()) consider(it->second);
      }
    }
  }
  std::sort(out.begin(), out.end(), EntryLess);
  // With wrapped keys (|cell coordinate| >= 2^31) one cell can be visited twice.
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

std::vector<SpatialEntry> SpatialIndex::All() const {
  std::vector<SpatialEntry> out;
  out.reserve(size_);
  for (const auto& [key, cell] : cells_) out.insert(out.end(), cell.begin(), cell.end());
  std::sort(out.begin(), out.end(), EntryLess);
  return out;
}

void SpatialIndex::Clear() {
  cells_.clear();
  size_ = 0;
}

std::size_t SpatialIndex::MemoryBytes() const {
  std::size_t bytes = cells_.bucket_count() * sizeof(void*);
  for (const auto& [key, cell] : cells_) {
    bytes += sizeof(std::int64_t) + sizeof(std::vector<SpatialEntry>) + 2 * sizeof(void*) +
             cell.capacity() * sizeof(SpatialEntry);
  }
  return bytes;
}

}  // namespace omnicml
