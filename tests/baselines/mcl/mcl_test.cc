#include "omnicml/baselines/mcl/mcl.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <random>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"
#include "omnicml/sim/simulator.h"
#include "omnicml/sim/world.h"
#include "testing/masked_ring_source.h"

namespace omnicml {
namespace {

using ::testing::HasSubstr;

// ------------------------------------------------------------------ crafted fixtures

// A 10 x 10 m open room (0.1 m cells) with a closed border.
OccupancyGrid OpenRoom() {
  OccupancyGrid g(100, 100, 0.1, Eigen::Vector2d(0, 0));
  for (int i = 0; i < 100; ++i) {
    g.Set({i, 0}, CellState::kOccupied);
    g.Set({i, 99}, CellState::kOccupied);
    g.Set({0, i}, CellState::kOccupied);
    g.Set({99, i}, CellState::kOccupied);
  }
  return g;
}

// An IFH-kind descriptor (features v, 1 - v) for crafted similarities.
Descriptor OneNumber(float v) {
  Descriptor d;
  d.kind = DescriptorKind::kInvariantFeatureHistogram;
  d.features = {v, 1.0f - v};
  return d;
}

std::shared_ptr<const DescriptorExtractor> Ifh() {
  DescriptorOptions o;
  o.kind = DescriptorKind::kInvariantFeatureHistogram;
  return MakeDescriptorExtractor(o);
}

// ------------------------------------------------------------------ resampling

// Low-variance resampling keeps the distribution: counts per source particle follow the
// weights (chi-square over 5 bins at a fixed seed), and the mean and variance of a
// 1-D weighted set are preserved.
TEST(Mcl, LowVarianceResamplingKeepsTheDistribution) {
  std::mt19937_64 rng(3);
  const std::vector<double> w = {0.1, 0.2, 0.3, 0.15, 0.25};
  std::vector<Particle> set;
  for (std::size_t i = 0; i < w.size(); ++i) set.push_back({MakePose(double(i), 0, 0), w[i]});
  const int n = 1000;
  std::vector<int> counts(w.size(), 0);
  for (const Particle& p : LowVarianceResample(set, n, rng)) ++counts[static_cast<int>(p.pose.x())];
  double chi2 = 0;
  for (std::size_t i = 0; i < w.size(); ++i) {
    const double e = n * w[i];
    chi2 += (counts[i] - e) * (counts[i] - e) / e;
    // Systematic resampling is within one of the expectation.
    EXPECT_NEAR(counts[i], e, 1.0 + 1e-9);
  }
  EXPECT_LT(chi2, 9.49);  // 95 % quantile, 4 degrees of freedom

  // A continuous weighted set: Gaussian samples weighted by exp(x): mean and variance.
  std::normal_distribution<double> n01(0, 1);
  std::vector<Particle> cont;
  double sw = 0, sx = 0, sxx = 0;
  for (int i = 0; i < 20000; ++i) {
    const double x = n01(rng);
    const double wt = std::exp(0.5 * x);
    cont.push_back({MakePose(x, 0, 0), wt});
    sw += wt;
    sx += wt * x;
  }
  const double mean = sx / sw;
  for (const auto& p : cont) sxx += p.weight * (p.pose.x() - mean) * (p.pose.x() - mean);
  const double var = sxx / sw;
  const auto out = LowVarianceResample(cont, 20000, rng);
  double m = 0, v = 0;
  for (const auto& p : out) m += p.pose.x();
  m /= out.size();
  for (const auto& p : out) v += (p.pose.x() - m) * (p.pose.x() - m);
  v /= out.size();
  EXPECT_NEAR(m, mean, 0.02);  // theory: mean 0.5, variance 1
  EXPECT_NEAR(v, var, 0.03);
  for (const auto& p : out) EXPECT_DOUBLE_EQ(p.weight, 1.0 / 20000);
  EXPECT_THROW(LowVarianceResample({{Pose2::Zero(), 0.0}}, 3, rng), Error);
}

// ------------------------------------------------------------------ weights (7)-(8)

// The visibility areas' cut-off follows the references' spacing: the median distance
// between consecutive references (coincident ones ignored; a second lap close to the
// first does not shrink it), times
// visibility_radius_spacings, unless a distance in metres is given; never below a cell.
TEST(Mcl, VisibilityRadiusFollowsReferenceSpacing) {
  const OccupancyGrid g = OpenRoom();
  const auto refs_every = [](double spacing_m) {
    std::vector<MclReference> refs;
    for (int lap = 0; lap < 2; ++lap) {  // the route twice, the second lap 2 cm aside
      for (int i = 0; i < 6; ++i) {
        MclReference r;
        r.map_T_robot = MakePose(2.0 + i * spacing_m, 5 + 0.02 * lap, 0);
        refs.push_back(r);
        if (i == 2) refs.push_back(r);  // a robot standing still: a coincident reference
      }
    }
    return refs;
  };
  EXPECT_NEAR(MedianReferenceSpacing(refs_every(0.4)), 0.4, 1e-12);
  EXPECT_NEAR(MedianReferenceSpacing(refs_every(0.8)), 0.8, 1e-12);
  EXPECT_EQ(MedianReferenceSpacing(std::vector<MclReference>(3)), 0.0);  // all coincident

  MclOptions o;
  ASSERT_EQ(o.visibility.max_distance_from_reference_m, 0.0);  // derived by default
  EXPECT_NEAR(VisibilityRadius(g, o, refs_every(0.4)), o.visibility_radius_spacings * 0.4, 1e-12);
  // Twice the spacing, twice the radius: the same areas in units of the data's scale.
  EXPECT_NEAR(VisibilityRadius(g, o, refs_every(0.8)),
              2.0 * VisibilityRadius(g, o, refs_every(0.4)), 1e-12);
  // Never below the grid's cell size (references 1 cm apart on a 0.1 m grid).
  EXPECT_EQ(VisibilityRadius(g, o, refs_every(0.01)), g.resolution_m());
  // An explicit distance overrides; both 0 means no cut-off.
  o.visibility.max_distance_from_reference_m = 1.5;
  EXPECT_EQ(VisibilityRadius(g, o, refs_every(0.4)), 1.5);
  o.visibility.max_distance_from_reference_m = 0.0;
  o.visibility_radius_spacings = 0.0;
  EXPECT_EQ(VisibilityRadius(g, o, refs_every(0.4)), 0.0);

  // The areas are cut at the derived radius: every cell within it of its reference.
  MclOptions d;
  d.visibility.max_ray_range_m = 20;
  d.visibility.max_distance_m = 20;
  std::vector<MclReference> refs = refs_every(0.8);
  const double radius = ComputeVisibilityAreas(g, d, &refs);
  EXPECT_NEAR(radius, d.visibility_radius_spacings * 0.8, 1e-12);
  std::size_t cells = 0;
  for (const MclReference& r : refs) {
    for (const int c : r.visibility) {
      const Eigen::Vector2d centre = g.CellCenter(g.FromLinear(c));
      EXPECT_LE((centre - r.map_T_robot.head<2>()).norm(), radius + 1e-9);
      ++cells;
    }
  }
  EXPECT_GT(cells, 0u);
}

// [W] eqs. (7)-(8): inside visibility areas the weight is the d-gated mean of xi over the
// covering references (normalisation K_i); outside every area it falls back to the prior.
TEST(Mcl, LikelihoodNormalisationAndPriorFallback) {
  const OccupancyGrid g = OpenRoom();
  std::vector<MclReference> refs(2);
  refs[0].map_T_robot = MakePose(3, 5, 0);  // looks at the right wall
  refs[0].descriptor = OneNumber(0.2f);
  refs[1].map_T_robot = MakePose(4, 5, 0);
  refs[1].descriptor = OneNumber(0.8f);
  MclOptions o;
  o.num_particles = 100;
  o.random_samples_per_step = 0;
  o.top_k = 0;
  o.prior_fraction = 0.5;
  o.visibility = {.max_ray_range_m = 20,
                  .max_distance_m = 20,
                  .max_view_angle_rad = kPi / 4,
                  .max_distance_from_reference_m = 1.5};
  ComputeVisibilityAreas(g, o, &refs);
  ASSERT_FALSE(refs[0].visibility.empty());
  MonteCarloLocalizer mcl(o, g, refs, Ifh());
  const std::vector<double> xi = {0.9, 0.3};
  // Covered by both: mean of xi (K = 2).
  EXPECT_NEAR(mcl.Likelihood(MakePose(3.5, 5, 2.0), xi), 0.6, 1e-12);
  // Covered by reference 0 only (x = 2, 1 m from it, 2 m from reference 1).
  EXPECT_NEAR(mcl.Likelihood(MakePose(2.0, 5, 0), xi), 0.9, 1e-12);
  // Outside every area (behind the references' field, far away): prior = 0.5 * mean xi.
  EXPECT_NEAR(mcl.Likelihood(MakePose(8.5, 1.0, 0), xi), 0.5 * 0.6, 1e-12);
  // In an occupied cell: zero.
  EXPECT_EQ(mcl.Likelihood(MakePose(0.05, 5, 0), xi), 0.0);

  // With the angular step function, a heading 10 degrees off is gated out: prior applies.
  o.heading_independent = false;
  MonteCarloLocalizer gated(o, g, refs, Ifh());
  EXPECT_NEAR(gated.Likelihood(MakePose(3.5, 5, 0.02), xi), 0.6, 1e-12);
  EXPECT_NEAR(gated.Likelihood(MakePose(3.5, 5, 10 * kPi / 180), xi), 0.3, 1e-12);

  // Similarities: the best reference scores highest, the worst 0, top_k cuts.
  const auto s = mcl.Similarities(OneNumber(0.75f));
  EXPECT_GT(s[1], s[0]);
  EXPECT_EQ(s[0], 0.0);
}

// Options are validated field by field.
TEST(Mcl, OptionsValidateNamesTheField) {
  MclOptions o;
  EXPECT_NO_THROW(o.Validate());
  o.num_particles = 3;
  try {
    o.Validate();
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("num_particles"));
  }
  o = MclOptions{};
  o.random_samples_per_step = o.num_particles;
  EXPECT_THROW(o.Validate(), Error);
  o = MclOptions{};
  o.visibility.max_view_angle_rad = 0;
  try {
    o.Validate();
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("max_view_angle_rad"));
  }
}

