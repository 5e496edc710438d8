#include "omnicml/mapping/view_index.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <numeric>
#include <utility>

#include <Eigen/Eigenvalues>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

constexpr std::size_t kNone = std::numeric_limits<std::size_t>::max();

// sum_k max(0, |a_k - b_k| - 1)^2 over `padded` int16 codes (a multiple of 8), stopping
// after the first group of 8 axes at which the sum reaches `limit`. Codes are within
// +-kMaxCode, so differences fit int16 and 64 squares fit int32.
inline std::int64_t GapSquares(const std::int16_t* a, const std::int16_t* b, int padded,
                               std::int64_t limit) {
  std::int64_t sum = 0;
#if defined(__SSE2__)
  const __m128i ones = _mm_set1_epi16(1);
  const __m128i zero = _mm_setzero_si128();
  __m128i acc = _mm_setzero_si128();
  for (int k = 0; k < padded; k += 8) {
    __m128i va, vb;
    std::memcpy(&va, a + k, sizeof(va));
    std::memcpy(&vb, b + k, sizeof(vb));
    const __m128i d = _mm_sub_epi16(va, vb);
    const __m128i ad = _mm_max_epi16(d, _mm_sub_epi16(zero, d));  // |d|
    const __m128i gap = _mm_subs_epu16(ad, ones);                 // max(0, |d| - 1)
    acc = _mm_add_epi32(acc, _mm_madd_epi16(gap, gap));           // pairs of squares
    alignas(16) std::int32_t lanes[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(lanes), acc);
    sum = static_cast<std::int64_t>(lanes[0]) + lanes[1] + lanes[2] + lanes[3];
    if (sum >= limit) return sum;
  }
#else
  for (int k = 0; k < padded; ++k) {
    const int gap = std::max(0, std::abs(int{a[k]} - int{b[k]}) - 1);
    sum += static_cast<std::int64_t>(gap) * gap;
    if ((k & 7) == 7 && sum >= limit) return sum;
  }
#endif
  return sum;
}

}  // namespace

void ViewIndex::Clear() { *this = ViewIndex(); }

void ViewIndex::Fit(const float* rows, std::size_t n) {
  const std::size_t d = feature_size_;
  const std::size_t stride = n > kMaxFitRows ? (n + kMaxFitRows - 1) / kMaxFitRows : 1;
  std::size_t used = 0;
  Eigen::VectorXd mean = Eigen::VectorXd::Zero(static_cast<Eigen::Index>(d));
  for (std::size_t r = 0; r < n; r += stride, ++used) {
    mean += Eigen::Map<const Eigen::VectorXf>(rows + r * d, static_cast<Eigen::Index>(d))
                .cast<double>();
  }
  Eigen::MatrixXd cov =
      Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(d), static_cast<Eigen::Index>(d));
  if (used > 0) {
    mean /= static_cast<double>(used);
    Eigen::VectorXd x(static_cast<Eigen::Index>(d));
    for (std::size_t r = 0; r < n; r += stride) {
      x = Eigen::Map<const Eigen::VectorXf>(rows + r * d, static_cast<Eigen::Index>(d))
              .cast<double>() -
          mean;
      if (!x.allFinite()) continue;  // a damaged row must not spoil the axes
      cov.selfadjointView<Eigen::Lower>().rankUpdate(x);
    }
    cov = cov.selfadjointView<Eigen::Lower>();
    cov /= static_cast<double>(used);
  }
  if (!mean.allFinite()) mean.setZero();
  // Principal axes: eigenvectors of the covariance, largest eigenvalue first. Any
  // orthonormal rows keep the bound exact; the leading axes make it tight.
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(cov);
  Eigen::MatrixXd basis(dims_, static_cast<Eigen::Index>(d));
  const double total = cov.trace();
  double kept = 0.0;
  if (eig.info() == Eigen::Success && std::isfinite(total)) {
    for (int k = 0; k < dims_; ++k) {
      const Eigen::Index col = static_cast<Eigen::Index>(d) - 1 - k;
      Eigen::VectorXd v = eig.eigenvectors().col(col);
      // Deterministic sign: the largest-magnitude entry positive.
      Eigen::Index arg = 0;
      v.cwiseAbs().maxCoeff(&arg);
      if (v[arg] < 0) v = -v;
      basis.row(k) = v.transpose();
      kept += std::max(0.0, eig.eigenvalues()[col]);
    }
  } else {
    // No usable covariance: the first `dims` coordinate axes (still orthonormal).
    basis.setZero();
    for (int k = 0; k < dims_; ++k) basis(k, k) = 1.0;
  }
  basis_ = std::move(basis);
  mean_ = std::move(mean);
  explained_variance_ = total > 0 ? std::min(1.0, kept / total) : 0.0;
  fitted_size_ = n;
  ++fits_;
}

