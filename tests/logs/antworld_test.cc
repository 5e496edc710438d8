// Tests of the AntWorld reader and importer on the shared data: the heading and image
// conventions (measured on the images), odometry noise, the import into a log.
#include "omnicml/logs/antworld.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"
#include "omnicml/logs/log_format.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;

const std::string kData = OMNICML_SOURCE_DIR "/../shared/datasets/antworld";
const std::string kRouteCsv = kData + "/ant1_route1/ant1_route1.csv";
const std::string kGridCsv = kData + "/grid_200mm/grid_200mm.csv";

#define SKIP_WITHOUT_ANTWORLD()                                                            \
  if (!fs::exists(kRouteCsv) || !fs::exists(kGridCsv)) {                                   \
    GTEST_SKIP() << "AntWorld data not found at " << kData << " (see ../shared/datasets)"; \
  }

// Grey image, float, each row's mean removed.
cv::Mat ZeroMeanRows(const cv::Mat& bgr) {
  cv::Mat grey;
  cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
  grey.convertTo(grey, CV_64F);
  for (int r = 0; r < grey.rows; ++r) grey.row(r) -= cv::mean(grey.row(r))[0];
  return grey;
}

// The column roll k (0..W-1) maximising sum_{r,c} after[r][c] before[r][(c + k) mod W],
// i.e. after ~ before rolled so that after[c] = before[c + k] (omni_unwrapper.h), from
// the row-wise circular cross-correlation summed over rows (cv::dft).
int MeasureRoll(const cv::Mat& after_bgr, const cv::Mat& before_bgr) {
  const cv::Mat a = ZeroMeanRows(after_bgr), b = ZeroMeanRows(before_bgr);
  cv::Mat fa, fb, cross, sum, corr;
  cv::dft(a, fa, cv::DFT_ROWS | cv::DFT_COMPLEX_OUTPUT);
  cv::dft(b, fb, cv::DFT_ROWS | cv::DFT_COMPLEX_OUTPUT);
  cv::mulSpectrums(fb, fa, cross, cv::DFT_ROWS, /*conjB=*/true);  // B conj(A)
  cv::reduce(cross, sum, 0, cv::REDUCE_SUM);
  cv::idft(sum, corr, cv::DFT_REAL_OUTPUT);
  cv::Point best;
  cv::minMaxLoc(corr, nullptr, nullptr, nullptr, &best);
  return best.x;
}

