// Tests of the replay page writer: the event log read back, decimation limits, escaping.
#include "omnicml/experiments/replay.h"

#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "omnicml/common/common.h"
#include "omnicml/run/run_report.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

// The JSON data block of a replay page.
nlohmann::json PageData(const std::string& html) {
  const std::string open = "<script type=\"application/json\" id=\"replay-data\">";
  const std::size_t a = html.find(open);
  const std::size_t b = html.find("</script>", a);
  EXPECT_NE(a, std::string::npos);
  return nlohmann::json::parse(html.substr(a + open.size(), b - a - open.size()));
}

std::vector<FrameRecord> Records(int sessions, int frames_per_session) {
  std::vector<FrameRecord> out;
  for (int s = 0; s < sessions; ++s) {
    for (int f = 0; f < frames_per_session; ++f) {
      FrameRecord r;
      r.session = s;
      r.frame = f;
      r.global_frame = static_cast<std::int64_t>(out.size());
      r.has_truth = true;
      r.truth = MakePose(0.1 * f, s, 0);
      r.has_estimate = f % 7 != 0;
      r.estimate = r.truth;
      r.cov_xx_m2 = r.cov_yy_m2 = 0.01;
      r.cov_xy_m2 = 0;
      r.views = f;
      out.push_back(r);
    }
  }
  RecomputeErrors(&out);
  return out;
}

TEST(ReadEventsCsv, ReadsBackWhatTheRecorderWrites) {
  // Every field, a reason with a comma and a quote included, survives the round trip.
  MapEvent a;
  a.type = MapEventType::kViewInserted;
  a.frame = 12;
  a.session = 1;
  a.view_id = 7;
  a.position = MakePose(1.25, -2.5, 0.5);
  a.weight = 1;
  a.reason = "no view within e_max";
  MapEvent b = a;
  b.type = MapEventType::kComponentRemoved;
  b.component_id = 9;
  b.reason = "odd, \"quoted\" reason";
  const fs::path path =
      fs::temp_directory_path() / ("omnicml_replay_events_" + std::to_string(::getpid()) + ".csv");
  {
    std::ofstream out(path);
    WriteEventsCsvHeader(out);
    WriteEventsCsvRow(out, a);
    WriteEventsCsvRow(out, b);
  }
  const std::vector<MapEvent> events = ReadEventsCsv(path);
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[0], a);
  EXPECT_EQ(events[1], b);
  std::ofstream(path, std::ios::app) << "view_removed,x,1,7,0,0,0,0,1,r\n";
  try {
    ReadEventsCsv(path);
    ADD_FAILURE() << "no error for a bad frame";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(":4: frame"), std::string::npos) << e.what();
  }
  fs::remove(path);
  EXPECT_TRUE(ReadEventsCsv(path).empty());  // a missing file: no events
}

TEST(RenderReplayHtml, KeepsAtMostMaxSamplesPlusDayStartsAndTheLastFrame) {
  // 3 days x 1000 frames decimated to 100 samples: every day's first frame and the last
  // frame are kept, samples increase, and no more than 100 + 3 remain.
  ReplayRun run{"passive", Records(3, 1000), {}};
  ReplayOptions options;
  options.max_samples = 100;
  const nlohmann::json data = PageData(RenderReplayHtml({run}, options));
  const auto& f = data["runs"][0]["frames"]["f"];
  EXPECT_LE(f.size(), 103u);
  EXPECT_GE(f.size(), 100u);
  std::vector<std::int64_t> frames = f.get<std::vector<std::int64_t>>();
  EXPECT_TRUE(std::is_sorted(frames.begin(), frames.end()));
  for (std::int64_t start : {0, 1000, 2000, 2999})
    EXPECT_NE(std::find(frames.begin(), frames.end(), start), frames.end()) << start;
  EXPECT_EQ(data["days"].size(), 2u);
  EXPECT_EQ(data["frames_total"], 3000);
  // Frames without an estimate carry null, not a stale pose.
  EXPECT_TRUE(data["runs"][0]["frames"]["ex"][0].is_null());
}

TEST(RenderReplayHtml, ThinsComponentRemovalsAndKeepsViewEvents) {
  // 1000 component removals with a limit of 50: 50 kept (and the total said); the views'
  // insertions and removals are all kept, with active forgetting's removals marked.
  ReplayRun run{"active", Records(1, 50), {}};
  for (int v = 0; v < 10; ++v) {
    MapEvent e;
    e.type = MapEventType::kViewInserted;
    e.view_id = static_cast<std::uint64_t>(v + 1);
    e.frame = v;
    run.events.push_back(e);
  }
  for (int k = 0; k < 1000; ++k) {
    MapEvent e;
    e.type = MapEventType::kComponentRemoved;
    e.view_id = static_cast<std::uint64_t>(k % 10 + 1);
    e.frame = 10 + k / 100;
    e.reason = kActiveForgettingReason;
    run.events.push_back(e);
  }
  MapEvent removed;
  removed.type = MapEventType::kViewRemoved;
  removed.view_id = 3;
  removed.frame = 30;
  removed.reason = "view empty";
  run.events.push_back(removed);
  ReplayOptions options;
  options.max_weakening_events = 50;
  const nlohmann::json data = PageData(RenderReplayHtml({run}, options));
  const auto& r = data["runs"][0];
  EXPECT_EQ(r["weak"]["f"].size(), 50u);
  EXPECT_EQ(r["weak"]["total"], 1000);
  EXPECT_EQ(r["views"]["id"].size(), 10u);
  EXPECT_EQ(r["views"]["died"][2], 30);
  EXPECT_EQ(r["views"]["why"][2], 1);  // its last component went by active forgetting
  EXPECT_EQ(r["views"]["died"][0], -1);
}

TEST(RenderReplayHtml, UserTextNeverBecomesMarkup) {
  // Titles, inputs and run names with markup travel as escaped JSON; the page holds no
  // tag from them and refers to nothing outside itself.
  ReplayRun run{"</script><img src=x onerror=alert(1)>", Records(1, 5), {}};
  ReplayOptions options;
  options.title = "<b>title</b> & co";
  options.input = "world '<x>'";
  const std::string html = RenderReplayHtml({run}, options);
  EXPECT_EQ(html.find("<img"), std::string::npos);
  EXPECT_EQ(html.find("<b>"), std::string::npos);
  EXPECT_EQ(html.find("<script src"), std::string::npos);
  EXPECT_EQ(html.find("http"), std::string::npos);
  const nlohmann::json data = PageData(html);
  EXPECT_EQ(data["title"], "<b>title</b> & co");
  EXPECT_EQ(data["runs"][0]["name"], "</script><img src=x onerror=alert(1)>");
  // Exactly the page's own two scripts.
  std::size_t scripts = 0;
  for (std::size_t p = html.find("<script"); p != std::string::npos;
       p = html.find("<script", p + 1))
    ++scripts;
  EXPECT_EQ(scripts, 2u);
}

}  // namespace
}  // namespace omnicml
