#include "omnicml/engine/engine_io.h"

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/common/options.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml {
// Defined in cml_engine_test.cc (same test binary): a textured room rendered as panoramas
// and laps through it with noisy odometry.
namespace engine_testing {
struct RouteFrame {
  Pose2 truth;
  Pose2 odom;
};
std::vector<RouteFrame> MakeLaps(int laps, double step_m, std::uint32_t seed, int start_offset);
SessionInfo PanoramaSession(const std::string& name, SessionStartMode mode, const Pose2& start);
Frame MakeFrame(const RouteFrame& r, int session, std::int64_t index);
CmlEngineOptions TestOptions();
void ExpectSameEstimate(const FrameResult& a, const FrameResult& b);
}  // namespace engine_testing

namespace {
using namespace engine_testing;
namespace fs = std::filesystem;

// A fresh scratch directory under the build tree.
fs::path ScratchDir(const std::string& name) {
  const fs::path dir = fs::path(OMNICML_BINARY_DIR) / "test_scratch" / "engine_io" / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::vector<std::uint8_t> ReadAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::vector<std::uint8_t>((std::istreambuf_iterator<char>(in)),
                                   std::istreambuf_iterator<char>());
}
void WriteAll(const fs::path& p, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
}

// Runs the frames of one day; returns the results.
std::vector<FrameResult> RunDay(CmlEngine& engine, const SessionInfo& info,
                                const std::vector<RouteFrame>& route, int session) {
  engine.BeginSession(info);
  std::vector<FrameResult> out;
  for (std::size_t i = 0; i < route.size(); ++i) {
    out.push_back(engine.ProcessFrame(MakeFrame(route[i], session, static_cast<std::int64_t>(i))));
  }
  return out;
}

// Expects `fn` to throw omnicml::Error whose message contains every fragment.
template <typename Fn>
void ExpectErrorWith(Fn fn, const std::vector<std::string>& fragments) {
  try {
    fn();
    ADD_FAILURE() << "no error thrown";
  } catch (const Error& e) {
    for (const std::string& f : fragments) {
      EXPECT_NE(std::string(e.what()).find(f), std::string::npos)
          << "'" << f << "' not in: " << e.what();
    }
  }
}

// Save then load restores the same state: re-encoding gives the same bytes.
TEST(EngineIo, RoundTripRestoresState) {
  const fs::path dir = ScratchDir("round_trip");
  CmlEngineOptions o = TestOptions();
  o.update_delay_frames = 4;
  o.model.retrieval.e_max = 0.45;
  o.descriptor.fourier.coefficients = 12;
  CmlEngine engine(o);
  const std::vector<RouteFrame> route = MakeLaps(1, 0.3, 21, 0);
  RunDay(engine, PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth), route, 0);
  // Delayed updates or pending multimodal frames are part of the state.
  ASSERT_FALSE(engine.queued_updates().empty() && engine.pending_frames().empty());
  const fs::path file = dir / "engine.omnicml";
  SaveEngine(engine, file.string());
  const std::unique_ptr<CmlEngine> loaded = LoadEngine(file.string());
  EXPECT_EQ(EncodeEngine(*loaded), EncodeEngine(engine));
  EXPECT_EQ(loaded->options().model.retrieval.e_max, 0.45);
  EXPECT_EQ(loaded->options().descriptor.fourier.coefficients, 12);
  EXPECT_EQ(loaded->options().update_delay_frames, 4);
  EXPECT_EQ(loaded->counters(), engine.counters());
  EXPECT_EQ(loaded->next_frame(), engine.next_frame());
  EXPECT_EQ(loaded->model().views(), engine.model().views());
  loaded->model().CheckInvariants();
  // No temporary file is left next to the result.
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
}

// The session camera's model, fields and user mask are part of the saved state.
TEST(EngineIo, RoundTripKeepsCameraModelAndMask) {
  const fs::path dir = ScratchDir("camera");
  CmlEngine engine(TestOptions());
  SessionInfo info = PanoramaSession("d1", SessionStartMode::kKnownPose, Pose2::Zero());
  FisheyeCalibration f;
  f.center_x_px = 100.5;
  f.center_y_px = 98.25;
  f.circle_radius_px = 95.0;
  f.field_of_view_deg = 200.0;
  f.projection = FisheyeProjection::kEquisolid;
  f.min_elevation_deg = -10.0;
  f.max_elevation_deg = 60.0;
  info.camera.kind = ImageKind::kRawRing;
  info.camera.image_width = 200;
  info.camera.image_height = 200;
  info.camera.calibration = f;
  info.camera.mask = cv::Mat(200, 200, CV_8UC1, cv::Scalar(255));
  info.camera.mask(cv::Rect(100, 90, 100, 20)).setTo(0);
  engine.BeginSession(info);
  const fs::path file = dir / "engine.omnicml";
  SaveEngine(engine, file.string());
  const std::unique_ptr<CmlEngine> loaded = LoadEngine(file.string());
  EXPECT_EQ(EncodeEngine(*loaded), EncodeEngine(engine));
  // Another mask gives other bytes: the mask is stored, not dropped.
  CmlEngine other(TestOptions());
  info.camera.mask = cv::Mat(200, 200, CV_8UC1, cv::Scalar(255));  // a new buffer
  other.BeginSession(info);
  EXPECT_NE(EncodeEngine(other), EncodeEngine(engine));
}

// Save and load restore every option field: all of them set to random values different
// from their defaults (common/options.h RandomizeOptions), for several seeds.
TEST(EngineIo, RestoresEveryOptionField) {
  for (std::uint32_t seed : {1u, 2u, 3u}) {
    std::mt19937 rng(seed);
    CmlEngineOptions o;
    RandomizeOptions(&o, rng);
    ASSERT_NO_THROW(o.Validate()) << OptionsToYaml(o);
    const OptionValue defaults = OptionsToValue(CmlEngineOptions{});
    const OptionValue randomised = OptionsToValue(o);
    for (std::size_t i = 0; i < defaults.members.size(); ++i) {
      if (defaults.members[i].second.kind == OptionValue::Kind::kMap) continue;  // sections
      EXPECT_FALSE(defaults.members[i].second == randomised.members[i].second)
          << defaults.members[i].first;
    }
    CmlEngine engine(o);
    const std::unique_ptr<CmlEngine> loaded = DecodeEngine(EncodeEngine(engine), "engine");
    EXPECT_TRUE(SameOptions(loaded->options(), o)) << OptionsToYaml(loaded->options()) << "\n---\n"
                                                   << OptionsToYaml(o);
    EXPECT_EQ(loaded->options().reconstruction.motion.a3, o.tracker.motion.a3);
    EXPECT_EQ(EncodeEngine(*loaded), EncodeEngine(engine));
  }
}

// Day 1, save, load, day 2 gives bit-identically the result of one run over both days.
TEST(EngineIo, SaveLoadBetweenDaysIsBitIdentical) {
  const fs::path dir = ScratchDir("days");
  const std::vector<RouteFrame> day1 = MakeLaps(2, 0.3, 31, 0);
  const std::vector<RouteFrame> day2 = MakeLaps(1, 0.3, 32, 11);
  const SessionInfo s1 = PanoramaSession("d1", SessionStartMode::kKnownPose, day1[0].truth);
  const SessionInfo s2 = PanoramaSession("d2", SessionStartMode::kGlobal, Pose2::Zero());
  for (int threads : {1, 2}) {
    CmlEngineOptions o = TestOptions();
    o.threads = threads;
    CmlEngine whole(o);
    RunDay(whole, s1, day1, 0);
    const std::vector<FrameResult> expected = RunDay(whole, s2, day2, 1);
    whole.Finish();

    CmlEngine first(o);
    RunDay(first, s1, day1, 0);
    const fs::path file = dir / "after_day1.omnicml";
    SaveEngine(first, file.string());
    const std::unique_ptr<CmlEngine> second = LoadEngine(file.string());
    const std::vector<FrameResult> got = RunDay(*second, s2, day2, 1);
    second->Finish();

    ASSERT_EQ(got.size(), expected.size());
    for (std::size_t i = 0; i < got.size(); ++i) {
      EXPECT_EQ(got[i].frame, expected[i].frame);
      ExpectSameEstimate(got[i], expected[i]);
    }
    EXPECT_EQ(EncodeEngine(*second), EncodeEngine(whole)) << "threads " << threads;
  }
}

// With map_update_spacing_m the place of the last map update is part of the state: a save
// and load in the middle of a session continues bit-identically to one run.
TEST(EngineIo, SaveLoadMidSessionWithSpacingIsBitIdentical) {
  const fs::path dir = ScratchDir("spacing");
  const std::vector<RouteFrame> route = MakeLaps(1, 0.15, 34, 0);
  const std::size_t half = route.size() / 2 + 1;
  const SessionInfo s1 = PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth);
  CmlEngineOptions o = TestOptions();
  o.map_update_spacing_m = 0.4;
  const auto run = [&](CmlEngine& engine, std::size_t begin, std::size_t end) {
    std::vector<FrameResult> out;
    for (std::size_t i = begin; i < end; ++i)
      out.push_back(engine.ProcessFrame(MakeFrame(route[i], 0, static_cast<std::int64_t>(i))));
    return out;
  };
  CmlEngine whole(o);
  whole.BeginSession(s1);
  const std::vector<FrameResult> expected = run(whole, 0, route.size());
  whole.Finish();
  EXPECT_LT(whole.counters().updates_queued, whole.counters().frames / 2);

  CmlEngine first(o);
  first.BeginSession(s1);
  run(first, 0, half);
  const fs::path file = dir / "mid_session.omnicml";
  SaveEngine(first, file.string());
  const std::unique_ptr<CmlEngine> second = LoadEngine(file.string());
  EXPECT_EQ(EncodeEngine(*second), EncodeEngine(first));
  const std::vector<FrameResult> got = run(*second, half, route.size());
  second->Finish();
  ASSERT_EQ(got.size(), route.size() - half);
  for (std::size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].stats.updates_queued, expected[half + i].stats.updates_queued)
        << "frame " << got[i].frame;
    ExpectSameEstimate(got[i], expected[half + i]);
  }
  EXPECT_EQ(EncodeEngine(*second), EncodeEngine(whole));
}

