// Tests of the [UN] topological localizer: unanimous voting on crafted votes, the
// Jeffrey-divergence nearest neighbour on rendered places, the belief, adjacency maps
// (YAML errors, places from a route) and a short simulated cross-day test.
#include "omnicml/baselines/topo/topological.h"

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/sim/renderer.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"
#include "testing/masked_ring_source.h"

namespace omnicml {
namespace {

using ::testing::HasSubstr;

BandVotes UniformVotes(int place, double confidence) {
  BandVotes v;
  for (auto& b : v) {
    b.place = place;
    b.reference = 0;
    b.confidence = confidence;
  }
  return v;
}

// Message of the omnicml::Error thrown by f, or "" if none.
template <typename F>
std::string ErrorOf(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// All confident bands name the same place: confident, overall confidence = their sum.
TEST(TopologicalVote, UnanimousConfidentBandsGiveConfident) {
  const TopologicalOptions options;
  const PlaceDecision d = Vote(UniformVotes(2, 0.3), options);
  EXPECT_EQ(d.state, PlaceState::kConfident);
  EXPECT_EQ(d.place, 2);
  EXPECT_EQ(d.voting_bands, 6);
  EXPECT_NEAR(d.confidence, 1.8, 1e-12);
}

// Confident bands that disagree leave the robot confused.
TEST(TopologicalVote, DisagreeingConfidentBandsGiveConfused) {
  const TopologicalOptions options = UlrichNourbakhshOptions();
  BandVotes v = UniformVotes(1, 0.3);
  v[4].place = 2;
  v[4].confidence = 0.2;
  const PlaceDecision d = Vote(v, options);
  EXPECT_EQ(d.state, PlaceState::kConfused);
  EXPECT_EQ(d.place, -1);
  // A disagreeing band below its threshold does not vote: unanimous again.
  v[4].confidence = 0.01;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfident);
  EXPECT_EQ(Vote(v, options).place, 1);
}

// No band reaches its threshold: uncertain.
TEST(TopologicalVote, NoConfidentBandGivesUncertain) {
  const TopologicalOptions options;
  const PlaceDecision d = Vote(UniformVotes(0, 0.04), options);
  EXPECT_EQ(d.state, PlaceState::kUncertain);
  EXPECT_EQ(d.voting_bands, 0);
  BandVotes none;  // no reference images at all
  EXPECT_EQ(Vote(none, options).state, PlaceState::kUncertain);
}

// Unanimous but below the action threshold (0.1): uncertain; at or above: confident.
TEST(TopologicalVote, ActionThreshold) {
  TopologicalOptions options;
  EXPECT_DOUBLE_EQ(options.action_threshold, 0.1);
  BandVotes v = UniformVotes(3, 0.0);
  v[1].confidence = 0.06;  // the only voting band
  PlaceDecision d = Vote(v, options);
  EXPECT_EQ(d.state, PlaceState::kUncertain);
  EXPECT_EQ(d.place, 3);
  EXPECT_EQ(d.voting_bands, 1);
  v[2].confidence = 0.06;  // two bands: 0.12 >= 0.1
  d = Vote(v, options);
  EXPECT_EQ(d.state, PlaceState::kConfident);
  options.action_threshold = 0.2;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kUncertain);
  // Band thresholds are per band.
  options.action_threshold = 0.1;
  options.band_threshold[2] = 0.5;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kUncertain);
}

// A light-dependent band (L by default) that disagrees is outvoted whatever its
// confidence but uses up a tolerated dissent; under [UN]'s unanimity
// (max_dissenting_bands 0) it makes the frame confused like any band.
TEST(TopologicalVote, LightDependentBandOutvotedButCountsAsDissent) {
  TopologicalOptions options;
  ASSERT_EQ(options.max_dissenting_bands, 1);
  ASSERT_TRUE(options.light_dependent_bands[1]);
  BandVotes v = UniformVotes(1, 0.3);
  v[1].place = 2;  // L names another place, surer than the others
  v[1].confidence = 0.9;
  PlaceDecision d = Vote(v, options);
  EXPECT_EQ(d.state, PlaceState::kConfident);
  EXPECT_EQ(d.place, 1);
  EXPECT_EQ(d.voting_bands, 6);
  EXPECT_NEAR(d.confidence, 1.5, 1e-12);  // L's confidence is not subtracted
  EXPECT_EQ(Vote(v, UlrichNourbakhshOptions()).state, PlaceState::kConfused);
  // L and one more band dissent: two dissenters, one tolerated.
  v[4].place = 0;
  v[4].confidence = 0.1;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfused);
  // Agreeing, L adds its confidence.
  v = UniformVotes(1, 0.3);
  d = Vote(v, options);
  EXPECT_NEAR(d.confidence, 1.8, 1e-12);
  // Only L takes part: it decides.
  v = UniformVotes(1, 0.0);
  v[1].confidence = 0.3;
  d = Vote(v, options);
  EXPECT_EQ(d.state, PlaceState::kConfident);
  EXPECT_EQ(d.place, 1);
  // Not light-dependent: a surer dissenting L is not outvoted.
  options.light_dependent_bands.fill(false);
  v = UniformVotes(1, 0.3);
  v[1].place = 2;
  v[1].confidence = 0.9;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfused);
}

