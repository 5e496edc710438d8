// Tests of the run records, error statistics, alignment and evaluation report.
#include "omnicml/evaluation/evaluation.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <gtest/gtest.h>
#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "omnicml/common/common.h"
#include "omnicml/evaluation/trajectory_metrics.h"
#include "omnicml/geometry/chi_square.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;

fs::path TempDir(const std::string& name) {
  fs::path dir = fs::temp_directory_path() /
                 ("omnicml_evaluation_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// A record with estimate and truth; errors computed by RecomputeErrors.
FrameRecord MakeRecord(int session, int frame, const Pose2& estimate, const Pose2& truth) {
  FrameRecord r;
  r.session = session;
  r.frame = frame;
  r.global_frame = session * 1000 + frame;
  r.stamp_s = 0.1 * frame;
  r.has_estimate = true;
  r.estimate = estimate;
  r.mean_estimate = estimate;
  r.unimodal = frame % 2 == 0;
  r.has_truth = true;
  r.truth = truth;
  r.views = frame;
  r.stage_times_us = {10.0, 20.0 + frame};
  return r;
}

TEST(ComputeStats, MatchesDirectComputation) {
  // Mean, median, p95 (linear interpolation) and max of 1..100, NaN ignored.
  std::vector<double> v;
  for (int i = 100; i >= 1; --i) v.push_back(i);
  v.push_back(kNaN);
  const ErrorStats s = ComputeStats(v);
  EXPECT_EQ(s.count, 100);
  EXPECT_DOUBLE_EQ(s.mean, 50.5);
  EXPECT_DOUBLE_EQ(s.median, 50.5);
  EXPECT_NEAR(s.p95, 95.05, 1e-12);
  EXPECT_DOUBLE_EQ(s.max, 100);
  const ErrorStats empty = ComputeStats({kNaN});
  EXPECT_EQ(empty.count, 0);
  EXPECT_TRUE(std::isnan(empty.mean));
}

TEST(HistogramCounts, KeepsEveryFiniteValue) {
  // Counts sum to the number of finite values >= the first edge; overflow goes to the last bin.
  const std::vector<double> edges = {0, 0.5, 1.0, 1.5};
  const std::vector<double> counts =
      HistogramCounts({0.0, 0.49, 0.5, 1.2, 1.5, 7.0, kNaN, -1}, edges);
  ASSERT_EQ(counts.size(), 3u);
  EXPECT_EQ(counts[0], 2);
  EXPECT_EQ(counts[1], 1);
  EXPECT_EQ(counts[2], 3);
}

TEST(FramesCsv, RoundTripsRecords) {
  // Writing and reading frames.csv gives back the same values, missing cells as missing.
  const fs::path dir = TempDir("roundtrip");
  std::vector<FrameRecord> records;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-3, 3);
  for (int i = 0; i < 20; ++i) {
    records.push_back(MakeRecord(i / 10, i % 10, MakePose(u(rng), u(rng), u(rng)),
                                 MakePose(u(rng), u(rng), u(rng))));
  }
  records[3].has_truth = false;
  records[4].has_estimate = false;
  RecomputeErrors(&records);
  records[5].odometry_error_m = 0.123456789012345;
  {
    std::ofstream os(dir / "frames.csv");
    WriteFramesCsvHeader(os, {"descriptor", "total"});
    for (const auto& r : records) WriteFramesCsvRow(os, r);
  }
  const FramesTable table = ReadFramesCsv(dir / "frames.csv");
  ASSERT_EQ(table.records.size(), records.size());
  EXPECT_EQ(table.stage_names, (std::vector<std::string>{"descriptor", "total"}));
  for (std::size_t i = 0; i < records.size(); ++i) {
    const FrameRecord& a = records[i];
    const FrameRecord& b = table.records[i];
    EXPECT_EQ(a.session, b.session);
    EXPECT_EQ(a.frame, b.frame);
    EXPECT_EQ(a.has_estimate, b.has_estimate);
    EXPECT_EQ(a.has_truth, b.has_truth);
    if (a.has_estimate) {
      EXPECT_EQ(a.estimate, b.estimate);
    }
    if (a.has_truth) {
      EXPECT_EQ(a.truth, b.truth);
    }
    EXPECT_EQ(std::isnan(a.position_error_m), std::isnan(b.position_error_m));
    if (!std::isnan(a.position_error_m)) {
      EXPECT_EQ(a.position_error_m, b.position_error_m);
    }
    EXPECT_EQ(a.unimodal, b.unimodal);
    EXPECT_EQ(a.stage_times_us, b.stage_times_us);
  }
  EXPECT_EQ(table.records[5].odometry_error_m, 0.123456789012345);
  fs::remove_all(dir);
}

TEST(FramesCsv, ReportsFileAndLineOfABadCell) {
  // An unparsable number names the file, the line and the column.
  const fs::path dir = TempDir("bad");
  {
    std::ofstream os(dir / "frames.csv");
    WriteFramesCsvHeader(os, {});
    WriteFramesCsvRow(os, MakeRecord(0, 0, Pose2(1, 2, 0), Pose2(1, 2, 0)));
    os << "0,1,1,0.1,abc,2,0,1,2,0,1,1,2,0,0,0,,1,1,1,1\n";
  }
  try {
    ReadFramesCsv(dir / "frames.csv");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("frames.csv:3"), std::string::npos) << what;
    EXPECT_NE(what.find("est_x_m"), std::string::npos) << what;
  }
  {
    std::ofstream os(dir / "short.csv");
    os << "session,frame\n0,1\n";
  }
  EXPECT_THROW(ReadFramesCsv(dir / "short.csv"), Error);
  fs::remove_all(dir);
}

