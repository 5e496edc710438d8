// Tests of the Fourier signature: rotation invariance, the relative heading convention,
// agreement of the FFT path with a naive DFT, illumination invariance, thread-safety.
#include "omnicml/descriptors/fourier_signature.h"

#include <cmath>
#include <complex>
#include <random>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Shifts a panorama by a fractional number of columns with cyclic linear
// interpolation: out(c) = in(c + shift), the sub-column version of RollColumns.
cv::Mat ShiftColumns(const cv::Mat& in, double shift) {
  cv::Mat map_x(in.size(), CV_32FC1), map_y(in.size(), CV_32FC1);
  for (int r = 0; r < in.rows; ++r) {
    for (int c = 0; c < in.cols; ++c) {
      double x = std::fmod(c + shift, in.cols);
      if (x < 0) x += in.cols;
      map_x.at<float>(r, c) = static_cast<float>(x);
      map_y.at<float>(r, c) = static_cast<float>(r);
    }
  }
  cv::Mat out;
  cv::remap(in, out, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_WRAP);
  return out;
}

// Circular distance in columns between two shifts.
double ColumnError(double a, double b, int width) {
  double d = std::fmod(a - b, width);
  if (d < 0) d += width;
  return std::min(d, width - d);
}

// Magnitudes are unchanged, to float tolerance, by any integer column roll.
TEST(FourierSignature, MagnitudesInvariantUnderColumnRoll) {
  const FourierSignature fs;
  const cv::Mat pano = MakeSyntheticPanorama(720, 120, 7);
  const Descriptor d0 = fs.Compute(pano);
  ASSERT_EQ(d0.features.size(), 64u);
  for (int k : {1, 7, 90, 359, 360, 719, -5, 1234}) {
    const Descriptor dk = fs.Compute(RollColumns(pano, k));
    for (std::size_t i = 0; i < d0.features.size(); ++i) {
      EXPECT_NEAR(dk.features[i], d0.features[i], 1e-5f * (1 + d0.features[i]))
          << "k=" << k << " i=" << i;
    }
    EXPECT_LT(fs.Distance(d0, dk), 1e-4) << "k=" << k;
  }
}

// RelativeHeading(after, before) is +k 2pi/W when after[c] = before[(c + k) mod W].
TEST(FourierSignature, RelativeHeadingRecoversIntegerRoll) {
  const FourierSignature fs;
  const int width = 720;
  const cv::Mat before = MakeSyntheticPanorama(width, 120, 11);
  const Descriptor db = fs.Compute(before);
  for (int k : {0, 1, 2, 45, 90, 180, 359, 360, 361, 600, 719, -90}) {
    const Descriptor da = fs.Compute(RollColumns(before, k));
    const auto shift = fs.RelativeShiftColumns(da, db);
    ASSERT_TRUE(shift.has_value());
    EXPECT_LT(ColumnError(*shift, k, width), 1e-3) << "k=" << k << " got " << *shift;
    const auto heading = fs.RelativeHeading(da, db);
    ASSERT_TRUE(heading.has_value());
    EXPECT_NEAR(WrapAngle(*heading - WrapAngle(kTwoPi * k / width)), 0.0, 1e-5) << "k=" << k;
    // Swapping the arguments negates the heading.
    EXPECT_NEAR(WrapAngle(*fs.RelativeHeading(db, da) + *heading), 0.0, 1e-5) << "k=" << k;
  }
}

// A sub-column shift made by resampling is recovered within 0.1 column.
TEST(FourierSignature, RelativeHeadingRecoversSubColumnShift) {
  for (const FourierOptions& options :
       {FourierOptions{}, FourierOptions{2, 32, FourierDistance::kL1, false}}) {
    const FourierSignature fs(options);
    const cv::Mat before = MakeSyntheticPanorama(720, 120, 5);
    const Descriptor db = fs.Compute(before);
    for (double s : {0.25, 0.5, 0.75, 10.3, 100.6, -33.4}) {
      const Descriptor da = fs.Compute(ShiftColumns(before, s));
      const auto shift = fs.RelativeShiftColumns(da, db);
      ASSERT_TRUE(shift.has_value());
      EXPECT_LT(ColumnError(*shift, s, 720), 0.1) << "shift " << s << " got " << *shift;
    }
  }
}

