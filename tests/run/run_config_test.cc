// Tests of the run configuration: YAML -> CmlEngineOptions, the dump round trip, errors
// naming key, file and line, overrides, and the run input.
#include "omnicml/run/run_config.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/engine/calibration.h"
#include "omnicml/sim/simulator.h"

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
  retrieval: {e_max: 0.75, top_k: 4}
  forgetting:
    mode: passive
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
  EXPECT_EQ(o.model.retrieval.e_max, 0.75);
  EXPECT_EQ(o.model.forgetting.mode, ForgettingMode::kPassive);
  EXPECT_EQ(o.model.retrieval.top_k, 4);
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
    o.model.retrieval.e_max = 0.1 + u(rng);
    o.model.update.beta = 0.01 + 0.5 * u(rng);
    o.model.forgetting.d_gain_m = u(rng);
    o.model.forgetting.mode = static_cast<ForgettingMode>(trial % 3);
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
    EXPECT_EQ(back.model.retrieval.e_max, o.model.retrieval.e_max);
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
    // The former flat model keys (still read, with a deprecation warning).
    os << "update_delay_frames: 5\nmodel: {e_max: 0.5, beta: 0.2}\n";
  }
  OptionOverrides ov;
  ov.config_path = path.string();
  ov.e_max = 0.9;
  ov.forgetting = "static";
  ov.threads = 2;
  const CmlEngineOptions o = ResolveEngineOptions(ov);
  EXPECT_EQ(o.update_delay_frames, 5);
  EXPECT_EQ(o.model.update.beta, 0.2);
  EXPECT_EQ(o.model.retrieval.e_max, 0.9);
  EXPECT_EQ(o.model.forgetting.mode, ForgettingMode::kStatic);
  EXPECT_EQ(o.threads, 2);
  ov.forgetting = "often";
  EXPECT_THROW(ResolveEngineOptions(ov), Error);
  std::filesystem::remove(path);
  OptionOverrides missing;
  missing.config_path = "/nonexistent/omnicml.yaml";
  EXPECT_NE(ErrorOf([&] { ResolveEngineOptions(missing); }).find("/nonexistent/omnicml.yaml"),
            std::string::npos);
}

// motion_noise_source: identified replaces the motion noise and appearance_sigma_m by
// values identified from the log; values the configuration file gives explicitly win.
TEST(RunConfig, IdentifiedMotionNoiseUnderExplicitValues) {
  const std::filesystem::path path =
      std::filesystem::temp_directory_path() /
      ("omnicml_identified_test_" + std::to_string(::getpid()) + ".yaml");
  {
    std::ofstream os(path);
    os << "motion_noise_source: identified\ntracker: {motion: {a1: 0.123}}\n";
  }
  OptionOverrides ov;
  ov.config_path = path.string();
  RunInput input;
  input.world = "home_store";
  input.days = 3;
  input.frames_per_day = 120;
  input.sim_image = ImageKind::kPanorama;
  std::string note;
  const CmlEngineOptions o = ResolveNewMapOptions(ov, input, &note);
  std::filesystem::remove(path);
  EXPECT_NE(note.find("motion noise identified from"), std::string::npos) << note;
  EXPECT_EQ(o.tracker.motion.a1, 0.123);  // explicit
  const MotionNoise defaults;
  EXPECT_NE(o.tracker.motion.a3, defaults.a3);  // identified
  EXPECT_NE(o.appearance_sigma_m, CmlEngineOptions{}.appearance_sigma_m);
  // The configured sources leave the options as resolved.
  OptionOverrides plain;
  const CmlEngineOptions p = ResolveNewMapOptions(plain, input, &note);
  EXPECT_TRUE(note.empty()) << note;
  EXPECT_TRUE(SameEngineOptions(p, CmlEngineOptions{}));
}