TEST(Evaluate, PerDayStatisticsOfAHandMadeTable) {
  // Day errors equal the statistics of the hand-made offsets; the change is their difference.
  FramesTable table;
  table.stage_names = {"descriptor", "total"};
  // Day 1: estimates offset by 0.1 .. 1.0 m in x; day 2: by 0.01 .. 0.1 m in y.
  for (int i = 1; i <= 10; ++i) {
    table.records.push_back(MakeRecord(0, i, Pose2(i * 0.1, 0, 0), Pose2(0, 0, 0)));
  }
  for (int i = 1; i <= 10; ++i) {
    table.records.push_back(MakeRecord(1, i, Pose2(5, 1 + i * 0.01, 0.1), Pose2(5, 1, 0)));
  }
  RecomputeErrors(&table.records);
  const EvaluationResult result = Evaluate(table, Alignment::kNone, 10);
  ASSERT_EQ(result.days.size(), 2u);
  EXPECT_NEAR(result.days[0].position_m.mean, 0.55, 1e-12);
  EXPECT_NEAR(result.days[0].position_m.median, 0.55, 1e-12);
  EXPECT_NEAR(result.days[0].position_m.max, 1.0, 1e-12);
  EXPECT_NEAR(result.days[0].position_m.p95, 0.955, 1e-12);
  EXPECT_NEAR(result.days[1].position_m.mean, 0.055, 1e-12);
  EXPECT_NEAR(result.days[1].heading_rad.mean, 0.1, 1e-12);
  EXPECT_EQ(result.days[0].frames, 10);
  EXPECT_EQ(result.overall.frames, 20);
  EXPECT_NEAR(result.days[0].unimodal_fraction, 0.5, 1e-12);
  EXPECT_NEAR(result.days[0].mean_frame_time_us, 20 + 5.5, 1e-12);
  // Histograms hold every frame of the day.
  for (const auto& h : result.position_histograms) {
    double sum = 0;
    for (double c : h) sum += c;
    EXPECT_EQ(sum, 10);
  }
  const std::string text = FormatEvaluation(result);
  EXPECT_NE(text.find("-0.495"), std::string::npos) << text;  // day-to-day change of the mean
  const std::string html = RenderEvaluationHtml(result, table, "test");
  EXPECT_NE(html.find("<svg"), std::string::npos);
  EXPECT_NE(html.find("</html>"), std::string::npos);
}

TEST(Align, Se2RecoversARigidTransform) {
  // Estimates that are truth moved by a rigid transform (plus small noise) align back.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-5, 5);
  std::normal_distribution<double> noise(0, 0.01);
  const Pose2 t_est_truth = MakePose(1.5, -2.0, 0.7);  // estimate = T * truth
  FramesTable table;
  for (int i = 0; i < 200; ++i) {
    const Pose2 truth = MakePose(u(rng), u(rng), u(rng));
    Pose2 est = Compose(t_est_truth, truth);
    est.x() += noise(rng);
    est.y() += noise(rng);
    table.records.push_back(MakeRecord(i / 100, i % 100, est, truth));
  }
  RecomputeErrors(&table.records);
  const EvaluationResult none = Evaluate(table, Alignment::kNone);
  EXPECT_GT(none.overall.position_m.mean, 1.0);
  const EvaluationResult se2 = Evaluate(table, Alignment::kSe2);
  EXPECT_LT(se2.overall.position_m.mean, 0.03);
  EXPECT_LT(se2.overall.heading_rad.max, 1e-2);
  const Pose2 inverse = Between(t_est_truth, Pose2::Zero());
  EXPECT_NEAR(se2.alignment_transform.x(), inverse.x(), 0.01);
  EXPECT_NEAR(se2.alignment_transform.y(), inverse.y(), 0.01);
  EXPECT_NEAR(se2.alignment_transform.z(), inverse.z(), 0.01);
}

TEST(Align, StartRemovesEachSessionsInitialOffset) {
  // Per-session offsets are removed exactly when the drift-free estimates differ by one rigid
  // transform.
  FramesTable table;
  const Pose2 offsets[2] = {MakePose(1, 2, 0.3), MakePose(-3, 0.5, -1.0)};
  for (int s = 0; s < 2; ++s) {
    for (int i = 0; i < 30; ++i) {
      const Pose2 truth = MakePose(0.2 * i, std::sin(0.3 * i), 0.1 * i);
      table.records.push_back(MakeRecord(s, i, Compose(offsets[s], truth), truth));
    }
  }
  RecomputeErrors(&table.records);
  const EvaluationResult start = Evaluate(table, Alignment::kStart);
  EXPECT_LT(start.days[0].position_m.max, 1e-9);
  EXPECT_LT(start.days[1].position_m.max, 1e-9);
  EXPECT_LT(start.overall.heading_rad.max, 1e-9);
  EXPECT_THROW(AlignmentFromString("affine"), Error);
}