// max_dissenting_bands: up to k light-independent bands, each less sure than the
// agreeing bands on average, may name other places; the majority place wins with the dissenters'
// confidence subtracted; more dissenters, a surer dissenter or a tie is confused.
TEST(TopologicalVote, ToleratedDissentLowersConfidence) {
  TopologicalOptions options;
  options.light_dependent_bands.fill(false);
  options.max_dissenting_bands = 1;
  BandVotes v = UniformVotes(0, 0.3);
  v[5].place = 2;
  v[5].confidence = 0.2;
  PlaceDecision d = Vote(v, options);
  EXPECT_EQ(d.state, PlaceState::kConfident);
  EXPECT_EQ(d.place, 0);
  EXPECT_EQ(d.voting_bands, 6);
  EXPECT_NEAR(d.confidence, 5 * 0.3 - 0.2, 1e-12);
  v[4].place = 2;  // two dissenters
  v[4].confidence = 0.2;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfused);
  options.max_dissenting_bands = 2;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfident);
  // One band each for two places: a tie, confused whatever the tolerance.
  v = UniformVotes(0, 0.0);
  v[0].confidence = v[1].confidence = 0.5;
  v[1].place = 3;
  options.max_dissenting_bands = 5;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfused);
  EXPECT_EQ(Vote(v, options).place, -1);
  // Dissent eats the confidence: below the action threshold the frame is uncertain.
  v = UniformVotes(0, 0.0);
  v[0].confidence = v[1].confidence = 0.06;
  v[2].confidence = 0.05;
  v[2].place = 1;
  options.max_dissenting_bands = 1;
  d = Vote(v, options);
  EXPECT_EQ(d.state, PlaceState::kUncertain);
  EXPECT_EQ(d.place, 0);
  EXPECT_NEAR(d.confidence, 0.07, 1e-12);
  // A dissenter at least as sure as the agreeing bands on average is not outvoted.
  v[2].confidence = 0.06;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfused);
  v = UniformVotes(0, 0.3);
  v[5].place = 2;
  v[5].confidence = 0.31;
  EXPECT_EQ(Vote(v, options).state, PlaceState::kConfused);
}

TEST(TopologicalOptions, ValidateNamesTheField) {
  TopologicalOptions o;
  o.band_threshold[3] = 1.5;
  EXPECT_THAT(ErrorOf([&] { o.Validate(); }), HasSubstr("band_threshold[3]"));
  o = {};
  o.action_threshold = -1;
  EXPECT_THAT(ErrorOf([&] { o.Validate(); }), HasSubstr("action_threshold"));
  o = {};
  o.histogram.bins = 1;
  EXPECT_THAT(ErrorOf([&] { o.Validate(); }), HasSubstr("bins"));
  o = {};
  o.average_block_px = 0;
  EXPECT_THAT(ErrorOf([&] { o.Validate(); }), HasSubstr("average_block_px"));
  o = {};
  o.calibration_exclusion_frames = -1;
  EXPECT_THAT(ErrorOf([&] { o.Validate(); }), HasSubstr("calibration_exclusion_frames"));
  o = {};
  o.calibration_max_wrong = 1.5;
  EXPECT_THAT(ErrorOf([&] { o.Validate(); }), HasSubstr("calibration_max_wrong"));
}

// Three places in a row a - b - c.
AdjacencyMap LineMap() {
  std::vector<Place> places(3);
  for (int i = 0; i < 3; ++i) {
    places[i].name = std::string(1, static_cast<char>('a' + i));
    places[i].center_m = Eigen::Vector2d(2.0 * i, 0.0);
  }
  places[0].neighbours = {1};
  places[2].neighbours = {1};
  return AdjacencyMap(places);
}

// A colour-histogram descriptor whose every band puts the given weights on bins 2, 12, 22.
Descriptor Crafted(double w0, double w1, double w2,
                   int bins = TopologicalHistogramDefaults().bins) {
  Descriptor d;
  d.kind = DescriptorKind::kColorHistogram;
  d.features.assign(ColorHistogram::kBands * bins, 0.001f);
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    d.features[b * bins + 2] += static_cast<float>(w0);
    d.features[b * bins + 12] += static_cast<float>(w1);
    d.features[b * bins + 22] += static_cast<float>(w2);
  }
  return d;
}