bool ViewIndex::Encode(const float* x, std::int16_t* codes) const {
  const Eigen::VectorXd v =
      Eigen::Map<const Eigen::VectorXf>(x, static_cast<Eigen::Index>(feature_size_))
          .cast<double>() -
      mean_;
  const Eigen::VectorXd p = basis_ * v;
  std::fill(codes, codes + padded_dims_, std::int16_t{0});
  if (!p.allFinite()) return false;
  for (int k = 0; k < dims_; ++k) {
    const double c = std::clamp(p[k] / step_, -double{kMaxCode}, double{kMaxCode});
    codes[k] = static_cast<std::int16_t>(std::lround(c));
  }
  return true;
}

void ViewIndex::Build(const float* rows, const std::uint64_t* ids, std::size_t n,
                      std::size_t feature_size, int dims, double step) {
  if (feature_size == 0) throw Error("ViewIndex::Build: feature size 0");
  const int max_dims = static_cast<int>(std::min<std::size_t>(feature_size, kMaxDims));
  if (dims < 1 || dims > max_dims) {
    throw Error(StrCat("ViewIndex::Build: dims must be in 1..", max_dims, ", got ", dims));
  }
  if (!(std::isfinite(step) && step > 0)) {
    throw Error(
        StrCat("ViewIndex::Build: the quantisation step must be finite and > 0, got ", step));
  }
  if (n >= std::numeric_limits<std::uint32_t>::max()) {
    throw Error(StrCat("ViewIndex::Build: ", n, " vectors are more than the index holds"));
  }
  const std::size_t fits = fits_, rebuilds = rebuilds_;
  Clear();
  fits_ = fits;  // the counters run over the index's whole life
  rebuilds_ = rebuilds;
  feature_size_ = feature_size;
  dims_ = dims;
  padded_dims_ = (dims + 7) / 8 * 8;
  tree_dims_ = std::min(dims, kMaxTreeDims);
  step_ = step;
  Fit(rows, n);
  // Entries in id order.
  std::vector<std::uint32_t> order(n);
  std::iota(order.begin(), order.end(), 0u);
  std::sort(order.begin(), order.end(),
            [&](std::uint32_t a, std::uint32_t b) { return ids[a] < ids[b]; });
  const std::size_t pd = static_cast<std::size_t>(padded_dims_);
  std::vector<std::uint64_t> sorted_ids(n);
  std::vector<std::uint32_t> sorted_rows(n);
  std::vector<std::int16_t> codes(n * pd);
  for (std::size_t i = 0; i < n; ++i) {
    sorted_ids[i] = ids[order[i]];
    sorted_rows[i] = order[i];
    Encode(rows + static_cast<std::size_t>(order[i]) * feature_size, codes.data() + i * pd);
  }
  BuildTree(std::move(sorted_ids), std::move(sorted_rows), std::move(codes));
}

std::size_t ViewIndex::AddSlot(std::uint32_t row, const std::int16_t* codes) {
  const std::size_t slot = rows_.size();
  codes_.insert(codes_.end(), codes, codes + padded_dims_);
  rows_.push_back(row);
  alive_.push_back(1);
  return slot;
}