// With smooth_map_updates the frames behind the smoothing of the queued updates are part
// of the state: a save and load in the middle of the second day continues bit-identically
// to one run, with one or two threads; and the option changes the map (day 2 localizes
// against day 1, so its updates are smoothed by later fixes).
TEST(EngineIo, SaveLoadMidSessionWithSmoothingIsBitIdentical) {
  const fs::path dir = ScratchDir("smoothing");
  const std::vector<RouteFrame> day1 = MakeLaps(1, 0.2, 35, 0);
  const std::vector<RouteFrame> day2 = MakeLaps(1, 0.2, 36, 7);
  const std::size_t half = day2.size() / 2 + 3;
  const SessionInfo s1 = PanoramaSession("d1", SessionStartMode::kKnownPose, day1[0].truth);
  const SessionInfo s2 = PanoramaSession("d2", SessionStartMode::kKnownPose, day2[0].truth);
  const auto run = [&](CmlEngine& engine, std::size_t begin, std::size_t end) {
    std::vector<FrameResult> out;
    for (std::size_t i = begin; i < end; ++i)
      out.push_back(engine.ProcessFrame(MakeFrame(day2[i], 1, static_cast<std::int64_t>(i))));
    return out;
  };
  CmlEngineOptions plain = TestOptions();
  plain.smooth_map_updates = false;
  CmlEngine unsmoothed(plain);
  RunDay(unsmoothed, s1, day1, 0);
  unsmoothed.BeginSession(s2);
  run(unsmoothed, 0, day2.size());
  unsmoothed.Finish();
  for (int threads : {1, 2}) {
    CmlEngineOptions o = TestOptions();
    o.smooth_map_updates = true;
    o.threads = threads;
    CmlEngine whole(o);
    RunDay(whole, s1, day1, 0);
    whole.BeginSession(s2);
    const std::vector<FrameResult> expected = run(whole, 0, day2.size());
    whole.Finish();
    BinaryWriter smoothed_model, unsmoothed_model;
    whole.model().Serialize(smoothed_model);
    unsmoothed.model().Serialize(unsmoothed_model);
    EXPECT_NE(smoothed_model.bytes(), unsmoothed_model.bytes())
        << "the smoothing changed no update";

    CmlEngine first(o);
    RunDay(first, s1, day1, 0);
    first.BeginSession(s2);
    run(first, 0, half);
    const fs::path file = dir / "mid_day2.omnicml";
    SaveEngine(first, file.string());
    const std::unique_ptr<CmlEngine> second = LoadEngine(file.string());
    EXPECT_EQ(EncodeEngine(*second), EncodeEngine(first));
    const std::vector<FrameResult> got = run(*second, half, day2.size());
    second->Finish();
    ASSERT_EQ(got.size(), day2.size() - half);
    for (std::size_t i = 0; i < got.size(); ++i) ExpectSameEstimate(got[i], expected[half + i]);
    EXPECT_EQ(EncodeEngine(*second), EncodeEngine(whole)) << "threads " << threads;
  }
}

