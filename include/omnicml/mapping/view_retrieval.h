// Place retrieval of the environment model (docs/design.md "Place retrieval at scale"):
// which stored views have E(y, y_i) < e_max, by one of three strategies over a ViewStore's
// feature rows, each giving every candidate the extractor's exact raw-pointer Distance:
//
//   scan   every row. Used on small maps and for distances without an L2 lower bound
//          (Jeffrey divergence, chi-square, intersection, unknown extractors).
//   exact  the candidates of view_index.h (PCA projection bound + kd-tree): the same
//          matches as the scan. Built from options index.index_min_views views on,
//          dropped below half of that, and kept only while the estimated fraction of
//          views it must bound is at most index.index_max_bounded_fraction.
//   ann    the candidates of an HNSW graph (ann_index.h): from index.ann_min_views views
//          on, taking precedence over the exact index. Approximate: a true match the
//          graph misses is not returned (never a false one). The graph is kept from the
//          first view on, one insertion per new view.
//
// Searches restricted to given rows (`only`) compare just those. Results are sorted by
// (distance, id) (MatchBefore) and cut to top_k when > 0; each match carries the
// extractor's relative heading.
//
// The indexes are derived state: never saved, rebuilt by Rebuild on load. The owner
// (EnvironmentModel) calls OnInsert / OnRemove / OnRowMoved for every change of the
// store's rows, then Maintain.
//
// Plain value; thread-compatible (const searches may run concurrently).
#ifndef OMNICML_MAPPING_VIEW_RETRIEVAL_H_
#define OMNICML_MAPPING_VIEW_RETRIEVAL_H_

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "omnicml/descriptors/descriptor.h"
#include "omnicml/mapping/ann_index.h"
#include "omnicml/mapping/environment_model_options.h"
#include "omnicml/mapping/reference_view.h"
#include "omnicml/mapping/view_index.h"
#include "omnicml/mapping/view_store.h"

namespace omnicml {

class ViewRetrieval {
 public:
  // `extractor` must not be null; it decides which strategies may serve its distance.
  ViewRetrieval(const EnvironmentModelOptions::Retrieval& retrieval,
                const EnvironmentModelOptions::Index& index,
                std::shared_ptr<const DescriptorExtractor> extractor);

  // Which strategy a search uses.
  enum class Strategy { kScan, kExact, kAnn };
  // The views of `store` with E(y, y_i) < e_max, sorted, at most top_k when > 0.
  // exhaustive: the scan whatever the indexes; only (optional, sorted unique rows):
  // compare these rows only. Precondition: y has the store's feature length.
  std::vector<ViewMatch> Search(const ViewStore& store, const Descriptor& y, int top_k,
                                bool exhaustive = false,
                                const std::vector<std::size_t>* only = nullptr) const;
  // The strategy an unrestricted, non-exhaustive search on `store` uses now.
  Strategy StrategyFor(const ViewStore& store) const;

  // The store gained a view at `row` / lost the view `id` / moved view `id` to `row`.
  void OnInsert(const ViewStore& store, std::size_t row);
  void OnRemove(std::uint64_t id);
  void OnRowMoved(std::uint64_t id, std::size_t row);
  // Builds, maintains or drops the indexes after the store changed.
  void Maintain(const ViewStore& store);
  // Drops the indexes and builds them again as Maintain would (a loaded map).
  void Rebuild(const ViewStore& store);
  // Search-time parameters of the graph (>= 1 each; checked by the caller).
  void SetAnnSearch(int ef, int k);

  // Whether the distance is bounded below by the L2 norm of the feature difference, so
  // the indexes may serve it (Fourier L1/L2, colour histogram L1/L2).
  bool IndexSupported() const { return index_supported_; }
  bool IndexActive() const { return view_index_.built(); }
  bool AnnActive(std::size_t num_views) const {
    return ann_index_.built() && num_views >= static_cast<std::size_t>(index_.ann_min_views);
  }
  // The estimated fraction of views the exact index must bound at its last evaluation;
  // -1 before any.
  double IndexBoundedFraction() const { return index_bounded_fraction_; }
  const ViewIndex& view_index() const { return view_index_; }
  const AnnIndex& ann_index() const { return ann_index_; }

  // Throws omnicml::InternalError unless each index is present exactly when the options
  // ask for it and holds every view of `store` once at its current row.
  void CheckInvariants(const ViewStore& store) const;
  std::size_t MemoryBytes() const;

 private:
  // Builds the exact index over every view and keeps it iff it pays.
  void BuildIndex(const ViewStore& store);
  // Builds the graph over every view, in id order.
  void BuildAnn(const ViewStore& store);
  // The radius query (top_k 0) or top_k query through the graph: appends to *rows the
  // rows of the views it returns (the candidates for the exact distance).
  void AnnCandidates(const ViewStore& store, const float* query, int top_k,
                     std::vector<std::size_t>* rows) const;

  EnvironmentModelOptions::Retrieval retrieval_;
  EnvironmentModelOptions::Index index_;
  std::shared_ptr<const DescriptorExtractor> extractor_;
  bool index_supported_ = false;
  bool distance_is_l2_ = false;  // E is exactly the L2 norm of the feature difference
  ViewIndex view_index_;
  double index_bounded_fraction_ = -1.0;
  std::size_t index_rejected_at_ = 0;  // views when the index was last dropped as unprofitable
  AnnIndex ann_index_;
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_VIEW_RETRIEVAL_H_