// Global initialisation puts every particle in a free cell; the same seed gives the same set.
TEST(Mcl, GlobalInitIsFreeAndDeterministic) {
  const OccupancyGrid g = OpenRoom();
  std::vector<MclReference> refs(1);
  refs[0].map_T_robot = MakePose(5, 5, 0);
  refs[0].descriptor = OneNumber(0.5f);
  MclOptions o;
  o.num_particles = 500;
  ComputeVisibilityAreas(g, o, &refs);
  MonteCarloLocalizer a(o, g, refs, Ifh()), b(o, g, refs, Ifh());
  a.InitializeGlobal();
  b.InitializeGlobal();
  for (std::size_t i = 0; i < a.particles().size(); ++i) {
    EXPECT_TRUE(g.IsFreePoint(a.particles()[i].pose.head<2>()));
    EXPECT_EQ(a.particles()[i].pose, b.particles()[i].pose);
  }
  a.Predict({0.1, 0.5, -0.1});
  b.Predict({0.1, 0.5, -0.1});
  EXPECT_EQ(a.Correct(OneNumber(0.4f)).mean, b.Correct(OneNumber(0.4f)).mean);
  EXPECT_EQ(a.particles().back().pose, b.particles().back().pose);
}

// ------------------------------------------------------------------ aliasing