// Truncated, corrupted, foreign and future-version files are rejected, naming the file.
TEST(EngineIo, RejectsDamagedFiles) {
  const fs::path dir = ScratchDir("damaged");
  CmlEngine engine(TestOptions());
  const std::vector<RouteFrame> route = MakeLaps(1, 0.5, 41, 0);
  RunDay(engine, PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth), route, 0);
  const fs::path good = dir / "good.omnicml";
  SaveEngine(engine, good.string());
  const std::vector<std::uint8_t> bytes = ReadAll(good);
  ASSERT_GT(bytes.size(), 100u);

  const fs::path bad = dir / "bad.omnicml";
  // Truncated at several places (header, payload, checksum).
  for (std::size_t keep :
       {std::size_t{0}, std::size_t{5}, std::size_t{15}, bytes.size() / 2, bytes.size() - 1}) {
    WriteAll(bad, std::vector<std::uint8_t>(bytes.begin(),
                                            bytes.begin() + static_cast<std::ptrdiff_t>(keep)));
    ExpectErrorWith([&] { LoadEngine(bad.string()); }, {bad.string()});
  }
  WriteAll(bad, std::vector<std::uint8_t>(bytes.begin(), bytes.end() - 10));
  ExpectErrorWith([&] { LoadEngine(bad.string()); }, {bad.string(), "truncated"});
  // One flipped bit anywhere in the payload breaks the checksum.
  for (std::size_t pos : {std::size_t{30}, bytes.size() / 3, bytes.size() - 6}) {
    std::vector<std::uint8_t> flipped = bytes;
    flipped[pos] ^= 0x10;
    WriteAll(bad, flipped);
    ExpectErrorWith([&] { LoadEngine(bad.string()); }, {bad.string(), "checksum"});
  }
  // Wrong magic.
  std::vector<std::uint8_t> foreign = bytes;
  foreign[0] = 'X';
  WriteAll(bad, foreign);
  ExpectErrorWith([&] { LoadEngine(bad.string()); }, {bad.string(), "magic"});
  // Unknown version.
  std::vector<std::uint8_t> future = bytes;
  future[8] = static_cast<std::uint8_t>(kEngineFormatVersion + 1);
  WriteAll(bad, future);
  ExpectErrorWith([&] { LoadEngine(bad.string()); }, {bad.string(), "version"});
  // Trailing garbage.
  std::vector<std::uint8_t> longer = bytes;
  longer.push_back(0);
  WriteAll(bad, longer);
  ExpectErrorWith([&] { LoadEngine(bad.string()); }, {bad.string()});
  // Missing file.
  ExpectErrorWith([&] { LoadEngine((dir / "missing.omnicml").string()); }, {"missing.omnicml"});
  // The good file still loads.
  EXPECT_NO_THROW(LoadEngine(good.string()));
}