TEST(Evaluate, CoverageCountsFramesWithoutEstimateAndErrorsStayOverLocalizedFrames) {
  // A day with unlocalized frames: localized + unlocalized = frames, coverage = their
  // ratio, the mean error is over the localized frames only, skipped frames are separate
  // (days.csv columns and the text table).
  FramesTable table;
  table.stage_names = {"total"};
  for (int i = 0; i < 10; ++i)
    table.records.push_back(MakeRecord(0, i, Pose2(1, 0, 0), Pose2(0, 0, 0)));
  for (int i = 0; i < 10; ++i) {
    FrameRecord r = MakeRecord(1, i, Pose2(0.5, 0, 0), Pose2(0, 0, 0));
    r.has_estimate = i >= 7;  // a global start that localizes at frame 7
    r.stage_times_us = {1.0};
    table.records.push_back(r);
  }
  for (auto& r : table.records) r.stage_times_us = {1.0};
  RecomputeErrors(&table.records);
  table.skipped_frames = {{1, 4}};
  const EvaluationResult e = Evaluate(table, Alignment::kNone);
  ASSERT_EQ(e.days.size(), 2u);
  EXPECT_EQ(e.days[0].frames_with_estimate, 10);
  EXPECT_EQ(e.days[0].frames_unlocalized, 0);
  EXPECT_DOUBLE_EQ(e.days[0].coverage, 1.0);
  EXPECT_EQ(e.days[1].frames, 10);
  EXPECT_EQ(e.days[1].frames_with_estimate, 3);
  EXPECT_EQ(e.days[1].frames_unlocalized, 7);
  EXPECT_DOUBLE_EQ(e.days[1].coverage, 0.3);
  EXPECT_EQ(e.days[1].position_m.count, 3);
  EXPECT_DOUBLE_EQ(e.days[1].position_m.mean, 0.5);
  EXPECT_EQ(e.days[1].frames_skipped, 4);
  EXPECT_EQ(e.days[0].frames_skipped, 0);
  EXPECT_EQ(e.overall.frames_with_estimate + e.overall.frames_unlocalized, e.overall.frames);
  EXPECT_DOUBLE_EQ(e.overall.coverage, 13.0 / 20.0);
  EXPECT_EQ(e.overall.frames_skipped, 4);

  std::ostringstream days;
  WriteDaysCsv(days, table.records, table.stage_names, {}, {}, table.skipped_frames);
  std::istringstream in(days.str());
  std::string header, day1, day2;
  std::getline(in, header);
  std::getline(in, day1);
  std::getline(in, day2);
  // The coverage columns, then the consistency columns (empty without covariances).
  const std::string block =
      "mean_frame_time_us,frames_localized,frames_unlocalized,coverage,frames_skipped,nees_xy_"
      "frames,";
  EXPECT_NE(header.find(block), std::string::npos) << header;
  const std::string suffix = ",prior_nees_xy_median,fix_nees_xy_median";
  EXPECT_EQ(header.substr(header.size() - suffix.size()), suffix);
  EXPECT_EQ(header.rfind("session,frames,frames_with_truth,unimodal_fraction,", 0), 0u);
  EXPECT_NE(day2.find(",1,3,7,0.3,4,0,,,,,"), std::string::npos) << day2;
  EXPECT_EQ(day2.rfind("1,10,10,", 0), 0u);
  EXPECT_NE(day2.find(",0.5,"), std::string::npos);  // position_error_mean_m

  const std::string text = FormatEvaluation(e, false);
  EXPECT_NE(text.find("coverage%"), std::string::npos) << text;
  EXPECT_NE(text.find("30.0"), std::string::npos) << text;
}

TEST(RunStampClock, KeepsIncreasingStampsAndShiftsSessionsThatRestart) {
  // Stamps already increasing over sessions stay as they are; a session starting again
  // at 0 follows the previous one by one frame period; run stamps increase strictly.
  RunStampClock keep;
  EXPECT_EQ(keep.Next(0, 10.0), 10.0);
  EXPECT_EQ(keep.Next(0, 10.5), 10.5);
  EXPECT_EQ(keep.Next(1, 100.0), 100.0);
  RunStampClock shift;
  std::vector<double> out;
  for (int s = 0; s < 3; ++s) {
    for (int i = 0; i < 5; ++i) out.push_back(shift.Next(s, 0.25 * i));
  }
  for (std::size_t i = 1; i < out.size(); ++i) EXPECT_GT(out[i], out[i - 1]) << i;
  EXPECT_DOUBLE_EQ(out[5], 1.0 + 0.25);  // day 1 ends at 1.0, period 0.25
  EXPECT_DOUBLE_EQ(out[10], 2.25 + 0.25);
  RunStampClock single;  // one-frame session: a period of 1 s
  single.Next(0, 3.0);
  EXPECT_DOUBLE_EQ(single.Next(1, 0.0), 4.0);
}

