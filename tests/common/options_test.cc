#include "omnicml/common/options.h"

#include <array>
#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Core>

#include "omnicml/baselines/mcl/mcl.h"
#include "omnicml/baselines/topo/topological.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {

// A struct with every supported field shape, for the framework's own tests.
enum class ToyMode { kSlow, kFast };
std::string ToString(ToyMode m) { return m == ToyMode::kSlow ? "slow" : "fast"; }
struct ToyInner {
  double gain = 0.5;
  std::uint32_t seed = 7;
  double late_gain = 0.25;  // added in format 3
};
struct ToyOptions {
  int count = 3;
  double rate_hz = 10.0;
  bool enabled = true;
  std::string name = "toy";
  std::vector<double> weights = {1.0, 2.0};
  std::array<double, 2> range = {0.0, 1.0};
  Eigen::Vector3d pose = Eigen::Vector3d::Zero();
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Identity();
  ToyMode mode = ToyMode::kSlow;
  ToyInner inner;
};
template <class V>
void VisitFields(V& v, ToyInner& o) {
  v("gain", o.gain);
  v("seed", o.seed);
  v.Since(3, [&](auto& w) { w("late_gain", o.late_gain); });
}
template <class V>
void VisitFields(V& v, ToyOptions& o) {
  v("count", o.count);
  v("rate_hz", o.rate_hz);
  v("enabled", o.enabled);
  v("name", o.name);
  v("weights", o.weights);
  v("range", o.range);
  v("pose", o.pose);
  v("covariance", o.covariance);
  v.Enum("mode", o.mode, {ToyMode::kSlow, ToyMode::kFast});
  v.Section("inner", o.inner);
}

namespace {

std::string ErrorOf(const std::function<void()>& fn) {
  try {
    fn();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

ToyOptions ParseToy(const std::string& text) {
  return ParseOptionsYaml<ToyOptions>(text, "toy.yaml");
}

// Every leaf (scalar or list) of `a` differs from the same leaf of `b` (maps recurse).
void ExpectEveryLeafDiffers(const OptionValue& a, const OptionValue& b, const std::string& path) {
  ASSERT_EQ(a.kind, b.kind) << path;
  if (a.kind != OptionValue::Kind::kMap) {
    EXPECT_FALSE(a == b) << "field '" << path << "' kept its default";
    return;
  }
  ASSERT_EQ(a.members.size(), b.members.size()) << path;
  for (std::size_t i = 0; i < a.members.size(); ++i) {
    ASSERT_EQ(a.members[i].first, b.members[i].first);
    ExpectEveryLeafDiffers(a.members[i].second, b.members[i].second,
                           path.empty() ? a.members[i].first : path + "." + a.members[i].first);
  }
}

// Randomised round trip of one options struct: every field changed from its default, then
// YAML dump -> load and binary encode -> decode give equal options (doubles exact).
template <class O>
void ExpectRoundTrips(std::uint32_t seed) {
  std::mt19937 rng(seed);
  O o;
  RandomizeOptions(&o, rng);
  ExpectEveryLeafDiffers(OptionsToValue(o), OptionsToValue(O{}), "");

  const std::string yaml = OptionsToYaml(o);
  O from_yaml;
  OptionsFromValue(ParseOptionYaml(yaml, "dump.yaml"), OptionSource{"dump.yaml", true, {}},
                   &from_yaml);
  EXPECT_TRUE(SameOptions(o, from_yaml)) << yaml;
  EXPECT_EQ(OptionsToYaml(from_yaml), yaml);

  BinaryWriter w;
  EncodeOptions(w, o);
  BinaryReader r(w.bytes(), "bytes");
  const O from_bytes = DecodeOptions<O>(r, "options");
  r.ExpectEnd("options");
  EXPECT_TRUE(SameOptions(o, from_bytes));
  BinaryWriter again;
  EncodeOptions(again, from_bytes);
  EXPECT_EQ(again.bytes(), w.bytes());
}

// Every field shape survives YAML and binary round trips; absent keys keep their values.
TEST(Options, ToyRoundTrips) {
  for (std::uint32_t seed : {1u, 2u, 3u}) ExpectRoundTrips<ToyOptions>(seed);
  const ToyOptions o =
      ParseToy("count: 5\ninner: {gain: 0.25}\ncovariance: [[2, 0.5], [0.5, 3]]\n");
  EXPECT_EQ(o.count, 5);
  EXPECT_EQ(o.inner.gain, 0.25);
  EXPECT_EQ(o.inner.seed, 7u);
  EXPECT_EQ(o.covariance(0, 1), 0.5);
  EXPECT_EQ(o.rate_hz, 10.0);
}

// Unknown keys, duplicates, wrong types and shapes are errors naming file, line and key.
TEST(Options, ErrorsNameFileLineAndKey) {
  std::string e = ErrorOf([] { ParseToy("count: 1\ninner:\n  gian: 2\n"); });
  EXPECT_NE(e.find("toy.yaml:3"), std::string::npos) << e;
  EXPECT_NE(e.find("unknown key 'inner.gian'"), std::string::npos) << e;
  e = ErrorOf([] { ParseToy("count: 1\ncount: 2\n"); });
  EXPECT_NE(e.find("toy.yaml:2"), std::string::npos) << e;
  EXPECT_NE(e.find("duplicate key 'count'"), std::string::npos) << e;
  e = ErrorOf([] { ParseToy("rate_hz: 1\ncount: many\n"); });
  EXPECT_NE(e.find("toy.yaml:2"), std::string::npos) << e;
  EXPECT_NE(e.find("'count'"), std::string::npos) << e;
  EXPECT_NE(ErrorOf([] { ParseToy("count: 1.5\n"); }).find("integer"), std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseToy("enabled: maybe\n"); }).find("'enabled'"), std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseToy("pose: [1, 2]\n"); }).find("'pose'"), std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseToy("covariance: [1, 2]\n"); }).find("'covariance'"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseToy("mode: medium\n"); }).find("slow, fast"), std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseToy("inner: 3\n"); }).find("'inner' must be a map"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseToy("inner: {seed: -1}\n"); }).find("'inner.seed'"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseToy("count: [\n"); }).find("toy.yaml"), std::string::npos);
}

