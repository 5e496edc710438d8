#include "omnicml/mapping/view_retrieval.h"

#include <algorithm>
#include <utility>

#include "omnicml/descriptors/color_histogram.h"
#include "omnicml/descriptors/fourier_signature.h"

namespace omnicml {
namespace {

// Whether E(a, b) >= ||a - b||_2 for every pair of feature vectors, which the candidate
// index's projection bound needs (view_index.h): the L2 norm itself, and the L1 norm
// (||v||_1 >= ||v||_2 for every v). Divergences and the intersection distance have no
// such bound; extractors this module does not know are not trusted to have one.
bool DistanceBoundedByL2(const DescriptorExtractor& extractor) {
  if (const auto* f = dynamic_cast<const FourierSignature*>(&extractor)) {
    return f->options().distance == FourierDistance::kL2 ||
           f->options().distance == FourierDistance::kL1;
  }
  if (const auto* c = dynamic_cast<const ColorHistogram*>(&extractor)) {
    return c->options().distance == HistogramDistance::kL2 ||
           c->options().distance == HistogramDistance::kL1;
  }
  return false;
}

// Whether the extractor's distance is exactly the L2 norm of the feature difference
// (then the graph's L2 order is E's order and a top_k query may stop at k neighbours).
bool DistanceIsL2(const DescriptorExtractor& extractor) {
  if (const auto* f = dynamic_cast<const FourierSignature*>(&extractor))
    return f->options().distance == FourierDistance::kL2;
  if (const auto* c = dynamic_cast<const ColorHistogram*>(&extractor))
    return c->options().distance == HistogramDistance::kL2;
  return false;
}

// Views whose bound the exact index is evaluated with (BuildIndex).
constexpr std::size_t kProfitSamples = 32;

}  // namespace

ViewRetrieval::ViewRetrieval(const EnvironmentModelOptions::Retrieval& retrieval,
                             const EnvironmentModelOptions::Index& index,
                             std::shared_ptr<const DescriptorExtractor> extractor)
    : retrieval_(retrieval), index_(index), extractor_(std::move(extractor)) {
  OMNICML_CHECK(extractor_ != nullptr) << "ViewRetrieval: null extractor";
  index_supported_ = DistanceBoundedByL2(*extractor_);
  distance_is_l2_ = DistanceIsL2(*extractor_);
}

ViewRetrieval::Strategy ViewRetrieval::StrategyFor(const ViewStore& store) const {
  if (AnnActive(store.size())) return Strategy::kAnn;
  if (view_index_.built()) return Strategy::kExact;
  return Strategy::kScan;
}

std::vector<ViewMatch> ViewRetrieval::Search(const ViewStore& store, const Descriptor& y, int top_k,
                                             bool exhaustive,
                                             const std::vector<std::size_t>* only) const {
  const std::size_t n = store.feature_size();
  const float* query = y.features.data();
  const float* rows = store.features().data();
  const double e_max = retrieval_.e_max;
  std::vector<ViewMatch> out;
  auto consider = [&](std::size_t i) {
    const double e = extractor_->Distance(query, rows + i * n, n);
    if (e < e_max) {
      ViewMatch m;
      m.view_index = i;
      m.view_id = store.view(i).id;
      m.distance = e;
      // docs/design.md: S = max(0, 1 - E / E_max), linear.
      m.similarity = std::max(0.0, 1.0 - e / e_max);
      out.push_back(m);
    }
  };
  const Strategy strategy = exhaustive ? Strategy::kScan : StrategyFor(store);
  std::vector<std::size_t> candidates;
  if (only != nullptr) {
    for (const std::size_t i : *only) consider(i);
  } else if (strategy == Strategy::kAnn) {
    // The graph's nearest views, then the same exact distance as the scan, so the result
    // equals the scan's whenever the candidates hold the true matches.
    AnnCandidates(store, query, top_k, &candidates);
    for (const std::size_t i : candidates) consider(i);
  } else if (strategy == Strategy::kExact) {
    // Every view with E < e_max is among the candidates, and each gets the same exact
    // distance as in the scan, so the matches are the same.
    view_index_.Candidates(query, e_max, &candidates);
    for (const std::size_t i : candidates) consider(i);
  } else {
    // The hot loop: one contiguous row per view, the extractor's raw-pointer distance.
    for (std::size_t i = 0; i < store.size(); ++i) consider(i);
  }
  std::sort(out.begin(), out.end(), MatchBefore);
  if (top_k > 0 && out.size() > static_cast<std::size_t>(top_k))
    out.resize(static_cast<std::size_t>(top_k));
  for (ViewMatch& m : out) {
    const std::optional<double> rel =
        extractor_->RelativeHeading(y, store.view(m.view_index).descriptor);
    if (rel) m.relative_heading_rad = WrapAngle(*rel);
  }
  return out;
}

void ViewRetrieval::BuildIndex(const ViewStore& store) {
  const std::size_t n = store.size();
  const std::size_t feature_size = store.feature_size();
  std::vector<std::uint64_t> ids(n);
  for (std::size_t i = 0; i < n; ++i) ids[i] = store.view(i).id;
  const int dims =
      std::min({index_.index_dims, static_cast<int>(feature_size), ViewIndex::kMaxDims});
  // Quantisation step e_max / 256: the bound loses at most one step per axis (view_index.h).
  view_index_.Build(store.features().data(), ids.data(), n, feature_size, dims,
                    retrieval_.e_max / 256.0);
  // Does it pay? Bound counts (not times, so the decision is deterministic) for stored
  // views, evenly spaced in storage order, as queries.
  std::size_t bounded = 0, queries = 0;
  std::vector<std::size_t> scratch;
  for (std::size_t k = 0; k < kProfitSamples && n > 0; ++k) {
    scratch.clear();
    bounded += view_index_.Candidates(store.row_features(k * n / kProfitSamples), retrieval_.e_max,
                                      &scratch);
    ++queries;
  }
  index_bounded_fraction_ =
      queries > 0 ? static_cast<double>(bounded) / static_cast<double>(queries * n) : 1.0;
  if (index_bounded_fraction_ > index_.index_max_bounded_fraction) {
    view_index_.Clear();  // the scan is as fast: revisit when the map has doubled
    index_rejected_at_ = n;
  } else {
    index_rejected_at_ = 0;
  }
}

void ViewRetrieval::AnnCandidates(const ViewStore& store, const float* query, int top_k,
                                  std::vector<std::size_t>* rows) const {
  // Squared L2 limit with the exact index's margin (view_index.h): float sums in the
  // graph and in the extractor differ by ~1e-6 relative.
  const double e_max = retrieval_.e_max;
  const double limit = (1.001 * e_max) * (1.001 * e_max);
  const std::size_t live = ann_index_.size();
  std::size_t k =
      std::min<std::size_t>(live, static_cast<std::size_t>(std::max(top_k, index_.ann_k)));
  std::vector<std::pair<float, std::uint64_t>> near;
  while (true) {
    ann_index_.Nearest(query, k, static_cast<std::size_t>(index_.ann_ef), &near);
    if (near.size() < k || k >= live) break;  // every view the graph reaches
    const double farthest = near.back().first;
    if (!(farthest < limit)) break;  // the radius is covered
    if (top_k > 0 && distance_is_l2_) {
      // E = L2: the top_k are found once top_k returned views are closer than the
      // farthest returned one (margin as above), which bounds every view not returned.
      const double closer = farthest / (1.001 * 1.001);
      std::size_t n = 0;
      for (const auto& [d, id] : near) n += d < closer;
      if (n >= static_cast<std::size_t>(top_k)) break;
    }
    k = std::min(live, 2 * k);
  }
  rows->reserve(rows->size() + near.size());
  for (const auto& [d, id] : near) {
    // Views beyond the radius by the graph's own distance cannot match (E >= L2); the
    // margin keeps the float difference from dropping a border match.
    if (!(d < limit)) continue;
    rows->push_back(store.RowOf(id));
  }
}

void ViewRetrieval::SetAnnSearch(int ef, int k) {
  index_.ann_ef = ef;
  index_.ann_k = k;
}

void ViewRetrieval::BuildAnn(const ViewStore& store) {
  AnnIndex::Params p;
  p.m = index_.ann_m;
  p.ef_construction = index_.ann_ef_construction;
  const std::size_t n = store.size();
  ann_index_.Reset(store.feature_size(), p, n + n / 4);
  // Id order: the order the views were inserted in, so a model rebuilt from its file
  // gets the graph the continuing model has when it removed no view.
  std::vector<std::pair<std::uint64_t, std::size_t>> order;
  order.reserve(n);
  for (std::size_t i = 0; i < n; ++i) order.emplace_back(store.view(i).id, i);
  std::sort(order.begin(), order.end());
  for (const auto& [id, row] : order) ann_index_.Insert(id, store.row_features(row));
}

void ViewRetrieval::OnInsert(const ViewStore& store, std::size_t row) {
  const std::uint64_t id = store.view(row).id;
  if (view_index_.built()) view_index_.Insert(id, row, store.row_features(row));
  if (ann_index_.built()) ann_index_.Insert(id, store.row_features(row));
}

void ViewRetrieval::OnRemove(std::uint64_t id) {
  if (view_index_.built()) view_index_.Remove(id);
  if (ann_index_.built()) ann_index_.Remove(id);
}

void ViewRetrieval::OnRowMoved(std::uint64_t id, std::size_t row) {
  if (view_index_.built()) view_index_.SetRow(id, row);
}

void ViewRetrieval::Maintain(const ViewStore& store) {
  const std::size_t views = store.size();
  // The graph is kept from the first view on (one insertion per new view, spread over
  // the run) and searched from ann_min_views views on, so no Update ever stalls on a
  // whole-map build when the map crosses the threshold.
  if (index_supported_ && index_.ann_min_views > 0 && !ann_index_.built() && views > 0) {
    BuildAnn(store);
  }
  const std::size_t threshold = static_cast<std::size_t>(index_.index_min_views);
  if (!index_supported_ || threshold == 0) return;
  if (!view_index_.built()) {
    if (views >= threshold && (index_rejected_at_ == 0 || views >= 2 * index_rejected_at_)) {
      BuildIndex(store);
    }
    return;
  }
  if (2 * views < threshold) {
    view_index_.Clear();  // a map this small is faster to scan
    index_rejected_at_ = 0;
    return;
  }
  switch (view_index_.Pending()) {
    case ViewIndex::Maintenance::kNone:
      break;
    case ViewIndex::Maintenance::kRetree:
      view_index_.Retree();
      break;
    case ViewIndex::Maintenance::kRefit:
      BuildIndex(store);
      break;
  }
}

void ViewRetrieval::Rebuild(const ViewStore& store) {
  view_index_.Clear();
  ann_index_.Clear();
  index_rejected_at_ = 0;
  index_bounded_fraction_ = -1.0;
  Maintain(store);
}

void ViewRetrieval::CheckInvariants(const ViewStore& store) const {
  const std::size_t views = store.size();
  // The exact index: present exactly when the options ask for it and it paid at its
  // last evaluation, holding every view once with its current row.
  const std::size_t threshold = static_cast<std::size_t>(index_.index_min_views);
  if (!index_supported_ || threshold == 0) {
    OMNICML_CHECK(!view_index_.built()) << "candidate index built although disabled";
  } else {
    if (views >= threshold && !view_index_.built()) {
      OMNICML_CHECK(index_rejected_at_ > 0 && views < 2 * index_rejected_at_)
          << "candidate index missing at " << views << " views";
    }
    if (2 * views < threshold) {
      OMNICML_CHECK(!view_index_.built()) << "candidate index kept below half the threshold";
    }
  }
  // The graph: kept from the first view on whenever enabled, holding every view once.
  if (!index_supported_ || index_.ann_min_views == 0) {
    OMNICML_CHECK(!ann_index_.built()) << "approximate index built although disabled";
  } else {
    OMNICML_CHECK(views == 0 || ann_index_.built())
        << "approximate index missing at " << views << " views";
  }
  if (ann_index_.built()) {
    std::vector<std::uint64_t> ids;
    for (const ReferenceView& v : store.views()) ids.push_back(v.id);
    std::sort(ids.begin(), ids.end());
    OMNICML_CHECK(ids == ann_index_.Ids()) << "approximate index out of sync";
  }
  if (view_index_.built()) {
    view_index_.CheckInvariants();
    std::vector<std::pair<std::uint64_t, std::size_t>> rows;
    for (std::size_t i = 0; i < views; ++i) rows.emplace_back(store.view(i).id, i);
    std::sort(rows.begin(), rows.end());
    OMNICML_CHECK(rows == view_index_.Entries()) << "candidate index out of sync";
  }
}

std::size_t ViewRetrieval::MemoryBytes() const {
  return view_index_.MemoryBytes() + ann_index_.MemoryBytes();
}

}  // namespace omnicml
