// Colour histograms of a panorama [UN] (docs/design.md "Descriptors"), used by the
// topological place-recognition baseline.
//
// Six 1-D histograms ("bands" in [UN]'s sense: colour bands, not image rows) of `bins`
// bins each, in this order: hue, luminance, saturation (OpenCV HLS of the 8-bit image),
// then either R, G, B or the normalised r = R/(R+G+B), g, b (a black pixel counts as
// 1/3 each). Each histogram is normalised to sum 1, then low-pass filtered by a moving
// average of `filter_width` bins (cyclic for hue; at the other histograms' ends the
// average is over the bins that exist) [UN] section 3, and renormalised to sum 1. The
// six are joined (6 * bins floats). The raw-pointer distances treat the vector as one
// histogram: for per-band figures call them on each `bins`-long slice.
//
// Illumination options (all off = [UN] as published). A light that multiplies
// a pixel's R, G, B by one factor k leaves its hue, its normalised r, g, b and its HSV
// saturation (max - min) / max unchanged, but not its HLS lightness L nor (above
// mid-grey) its HLS saturation. In 8-bit images the invariance holds only where the
// pixel's values are reliable: a dark pixel's chromaticity is scattered by the sensor
// noise and quantisation, a clipped channel (255) has lost its ratio to the others.
//   hsv_saturation        band 3 is HSV's S = (max - min) / max instead of HLS S.
//   relative_luminance    band 2 holds log2(L / median L of the image) over
//                         [-relative_luminance_range_stops, +range] instead of L: a
//                         light scaling the whole image leaves it unchanged.
//   reliable_chromaticity H, S, r, g, b are histogrammed over reliable pixels only:
//                         no channel at 255, and R + G + B >= 2 sqrt(2/3) bins sigma,
//                         where sigma is the per-channel noise (given, or estimated from
//                         the image, EstimateNoiseSigma): the standard deviation of a
//                         grey pixel's r, sqrt(2/3) sigma / (R + G + B), is then at most
//                         half a bin. With no reliable pixel all pixels count.
//
// Distances between feature vectors h, k (m_i = (h_i + k_i) / 2; terms with
// h_i = k_i = 0 are zero):
//   Jeffrey divergence [UN] eq. (1): sum_i h_i log(h_i / m_i) + k_i log(k_i / m_i)
//   chi-square [UN] eq. (2):          sum_i (h_i - m_i)^2 / m_i
//   L1, L2 (Minkowski), intersection: 1 - sum_i min(h_i, k_i) / max(sum h, sum k).
// All are symmetric, >= 0 and zero only for h = k (for non-negative inputs).
//
// Thread-safety: immutable after construction; Compute may run on any number of threads.
#ifndef OMNICML_DESCRIPTORS_COLOR_HISTOGRAM_H_
#define OMNICML_DESCRIPTORS_COLOR_HISTOGRAM_H_

#include <cstddef>
#include <optional>
#include <string>

#include "omnicml/descriptors/descriptor.h"

namespace omnicml {

enum class HistogramDistance { kJeffrey, kChiSquare, kL1, kL2, kIntersection };
// "jeffrey", "chi_square", "l1", "l2", "intersection".
std::string ToString(HistogramDistance d);
HistogramDistance HistogramDistanceFromString(const std::string& s);  // throws omnicml::Error

struct ColorHistogramOptions {
  // Bins per colour band. 2..256.
  int bins = 32;
  // Width in bins of the moving-average low-pass filter; odd, 1 (off) .. bins. [UN]: 5.
  int filter_width = 5;
  // The last three bands: normalised rgb (true) or plain RGB (false).
  bool normalized_rgb = false;
  // E between two descriptors; [UN] found the Jeffrey divergence best.
  HistogramDistance distance = HistogramDistance::kJeffrey;
  // Illumination options (file comment); false = [UN].
  bool hsv_saturation = false;
  bool relative_luminance = false;
  // Half-width in stops (factors of 2) of the relative-luminance band. (0, 16].
  double relative_luminance_range_stops = 3.0;
  bool reliable_chromaticity = false;

  // Throws omnicml::Error naming the field when a value is out of range.
  void Validate() const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, ColorHistogramOptions& o) {
  v("bins", o.bins);
  v("filter_width", o.filter_width);
  v("normalized_rgb", o.normalized_rgb);
  v.Enum("distance", o.distance,
         {HistogramDistance::kJeffrey, HistogramDistance::kChiSquare, HistogramDistance::kL1,
          HistogramDistance::kL2, HistogramDistance::kIntersection});
  v("hsv_saturation", o.hsv_saturation);
  v("relative_luminance", o.relative_luminance);
  v("relative_luminance_range_stops", o.relative_luminance_range_stops);
  v("reliable_chromaticity", o.reliable_chromaticity);
}

// The per-channel standard deviation of additive white noise in an 8-bit image (grey or
// BGR; channels pooled), in grey levels, by Immerkaer's estimator ("Fast noise variance
// estimation", CVIU 64(2), 1996): sigma = sqrt(pi / 2) / (6 (W - 2) (H - 2)) *
// sum |I * N| with the Laplacian-difference mask N = [1 -2 1; -2 4 -2; 1 -2 1], which
// cancels image structure up to second order. Texture and edges bias it upwards (an
// upper bound for the noise). Throws omnicml::Error on an image below 3 x 3 or not 8-bit.
double EstimateNoiseSigma(const cv::Mat& image);

class ColorHistogram final : public DescriptorExtractor {
 public:
  static constexpr int kBands = 6;  // H, L, S, R|r, G|g, B|b

  // Throws omnicml::Error if the options are invalid.
  explicit ColorHistogram(const ColorHistogramOptions& options = {});

  DescriptorKind kind() const override { return DescriptorKind::kColorHistogram; }

  // Image: CV_8UC3 (BGR) or CV_8UC1 (treated as grey BGR), at least 2 x 2 pixels.
  // Throws omnicml::Error otherwise.
  // With reliable_chromaticity, the noise is estimated from the image itself.
  Descriptor Compute(const cv::Mat& panorama) const override;
  // As Compute, with the per-channel noise sigma (grey levels, >= 0) of `panorama` given
  // (e.g. the camera's after block averaging); used only by reliable_chromaticity.
  Descriptor Compute(const cv::Mat& panorama, double noise_sigma) const;
  // The smallest R + G + B of a pixel whose chromaticity counts under
  // reliable_chromaticity, for noise sigma: 2 sqrt(2/3) bins sigma.
  double ReliableIntensitySum(double noise_sigma) const;

  // options().distance between two histograms of n bins.
  double Distance(const float* a, const float* b, std::size_t n) const override;
  using DescriptorExtractor::Distance;

  // The individual distances (see the file comment), for any non-negative vectors.
  static double JeffreyDivergence(const float* a, const float* b, std::size_t n);
  static double ChiSquare(const float* a, const float* b, std::size_t n);
  static double L1(const float* a, const float* b, std::size_t n);
  static double L2(const float* a, const float* b, std::size_t n);
  static double IntersectionDistance(const float* a, const float* b, std::size_t n);

  // Histograms carry no rotation information.
  bool ProvidesHeading() const override { return false; }
  std::optional<double> RelativeHeading(const Descriptor&, const Descriptor&) const override {
    return std::nullopt;
  }

  std::size_t FeatureSize() const override {
    return static_cast<std::size_t>(kBands) * options_.bins;
  }

  const ColorHistogramOptions& options() const { return options_; }

 private:
  ColorHistogramOptions options_;
};

}  // namespace omnicml

#endif  // OMNICML_DESCRIPTORS_COLOR_HISTOGRAM_H_
