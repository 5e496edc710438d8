#include "omnicml/mapping/view_store.h"

#include <algorithm>
#include <complex>
#include <utility>

#include "omnicml/common/common.h"

namespace omnicml {

ViewStore::ViewStore(std::size_t feature_size, double spatial_cell_m)
    : feature_size_(feature_size), spatial_(spatial_cell_m) {}

std::size_t ViewStore::Insert(ReferenceView v) {
  OMNICML_CHECK(v.descriptor.features.size() == feature_size_)
      << "ViewStore::Insert: feature length";
  v.id = next_view_id_++;
  for (ViewComponent& c : v.components) {
    c.id = next_component_id_++;
    spatial_.Insert(SpatialEntry{v.id, c.id, c.mean.x(), c.mean.y()});
    ++num_components_;
  }
  features_.insert(features_.end(), v.descriptor.features.begin(), v.descriptor.features.end());
  index_of_id_[v.id] = views_.size();
  views_.push_back(std::move(v));
  return views_.size() - 1;
}

std::uint64_t ViewStore::AppendComponent(std::size_t row, ViewComponent c) {
  ReferenceView& view = views_[row];
  c.id = next_component_id_++;
  view.components.push_back(c);
  spatial_.Insert(SpatialEntry{view.id, c.id, c.mean.x(), c.mean.y()});
  ++num_components_;
  return c.id;
}

void ViewStore::ReplaceComponent(std::size_t row, std::size_t j, const ViewComponent& c) {
  ReferenceView& view = views_[row];
  ViewComponent& slot = view.components[j];
  const Pose2 old = slot.mean;
  const std::uint64_t id = slot.id;
  slot = c;
  slot.id = id;
  spatial_.Move(view.id, id, old.x(), old.y(), slot.mean.x(), slot.mean.y());
}

void ViewStore::EraseComponent(std::size_t row, std::size_t j) {
  ReferenceView& view = views_[row];
  const ViewComponent& c = view.components[j];
  spatial_.Remove(view.id, c.id, c.mean.x(), c.mean.y());
  view.components.erase(view.components.begin() + static_cast<std::ptrdiff_t>(j));
  --num_components_;
}

ViewStore::Removal ViewStore::RemoveAt(std::size_t row) {
  OMNICML_CHECK(row < views_.size());
  const std::size_t last = views_.size() - 1;
  for (const ViewComponent& c : views_[row].components) {
    spatial_.Remove(views_[row].id, c.id, c.mean.x(), c.mean.y());
    --num_components_;
  }
  Removal removal;
  removal.removed_id = views_[row].id;
  index_of_id_.erase(removal.removed_id);
  if (row != last) {
    // Swap-remove: the last view (and its feature row) takes the freed slot.
    views_[row] = std::move(views_[last]);
    std::copy(features_.begin() + static_cast<std::ptrdiff_t>(last * feature_size_),
              features_.begin() + static_cast<std::ptrdiff_t>((last + 1) * feature_size_),
              features_.begin() + static_cast<std::ptrdiff_t>(row * feature_size_));
    index_of_id_[views_[row].id] = row;
    removal.moved_id = views_[row].id;
  }
  views_.pop_back();
  features_.resize(views_.size() * feature_size_);
  return removal;
}

void ViewStore::Restore(std::vector<ReferenceView> views, std::uint64_t next_view_id,
                        std::uint64_t next_component_id) {
  views_ = std::move(views);
  next_view_id_ = next_view_id;
  next_component_id_ = next_component_id;
  features_.clear();
  features_.reserve(views_.size() * feature_size_);
  index_of_id_.clear();
  spatial_.Clear();
  num_components_ = 0;
  for (std::size_t i = 0; i < views_.size(); ++i) {
    const ReferenceView& v = views_[i];
    features_.insert(features_.end(), v.descriptor.features.begin(), v.descriptor.features.end());
    index_of_id_[v.id] = i;
    for (const ViewComponent& c : v.components) {
      spatial_.Insert(SpatialEntry{v.id, c.id, c.mean.x(), c.mean.y()});
      ++num_components_;
    }
  }
}

std::optional<std::size_t> ViewStore::Find(std::uint64_t view_id) const {
  auto it = index_of_id_.find(view_id);
  if (it == index_of_id_.end()) return std::nullopt;
  return it->second;
}

std::size_t ViewStore::RowOf(std::uint64_t view_id) const {
  const auto it = index_of_id_.find(view_id);
  OMNICML_CHECK(it != index_of_id_.end()) << "ViewStore: no view " << view_id;
  return it->second;
}

void ViewStore::CheckInvariants() const {
  OMNICML_CHECK(features_.size() == views_.size() * feature_size_) << "feature rows out of sync";
  OMNICML_CHECK(index_of_id_.size() == views_.size()) << "id map out of sync";
  std::size_t components = 0;
  std::vector<SpatialEntry> expected;
  std::vector<std::uint64_t> component_ids;
  for (std::size_t i = 0; i < views_.size(); ++i) {
    const ReferenceView& v = views_[i];
    OMNICML_CHECK(!v.components.empty()) << "view " << v.id << " is empty";
    OMNICML_CHECK(v.id < next_view_id_) << "view id " << v.id;
    const auto it = index_of_id_.find(v.id);
    OMNICML_CHECK(it != index_of_id_.end() && it->second == i) << "id map wrong for view " << v.id;
    OMNICML_CHECK(std::equal(v.descriptor.features.begin(), v.descriptor.features.end(),
                             features_.begin() + static_cast<std::ptrdiff_t>(i * feature_size_)))
        << "feature row of view " << v.id << " differs from its descriptor";
    for (const ViewComponent& c : v.components) {
      OMNICML_CHECK(c.weight >= 0.0 && c.weight <= 1.0) << "weight " << c.weight;
      OMNICML_CHECK(c.eta > 0.0) << "eta " << c.eta;
      OMNICML_CHECK(c.id < next_component_id_) << "component id " << c.id;
      expected.push_back(SpatialEntry{v.id, c.id, c.mean.x(), c.mean.y()});
      component_ids.push_back(c.id);
      ++components;
    }
  }
  OMNICML_CHECK(components == num_components_) << "component count out of sync";
  std::sort(component_ids.begin(), component_ids.end());
  OMNICML_CHECK(std::adjacent_find(component_ids.begin(), component_ids.end()) ==
                component_ids.end())
      << "duplicate component id";
  std::sort(expected.begin(), expected.end(), [](const SpatialEntry& a, const SpatialEntry& b) {
    return a.view_id != b.view_id ? a.view_id < b.view_id : a.component_id < b.component_id;
  });
  OMNICML_CHECK(expected == spatial_.All()) << "spatial index out of sync";
}

std::size_t ViewStore::MemoryBytes() const {
  std::size_t bytes = features_.capacity() * sizeof(float);
  bytes += views_.capacity() * sizeof(ReferenceView);
  for (const ReferenceView& v : views_) {
    bytes += v.descriptor.features.capacity() * sizeof(float);
    bytes += v.descriptor.coefficients.capacity() * sizeof(std::complex<float>);
    bytes += v.components.capacity() * sizeof(ViewComponent);
  }
  bytes += index_of_id_.bucket_count() * sizeof(void*) +
           index_of_id_.size() * (sizeof(std::uint64_t) + sizeof(std::size_t) + 2 * sizeof(void*));
  bytes += spatial_.MemoryBytes();
  return bytes;
}

}  // namespace omnicml