// The FFTW path agrees with a naive DFT of the band signals on a small random image.
TEST(FourierSignature, FftMatchesNaiveDft) {
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> u(0, 255);
  cv::Mat image(6, 30, CV_8UC1);
  for (int r = 0; r < image.rows; ++r)
    for (int c = 0; c < image.cols; ++c)
      image.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>(u(rng));
  for (int variant = 0; variant < 4; ++variant) {
    const bool normalize = variant & 1, columns = variant & 2;
    FourierOptions options;
    options.bands = 2;
    options.coefficients = 7;
    options.normalize_bands = normalize;
    options.normalize_columns = columns;
    const FourierSignature fs(options);
    const cv::Mat signals = fs.BandSignals(image);
    const Descriptor d = fs.Compute(image);
    const int w = image.cols, k = options.coefficients, m0 = options.first_harmonic();
    for (int b = 0; b < options.bands; ++b) {
      for (int j = 0; j < k; ++j) {
        std::complex<double> sum = 0;
        for (int c = 0; c < w; ++c) {
          sum += static_cast<double>(signals.at<float>(b, c)) *
                 std::polar(1.0, -kTwoPi * (m0 + j) * c / w);
        }
        sum /= w;
        const std::complex<float> got = d.coefficients[b * k + j];
        EXPECT_NEAR(got.real(), sum.real(), 1e-5) << "band " << b << " harmonic " << m0 + j;
        EXPECT_NEAR(got.imag(), sum.imag(), 1e-5) << "band " << b << " harmonic " << m0 + j;
        EXPECT_NEAR(d.features[b * k + j], std::abs(sum), 1e-5);
      }
    }
    if (!normalize) {
      // Without band normalisation the band signal is the mean grey of its rows in [0, 1],
      // divided by the mean grey of the whole column when columns are normalised.
      double mean = 0, column = 0;
      for (int r = 0; r < 3; ++r) mean += image.at<std::uint8_t>(r, 4);
      for (int r = 0; r < image.rows; ++r) column += image.at<std::uint8_t>(r, 4);
      const double expected = columns ? (mean / 3) / (column / image.rows) : mean / (3 * 255.0);
      EXPECT_NEAR(signals.at<float>(0, 4), expected, 1e-6);
    }
  }
}

// Per-band normalisation makes the descriptor invariant to a global gain and offset;
// without it the descriptor changes (so the test can tell the two apart). (Column
// normalisation is off here: it removes gains, not offsets.)
TEST(FourierSignature, NormalisationRemovesGainAndOffset) {
  cv::Mat grey;
  cv::cvtColor(MakeSyntheticPanorama(720, 120, 9), grey, cv::COLOR_BGR2GRAY);
  grey = grey / 2;                   // values <= 127
  cv::Mat brighter = grey * 2 + 10;  // exact in 8 bits, <= 264 -> check no saturation
  double max_value = 0;
  cv::minMaxLoc(grey, nullptr, &max_value);
  ASSERT_LE(2 * max_value + 10, 255);
  FourierOptions band_options;
  band_options.normalize_columns = false;
  const FourierSignature normalized(band_options);
  const Descriptor a = normalized.Compute(grey), b = normalized.Compute(brighter);
  for (std::size_t i = 0; i < a.features.size(); ++i)
    EXPECT_NEAR(a.features[i], b.features[i], 1e-4);
  const auto heading = normalized.RelativeHeading(a, b);
  ASSERT_TRUE(heading.has_value());
  EXPECT_NEAR(*heading, 0.0, 1e-6);

  FourierOptions raw_options;
  raw_options.normalize_bands = false;
  raw_options.normalize_columns = false;
  const FourierSignature raw(raw_options);
  EXPECT_GT(raw.Distance(raw.Compute(grey), raw.Compute(brighter)), 0.05);
}

// Column normalisation (the default) makes the descriptor invariant to a brightness gain
// that differs between sectors of the panorama, as when the lights of one room go off:
// here a quarter of the panorama is dimmed to 40 %. Without it the same change moves the
// descriptor far beyond e_max, and the relative heading stays exact with it.
TEST(FourierSignature, ColumnNormalisationRemovesASectorGain) {
  cv::Mat grey;
  cv::cvtColor(MakeSyntheticPanorama(720, 120, 4), grey, cv::COLOR_BGR2GRAY);
  // Multiples of 5 (per pixel: OpenCV would fold (grey / 5) * 5 into one scale of 1), so
  // that 0.4 x value is an exact integer.
  for (int r = 0; r < grey.rows; ++r)
    for (int c = 0; c < grey.cols; ++c)
      grey.at<std::uint8_t>(r, c) = grey.at<std::uint8_t>(r, c) / 5 * 5;
  cv::Mat dimmed = grey.clone();
  for (int r = 0; r < dimmed.rows; ++r)
    for (int c = 200; c < 380; ++c)
      dimmed.at<std::uint8_t>(r, c) =
          static_cast<std::uint8_t>(dimmed.at<std::uint8_t>(r, c) * 2 / 5);
  const FourierSignature fs;  // defaults: normalize_columns and normalize_bands
  ASSERT_TRUE(fs.options().normalize_columns);
  const Descriptor a = fs.Compute(grey), b = fs.Compute(dimmed);
  EXPECT_LT(fs.Distance(a, b), 1e-4);
  const auto heading = fs.RelativeHeading(a, b);
  ASSERT_TRUE(heading.has_value());
  EXPECT_NEAR(*heading, 0.0, 1e-6);

  FourierOptions bands_only;
  bands_only.normalize_columns = false;
  const FourierSignature without(bands_only);
  EXPECT_GT(without.Distance(without.Compute(grey), without.Compute(dimmed)), 0.3);
}

