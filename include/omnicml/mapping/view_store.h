// The storage of the environment model: its reference views, one contiguous float row of
// features per view (same order as views()), the id -> row map, the uniform grid over the
// component positions (spatial_index.h), the component count and the next ids.
//
// Invariants (CheckInvariants): row i of features() equals views()[i]'s descriptor
// features; the id map holds every view at its row; no view is empty; the spatial grid
// holds exactly one entry per component at its mean's xy; NumComponents() counts the
// components; every id is unique and below the next id of its kind. Removal swaps the
// last view into the freed row, so rows change when views are removed.
//
// The store does not match, weigh or log: the model's phases (environment_model.h) do,
// through the mutators below, which keep the invariants. A component's weight, eta and
// covariance, and a view's counters and footprint, may be changed in place (view());
// a component's mean only through ReplaceComponent, which moves its grid entry too.
//
// Plain value; thread-compatible.
#ifndef OMNICML_MAPPING_VIEW_STORE_H_
#define OMNICML_MAPPING_VIEW_STORE_H_

#include <cstddef>
#include <cstdint>
#include <optional>
#include <unordered_map>
#include <vector>

#include "omnicml/descriptors/descriptor.h"
#include "omnicml/mapping/reference_view.h"
#include "omnicml/mapping/spatial_index.h"

namespace omnicml {

class ViewStore {
 public:
  // feature_size: floats per row (> 0); spatial_cell_m: the grid's cell size (> 0).
  ViewStore(std::size_t feature_size, double spatial_cell_m);

  // Appends a view: assigns it the next view id and every component the next component
  // ids (ids given are ignored), adds its row and grid entries. Returns its row.
  // Precondition: v.descriptor has feature_size() features.
  std::size_t Insert(ReferenceView v);
  // Appends c to the view at `row` with the next component id; returns the id.
  std::uint64_t AppendComponent(std::size_t row, ViewComponent c);
  // Replaces component j of the view at `row` by c (which keeps component j's id); its
  // grid entry follows the mean.
  void ReplaceComponent(std::size_t row, std::size_t j, const ViewComponent& c);
  // Erases component j of the view at `row` (the view may be left empty: the caller
  // removes it before the next query).
  void EraseComponent(std::size_t row, std::size_t j);
  // What RemoveAt changed in the rows: the removed view's id and, unless it was the last
  // row, the id of the view moved into its row.
  struct Removal {
    std::uint64_t removed_id = 0;
    std::optional<std::uint64_t> moved_id;
  };
  // Removes the view at `row` (swap-remove). Precondition: row < size().
  Removal RemoveAt(std::size_t row);
  // Replaces the whole content (a loaded map): views in row order and the next ids; the
  // rows, id map, grid and count are rebuilt. Ids are not checked (CheckInvariants does).
  void Restore(std::vector<ReferenceView> views, std::uint64_t next_view_id,
               std::uint64_t next_component_id);

  std::size_t size() const { return views_.size(); }
  bool empty() const { return views_.empty(); }
  std::size_t feature_size() const { return feature_size_; }
  std::size_t NumComponents() const { return num_components_; }
  const std::vector<ReferenceView>& views() const { return views_; }
  const ReferenceView& view(std::size_t row) const { return views_[row]; }
  // For in-place changes of weights, counters and footprints (see the class comment).
  ReferenceView& view(std::size_t row) { return views_[row]; }
  // size() rows of feature_size() floats.
  const std::vector<float>& features() const { return features_; }
  const float* row_features(std::size_t row) const {
    return features_.data() + row * feature_size_;
  }
  std::optional<std::size_t> Find(std::uint64_t view_id) const;
  // Row of a view known to be in the store (OMNICML_CHECK otherwise).
  std::size_t RowOf(std::uint64_t view_id) const;
  const SpatialIndex& spatial() const { return spatial_; }
  std::uint64_t next_view_id() const { return next_view_id_; }
  std::uint64_t next_component_id() const { return next_component_id_; }

  // Throws omnicml::InternalError naming the first broken invariant.
  void CheckInvariants() const;
  // Approximate heap bytes (views, rows, components, id map, grid).
  std::size_t MemoryBytes() const;

 private:
  std::size_t feature_size_ = 0;
  std::vector<ReferenceView> views_;
  std::vector<float> features_;  // views_.size() rows of feature_size_ floats
  std::unordered_map<std::uint64_t, std::size_t> index_of_id_;
  SpatialIndex spatial_;
  std::size_t num_components_ = 0;
  std::uint64_t next_view_id_ = 1;
  std::uint64_t next_component_id_ = 1;
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_VIEW_STORE_H_
