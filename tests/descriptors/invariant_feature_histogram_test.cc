// Tests of the invariant feature histogram [W]: invariance to 90-degree rotation and
// cyclic translation, normalised intersection, Monte-Carlo sampling, thread-safety.
#include "omnicml/descriptors/invariant_feature_histogram.h"

#include <numeric>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Rolls an image cyclically by dx columns and dy rows.
cv::Mat RollBoth(const cv::Mat& in, int dx, int dy) {
  cv::Mat rolled = RollColumns(in, dx);
  cv::Mat t;
  cv::transpose(rolled, t);
  cv::Mat t2 = RollColumns(t, dy);
  cv::transpose(t2, rolled);
  return rolled;
}

double MaxAbsDifference(const Descriptor& a, const Descriptor& b) {
  double m = 0;
  for (std::size_t i = 0; i < a.features.size(); ++i)
    m = std::max(m, std::fabs(double{a.features[i]} - b.features[i]));
  return m;
}

// A cyclic translation of the image (torus) leaves the histogram unchanged.
TEST(InvariantFeatureHistogram, InvariantToCyclicTranslation) {
  IfhOptions options;
  options.scales = {1.0, 2.0};
  const InvariantFeatureHistogram ifh(options);
  const cv::Mat image = MakeSyntheticPanorama(160, 48, 3);
  const Descriptor d0 = ifh.Compute(image);
  for (auto [dx, dy] : {std::pair{17, 0}, std::pair{0, 5}, std::pair{-40, 23}}) {
    const Descriptor d1 = ifh.Compute(RollBoth(image, dx, dy));
    EXPECT_LT(MaxAbsDifference(d0, d1), 1e-6) << dx << "," << dy;
    EXPECT_LT(ifh.Distance(d0, d1), 1e-5);
  }
}

// A 90-degree rotation leaves the histogram unchanged up to interpolation rounding,
// while an unrelated image is far away (so the comparison is meaningful).
TEST(InvariantFeatureHistogram, InvariantTo90DegreeRotation) {
  const InvariantFeatureHistogram ifh;
  const cv::Mat image = MakeSyntheticPanorama(160, 48, 4);
  const Descriptor d0 = ifh.Compute(image);
  for (auto code : {cv::ROTATE_90_CLOCKWISE, cv::ROTATE_180, cv::ROTATE_90_COUNTERCLOCKWISE}) {
    cv::Mat rotated;
    cv::rotate(image, rotated, code);
    const Descriptor d1 = ifh.Compute(rotated);
    EXPECT_LT(ifh.Distance(d0, d1), 1e-3) << "rotate code " << code;
  }
  const Descriptor other = ifh.Compute(MakeSyntheticPanorama(160, 48, 99));
  EXPECT_GT(ifh.Distance(d0, other), 0.02);
}

// normalize_columns: a brightness gain that differs between sectors of the panorama (the
// lights of one room off: a quarter dimmed to 40 %) leaves the histogram as it was, a
// uniform image of any brightness gives one descriptor, and the cyclic-translation
// invariance holds. Without it the same dimming moves the descriptor.
TEST(InvariantFeatureHistogram, ColumnNormalisationRemovesASectorGain) {
  cv::Mat image = MakeSyntheticPanorama(160, 48, 4);
  // Multiples of 5, so that 0.4 x value is an exact integer.
  image.forEach<cv::Vec3b>([](cv::Vec3b& p, const int*) {
    for (int k = 0; k < 3; ++k) p[k] = static_cast<std::uint8_t>(p[k] / 5 * 5);
  });
  cv::Mat dimmed = image.clone();
  for (int r = 0; r < dimmed.rows; ++r) {
    for (int c = 40; c < 80; ++c) {
      for (int k = 0; k < 3; ++k) {
        auto& v = dimmed.at<cv::Vec3b>(r, c)[k];
        v = static_cast<std::uint8_t>(v * 2 / 5);
      }
    }
  }
  IfhOptions options;
  options.normalize_columns = true;
  const InvariantFeatureHistogram normalized(options);
  const Descriptor a = normalized.Compute(image);
  EXPECT_LT(normalized.Distance(a, normalized.Compute(dimmed)), 1e-3);
  EXPECT_LT(MaxAbsDifference(a, normalized.Compute(RollBoth(image, 37, 0))), 1e-6);
  const Descriptor other = normalized.Compute(MakeSyntheticPanorama(160, 48, 99));
  EXPECT_GT(normalized.Distance(a, other), 0.02);
  const Descriptor dark = normalized.Compute(cv::Mat(48, 160, CV_8UC3, cv::Scalar(20, 20, 20)));
  const Descriptor light = normalized.Compute(cv::Mat(48, 160, CV_8UC3, cv::Scalar(200, 200, 200)));
  EXPECT_EQ(MaxAbsDifference(dark, light), 0.0);

  const InvariantFeatureHistogram raw;
  ASSERT_FALSE(raw.options().normalize_columns);
  EXPECT_GT(raw.Distance(raw.Compute(image), raw.Compute(dimmed)), 0.05);
}