void ViewIndex::BuildTree(std::vector<std::uint64_t> ids, std::vector<std::uint32_t> rows,
                          std::vector<std::int16_t> codes) {
  ++rebuilds_;
  const std::size_t n = ids.size();
  const std::size_t pd = static_cast<std::size_t>(padded_dims_);
  std::vector<std::uint32_t> perm(n);
  std::iota(perm.begin(), perm.end(), 0u);
  nodes_.clear();
  box_lo_.clear();
  box_hi_.clear();
  codes_.clear();
  rows_.clear();
  alive_.clear();
  tail_ids_.clear();
  dead_ = 0;
  codes_.reserve(n * pd);
  rows_.reserve(n);
  alive_.reserve(n);
  nodes_.reserve(2 * (n / (kLeafSize / 2) + 1));
  if (n > 0) BuildNode(0, static_cast<std::uint32_t>(n), perm, codes, ids);
  // Leaves in node order are depth-first; BuildNode left each leaf's range of perm in its
  // begin/end, which become slot ranges here.
  by_id_.assign(n, {0, 0});
  for (Node& node : nodes_) {
    if (node.left >= 0) continue;
    const auto first = static_cast<std::uint32_t>(rows_.size());
    for (std::uint32_t i = node.begin; i < node.end; ++i) {
      const std::uint32_t src = perm[i];
      const std::size_t slot =
          AddSlot(rows[src], codes.data() + static_cast<std::size_t>(src) * pd);
      by_id_[src] = {ids[src], static_cast<std::uint32_t>(slot)};  // input in id order
    }
    node.begin = first;
    node.end = static_cast<std::uint32_t>(rows_.size());
  }
  tree_slots_ = rows_.size();
  live_ = n;
  built_size_ = n;
}

std::int32_t ViewIndex::BuildNode(std::uint32_t begin, std::uint32_t end,
                                  std::vector<std::uint32_t>& perm,
                                  const std::vector<std::int16_t>& codes,
                                  const std::vector<std::uint64_t>& ids) {
  const std::size_t pd = static_cast<std::size_t>(padded_dims_);
  const std::size_t t = static_cast<std::size_t>(tree_dims_);
  const auto index = static_cast<std::int32_t>(nodes_.size());
  nodes_.push_back(Node{begin, end, -1, -1});
  std::vector<std::int16_t> lo(t, std::numeric_limits<std::int16_t>::max());
  std::vector<std::int16_t> hi(t, std::numeric_limits<std::int16_t>::min());
  for (std::uint32_t i = begin; i < end; ++i) {
    const std::int16_t* p = codes.data() + static_cast<std::size_t>(perm[i]) * pd;
    for (std::size_t k = 0; k < t; ++k) {
      lo[k] = std::min(lo[k], p[k]);
      hi[k] = std::max(hi[k], p[k]);
    }
  }
  box_lo_.insert(box_lo_.end(), lo.begin(), lo.end());
  box_hi_.insert(box_hi_.end(), hi.begin(), hi.end());
  if (end - begin <= kLeafSize) return index;
  std::size_t dim = 0;
  int widest = -1;
  for (std::size_t k = 0; k < t; ++k) {
    const int w = int{hi[k]} - int{lo[k]};
    if (w > widest) {
      widest = w;
      dim = k;
    }
  }
  // Median split on the widest axis, ties by id, so the split is a function of the data
  // only (all codes equal: the split goes by id and the boxes stay valid).
  const std::uint32_t mid = begin + (end - begin) / 2;
  auto key_less = [&](std::uint32_t a, std::uint32_t b) {
    const std::int16_t za = codes[static_cast<std::size_t>(a) * pd + dim];
    const std::int16_t zb = codes[static_cast<std::size_t>(b) * pd + dim];
    return za != zb ? za < zb : ids[a] < ids[b];
  };
  std::nth_element(perm.begin() + begin, perm.begin() + mid, perm.begin() + end, key_less);
  const std::int32_t left = BuildNode(begin, mid, perm, codes, ids);
  const std::int32_t right = BuildNode(mid, end, perm, codes, ids);
  nodes_[static_cast<std::size_t>(index)].left = left;
  nodes_[static_cast<std::size_t>(index)].right = right;
  return index;
}