// A point-symmetric pair in the open room: reference A at (3, 5) heading 0 and its mirror
// B at (7, 5) heading pi see the same panorama in their own frames (same IFH, same
// Fourier signature); C and D elsewhere give the retrieval its scale.
struct MirrorRoom {
  OccupancyGrid grid = OpenRoom();
  std::vector<MclReference> refs;
  cv::Mat panorama = MakeSyntheticPanorama(120, 24, 7);
  std::shared_ptr<const DescriptorExtractor> heading = MakeMclHeadingExtractor();
};

MirrorRoom MakeMirrorRoom(const MclOptions& o) {
  MirrorRoom m;
  const Descriptor h = m.heading->Compute(m.panorama);
  const Descriptor other = m.heading->Compute(MakeSyntheticPanorama(120, 24, 8));
  const std::vector<std::pair<Pose2, float>> refs = {{MakePose(3, 5, 0), 0.50f},
                                                     {MakePose(7, 5, kPi), 0.52f},
                                                     {MakePose(5, 2, kPi / 2), 0.0f},
                                                     {MakePose(5, 8, -kPi / 2), 1.0f}};
  for (std::size_t i = 0; i < refs.size(); ++i) {
    MclReference r;
    r.map_T_robot = refs[i].first;
    r.descriptor = OneNumber(refs[i].second);
    r.heading_descriptor = i < 2 ? h : other;
    m.refs.push_back(std::move(r));
  }
  // The references are metres apart (the derived radius would be several metres, and the
  // areas would overlap): cut them at 0.75 m explicitly, as the room is built for.
  MclOptions areas = o;
  areas.visibility.max_distance_from_reference_m = 0.75;
  ComputeVisibilityAreas(m.grid, areas, &m.refs);
  return m;
}

