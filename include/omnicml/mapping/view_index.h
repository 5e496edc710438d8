// Candidate index for exact radius search over the views' feature vectors
// (docs/design.md "Place retrieval at scale").
//
// The question EnvironmentModel asks is a radius query: every stored vector x_i with
// E(y, x_i) < e_max. This index answers the cheaper question "which x_i can possibly be
// that close?" without ever dropping a true answer, and the caller computes the exact E
// for those candidates only.
//
// The bound. Let P be an m x d matrix with orthonormal rows (P P^T = I_m) and mu a
// vector; z = P (x - mu). For any a, b:
//   ||P (a - b)||_2 <= ||a - b||_2 <= ||a - b||_1
// (Bessel's inequality; the second holds for every vector). So for every distance that
// is at least the L2 norm of the difference (the Fourier signature's L2 and L1), the
// projected distance ||z_y - z_i||_2 is a lower bound of E(y, x_i): a vector whose
// projected distance is >= e_max cannot match and is skipped. P holds the m leading
// principal axes of the stored vectors (PCA of their covariance), so the bound captures
// as much of the distance as m dimensions can.
//
// The spatial structure. The projected points live in a kd-tree [Bentley 1975] with
// buckets of up to kLeafSize points, split at the median of the widest of the leading
// min(m, kMaxTreeDims) coordinates of each node's bounding box (the axes with the most
// variance; a kd-tree does not prune in more dimensions than that). A node whose box lies
// at distance >= e_max from z_y in those coordinates is skipped whole (Friedman, Bentley,
// Finkel 1977: the box distance is a lower bound of the projected distance to every
// point in it). How much it prunes depends on the data: on descriptors whose variance
// is spread over many axes (measured: real Fourier signatures) few boxes lie that far
// and the per-point bound does the work (docs/design.md "Place retrieval at scale").
//
// Quantised storage. The projections are stored as 16-bit integer codes
// c(z) = round(clamp(z / s, -kMaxCode, kMaxCode)) with a step s set at Build (the model uses
// e_max / 256). Since c is 1-Lipschitz in z / s up to the rounding of +-1/2,
//   |z_a - z_b| >= s (|c(z_a) - c(z_b)| - 1)   for every axis, clamped or not,
// so s^2 sum_k max(0, |c_ak - c_bk| - 1)^2 is still a lower bound of ||P (a - b)||^2, and
// it is computed exactly in integers (8 axes per SSE2 multiply-add). The loss is one step
// per axis, small against e_max. A point is pruned when this bound is >= (radius + Slack)^2,
// Slack = 1e-3 radius, which covers the rounding of the double projection and of the
// extractor's float sums (~1e-6 relative) with room to spare. Axes are summed in order
// of decreasing variance, 8 at a time, and the sum stops as soon as it reaches the
// limit: most vectors are rejected after the first 8 axes.
//
// Maintenance. The tree is built over a snapshot. Vectors inserted later go to a tail
// that every query scans (projected distance only, m floats each); removed vectors are
// marked dead where they are. When tail + dead exceed
// max(kMinRebuild, size at the last build / kRebuildDivisor), Pending() asks the caller
// to rebuild the tree from the stored projections (Retree: O(n log n), no
// re-projection) or, when the number of vectors has doubled or halved since P was
// fitted, to Build anew (fit and project every vector: O(n d m) plus the tree). The
// caller does this inside its mutating calls, never in a query, so the cost of a
// change is O(log n) amortised, with one rebuild every n / kRebuildDivisor changes.
// Each entry also records its row in the caller's contiguous array, which the caller
// keeps up to date (SetRow) when rows move.
//
// Determinism: the same sequence of calls gives the same P, the same tree and the same
// candidate lists (PCA by Eigen's SelfAdjointEigenSolver on a fixed subsample, ties in
// the median split broken by id).
//
// Thread-safety: thread-compatible; Candidates is const and keeps no scratch state.
#ifndef OMNICML_MAPPING_VIEW_INDEX_H_
#define OMNICML_MAPPING_VIEW_INDEX_H_

#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include <Eigen/Core>

namespace omnicml {

class ViewIndex {
 public:
  static constexpr std::size_t kLeafSize = 32;  // points per kd-tree bucket, at most
  static constexpr int kMaxTreeDims = 8;        // the tree splits on the leading axes only
  static constexpr int kMaxDims = 64;           // projection dimensions, at most
  static constexpr int kMaxCode = 2047;         // |code| <= kMaxCode: 64 squared gaps fit int32
  static constexpr std::size_t kMinRebuild = 256;
  static constexpr std::size_t kRebuildDivisor = 8;
  // PCA is fitted on at most this many rows (a deterministic stride over all rows).
  static constexpr std::size_t kMaxFitRows = 32768;

  ViewIndex() = default;

  // Fits P (the `dims` leading principal axes) and mu to the rows, stores every row's
  // codes with quantisation step `step` (distance units, > 0) and builds the tree. rows:
  // n x feature_size floats, row r belongs to ids[r]; ids unique. Throws omnicml::Error
  // unless 1 <= dims <= min(feature_size, kMaxDims), step is finite and > 0, and
  // n < 2^32.
  void Build(const float* rows, const std::uint64_t* ids, std::size_t n, std::size_t feature_size,
             int dims, double step);

