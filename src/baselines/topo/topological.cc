// Topological localization by colour-histogram place recognition [UN].
#include "omnicml/baselines/topo/topological.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <sstream>
#include <utility>

#include <yaml-cpp/yaml.h>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/common/options.h"
#include "omnicml/common/yaml_io.h"
#include "omnicml/geometry/planar_geometry.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kRouteSampleStepM = 0.05;

// Arc length of the route point nearest to p_m (sampled every kRouteSampleStepM).
double ProjectOntoRoute(const RoutePath& route, const Eigen::Vector2d& p_m) {
  const int n = std::max(1, static_cast<int>(std::ceil(route.length_m() / kRouteSampleStepM)));
  double best_d2 = kInf, best_s = 0.0;
  for (int i = 0; i < n; ++i) {
    const double s = route.length_m() * i / n;
    const double d2 = (route.PoseAt(s).head<2>() - p_m).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best_s = s;
    }
  }
  return best_s;
}

std::string RegionKey(PlaceRegionKind k) {
  switch (k) {
    case PlaceRegionKind::kPolygon:
      return "polygon_m";
    case PlaceRegionKind::kRouteInterval:
      return "route_interval_m";
    case PlaceRegionKind::kCenter:
      return "center_m";
  }
  return "?";
}

// Error "<source>:<line>: <key>: what" at node n.
[[noreturn]] void FailAt(const std::string& source, const YAML::Node& n, const std::string& key,
                         const std::string& what) {
  throw Error(StrCat(source, ":", n.Mark().line + 1, ": ", key, ": ", what));
}

std::vector<double> Numbers(const std::string& source, const YAML::Node& n,
                            const std::string& key) {
  if (!n.IsSequence()) FailAt(source, n, key, "expected a list of numbers");
  std::vector<double> out;
  for (const auto& e : n) {
    double v = 0;
    try {
      if (!e.IsScalar()) throw YAML::Exception(e.Mark(), "not a scalar");
      v = e.as<double>();
    } catch (const YAML::Exception&) {
      FailAt(source, e, key, "expected a number");
    }
    if (!std::isfinite(v)) FailAt(source, e, key, "expected a finite number");
    out.push_back(v);
  }
  return out;
}

Eigen::Vector2d Point(const std::string& source, const YAML::Node& n, const std::string& key) {
  const auto v = Numbers(source, n, key);
  if (v.size() != 2) FailAt(source, n, key, "expected [x, y]");
  return {v[0], v[1]};
}

}  // namespace

// ---------------------------------------------------------------------------------------
// AdjacencyMap

AdjacencyMap::AdjacencyMap(std::vector<Place> places) : places_(std::move(places)) {
  const int n = size();
  std::set<std::string> names;
  for (int i = 0; i < n; ++i) {
    const Place& p = places_[i];
    if (p.name.empty()) throw Error(StrCat("adjacency map: place ", i, " has an empty name"));
    if (!names.insert(p.name).second) {
      throw Error(StrCat("adjacency map: place name '", p.name, "' is used twice"));
    }
    if (p.region == PlaceRegionKind::kPolygon && p.polygon_m.size() < 3) {
      throw Error(StrCat("adjacency map: place '", p.name, "': polygon_m needs 3 vertices"));
    }
    if (p.region == PlaceRegionKind::kRouteInterval &&
        !(p.route_from_m >= 0 && p.route_to_m > p.route_from_m)) {
      throw Error(
          StrCat("adjacency map: place '", p.name, "': route_interval_m needs 0 <= from < to"));
    }
  }
  std::vector<std::set<int>> adj(n);
  for (int i = 0; i < n; ++i) {
    for (int j : places_[i].neighbours) {
      if (j < 0 || j >= n) {
        throw Error(StrCat("adjacency map: place '", places_[i].name, "': neighbour index ", j,
                           " out of range"));
      }
      if (j == i) continue;
      adj[i].insert(j);
      adj[j].insert(i);
    }
  }
  for (int i = 0; i < n; ++i) places_[i].neighbours.assign(adj[i].begin(), adj[i].end());
}

int AdjacencyMap::Find(const std::string& name) const {
  for (int i = 0; i < size(); ++i) {
    if (places_[i].name == name) return i;
  }
  return -1;
}

bool AdjacencyMap::AreNeighbours(int a, int b) const {
  if (a < 0 || a >= size()) return false;
  const auto& nb = places_[a].neighbours;
  return std::binary_search(nb.begin(), nb.end(), b);
}