// The mirror reference matches only at a 180-degree heading offset: with the panoramas'
// relative heading, a particle at the mirror with the tracked heading gets no eq. (7)
// credit, one turned by pi does; at the true place the tracked heading gets it.
TEST(Mcl, RelativeHeadingGatesTheMirrorReference) {
  MclOptions o;
  o.num_particles = 100;
  const MirrorRoom m = MakeMirrorRoom(o);
  ASSERT_FALSE(m.refs[0].visibility.empty());
  ASSERT_FALSE(m.refs[1].visibility.empty());
  MonteCarloLocalizer mcl(o, m.grid, m.refs, Ifh());
  const Descriptor query = OneNumber(0.51f);
  const Descriptor heading_query = m.heading->Compute(m.panorama);  // robot at A, heading 0
  const std::vector<double> xi = mcl.Similarities(query);
  const std::vector<double> implied = mcl.ImpliedHeadings(xi, &heading_query);
  EXPECT_NEAR(WrapAngle(implied[0]), 0.0, 0.05);
  EXPECT_NEAR(std::abs(WrapAngle(implied[1])), kPi, 0.05);
  const double at_a = mcl.Likelihood(MakePose(3, 5, 0), xi, implied);
  const double mirror_tracked = mcl.Likelihood(MakePose(7, 5, 0), xi, implied);
  const double mirror_turned = mcl.Likelihood(MakePose(7, 5, kPi), xi, implied);
  EXPECT_GT(at_a, 0.9);
  EXPECT_GT(mirror_turned, 0.9);
  EXPECT_EQ(mirror_tracked, 0.0);
  // Without heading information the mirror is as good as the truth ([W]'s model).
  EXPECT_GT(mcl.Likelihood(MakePose(7, 5, 0), xi), 0.9);
}

// Runs a filter standing still at `truth` for `steps` steps with the given query; returns
// the position errors per step and the samples injected.
std::vector<double> StandStill(MonteCarloLocalizer& mcl, const Pose2& start, const Pose2& truth,
                               const Descriptor& query, const Descriptor* heading, int steps,
                               int* injected) {
  mcl.InitializeAt(start);
  std::vector<double> err;
  *injected = 0;
  for (int s = 0; s < steps; ++s) {
    if (s > 0) mcl.Predict({0.0, 0.0, 0.0});
    const MclEstimate e = mcl.Correct(query, heading);
    *injected += mcl.last_step().injected;
    err.push_back((e.cluster.head<2>() - truth.head<2>()).norm());
  }
  return err;
}

// The aliasing episode in miniature: the robot stays at A while retrieval
// ranks the mirror B first (xi_B = 1, xi_A ~ 0.96). [W]'s filter, whose retrieval keeps
// only the best reference (as home_store's top 10 did during an episode), gives the true
// cloud the floor; its steady uniform injection lands at B and takes over. The default
// filter (top_k covering both, injection only when lost) stays at A and never injects.
TEST(Mcl, AliasingMirrorDoesNotCaptureTheDefaultFilter) {
  MclOptions w;  // [W]
  w.num_particles = 500;
  w.injection = MclInjection::kEveryStep;
  w.random_samples_per_step = 20;
  w.top_k = 1;
  w.relative_heading = false;
  w.seed = 5;
  MclOptions d;  // default filter
  d.num_particles = 500;
  d.seed = 5;
  const MirrorRoom m = MakeMirrorRoom(d);
  const Pose2 truth = MakePose(3.2, 5, 0);
  const Descriptor query = OneNumber(0.52f);
  const Descriptor heading_query = m.heading->Compute(m.panorama);
  int injected_w = 0, injected_d = 0;
  MonteCarloLocalizer old_filter(w, m.grid, m.refs, Ifh());
  const auto err_w = StandStill(old_filter, truth, truth, query, nullptr, 40, &injected_w);
  MonteCarloLocalizer new_filter(d, m.grid, m.refs, Ifh());
  const auto err_d = StandStill(new_filter, truth, truth, query, &heading_query, 40, &injected_d);
  EXPECT_GT(err_w.back(), 3.0) << "[W]'s filter was expected to jump to the mirror";
  EXPECT_GT(injected_w, 0);
  EXPECT_LT(*std::max_element(err_d.begin(), err_d.end()), 0.5);
  EXPECT_EQ(injected_d, 0);
}

