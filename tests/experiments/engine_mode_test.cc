// Mode changes of a running CmlEngine (SetForgettingMode, SetThreads) against the path
// they replace: re-encoding the engine with other options in the stored bytes and
// decoding it (what RebuildEngineWithOptions did), and against engines constructed with
// the mode.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/engine/engine_io.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {
namespace {

constexpr int kFramesPerDay = 120;

struct SimulatedInput {
  std::vector<std::vector<Frame>> days;  // frames of each day
  std::vector<SessionInfo> sessions;
};

SimulatedInput SimulatedDays(int days) {
  SimulatorOptions so;
  so.world = "home_store";
  so.days = days;
  so.frames_per_day = kFramesPerDay;
  so.seed = 2;
  so.output = ImageKind::kPanorama;
  SimulatedFrameSource source(so);
  SimulatedInput out;
  out.days.resize(static_cast<std::size_t>(days));
  Frame f;
  while (source.Next(&f)) out.days[static_cast<std::size_t>(f.session_index)].push_back(f);
  for (int d = 0; d < days; ++d) out.sessions.push_back(source.Session(d));
  return out;
}

// The reference: the engine re-encoded with `options` spliced into the stored bytes
// (the payload starts with the options, engine_io.h) and decoded.
std::unique_ptr<CmlEngine> DecodeWithOptions(const CmlEngine& engine,
                                             const CmlEngineOptions& options) {
  const std::vector<std::uint8_t> bytes = EncodeEngine(engine);
  constexpr std::size_t kHeader = 8 + 4 + 8, kTrailer = 4;
  BinaryWriter old_options, new_options;
  WriteEngineOptions(old_options, engine.options());
  WriteEngineOptions(new_options, options);
  const std::size_t old_size = old_options.bytes().size();
  EXPECT_TRUE(
      std::equal(old_options.bytes().begin(), old_options.bytes().end(), bytes.begin() + kHeader));
  std::vector<std::uint8_t> payload(new_options.bytes());
  payload.insert(payload.end(), bytes.begin() + static_cast<std::ptrdiff_t>(kHeader + old_size),
                 bytes.end() - static_cast<std::ptrdiff_t>(kTrailer));
  BinaryWriter file;
  for (char ch : kEngineMagic) file.Write<std::uint8_t>(static_cast<std::uint8_t>(ch));
  file.Write<std::uint32_t>(kEngineFormatVersion);
  file.Write<std::uint64_t>(payload.size());
  file.WriteBytes(payload);
  file.Write<std::uint32_t>(Crc32(payload));
  return DecodeEngine(file.Release(), "spliced engine");
}

class EngineModeTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { input_ = new SimulatedInput(SimulatedDays(2)); }
  static void TearDownTestSuite() { delete input_; }

  // Runs frames [begin, end) of day `d` (BeginSession first when begin == 0) and
  // returns the strongest estimates (NaN without estimate) and the map size per frame.
  static std::vector<double> RunDay(CmlEngine& engine, int d, std::size_t begin = 0,
                                    std::size_t end = SIZE_MAX) {
    const std::vector<Frame>& frames = input_->days[static_cast<std::size_t>(d)];
    if (begin == 0) engine.BeginSession(input_->sessions[static_cast<std::size_t>(d)]);
    std::vector<double> out;
    for (std::size_t i = begin; i < std::min(end, frames.size()); ++i) {
      const FrameResult r = engine.ProcessFrame(frames[i]);
      const Pose2 p = r.estimate ? r.estimate->strongest.mean
                                 : Pose2::Constant(std::numeric_limits<double>::quiet_NaN());
      out.insert(out.end(), {p.x(), p.y(), p.z(), static_cast<double>(r.stats.num_views)});
    }
    return out;
  }

  static inline SimulatedInput* input_ = nullptr;
};

// Bitwise equality of estimate sequences (NaN == NaN).
void ExpectSameSequence(const std::vector<double>& a, const std::vector<double>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::isnan(a[i]) && std::isnan(b[i])) continue;
    ASSERT_EQ(a[i], b[i]) << "value " << i;
  }
}