void ViewIndex::VisitLeaves(const std::int16_t* q, std::int64_t limit,
                            const std::function<void(std::size_t, std::size_t)>& scan) const {
  // Depth-first over the tree; a node is skipped when the bound from its box on the
  // tree's axes reaches the limit.
  if (nodes_.empty()) return;
  const std::size_t t = static_cast<std::size_t>(tree_dims_);
  constexpr int kStack = 128;
  std::int32_t stack[kStack];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const std::size_t ni = static_cast<std::size_t>(stack[--top]);
    const Node& node = nodes_[ni];
    const std::int16_t* lo = box_lo_.data() + ni * t;
    const std::int16_t* hi = box_hi_.data() + ni * t;
    std::int64_t box = 0;
    for (std::size_t k = 0; k < t; ++k) {
      const int outside = std::max({int{lo[k]} - int{q[k]}, int{q[k]} - int{hi[k]}, 0});
      const std::int64_t gap = std::max(0, outside - 1);
      box += gap * gap;
    }
    if (box >= limit) continue;
    if (node.left < 0) {
      scan(node.begin, node.end);
      continue;
    }
    OMNICML_CHECK(top + 2 <= kStack) << "kd-tree deeper than its stack";
    stack[top++] = node.right;
    stack[top++] = node.left;
  }
}

std::size_t ViewIndex::Candidates(const float* query, double radius,
                                  std::vector<std::size_t>* rows_out) const {
  if (!built() || !(radius > 0)) return 0;
  const std::size_t pd = static_cast<std::size_t>(padded_dims_);
  std::vector<std::int16_t> qc(pd);
  if (!Encode(query, qc.data())) return 0;  // E is NaN or infinite for every vector
  // Prune iff s^2 sum gap^2 >= (radius + slack)^2, i.e. sum gap^2 >= limit (integers).
  const double r = radius * (1.0 + 1e-3);
  const double bound = std::ceil((r / step_) * (r / step_));
  const std::int64_t limit =
      bound >= 4e18 ? std::numeric_limits<std::int64_t>::max() : static_cast<std::int64_t>(bound);
  const std::int16_t* q = qc.data();
  std::size_t bounded = 0;
  const int pd_int = padded_dims_;
  auto finish = [&](std::size_t slot, std::int64_t first8) {
    // The axes after the first 8, for a vector the first 8 did not reject.
    const std::int64_t rest =
        pd_int > 8 ? GapSquares(q + 8, codes_.data() + slot * pd + 8, pd_int - 8, limit - first8)
                   : 0;
    if (first8 + rest < limit) rows_out->push_back(rows_[slot]);
  };
  auto scan = [&](std::size_t first, std::size_t last) {
    std::size_t slot = first;
#if defined(__SSE2__)
    // Four vectors at a time through the first 8 axes, without a branch per vector:
    // most are rejected there (the leading axes carry most of the distance).
    const std::int32_t limit32 = static_cast<std::int32_t>(
        std::min<std::int64_t>(limit, std::numeric_limits<std::int32_t>::max()));
    const __m128i ones = _mm_set1_epi16(1);
    const __m128i zero = _mm_setzero_si128();
    const __m128i limit_v = _mm_set1_epi32(limit32);
    __m128i qv;
    std::memcpy(&qv, q, sizeof(qv));
    auto first8 = [&](std::size_t at) {
      __m128i v;
      std::memcpy(&v, codes_.data() + at * pd, sizeof(v));
      const __m128i d = _mm_sub_epi16(v, qv);
      const __m128i gap = _mm_subs_epu16(_mm_max_epi16(d, _mm_sub_epi16(zero, d)), ones);
      return _mm_madd_epi16(gap, gap);
    };
    for (; slot + 4 <= last; slot += 4) {
      const __m128i m0 = first8(slot), m1 = first8(slot + 1);
      const __m128i m2 = first8(slot + 2), m3 = first8(slot + 3);
      const __m128i s01 = _mm_add_epi32(_mm_unpacklo_epi32(m0, m1), _mm_unpackhi_epi32(m0, m1));
      const __m128i s23 = _mm_add_epi32(_mm_unpacklo_epi32(m2, m3), _mm_unpackhi_epi32(m2, m3));
      const __m128i total =
          _mm_add_epi32(_mm_unpacklo_epi64(s01, s23), _mm_unpackhi_epi64(s01, s23));
      unsigned below =
          static_cast<unsigned>(_mm_movemask_ps(_mm_castsi128_ps(_mm_cmplt_epi32(total, limit_v))));
      bounded += 4;
      if (below == 0) continue;
      alignas(16) std::int32_t sums[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(sums), total);
      while (below != 0) {
        const int lane = __builtin_ctz(below);
        below &= below - 1;
        const std::size_t at = slot + static_cast<std::size_t>(lane);
        if (alive_[at]) finish(at, sums[lane]);
      }
    }
#endif
    for (; slot < last; ++slot) {
      ++bounded;
      const std::int64_t first = GapSquares(q, codes_.data() + slot * pd, 8, limit);
      if (first < limit && alive_[slot]) finish(slot, first);
    }
  };
  VisitLeaves(q, limit, scan);
  scan(tree_slots_, rows_.size());
  return bounded;
}