// Kidnapping in the same room: after 10 steps at A the robot is at C (its query now
// unique to C). The lost detector fires after lost_after_steps inconsistent steps,
// samples are injected near the retrieved reference with its implied heading, and the
// filter converges at C; it injected nothing before the kidnapping.
TEST(Mcl, LostDetectorRecoversFromKidnapping) {
  MclOptions o;
  o.num_particles = 500;
  o.seed = 9;
  const MirrorRoom m = MakeMirrorRoom(o);
  ASSERT_FALSE(m.refs[2].visibility.empty());
  MonteCarloLocalizer mcl(o, m.grid, m.refs, Ifh());
  const Descriptor at_a = OneNumber(0.50f), at_c = OneNumber(0.0f);
  const Descriptor heading_a = m.heading->Compute(m.panorama);
  const Descriptor heading_c = m.refs[2].heading_descriptor;
  mcl.InitializeAt(MakePose(3, 5, 0));
  for (int s = 0; s < 10; ++s) {
    mcl.Correct(at_a, &heading_a);
    EXPECT_EQ(mcl.last_step().injected, 0);
    EXPECT_FALSE(mcl.last_step().lost);
  }
  const Pose2 c = m.refs[2].map_T_robot;
  int first_lost = -1, recovered = -1;
  for (int s = 0; s < 30; ++s) {
    mcl.Predict({0.0, 0.0, 0.0});
    const MclEstimate e = mcl.Correct(at_c, &heading_c);
    if (first_lost < 0 && mcl.last_step().lost) first_lost = s;
    const double err = (e.cluster.head<2>() - c.head<2>()).norm();
    if (recovered < 0 && err < 1.0 && std::abs(WrapAngle(e.cluster.z() - c.z())) < 0.6) {
      recovered = s;
    }
  }
  EXPECT_EQ(first_lost, o.lost_after_steps - 1);
  ASSERT_GE(recovered, 0);
  EXPECT_LE(recovered, first_lost + 3);
}

// ------------------------------------------------------------------ simulated logs

// Day 1 (references) and day 2 (queries) of a world (home_store by default) with small
// panoramas, for a seed; ifh_normalize_columns as IfhOptions::normalize_columns.
struct SimData {
  OccupancyGrid grid;
  std::vector<MclReference> refs;
  std::vector<MclFrame> test;
  std::shared_ptr<const DescriptorExtractor> extractor;
};

SimData MakeSim(std::uint64_t seed, const std::string& world_name = "home_store",
                bool ifh_normalize_columns = false) {
  SimData d;
  World world = LoadBuiltinWorld(world_name);
  world.camera.panorama_width_px = 128;
  world.camera.panorama_height_px = 24;
  SimulatorOptions so;
  so.days = 2;
  so.frames_per_day = 150;
  so.seed = seed;
  so.output = ImageKind::kPanorama;
  so.people = false;
  DescriptorOptions dopt;
  dopt.kind = DescriptorKind::kInvariantFeatureHistogram;
  dopt.ifh.normalize_columns = ifh_normalize_columns;
  d.extractor = MakeDescriptorExtractor(dopt);
  SimulatedFrameSource source(so, world);
  const auto frames =
      ReadMclFrames(source, *d.extractor, {0, 1}, 1, MakeMclHeadingExtractor().get());
  std::vector<MclFrame> train;
  for (const auto& f : frames) {
    if (f.session == 0 && f.index % 2 == 0) train.push_back(f);
    if (f.session == 1) d.test.push_back(f);
  }
  d.grid = MakeOccupancyGrid(world, InitialWorldState(world), {.resolution_m = 0.1});
  d.refs = MakeReferences(train);
  return d;
}

// Tracks the test day from the known start with these options; the largest position
// error (m) and heading error (rad) over the day.
std::pair<double, double> TrackFromKnownStart(const SimData& d, const MclOptions& o) {
  auto refs = d.refs;
  ComputeVisibilityAreas(d.grid, o, &refs);
  MonteCarloLocalizer mcl(o, d.grid, refs, d.extractor);
  const auto rec = RunMcl(mcl, d.test, {.known_start = true});
  double max_err = 0, max_head = 0;
  for (const auto& r : rec) {
    max_err = std::max(max_err, r.position_error_m);
    max_head = std::max(max_head, r.heading_error_rad);
  }
  return {max_err, max_head};
}