// Two neighbouring places, 40 references each taken in one pass (a then b). Bands 0-2
// tell the places apart (a's mass on bin 2, b's on bin 12, slightly jittered); bands 3-5
// are drawn independently of the place (pseudo-random mass on bins 2 and 12).
TopologicalLocalizer TwoPlacesCleanAndNoisyBands(const TopologicalOptions& options = {}) {
  std::vector<Place> places(2);
  places[0].name = "a";
  places[1].name = "b";
  places[1].center_m = Eigen::Vector2d(2.0, 0.0);
  places[0].neighbours = {1};
  TopologicalLocalizer loc{AdjacencyMap(places), options};
  const int bins = options.histogram.bins;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int place = 0; place < 2; ++place) {
    for (int i = 0; i < 40; ++i) {
      Descriptor d;
      d.kind = DescriptorKind::kColorHistogram;
      d.features.assign(ColorHistogram::kBands * bins, 0.001f);
      for (int b = 0; b < ColorHistogram::kBands; ++b) {
        const double w = b < 3 ? (place == 0 ? 0.9 : 0.1) + 0.05 * u(rng) : u(rng);
        d.features[b * bins + 2] += static_cast<float>(w);
        d.features[b * bins + 12] += static_cast<float>(1.0 - w);
      }
      loc.AddReference(place, d);
    }
  }
  return loc;
}

// The learned thresholds keep the place-blind bands (many wrong votes) from voting and
// let the place-telling bands vote; deterministic; the localizer then votes with
// max(configured, learned) and keeps its configured options.
TEST(TopologicalLocalizer, LearnedBandThresholdsSilenceUninformativeBands) {
  TopologicalLocalizer loc = TwoPlacesCleanAndNoisyBands();
  BandCalibration cal;
  const auto t = loc.CalibrateBandThresholds(&cal);
  // References 19, 20 (a) and 59, 60 (b) have no reference of their place 21+ away.
  EXPECT_EQ(cal.queries, 76);
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    EXPECT_EQ(cal.votes[b], 76) << b;
    EXPECT_GE(t[b], 0.0) << b;
    EXPECT_LE(t[b], 1.0 + 1e-9) << b;
    if (b < 3) {
      EXPECT_EQ(cal.correct[b], 76) << b;
    } else {
      EXPECT_LT(cal.correct[b], 68) << b;
      EXPECT_GT(t[b], 0.9) << b;
    }
  }
  EXPECT_EQ(loc.CalibrateBandThresholds(), t);  // deterministic
  loc.LearnBandThresholds();
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    EXPECT_EQ(loc.effective_options().band_threshold[b],
              std::max(loc.options().band_threshold[b], t[b]));
    EXPECT_EQ(loc.options().band_threshold[b], TopologicalOptions{}.band_threshold[b]);
  }
  // An image of a whose place-blind bands lean to b: the clean bands decide.
  const int bins = loc.options().histogram.bins;
  Descriptor q;
  q.kind = DescriptorKind::kColorHistogram;
  q.features.assign(ColorHistogram::kBands * bins, 0.001f);
  for (int b = 0; b < ColorHistogram::kBands; ++b) {
    q.features[b * bins + 2] += b < 3 ? 0.92f : 0.2f;
    q.features[b * bins + 12] += b < 3 ? 0.08f : 0.8f;
  }
  loc.Reset();
  const PlaceDecision d = loc.Localize(q);
  EXPECT_EQ(d.state, PlaceState::kConfident);
  EXPECT_EQ(d.place, 0);
  EXPECT_EQ(d.voting_bands, 3);
}

// With the default 4 x 4 block averages, the hue and chromaticity histograms of a dark,
// noisy copy of a rendered panorama stay much closer to those of the bright original
// than without (the sensor noise would scatter the dark near-grey pixels).
TEST(TopologicalLocalizer, BlockAveragesSteadyChromaticityOfDarkNoisyImages) {
  const World world = LoadBuiltinWorld("institute");
  Renderer renderer(world);
  const cv::Mat bright = renderer.RenderPanorama(Pose2(7.5, 7.5, 0.3));
  cv::Mat dark;
  bright.convertTo(dark, CV_32FC3, 0.25);
  cv::Mat noise(dark.size(), CV_32FC3);
  cv::RNG rng(3);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, 2.0);
  dark += noise;
  dark.convertTo(dark, CV_8UC3);
  auto chroma_distance = [&](int block) {
    TopologicalOptions options;
    options.average_block_px = block;
    const TopologicalLocalizer loc(LineMap(), options);
    const int bins = options.histogram.bins;
    const Descriptor a = loc.Describe(bright), b = loc.Describe(dark);
    double d = 0.0;
    for (int band : {0, 3, 4, 5}) {  // H, r, g, b
      d += ColorHistogram::JeffreyDivergence(a.features.data() + band * bins,
                                             b.features.data() + band * bins, bins);
    }
    return d;
  };
  EXPECT_EQ(TopologicalOptions{}.average_block_px, 4);
  EXPECT_LT(chroma_distance(4), 0.5 * chroma_distance(1));
}

