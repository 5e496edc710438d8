// Survey mapping (experiments/survey.h, CmlEngine::ProcessSurveyFrame): the map of the
// survey days is built at the trusted poses; TUM parsing and its errors; determinism;
// the run's evaluation leaves the survey days out.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "omnicml/common/binary_io.h"
#include "omnicml/common/common.h"
#include "omnicml/engine/cml_engine.h"
#include "omnicml/evaluation/evaluation.h"
#include "omnicml/experiments/run_experiment.h"
#include "omnicml/experiments/survey.h"
#include "omnicml/report/map_export.h"
#include "omnicml/sim/simulator.h"

namespace omnicml {
namespace {

namespace fs = std::filesystem;

SimulatorOptions Sim(int days, int frames) {
  SimulatorOptions so;
  so.world = "home_store";
  so.days = days;
  so.frames_per_day = frames;
  so.seed = 3;
  so.output = ImageKind::kPanorama;
  return so;
}

fs::path TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("omnicml_survey_test_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::vector<std::uint8_t> ModelBytes(const CmlEngine& engine) {
  BinaryWriter w;
  engine.model().Serialize(w);
  return w.bytes();
}

// Runs `engine` over the simulated days with the survey processor; returns the frames.
std::vector<Frame> RunSurvey(CmlEngine& engine, const SimulatorOptions& so,
                             const SurveyOptions& survey) {
  SimulatedFrameSource source(so);
  ProgressOptions quiet;
  quiet.quiet = true;
  std::vector<Frame> frames;
  // Collect the frames from a second, identical source (deterministic simulator).
  SimulatedFrameSource copy(so);
  Frame f;
  while (copy.Next(&f)) frames.push_back(f);
  RunEngineOverSource(engine, source, nullptr, quiet, {},
                      MakeSurveyFrameProcessor(survey, nullptr));
  engine.Finish();
  return frames;
}

// Survey views are inserted at the trusted poses: with merging off, every component
// mean's xy is exactly a ground-truth position of the day, and each view's first
// component is the full pose (heading included) of the frame that created it.
TEST(Survey, ViewsAreBuiltAtTheTrustedPoses) {
  CmlEngineOptions o;
  o.model.update.merge_delta = 1e-12;  // no merge: a component is one update's pose
  o.model.forgetting.mode = ForgettingMode::kPassive;
  CmlEngine engine(o);
  SurveyOptions survey;
  survey.days = 1;
  const std::vector<Frame> frames = RunSurvey(engine, Sim(1, 120), survey);
  ASSERT_EQ(frames.size(), 120u);
  ASSERT_GT(engine.model().NumViews(), 5u);
  for (const ReferenceView& v : engine.model().views()) {
    const Frame& creator = frames[static_cast<std::size_t>(v.stats.created_frame)];
    ASSERT_TRUE(creator.map_T_robot_truth);
    // The creating update matched its own view with relative heading 0.
    EXPECT_EQ(v.components.front().mean.x(), creator.map_T_robot_truth->x());
    EXPECT_EQ(v.components.front().mean.y(), creator.map_T_robot_truth->y());
    EXPECT_NEAR(v.components.front().mean.z(), creator.map_T_robot_truth->z(), 1e-12);
    for (const ViewComponent& c : v.components) {
      bool found = false;
      for (const Frame& fr : frames) {
        found = found || (fr.map_T_robot_truth->x() == c.mean.x() &&
                          fr.map_T_robot_truth->y() == c.mean.y());
      }
      EXPECT_TRUE(found) << "component " << c.id << " of view " << v.id << " at "
                         << c.mean.transpose();
    }
  }
}

// The estimate of a survey frame is the trusted pose, and CML goes on from it.
TEST(Survey, EstimateIsTheTrustedPoseThenCmlTakesOver) {
  CmlEngine engine(CmlEngineOptions{});
  SimulatedFrameSource source(Sim(2, 60));
  Frame f;
  const FrameProcessor process =
      MakeSurveyFrameProcessor(SurveyOptions{1, "", 0.05, 0.02}, nullptr);
  int session = -1, cml_frames = 0;
  while (source.Next(&f)) {
    if (f.session_index != session) {
      session = f.session_index;
      engine.BeginSession(source.Session(session));
    }
    const FrameResult r = process(engine, f);
    ASSERT_TRUE(r.estimate);
    if (f.session_index == 0) {
      EXPECT_EQ(r.estimate->mean.mean, *f.map_T_robot_truth);
      EXPECT_NEAR(r.estimate->mean.covariance(0, 0), 0.05 * 0.05, 1e-15);
      EXPECT_EQ(r.stats.num_matches, 0);
    } else {
      ++cml_frames;
      // Day 2 localizes on the survey map (within a metre of the truth).
      EXPECT_LT((r.estimate->strongest.mean.head<2>() - f.map_T_robot_truth->head<2>()).norm(),
                1.0);
    }
  }
  EXPECT_EQ(cml_frames, 60);
}

// Poses from a TUM file matched by stamp give exactly the map of the ground-truth survey.
TEST(Survey, TumPosesMatchedByStampEqualGroundTruthSurvey) {
  const fs::path dir = TempDir("tum");
  const SimulatorOptions so = Sim(1, 80);
  {
    SimulatedFrameSource source(so);
    std::ofstream out(dir / "poses.tum");
    out << "# stamp x y z qx qy qz qw\n\n";
    Frame f;
    std::vector<std::string> lines;
    while (source.Next(&f)) lines.push_back(TumLine(f.stamp_s, *f.map_T_robot_truth));
    // Out of order in the file: matching is by stamp.
    for (std::size_t i = lines.size(); i-- > 0;) out << lines[i] << "\n";
  }
  CmlEngine a(CmlEngineOptions{}), b(CmlEngineOptions{});
  RunSurvey(a, so, SurveyOptions{1, "", 0.05, 0.02});
  RunSurvey(b, so, SurveyOptions{1, (dir / "poses.tum").string(), 0.05, 0.02});
  ASSERT_GT(a.model().NumViews(), 0u);
  // TumLine stores the heading as a quaternion: equal up to rounding of the yaw.
  ASSERT_EQ(a.model().NumViews(), b.model().NumViews());
  for (std::size_t i = 0; i < a.model().NumViews(); ++i) {
    const auto& va = a.model().views()[i];
    const auto& vb = b.model().views()[i];
    ASSERT_EQ(va.components.size(), vb.components.size());
    for (std::size_t j = 0; j < va.components.size(); ++j) {
      EXPECT_EQ(va.components[j].mean.head<2>(), vb.components[j].mean.head<2>());
      EXPECT_NEAR(va.components[j].mean.z(), vb.components[j].mean.z(), 1e-9);
    }
  }
  fs::remove_all(dir);
}

// Malformed TUM lines, repeated stamps and frames without a pose name file and line.
TEST(Survey, TumErrorsNameFileAndLine) {
  const fs::path dir = TempDir("errors");
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir / name) << text;
    return (dir / name).string();
  };
  auto message = [](const std::string& path) {
    try {
      SurveyPoses::Read(path);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  const std::string short_line = write("short.tum", "# c\n0 0 0 0 0 0 0 1\n1 2 3 0 0 0 1\n");
  EXPECT_NE(message(short_line).find(short_line + ":3: expected 8 numbers"), std::string::npos)
      << message(short_line);
  const std::string extra = write("extra.tum", "0 0 0 0 0 0 0 1 9\n");
  EXPECT_NE(message(extra).find(extra + ":1: more than 8 values"), std::string::npos);
  const std::string nan = write("nan.tum", "0 0 0 0 0 0 0 1\n1 nan 0 0 0 0 0 1\n");
  EXPECT_NE(message(nan).find(nan + ":2:"), std::string::npos) << message(nan);
  const std::string zero_q = write("q.tum", "0 0 0 0 0 0 0 0\n");
  EXPECT_NE(message(zero_q).find(zero_q + ":1: zero quaternion"), std::string::npos);
  const std::string dup =
      write("dup.tum", "0 0 0 0 0 0 0 1\n5 0 0 0 0 0 0 1\n# x\n5 1 0 0 0 0 0 1\n");
  EXPECT_NE(message(dup).find(dup + ":4: stamp 5 repeats the stamp of line 2"), std::string::npos)
      << message(dup);
  const std::string empty = write("empty.tum", "# nothing\n");
  EXPECT_NE(message(empty).find(empty + ": no pose"), std::string::npos);

  // A survey frame whose stamp is not in the file.
  const std::string partial = write("partial.tum", "0 0 0 0 0 0 0 1\n");
  CmlEngine engine(CmlEngineOptions{});
  try {
    RunSurvey(engine, Sim(1, 5), SurveyOptions{1, partial, 0.05, 0.02});
    ADD_FAILURE() << "no error for frames without a pose";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(partial + ": no pose with stamp"), std::string::npos)
        << e.what();
  }
  // --survey-poses without --survey-days, negative days.
  EXPECT_THROW((SurveyOptions{0, partial, 0.05, 0.02}.Validate()), Error);
  EXPECT_THROW((SurveyOptions{-1, "", 0.05, 0.02}.Validate()), Error);
  fs::remove_all(dir);
}

// A survey then CML: bit-identical maps and estimates with 1 and 2 threads and run to run.
TEST(Survey, DeterministicWithOneOrTwoThreads) {
  const SimulatorOptions so = Sim(2, 70);
  std::vector<std::vector<std::uint8_t>> maps;
  for (int threads : {1, 2, 1}) {
    CmlEngineOptions o;
    o.threads = threads;
    CmlEngine engine(o);
    RunSurvey(engine, so, SurveyOptions{1, "", 0.05, 0.02});
    maps.push_back(ModelBytes(engine));
  }
  EXPECT_EQ(maps[0], maps[1]);
  EXPECT_EQ(maps[0], maps[2]);
}

// `run --survey-days 1`: the evaluation covers day 2 only and the output says why.
TEST(Survey, RunEvaluatesTheDaysAfterTheSurvey) {
  const fs::path dir = TempDir("run");
  RunExperimentOptions o;
  o.settings.input.world = "home_store";
  o.settings.input.days = 2;
  o.settings.input.frames_per_day = 60;
  o.settings.input.seed = 3;
  o.settings.out_dir = (dir / "out").string();
  o.settings.quiet = true;
  o.settings.survey.days = 1;
  const RunExperimentResult r = RunExperiment(o);
  EXPECT_EQ(r.survey_frames, 60);
  ASSERT_EQ(r.evaluation.days.size(), 1u);
  EXPECT_EQ(r.evaluation.days[0].session, 1);
  EXPECT_EQ(r.evaluation.overall.frames, 60);
  const std::string text = FormatRunExperimentResult(o, r);
  EXPECT_NE(text.find("survey day 1 (60 frames) excluded from the errors"), std::string::npos)
      << text;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omnicml