TEST(WriteTum, LocalizedFramesOnlyOnSharedRunStamps) {
  // Estimate, truth and odometry files list the same stamps (run stamps), leave out frames
  // without an estimate and write a planar pose with a yaw quaternion.
  std::vector<FrameRecord> records;
  for (int i = 0; i < 4; ++i) {
    FrameRecord r = MakeRecord(0, i, Pose2(i, 1, 0.5), Pose2(i, 2, kPi / 2));
    r.run_stamp_s = 100 + i;
    r.has_odometry = true;
    r.odometry = Pose2(-i, 0, 0);
    records.push_back(r);
  }
  records[1].has_estimate = false;
  std::ostringstream est, gt, odo;
  WriteTum(est, records, TumContent::kEstimate);
  WriteTum(gt, records, TumContent::kGroundTruth);
  WriteTum(odo, records, TumContent::kOdometry);
  auto stamps = [](const std::string& text) {
    std::vector<std::string> out;
    std::istringstream in(text);
    std::string line;
    while (std::getline(in, line)) {
      if (!line.empty() && line[0] != '#') out.push_back(line.substr(0, line.find(' ')));
    }
    return out;
  };
  EXPECT_EQ(stamps(est.str()), (std::vector<std::string>{"100", "102", "103"}));
  EXPECT_EQ(stamps(gt.str()), stamps(est.str()));
  EXPECT_EQ(stamps(odo.str()), stamps(est.str()));
  EXPECT_NE(gt.str().find("\n100 0 2 0 0 0 "), std::string::npos) << gt.str();
  EXPECT_TRUE(HasTumContent(records, TumContent::kGroundTruth));
  for (auto& r : records) r.has_truth = false;
  EXPECT_FALSE(HasTumContent(records, TumContent::kGroundTruth));
}

TEST(FramesCsv, RoundTripsTheLaterColumns) {
  // run_stamp_s and the odometry pose read back; a file without them still reads.
  const fs::path dir = TempDir("later");
  FrameRecord r = MakeRecord(1, 2, Pose2(1, 2, 0.3), Pose2(1, 2, 0.3));
  r.run_stamp_s = 12345.678;
  r.stage_times_us = {10.0};
  r.has_odometry = true;
  r.odometry = Pose2(0.1, -0.2, 0.3);
  {
    std::ofstream os(dir / "frames.csv");
    WriteFramesCsvHeader(os, {"total"});
    WriteFramesCsvRow(os, r);
  }
  const FramesTable t = ReadFramesCsv(dir / "frames.csv");
  ASSERT_EQ(t.records.size(), 1u);
  EXPECT_EQ(t.stage_names, (std::vector<std::string>{"total"}));
  EXPECT_EQ(t.records[0].run_stamp_s, 12345.678);
  EXPECT_TRUE(t.records[0].has_odometry);
  EXPECT_EQ(t.records[0].odometry, r.odometry);
  EXPECT_EQ(t.records[0].stage_times_us, r.stage_times_us);
  {
    std::ofstream os(dir / "days.csv");
    os << "session,frames,frames_skipped\n0,5,0\n1,5,3\n";
  }
  FramesTable with_days = t;
  ReadSkippedFrames(dir / "days.csv", &with_days);
  EXPECT_EQ(with_days.skipped_frames, (std::map<int, std::int64_t>{{1, 3}}));
  ReadSkippedFrames(dir / "absent.csv", &with_days);
  EXPECT_TRUE(with_days.skipped_frames.empty());
  fs::remove_all(dir);
}