bool AdjacencyMap::NeedsRoute() const {
  return std::any_of(places_.begin(), places_.end(),
                     [](const Place& p) { return p.region == PlaceRegionKind::kRouteInterval; });
}

int AdjacencyMap::PlaceAt(const Eigen::Vector2d& p_m, const RoutePath* route) const {
  for (int i = 0; i < size(); ++i) {
    if (places_[i].region == PlaceRegionKind::kPolygon &&
        geometry::PointInPolygon(places_[i].polygon_m, p_m)) {
      return i;
    }
  }
  if (NeedsRoute()) {
    if (route == nullptr) {
      throw Error("adjacency map: route-interval places need the route to label a position");
    }
    const double s = ProjectOntoRoute(*route, p_m);
    for (int i = 0; i < size(); ++i) {
      const Place& p = places_[i];
      if (p.region == PlaceRegionKind::kRouteInterval && s >= p.route_from_m && s < p.route_to_m) {
        return i;
      }
    }
  }
  int best = -1;
  double best_d2 = kInf;
  for (int i = 0; i < size(); ++i) {
    if (places_[i].region != PlaceRegionKind::kCenter) continue;
    const double d2 = (places_[i].center_m - p_m).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best = i;
    }
  }
  return best;
}

AdjacencyMap ParseAdjacencyMap(const std::string& yaml_text, const std::string& source) {
  YAML::Node root;
  try {
    root = LoadYaml(yaml_text, source);
  } catch (const YAML::ParserException& e) {
    throw Error(StrCat(source, ":", e.mark.line + 1, ": YAML syntax error: ", e.msg));
  }
  if (!root.IsMap()) throw Error(StrCat(source, ":1: expected a mapping with key 'places'"));
  for (const auto& kv : root) {
    const std::string key = kv.first.Scalar();
    if (key != "places") FailAt(source, kv.first, key, "unknown key (expected: places)");
  }
  const YAML::Node list = root["places"];
  if (!list) throw Error(StrCat(source, ":1: places: missing required key"));
  if (!list.IsSequence() || list.size() == 0) {
    FailAt(source, list, "places", "expected a non-empty list of places");
  }
  std::vector<Place> places;
  std::vector<std::vector<std::pair<std::string, YAML::Node>>> neighbour_names;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const YAML::Node n = list[i];
    const std::string path = StrCat("places[", i, "]");
    if (!n.IsMap()) FailAt(source, n, path, "expected a mapping");
    Place place;
    int regions = 0;
    std::vector<std::pair<std::string, YAML::Node>> nb;
    bool have_name = false;
    for (const auto& kv : n) {
      const std::string key = kv.first.Scalar();
      const std::string kpath = path + "." + key;
      const YAML::Node v = kv.second;
      if (key == "name") {
        if (!v.IsScalar() || v.Scalar().empty()) FailAt(source, v, kpath, "expected a name");
        place.name = v.Scalar();
        have_name = true;
      } else if (key == "center_m") {
        place.region = PlaceRegionKind::kCenter;
        place.center_m = Point(source, v, kpath);
        ++regions;
      } else if (key == "polygon_m") {
        place.region = PlaceRegionKind::kPolygon;
        if (!v.IsSequence()) FailAt(source, v, kpath, "expected a list of [x, y]");
        for (const auto& e : v) place.polygon_m.push_back(Point(source, e, kpath));
        if (place.polygon_m.size() < 3) FailAt(source, v, kpath, "a polygon needs 3 vertices");
        ++regions;
      } else if (key == "route_interval_m") {
        place.region = PlaceRegionKind::kRouteInterval;
        const auto s = Numbers(source, v, kpath);
        if (s.size() != 2 || s[0] < 0 || s[1] <= s[0]) {
          FailAt(source, v, kpath, "expected [from_m, to_m] with 0 <= from_m < to_m");
        }
        place.route_from_m = s[0];
        place.route_to_m = s[1];
        ++regions;
      } else if (key == "neighbours") {
        if (!v.IsSequence()) FailAt(source, v, kpath, "expected a list of place names");
        for (const auto& e : v) {
          if (!e.IsScalar()) FailAt(source, e, kpath, "expected a place name");
          nb.emplace_back(e.Scalar(), e);
        }
      } else {
        FailAt(source, kv.first, kpath,
               "unknown key (expected: name, center_m, polygon_m, route_interval_m, neighbours)");
      }
    }
    if (!have_name) FailAt(source, n, path + ".name", "missing required key");
    if (regions != 1) {
      FailAt(source, n, path + ".center_m|polygon_m|route_interval_m",
             "exactly one region key is required");
    }
    for (const auto& p : places) {
      if (p.name == place.name) {
        FailAt(source, n, path + ".name", StrCat("place name '", place.name, "' is used twice"));
      }
    }
    places.push_back(std::move(place));
    neighbour_names.push_back(std::move(nb));
  }
  for (std::size_t i = 0; i < places.size(); ++i) {
    for (const auto& [name, node] : neighbour_names[i]) {
      int j = -1;
      for (std::size_t k = 0; k < places.size(); ++k) {
        if (places[k].name == name) j = static_cast<int>(k);
      }
      if (j < 0) {
        FailAt(source, node, StrCat("places[", i, "].neighbours"),
               StrCat("unknown place '", name, "'"));
      }
      places[i].neighbours.push_back(j);
    }
  }
  try {
    return AdjacencyMap(std::move(places));
  } catch (const Error& e) {
    throw Error(StrCat(source, ": ", e.what()));
  }
}