// A query never matches a reference within calibration_exclusion_frames of itself: with a
// window wider than a place's pass no query has a reference of its place left.
TEST(TopologicalLocalizer, CalibrationExcludesNearbyReferences) {
  TopologicalOptions options;
  options.calibration_exclusion_frames = 40;
  BandCalibration cal;
  TwoPlacesCleanAndNoisyBands(options).CalibrateBandThresholds(&cal);
  EXPECT_EQ(cal.queries, 0);
  for (int b = 0; b < ColorHistogram::kBands; ++b) EXPECT_EQ(cal.votes[b], 0);
  options.calibration_exclusion_frames = 0;
  TwoPlacesCleanAndNoisyBands(options).CalibrateBandThresholds(&cal);
  EXPECT_EQ(cal.queries, 80);
  EXPECT_EQ(cal.correct[0], 80);
}

// The belief follows confident answers only and stays at the last confident place
// through uncertain and confused frames; candidates are the place and its neighbours.
TEST(TopologicalLocalizer, BeliefStaysAtLastConfidentPlace) {
  const AdjacencyMap map = LineMap();
  EXPECT_TRUE(map.AreNeighbours(1, 0));  // made symmetric
  TopologicalLocalizer loc(map);
  loc.AddReference(0, Crafted(1, 0, 0));
  loc.AddReference(1, Crafted(0, 1, 0));
  loc.AddReference(2, Crafted(0, 0, 1));
  loc.Reset();
  EXPECT_EQ(loc.believed_place(), -1);
  EXPECT_EQ(loc.CandidatePlaces(), (std::vector<int>{0, 1, 2}));

  PlaceDecision d = loc.Localize(Crafted(0.05, 1, 0));
  EXPECT_EQ(d.state, PlaceState::kConfident);
  EXPECT_EQ(d.place, 1);
  EXPECT_EQ(loc.believed_place(), 1);

  // Half place a, half place c: a tie between a and c in every band -> uncertain.
  d = loc.Localize(Crafted(0.5, 0, 0.5));
  EXPECT_EQ(d.state, PlaceState::kUncertain);
  EXPECT_EQ(loc.believed_place(), 1);

  // Bands 0-2 look like a, bands 3-5 like c -> confused.
  Descriptor mixed = Crafted(1, 0, 0);
  const Descriptor c = Crafted(0, 0, 1);
  const int bins = TopologicalHistogramDefaults().bins;
  std::copy(c.features.begin() + 3 * bins, c.features.end(), mixed.features.begin() + 3 * bins);
  d = loc.Localize(mixed);
  EXPECT_EQ(d.state, PlaceState::kConfused);
  EXPECT_EQ(loc.believed_place(), 1);

  d = loc.Localize(Crafted(0, 0, 1));
  EXPECT_EQ(d.state, PlaceState::kConfident);
  EXPECT_EQ(loc.believed_place(), 2);
  EXPECT_EQ(loc.CandidatePlaces(), (std::vector<int>{1, 2}));
  // Place a is not a neighbour of c: an image of a now matches b or c, never a.
  d = loc.Localize(Crafted(1, 0, 0));
  for (const BandVote& v : d.bands) EXPECT_NE(v.place, 0);
}

// Only with global_search_after_frames > 0 does a robot whose belief is wrong compare with
// all places again, after that many non-confident frames.
TEST(TopologicalLocalizer, GlobalSearchAfterNonConfidentFrames) {
  for (int after : {0, 2}) {
    TopologicalOptions options;
    options.global_search_after_frames = after;
    TopologicalLocalizer loc(LineMap(), options);
    loc.AddReference(0, Crafted(1, 0, 0));
    loc.AddReference(1, Crafted(0, 1, 0));
    loc.AddReference(2, Crafted(0, 0, 1));
    loc.Reset(2);
    EXPECT_EQ(loc.believed_place(), 2);
    // An image of a, while believed at c: b and c tie -> uncertain.
    EXPECT_EQ(loc.Localize(Crafted(1, 0.05, 0.05)).state, PlaceState::kUncertain);
    EXPECT_EQ(loc.Localize(Crafted(1, 0.05, 0.05)).state, PlaceState::kUncertain);
    const PlaceDecision d = loc.Localize(Crafted(1, 0.05, 0.05));
    if (after == 0) {
      EXPECT_EQ(d.state, PlaceState::kUncertain);
      EXPECT_EQ(loc.believed_place(), 2);
    } else {
      EXPECT_EQ(d.state, PlaceState::kConfident);
      EXPECT_EQ(loc.believed_place(), 0);
      EXPECT_EQ(loc.CandidatePlaces(), (std::vector<int>{0, 1}));
    }
  }
}