// The position NEES is e^T C^-1 e; it is written and read back with the covariance, is
// left empty (NaN) without a covariance or a positive-definite one, and a file from
// before these columns reads with NaN.
TEST(FramesCsv, CovarianceAndNeesRoundTrip) {
  FrameRecord r = MakeRecord(0, 1, MakePose(1.3, 2.4, 0.1), MakePose(1.0, 2.0, 0.0));
  r.cov_xx_m2 = 0.01;
  r.cov_xy_m2 = 0.006;
  r.cov_yy_m2 = 0.04;
  r.var_phi_rad2 = 0.003;
  std::vector<FrameRecord> records = {r};
  RecomputeErrors(&records);
  Eigen::Matrix2d c;
  c << 0.01, 0.006, 0.006, 0.04;
  const Eigen::Vector2d e(0.3, 0.4);
  EXPECT_NEAR(records[0].nees_xy, e.dot(c.inverse() * e), 1e-9);
  // Without the cross term: 0.09 / 0.01 + 0.16 / 0.04 = 13.
  FrameRecord diagonal = records[0];
  diagonal.cov_xy_m2 = 0.0;
  EXPECT_NEAR(PositionNees(diagonal), 13.0, 1e-9);
  FrameRecord singular = records[0];
  singular.cov_xy_m2 = 0.02;  // det = 0.0004 - 0.0004 = 0
  EXPECT_TRUE(std::isnan(PositionNees(singular)));
  FrameRecord unknown = MakeRecord(0, 2, MakePose(1, 2, 0), MakePose(1, 2, 0));
  EXPECT_TRUE(std::isnan(PositionNees(unknown)));

  const fs::path dir = TempDir("nees");
  {
    std::ofstream os(dir / "frames.csv");
    WriteFramesCsvHeader(os, {"total"});
    records[0].stage_times_us = {10.0};
    records[0].matches = 3;
    records[0].best_similarity = 0.4375;
    unknown.stage_times_us = {10.0};
    WriteFramesCsvRow(os, records[0]);
    WriteFramesCsvRow(os, unknown);
  }
  const FramesTable table = ReadFramesCsv(dir / "frames.csv");
  ASSERT_EQ(table.records.size(), 2u);
  EXPECT_EQ(table.records[0].cov_xx_m2, 0.01);
  EXPECT_EQ(table.records[0].cov_xy_m2, 0.006);
  EXPECT_EQ(table.records[0].cov_yy_m2, 0.04);
  EXPECT_EQ(table.records[0].var_phi_rad2, 0.003);
  EXPECT_EQ(table.records[0].nees_xy, records[0].nees_xy);
  EXPECT_TRUE(std::isnan(table.records[1].cov_xx_m2));
  EXPECT_TRUE(std::isnan(table.records[1].nees_xy));
  EXPECT_EQ(table.records[0].matches, 3);
  EXPECT_EQ(table.records[0].best_similarity, 0.4375);
  EXPECT_EQ(table.records[1].matches, -1);  // unknown stays unknown
  EXPECT_TRUE(std::isnan(table.records[1].best_similarity));
  const EvaluationResult result = Evaluate(table, Alignment::kNone);
  EXPECT_EQ(result.overall.nees_xy.count, 1);
  EXPECT_NEAR(result.overall.nees_xy.mean, records[0].nees_xy, 1e-9);
  EXPECT_NE(FormatEvaluation(result, false).find("position NEES"), std::string::npos);
  // The header and the first row of the file written above.
  auto header_and_row = [&dir] {
    std::ifstream in(dir / "frames.csv");
    std::pair<std::string, std::string> lines;
    std::getline(in, lines.first);
    std::getline(in, lines.second);
    return lines;
  };
  {
    // Written before the covariance columns: the header stops at odom_phi_rad.
    const auto [header, row] = header_and_row();
    const std::size_t cut = header.find(",cov_xx_m2");
    ASSERT_NE(cut, std::string::npos);
    std::size_t cells = 0;
    for (char ch : header.substr(0, cut)) cells += ch == ',';
    std::size_t pos = 0;
    for (std::size_t k = 0; k <= cells; ++k) pos = row.find(',', pos) + 1;
    std::ofstream os(dir / "old.csv");
    os << header.substr(0, cut) << "\n" << row.substr(0, pos - 1) << "\n";
  }
  const FramesTable old = ReadFramesCsv(dir / "old.csv");
  ASSERT_EQ(old.records.size(), 1u);
  EXPECT_TRUE(std::isnan(old.records[0].cov_xx_m2));
  EXPECT_TRUE(std::isnan(old.records[0].nees_xy));
  EXPECT_EQ(old.records[0].matches, -1);
  EXPECT_TRUE(std::isnan(old.records[0].best_similarity));
  EXPECT_EQ(old.records[0].estimate, records[0].estimate);
  {
    // A match count that is not a count is named with its file, line and column.
    const auto [header, row] = header_and_row();
    const std::size_t cut = row.rfind(",3,");
    ASSERT_NE(cut, std::string::npos);
    std::ofstream os(dir / "bad.csv");
    os << header << "\n" << row.substr(0, cut) << ",2.5," << row.substr(cut + 3) << "\n";
  }
  try {
    ReadFramesCsv(dir / "bad.csv");
    ADD_FAILURE() << "a fractional match count was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("bad.csv:2: column 'matches'"), std::string::npos)
        << e.what();
  }
  fs::remove_all(dir);
}

// Aligning turns the covariance with the estimate: a trajectory moved by a rigid T with
// covariances turned by T's rotation gets, aligned back, the covariance it had in the
// truth's frame, and the NEES is taken with it.
TEST(Align, Se2TurnsTheCovarianceWithTheEstimate) {
  const Pose2 t_est_truth = MakePose(2.0, -1.0, 1.1);  // estimate frame = T * truth frame
  FramesTable table;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-4, 4);
  const Eigen::Matrix2d c_truth = (Eigen::Matrix2d() << 0.09, 0.02, 0.02, 0.01).finished();
  const Eigen::Matrix2d rot = Eigen::Rotation2Dd(t_est_truth.z()).toRotationMatrix();
  const Eigen::Matrix2d c_est = rot * c_truth * rot.transpose();
  for (int i = 0; i < 50; ++i) {
    const Pose2 truth = MakePose(u(rng), u(rng), u(rng));
    // An error of 0.2 m along x of the truth frame, then everything moved by T.
    Pose2 off = truth;
    off.x() += 0.2;
    FrameRecord r = MakeRecord(0, i, Compose(t_est_truth, off), truth);
    r.cov_xx_m2 = c_est(0, 0);
    r.cov_xy_m2 = c_est(0, 1);
    r.cov_yy_m2 = c_est(1, 1);
    table.records.push_back(r);
  }
  const EvaluationResult se2 = Evaluate(table, Alignment::kSe2);
  std::vector<FrameRecord> aligned = table.records;
  Align(&aligned, Alignment::kSe2);
  for (std::size_t i = 0; i < aligned.size(); ++i) {
    Eigen::Matrix2d c;
    c << aligned[i].cov_xx_m2, aligned[i].cov_xy_m2, aligned[i].cov_xy_m2, aligned[i].cov_yy_m2;
    EXPECT_TRUE(c.isApprox(c_truth, 1e-6)) << c;
    const Eigen::Vector2d e = aligned[i].estimate.head<2>() - aligned[i].truth.head<2>();
    EXPECT_NEAR(aligned[i].nees_xy, e.dot(c_truth.inverse() * e), 1e-6);
  }
  EXPECT_EQ(se2.overall.nees_xy.count, 50);
}