AdjacencyMap LoadAdjacencyMap(const std::string& path) {
  // A regular file of at most kMaxTextFileBytes (no FIFO, device or directory).
  return ParseAdjacencyMap(ReadTextFile(path, kMaxTextFileBytes, "places file"), path);
}

std::string AdjacencyMapYaml(const AdjacencyMap& map) {
  std::ostringstream os;
  os << "# Adjacency map of places (omnicml topological localization, [UN]).\n"
     << "# Region per place: center_m (Voronoi cell), polygon_m or route_interval_m.\n"
     << "places:\n";
  for (const Place& p : map.places()) {
    os << "  - name: " << p.name << "\n    " << RegionKey(p.region) << ": ";
    switch (p.region) {
      case PlaceRegionKind::kCenter:
        os << "[" << FormatRoundTrip(p.center_m.x()) << ", " << FormatRoundTrip(p.center_m.y())
           << "]";
        break;
      case PlaceRegionKind::kRouteInterval:
        os << "[" << FormatRoundTrip(p.route_from_m) << ", " << FormatRoundTrip(p.route_to_m)
           << "]";
        break;
      case PlaceRegionKind::kPolygon:
        os << "[";
        for (std::size_t i = 0; i < p.polygon_m.size(); ++i) {
          os << (i ? ", " : "") << "[" << FormatRoundTrip(p.polygon_m[i].x()) << ", "
             << FormatRoundTrip(p.polygon_m[i].y()) << "]";
        }
        os << "]";
        break;
    }
    os << "\n    neighbours: [";
    for (std::size_t i = 0; i < p.neighbours.size(); ++i) {
      os << (i ? ", " : "") << map.places()[p.neighbours[i]].name;
    }
    os << "]\n";
  }
  return os.str();
}

AdjacencyMap PlacesFromRoute(const RoutePath& route, double place_length_m) {
  if (!(place_length_m > 0) || !std::isfinite(place_length_m)) {
    throw Error(StrCat("place_length_m: must be > 0, got ", place_length_m));
  }
  const int n = std::max(3, static_cast<int>(std::ceil(route.length_m() / kRouteSampleStepM)));
  std::vector<Eigen::Vector2d> samples(n);
  for (int i = 0; i < n; ++i) samples[i] = route.PoseAt(route.length_m() * i / n).head<2>();
  std::vector<Place> places;
  for (const auto& p : samples) {
    bool near = false;
    for (const auto& q : places) near |= (q.center_m - p).norm() <= place_length_m;
    if (!near) {
      Place place;
      place.name = StrCat(places.size() < 10 ? "P0" : "P", places.size());
      place.region = PlaceRegionKind::kCenter;
      place.center_m = p;
      places.push_back(std::move(place));
    }
  }
  AdjacencyMap unlinked(places);
  std::vector<int> label(n);
  for (int i = 0; i < n; ++i) label[i] = unlinked.PlaceAt(samples[i]);
  for (int i = 0; i < n; ++i) {
    const int a = label[i], b = label[(i + 1) % n];
    if (a != b) places[a].neighbours.push_back(b);
  }
  return AdjacencyMap(std::move(places));
}

