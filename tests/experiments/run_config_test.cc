// Tests of the run configuration: YAML -> CmlEngineOptions, the dump round trip, errors
// naming key, file and line, overrides, and the run input.
#include "omnicml/experiments/run_config.h"

#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Message of the omnicml::Error thrown by f, or "" when nothing is thrown.
template <class F>
std::string ErrorOf(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST(RunConfig, NestedKeysSetTheirFields) {
  // Keys equal member names; nested sections reach nested options structs.
  const std::string yaml = R"(
update_delay_frames: 7
threads: 2
initial_pose: [1.5, -2, 0.25]
initial_covariance: [[0.04, 0, 0], [0, 0.09, 0], [0, 0, 0.01]]
descriptor:
  kind: fourier
  fourier: {bands: 3, coefficients: 12, distance: l1, normalize_bands: false}
tracker:
  gamma: 9.5
  motion: {a3: 0.2}
model:
  e_max: 0.75
  forgetting: passive
  top_k: 4
reconstruction: {max_iterations: 17}
)";
  const CmlEngineOptions o = ParseEngineOptionsYaml(yaml, "test.yaml");
  EXPECT_EQ(o.update_delay_frames, 7);
  EXPECT_EQ(o.threads, 2);
  EXPECT_EQ(o.initial_pose, Pose2(1.5, -2, 0.25));
  EXPECT_EQ(o.initial_covariance(1, 1), 0.09);
  EXPECT_EQ(o.descriptor.fourier.bands, 3);
  EXPECT_EQ(o.descriptor.fourier.coefficients, 12);
  EXPECT_EQ(o.descriptor.fourier.distance, FourierDistance::kL1);
  EXPECT_FALSE(o.descriptor.fourier.normalize_bands);
  EXPECT_EQ(o.tracker.gamma, 9.5);
  EXPECT_EQ(o.tracker.motion.a3, 0.2);
  EXPECT_EQ(o.tracker.motion.a1, MotionNoise{}.a1);  // untouched keys keep defaults
  EXPECT_EQ(o.model.e_max, 0.75);
  EXPECT_EQ(o.model.forgetting, ForgettingMode::kPassive);
  EXPECT_EQ(o.model.top_k, 4);
  EXPECT_EQ(o.reconstruction.max_iterations, 17);
}

TEST(RunConfig, DumpRoundTripsExactly) {
  // Random option values survive dump -> parse bit for bit, and the dump is a fixed point.
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    CmlEngineOptions o;
    o.tracker.gamma = 5 + 10 * u(rng);
    o.tracker.w_min = 1e-4 + 1e-3 * u(rng);
    o.tracker.motion.a2 = u(rng) / 3;
    o.model.e_max = 0.1 + u(rng);
    o.model.beta = 0.01 + 0.5 * u(rng);
    o.model.d_gain_m = u(rng);
    o.model.forgetting = static_cast<ForgettingMode>(trial % 3);
    o.update_delay_frames = 1 + trial % 5;
    o.initial_pose = Pose2(u(rng) * 10, -u(rng) * 10, u(rng) - 0.5);
    o.initial_covariance =
        Eigen::Vector3d(u(rng) + 0.01, u(rng) + 0.01, u(rng) + 0.01).asDiagonal();
    o.descriptor.kind = trial % 2 ? DescriptorKind::kColorHistogram : DescriptorKind::kFourier;
    o.descriptor.ifh.scales = {1.0, 1.0 + u(rng)};
    o.descriptor.ifh.kernels = {IfhKernel{{{0, 0}, {0, 2}}}};
    o.reconstruction.function_tolerance = 1e-10 * (1 + u(rng));
    const std::string yaml = EngineOptionsToYaml(o);
    const CmlEngineOptions back = ParseEngineOptionsYaml(yaml, "dump.yaml");
    EXPECT_EQ(EngineOptionsToYaml(back), yaml);
    EXPECT_TRUE(SameEngineOptions(o, back));
    EXPECT_EQ(back.tracker.gamma, o.tracker.gamma);
    EXPECT_EQ(back.model.e_max, o.model.e_max);
    EXPECT_EQ(back.initial_pose, o.initial_pose);
    EXPECT_EQ(back.initial_covariance, o.initial_covariance);
    EXPECT_EQ(back.descriptor.ifh.scales, o.descriptor.ifh.scales);
    ASSERT_EQ(back.descriptor.ifh.kernels.size(), 1u);
    EXPECT_EQ(back.descriptor.ifh.kernels[0].offsets, o.descriptor.ifh.kernels[0].offsets);
    EXPECT_EQ(back.reconstruction.function_tolerance, o.reconstruction.function_tolerance);
  }
}