// The prior's and the fix's NEES compare means the records do not hold with the truth,
// so an alignment that moves the estimate cannot move them: the aligned evaluation
// leaves them out (and says so) instead of reporting them in the unaligned frame.
TEST(Align, PriorAndFixNeesAreLeftOutUnderAlignment) {
  FramesTable table;
  for (int i = 0; i < 20; ++i) {
    const Pose2 truth = MakePose(0.5 * i, 0.1 * i, 0.0);
    Pose2 est = truth;
    est.y() += 0.3;
    FrameRecord r = MakeRecord(0, i, est, truth);
    r.cov_xx_m2 = r.cov_yy_m2 = 0.04;
    r.cov_xy_m2 = 0.0;
    r.prior_nees_xy = 2.5;
    r.fix_nees_xy = 0.5;
    table.records.push_back(r);
  }
  const EvaluationResult none = Evaluate(table, Alignment::kNone);
  EXPECT_EQ(none.overall.prior_nees_xy.count, 20);
  EXPECT_NEAR(none.overall.fix_nees_xy.median, 0.5, 1e-12);
  EXPECT_EQ(FormatEvaluation(none).find("not reported under alignment"), std::string::npos);
  for (const Alignment a : {Alignment::kSe2, Alignment::kStart}) {
    const EvaluationResult aligned = Evaluate(table, a);
    EXPECT_EQ(aligned.overall.prior_nees_xy.count, 0) << ToString(a);
    EXPECT_EQ(aligned.overall.fix_nees_xy.count, 0) << ToString(a);
    // The position NEES is recomputed against the aligned truth: the 0.3 m offset is gone.
    EXPECT_LT(aligned.overall.nees_xy.median, 1e-6) << ToString(a);
    EXPECT_NE(FormatEvaluation(aligned).find("not reported under alignment"), std::string::npos)
        << ToString(a);
  }
}

// A straight 10 m run along x, one frame per metre.
std::vector<FrameRecord> StraightRun(double est_scale, double est_heading_rate_rad_per_m) {
  std::vector<FrameRecord> records;
  for (int i = 0; i <= 10; ++i) {
    records.push_back(MakeRecord(0, i, MakePose(est_scale * i, 0, est_heading_rate_rad_per_m * i),
                                 MakePose(i, 0, 0)));
  }
  RecomputeErrors(&records);
  return records;
}

TEST(TrajectoryMetrics, ApeRmseAndRpeOfAScaledRunByHand) {
  // est x = 1.1 truth x: APE e_i = 0.1 i, RMSE = 0.1 sqrt(mean(i^2), i = 0..10) =
  // 0.1 sqrt(35); RPE over 2 m: pairs (2,4) (4,6) (6,8) (8,10), each 0.2 m too long.
  TrajectoryMetricsOptions options;
  options.rpe_delta_m = 2.0;
  const TrajectoryMetrics m = ComputeTrajectoryMetrics(StraightRun(1.1, 0), options);
  EXPECT_EQ(m.frames_evaluated, 11);
  EXPECT_NEAR(m.ape_m.rmse, 0.1 * std::sqrt(35.0), 1e-12);
  EXPECT_NEAR(m.ape_m.mean, 0.5, 1e-12);
  EXPECT_NEAR(m.ape_m.max, 1.0, 1e-12);
  EXPECT_NEAR(m.ape_m.std, 0.1 * std::sqrt(10.0), 1e-12);  // population std of 0..10 = sqrt(10)
  EXPECT_EQ(m.rpe_pairs, 4);
  EXPECT_NEAR(m.rpe_translation_m.rmse, 0.2, 1e-12);
  EXPECT_NEAR(m.rpe_rotation_deg.max, 0.0, 1e-12);
  EXPECT_NEAR(m.drift_percent, 10.0, 1e-9);
}

TEST(TrajectoryMetrics, RpeRotationOfAHeadingDriftByHand) {
  // The heading drifts by 0.01 rad per metre: every 2 m pair turns 0.02 rad too far.
  TrajectoryMetricsOptions options;
  options.rpe_delta_m = 2.0;
  const TrajectoryMetrics m = ComputeTrajectoryMetrics(StraightRun(1.0, 0.01), options);
  EXPECT_EQ(m.rpe_pairs, 4);
  EXPECT_NEAR(m.rpe_rotation_deg.rmse, 0.02 * 180 / kPi, 1e-9);
  EXPECT_NEAR(m.rotation_drift_deg_per_m, 0.01 * 180 / kPi, 1e-9);
  EXPECT_NEAR(m.ape_m.max, 0.0, 1e-12);
  EXPECT_NEAR(m.ape_heading_deg.max, 0.1 * 180 / kPi, 1e-9);
}