// ---------------------------------------------------------------------------------------
// Voting

std::string ToString(PlaceState state) {
  switch (state) {
    case PlaceState::kConfident:
      return "confident";
    case PlaceState::kUncertain:
      return "uncertain";
    case PlaceState::kConfused:
      return "confused";
  }
  return "?";
}

void TopologicalOptions::Validate() const {
  histogram.Validate();
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    if (!(band_threshold[b] >= 0.0 && band_threshold[b] <= 1.0)) {
      throw Error(StrCat("band_threshold[", b, "]: must be in [0, 1], got ", band_threshold[b]));
    }
  }
  if (!(action_threshold >= 0.0) || !std::isfinite(action_threshold)) {
    throw Error(StrCat("action_threshold: must be >= 0, got ", action_threshold));
  }
  if (max_dissenting_bands < 0 || max_dissenting_bands > ColorHistogram::kBands - 1) {
    throw Error(StrCat("max_dissenting_bands: must be in 0..5, got ", max_dissenting_bands));
  }
  if (average_block_px < 1 || average_block_px > 16) {
    throw Error(StrCat("average_block_px: must be in 1..16, got ", average_block_px));
  }
  if (calibration_exclusion_frames < 0) {
    throw Error(
        StrCat("calibration_exclusion_frames: must be >= 0, got ", calibration_exclusion_frames));
  }
  if (!(calibration_max_wrong >= 0.0 && calibration_max_wrong <= 1.0)) {
    throw Error(StrCat("calibration_max_wrong: must be in [0, 1], got ", calibration_max_wrong));
  }
  if (global_search_after_frames < 0) {
    throw Error(
        StrCat("global_search_after_frames: must be >= 0, got ", global_search_after_frames));
  }
}

TopologicalOptions UlrichNourbakhshOptions() {
  TopologicalOptions o;
  o.histogram.hsv_saturation = false;
  o.histogram.relative_luminance = false;
  o.histogram.reliable_chromaticity = false;
  o.max_dissenting_bands = 0;
  return o;
}

PlaceDecision Vote(const BandVotes& bands, const TopologicalOptions& options) {
  PlaceDecision d;
  d.bands = bands;
  constexpr int kBands = ColorHistogram::kBands;
  // [UN]: a band's vote counts only with a confidence above its threshold.
  auto takes_part = [&](int b) {
    return bands[b].place >= 0 && bands[b].confidence >= options.band_threshold[b];
  };
  // The ruling bands: the light-independent ones that take part, or the light-dependent
  // ones when no other band takes part.
  bool any_independent = false;
  for (int b = 0; b < kBands; ++b) {
    any_independent |= takes_part(b) && !options.light_dependent_bands[b];
  }
  auto ruling = [&](int b) {
    return takes_part(b) && (!any_independent || !options.light_dependent_bands[b]);
  };
  // The place named by the most ruling bands (a tie: confused).
  int place = -1, best = 0;
  bool tie = false;
  for (int b = 0; b < kBands; ++b) {
    if (!ruling(b)) continue;
    int n = 0;
    for (int c = 0; c < kBands; ++c) n += ruling(c) && bands[c].place == bands[b].place;
    if (n > best) {
      best = n;
      place = bands[b].place;
      tie = false;
    } else if (n == best && bands[b].place != place) {
      tie = true;
    }
  }
  double agreeing_sum = 0.0, ruling_dissent_sum = 0.0, ruling_dissent_max = 0.0;
  int agreeing = 0, ruling_dissenters = 0, dissenters = 0;
  for (int b = 0; b < kBands; ++b) {
    if (!takes_part(b)) continue;
    if (bands[b].place == place) {
      ++agreeing;
      agreeing_sum += bands[b].confidence;
    } else {
      ++dissenters;
      if (ruling(b)) {
        ++ruling_dissenters;
        ruling_dissent_sum += bands[b].confidence;
        ruling_dissent_max = std::max(ruling_dissent_max, bands[b].confidence);
      }
    }
  }
  d.voting_bands = agreeing + dissenters;
  // A light-independent dissenter is outvoted only when it is less sure than the
  // agreeing bands on average.
  const bool dissent_tolerated =
      dissenters == 0 || (dissenters <= options.max_dissenting_bands && best > ruling_dissenters &&
                          (ruling_dissenters == 0 || ruling_dissent_max < agreeing_sum / agreeing));
  if (place < 0) {
    d.state = PlaceState::kUncertain;
  } else if (tie || !dissent_tolerated) {
    // [UN] unanimous voting (max_dissenting_bands 0): confident bands that disagree
    // leave the robot confused.
    d.state = PlaceState::kConfused;
  } else {
    d.place = place;
    d.confidence = agreeing_sum - ruling_dissent_sum;
    // [UN] action threshold on the overall confidence.
    d.state =
        d.confidence >= options.action_threshold ? PlaceState::kConfident : PlaceState::kUncertain;
  }
  return d;
}