// Angle in degrees of a column offset, wrapped to (-180, 180].
double ColumnsToDegrees(double columns, int width) {
  return WrapAngle(columns * kTwoPi / width) * 180.0 / kPi;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

TEST(AntWorldConversion, PanoramaPermutationIsOurConvention) {
  // out[c] = in[(W/2 - c) mod W]: the AntWorld centre column becomes column 0 and the
  // column order is reversed.
  cv::Mat in(2, 8, CV_8UC1);
  for (int r = 0; r < 2; ++r) {
    for (int c = 0; c < 8; ++c) in.at<unsigned char>(r, c) = static_cast<unsigned char>(10 * r + c);
  }
  const cv::Mat out = AntWorldToOurPanorama(in);
  for (int r = 0; r < 2; ++r) {
    for (int c = 0; c < 8; ++c)
      EXPECT_EQ(out.at<unsigned char>(r, c), in.at<unsigned char>(r, (4 - c + 8) % 8));
  }
  EXPECT_NEAR(AntWorldHeadingToPhi(0.0), kPi / 2, 1e-15);  // compass north = +y
  EXPECT_NEAR(AntWorldHeadingToPhi(90.0), 0.0, 1e-15);     // compass east = +x
  EXPECT_NEAR(AntWorldHeadingToPhi(219.96), (90.0 - 219.96) * kPi / 180.0, 1e-12);
}

TEST(AntWorldReader, HeadingIsTheDirectionOfTravel) {
  // The converted heading phi points along the route's direction of travel (the file's
  // heading is a compass angle): circular mean of the difference near 0, tight spread.
  SKIP_WITHOUT_ANTWORLD();
  const std::vector<AntWorldRow> rows = ReadAntWorldCsv(kRouteCsv);
  ASSERT_GT(rows.size(), 100u);
  double c = 0, s = 0;
  int n = 0;
  for (std::size_t i = 10; i < rows.size(); ++i) {
    const Eigen::Vector3d d = rows[i].map_T_robot - rows[i - 10].map_T_robot;
    if (std::hypot(d.x(), d.y()) < 0.03) continue;
    const double diff = std::atan2(d.y(), d.x()) - rows[i - 5].map_T_robot.z();
    c += std::cos(diff);
    s += std::sin(diff);
    ++n;
  }
  ASSERT_GT(n, 100);
  EXPECT_LT(std::abs(std::atan2(s, c)), 2.0 * kPi / 180.0);
  EXPECT_GT(std::hypot(c, s) / n, 0.99);  // resultant length: nearly all agree
}

TEST(AntWorldReader, ConvertedFramesFollowOurPanoramaConvention) {
  // For route frames, the measured roll between the converted frame and the converted
  // nearest grid view equals the converted heading difference in columns, as our
  // convention requires (after[c] = before[c + k], k = dphi / (2 pi / W)).
  SKIP_WITHOUT_ANTWORLD();
  AntWorldOptions options;
  options.stride = 8;
  AntWorldReader route(kRouteCsv, options);
  const std::vector<AntWorldRow> grid = ReadAntWorldCsv(kGridCsv);
  std::vector<double> errors_deg, flipped_errors_deg;
  Frame frame;
  while (route.Next(&frame)) {
    ASSERT_EQ(frame.image.type(), CV_8UC3);
    const Pose2& truth = *frame.map_T_robot_truth;
    const auto nearest =
        std::min_element(grid.begin(), grid.end(), [&](const AntWorldRow& a, const AntWorldRow& b) {
          return (a.map_T_robot.head<2>() - truth.head<2>()).norm() <
                 (b.map_T_robot.head<2>() - truth.head<2>()).norm();
        });
    const cv::Mat grid_view = AntWorldToOurPanorama(ReadImage(nearest->image_path));
    const int width = frame.image.cols;
    const double measured_deg = ColumnsToDegrees(MeasureRoll(frame.image, grid_view), width);
    const double expected_deg = WrapAngle(truth.z() - nearest->map_T_robot.z()) * 180.0 / kPi;
    errors_deg.push_back(std::abs(WrapAngle((measured_deg - expected_deg) * kPi / 180.0)) * 180.0 /
                         kPi);
    flipped_errors_deg.push_back(std::abs(WrapAngle((measured_deg + expected_deg) * kPi / 180.0)) *
                                 180.0 / kPi);
  }
  ASSERT_GE(errors_deg.size(), 100u);
  const double within_15 =
      std::count_if(errors_deg.begin(), errors_deg.end(), [](double e) { return e <= 15.0; }) /
      static_cast<double>(errors_deg.size());
  // Measured: median 2.8 deg, 87 % within 15 deg (grass parallax up to 140 mm from the
  // grid view spoils the rest). The opposite sign gives a median of about 32 deg.
  std::cout << "roll vs heading: " << errors_deg.size() << " frames, median error "
            << Median(errors_deg) << " deg, within 15 deg " << within_15
            << ", opposite sign median " << Median(flipped_errors_deg) << " deg\n";
  EXPECT_LT(Median(errors_deg), 5.0);
  EXPECT_GT(within_15, 0.8);
  EXPECT_GT(Median(flipped_errors_deg), 20.0);
}

TEST(AntWorldReader, GridOpticalFlowPutsForwardAtColumnZero) {
  // Independent of the file's heading: between two neighbouring grid views (both phi =
  // 90 deg, facing world +y) scene points flow away from the focus of expansion, which
  // must appear at the robot azimuth of the step's direction: -90 deg for a step along
  // world +x, 0 deg (column 0) for a step along +y.
  SKIP_WITHOUT_ANTWORLD();
  const std::vector<AntWorldRow> grid = ReadAntWorldCsv(kGridCsv);
  std::map<std::pair<long, long>, std::size_t> by_mm;
  for (std::size_t i = 0; i < grid.size(); ++i) {
    EXPECT_NEAR(grid[i].map_T_robot.z(), kPi / 2, 1e-12);
    by_mm[{std::lround(grid[i].map_T_robot.x() * 1000),
           std::lround(grid[i].map_T_robot.y() * 1000)}] = i;
  }
  constexpr int kWindow = 30, kMaxShift = 12, kRow0 = 40, kRow1 = 110;
  for (const int axis : {0, 1}) {
    double sin_sum = 0, cos_sum = 0;
    int pairs = 0;
    for (std::size_t i = 0; i < grid.size() && pairs < 40; i += 7) {
      const long x = std::lround(grid[i].map_T_robot.x() * 1000) + (axis == 0 ? 200 : 0);
      const long y = std::lround(grid[i].map_T_robot.y() * 1000) + (axis == 1 ? 200 : 0);
      const auto next = by_mm.find({x, y});
      if (next == by_mm.end()) continue;
      cv::Mat a = ZeroMeanRows(AntWorldToOurPanorama(ReadImage(grid[i].image_path)));
      cv::Mat b = ZeroMeanRows(AntWorldToOurPanorama(ReadImage(grid[next->second].image_path)));
      const int width = a.cols;
      // Per window of columns, the shift s that best maps a's window onto b (a[c] ~ b[c + s]).
      for (int c0 = 0; c0 < width; c0 += kWindow) {
        double best = -1e300;
        int best_shift = 0;
        for (int shift = -kMaxShift; shift <= kMaxShift; ++shift) {
          cv::Mat wa = a(cv::Range(kRow0, kRow1), cv::Range(c0, c0 + kWindow)).clone();
          cv::Mat wb(wa.size(), CV_64F);
          for (int c = 0; c < kWindow; ++c) {
            b(cv::Range(kRow0, kRow1), cv::Range::all())
                .col(((c0 + c + shift) % width + width) % width)
                .copyTo(wb.col(c));
          }
          wa -= cv::mean(wa)[0];
          wb -= cv::mean(wb)[0];
          const double score = wa.dot(wb) / std::sqrt(wa.dot(wa) * wb.dot(wb) + 1e-9);
          if (score > best) {
            best = score;
            best_shift = shift;
          }
        }
        // Flow away from the focus f: s ~ K sin(alpha - f) with K > 0.
        const double alpha = kTwoPi * (c0 + kWindow / 2.0) / width;
        sin_sum += best_shift * std::sin(alpha);
        cos_sum += best_shift * std::cos(alpha);
      }
      ++pairs;
    }
    ASSERT_GE(pairs, 10);
    // Measured on 40 pairs: -87.7 deg (step along +x) and 1.2 deg (along +y); without the
    // reflection +91.5 and 0.0, i.e. the +x step on the wrong side.
    const double focus_deg = std::atan2(-cos_sum, sin_sum) * 180.0 / kPi;
    const double expected_deg = axis == 0 ? -90.0 : 0.0;
    std::cout << "focus of expansion, step along " << (axis == 0 ? "+x" : "+y") << ": " << focus_deg
              << " deg (expected " << expected_deg << ")\n";
    EXPECT_NEAR(WrapAngle((focus_deg - expected_deg) * kPi / 180.0) * 180.0 / kPi, 0.0, 10.0)
        << "axis " << axis;
  }
}

TEST(AntWorldReader, PosesAndOdometry) {
  // Ground truth comes from the file in metres and radians; without noise the odometry
  // equals the ground truth; with noise it is seeded and drifts.
  SKIP_WITHOUT_ANTWORLD();
  AntWorldOptions exact;
  exact.odometry_noise = MotionNoise{.a1 = 0, .a2 = 0, .a3 = 0, .a4 = 0};
  exact.stride = 3;
  AntWorldReader reader(kRouteCsv, exact);
  const std::vector<AntWorldRow> rows = ReadAntWorldCsv(kRouteCsv);
  EXPECT_EQ(reader.NumFrames(), static_cast<std::int64_t>((rows.size() + 2) / 3));
  EXPECT_NEAR(rows[0].map_T_robot.x(), 6.3, 1e-12);
  EXPECT_NEAR(rows[0].map_T_robot.y(), 8.45, 1e-12);
  EXPECT_EQ(reader.Session(0).camera.image_width, 720);
  EXPECT_EQ(reader.Session(0).camera.image_height, 150);
  EXPECT_EQ(reader.Session(0).start.mode, SessionStartMode::kKnownPose);
  EXPECT_EQ(reader.Session(0).start.map_T_robot, rows[0].map_T_robot);
  Frame frame;
  std::int64_t n = 0;
  double last_stamp = -1;
  while (reader.Next(&frame)) {
    ASSERT_TRUE(frame.map_T_robot_truth.has_value());
    EXPECT_EQ(*frame.map_T_robot_truth, rows[n * 3].map_T_robot);
    EXPECT_LT(PoseDifference(frame.odom_T_robot, *frame.map_T_robot_truth).norm(), 1e-9);
    EXPECT_GT(frame.stamp_s, last_stamp);
    last_stamp = frame.stamp_s;
    ++n;
  }
  EXPECT_EQ(n, reader.NumFrames());

  AntWorldOptions noisy;
  noisy.odometry_noise = MotionNoise{.a1 = 0.05, .a2 = 0.01, .a3 = 0.05, .a4 = 0.01};
  noisy.stride = 20;
  const auto odometry = [&](std::uint64_t seed) {
    noisy.seed = seed;
    AntWorldReader r(kRouteCsv, noisy);
    std::vector<Pose2> out;
    Frame f;
    while (r.Next(&f)) out.push_back(f.odom_T_robot);
    return out;
  };
  const std::vector<Pose2> a = odometry(7), b = odometry(7), c = odometry(8);
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i], b[i]);
  EXPECT_GT(PoseDifference(a.back(), c.back()).head<2>().norm(), 1e-4);
}