// L1 and L2 distances agree with their definitions, also for lengths not a multiple of 8.
TEST(FourierSignature, DistanceMatchesDefinition) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0, 1);
  for (std::size_t n : {1u, 7u, 8u, 13u, 64u, 100u}) {
    std::vector<float> a(n), b(n);
    for (auto& v : a) v = u(rng);
    for (auto& v : b) v = u(rng);
    double l1 = 0, l2 = 0;
    for (std::size_t i = 0; i < n; ++i) {
      l1 += std::fabs(a[i] - b[i]);
      l2 += (a[i] - b[i]) * (a[i] - b[i]);
    }
    FourierOptions o1;
    o1.distance = FourierDistance::kL1;
    EXPECT_NEAR(FourierSignature(o1).Distance(a.data(), b.data(), n), l1, 1e-5 * n);
    EXPECT_NEAR(FourierSignature().Distance(a.data(), b.data(), n), std::sqrt(l2), 1e-5 * n);
    EXPECT_EQ(FourierSignature().Distance(a.data(), a.data(), n), 0.0);
  }
}

// Compute from two threads at once gives bit-identical results to a sequential run
// (also while the plans of new sizes are created concurrently).
TEST(FourierSignature, ThreadSafeAndDeterministic) {
  const FourierSignature fs;
  std::vector<cv::Mat> images;
  for (int i = 0; i < 6; ++i) images.push_back(MakeSyntheticPanorama(360 + 2 * i, 60, 100 + i));
  std::vector<Descriptor> results[2];
  auto work = [&](int t) {
    for (int rep = 0; rep < 5; ++rep)
      for (const auto& img : images) results[t].push_back(fs.Compute(img));
  };
  std::thread t0(work, 0), t1(work, 1);
  t0.join();
  t1.join();
  ASSERT_EQ(results[0].size(), results[1].size());
  for (std::size_t i = 0; i < results[0].size(); ++i) {
    EXPECT_EQ(results[0][i], results[1][i]);
    EXPECT_EQ(results[0][i], fs.Compute(images[i % images.size()]));
  }
}

// Bad input is reported as omnicml::Error, not a crash.
TEST(FourierSignature, RejectsBadInput) {
  const FourierSignature fs;
  EXPECT_THROW(fs.Compute(cv::Mat()), Error);
  EXPECT_THROW(fs.Compute(cv::Mat(1, 1, CV_8UC1, cv::Scalar(3))), Error);
  EXPECT_THROW(fs.Compute(cv::Mat(120, 720, CV_8UC4, cv::Scalar::all(3))), Error);
  EXPECT_THROW(fs.Compute(cv::Mat(120, 720, CV_16UC1, cv::Scalar(3))), Error);
  EXPECT_THROW(fs.Compute(cv::Mat(3, 720, CV_8UC1, cv::Scalar(3))),
               Error);  // fewer rows than bands
  EXPECT_THROW(fs.Compute(cv::Mat(120, 20, CV_8UC1, cv::Scalar(3))), Error);  // too narrow
  EXPECT_THROW(FourierSignature(FourierOptions{0, 16, FourierDistance::kL2, true}), Error);
  EXPECT_THROW(FourierSignature(FourierOptions{4, 0, FourierDistance::kL2, true}), Error);
  // Descriptors of different widths cannot be compared for heading.
  const Descriptor a = fs.Compute(MakeSyntheticPanorama(720, 120, 1));
  const Descriptor b = fs.Compute(MakeSyntheticPanorama(360, 120, 1));
  EXPECT_THROW(fs.RelativeHeading(a, b), Error);
}

// A uniform panorama has no rotation to read: std::nullopt, never a fake 0.
TEST(FourierSignature, FlatPanoramaHasNoHeading) {
  const FourierSignature fs;
  const Descriptor flat = fs.Compute(cv::Mat(120, 720, CV_8UC3, cv::Scalar(90, 100, 110)));
  EXPECT_FALSE(fs.RelativeHeading(flat, flat).has_value());
}

// A mask of the robot's mast: columns [c0, c0 + n) invalid in every row.
cv::Mat ColumnBandMask(int width, int height, int c0, int n) {
  cv::Mat mask(height, width, CV_8UC1, cv::Scalar(255));
  mask.colRange(c0, c0 + n).setTo(0);
  return mask;
}

