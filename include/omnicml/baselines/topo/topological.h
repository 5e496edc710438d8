// Topological localization by colour-histogram place recognition, the baseline of
// Ulrich & Nourbakhsh [UN] (docs/design.md "Baselines from the seeds").
//
// The environment is an adjacency map of places (a graph: each place knows its
// neighbours). Every place holds reference images taken from a labelled log (frames whose
// ground-truth position lies in the place). An input image is described by six 1-D
// colour histograms (ColorHistogram: H, L, S, then R, G, B or r, g, b; see
// color_histogram.h). Then, [UN] section 4:
//   1. Candidates: the reference images of the believed place and of its neighbours
//      (all places while nothing is believed yet).
//   2. Per band b: the nearest neighbour (NN) among the candidates under the histogram
//      distance (Jeffrey divergence by default); the band votes for the NN's place.
//   3. Per band confidence C_b = 1 - d_nn / d_other, where d_other is the smallest
//      distance to a candidate image of any other place (C_b = 1 when the candidates hold
//      no other place). A band takes part only if C_b >= band_threshold[b].
//   4. Unanimous voting: no band takes part -> kUncertain; the taking-part bands name
//      different places -> kConfused; they all name place p -> the overall confidence is
//      the sum of their C_b, and the image is classified as p (kConfident) only if it
//      reaches the action threshold (0.1 in [UN]); below it the result is kUncertain.
//      Default beyond [UN] (TopologicalOptions::max_dissenting_bands,
//      light_dependent_bands): one band may dissent when it is less sure than the
//      agreeing bands on average (its C_b is subtracted), and L's dissent is always
//      outvoted; UlrichNourbakhshOptions() restores unanimity and [UN]'s bands.
//   5. The belief moves to p on kConfident and otherwise stays at the last confident
//      place.
// [UN] does not spell out how the band confidences combine before the action threshold;
// summing those of the agreeing bands is our reading (documented, configurable through
// the thresholds). Everything is deterministic: ties go to the lower reference index.
//
// Places come from an adjacency-map YAML file (LoadAdjacencyMap) or are derived from a
// simulated world's route (PlacesFromRoute). A place's region is one of
//   polygon_m: [[x, y], ...]      the floor area inside the polygon
//   route_interval_m: [s0, s1]    route arc lengths s0 <= s < s1 (needs the route)
//   center_m: [x, y]              the Voronoi cell of the centre among all centre places
// A position is labelled by the first polygon containing it, else the first route interval
// containing its projection onto the route, else the nearest centre, else -1 (no place).
//
// Thread-safety: AdjacencyMap is an immutable value; TopologicalLocalizer is not
// thread-safe (Localize changes the belief); const methods may run concurrently.
#ifndef OMNICML_BASELINES_TOPO_TOPOLOGICAL_H_
#define OMNICML_BASELINES_TOPO_TOPOLOGICAL_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "omnicml/descriptors/color_histogram.h"
#include "omnicml/descriptors/descriptor.h"
#include "omnicml/geometry/pose.h"
#include "omnicml/sensor/frame.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {

enum class PlaceRegionKind { kPolygon, kRouteInterval, kCenter };

struct Place {
  std::string name;  // unique, non-empty
  PlaceRegionKind region = PlaceRegionKind::kCenter;
  std::vector<Eigen::Vector2d> polygon_m;  // kPolygon: at least 3 vertices, map frame
  double route_from_m = 0.0;               // kRouteInterval: [from, to) of the route arc length
  double route_to_m = 0.0;
  Eigen::Vector2d center_m = Eigen::Vector2d::Zero();  // kCenter
  std::vector<int> neighbours;  // indices into AdjacencyMap::places(); symmetric, no self
};

// The graph of places. A plain value type.
class AdjacencyMap {
 public:
  AdjacencyMap() = default;
  // Validates names (unique, non-empty), regions and neighbour indices, and makes the
  // neighbour relation symmetric (sorted, without duplicates). Throws omnicml::Error.
  explicit AdjacencyMap(std::vector<Place> places);