TEST(RunConfig, UnknownKeyNamesKeyFileAndLine) {
  // A misspelt key is an error with the dotted key, the file and its line.
  const std::string yaml = "threads: 1\ntracker:\n  gamma: 3\n  gama: 4\n";
  const std::string what = ErrorOf([&] { ParseEngineOptionsYaml(yaml, "cfg.yaml"); });
  EXPECT_NE(what.find("cfg.yaml:4"), std::string::npos) << what;
  EXPECT_NE(what.find("tracker.gama"), std::string::npos) << what;
  const std::string top = ErrorOf([&] { ParseEngineOptionsYaml("bogus: 1\n", "c.yaml"); });
  EXPECT_NE(top.find("c.yaml:1"), std::string::npos) << top;
  EXPECT_NE(top.find("bogus"), std::string::npos) << top;
}

TEST(RunConfig, BadValuesAreErrors) {
  // Wrong types, unknown enum names and invalid values are errors naming the key.
  EXPECT_NE(ErrorOf([] { ParseEngineOptionsYaml("threads: two\n", "c.yaml"); }).find("threads"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseEngineOptionsYaml("threads: 1.5\n", "c.yaml"); }).find("threads"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              ParseEngineOptionsYaml("model: {forgetting: sometimes}\n", "c.yaml");
            }).find("model.forgetting"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              ParseEngineOptionsYaml("initial_pose: [1, 2]\n", "c.yaml");
            }).find("initial_pose"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] { ParseEngineOptionsYaml("tracker: 3\n", "c.yaml"); }).find("tracker"),
            std::string::npos);
  // Validation of the values themselves (negative delay).
  EXPECT_NE(ErrorOf([] { ParseEngineOptionsYaml("update_delay_frames: 0\n", "c.yaml"); }), "");
  EXPECT_NE(ErrorOf([] { ParseEngineOptionsYaml("a: [\n", "c.yaml"); }).find("c.yaml"),
            std::string::npos);
}

TEST(RunConfig, OverridesApplyOnTopOfTheFile) {
  // Flags win over the configuration file, which wins over the defaults.
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("omnicml_run_config_test_" + std::to_string(::getpid()) + ".yaml");
  {
    std::ofstream os(path);
    os << "update_delay_frames: 5\nmodel: {e_max: 0.5, beta: 0.2}\n";
  }
  OptionOverrides ov;
  ov.config_path = path.string();
  ov.e_max = 0.9;
  ov.forgetting = "static";
  ov.threads = 2;
  const CmlEngineOptions o = ResolveEngineOptions(ov);
  EXPECT_EQ(o.update_delay_frames, 5);
  EXPECT_EQ(o.model.beta, 0.2);
  EXPECT_EQ(o.model.e_max, 0.9);
  EXPECT_EQ(o.model.forgetting, ForgettingMode::kStatic);
  EXPECT_EQ(o.threads, 2);
  ov.forgetting = "often";
  EXPECT_THROW(ResolveEngineOptions(ov), Error);
  std::filesystem::remove(path);
  OptionOverrides missing;
  missing.config_path = "/nonexistent/omnicml.yaml";
  EXPECT_NE(ErrorOf([&] { ResolveEngineOptions(missing); }).find("/nonexistent/omnicml.yaml"),
            std::string::npos);
}

TEST(RunInput, ValidatesTheInput) {
  // Exactly one input kind; missing log directories and unknown worlds are named.
  RunInput none;
  EXPECT_THROW(none.Validate(), Error);
  RunInput missing;
  missing.log_dirs = {"/nonexistent/log"};
  EXPECT_NE(ErrorOf([&] { missing.Validate(); }).find("/nonexistent/log"), std::string::npos);
  RunInput world;
  world.world = "no_such_world";
  EXPECT_NE(ErrorOf([&] { OpenFrameSource(world); }).find("no_such_world"), std::string::npos);
  RunInput days;
  days.world = "home_store";
  days.days = 0;
  EXPECT_THROW(days.Validate(), Error);
}

}  // namespace
}  // namespace omnicml
