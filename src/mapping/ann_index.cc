#include "omnicml/mapping/ann_index.h"

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <set>

#include <hnswlib/hnswlib.h>

#include "omnicml/common/common.h"

namespace omnicml {

using Graph = hnswlib::HierarchicalNSW<float>;

struct AnnIndex::Impl {
  // The space must outlive the graph (the graph keeps its distance function's parameter).
  std::unique_ptr<hnswlib::L2Space> space;
  std::unique_ptr<Graph> graph;
  std::set<hnswlib::tableint> free_slots;  // deleted slots, reused lowest first
  std::size_t live = 0;
};

namespace {

// A copy of `src` over `space` (same dimension): hnswlib 0.6.2 has no copy, but its
// state is public: the level-0 block, the upper layers' link lists, the label map, the
// entry point and the generators.
std::unique_ptr<Graph> CopyGraph(const Graph& src, hnswlib::L2Space* space,
                                 const AnnIndex::Params& p) {
  auto dst = std::make_unique<Graph>(space, src.max_elements_, static_cast<std::size_t>(p.m),
                                     static_cast<std::size_t>(p.ef_construction), p.seed);
  OMNICML_CHECK(dst->size_data_per_element_ == src.size_data_per_element_ &&
                dst->size_links_per_element_ == src.size_links_per_element_)
      << "AnnIndex: graph layouts differ";
  std::memcpy(dst->data_level0_memory_, src.data_level0_memory_,
              src.cur_element_count * src.size_data_per_element_);
  dst->cur_element_count = src.cur_element_count;
  dst->element_levels_ = src.element_levels_;
  for (std::size_t i = 0; i < src.cur_element_count; ++i) {
    const int level = src.element_levels_[i];
    if (level > 0) {
      const std::size_t bytes = src.size_links_per_element_ * static_cast<std::size_t>(level);
      dst->linkLists_[i] = static_cast<char*>(std::malloc(bytes));
      if (dst->linkLists_[i] == nullptr) throw Error("AnnIndex: out of memory copying the graph");
      std::memcpy(dst->linkLists_[i], src.linkLists_[i], bytes);
    } else {
      dst->linkLists_[i] = nullptr;
    }
  }
  dst->enterpoint_node_ = src.enterpoint_node_;
  dst->maxlevel_ = src.maxlevel_;
  dst->label_lookup_ = src.label_lookup_;
  dst->num_deleted_ = src.num_deleted_;
  dst->level_generator_ = src.level_generator_;
  dst->update_probability_generator_ = src.update_probability_generator_;
  dst->ef_ = src.ef_;
  return dst;
}

}  // namespace

AnnIndex::AnnIndex() = default;
AnnIndex::~AnnIndex() = default;
AnnIndex::AnnIndex(AnnIndex&& other) noexcept = default;
AnnIndex& AnnIndex::operator=(AnnIndex&& other) noexcept = default;

AnnIndex::AnnIndex(const AnnIndex& other) : dims_(other.dims_), params_(other.params_) {
  if (!other.impl_) return;
  impl_ = std::make_unique<Impl>();
  impl_->space = std::make_unique<hnswlib::L2Space>(dims_);
  impl_->graph = CopyGraph(*other.impl_->graph, impl_->space.get(), params_);
  impl_->free_slots = other.impl_->free_slots;
  impl_->live = other.impl_->live;
}

AnnIndex& AnnIndex::operator=(const AnnIndex& other) {
  if (this != &other) {
    AnnIndex copy(other);
    *this = std::move(copy);
  }
  return *this;
}

void AnnIndex::Reset(std::size_t dims, const Params& params, std::size_t capacity) {
  if (dims < 1) throw Error("AnnIndex::Reset: dims must be >= 1");
  if (params.m < 2 || params.m > 64) throw Error("AnnIndex::Reset: m must be in [2, 64]");
  if (params.ef_construction < 1) throw Error("AnnIndex::Reset: ef_construction must be >= 1");
  Clear();
  dims_ = dims;
  params_ = params;
  impl_ = std::make_unique<Impl>();
  impl_->space = std::make_unique<hnswlib::L2Space>(dims);
  impl_->graph = std::make_unique<Graph>(
      impl_->space.get(), std::max<std::size_t>(capacity, 16), static_cast<std::size_t>(params.m),
      static_cast<std::size_t>(params.ef_construction), params.seed);
  // Nearest asks for max(k, ef) neighbours: hnswlib's own list is then exactly that long.
  impl_->graph->setEf(1);
}

void AnnIndex::Insert(std::uint64_t id, const float* x) {
  OMNICML_CHECK(impl_ != nullptr) << "AnnIndex::Insert before Reset";
  Graph& g = *impl_->graph;
  OMNICML_CHECK(g.label_lookup_.count(id) == 0) << "AnnIndex::Insert: id " << id << " present";
  if (!impl_->free_slots.empty()) {
    // Reuse the lowest deleted slot: relabel it, then hnswlib's addPoint finds the label,
    // unmarks the slot and re-links it as the new vector (updatePoint).
    const hnswlib::tableint slot = *impl_->free_slots.begin();
    impl_->free_slots.erase(impl_->free_slots.begin());
    g.label_lookup_.erase(g.getExternalLabel(slot));
    g.label_lookup_[id] = slot;
    g.setExternalLabel(slot, id);
    g.addPoint(x, id);
  } else {
    if (g.cur_element_count >= g.max_elements_) g.resizeIndex(2 * g.max_elements_);
    g.addPoint(x, id);
  }
  ++impl_->live;
}

bool AnnIndex::Remove(std::uint64_t id) {
  if (!impl_) return false;
  Graph& g = *impl_->graph;
  const auto it = g.label_lookup_.find(id);
  if (it == g.label_lookup_.end() || g.isMarkedDeleted(it->second)) return false;
  g.markDeletedInternal(it->second);
  impl_->free_slots.insert(it->second);
  --impl_->live;
  return true;
}

void AnnIndex::Nearest(const float* q, std::size_t k, std::size_t ef,
                       std::vector<std::pair<float, std::uint64_t>>* out) const {
  out->clear();
  if (!impl_ || impl_->live == 0 || k == 0) return;
  // A search for max(k, ef) neighbours (ef_ is 1) is hnswlib's search with ef, and its
  // k nearest are the answer; no state changes, so concurrent calls may differ in ef.
  auto heap = impl_->graph->searchKnn(q, std::max(k, ef));  // a max-heap of (distance, label)
  out->reserve(heap.size());
  while (!heap.empty()) {
    out->emplace_back(heap.top().first, static_cast<std::uint64_t>(heap.top().second));
    heap.pop();
  }
  std::sort(out->begin(), out->end());
  if (out->size() > k) out->resize(k);
}

std::size_t AnnIndex::size() const { return impl_ ? impl_->live : 0; }

std::size_t AnnIndex::slots() const { return impl_ ? impl_->graph->cur_element_count : 0; }

void AnnIndex::Clear() {
  impl_.reset();
  dims_ = 0;
}

std::size_t AnnIndex::MemoryBytes() const {
  if (!impl_) return 0;
  const Graph& g = *impl_->graph;
  std::size_t bytes = g.max_elements_ * (g.size_data_per_element_ + sizeof(void*) + sizeof(int) +
                                         sizeof(std::mutex) + 2 * sizeof(hnswlib::vl_type));
  for (std::size_t i = 0; i < g.cur_element_count; ++i) {
    if (g.element_levels_[i] > 0)
      bytes += g.size_links_per_element_ * static_cast<std::size_t>(g.element_levels_[i]);
  }
  bytes += g.label_lookup_.bucket_count() * sizeof(void*) +
           g.label_lookup_.size() *
               (sizeof(hnswlib::labeltype) + sizeof(hnswlib::tableint) + 2 * sizeof(void*));
  bytes += impl_->free_slots.size() * (sizeof(hnswlib::tableint) + 4 * sizeof(void*));
  return bytes;
}

std::vector<std::uint64_t> AnnIndex::Ids() const {
  std::vector<std::uint64_t> ids;
  if (!impl_) return ids;
  const Graph& g = *impl_->graph;
  for (const auto& [label, slot] : g.label_lookup_) {
    if (!g.isMarkedDeleted(slot)) ids.push_back(static_cast<std::uint64_t>(label));
  }
  std::sort(ids.begin(), ids.end());
  return ids;
}

}  // namespace omnicml