// A configuration file in the temporary directory (removed at scope exit) and the
// overrides that read it.
class TempConfig {
 public:
  explicit TempConfig(const std::string& stem)
      : path_(std::filesystem::temp_directory_path() /
              (stem + "_" + std::to_string(::getpid()) + ".yaml")) {
    overrides.config_path = path_.string();
  }
  ~TempConfig() { std::filesystem::remove(path_); }
  void Write(const std::string& yaml) const {
    std::ofstream os(path_);
    os << yaml;
  }
  OptionOverrides overrides;

 private:
  std::filesystem::path path_;
};

// A simulated panoramic input of `world`.
RunInput SimulatedInput(const std::string& world, int days, int frames_per_day) {
  RunInput input;
  input.world = world;
  input.days = days;
  input.frames_per_day = frames_per_day;
  input.sim_image = ImageKind::kPanorama;
  return input;
}

// appearance_offset_source: calibrated gives a new map the first session's appearance
// curve up to e_max (AppearanceOffsetCurve); an explicit curve in the configuration wins,
// even an empty one.
TEST(RunConfig, CalibratedAppearanceOffsetsTakeTheAppearanceCurve) {
  Calibration c;
  c.e_max = 0.45;
  c.curve = {{1, 10, 0.2, 0.24}, {2, 10, 0.2, 0.30}, {3, 10, 0.6, 0.46}, {4, 10, 0.8, 0.5}};
  const std::vector<std::array<double, 2>> expected = {{0.2, 0.24}, {0.6, 0.46}};
  EXPECT_EQ(AppearanceOffsetCurve(c), expected);

  TempConfig file("omnicml_offset_curve_test");
  const RunInput input = SimulatedInput("home_store", 1, 150);
  std::string note;
  file.Write("appearance_offset_source: calibrated\n");
  const CmlEngineOptions o = ResolveNewMapOptions(file.overrides, input, &note);
  EXPECT_NE(note.find("appearance offsets from the first session's appearance curve"),
            std::string::npos)
      << note;
  const std::vector<std::array<double, 2>>& curve = o.appearance_offset_curve;
  ASSERT_GE(curve.size(), 2u);
  for (std::size_t i = 1; i < curve.size(); ++i) EXPECT_GT(curve[i][0], curve[i - 1][0]);
  for (std::size_t i = 0; i + 1 < curve.size(); ++i)
    EXPECT_LT(curve[i][1], o.model.retrieval.e_max);
  EXPECT_GE(curve.back()[1], o.model.retrieval.e_max);
  EXPECT_NO_THROW(o.Validate());
  EXPECT_EQ(o.tracker.motion.a1, CmlEngineOptions{}.tracker.motion.a1);  // not asked to identify

  file.Write("appearance_offset_source: calibrated\nappearance_offset_curve: []\n");
  EXPECT_TRUE(ResolveNewMapOptions(file.overrides, input, &note).appearance_offset_curve.empty());
  file.Write("motion_noise_source: identified\n");
  EXPECT_TRUE(ResolveNewMapOptions(file.overrides, input, &note).appearance_offset_curve.empty());
}