TEST(AntWorldOdometry, SampledNoiseMatchesTheModel) {
  // The perturbations of rot1, trans, rot2 are zero-mean with the variances
  // a1 rot1^2 + a2 trans^2, a3 trans^2 + a4 (rot1^2 + rot2^2), a1 rot2^2 + a2 trans^2.
  const MotionNoise noise{.a1 = 0.02, .a2 = 0.05, .a3 = 0.03, .a4 = 0.2};
  std::mt19937 pick(3);
  std::uniform_real_distribution<double> rot(-1.0, 1.0), trans(0.0, 0.5);
  std::mt19937_64 rng(11);
  constexpr int kSamples = 20000;
  double sum[3] = {0, 0, 0}, sum_sq[3] = {0, 0, 0};
  for (int i = 0; i < kSamples; ++i) {
    const OdometryIncrement u{rot(pick), trans(pick), rot(pick)};
    const OdometryIncrement v = SampleOdometryIncrement(u, noise, rng);
    const double r1 = u.rot1_rad * u.rot1_rad, r2 = u.rot2_rad * u.rot2_rad,
                 t = u.trans_m * u.trans_m;
    const double z[3] = {(v.rot1_rad - u.rot1_rad) / std::sqrt(noise.a1 * r1 + noise.a2 * t),
                         (v.trans_m - u.trans_m) / std::sqrt(noise.a3 * t + noise.a4 * (r1 + r2)),
                         (v.rot2_rad - u.rot2_rad) / std::sqrt(noise.a1 * r2 + noise.a2 * t)};
    for (int k = 0; k < 3; ++k) {
      sum[k] += z[k];
      sum_sq[k] += z[k] * z[k];
    }
  }
  for (int k = 0; k < 3; ++k) {
    // Standard errors: mean 1/sqrt(n) = 0.007, variance sqrt(2/n) = 0.01.
    EXPECT_NEAR(sum[k] / kSamples, 0.0, 0.03) << k;
    EXPECT_NEAR(sum_sq[k] / kSamples, 1.0, 0.05) << k;
  }
}