// A complete (binary) read requires every field and names the missing one.
TEST(Options, CompleteReadNamesMissingField) {
  OptionValue v = OptionsToValue(ToyOptions{});
  v.members.erase(v.members.begin() + 1);  // rate_hz
  ToyOptions o;
  const std::string e = ErrorOf([&] {
    OptionsFromValue(v, OptionSource{"engine.omap: options", true, {}}, &o);
  });
  EXPECT_NE(e.find("missing option 'rate_hz'"), std::string::npos) << e;
}

// Fields added in a later file format than the file's are left out while they keep their
// defaults (so such a file keeps its bytes) and take their defaults when absent; a file of
// their own format must have them.
TEST(Options, NewerFieldsOmittedWhenDefaultAndFilledOnLoad) {
  auto inner_keys = [](const OptionValue& tree) {
    std::vector<std::string> keys;
    for (const auto& [k, v] : tree.members) {
      if (k != "inner") continue;
      for (const auto& [ik, iv] : v.members) keys.push_back(ik);
    }
    return keys;
  };
  ToyOptions o;
  o.count = 9;
  const OptionValue old_file = OptionsToFileValue(o, 2);
  EXPECT_EQ(inner_keys(old_file), (std::vector<std::string>{"gain", "seed"}));
  EXPECT_EQ(inner_keys(OptionsToFileValue(o, 3)),
            (std::vector<std::string>{"gain", "seed", "late_gain"}));
  ToyOptions changed = o;
  changed.inner.late_gain = 0.75;
  EXPECT_EQ(inner_keys(OptionsToFileValue(changed, 2)),
            (std::vector<std::string>{"gain", "seed", "late_gain"}));

  ToyOptions loaded;
  loaded.inner.late_gain = 0.25;
  OptionSource v2{"old.omap: options", true, {}, 2};
  OptionsFromValue(old_file, v2, &loaded);
  EXPECT_EQ(loaded.count, 9);
  EXPECT_EQ(loaded.inner.late_gain, 0.25);
  OptionsFromValue(OptionsToFileValue(changed, 2), v2, &loaded);
  EXPECT_EQ(loaded.inner.late_gain, 0.75);
  const std::string e = ErrorOf([&] {
    ToyOptions x;
    OptionsFromValue(old_file, OptionSource{"new.omap: options", true, {}, 3}, &x);
  });
  EXPECT_NE(e.find("missing option 'inner.late_gain'"), std::string::npos) << e;
}

// Randomised round trips of every options struct of the project.
TEST(Options, EngineOptionsRoundTrip) {
  for (std::uint32_t seed : {11u, 12u, 13u}) ExpectRoundTrips<CmlEngineOptions>(seed);
}
TEST(Options, MclOptionsRoundTrip) {
  for (std::uint32_t seed : {21u, 22u}) ExpectRoundTrips<MclOptions>(seed);
}
TEST(Options, TopologicalOptionsRoundTrip) {
  for (std::uint32_t seed : {31u, 32u}) ExpectRoundTrips<TopologicalOptions>(seed);
}
TEST(Options, SimulatorOptionsRoundTrip) {
  for (std::uint32_t seed : {41u, 42u}) ExpectRoundTrips<SimulatorOptions>(seed);
}