// spatial_scale_source: calibrated multiplies the spatial thresholds by the scale measured
// on the input: 1 on home_store, where the defaults were measured; 2 on home_store with
// every length doubled. Explicit values win.
TEST(RunConfig, CalibratedSpatialThresholdsFollowTheWorldsScale) {
  TempConfig file("omnicml_spatial_test");
  RunInput input = SimulatedInput("home_store", 1, 200);
  std::string note;
  const CmlEngineOptions defaults;

  file.Write("spatial_scale_source: calibrated\n");
  const CmlEngineOptions same = ResolveNewMapOptions(file.overrides, input, &note);
  EXPECT_NE(note.find("spatial scale 1 "), std::string::npos) << note;
  CmlEngineOptions calibrated = defaults;
  calibrated.spatial_scale_source = SpatialScaleSource::kCalibrated;
  EXPECT_TRUE(SameEngineOptions(same, calibrated));

  input.world = (std::filesystem::path(OMNICML_SOURCE_DIR) / "datasets" / "sweeps" / "worlds" /
                 "home_store_x2.yaml")
                    .string();
  const CmlEngineOptions o = ResolveNewMapOptions(file.overrides, input, &note);
  EXPECT_NE(note.find("spatial scale 2 "), std::string::npos) << note;
  EXPECT_DOUBLE_EQ(o.appearance_sigma_m, 2 * defaults.appearance_sigma_m);
  EXPECT_DOUBLE_EQ(o.anchor_max_sigma_m, 2 * defaults.anchor_max_sigma_m);
  EXPECT_DOUBLE_EQ(o.model.forgetting.d_for_m, 2 * defaults.model.forgetting.d_for_m);
  EXPECT_DOUBLE_EQ(o.model.index.spatial_cell_m, 2 * defaults.model.index.spatial_cell_m);
  EXPECT_EQ(o.tracker.motion.a3, defaults.tracker.motion.a3);  // not asked to identify
  // A map update spacing in the base options is a spatial threshold too.
  CmlEngineOptions spaced_base;
  spaced_base.map_update_spacing_m = 0.15;
  const CmlEngineOptions spaced = ResolveNewMapOptions(file.overrides, input, &note, spaced_base);
  EXPECT_DOUBLE_EQ(spaced.map_update_spacing_m, 0.3);

  file.Write("spatial_scale_source: calibrated\nmodel: {forgetting: {d_for_m: 0.7}}\n");
  const CmlEngineOptions f = ResolveNewMapOptions(file.overrides, input, &note);
  EXPECT_DOUBLE_EQ(f.model.forgetting.d_for_m, 0.7);  // explicit
  EXPECT_DOUBLE_EQ(f.appearance_sigma_m, 2 * defaults.appearance_sigma_m);
}