void ViewIndex::Insert(std::uint64_t id, std::size_t row, const float* features) {
  OMNICML_CHECK(built()) << "ViewIndex::Insert before Build";
  OMNICML_CHECK(tail_ids_.empty() || tail_ids_.back() < id) << "ids must increase";
  OMNICML_CHECK(by_id_.empty() || by_id_.back().first < id) << "ids must increase";
  std::vector<std::int16_t> codes(static_cast<std::size_t>(padded_dims_));
  Encode(features, codes.data());
  AddSlot(static_cast<std::uint32_t>(row), codes.data());
  tail_ids_.push_back(id);
  ++live_;
}

std::size_t ViewIndex::FindSlot(std::uint64_t id) const {
  std::size_t slot = kNone;
  const auto it =
      std::lower_bound(by_id_.begin(), by_id_.end(), std::make_pair(id, std::uint32_t{0}));
  if (it != by_id_.end() && it->first == id) {
    slot = it->second;
  } else {
    const auto t = std::lower_bound(tail_ids_.begin(), tail_ids_.end(), id);
    if (t != tail_ids_.end() && *t == id)
      slot = TailSlot(static_cast<std::size_t>(t - tail_ids_.begin()));
  }
  return slot != kNone && alive_[slot] ? slot : kNone;
}

bool ViewIndex::Remove(std::uint64_t id) {
  if (!built()) return false;
  const std::size_t slot = FindSlot(id);
  if (slot == kNone) return false;
  alive_[slot] = 0;
  ++dead_;
  --live_;
  return true;
}

bool ViewIndex::SetRow(std::uint64_t id, std::size_t row) {
  if (!built()) return false;
  const std::size_t slot = FindSlot(id);
  if (slot == kNone) return false;
  rows_[slot] = static_cast<std::uint32_t>(row);
  return true;
}

ViewIndex::Maintenance ViewIndex::Pending() const {
  if (!built()) return Maintenance::kNone;
  const std::size_t changes = tail_ids_.size() + dead_;
  if (changes <= std::max(kMinRebuild, built_size_ / kRebuildDivisor)) return Maintenance::kNone;
  if (live_ >= 2 * fitted_size_ || 2 * live_ <= fitted_size_) return Maintenance::kRefit;
  return Maintenance::kRetree;
}

void ViewIndex::Retree() {
  if (!built()) return;
  // The stored codes of the live vectors, tree then tail: in id order.
  const std::size_t pd = static_cast<std::size_t>(padded_dims_);
  std::vector<std::uint64_t> ids;
  std::vector<std::uint32_t> rws;
  std::vector<std::int16_t> codes;
  ids.reserve(live_);
  rws.reserve(live_);
  codes.reserve(live_ * pd);
  auto take = [&](std::uint64_t id, std::size_t slot) {
    if (!alive_[slot]) return;
    ids.push_back(id);
    rws.push_back(rows_[slot]);
    codes.insert(codes.end(), codes_.begin() + static_cast<std::ptrdiff_t>(slot * pd),
                 codes_.begin() + static_cast<std::ptrdiff_t>((slot + 1) * pd));
  };
  for (const auto& [id, slot] : by_id_) take(id, slot);
  for (std::size_t i = 0; i < tail_ids_.size(); ++i) take(tail_ids_[i], TailSlot(i));
  BuildTree(std::move(ids), std::move(rws), std::move(codes));
}