// Seed 3: a day 2 whose lighting lets IFH retrieval work (seeds 2, 5: ~12 % wrong).
const SimData& Sim() {
  static const SimData data = MakeSim(3);
  return data;
}

MclOptions SmallOptions() {
  MclOptions o;
  o.num_particles = 1000;
  o.random_samples_per_step = 20;
  o.seed = 11;
  return o;
}

// Tracking from the known start keeps the error bounded over a simulated day.
TEST(Mcl, TrackingErrorBoundedOnSimulatedLog) {
  const SimData& d = Sim();
  MclOptions o = SmallOptions();
  auto refs = d.refs;
  ComputeVisibilityAreas(d.grid, o, &refs);
  MonteCarloLocalizer mcl(o, d.grid, refs, d.extractor);
  const auto rec = RunMcl(mcl, d.test, {.known_start = true});
  ASSERT_EQ(rec.size(), d.test.size());
  double max_err = 0, max_head = 0;
  for (const auto& r : rec) {
    max_err = std::max(max_err, r.position_error_m);
    max_head = std::max(max_head, r.heading_error_rad);
  }
  RecordProperty("max_position_error_m", std::to_string(max_err));
  EXPECT_LT(max_err, 0.9);  // measured 0.74 m
  EXPECT_LT(max_head, 0.35);
}

// The default filter (top_k 30, injection only when lost, relative heading)
// tracks every seed from the known start without jumping and within [W]'s accuracy.
TEST(Mcl, DefaultFilterTracksEverySeed) {
  for (std::uint64_t seed : {1u, 2u, 5u}) {
    MclOptions o;
    o.num_particles = 1000;
    o.seed = 11;
    const auto [max_err, max_head] = TrackFromKnownStart(MakeSim(seed), o);
    RecordProperty(StrCat("max_position_error_m_seed_", seed), std::to_string(max_err));
    EXPECT_LT(max_err, 1.0) << "seed " << seed;
    EXPECT_LT(max_head, 20 * kPi / 180) << "seed " << seed;
  }
}

// institute, whose office lights switch between the days: with column-normalised
// histograms and no relative heading (datasets/mcl/switching_lights.yaml) the filter
// tracks day 2 from the known start on several seeds; the defaults jump 10-13 m there
// (docs/results.md "institute with column-normalised histograms").
TEST(Mcl, InstituteTracksWithColumnNormalisedHistograms) {
  for (std::uint64_t seed : {1u, 2u, 3u}) {
    MclOptions o;
    o.num_particles = 1000;
    o.seed = 11;
    o.relative_heading = false;
    const auto [max_err, max_head] =
        TrackFromKnownStart(MakeSim(seed, "institute", /*ifh_normalize_columns=*/true), o);
    RecordProperty(StrCat("institute_max_position_error_m_seed_", seed), std::to_string(max_err));
    std::cout << "institute seed " << seed << ": max error " << max_err << " m, "
              << max_head * 180 / kPi << " deg\n";
    EXPECT_LT(max_err, 1.5) << "seed " << seed;
    EXPECT_LT(max_head, 30 * kPi / 180) << "seed " << seed;
  }
}

// Raw ring sessions are unwrapped with their calibration before the descriptors.
TEST(Mcl, ReadsRawRingSessions) {
  World world = LoadBuiltinWorld("home_store");
  SimulatorOptions so;
  so.days = 1;
  so.frames_per_day = 3;
  so.seed = 1;
  so.output = ImageKind::kRawRing;
  so.people = false;
  SimulatedFrameSource source(so, world);
  const auto extractor = Ifh();
  const auto heading = MakeMclHeadingExtractor();
  const auto frames = ReadMclFrames(source, *extractor, {}, 1, heading.get());
  ASSERT_EQ(frames.size(), 3u);
  for (const MclFrame& f : frames) {
    EXPECT_EQ(f.descriptor.kind, DescriptorKind::kInvariantFeatureHistogram);
    EXPECT_FALSE(f.descriptor.features.empty());
    EXPECT_EQ(f.heading_descriptor.kind, DescriptorKind::kFourier);
    EXPECT_TRUE(f.truth.has_value());
  }
}