// A new map's per-frame quantities are restated for the log's frame step
// (reference_frame_step_m): unchanged at the step they are stated for; otherwise, with k
// = reference / step rounded to a half octave, the motion noise times k and the
// appearance evidence per frame times 1 / k (only for k > 1). Explicit values, a
// reference of 0 and identified noise (for the a's) are not scaled.
TEST(RunConfig, PerFrameOptionsFollowTheFrameStep) {
  TempConfig file("omnicml_motion_step_test");
  const RunInput input = SimulatedInput("home_store", 1, 60);  // frames 0.2 m apart
  std::string note;
  const CmlEngineOptions defaults;
  file.Write("threads: 1\n");
  EXPECT_TRUE(SameEngineOptions(ResolveNewMapOptions(file.overrides, input, &note),
                                ResolveEngineOptions(file.overrides)));
  EXPECT_EQ(note, "");

  // Stated for frames 0.4 m apart: twice the noise and half the evidence per frame at
  // 0.2 m per frame.
  CmlEngineOptions sparse;
  sparse.reference_frame_step_m = 0.4;
  const CmlEngineOptions o = ResolveNewMapOptions(file.overrides, input, &note, sparse);
  EXPECT_NE(note.find("motion noise a1..a4 x 2, appearance evidence per frame x 0.5 for "
                      "frames "),
            std::string::npos)
      << note;
  EXPECT_DOUBLE_EQ(o.tracker.motion.a1, 2 * defaults.tracker.motion.a1);
  EXPECT_DOUBLE_EQ(o.tracker.motion.a2, 2 * defaults.tracker.motion.a2);
  EXPECT_DOUBLE_EQ(o.tracker.motion.a3, 2 * defaults.tracker.motion.a3);
  EXPECT_DOUBLE_EQ(o.tracker.motion.a4, 2 * defaults.tracker.motion.a4);
  EXPECT_DOUBLE_EQ(o.hypothesis_evidence_scale, 0.5);
  EXPECT_EQ(o.appearance_sigma_m, defaults.appearance_sigma_m);

  // Stated for frames 0.1 m apart: half the noise per frame, the evidence as it is (a
  // frame never counts for more than one).
  CmlEngineOptions dense;
  dense.reference_frame_step_m = 0.1;
  const CmlEngineOptions d = ResolveNewMapOptions(file.overrides, input, &note, dense);
  EXPECT_DOUBLE_EQ(d.tracker.motion.a3, 0.5 * defaults.tracker.motion.a3);
  EXPECT_EQ(d.hypothesis_evidence_scale, 1.0);

  file.Write("tracker: {motion: {a3: 0.07}}\nhypothesis_evidence_scale: 0.8\n");
  const CmlEngineOptions e = ResolveNewMapOptions(file.overrides, input, &note, sparse);
  EXPECT_DOUBLE_EQ(e.tracker.motion.a3, 0.07);  // explicit
  EXPECT_DOUBLE_EQ(e.hypothesis_evidence_scale, 0.8);
  EXPECT_DOUBLE_EQ(e.tracker.motion.a1, 2 * defaults.tracker.motion.a1);

  file.Write("reference_frame_step_m: 0\n");
  const CmlEngineOptions off = ResolveNewMapOptions(file.overrides, input, &note, sparse);
  EXPECT_EQ(off.tracker.motion.a1, defaults.tracker.motion.a1);
  EXPECT_EQ(off.hypothesis_evidence_scale, 1.0);

  file.Write("motion_noise_source: identified\n");
  const CmlEngineOptions id = ResolveNewMapOptions(file.overrides, input, &note, sparse);
  EXPECT_EQ(note.find("motion noise a1..a4 x"), std::string::npos) << note;
  EXPECT_NE(note.find("appearance evidence per frame x 0.5"), std::string::npos) << note;
  EXPECT_DOUBLE_EQ(id.hypothesis_evidence_scale, 0.5);

  // The live node's path (the step measured on its held first frames) gives the same
  // options and the same note for the same step, explicit values winning as above.
  const std::unique_ptr<FrameSource> poses = OpenPoseOnlySource(input);
  const double step = MedianOdometryStep(*poses, kFrameStepSampleFrames, 0.004);
  for (const std::string& yaml :
       {std::string("threads: 1\n"), std::string("tracker: {motion: {a3: 0.07}}\n"),
        std::string("hypothesis_evidence_scale: 0.8\n")}) {
    file.Write(yaml);
    std::string live_note;
    EXPECT_TRUE(SameEngineOptions(ResolveFrameStepOptions(file.overrides, step, &live_note, sparse),
                                  ResolveNewMapOptions(file.overrides, input, &note, sparse)))
        << yaml;
    EXPECT_EQ(live_note, note) << yaml;
  }
  std::string live_note;
  EXPECT_TRUE(SameEngineOptions(ResolveFrameStepOptions(file.overrides, 0.0, &live_note, sparse),
                                ResolveEngineOptions(file.overrides, sparse)));
  EXPECT_NE(live_note.find("as configured"), std::string::npos) << live_note;
}