// A version of any section other than the one this build reads (the header's engine
// format, the model section inside it), with a valid checksum, is refused by a one-line
// "unsupported ... version N (this build reads A..B)" naming the file, not misread.
TEST(EngineIo, RefusesUnsupportedSectionVersions) {
  const fs::path dir = ScratchDir("section_versions");
  CmlEngine engine(TestOptions());
  const std::vector<RouteFrame> route = MakeLaps(1, 0.5, 43, 0);
  RunDay(engine, PanoramaSession("d1", SessionStartMode::kKnownPose, route[0].truth), route, 0);
  const fs::path good = dir / "good.omnicml";
  SaveEngine(engine, good.string());
  const std::vector<std::uint8_t> bytes = ReadAll(good);
  constexpr std::size_t kHeader = 8 + 4 + 8;  // magic, format version, payload length
  ASSERT_GT(bytes.size(), kHeader + 4);
  // The model section starts with its magic "OCEM" and a u32 version.
  const std::vector<std::uint8_t> magic = {'O', 'C', 'E', 'M'};
  const auto at = std::search(bytes.begin() + kHeader, bytes.end() - 4, magic.begin(), magic.end());
  ASSERT_NE(at, bytes.end() - 4) << "no model section found";
  const std::size_t model_version_at = static_cast<std::size_t>(at - bytes.begin()) + 4;
  ASSERT_EQ(bytes[model_version_at], EnvironmentModel::kFormatVersion);

  // Sets the u32 at `offset` and recomputes the payload checksum.
  const auto with_u32 = [&](std::size_t offset, std::uint32_t value) {
    std::vector<std::uint8_t> out = bytes;
    for (int i = 0; i < 4; ++i) out[offset + i] = static_cast<std::uint8_t>(value >> (8 * i));
    const std::span<const std::uint8_t> payload(out.data() + kHeader, out.size() - kHeader - 4);
    const std::uint32_t crc = Crc32(payload);
    for (int i = 0; i < 4; ++i) out[out.size() - 4 + i] = static_cast<std::uint8_t>(crc >> (8 * i));
    return out;
  };
  const fs::path bad = dir / "bad.omnicml";
  const auto expect_refused = [&](const std::vector<std::uint8_t>& file, const std::string& text) {
    WriteAll(bad, file);
    try {
      LoadEngine(bad.string());
      ADD_FAILURE() << "loaded a file with " << text;
    } catch (const Error& e) {
      const std::string message = e.what();
      EXPECT_EQ(message.rfind(bad.string() + ": ", 0), 0u) << message;
      EXPECT_NE(message.find(text), std::string::npos) << message;
      EXPECT_EQ(message.find('\n'), std::string::npos) << message;
    }
  };
  const std::string v = std::to_string(kEngineFormatVersion);
  for (const std::uint32_t version : {kEngineFormatVersion - 1, kEngineFormatVersion + 1, 0u}) {
    expect_refused(with_u32(8, version), StrCat("unsupported engine format version ", version,
                                                " (this build reads ", v, "..", v, ")"));
  }
  const std::string m = std::to_string(EnvironmentModel::kFormatVersion);
  for (const std::uint32_t version :
       {EnvironmentModel::kFormatVersion - 1, EnvironmentModel::kFormatVersion + 1, 1u, 0u}) {
    expect_refused(with_u32(model_version_at, version),
                   StrCat("unsupported environment model version ", version, " (this build reads ",
                          m, "..", m, ")"));
  }
  // The unchanged bytes, checksum recomputed the same way, still load.
  WriteAll(bad, with_u32(model_version_at, EnvironmentModel::kFormatVersion));
  EXPECT_NO_THROW(LoadEngine(bad.string()));
}

// Saving over an existing file replaces it atomically; an unwritable place is an error.
TEST(EngineIo, AtomicOverwriteAndWriteErrors) {
  const fs::path dir = ScratchDir("overwrite");
  const fs::path file = dir / "e.omnicml";
  WriteAll(file, {1, 2, 3});
  CmlEngine engine(TestOptions());
  SaveEngine(engine, file.string());
  EXPECT_EQ(ReadAll(file), EncodeEngine(engine));
  ExpectErrorWith([&] { SaveEngine(engine, (dir / "no_such_dir" / "e.omnicml").string()); },
                  {"no_such_dir"});
}

}  // namespace
}  // namespace omnicml