// The loaders validate and read back their own dumps.
TEST(Options, ModuleLoadersReadTheirDumps) {
  MclOptions mcl;
  mcl.num_particles = 1234;
  mcl.visibility.max_distance_m = 7.5;
  const MclOptions mcl_back = ParseMclOptionsYaml(MclOptionsToYaml(mcl), "mcl.yaml");
  EXPECT_TRUE(SameOptions(mcl, mcl_back));
  TopologicalOptions topo;
  topo.band_threshold[2] = 0.3;
  topo.histogram.bins = 16;
  EXPECT_TRUE(
      SameOptions(topo, ParseTopologicalOptionsYaml(TopologicalOptionsToYaml(topo), "t.yaml")));
  SimulatorOptions sim;
  sim.output = ImageKind::kPanorama;
  sim.later_days_start = SessionStartMode::kGlobal;
  EXPECT_TRUE(SameOptions(sim, ParseSimulatorOptionsYaml(SimulatorOptionsToYaml(sim), "s.yaml")));
  EXPECT_NE(ErrorOf([] { ParseMclOptionsYaml("num_particles: 3\n", "m.yaml"); }).find("m.yaml"),
            std::string::npos);
}

// What `omnicml mcl`, `topo` and `simulate` write today (options next to their inputs)
// loads back through the module loaders.
TEST(Options, AppDumpsLoadBack) {
  const std::string mcl_yaml =
      "# Effective configuration of `omnicml mcl` (MclOptions and inputs).\n"
      "input: \"world home_store\"\ntrain_day: 1\ntest_day: 2\nref_every: 1\nreferences: 300\n"
      "panorama_width_px: 360\npanorama_height_px: 60\ndescriptor: fourier\n"
      "grid_resolution_m: 0.1\nstart: known\nnum_particles: 2000\nrandom_samples_per_step: 20\n"
      "motion: {a1: 0.02, a2: 0.005, a3: 0.01, a4: 0.002}\n"
      "heading_gate_half_width_rad: 0.08726646259971647\nheading_independent: true\ntop_k: 10\n"
      "prior_fraction: 0.2\nmin_likelihood: 0.001\naxis_offset_rad: 0\n"
      "visibility: {max_ray_range_m: 50, max_distance_m: 50, max_view_angle_rad: "
      "0.7853981633974483, max_distance_from_reference_m: 2.5}\n"
      "cluster_cell_m: 0.5\ncluster_radius_m: 1\ninit_sigma_xy_m: 0.2\ninit_sigma_phi_rad: 0.1\n"
      "seed: 3\n";
  const MclOptions mcl = ParseMclOptionsYaml(mcl_yaml, "config.yaml");
  EXPECT_EQ(mcl.num_particles, 2000);
  EXPECT_EQ(mcl.seed, 3u);
  EXPECT_EQ(mcl.visibility.max_distance_from_reference_m, 2.5);

  const std::string topo_yaml =
      "# Effective options of `omnicml topo` ([UN] topological localization).\n"
      "world: \"home_store\"\ndays: 3\nframes_per_day: 285\nseed: 1\nstep_m: 0.2\npeople: true\n"
      "train_day: 1\ntest_day: 2\nplaces: \"datasets/places/home_store_areas.yaml\"\n"
      "reference_stride_frames: 1\nknown_start: true\n"
      "histogram: {bins: 32, filter_width: 5, normalized_rgb: false, distance: jeffrey}\n"
      "band_threshold: [0.05, 0.05, 0.1, 0.05, 0.05, 0.05]\naction_threshold: 0.1\n"
      "restrict_to_neighbours: true\nglobal_search_after_frames: 0\n";
  const TopologicalOptions topo = ParseTopologicalOptionsYaml(topo_yaml, "topo_config.yaml");
  EXPECT_EQ(topo.band_threshold[2], 0.1);

  const std::string sim_yaml =
      "# Effective options of `omnicml simulate` (SimulatorOptions).\n"
      "world: \"institute\"\nworld_name: institute\ndays: 2\nframes_per_day: 100\nseed: 5\n"
      "output: panorama\nstep_m: 0.25\nlater_days_start: continue\nsensor_noise: false\n"
      "people: true\n";
  const SimulatorOptions sim = ParseSimulatorOptionsYaml(sim_yaml, "simulation.yaml");
  EXPECT_EQ(sim.world, "institute");
  EXPECT_EQ(sim.output, ImageKind::kPanorama);
  EXPECT_EQ(sim.later_days_start, SessionStartMode::kContinue);
  EXPECT_EQ(sim.step_m, 0.25);
}

}  // namespace
}  // namespace omnicml