// `omnicml calibrate`'s YAML loads as a configuration: the default spatial thresholds
// times s, and the map update spacing for that scale as a comment only.
TEST(RunConfig, CalibrationYamlLoadsWithTheSpacingAsAComment) {
  Calibration c;
  c.frames_used = 100;
  c.e_max = 0.45;
  c.median_step_m = 0.4;
  c.match_length_m = 0.54;
  c.measured_scale = 2.0;
  c.scale = 2.0;
  const std::string yaml = c.ToYaml();
  // Not wider than at the reference scale: a larger place does not afford sparser views.
  EXPECT_NE(yaml.find(StrCat("# map_update_spacing_m: ", kReferenceMapUpdateSpacingM, "\n")),
            std::string::npos)
      << yaml;
  Calibration small = c;
  small.scale = 0.5;
  EXPECT_NE(small.ToYaml().find(
                StrCat("# map_update_spacing_m: ", 0.5 * kReferenceMapUpdateSpacingM, "\n")),
            std::string::npos);
  TempConfig file("omnicml_calibration_yaml_test");
  file.Write(yaml);
  const CmlEngineOptions o = ResolveEngineOptions(file.overrides);
  const CmlEngineOptions defaults;
  EXPECT_DOUBLE_EQ(o.appearance_sigma_m, 2 * defaults.appearance_sigma_m);
  EXPECT_DOUBLE_EQ(o.model.forgetting.d_for_m, 2 * defaults.model.forgetting.d_for_m);
  EXPECT_EQ(o.map_update_spacing_m, 0.0);
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

// A source of `n` numbered frames in one session that throws at frame `throw_at` (-1:
// never).
class CountingSource : public FrameSource {
 public:
  CountingSource(int n, int throw_at) : n_(n), throw_at_(throw_at) { session_.name = "s"; }
  int NumSessions() const override { return 1; }
  const SessionInfo& Session(int) const override { return session_; }
  bool Next(Frame* frame) override {
    if (next_ == throw_at_) throw Error("bad frame " + std::to_string(next_));
    if (next_ >= n_) return false;
    frame->global_index = next_++;
    return true;
  }

 private:
  int n_, throw_at_, next_ = 0;
  SessionInfo session_;
};

// Prefetched simulated frames are the simulator's frames, byte for byte and in order
// (so a run's output does not depend on prefetching), for either image kind.
TEST(PrefetchFrames, DeliversTheSameFramesInOrder) {
  for (const ImageKind kind : {ImageKind::kRawRing, ImageKind::kPanorama}) {
    SimulatorOptions o;
    o.world = "institute";
    o.days = 2;
    o.frames_per_day = 6;
    o.seed = 3;
    o.output = kind;
    SimulatedFrameSource direct(o);
    const auto prefetched = PrefetchFrames(std::make_unique<SimulatedFrameSource>(o), 2);
    ASSERT_EQ(prefetched->NumSessions(), direct.NumSessions());
    Frame a, b;
    int n = 0;
    while (direct.Next(&a)) {
      ASSERT_TRUE(prefetched->Next(&b)) << "frame " << n;
      EXPECT_EQ(a.global_index, b.global_index);
      EXPECT_EQ(a.session_index, b.session_index);
      EXPECT_TRUE(a.odom_T_robot == b.odom_T_robot);
      ASSERT_EQ(a.image.size(), b.image.size());
      EXPECT_EQ(cv::norm(a.image, b.image, cv::NORM_INF), 0.0) << "frame " << n;
      ++n;
    }
    EXPECT_FALSE(prefetched->Next(&b));
    EXPECT_EQ(n, 12);
  }
}

// An error of the inner source reaches the consumer at the frame that failed, after the
// frames before it; a source destroyed before its end stops its thread.
TEST(PrefetchFrames, RethrowsErrorsInOrderAndStopsEarly) {
  const auto source = PrefetchFrames(std::make_unique<CountingSource>(10, 3), 4);
  Frame f;
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(source->Next(&f));
    EXPECT_EQ(f.global_index, i);
  }
  EXPECT_NE(ErrorOf([&] { source->Next(&f); }).find("bad frame 3"), std::string::npos);
  EXPECT_FALSE(source->Next(&f));
  // Destroyed with frames still queued and the producer waiting for space.
  auto early = PrefetchFrames(std::make_unique<CountingSource>(1000, -1), 1);
  ASSERT_TRUE(early->Next(&f));
  early.reset();
}

// The forgetting mode of a run directory comes from its config.yaml whether nested
// (model.forgetting.mode, what runs write) or flat (older configurations); a missing
// or unparsable file names none.
TEST(RunConfig, ReadRunForgettingOfARunDirectory) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("omnicml_run_forgetting_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  EXPECT_EQ(ReadRunForgetting(dir), "");
  CmlEngineOptions o;
  o.model.forgetting.mode = ForgettingMode::kPassive;
  WriteFileAtomic(dir / "config.yaml", "# input: world x\n" + EngineOptionsToYaml(o));
  EXPECT_EQ(ReadRunForgetting(dir), "passive");
  WriteFileAtomic(dir / "config.yaml", "model:\n  forgetting: static\n");
  EXPECT_EQ(ReadRunForgetting(dir), "static");
  WriteFileAtomic(dir / "config.yaml", "model: [unclosed\n");
  EXPECT_EQ(ReadRunForgetting(dir), "");
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace omnicml