// Per band, the Jeffrey-divergence nearest neighbour picks the place the query was
// rendered at, between two distinct places of home_store (query 0.3 m away, turned).
TEST(TopologicalLocalizer, JeffreyNearestNeighbourPicksRenderedPlace) {
  const World world = LoadBuiltinWorld("home_store");
  Renderer renderer(world);
  const RoutePath route(world.route.waypoints_m, world.route.turn_radius_m);
  const double s_a = 6.0, s_b = 30.0;
  std::vector<Place> places(2);
  places[0].name = "A";
  places[0].center_m = route.PoseAt(s_a).head<2>();
  places[1].name = "B";
  places[1].center_m = route.PoseAt(s_b).head<2>();
  places[0].neighbours = {1};
  TopologicalOptions options;
  ASSERT_EQ(options.histogram.distance, HistogramDistance::kJeffrey);
  TopologicalLocalizer loc(AdjacencyMap(places), options);
  loc.AddReference(0, loc.Describe(renderer.RenderPanorama(route.PoseAt(s_a))));
  loc.AddReference(1, loc.Describe(renderer.RenderPanorama(route.PoseAt(s_b))));
  for (int truth = 0; truth < 2; ++truth) {
    Pose2 pose = route.PoseAt((truth == 0 ? s_a : s_b) + 0.3);
    pose.z() = WrapAngle(pose.z() + 1.0);
    const BandVotes votes = loc.ClassifyBands(loc.Describe(renderer.RenderPanorama(pose)), {0, 1});
    for (int b = 0; b < ColorHistogram::kBands; ++b) {
      EXPECT_EQ(votes[b].place, truth) << "band " << b;
      EXPECT_GT(votes[b].confidence, 0.0) << "band " << b;
      EXPECT_LT(votes[b].distance_nn, votes[b].distance_other) << "band " << b;
    }
    EXPECT_EQ(Vote(votes, options).state, PlaceState::kConfident);
  }
}

// Unknown keys and bad values are errors naming the file, the line and the key.
TEST(AdjacencyMap, YamlErrorsNameFileAndKey) {
  const std::string ok =
      "places:\n"
      "  - {name: dock, center_m: [1, 1], neighbours: [aisle]}\n"
      "  - {name: aisle, polygon_m: [[2, 0], [4, 0], [4, 2], [2, 2]]}\n"
      "  - {name: back, route_interval_m: [10, 20], neighbours: [aisle]}\n";
  const AdjacencyMap map = ParseAdjacencyMap(ok, "places.yaml");
  ASSERT_EQ(map.size(), 3);
  EXPECT_TRUE(map.AreNeighbours(1, 0));
  EXPECT_TRUE(map.AreNeighbours(1, 2));
  EXPECT_FALSE(map.AreNeighbours(0, 2));
  EXPECT_EQ(map.PlaceAt(Eigen::Vector2d(3, 1), nullptr), 1);  // inside the polygon
  EXPECT_THAT(ErrorOf([&] { map.PlaceAt(Eigen::Vector2d(9, 9)); }), HasSubstr("route"));

  EXPECT_THAT(ErrorOf([] {
                ParseAdjacencyMap("places:\n  - name: a\n    center_m: [0, 0]\n    colour: red\n",
                                  "places.yaml");
              }),
              HasSubstr("places.yaml:4: places[0].colour: unknown key"));
  EXPECT_THAT(ErrorOf([] { ParseAdjacencyMap("places: []\nscale: 2\n", "m.yaml"); }),
              HasSubstr("m.yaml:2: scale: unknown key"));
  EXPECT_THAT(ErrorOf([] {
                ParseAdjacencyMap("places:\n  - {name: a, center_m: [0, 0], neighbours: [zz]}\n",
                                  "p.yaml");
              }),
              HasSubstr("p.yaml:2: places[0].neighbours: unknown place 'zz'"));
  EXPECT_THAT(ErrorOf([] { ParseAdjacencyMap("places:\n  - {name: a}\n", "p.yaml"); }),
              HasSubstr("p.yaml:2: places[0].center_m|polygon_m|route_interval_m"));
  EXPECT_THAT(
      ErrorOf([] { ParseAdjacencyMap("places:\n  - {name: a, center_m: [0, x]}\n", "p.yaml"); }),
      HasSubstr("p.yaml:2: places[0].center_m"));
  EXPECT_THAT(ErrorOf([] { ParseAdjacencyMap("places: [\n", "p.yaml"); }), HasSubstr("p.yaml:"));
  EXPECT_THAT(ErrorOf([] { LoadAdjacencyMap("/nonexistent/places.yaml"); }),
              HasSubstr("/nonexistent/places.yaml"));

  // Written and read back: the same map.
  const AdjacencyMap again = ParseAdjacencyMap(AdjacencyMapYaml(map), "again.yaml");
  ASSERT_EQ(again.size(), 3);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(again.places()[i].name, map.places()[i].name);
    EXPECT_EQ(again.places()[i].neighbours, map.places()[i].neighbours);
    EXPECT_EQ(again.places()[i].region, map.places()[i].region);
  }
}