// ---------------------------------------------------------------------------------------
// TopologicalLocalizer

TopologicalLocalizer::TopologicalLocalizer(AdjacencyMap map, const TopologicalOptions& options)
    : map_(std::move(map)), options_(options), histogram_((options.Validate(), options.histogram)) {
  if (map_.size() == 0) throw Error("topological localizer: the adjacency map has no place");
  bins_ = options_.histogram.bins;
  effective_ = options_;
}

Descriptor TopologicalLocalizer::Describe(const cv::Mat& panorama) const {
  const int block = options_.average_block_px;
  // reliable_chromaticity: the sensor noise is estimated on the image as taken; averaging
  // block x block pixels divides its standard deviation by block.
  const bool estimate_noise = options_.histogram.reliable_chromaticity && !panorama.empty() &&
                              panorama.depth() == CV_8U &&
                              (panorama.channels() == 1 || panorama.channels() == 3) &&
                              panorama.rows >= 3 && panorama.cols >= 3;
  const double sigma = estimate_noise ? EstimateNoiseSigma(panorama) : 0.0;
  if (block > 1 && !panorama.empty() && panorama.cols >= 2 * block && panorama.rows >= 2 * block) {
    // Block averages (a last partial block of a row or column is dropped).
    cv::Mat averaged;
    cv::resize(
        panorama(cv::Rect(0, 0, panorama.cols / block * block, panorama.rows / block * block)),
        averaged, cv::Size(panorama.cols / block, panorama.rows / block), 0, 0, cv::INTER_AREA);
    Descriptor d = histogram_.Compute(averaged, sigma / block);
    d.panorama_width = panorama.cols;
    return d;
  }
  return histogram_.Compute(panorama, sigma);
}

Descriptor TopologicalLocalizer::Describe(const cv::Mat& panorama,
                                          const cv::Mat& valid_mask) const {
  if (valid_mask.empty() || panorama.empty()) return Describe(panorama);
  return Describe(FillInvalidPixels(panorama, valid_mask));
}

void TopologicalLocalizer::AddReference(int place, const Descriptor& descriptor) {
  if (place < 0 || place >= map_.size()) {
    throw Error(
        StrCat("AddReference: place index ", place, " out of range [0, ", map_.size(), ")"));
  }
  if (descriptor.kind != DescriptorKind::kColorHistogram ||
      descriptor.features.size() != histogram_.FeatureSize()) {
    throw Error(StrCat("AddReference: expected a colour histogram of ", histogram_.FeatureSize(),
                       " values, got ", ToString(descriptor.kind), " of ",
                       descriptor.features.size()));
  }
  references_.insert(references_.end(), descriptor.features.begin(), descriptor.features.end());
  reference_place_.push_back(place);
}

int TopologicalLocalizer::NumReferences(int place) const {
  return static_cast<int>(std::count(reference_place_.begin(), reference_place_.end(), place));
}

void TopologicalLocalizer::Reset(int start_place) {
  if (start_place >= map_.size()) {
    throw Error(StrCat("Reset: place index ", start_place, " out of range"));
  }
  believed_place_ = start_place < 0 ? -1 : start_place;
  non_confident_run_ = 0;
}

std::vector<int> TopologicalLocalizer::CandidatePlaces() const {
  const bool global = believed_place_ < 0 || !options_.restrict_to_neighbours ||
                      (options_.global_search_after_frames > 0 &&
                       non_confident_run_ >= options_.global_search_after_frames);
  std::vector<int> out;
  if (global) {
    for (int i = 0; i < map_.size(); ++i) out.push_back(i);
    return out;
  }
  out = map_.places()[believed_place_].neighbours;
  out.push_back(believed_place_);
  std::sort(out.begin(), out.end());
  return out;
}

