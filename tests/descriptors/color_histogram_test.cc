// Tests of the colour histograms [UN]: the distances' properties, normalisation,
// invariance to rotation of the panorama, thread-safety.
#include "omnicml/descriptors/color_histogram.h"

#include <cmath>
#include <numeric>
#include <random>
#include <thread>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

std::vector<float> RandomHistogram(std::mt19937& rng, std::size_t n, double zero_fraction) {
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<float> h(n);
  for (auto& v : h) v = u(rng) < zero_fraction ? 0.0f : u(rng);
  const float sum = std::accumulate(h.begin(), h.end(), 0.0f);
  for (auto& v : h) v /= sum;
  return h;
}

// Jeffrey divergence is symmetric, non-negative and zero only for equal histograms;
// the other distances share these properties.
TEST(ColorHistogram, DistancesSymmetricNonNegativeZeroOnlyForEqual) {
  std::mt19937 rng(12);
  using Fn = double (*)(const float*, const float*, std::size_t);
  const Fn distances[] = {&ColorHistogram::JeffreyDivergence, &ColorHistogram::ChiSquare,
                          &ColorHistogram::L1, &ColorHistogram::L2,
                          &ColorHistogram::IntersectionDistance};
  for (int trial = 0; trial < 50; ++trial) {
    const std::size_t n = 5 + trial;
    const auto a = RandomHistogram(rng, n, 0.3), b = RandomHistogram(rng, n, 0.3);
    for (Fn d : distances) {
      const double ab = d(a.data(), b.data(), n), ba = d(b.data(), a.data(), n);
      EXPECT_NEAR(ab, ba, 1e-9 + 1e-6 * ab);
      EXPECT_GT(ab, 0.0);
      EXPECT_EQ(d(a.data(), a.data(), n), 0.0);
    }
  }
  // Jeffrey divergence of disjoint histograms is its maximum 2 log 2.
  const std::vector<float> p = {1, 0, 0}, q = {0, 0, 1};
  EXPECT_NEAR(ColorHistogram::JeffreyDivergence(p.data(), q.data(), 3), 2 * std::log(2.0), 1e-6);
}

// Each of the six bands is a histogram summing to 1 and the descriptor has 6 x bins floats.
TEST(ColorHistogram, BandsAreNormalised) {
  for (bool normalized : {false, true}) {
    ColorHistogramOptions options;
    options.normalized_rgb = normalized;
    const ColorHistogram ch(options);
    const Descriptor d = ch.Compute(MakeSyntheticPanorama(720, 120, 1));
    ASSERT_EQ(d.features.size(), 6u * 32u);
    for (int band = 0; band < 6; ++band) {
      const double sum = std::accumulate(d.features.begin() + band * 32,
                                         d.features.begin() + (band + 1) * 32, 0.0);
      EXPECT_NEAR(sum, 1.0, 1e-5) << "band " << band;
    }
    for (float v : d.features) EXPECT_GE(v, 0.0f);
  }
}

// A rotated panorama has the same histograms; a different place does not.
TEST(ColorHistogram, InvariantToColumnRoll) {
  const ColorHistogram ch;
  const cv::Mat pano = MakeSyntheticPanorama(720, 120, 2);
  const Descriptor a = ch.Compute(pano), b = ch.Compute(RollColumns(pano, 123));
  EXPECT_EQ(a.features, b.features);
  EXPECT_GT(ch.Distance(a, ch.Compute(MakeSyntheticPanorama(720, 120, 3))), 0.01);
}

// A uniform image puts the low-pass-filtered mass around its own bins: the filter of
// width 5 spreads one bin over 5 (3 at an end of a non-cyclic band).
TEST(ColorHistogram, LowPassFilterSpreadsMass) {
  ColorHistogramOptions options;
  options.bins = 16;
  const ColorHistogram ch(options);
  const Descriptor d = ch.Compute(cv::Mat(10, 10, CV_8UC3, cv::Scalar(128, 128, 128)));
  // R band (index 3): value 128 -> bin 8; spread over bins 6..10 equally.
  for (int i = 0; i < 16; ++i) {
    EXPECT_NEAR(d.features[3 * 16 + i], (i >= 6 && i <= 10) ? 0.2 : 0.0, 1e-6) << i;
  }
  // Saturation 0 -> bin 0, at the end: spread over bins 0..2 with weights 1/3,1/4,1/5.
  const double w0 = 1.0 / 3, w1 = 1.0 / 4, w2 = 1.0 / 5, total = w0 + w1 + w2;
  EXPECT_NEAR(d.features[2 * 16 + 0], w0 / total, 1e-6);
  EXPECT_NEAR(d.features[2 * 16 + 2], w2 / total, 1e-6);
}