// Places from a route: spaced about place_length_m apart, every route point in a place,
// consecutive places neighbours; the institute's corridor driven up and down shares places.
TEST(AdjacencyMap, PlacesFromRouteShareStretchesDrivenTwice) {
  const World world = LoadBuiltinWorld("institute");
  const RoutePath route(world.route.waypoints_m, world.route.turn_radius_m);
  const AdjacencyMap map = PlacesFromRoute(route, 2.0);
  EXPECT_GT(map.size(), 5);
  EXPECT_LT(map.size(), static_cast<int>(route.length_m() / 2.0));  // fewer than a split by length
  int previous = map.PlaceAt(route.PoseAt(0).head<2>());
  for (double s = 0.1; s < route.length_m(); s += 0.1) {
    const int p = map.PlaceAt(route.PoseAt(s).head<2>());
    ASSERT_GE(p, 0);
    if (p != previous) {
      EXPECT_TRUE(map.AreNeighbours(previous, p)) << "s=" << s;
    }
    previous = p;
  }
  // Up the corridor at x = 4.6 and down at x = 5.4: the same place.
  EXPECT_EQ(map.PlaceAt(Eigen::Vector2d(4.6, 3.0)), map.PlaceAt(Eigen::Vector2d(5.4, 3.0)));
  EXPECT_THAT(ErrorOf([&] { PlacesFromRoute(route, 0.0); }), HasSubstr("place_length_m"));
}

// Places that cover only part of the floor (the west half of home_store): frames outside
// them give no reference and are not counted, and the result says how many there were.
TEST(TopologicalLocalizer, FramesOutsideEveryPlaceAreCountedApart) {
  SimulatorOptions sim;
  sim.world = "home_store";
  sim.days = 2;
  sim.frames_per_day = 120;
  sim.seed = 1;
  sim.step_m = 0.5;
  sim.output = ImageKind::kPanorama;
  SimulatedFrameSource source(sim);
  const AdjacencyMap map = ParseAdjacencyMap(
      "places:\n"
      "  - {name: west, polygon_m: [[0, 0], [6, 0], [6, 10], [0, 10]], neighbours: [middle]}\n"
      "  - {name: middle, polygon_m: [[6, 0], [12.5, 0], [12.5, 10], [6, 10]]}\n",
      "west_half.yaml");
  TopologicalLocalizer loc(map);
  const CrossSequenceResult r = RunCrossSequence(&source, &loc, CrossSequenceOptions{});
  EXPECT_EQ(r.train_frames, 120);
  EXPECT_GT(r.train_frames_without_place, 0);
  EXPECT_EQ(r.train_frames - r.train_frames_without_place, r.references);
  std::int64_t unlabelled = 0;
  for (const auto& f : r.frames) unlabelled += f.true_place < 0;
  EXPECT_GT(unlabelled, 0);
  EXPECT_EQ(r.test_frames_without_place(), unlabelled);
  EXPECT_EQ(r.counts.frames + unlabelled, static_cast<std::int64_t>(r.frames.size()));
}

// The session's user mask reaches the histograms of the cross-sequence test: noise under
// the mask changes no belief and no descriptor; without the declared mask it does.
TEST(TopologicalLocalizer, MaskedPixelsDoNotChangeTheCrossSequenceResult) {
  SimulatorOptions sim;
  sim.world = "home_store";
  sim.days = 2;
  sim.frames_per_day = 30;
  sim.seed = 1;
  sim.step_m = 0.8;
  sim.people = false;
  const auto run = [&](bool declare_mask, bool scramble) {
    testing::MaskedRingSource source(sim, declare_mask, scramble);
    SimulatedFrameSource route_source(sim);
    TopologicalLocalizer loc(PlacesFromRoute(route_source.route(), 3.0));
    return RunCrossSequence(&source, &loc, CrossSequenceOptions{}, &route_source.route());
  };
  const CrossSequenceResult clean = run(true, false), scrambled = run(true, true);
  ASSERT_EQ(clean.frames.size(), scrambled.frames.size());
  ASSERT_FALSE(clean.frames.empty());
  for (std::size_t i = 0; i < clean.frames.size(); ++i) {
    EXPECT_EQ(clean.frames[i].believed_place, scrambled.frames[i].believed_place) << "frame " << i;
  }
  EXPECT_EQ(clean.counts.frames, scrambled.counts.frames);

  // The same panorama through Describe(panorama, mask): identical histograms.
  SimulatorOptions one = sim;
  one.days = 1;
  one.frames_per_day = 1;
  testing::MaskedRingSource a(one, true, false), b(one, true, true);
  Frame fa, fb;
  ASSERT_TRUE(a.Next(&fa) && b.Next(&fb));
  const CameraModel& camera = a.Session(0).camera;
  const OmniUnwrapper unwrapper(camera.calibration, camera.image_width, camera.image_height,
                                camera.mask);
  const cv::Mat pa = unwrapper.Unwrap(fa.image), pb = unwrapper.Unwrap(fb.image);
  const cv::Mat mask = unwrapper.MaskFor(pa.cols, pa.rows);
  ASSERT_FALSE(mask.empty());
  TopologicalLocalizer loc(PlacesFromRoute(SimulatedFrameSource(one).route(), 3.0));
  EXPECT_EQ(loc.Describe(pa, mask).features, loc.Describe(pb, mask).features);
  EXPECT_NE(loc.Describe(pa).features, loc.Describe(pb).features);
}