BandVotes TopologicalLocalizer::ClassifyBands(const Descriptor& descriptor,
                                              const std::vector<int>& candidates) const {
  const std::size_t fs = histogram_.FeatureSize();
  if (descriptor.features.size() != fs) {
    throw Error(StrCat("ClassifyBands: expected ", fs, " histogram values, got ",
                       descriptor.features.size()));
  }
  return ClassifyBandsExcluding(descriptor.features.data(), candidates, -1, -1);
}

BandVotes TopologicalLocalizer::ClassifyBandsExcluding(const float* features,
                                                       const std::vector<int>& candidates,
                                                       int exclude_from, int exclude_to) const {
  const std::size_t fs = histogram_.FeatureSize();
  std::vector<char> is_candidate(map_.size(), 0);
  for (int c : candidates) {
    if (c >= 0 && c < map_.size()) is_candidate[c] = 1;
  }
  BandVotes votes;
  const int n = NumReferences();
  // Per band, the nearest image per candidate place: then NN = best, d_other = best of
  // the other places.
  std::vector<double> best_per_place(map_.size());
  std::vector<int> best_ref_per_place(map_.size());
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    std::fill(best_per_place.begin(), best_per_place.end(), kInf);
    std::fill(best_ref_per_place.begin(), best_ref_per_place.end(), -1);
    const float* q = features + static_cast<std::size_t>(b) * bins_;
    for (int r = 0; r < n; ++r) {
      const int p = reference_place_[r];
      if (!is_candidate[p] || (r >= exclude_from && r <= exclude_to)) continue;
      const float* ref = references_.data() + r * fs + static_cast<std::size_t>(b) * bins_;
      const double d = histogram_.Distance(q, ref, static_cast<std::size_t>(bins_));
      if (d < best_per_place[p]) {  // strict: ties keep the lower reference index
        best_per_place[p] = d;
        best_ref_per_place[p] = r;
      }
    }
    BandVote& v = votes[b];
    for (int p = 0; p < map_.size(); ++p) {
      if (best_ref_per_place[p] < 0) continue;
      if (v.place < 0 || best_per_place[p] < v.distance_nn ||
          (best_per_place[p] == v.distance_nn && best_ref_per_place[p] < v.reference)) {
        v.place = p;
        v.reference = best_ref_per_place[p];
        v.distance_nn = best_per_place[p];
      }
    }
    if (v.place < 0) continue;
    v.distance_other = kInf;
    for (int p = 0; p < map_.size(); ++p) {
      if (p != v.place && best_ref_per_place[p] >= 0) {
        v.distance_other = std::min(v.distance_other, best_per_place[p]);
      }
    }
    // [UN]: confidence from the ratio of the nearest distance to that of another place.
    if (!std::isfinite(v.distance_other)) {
      v.confidence = 1.0;
    } else if (v.distance_other <= 0.0) {
      v.confidence = 0.0;  // both zero: no margin
    } else {
      v.confidence = std::clamp(1.0 - v.distance_nn / v.distance_other, 0.0, 1.0);
    }
  }
  return votes;
}