  // Adds a vector: ids must be larger than every id ever added (the model's are);
  // `row` is its row in the caller's array. It joins the tail. Precondition: built().
  void Insert(std::uint64_t id, std::size_t row, const float* features);
  // Removes the vector with this id; false if absent.
  bool Remove(std::uint64_t id);
  // The vector with this id now lives in row `row` of the caller's array. Returns false
  // if the id is absent.
  bool SetRow(std::uint64_t id, std::size_t row);

  // Appends to `rows_out` the row of every live vector x whose quantised projected bound
  // is below radius + Slack: a superset of those with ||query - x||_2 < radius, hence of
  // those with E < radius for every distance E >= L2. A query with a non-finite
  // projection gets no candidates (no distance to it is below any radius). Order: tree
  // order, then the tail (deterministic, not sorted). query: feature_size floats.
  // Returns the number of vectors whose bound was computed (the others were pruned with
  // their kd-tree node), for statistics.
  std::size_t Candidates(const float* query, double radius,
                         std::vector<std::size_t>* rows_out) const;

  // What the caller must do after Insert/Remove (see "Maintenance" in the file comment):
  // nothing, Retree(), or Build() anew over all its rows.
  enum class Maintenance : std::uint8_t { kNone, kRetree, kRefit };
  Maintenance Pending() const;
  // Rebuilds the tree over the stored codes of the live vectors (tail included).
  void Retree();

  bool built() const { return dims_ > 0; }
  int dims() const { return dims_; }
  double step() const { return step_; }
  std::size_t size() const { return live_; }
  std::size_t tail_size() const { return tail_ids_.size(); }
  std::size_t dead() const { return dead_; }
  // Number of tree builds and projection fits since construction (Clear resets them), for
  // tests and benchmarks of the maintenance cost.
  std::size_t rebuilds() const { return rebuilds_; }
  std::size_t fits() const { return fits_; }
  // Fraction of the stored vectors' variance (trace of the covariance at the last fit)
  // that P keeps, in [0, 1].
  double explained_variance() const { return explained_variance_; }
  void Clear();
  std::size_t MemoryBytes() const;

  // Every live (id, row) pair sorted by id; for consistency checks.
  std::vector<std::pair<std::uint64_t, std::size_t>> Entries() const;
  // Checks the tree (boxes contain their points, every id once); throws
  // omnicml::InternalError.
  void CheckInvariants() const;

 private:
  // A kd-tree node; leaves own slots [begin, end).
  struct Node {
    std::uint32_t begin = 0, end = 0;
    std::int32_t left = -1, right = -1;  // children; -1 for a leaf
  };
  void Fit(const float* rows, std::size_t n);
  // Codes of x (padded_dims_ int16, zero beyond dims_); false if the projection is not
  // finite (the codes are then zero).
  bool Encode(const float* x, std::int16_t* codes) const;
  // Builds the tree over entries given as (id, row, codes) in id order.
  void BuildTree(std::vector<std::uint64_t> ids, std::vector<std::uint32_t> rows,
                 std::vector<std::int16_t> codes);
  std::int32_t BuildNode(std::uint32_t begin, std::uint32_t end, std::vector<std::uint32_t>& perm,
                         const std::vector<std::int16_t>& codes,
                         const std::vector<std::uint64_t>& ids);
  // Appends a slot; returns its number.
  std::size_t AddSlot(std::uint32_t row, const std::int16_t* codes);
  std::size_t TailSlot(std::size_t t) const { return tree_slots_ + t; }
  // Slot of a live id, or SIZE_MAX.
  std::size_t FindSlot(std::uint64_t id) const;
  // Calls scan(begin, end) for the slots of every leaf whose box is not pruned for the
  // query codes q under `limit` (sum of squared code gaps), depth-first.
  void VisitLeaves(const std::int16_t* q, std::int64_t limit,
                   const std::function<void(std::size_t, std::size_t)>& scan) const;

  std::size_t feature_size_ = 0;
  int dims_ = 0;
  int padded_dims_ = 0;    // dims_ rounded up to a multiple of 8
  int tree_dims_ = 0;      // leading dimensions the tree splits and bounds on
  double step_ = 0.0;      // quantisation step s, distance units
  Eigen::MatrixXd basis_;  // dims x feature_size, orthonormal rows
  Eigen::VectorXd mean_;   // feature_size
  double explained_variance_ = 0.0;
  std::size_t fitted_size_ = 0;  // live vectors when P was fitted
  std::size_t built_size_ = 0;   // live vectors when the tree was built

  // Slots: [0, tree_slots_) the tree's leaves in depth-first order, then the tail.
  std::vector<std::int16_t> codes_;  // slots x padded_dims_
  std::vector<std::uint32_t> rows_;  // per slot: the caller's row
  std::vector<std::uint8_t> alive_;  // per slot: 1 while it holds a live vector
  std::size_t tree_slots_ = 0;
  std::vector<Node> nodes_;                    // nodes_[0] is the root
  std::vector<std::int16_t> box_lo_, box_hi_;  // nodes x tree_dims_, in codes
  // (id, slot) of the tree's vectors sorted by id, for Remove/SetRow.
  std::vector<std::pair<std::uint64_t, std::uint32_t>> by_id_;
  // Tail: ids inserted since the last build, in id order; tail vector t is in slot
  // TailSlot(t) (dead slots stay until the next build).
  std::vector<std::uint64_t> tail_ids_;
  std::size_t dead_ = 0;  // dead slots (tree and tail)

  std::size_t live_ = 0;
  std::size_t rebuilds_ = 0;
  std::size_t fits_ = 0;
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_VIEW_INDEX_H_