// A short cross-day test on the simulated home_store (train on day 1, test on day 2),
// seeds 1-3: most confident answers are right and the belief is mostly right.
TEST(TopologicalLocalizer, SimulatedCrossDayMostlyCorrect) {
  for (std::uint64_t seed : {1u, 2u, 3u}) {
    SCOPED_TRACE(StrCat("seed ", seed));
    SimulatorOptions sim;
    sim.world = "home_store";
    sim.days = 2;
    sim.frames_per_day = 200;
    sim.seed = seed;
    sim.step_m = 0.3;
    sim.output = ImageKind::kPanorama;
    SimulatedFrameSource source(sim);
    const AdjacencyMap map = PlacesFromRoute(source.route(), 3.0);
    TopologicalLocalizer loc(map);
    CrossSequenceOptions cross;
    cross.train_session = 0;
    cross.test_session = 1;
    const CrossSequenceResult r = RunCrossSequence(&source, &loc, cross, &source.route());
    const TopologicalCounts& c = r.counts;
    ASSERT_EQ(c.frames, 200);
    // Route places cover every position.
    EXPECT_EQ(r.train_frames, 200);
    EXPECT_EQ(r.train_frames_without_place, 0);
    EXPECT_EQ(r.test_frames_without_place(), 0);
    EXPECT_EQ(c.confident_correct + c.confident_wrong + c.uncertain + c.confused, c.frames);
    const double confident = static_cast<double>(c.confident_correct + c.confident_wrong);
    std::cout << TopologicalSummaryTable(c, StrCat("home_store day 1 -> day 2, seed ", seed));
    ASSERT_GT(confident, 0.5 * c.frames);
    EXPECT_GT(c.confident_correct / confident, 0.9);  // 0.99 / 0.97 / 0.96 at writing
    EXPECT_GT(static_cast<double>(c.belief_correct) / c.frames, 0.7);
    // reference_frames are the training frames in reference order: one per reference,
    // all from day 1, and every band's nearest reference lies in the place the band names.
    ASSERT_EQ(static_cast<int>(r.reference_frames.size()), r.references);
    ASSERT_EQ(r.references, loc.NumReferences());
    for (const auto& ref : r.reference_frames) {
      EXPECT_EQ(map.PlaceAt(ref.map_T_robot_truth.head<2>(), &source.route()), ref.true_place);
    }
    for (const auto& f : r.frames) {
      for (const BandVote& v : f.decision.bands) {
        if (v.reference < 0) continue;
        ASSERT_LT(v.reference, r.references);
        EXPECT_EQ(r.reference_frames[v.reference].true_place, v.place);
      }
    }
  }
}

// Institute with the repository's room places (datasets/places/
// institute_rooms.yaml, the corridor one place as in [UN]), train day 1, test day 2, on
// several seeds (short laps): confident answers are rarely wrong (target:
// <= 1 %, i.e. at most one of the 90 frames; 0 on each seed with the defaults).
TEST(TopologicalLocalizer, InstituteRoomsRarelyConfidentWrongOnSeveralSeeds) {
  const AdjacencyMap map =
      LoadAdjacencyMap(std::string(OMNICML_SOURCE_DIR) + "/datasets/places/institute_rooms.yaml");
  for (std::uint64_t seed : {1u, 2u, 3u}) {
    SimulatorOptions sim;
    sim.world = "institute";
    sim.days = 2;
    sim.frames_per_day = 90;  // one 36 m lap at 0.4 m a frame
    sim.step_m = 0.4;
    sim.seed = seed;
    sim.output = ImageKind::kPanorama;
    SimulatedFrameSource source(sim);
    TopologicalLocalizer loc(map);
    CrossSequenceOptions cross;
    cross.train_session = 0;
    cross.test_session = 1;
    const TopologicalCounts c = RunCrossSequence(&source, &loc, cross).counts;
    std::cout << TopologicalSummaryTable(c, StrCat("institute rooms seed ", seed, " day 1 -> 2"));
    ASSERT_EQ(c.frames, 90);
    EXPECT_LE(c.confident_wrong, 1) << "seed " << seed;
    EXPECT_GT(c.confident_correct, 0.4 * c.frames) << "seed " << seed;
  }
}