std::vector<std::pair<std::uint64_t, std::size_t>> ViewIndex::Entries() const {
  std::vector<std::pair<std::uint64_t, std::size_t>> out;
  for (const auto& [id, slot] : by_id_) {
    if (alive_[slot]) out.emplace_back(id, rows_[slot]);
  }
  for (std::size_t i = 0; i < tail_ids_.size(); ++i) {
    if (alive_[TailSlot(i)]) out.emplace_back(tail_ids_[i], rows_[TailSlot(i)]);
  }
  return out;
}

void ViewIndex::CheckInvariants() const {
  if (!built()) return;
  const std::size_t pd = static_cast<std::size_t>(padded_dims_);
  const std::size_t t = static_cast<std::size_t>(tree_dims_);
  const std::size_t slots = rows_.size();
  OMNICML_CHECK(codes_.size() == slots * pd && alive_.size() == slots) << "slot arrays";
  OMNICML_CHECK(slots == tree_slots_ + tail_ids_.size() && by_id_.size() == tree_slots_)
      << "slot counts";
  std::size_t alive = 0;
  for (std::uint8_t a : alive_) alive += a;
  OMNICML_CHECK(alive == live_ && slots == live_ + dead_)
      << "live count " << live_ << " but " << alive << " live slots";
  for (std::size_t i = 1; i < by_id_.size(); ++i)
    OMNICML_CHECK(by_id_[i - 1].first < by_id_[i].first) << "by_id_ order";
  for (std::size_t i = 1; i < tail_ids_.size(); ++i)
    OMNICML_CHECK(tail_ids_[i - 1] < tail_ids_[i]) << "tail order";
  OMNICML_CHECK(by_id_.empty() || tail_ids_.empty() || by_id_.back().first < tail_ids_.front())
      << "tail ids must follow the tree's";
  std::vector<std::uint8_t> seen(tree_slots_, 0);
  for (const auto& [id, slot] : by_id_) {
    OMNICML_CHECK(slot < tree_slots_ && !seen[slot]) << "slot of view " << id;
    seen[slot] = 1;
  }
  // Every slot of a leaf lies inside the boxes of the leaf and of its ancestors.
  std::vector<std::int32_t> parent(nodes_.size(), -1);
  for (std::size_t ni = 0; ni < nodes_.size(); ++ni) {
    if (nodes_[ni].left >= 0) {
      parent[static_cast<std::size_t>(nodes_[ni].left)] = static_cast<std::int32_t>(ni);
      parent[static_cast<std::size_t>(nodes_[ni].right)] = static_cast<std::int32_t>(ni);
    }
  }
  std::size_t in_leaves = 0;
  for (std::size_t ni = 0; ni < nodes_.size(); ++ni) {
    if (nodes_[ni].left >= 0) continue;
    in_leaves += nodes_[ni].end - nodes_[ni].begin;
    for (std::uint32_t slot = nodes_[ni].begin; slot < nodes_[ni].end; ++slot) {
      for (std::int32_t a = static_cast<std::int32_t>(ni); a >= 0;
           a = parent[static_cast<std::size_t>(a)]) {
        const std::size_t ai = static_cast<std::size_t>(a);
        for (std::size_t k = 0; k < t; ++k) {
          const std::int16_t v = codes_[static_cast<std::size_t>(slot) * pd + k];
          OMNICML_CHECK(v >= box_lo_[ai * t + k] && v <= box_hi_[ai * t + k])
              << "slot " << slot << " outside the box of node " << ai;
        }
      }
    }
  }
  OMNICML_CHECK(in_leaves == tree_slots_) << "leaves cover " << in_leaves << " of " << tree_slots_;
}

std::size_t ViewIndex::MemoryBytes() const {
  return codes_.capacity() * sizeof(std::int16_t) + rows_.capacity() * sizeof(std::uint32_t) +
         alive_.capacity() + nodes_.capacity() * sizeof(Node) +
         (box_lo_.capacity() + box_hi_.capacity()) * sizeof(std::int16_t) +
         by_id_.capacity() * sizeof(std::pair<std::uint64_t, std::uint32_t>) +
         tail_ids_.capacity() * sizeof(std::uint64_t) +
         static_cast<std::size_t>(basis_.size() + mean_.size()) * sizeof(double);
}

}  // namespace omnicml