TEST(TrajectoryMetrics, RpePairsStayWithinASessionAndCountUnlocalizedFrames) {
  // Two sessions of a straight run; pairs never join them; frames without an estimate
  // are counted in frames but not evaluated.
  std::vector<FrameRecord> records = StraightRun(1.1, 0);
  std::vector<FrameRecord> day2 = StraightRun(1.1, 0);
  for (FrameRecord& r : day2) r.session = 1, r.global_frame += 11;
  day2[5].has_estimate = false;
  records.insert(records.end(), day2.begin(), day2.end());
  RecomputeErrors(&records);
  TrajectoryMetricsOptions options;
  options.rpe_delta_m = 2.0;
  const TrajectoryMetrics m = ComputeTrajectoryMetrics(records, options);
  EXPECT_EQ(m.frames, 22);
  EXPECT_EQ(m.frames_evaluated, 21);
  // Day 1: 4 pairs; day 2 without frame 5: path 2 at 2, 4 at 4, (5 missing) 6, 8, 10 -> 4.
  EXPECT_EQ(m.rpe_pairs, 8);
  EXPECT_NEAR(m.rpe_translation_m.rmse, 0.2, 1e-12);
  EXPECT_EQ(ComputeTrajectoryMetrics(records, options, 1).rpe_pairs, 4);
}

TEST(AssociateGroundTruth, NearestStampWithinTheToleranceElseNone) {
  // Reference stamps 4 ms after the frames: associated within 10 ms, not within 3 ms;
  // frames left without ground truth stay counted.
  std::vector<FrameRecord> records = StraightRun(1.0, 0);
  std::vector<TimedPose> reference;
  for (const FrameRecord& r : records) reference.push_back({r.stamp_s + 0.004, r.truth});
  std::reverse(reference.begin(), reference.end());  // need not be sorted
  std::vector<FrameRecord> a = records;
  EXPECT_EQ(AssociateGroundTruth(&a, reference, 0.01), 11);
  EXPECT_NEAR(a[3].truth.x(), 3.0, 1e-12);
  EXPECT_NEAR(a[3].position_error_m, 0.0, 1e-12);
  std::vector<FrameRecord> b = records;
  EXPECT_EQ(AssociateGroundTruth(&b, reference, 0.003), 0);
  EXPECT_FALSE(b[3].has_truth);
  EXPECT_TRUE(std::isnan(b[3].position_error_m));
  EXPECT_THROW(AssociateGroundTruth(&b, reference, -1), Error);
}
// Heading NEES is WrapAngle(est - truth)^2 / var_phi (hand values, across +-pi), and NaN
// without a positive variance; NIS and the stage NEES round-trip through frames.csv.
TEST(Consistency, HeadingNeesAndNewColumnsRoundTrip) {
  FrameRecord r = MakeRecord(0, 1, MakePose(1.0, 2.0, 0.3), MakePose(1.0, 2.0, 0.1));
  r.cov_xx_m2 = 0.04;
  r.cov_xy_m2 = 0.0;
  r.cov_yy_m2 = 0.01;
  r.var_phi_rad2 = 0.01;
  ComputeErrors(&r);
  EXPECT_NEAR(r.nees_phi, 0.04 / 0.01, 1e-12);  // (0.3 - 0.1)^2 / 0.01
  EXPECT_NEAR(r.nees_xy, 0.0, 1e-12);
  FrameRecord wrap = MakeRecord(0, 2, MakePose(0, 0, 3.1), MakePose(0, 0, -3.1));
  wrap.var_phi_rad2 = 0.0004;
  ComputeErrors(&wrap);
  const double e = 2 * kPi - 6.2;  // the wrapped difference, 0.0832 rad
  EXPECT_NEAR(wrap.nees_phi, e * e / 0.0004, 1e-9);
  FrameRecord no_variance = wrap;
  no_variance.var_phi_rad2 = 0.0;
  EXPECT_TRUE(std::isnan(HeadingNees(no_variance)));
  // Position NEES by hand: e = (0.1, -0.2), C = [0.02 0.01; 0.01 0.05], det 0.0009:
  // (0.05 * 0.01 - 2 * 0.01 * 0.1 * -0.2 + 0.02 * 0.04) / 0.0009 = 0.0017 / 0.0009.
  EXPECT_NEAR(PositionNees(0.1, -0.2, 0.02, 0.01, 0.05), 0.0017 / 0.0009, 1e-12);
  EXPECT_TRUE(std::isnan(PositionNees(kNaN, 0.0, 1.0, 0.0, 1.0)));

  r.nis = 2.5;
  r.prior_nees_xy = 0.125;
  r.fix_nees_xy = 3.75;
  const fs::path dir = TempDir("consistency");
  {
    std::ofstream os(dir / "frames.csv");
    WriteFramesCsvHeader(os, {"a", "b"});
    WriteFramesCsvRow(os, r);
    WriteFramesCsvRow(os, wrap);
  }
  const FramesTable table = ReadFramesCsv(dir / "frames.csv");
  ASSERT_EQ(table.records.size(), 2u);
  EXPECT_EQ(table.records[0].nees_phi, r.nees_phi);
  EXPECT_EQ(table.records[0].nis, 2.5);
  EXPECT_EQ(table.records[0].prior_nees_xy, 0.125);
  EXPECT_EQ(table.records[0].fix_nees_xy, 3.75);
  EXPECT_TRUE(std::isnan(table.records[1].nis));
  fs::remove_all(dir);
}