  const std::vector<Place>& places() const { return places_; }
  int size() const { return static_cast<int>(places_.size()); }
  // Index of the place with this name, or -1.
  int Find(const std::string& name) const;
  bool AreNeighbours(int a, int b) const;
  // True if some place is a route interval (PlaceAt then needs the route).
  bool NeedsRoute() const;

  // The place containing the floor position p_m (see the file comment), or -1. `route`
  // is needed for route-interval places (omnicml::Error if one exists and route is null).
  int PlaceAt(const Eigen::Vector2d& p_m, const RoutePath* route = nullptr) const;

 private:
  std::vector<Place> places_;
};

// Parses an adjacency map from YAML text:
//   places:
//     - name: aisle_1
//       center_m: [3.0, 1.2]            (or polygon_m / route_interval_m; exactly one)
//       neighbours: [dock, aisle_2]     names of other places
// Neighbours need to be listed on one side only. Throws omnicml::Error
// "<source>:<line>: <key>: what" on a syntax error, an unknown or missing key, a bad value
// or an unknown neighbour name.
AdjacencyMap ParseAdjacencyMap(const std::string& yaml_text, const std::string& source);
// Reads an adjacency-map file. Throws omnicml::Error naming the file.
AdjacencyMap LoadAdjacencyMap(const std::string& path);
// The YAML text of a map (ParseAdjacencyMap reads it back to an equal map).
std::string AdjacencyMapYaml(const AdjacencyMap& map);

// Places derived from a route: centres placed greedily along the loop (sampled every
// 0.05 m): a point farther than place_length_m from every centre so far becomes a new
// centre, so stretches driven twice (there and back along a corridor) share places.
// Regions are the Voronoi cells of the centres (kCenter); two places are neighbours
// when the route passes directly from one cell into the other. Names "P00", "P01", ...
// Throws omnicml::Error if place_length_m <= 0.
AdjacencyMap PlacesFromRoute(const RoutePath& route, double place_length_m);

enum class PlaceState { kConfident, kUncertain, kConfused };
std::string ToString(PlaceState state);  // confident|uncertain|confused

// The localizer's histogram defaults (docs/results.md "[UN] ..."): [UN]'s
// six bands with the normalised r, g, b (chromaticity: unchanged when a room's lights
// change its brightness) and 64 bins per band (near-grey walls put most chromaticity
// values within a few hundredths of 1/3). Chosen among bins {32, 64} on home_store and
// institute, seeds 1-3, all day pairs, one setting for both worlds. HSV saturation and
// relative luminance instead of HLS S and L ("Topological under illumination
// change"): S is then unchanged by a light, L by a light over the whole image.
inline ColorHistogramOptions TopologicalHistogramDefaults() {
  ColorHistogramOptions o;
  o.bins = 64;
  o.normalized_rgb = true;
  o.hsv_saturation = true;
  o.relative_luminance = true;
  return o;
}