// The session's user mask reaches the descriptors: noise under the mask leaves every
// descriptor unchanged, and the same noise without a declared mask changes them.
TEST(Mcl, MaskedPixelsDoNotChangeTheDescriptors) {
  SimulatorOptions so;
  so.world = "home_store";
  so.days = 1;
  so.frames_per_day = 3;
  so.seed = 2;
  so.people = false;
  const auto extractor = Ifh();
  const auto heading = MakeMclHeadingExtractor();
  const auto read = [&](bool declare_mask, bool scramble) {
    testing::MaskedRingSource source(so, declare_mask, scramble);
    return ReadMclFrames(source, *extractor, {}, 1, heading.get());
  };
  const auto clean = read(true, false), scrambled = read(true, true);
  const auto unmasked_clean = read(false, false), unmasked_scrambled = read(false, true);
  ASSERT_EQ(clean.size(), 3u);
  ASSERT_EQ(scrambled.size(), 3u);
  for (std::size_t i = 0; i < clean.size(); ++i) {
    EXPECT_EQ(clean[i].descriptor.features, scrambled[i].descriptor.features) << "frame " << i;
    EXPECT_EQ(clean[i].heading_descriptor.coefficients,
              scrambled[i].heading_descriptor.coefficients)
        << "frame " << i;
    EXPECT_NE(unmasked_clean[i].descriptor.features, unmasked_scrambled[i].descriptor.features)
        << "frame " << i << ": the scrambled region is not seen at all";
  }
}

// A filter that never injects random samples does not jump to the aliased
// (mirror) end of the point-symmetric store, on every seed, even where retrieval aliases
// for many frames in a row (seeds 2, 5); [W]'s steady injection jumps 20-24 m there.
TEST(Mcl, TrackingWithoutInjectionNeverJumpsOnAnySeed) {
  for (std::uint64_t seed : {1u, 2u, 5u}) {
    const SimData d = MakeSim(seed);
    MclOptions o = SmallOptions();
    o.injection = MclInjection::kAugmented;
    o.max_injection_fraction = 0.0;  // never inject
    auto refs = d.refs;
    ComputeVisibilityAreas(d.grid, o, &refs);
    MonteCarloLocalizer mcl(o, d.grid, refs, d.extractor);
    const auto rec = RunMcl(mcl, d.test, {.known_start = true});
    double max_err = 0;
    int injected = 0;
    for (const auto& r : rec) {
      max_err = std::max(max_err, r.position_error_m);
      injected += r.stats.injected;
      EXPECT_GT(r.stats.effective_sample_size, 0.0);
      EXPECT_LE(r.stats.effective_sample_size, o.num_particles + 1e-6);
    }
    RecordProperty(StrCat("max_position_error_m_seed_", seed), std::to_string(max_err));
    EXPECT_EQ(injected, 0) << "seed " << seed;
    EXPECT_LT(max_err, 2.5) << "seed " << seed;  // a jump is > 15 m
  }
}

// After a kidnapping (carried half a lap without odometry) the filter recovers within a
// bounded number of steps: [W]'s steady injection and the default injection when lost.
TEST(Mcl, RecoversFromKidnapping) {
  for (const MclInjection injection : {MclInjection::kEveryStep, MclInjection::kWhenLost}) {
    const SimData& d = Sim();
    MclOptions o = SmallOptions();
    o.num_particles = 2000;
    o.random_samples_per_step = 50;
    o.injection = injection;
    auto refs = d.refs;
    ComputeVisibilityAreas(d.grid, o, &refs);
    MonteCarloLocalizer mcl(o, d.grid, refs, d.extractor);
    MclRunSpec spec;
    spec.kidnap_step = 20;
    spec.kidnap_to_frame = 90;
    const auto rec = RunMcl(mcl, d.test, spec);
    ASSERT_GT(rec.size(), 40u);
    EXPECT_TRUE(rec[21].kidnapped);
    EXPECT_GT(rec[21].position_error_m, 2.0);  // it really was lost
    const int steps = StepsToConverge(rec, 21, 1.0, 35 * kPi / 180, 3);
    RecordProperty(StrCat("steps_to_recover_", static_cast<int>(injection)), std::to_string(steps));
    EXPECT_GE(steps, 0);
    EXPECT_LE(steps, 40);
  }
}

}  // namespace
}  // namespace omnicml