std::array<double, ColorHistogram::kBands> TopologicalLocalizer::CalibrateBandThresholds(
    BandCalibration* calibration) const {
  // Every reference image r is a query against the other reference images of its place
  // and of the neighbouring places, leaving out those taken within
  // calibration_exclusion_frames of it (references are numbered in the order they were
  // taken): the band then has to recognise the place from another visit or another part
  // of it, as on a test day. Queries whose place has no reference left are skipped (no
  // correct answer exists). Per band, the votes are sorted by confidence, and the
  // threshold is the smallest confidence t such that, of the votes with C_b >= t, at most
  // calibration_max_wrong are wrong (1 + 1e-9 when no such t exists: the band never
  // votes).
  const int n = NumReferences();
  const int w = options_.calibration_exclusion_frames;
  std::array<std::vector<std::pair<double, bool>>, ColorHistogram::kBands> votes;
  int queries = 0;
  const std::size_t fs = histogram_.FeatureSize();
  for (int r = 0; r < n; ++r) {
    const int p = reference_place_[r];
    const int from = std::max(0, r - w), to = std::min(n - 1, r + w);
    bool has_other = false;
    for (int k = 0; k < n && !has_other; ++k) {
      has_other = reference_place_[k] == p && (k < from || k > to);
    }
    if (!has_other) continue;
    ++queries;
    std::vector<int> candidates = map_.places()[p].neighbours;
    candidates.push_back(p);
    const BandVotes v = ClassifyBandsExcluding(references_.data() + r * fs, candidates, from, to);
    for (int b = 0; b < ColorHistogram::kBands; ++b) {
      if (v[b].place >= 0) votes[b].emplace_back(v[b].confidence, v[b].place == p);
    }
  }
  std::array<double, ColorHistogram::kBands> threshold;
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    auto& vb = votes[b];
    // Descending confidence; ties broken by correctness so the result does not depend
    // on the sort's order of equal elements.
    std::sort(vb.begin(), vb.end(), [](const auto& x, const auto& y) {
      return x.first != y.first ? x.first > y.first : x.second > y.second;
    });
    threshold[b] = 1.0 + 1e-9;
    std::int64_t wrong = 0;
    for (std::size_t i = 0; i < vb.size(); ++i) {
      wrong += !vb[i].second;
      // Only at the end of a run of equal confidences (a threshold takes all of them).
      if (i + 1 < vb.size() && vb[i + 1].first == vb[i].first) continue;
      if (static_cast<double>(wrong) <= options_.calibration_max_wrong * (i + 1)) {
        threshold[b] = vb[i].first;
      }
    }
    if (calibration != nullptr) {
      calibration->votes[b] = static_cast<int>(vb.size());
      std::int64_t correct = 0;
      for (const auto& e : vb) correct += e.second;
      calibration->correct[b] = static_cast<int>(correct);
    }
  }
  if (calibration != nullptr) {
    calibration->queries = queries;
    calibration->threshold = threshold;
  }
  return threshold;
}

void TopologicalLocalizer::LearnBandThresholds(BandCalibration* calibration) {
  const auto learned = CalibrateBandThresholds(calibration);
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    effective_.band_threshold[b] = std::max(options_.band_threshold[b], learned[b]);
  }
}

PlaceDecision TopologicalLocalizer::Localize(const Descriptor& descriptor) {
  const PlaceDecision d = Vote(ClassifyBands(descriptor, CandidatePlaces()), effective_);
  if (d.state == PlaceState::kConfident) {
    believed_place_ = d.place;  // [UN]: the belief follows confident classifications only
    non_confident_run_ = 0;
  } else {
    ++non_confident_run_;
  }
  return d;
}

// ---------------------------------------------------------------------------------------
// Cross-sequence experiment

void CrossSequenceOptions::Validate() const {
  if (train_session < 0) throw Error(StrCat("train_session: must be >= 0, got ", train_session));
  if (test_session < 0) throw Error(StrCat("test_session: must be >= 0, got ", test_session));
  if (reference_stride_frames < 1) {
    throw Error(StrCat("reference_stride_frames: must be >= 1, got ", reference_stride_frames));
  }
}