// Normalised rgb bands ignore a uniform brightness change; plain RGB bands do not.
TEST(ColorHistogram, NormalisedRgbIgnoresBrightness) {
  const cv::Mat pano = MakeSyntheticPanorama(360, 60, 5);
  cv::Mat darker;
  pano.convertTo(darker, CV_8UC3, 0.5);
  ColorHistogramOptions options;
  options.normalized_rgb = true;
  const ColorHistogram normalized(options), plain;
  const int bins = options.bins;
  auto rgb_distance = [&](const ColorHistogram& ch) {
    const Descriptor a = ch.Compute(pano), b = ch.Compute(darker);
    return ColorHistogram::JeffreyDivergence(a.features.data() + 3 * bins,
                                             b.features.data() + 3 * bins, 3 * bins);
  };
  EXPECT_LT(rgb_distance(normalized), 0.3 * rgb_distance(plain));
}

// A random BGR image with every channel in [lo, hi].
cv::Mat RandomImage(std::mt19937& rng, int rows, int cols, int lo, int hi) {
  std::uniform_int_distribution<int> u(lo, hi);
  cv::Mat m(rows, cols, CV_8UC3);
  for (int y = 0; y < rows; ++y) {
    for (int x = 0; x < cols * 3; ++x)
      m.ptr<std::uint8_t>(y)[x] = static_cast<std::uint8_t>(u(rng));
  }
  return m;
}

double BandDistance(const Descriptor& a, const Descriptor& b, int band, int bins) {
  return ColorHistogram::JeffreyDivergence(a.features.data() + band * bins,
                                           b.features.data() + band * bins, bins);
}

// A light doubling every pixel (exactly, within the reliable range: no channel reaches
// 255) leaves the hue, HSV saturation and r, g, b histograms bit-identical and the
// relative luminance nearly so; HLS L and S, [UN]'s bands, change.
TEST(ColorHistogram, InvariantBandsUnchangedByALightInTheReliableRange) {
  ColorHistogramOptions invariant;
  invariant.normalized_rgb = true;
  invariant.hsv_saturation = true;
  invariant.relative_luminance = true;
  invariant.reliable_chromaticity = true;
  ColorHistogramOptions published = invariant;
  published.hsv_saturation = published.relative_luminance = published.reliable_chromaticity = false;
  const ColorHistogram inv(invariant), un(published);
  const int bins = invariant.bins;
  std::mt19937 rng(7);
  for (int trial = 0; trial < 5; ++trial) {
    const cv::Mat dim = RandomImage(rng, 40, 90, 40, 120);
    cv::Mat lit;
    dim.convertTo(lit, CV_8UC3, 2.0);  // exact: every value <= 240
    const Descriptor a = inv.Compute(dim, 1.0), b = inv.Compute(lit, 2.0);
    for (int band : {0, 2, 3, 4, 5}) {
      for (int i = 0; i < bins; ++i) {
        EXPECT_EQ(a.features[band * bins + i], b.features[band * bins + i])
            << "trial " << trial << " band " << band << " bin " << i;
      }
    }
    const Descriptor ua = un.Compute(dim), ub = un.Compute(lit);
    EXPECT_LT(BandDistance(a, b, 1, bins), 0.02) << "relative luminance, trial " << trial;
    EXPECT_GT(BandDistance(ua, ub, 1, bins), 0.5) << "HLS L, trial " << trial;
    EXPECT_GT(BandDistance(ua, ub, 2, bins), 0.1) << "HLS S, trial " << trial;
  }
}