// The fraction inside the two-sided 95 % band counts exactly the values within
// [q(0.025), q(0.975)] (2 dof: [0.0506, 7.378]) among the finite ones.
TEST(Consistency, FractionInBandCountsFiniteValues) {
  EXPECT_DOUBLE_EQ(FractionInChiSquareBand({0.01, 0.06, 1.0, 7.0, 7.5, kNaN}, 2), 3.0 / 5.0);
  EXPECT_DOUBLE_EQ(FractionInChiSquareBand({0.0005, 0.002, 5.0, 5.1}, 1), 2.0 / 4.0);
  EXPECT_TRUE(std::isnan(FractionInChiSquareBand({kNaN}, 2)));
}

// A consistent Gaussian estimator (errors drawn from the covariance it reports, random
// correlated covariances) gives position NEES mean ~2, median ~1.39, p95 ~5.99 and 95 %
// in band, heading NEES mean ~1, median ~0.45; an estimator reporting 3x the standard
// deviation gives a mean of ~2/9. Through days.csv as well.
TEST(Consistency, ConsistentGaussianEstimatorAveragesTheDegreesOfFreedom) {
  std::mt19937 rng(11);
  std::normal_distribution<double> n(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.05, 0.8);
  std::vector<FrameRecord> consistent, wide;
  const int kFrames = 20000;
  for (int i = 0; i < kFrames; ++i) {
    const double sx = u(rng), sy = u(rng), rho = 0.9 * (2 * u(rng) - 0.85), sphi = 0.2 * u(rng);
    Eigen::Matrix2d c;
    c << sx * sx, rho * sx * sy, rho * sx * sy, sy * sy;
    const Eigen::Matrix2d l = c.llt().matrixL();
    const Eigen::Vector2d e = l * Eigen::Vector2d(n(rng), n(rng));
    const Pose2 truth = MakePose(5 * u(rng), 5 * u(rng), 3 * (u(rng) - 0.4));
    FrameRecord r = MakeRecord(
        2 * i / kFrames, i,
        MakePose(truth.x() + e.x(), truth.y() + e.y(), truth.z() + sphi * n(rng)), truth);
    r.cov_xx_m2 = c(0, 0);
    r.cov_xy_m2 = c(0, 1);
    r.cov_yy_m2 = c(1, 1);
    r.var_phi_rad2 = sphi * sphi;
    ComputeErrors(&r);
    consistent.push_back(r);
    r.cov_xx_m2 *= 9;
    r.cov_xy_m2 *= 9;
    r.cov_yy_m2 *= 9;
    r.var_phi_rad2 *= 9;
    ComputeErrors(&r);
    wide.push_back(r);
  }
  const DayEvaluation d = EvaluateDay(consistent, -1, {});
  EXPECT_EQ(d.nees_xy.count, kFrames);
  EXPECT_NEAR(d.nees_xy.mean, 2.0, 0.06);
  EXPECT_NEAR(d.nees_xy.median, 1.386, 0.05);
  EXPECT_NEAR(d.nees_xy.p95, 5.99, 0.25);
  EXPECT_NEAR(d.nees_xy_in_band, 0.95, 0.01);
  EXPECT_NEAR(d.nees_phi.mean, 1.0, 0.04);
  EXPECT_NEAR(d.nees_phi.median, 0.455, 0.03);
  EXPECT_NEAR(d.nees_phi_in_band, 0.95, 0.01);
  const DayEvaluation w = EvaluateDay(wide, -1, {});
  EXPECT_NEAR(w.nees_xy.mean, 2.0 / 9, 0.01);
  // Inside the band iff chi2 / 9 >= 0.0506, i.e. with probability exp(-9 x 0.0506 / 2).
  EXPECT_NEAR(w.nees_xy_in_band, std::exp(-4.5 * ChiSquareTwoSidedBand(0.95, 2).lower), 0.01);

  std::ostringstream days;
  WriteDaysCsv(days, consistent, {});
  std::istringstream in(days.str());
  std::string header, row;
  std::getline(in, header);
  std::getline(in, row);
  const auto cell = [&](const std::string& name) {
    std::vector<std::string> names, cells;
    std::stringstream hs(header), rs(row);
    std::string item;
    while (std::getline(hs, item, ',')) names.push_back(item);
    while (std::getline(rs, item, ',')) cells.push_back(item);
    const auto it = std::find(names.begin(), names.end(), name);
    EXPECT_NE(it, names.end()) << name;
    return it == names.end() ? kNaN : std::stod(cells.at(it - names.begin()));
  };
  const DayEvaluation day0 = EvaluateDay(consistent, 0, {});
  EXPECT_EQ(cell("nees_xy_frames"), day0.nees_xy.count);
  EXPECT_DOUBLE_EQ(cell("nees_xy_median"), day0.nees_xy.median);
  EXPECT_DOUBLE_EQ(cell("nees_xy_in_band"), day0.nees_xy_in_band);
  EXPECT_DOUBLE_EQ(cell("nees_phi_p95"), day0.nees_phi.p95);
  EXPECT_EQ(cell("nis_frames"), 0);
}

}  // namespace
}  // namespace omnicml