TEST(AntWorldImport, ImportedLogReadsBackAsTheReaderDelivers) {
  // ImportAntWorld writes a valid one-session log whose frames equal what AntWorldReader
  // delivers (bit-identical poses and stamps, identical converted images).
  SKIP_WITHOUT_ANTWORLD();
  const fs::path out = fs::path(::testing::TempDir()) / StrCat("omnicml_antworld_", ::getpid());
  fs::remove_all(out);
  AntWorldOptions options;
  options.stride = 40;
  options.seed = 5;
  const std::int64_t written = ImportAntWorld(kRouteCsv, out.string(), options);
  EXPECT_EQ(ValidateLog(out.string()).total_frames, written);
  AntWorldReader direct(kRouteCsv, options);
  LogReader log(out.string());
  ASSERT_EQ(log.NumSessions(), 1);
  EXPECT_EQ(log.Session(0).name, "ant1_route1");
  Frame a, b;
  std::int64_t n = 0;
  while (direct.Next(&a)) {
    ASSERT_TRUE(log.Next(&b));
    EXPECT_EQ(a.stamp_s, b.stamp_s);
    EXPECT_EQ(a.odom_T_robot, b.odom_T_robot);
    EXPECT_EQ(*a.map_T_robot_truth, *b.map_T_robot_truth);
    EXPECT_EQ(cv::norm(a.image, b.image, cv::NORM_INF), 0.0);
    ++n;
  }
  EXPECT_FALSE(log.Next(&b));
  EXPECT_EQ(n, written);
  EXPECT_THROW(ImportAntWorld(kRouteCsv, out.string(), options), Error);  // exists
  fs::remove_all(out);
}

TEST(AntWorldReader, BadCsvNamesFileAndLine) {
  // A malformed row is reported with the CSV's name and line.
  const fs::path dir = fs::path(::testing::TempDir()) / StrCat("omnicml_antworld_bad_", ::getpid());
  fs::create_directories(dir);
  const std::string csv = (dir / "route.csv").string();
  {
    std::ofstream out(csv);
    out << "X [mm], Y [mm], Z [mm], Heading [degrees], Filename\n"
        << "6300, 8450, 10, 219.96, a.png\n"
        << "6293.58, nan, 10, 219.96, b.png\n";
  }
  try {
    ReadAntWorldCsv(csv);
    ADD_FAILURE() << "NaN accepted";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("route.csv:3:"));
  }
  {
    std::ofstream out(csv);
    out << "X [mm], Y [mm], Z [mm], Heading [degrees], Filename\n"
        << "6300, 8450, 10, 219.96, missing.png\n";
  }
  try {
    AntWorldReader reader(csv);
    ADD_FAILURE() << "missing image accepted";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("route.csv:2:"));
    EXPECT_THAT(e.what(), HasSubstr("missing.png"));
  }
  AntWorldOptions bad;
  bad.stride = 0;
  EXPECT_THROW(bad.Validate(), Error);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace omnicml