// Whatever the masked pixels hold, the descriptor is the same: the distance between two
// views is that of their unmasked parts.
TEST(FourierSignatureMask, MaskedPixelsHaveNoInfluence) {
  const FourierSignature fourier;
  const cv::Mat a = MakeSyntheticPanorama(360, 60, 1);
  const cv::Mat b = MakeSyntheticPanorama(360, 60, 2);
  const cv::Mat mask = ColumnBandMask(360, 60, 100, 45);
  // Rows 0-9 of a few columns elsewhere masked too (a cable), to cover partial columns.
  cv::Mat mask2 = mask.clone();
  mask2(cv::Rect(250, 0, 20, 10)).setTo(0);
  std::mt19937 rng(5);
  for (const cv::Mat& m : {mask, mask2}) {
    cv::Mat a_noise = a.clone(), b_noise = b.clone();
    cv::Mat junk(a.size(), a.type());
    cv::randu(junk, cv::Scalar::all(0), cv::Scalar::all(255));
    junk.copyTo(a_noise, m == 0);
    cv::randu(junk, cv::Scalar::all(0), cv::Scalar::all(255));
    junk.copyTo(b_noise, m == 0);
    const Descriptor da = fourier.ComputeMasked(a, m), dan = fourier.ComputeMasked(a_noise, m);
    const Descriptor db = fourier.ComputeMasked(b, m), dbn = fourier.ComputeMasked(b_noise, m);
    EXPECT_LT(fourier.Distance(da, dan), 1e-6);
    EXPECT_NEAR(fourier.Distance(da, db), fourier.Distance(dan, dbn), 1e-6);
    // Without the mask the junk changes the descriptor.
    EXPECT_GT(fourier.Distance(fourier.Compute(a), fourier.Compute(a_noise)), 1e-3);
  }
  // A full mask is the unmasked descriptor, bit for bit.
  const cv::Mat all(60, 360, CV_8UC1, cv::Scalar(255));
  EXPECT_EQ(fourier.ComputeMasked(a, all), fourier.Compute(a));
}

// A masked band of g of the columns shrinks the band spectra's energy by about g
// (Parseval: the gap is at the band's mean), so distances shrink by about sqrt(1 - g).
TEST(FourierSignatureMask, GapShrinksMagnitudesByItsFraction) {
  FourierOptions options;
  options.coefficients = 179;  // all harmonics of W = 360 but DC and Nyquist
  const FourierSignature fourier(options);
  const cv::Mat a = MakeSyntheticPanorama(360, 60, 3);
  for (const int n : {36, 90}) {
    const Descriptor d = fourier.ComputeMasked(a, ColumnBandMask(360, 60, 0, n));
    double energy = 0;
    for (const float f : d.features) energy += f * f;
    // Normalised band signals: unit variance over the valid columns, zero in the gap, so
    // sum_m |S[m]|^2 over the stored half spectrum is (1 - g) / 2 per band.
    const double g = n / 360.0;
    EXPECT_NEAR(energy, options.bands * (1.0 - g) / 2.0, 0.02 * options.bands) << n;
  }
}

// The relative heading of two views of one place, turned by k columns, with the same
// mask (fixed in the robot frame) on both, is still found within a column.
TEST(FourierSignatureMask, RelativeHeadingUnderRollWithMask) {
  const FourierSignature fourier;
  const int width = 360;
  const cv::Mat mask = ColumnBandMask(width, 60, 170, width / 8);
  for (const std::uint32_t seed : {11u, 12u, 13u}) {
    const cv::Mat before = MakeSyntheticPanorama(width, 60, seed);
    for (const int k : {-90, -37, -5, 12, 45, 90}) {
      const cv::Mat after = RollColumns(before, k);
      const auto shift = fourier.RelativeShiftColumns(fourier.ComputeMasked(after, mask),
                                                      fourier.ComputeMasked(before, mask));
      ASSERT_TRUE(shift.has_value());
      EXPECT_LT(ColumnError(*shift, (k % width + width) % width, width), 1.0)
          << "seed " << seed << " k " << k;
    }
  }
}

// Bad masks are errors naming the mask.
TEST(FourierSignatureMask, RejectsBadMask) {
  const FourierSignature fourier;
  const cv::Mat a = MakeSyntheticPanorama(360, 60, 1);
  EXPECT_THROW(fourier.ComputeMasked(a, cv::Mat(60, 100, CV_8UC1, cv::Scalar(255))), Error);
  EXPECT_THROW(fourier.ComputeMasked(a, cv::Mat(60, 360, CV_8UC1, cv::Scalar(0))), Error);
  EXPECT_THROW(fourier.ComputeMasked(a, cv::Mat(60, 360, CV_32FC1, cv::Scalar(1))), Error);
}

}  // namespace
}  // namespace omnicml