struct TopologicalOptions {
  // The six histograms and their distance ([UN]: Jeffrey divergence, low-pass filtered).
  ColorHistogramOptions histogram = TopologicalHistogramDefaults();
  // Describe averages blocks of this many x this many pixels (cv::INTER_AREA) before the
  // histograms; 1 = off. Averaging n^2 pixels divides the sensor noise by n, which
  // otherwise scatters the hue and chromaticity of the dark near-grey pixels of a room
  // whose lights are off (with 4, institute's hue band names another place in
  // 10 % instead of 59 % of the frames of rooms whose lights changed between the days).
  // Chosen among {1, 4, 8}. Not in [UN]. 1..16.
  int average_block_px = 4;
  // Per band (H, L, S, R|r, G|g, B|b), the smallest confidence C_b, in [0, 1], with which
  // the band's vote counts.
  std::array<double, ColorHistogram::kBands> band_threshold = {0.05, 0.05, 0.05, 0.05, 0.05, 0.05};
  // How many taking-part bands may name another place than the majority without making
  // the frame confused (0 = [UN]'s unanimity). The place is the one named by the most
  // light-independent bands (a tie is confused; the light-dependent bands rule only when
  // no other band takes part). The dissent is tolerated when there are at most k
  // dissenters in all, fewer light-independent dissenters than agreeing bands, and each
  // light-independent dissenter is less sure (C_b) than the agreeing bands on average;
  // the overall confidence is then the agreeing bands' C_b (light-dependent ones
  // included) minus the light-independent dissenters'. One band's histogram can be
  // changed by what changes between days (a light, a restocked shelf, a curtain) while
  // the others still agree. 0..5.
  int max_dissenting_bands = 1;
  // Per band (H, L, S, r, g, b): whether its histogram changes with the light (
  // L, even relative to the image's median, since a light switches only part of a
  // panorama). Such a band's dissent counts towards max_dissenting_bands but is
  // outvoted whatever its confidence (it is not compared with the agreeing bands nor
  // subtracted). No effect with max_dissenting_bands 0.
  std::array<bool, ColorHistogram::kBands> light_dependent_bands = {false, true,  false,
                                                                    false, false, false};
  // The smallest overall confidence (sum of the agreeing bands' C_b) for a confident
  // classification. [UN]: 0.1. >= 0.
  double action_threshold = 0.1;
  // Compare only with the believed place and its neighbours ([UN]); false: all places.
  bool restrict_to_neighbours = true;
  // Learn per-band thresholds from the reference images (TopologicalLocalizer::
  // LearnBandThresholds, run by RunCrossSequence after the references are added): each
  // band's threshold becomes max(band_threshold[b], the learned one). [UN] sets a
  // threshold per band; this derives it from the training day instead of by hand.
  bool learn_band_thresholds = false;
  // Calibration: a reference image is compared with the references taken more than this
  // many reference images before or after it (another visit or another part of the
  // place). >= 0.
  int calibration_exclusion_frames = 20;
  // Calibration: the largest fraction of wrong votes among those at or above a band's
  // learned threshold, in [0, 1]. [UN] aims at no confident-wrong classification.
  double calibration_max_wrong = 0.01;
  // After this many consecutive non-confident frames compare with all places until the
  // next confident one (a recovery [UN] does not have). 0 = never.
  int global_search_after_frames = 0;

  // Throws omnicml::Error naming the field when a value is out of range.
  void Validate() const;
};

// [UN]'s bands and vote as published, on the defaults before the illumination
// work (the "before" rows of docs/results.md): HLS L and S, unanimity; 64 bins,
// normalised r, g, b and 4 x 4 block averages as the defaults. As YAML (--config):
// histogram: {hsv_saturation: false, relative_luminance: false}, max_dissenting_bands: 0.
TopologicalOptions UlrichNourbakhshOptions();

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, TopologicalOptions& o) {
  v.Section("histogram", o.histogram);
  v("average_block_px", o.average_block_px);
  v("band_threshold", o.band_threshold);
  v("max_dissenting_bands", o.max_dissenting_bands);
  v("light_dependent_bands", o.light_dependent_bands);
  v("action_threshold", o.action_threshold);
  v("learn_band_thresholds", o.learn_band_thresholds);
  v("calibration_exclusion_frames", o.calibration_exclusion_frames);
  v("calibration_max_wrong", o.calibration_max_wrong);
  v("restrict_to_neighbours", o.restrict_to_neighbours);
  v("global_search_after_frames", o.global_search_after_frames);
}

// TopologicalOptions in YAML (keys = member names; absent keys keep their defaults),
// validated. The inputs `omnicml topo` writes next to the options in its
// topo_config.yaml (kTopoRunKeys) are accepted and skipped, so that file loads back.
// Throws omnicml::Error "<file>:<line>: ..." naming the key.
inline const std::vector<std::string> kTopoRunKeys = {
    "world",     "log",      "days",   "frames_per_day",          "seed",       "step_m", "people",
    "train_day", "test_day", "places", "reference_stride_frames", "known_start"};
TopologicalOptions ParseTopologicalOptionsYaml(const std::string& yaml_text,
                                               const std::string& source);