// reliable_chromaticity leaves pixels out of H, S, r, g, b when their sum R + G + B is
// below ReliableIntensitySum(sigma) or a channel is clipped at 255: appending rows of
// such pixels to an image changes only its L band; without the option it changes all.
TEST(ColorHistogram, ReliableChromaticityIgnoresDarkAndClippedPixels) {
  ColorHistogramOptions options;
  options.normalized_rgb = true;
  options.hsv_saturation = true;
  options.reliable_chromaticity = true;
  const ColorHistogram ch(options);
  ColorHistogramOptions all_pixels = options;
  all_pixels.reliable_chromaticity = false;
  const ColorHistogram plain(all_pixels);
  const int bins = options.bins;
  const double sigma = 1.5;
  const double min_sum = ch.ReliableIntensitySum(sigma);
  EXPECT_NEAR(min_sum, 2.0 * std::sqrt(2.0 / 3.0) * bins * sigma, 1e-9);
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> dark(0, static_cast<int>(min_sum / 3.0) - 1);
  for (int trial = 0; trial < 5; ++trial) {
    const cv::Mat image = RandomImage(rng, 30, 60, 60, 200);
    cv::Mat unreliable = RandomImage(rng, 10, 60, 60, 200);
    for (int y = 0; y < unreliable.rows; ++y) {
      for (int x = 0; x < unreliable.cols; ++x) {
        auto& px = unreliable.at<cv::Vec3b>(y, x);
        if ((x + y) % 2 == 0) {
          px = cv::Vec3b(dark(rng), dark(rng), dark(rng));  // sum < min_sum
        } else {
          px[(x + y) % 3] = 255;  // one clipped channel
        }
      }
    }
    cv::Mat extended;
    cv::vconcat(image, unreliable, extended);
    const Descriptor before = ch.Compute(image, sigma), after = ch.Compute(extended, sigma);
    const Descriptor plain_before = plain.Compute(image), plain_after = plain.Compute(extended);
    for (int band : {0, 2, 3, 4, 5}) {
      EXPECT_EQ(BandDistance(before, after, band, bins), 0.0) << "band " << band;
      EXPECT_GT(BandDistance(plain_before, plain_after, band, bins), 0.0) << "band " << band;
    }
    EXPECT_GT(BandDistance(before, after, 1, bins), 0.0);  // L counts every pixel
  }
  // An image with no reliable pixel falls back to all pixels (finite, normalised bands).
  const Descriptor black = ch.Compute(cv::Mat(10, 10, CV_8UC3, cv::Scalar::all(2)), sigma);
  for (float v : black.features) EXPECT_TRUE(std::isfinite(v));
}

// Immerkaer's estimator recovers the standard deviation of Gaussian noise added to a
// flat image and to a smooth ramp (structure up to second order cancels).
TEST(ColorHistogram, EstimateNoiseSigmaRecoversAddedNoise) {
  std::mt19937 rng(5);
  for (double sigma : {1.0, 2.0, 4.0}) {
    std::normal_distribution<double> noise(0.0, sigma);
    cv::Mat flat(120, 360, CV_8UC3), ramp(120, 360, CV_8UC3);
    for (int y = 0; y < 120; ++y) {
      for (int x = 0; x < 360 * 3; ++x) {
        flat.ptr<std::uint8_t>(y)[x] = cv::saturate_cast<std::uint8_t>(100 + noise(rng));
        ramp.ptr<std::uint8_t>(y)[x] =
            cv::saturate_cast<std::uint8_t>(40 + 0.3 * (x / 3) + 0.5 * y + noise(rng));
      }
    }
    EXPECT_NEAR(EstimateNoiseSigma(flat), sigma, 0.1 * sigma + 0.1) << sigma;
    EXPECT_NEAR(EstimateNoiseSigma(ramp), sigma, 0.1 * sigma + 0.15) << sigma;
  }
  EXPECT_NEAR(EstimateNoiseSigma(cv::Mat(20, 20, CV_8UC1, cv::Scalar(9))), 0.0, 1e-12);
  EXPECT_THROW(EstimateNoiseSigma(cv::Mat(2, 20, CV_8UC3, cv::Scalar::all(0))), Error);
}

// Compute from two threads gives bit-identical results; bad input is an Error.
TEST(ColorHistogram, ThreadSafeAndRejectsBadInput) {
  const ColorHistogram ch;
  const cv::Mat pano = MakeSyntheticPanorama(360, 60, 6);
  Descriptor r[2];
  std::thread t0([&] { r[0] = ch.Compute(pano); }), t1([&] { r[1] = ch.Compute(pano); });
  t0.join();
  t1.join();
  EXPECT_EQ(r[0], r[1]);
  EXPECT_THROW(ch.Compute(cv::Mat()), Error);
  EXPECT_THROW(ch.Compute(cv::Mat(1, 1, CV_8UC3, cv::Scalar::all(0))), Error);
  EXPECT_THROW(ch.Compute(cv::Mat(10, 10, CV_8UC4, cv::Scalar::all(0))), Error);
  EXPECT_THROW(ColorHistogram(ColorHistogramOptions{1, 1, false, HistogramDistance::kJeffrey}),
               Error);
}

}  // namespace
}  // namespace omnicml