CrossSequenceResult RunCrossSequence(FrameSource* source, TopologicalLocalizer* localizer,
                                     const CrossSequenceOptions& options, const RoutePath* route) {
  OMNICML_CHECK(source != nullptr && localizer != nullptr);
  options.Validate();
  const int sessions = source->NumSessions();
  if (options.train_session >= sessions || options.test_session >= sessions) {
    throw Error(StrCat("cross-sequence test: sessions ", options.train_session + 1, " (train) and ",
                       options.test_session + 1, " (test) asked for, the log has ", sessions));
  }
  const AdjacencyMap& map = localizer->map();
  std::vector<std::unique_ptr<OmniUnwrapper>> unwrappers(sessions);
  // Pixels outside a clipped ring or under the user mask do not count (descriptor.h).
  auto describe = [&](const Frame& f) -> Descriptor {
    const SessionInfo& info = source->Session(f.session_index);
    if (info.camera.kind == ImageKind::kPanorama) return localizer->Describe(f.image);
    auto& u = unwrappers[f.session_index];
    if (!u) {
      u = std::make_unique<OmniUnwrapper>(info.camera.calibration, info.camera.image_width,
                                          info.camera.image_height, info.camera.mask);
    }
    const cv::Mat panorama = u->Unwrap(f.image);
    return localizer->Describe(panorama, u->MaskFor(panorama.cols, panorama.rows));
  };
  CrossSequenceResult result;
  std::vector<std::pair<int, Descriptor>> train;
  std::vector<Descriptor> test_descriptors;
  Frame frame;
  std::int64_t labelled_train = 0;
  while (source->Next(&frame)) {
    const bool is_train = frame.session_index == options.train_session;
    const bool is_test = frame.session_index == options.test_session;
    if (!is_train && !is_test) continue;
    if (!frame.map_T_robot_truth) {
      throw Error(StrCat("cross-sequence test: frame ", frame.index_in_session, " of session ",
                         frame.session_index + 1, " has no ground truth (needed for the labels)"));
    }
    const int place = map.PlaceAt(frame.map_T_robot_truth->head<2>(), route);
    result.train_frames += is_train;
    TopologicalFrameResult labelled;
    labelled.stamp_s = frame.stamp_s;
    labelled.index_in_session = frame.index_in_session;
    labelled.map_T_robot_truth = *frame.map_T_robot_truth;
    labelled.true_place = place;
    std::optional<Descriptor> d;
    if (is_train && place >= 0 && labelled_train++ % options.reference_stride_frames == 0) {
      d = describe(frame);
      train.emplace_back(place, *d);
      result.reference_frames.push_back(labelled);
    }
    if (is_test) {
      if (!d) d = describe(frame);
      result.frames.push_back(labelled);
      test_descriptors.push_back(std::move(*d));
    }
  }
  // labelled_train counts the training frames that lie in a place.
  result.train_frames_without_place = result.train_frames - labelled_train;
  for (const auto& [place, d] : train) localizer->AddReference(place, d);
  result.references = static_cast<int>(train.size());
  for (int p = 0; p < map.size(); ++p)
    result.places_with_references += localizer->NumReferences(p) > 0;
  if (train.empty()) {
    throw Error(StrCat("cross-sequence test: session ", options.train_session + 1,
                       " gave no labelled reference image"));
  }
  if (localizer->options().learn_band_thresholds) {
    localizer->LearnBandThresholds(&result.calibration);
  }
  localizer->Reset(options.known_start && !result.frames.empty() ? result.frames[0].true_place
                                                                 : -1);
  TopologicalCounts& c = result.counts;
  for (std::size_t i = 0; i < result.frames.size(); ++i) {
    TopologicalFrameResult& r = result.frames[i];
    r.decision = localizer->Localize(test_descriptors[i]);
    r.believed_place = localizer->believed_place();
    if (r.true_place < 0) continue;
    ++c.frames;
    switch (r.decision.state) {
      case PlaceState::kConfident:
        ++(r.decision.place == r.true_place ? c.confident_correct : c.confident_wrong);
        break;
      case PlaceState::kUncertain:
        ++c.uncertain;
        break;
      case PlaceState::kConfused:
        ++c.confused;
        break;
    }
    c.belief_correct += r.believed_place == r.true_place;
  }
  return result;
}

std::string TopologicalSummaryTable(const TopologicalCounts& c, const std::string& title) {
  std::ostringstream os;
  auto row = [&](const std::string& name, std::int64_t n) {
    const double pct = c.frames > 0 ? 100.0 * static_cast<double>(n) / c.frames : 0.0;
    os << "| " << std::left << std::setw(18) << name << " | " << std::right << std::setw(6) << n
       << " | " << std::setw(6) << std::fixed << std::setprecision(1) << pct << " |\n";
  };
  os << "### " << title << "\n\n"
     << "| result             | frames |      % |\n"
     << "|--------------------|-------:|-------:|\n";
  row("confident correct", c.confident_correct);
  row("confident wrong", c.confident_wrong);
  row("uncertain", c.uncertain);
  row("confused", c.confused);
  row("total", c.frames);
  os << "\nbelief (last confident place) correct: " << c.belief_correct << " of " << c.frames
     << " frames\n";
  return os.str();
}

// ---- options (the schema of the header's VisitFields, common/options.h)

TopologicalOptions ParseTopologicalOptionsYaml(const std::string& yaml_text,
                                               const std::string& source) {
  return ParseOptionsYaml<TopologicalOptions>(yaml_text, source, TopologicalOptions{},
                                              kTopoRunKeys);
}
TopologicalOptions LoadTopologicalOptions(const std::string& path) {
  return ParseTopologicalOptionsYaml(ReadOptionFile(path), path);
}
std::string TopologicalOptionsToYaml(const TopologicalOptions& options) {
  return OptionsToYaml(options);
}

}  // namespace omnicml