TopologicalOptions LoadTopologicalOptions(const std::string& path);
// Every field as YAML; LoadTopologicalOptions reads it back to equal options.
std::string TopologicalOptionsToYaml(const TopologicalOptions& options);

// One band's nearest-neighbour result.
struct BandVote {
  int place = -1;               // place of the nearest reference image, -1 if none
  int reference = -1;           // index of that image (TopologicalLocalizer numbering)
  double distance_nn = 0.0;     // distance to it
  double distance_other = 0.0;  // nearest image of another candidate place (inf if none)
  double confidence = 0.0;      // C_b = 1 - distance_nn / distance_other, in [0, 1]
};
using BandVotes = std::array<BandVote, ColorHistogram::kBands>;

struct PlaceDecision {
  PlaceState state = PlaceState::kUncertain;
  int place = -1;           // the unanimous place (also when kUncertain by the action threshold)
  double confidence = 0.0;  // sum of C_b of the bands that took part (0 if kConfused)
  int voting_bands = 0;     // bands with C_b >= their threshold that count (advisory: agreeing)
  BandVotes bands;
};

// What LearnBandThresholds measured on the reference images, per band.
struct BandCalibration {
  int queries = 0;  // reference images used as queries (their place had references left)
  std::array<int, ColorHistogram::kBands> votes{};         // queries where the band voted
  std::array<int, ColorHistogram::kBands> correct{};       // ... for the query's own place
  std::array<double, ColorHistogram::kBands> threshold{};  // learned (before the max)
};

// Steps 3-4 of the file comment on given band votes (pure; no state).
PlaceDecision Vote(const BandVotes& bands, const TopologicalOptions& options);

// The localizer: reference images per place, the belief, and Localize per input image.
// Lifecycle: construct, AddReference for the training images, Reset (optionally with a
// known start place), then Localize frame by frame.
class TopologicalLocalizer {
 public:
  // Throws omnicml::Error on invalid options or an empty map.
  TopologicalLocalizer(AdjacencyMap map, const TopologicalOptions& options = {});

  // The six histograms of a panorama (CV_8UC3 BGR or CV_8UC1), after averaging
  // average_block_px blocks (when the image holds at least 2 x 2 blocks). Throws
  // omnicml::Error on a bad image.
  Descriptor Describe(const cv::Mat& panorama) const;
  // The same for a panorama of which only some pixels show the scene (`valid_mask` as
  // DescriptorExtractor::ComputeMasked, descriptor.h; empty = all valid): invalid pixels
  // are filled with their row's valid mean (FillInvalidPixels) before the noise estimate
  // and the histograms, so they have no influence on the result.
  Descriptor Describe(const cv::Mat& panorama, const cv::Mat& valid_mask) const;

  // Adds a reference image (its Describe() result) to `place`. Throws omnicml::Error on a
  // bad place index or descriptor size.
  void AddReference(int place, const Descriptor& descriptor);
  int NumReferences() const { return static_cast<int>(reference_place_.size()); }
  int NumReferences(int place) const;

  // Forgets the belief; with start_place >= 0 the robot starts believed there.
  void Reset(int start_place = -1);
  int believed_place() const { return believed_place_; }

  // The places compared with now (sorted): the believed place and its neighbours, or all.
  std::vector<int> CandidatePlaces() const;

  // Step 2-3 of the file comment against the reference images of `candidates`.
  BandVotes ClassifyBands(const Descriptor& descriptor, const std::vector<int>& candidates) const;

  // Per-band thresholds learned from the reference images (see TopologicalOptions::
  // calibration_*): each reference is classified against the references of its place
  // and its neighbours taken more than calibration_exclusion_frames away from it, and a
  // band's threshold is the smallest confidence above which at most
  // calibration_max_wrong of its votes were wrong. Deterministic; does not change the
  // localizer. `calibration` (optional) receives the counts.
  std::array<double, ColorHistogram::kBands> CalibrateBandThresholds(
      BandCalibration* calibration = nullptr) const;
  // Sets the thresholds Localize uses to max(options().band_threshold, the learned ones).
  // Call after the last AddReference.
  void LearnBandThresholds(BandCalibration* calibration = nullptr);
  // The options Localize votes with (options() with the learned band thresholds).
  const TopologicalOptions& effective_options() const { return effective_; }