TEST_F(EngineModeTest, SetForgettingModeMidRunEqualsTheDecodedEngineWithThatMode) {
  // Freezing after day 1 in place gives the state and day 2 of the spliced-and-decoded
  // engine (the old RebuildEngineWithOptions path), bit for bit.
  CmlEngineOptions options;
  options.model.forgetting.mode = ForgettingMode::kActive;
  CmlEngine in_place(options);
  RunDay(in_place, 0);
  CmlEngineOptions frozen = in_place.options();
  frozen.model.forgetting.mode = ForgettingMode::kStatic;
  std::unique_ptr<CmlEngine> decoded = DecodeWithOptions(in_place, frozen);
  in_place.SetForgettingMode(ForgettingMode::kStatic);
  EXPECT_EQ(in_place.options().model.forgetting.mode, ForgettingMode::kStatic);
  EXPECT_EQ(in_place.model().options().forgetting.mode, ForgettingMode::kStatic);
  EXPECT_EQ(EncodeEngine(in_place), EncodeEngine(*decoded));
  ExpectSameSequence(RunDay(in_place, 1), RunDay(*decoded, 1));
  in_place.Finish();
  decoded->Finish();
  EXPECT_EQ(EncodeEngine(in_place), EncodeEngine(*decoded));
}

TEST_F(EngineModeTest, SetForgettingModeBeforeTheFirstFrameEqualsConstructingWithIt) {
  // An engine switched to passive before any frame is the engine constructed passive.
  CmlEngineOptions active;
  active.model.forgetting.mode = ForgettingMode::kActive;
  CmlEngineOptions passive = active;
  passive.model.forgetting.mode = ForgettingMode::kPassive;
  CmlEngine switched(active);
  switched.SetForgettingMode(ForgettingMode::kPassive);
  CmlEngine constructed(passive);
  EXPECT_EQ(EncodeEngine(switched), EncodeEngine(constructed));
  for (int d = 0; d < 2; ++d) ExpectSameSequence(RunDay(switched, d), RunDay(constructed, d));
  EXPECT_EQ(EncodeEngine(switched), EncodeEngine(constructed));
}

TEST_F(EngineModeTest, SetThreadsMidRunChangesNothingButTheWorker) {
  // threads 1 -> 2 during day 1 (queued updates handed to the new updater)
  // gives the estimates and map of threads 1 throughout, and of the decoded engine with
  // threads 2; back to 1, the state is the reference's bit for bit.
  CmlEngineOptions one;
  one.threads = 1;
  CmlEngine reference(one), switched(one);
  // Switch at the first frame after which updates are waiting in the queue.
  std::size_t k = 0;
  const std::size_t n = input_->days[0].size();
  while (k < n && (k == 0 || switched.queued_updates().empty())) {
    RunDay(reference, 0, k, k + 1);
    RunDay(switched, 0, k, k + 1);
    ++k;
  }
  ASSERT_LT(k, n) << "the test needs queued updates";
  CmlEngineOptions two = switched.options();
  two.threads = 2;
  std::unique_ptr<CmlEngine> decoded = DecodeWithOptions(switched, two);
  switched.SetThreads(2);
  EXPECT_EQ(switched.options().threads, 2);
  EXPECT_EQ(EncodeEngine(switched), EncodeEngine(*decoded));
  std::vector<double> rest = RunDay(switched, 0, k);
  ExpectSameSequence(rest, RunDay(reference, 0, k));
  ExpectSameSequence(rest, RunDay(*decoded, 0, k));
  rest = RunDay(switched, 1);
  ExpectSameSequence(rest, RunDay(reference, 1));
  ExpectSameSequence(rest, RunDay(*decoded, 1));
  switched.SetThreads(1);
  EXPECT_EQ(EncodeEngine(switched), EncodeEngine(reference));
}

TEST_F(EngineModeTest, SetThreadsRejectsZeroAndLeavesTheEngineUnchanged) {
  // An invalid thread count is an omnicml::Error and changes nothing.
  CmlEngine engine(CmlEngineOptions{});
  RunDay(engine, 0);
  const std::vector<std::uint8_t> before = EncodeEngine(engine);
  EXPECT_THROW(engine.SetThreads(0), Error);
  EXPECT_EQ(EncodeEngine(engine), before);
}

}  // namespace
}  // namespace omnicml