// The normalised intersection of a histogram with itself is 1 (distance 0); it is
// symmetric and within [0, 1] otherwise; the feature vector sums to 1.
TEST(InvariantFeatureHistogram, NormalisedIntersection) {
  const InvariantFeatureHistogram ifh;
  const Descriptor a = ifh.Compute(MakeSyntheticPanorama(200, 40, 5));
  const Descriptor b = ifh.Compute(MakeSyntheticPanorama(200, 40, 6));
  const std::size_t n = a.features.size();
  EXPECT_EQ(n, ifh.FeatureSize());
  EXPECT_NEAR(std::accumulate(a.features.begin(), a.features.end(), 0.0), 1.0, 1e-5);
  EXPECT_DOUBLE_EQ(InvariantFeatureHistogram::Intersection(a.features.data(), a.features.data(), n),
                   1.0);
  EXPECT_EQ(ifh.Distance(a, a), 0.0);
  const double ab =
      InvariantFeatureHistogram::Intersection(a.features.data(), b.features.data(), n);
  EXPECT_DOUBLE_EQ(
      ab, InvariantFeatureHistogram::Intersection(b.features.data(), a.features.data(), n));
  EXPECT_GT(ab, 0.0);
  EXPECT_LT(ab, 1.0);
  // A histogram contained in another is not equal to it.
  std::vector<float> half(a.features);
  for (auto& v : half) v *= 0.5f;
  EXPECT_NEAR(InvariantFeatureHistogram::Intersection(half.data(), a.features.data(), n), 0.5,
              1e-6);
}

// A constant image gives T = v^2 everywhere: all weight in the bins around v^2.
TEST(InvariantFeatureHistogram, ConstantImageHitsExpectedBin) {
  IfhOptions options;
  options.color = false;
  options.bins = 10;
  const InvariantFeatureHistogram ifh(options);
  const float v = 178.0f / 255.0f;  // T = v^2 ~ 0.487 -> t = 4.37: bins 4 and 5
  const Descriptor d = ifh.Compute(cv::Mat(20, 30, CV_8UC1, cv::Scalar(178)));
  ASSERT_EQ(d.features.size(), 20u);  // 1 channel x 2 kernels x 10 bins
  const float t = v * v * 10 - 0.5f;
  const float frac = t - std::floor(t);
  for (int k = 0; k < 2; ++k) {
    EXPECT_NEAR(d.features[k * 10 + 4], 0.5 * (1 - frac), 1e-4);
    EXPECT_NEAR(d.features[k * 10 + 5], 0.5 * frac, 1e-4);
  }
}

// Monte-Carlo sampling is deterministic per seed and approximates the full histogram.
TEST(InvariantFeatureHistogram, MonteCarloSampling) {
  const cv::Mat image = MakeSyntheticPanorama(240, 60, 8);
  IfhOptions options;
  options.sample_fraction = 0.25;
  const InvariantFeatureHistogram sampled(options);
  const InvariantFeatureHistogram full;
  const Descriptor s1 = sampled.Compute(image), s2 = sampled.Compute(image);
  EXPECT_EQ(s1, s2);
  options.seed = 43;
  const Descriptor s3 = InvariantFeatureHistogram(options).Compute(image);
  EXPECT_NE(s1, s3);
  const Descriptor f = full.Compute(image);
  EXPECT_LT(full.Distance(f, s1), 0.05);
  const Descriptor other = full.Compute(MakeSyntheticPanorama(240, 60, 77));
  EXPECT_GT(full.Distance(f, other), full.Distance(f, s1));
}

// Compute from two threads gives bit-identical results.
TEST(InvariantFeatureHistogram, ThreadSafe) {
  const InvariantFeatureHistogram ifh;
  std::vector<cv::Mat> images;
  for (int i = 0; i < 3; ++i) images.push_back(MakeSyntheticPanorama(160, 40, 20 + i));
  std::vector<Descriptor> results[2];
  auto work = [&](int t) {
    for (const auto& img : images) results[t].push_back(ifh.Compute(img));
  };
  std::thread t0(work, 0), t1(work, 1);
  t0.join();
  t1.join();
  for (std::size_t i = 0; i < images.size(); ++i) EXPECT_EQ(results[0][i], results[1][i]);
}

// Bad input and bad options are reported as omnicml::Error.
TEST(InvariantFeatureHistogram, RejectsBadInput) {
  const InvariantFeatureHistogram ifh;
  EXPECT_THROW(ifh.Compute(cv::Mat()), Error);
  EXPECT_THROW(ifh.Compute(cv::Mat(1, 1, CV_8UC3, cv::Scalar::all(1))), Error);
  EXPECT_THROW(ifh.Compute(cv::Mat(10, 10, CV_8UC2, cv::Scalar::all(1))), Error);
  IfhOptions o;
  o.scales = {3.0};
  EXPECT_THROW(InvariantFeatureHistogram{o}, Error);
  o = {};
  o.kernels.clear();
  EXPECT_THROW(InvariantFeatureHistogram{o}, Error);
  o = {};
  o.sample_fraction = 0;
  EXPECT_THROW(InvariantFeatureHistogram{o}, Error);
}

}  // namespace
}  // namespace omnicml