  // Classifies one input image against CandidatePlaces() and updates the belief.
  PlaceDecision Localize(const Descriptor& descriptor);

  const AdjacencyMap& map() const { return map_; }
  const TopologicalOptions& options() const { return options_; }

 private:
  AdjacencyMap map_;
  TopologicalOptions options_;
  ColorHistogram histogram_;
  int bins_ = 0;
  std::vector<float> references_;     // NumReferences() x (6 * bins), row-major
  std::vector<int> reference_place_;  // place of each reference image
  // ClassifyBands on a raw feature vector, ignoring references [exclude_from, exclude_to].
  BandVotes ClassifyBandsExcluding(const float* features, const std::vector<int>& candidates,
                                   int exclude_from, int exclude_to) const;

  TopologicalOptions effective_;  // options_ with the learned band thresholds
  int believed_place_ = -1;
  int non_confident_run_ = 0;
};

// [UN] Table 1 counts over classified frames (frames whose true place is known).
struct TopologicalCounts {
  std::int64_t frames = 0;             // test frames with a true place
  std::int64_t confident_correct = 0;  // kConfident, voted place == true place
  std::int64_t confident_wrong = 0;
  std::int64_t uncertain = 0;
  std::int64_t confused = 0;
  std::int64_t belief_correct = 0;  // believed place (after the frame) == true place
};

// One test frame's outcome.
struct TopologicalFrameResult {
  double stamp_s = 0.0;
  std::int64_t index_in_session = 0;
  Pose2 map_T_robot_truth = Pose2::Zero();
  int true_place = -1;
  int believed_place = -1;
  PlaceDecision decision;
};

struct CrossSequenceOptions {
  int train_session = 0;  // 0-based session index of the reference images
  int test_session = 1;   // 0-based session index of the test images
  // Every k-th labelled training frame becomes a reference image (>= 1).
  int reference_stride_frames = 1;
  // Start the test believed at the true place of its first frame (the robot leaves a
  // known dock, as in [UN]); false: start with no belief (all places compared).
  bool known_start = true;
  void Validate() const;  // throws omnicml::Error
};

struct CrossSequenceResult {
  std::vector<TopologicalFrameResult> frames;
  TopologicalCounts counts;
  int references = 0;  // reference images taken from the training session
  // The training frames that became reference images, in reference order (index =
  // BandVote::reference); stamp, index, truth and true_place set, decision unset.
  std::vector<TopologicalFrameResult> reference_frames;
  BandCalibration calibration;  // when options().learn_band_thresholds
  int places_with_references = 0;
  // Frames of the training session, and how many of them lie in no place (no reference
  // image): many of them suggest a places file of another world.
  std::int64_t train_frames = 0;
  std::int64_t train_frames_without_place = 0;
  // Test frames that lie in no place (not in counts).
  std::int64_t test_frames_without_place() const {
    return static_cast<std::int64_t>(frames.size()) - counts.frames;
  }
};

// The cross-sequence experiment of [UN]: reads `source` once; frames of
// options.train_session with ground truth become reference images of the place they lie
// in; frames of options.test_session are then localized in order. Raw ring images are
// unwrapped with the session's calibration. `route` labels route-interval places.
// Throws omnicml::Error if a session index is out of range, a needed frame has no
// ground truth, or no reference image was found.
CrossSequenceResult RunCrossSequence(FrameSource* source, TopologicalLocalizer* localizer,
                                     const CrossSequenceOptions& options,
                                     const RoutePath* route = nullptr);

// The summary table (markdown) of counts like [UN] Table 1.
std::string TopologicalSummaryTable(const TopologicalCounts& counts, const std::string& title);

}  // namespace omnicml

#endif  // OMNICML_BASELINES_TOPO_TOPOLOGICAL_H_