// The localizer's decision on a synthetic pair of places under a light change: place A
// is a bright panorama, place B another, dark one; the query is A with its light dimmed
// to 30 % (plus sensor noise). [UN]'s HLS L (and S) then name the dark place B, so
// [UN]'s bands and vote (UlrichNourbakhshOptions) are not confidently right; with the
// defaults (HSV S, relative luminance, L light-dependent) the query is A, confidently.
TEST(TopologicalLocalizer, DimmedPlaceRecognisedDespiteLuminance) {
  std::vector<Place> places(2);
  places[0].name = "A";
  places[1].name = "B";
  places[1].center_m = Eigen::Vector2d(5.0, 0.0);
  places[0].neighbours = {1};
  const AdjacencyMap map(places);
  auto scaled = [](const cv::Mat& image, double factor, std::uint64_t noise_seed) {
    cv::Mat f;
    image.convertTo(f, CV_32FC3, factor);
    cv::Mat noise(f.size(), CV_32FC3);
    cv::RNG rng(noise_seed);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, 2.0);
    f += noise;
    cv::Mat out;
    f.convertTo(out, CV_8UC3);
    return out;
  };
  for (std::uint32_t seed = 1; seed <= 4; ++seed) {
    const cv::Mat a = MakeSyntheticPanorama(720, 120, seed);
    const cv::Mat b = scaled(MakeSyntheticPanorama(720, 120, seed + 100), 0.3, 7 * seed);
    const cv::Mat query = scaled(RollColumns(a, 200), 0.3, 7 * seed + 1);
    auto decide = [&](const TopologicalOptions& options) {
      TopologicalLocalizer loc(map, options);
      loc.AddReference(0, loc.Describe(scaled(a, 1.0, 7 * seed + 2)));
      loc.AddReference(1, loc.Describe(b));
      loc.Reset(0);
      return loc.Localize(loc.Describe(query));
    };
    const PlaceDecision with_defaults = decide(TopologicalOptions{});
    EXPECT_EQ(with_defaults.state, PlaceState::kConfident) << "seed " << seed;
    EXPECT_EQ(with_defaults.place, 0) << "seed " << seed;
    const PlaceDecision published = decide(UlrichNourbakhshOptions());
    EXPECT_EQ(published.bands[1].place, 1) << "seed " << seed;  // HLS L: the dark place
    EXPECT_FALSE(published.state == PlaceState::kConfident && published.place == 0)
        << "seed " << seed;
  }
}

// The cross-sequence test over a written log of raw ring images (unwrapped with the
// session's calibration), areas as polygon places: deterministic, mostly right, and bad
// session indices are errors.
TEST(TopologicalLocalizer, CrossSequenceOverRawRingLog) {
  namespace fs = std::filesystem;
  const fs::path dir =
      fs::temp_directory_path() / ("omnicml_topo_test_log_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  {
    SimulatorOptions sim;
    sim.world = "home_store";
    sim.days = 2;
    sim.frames_per_day = 60;
    sim.step_m = 0.95;
    sim.seed = 5;
    sim.output = ImageKind::kRawRing;
    SimulatedFrameSource source(sim);
    LogWriter writer(dir.string());
    WriteFrames(source, writer);
    writer.Finish();
  }
  const AdjacencyMap map = ParseAdjacencyMap(
      "places:\n"
      "  - {name: west_end, polygon_m: [[0, 0], [2.8, 0], [2.8, 6.2], [0, 6.2]], neighbours: "
      "[front_west, middle_west]}\n"
      "  - {name: front_west, polygon_m: [[2.8, 0], [12.5, 0], [12.5, 2.4], [2.8, 2.4]], "
      "neighbours: [front_east]}\n"
      "  - {name: front_east, polygon_m: [[12.5, 0], [21.5, 0], [21.5, 2.4], [12.5, 2.4]], "
      "neighbours: [east_end]}\n"
      "  - {name: east_end, polygon_m: [[21.5, 0], [25, 0], [25, 10], [21.5, 10]], neighbours: "
      "[back_east]}\n"
      "  - {name: back_east, polygon_m: [[11.5, 7.6], [21.5, 7.6], [21.5, 10], [11.5, 10]], "
      "neighbours: [cross_aisle]}\n"
      "  - {name: cross_aisle, polygon_m: [[11.5, 2.4], [13.5, 2.4], [13.5, 7.6], [11.5, 7.6]], "
      "neighbours: [middle_west]}\n"
      "  - {name: middle_west, polygon_m: [[2.8, 2.4], [11.5, 2.4], [11.5, 6.4], [2.8, 6.4]]}\n",
      "home_store_areas.yaml");
  CrossSequenceOptions cross;
  cross.train_session = 0;
  cross.test_session = 1;
  std::vector<CrossSequenceResult> runs;
  for (int run = 0; run < 2; ++run) {
    LogReader reader(dir.string());
    TopologicalLocalizer loc(map);
    runs.push_back(RunCrossSequence(&reader, &loc, cross));
  }
  const TopologicalCounts& c = runs[0].counts;
  std::cout << TopologicalSummaryTable(c, "home_store areas, raw ring log, day 1 -> day 2");
  ASSERT_EQ(c.frames, 60);
  EXPECT_EQ(runs[0].places_with_references, 7);
  EXPECT_GT(c.confident_correct, 0.6 * c.frames);
  EXPECT_LE(c.confident_wrong, 0.05 * c.frames);
  ASSERT_EQ(runs[1].frames.size(), runs[0].frames.size());
  for (std::size_t i = 0; i < runs[0].frames.size(); ++i) {
    EXPECT_EQ(runs[1].frames[i].decision.state, runs[0].frames[i].decision.state);
    EXPECT_EQ(runs[1].frames[i].decision.confidence, runs[0].frames[i].decision.confidence);
  }
  cross.test_session = 2;
  LogReader reader(dir.string());
  TopologicalLocalizer loc(map);
  EXPECT_THAT(ErrorOf([&] { RunCrossSequence(&reader, &loc, cross); }), HasSubstr("the log has 2"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omnicml
