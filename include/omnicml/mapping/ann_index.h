// Approximate candidate index for radius search over the views' feature vectors
// (docs/design.md "Place retrieval at scale", "Approximate retrieval").
//
// A hierarchical navigable small-world graph [Malkov, Yashunin 2018] over the feature
// rows, L2 distance, from hnswlib 0.6.2 (Debian libhnswlib-dev, header-only; used only in
// ann_index.cc). Nearest(q, k) returns (approximately) the k live vectors nearest to q by
// squared L2; EnvironmentModel turns that into a radius query by doubling k until the
// farthest returned vector is beyond the radius, then computes the extractor's exact
// distance for the returned vectors only. Unlike view_index.h it is NOT exact: a true
// match the graph search does not reach is missed (recall measured in
// docs/results.md "Approximate retrieval").
//
// Lifecycle: Reset (empty graph with parameters) -> Insert / Remove in any order ->
// Clear. Vectors are labelled by the caller's ids (the model's view ids), so they stay
// valid when the caller's rows move. A removed vector is marked deleted (never returned;
// the graph still routes through it) and its slot is reused, lowest slot first, by the
// next Insert, which re-links it as a new point (hnswlib updatePoint); the graph never
// holds more slots than the most vectors it held at once.
//
// Determinism: single-threaded insertion, a fixed level seed, slots reused in a fixed
// order: the same sequence of calls gives the same graph and the same answers, on any
// machine with the same build. Inserting the same vectors in the same order into an empty
// index gives the same graph as it did the first time; after removals the graph depends
// on the history (which slots were reused), which a fresh build does not reproduce.
//
// Thread-safety: thread-compatible. Nearest is const and may run concurrently (hnswlib's
// visited-list pool is locked); Insert/Remove/Reset/Clear/assignment need exclusive
// access.
#ifndef OMNICML_MAPPING_ANN_INDEX_H_
#define OMNICML_MAPPING_ANN_INDEX_H_

#include <cstddef>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

namespace omnicml {

class AnnIndex {
 public:
  struct Params {
    int m = 16;                 // graph degree M (links per node and layer; 2 M on layer 0)
    int ef_construction = 128;  // candidate list while inserting
    std::uint64_t seed = 19;    // level generator seed
  };

  AnnIndex();
  ~AnnIndex();
  // Deep copies (the copy answers every query as the original does).
  AnnIndex(const AnnIndex& other);
  AnnIndex& operator=(const AnnIndex& other);
  AnnIndex(AnnIndex&& other) noexcept;
  AnnIndex& operator=(AnnIndex&& other) noexcept;

  // Empties the index and sets it up for vectors of `dims` floats with room for
  // `capacity` of them (grown by doubling as needed). Throws omnicml::Error unless
  // dims >= 1, 2 <= m <= 64, ef_construction >= 1.
  void Reset(std::size_t dims, const Params& params, std::size_t capacity);
  // Adds a vector (dims floats). Precondition: built(), id not live (OMNICML_CHECK).
  void Insert(std::uint64_t id, const float* x);
  // Removes the vector with this id; false if absent.
  bool Remove(std::uint64_t id);
  // Up to k live vectors nearest to q (approximately), as (squared L2 distance in float,
  // id) sorted by (distance, id); fewer when the index holds fewer. Searches with a
  // candidate list of max(ef, k) (the search's time against its recall).
  void Nearest(const float* q, std::size_t k, std::size_t ef,
               std::vector<std::pair<float, std::uint64_t>>* out) const;

  bool built() const { return impl_ != nullptr; }
  std::size_t size() const;   // live vectors
  std::size_t slots() const;  // graph nodes, live or deleted
  std::size_t dims() const { return dims_; }
  const Params& params() const { return params_; }
  void Clear();
  std::size_t MemoryBytes() const;
  // Ids of the live vectors, sorted; for consistency checks.
  std::vector<std::uint64_t> Ids() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::size_t dims_ = 0;
  Params params_;
};

}  // namespace omnicml

#endif  // OMNICML_MAPPING_ANN_INDEX_H_
