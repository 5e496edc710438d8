#include "omnicml/descriptors/color_histogram.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

#include <opencv2/imgproc.hpp>

#include "descriptors/internal/descriptor_util.h"
#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Moving average of `width` bins (odd) over a histogram, cyclic or truncated at the ends
// ([UN] section 3: low-pass filtering against small shifts of colour).
std::vector<double> LowPass(const std::vector<double>& h, int width, bool cyclic) {
  const int n = static_cast<int>(h.size()), half = width / 2;
  std::vector<double> out(h.size(), 0.0);
  for (int i = 0; i < n; ++i) {
    double sum = 0;
    int count = 0;
    for (int j = i - half; j <= i + half; ++j) {
      if (cyclic) {
        sum += h[((j % n) + n) % n];
        ++count;
      } else if (j >= 0 && j < n) {
        sum += h[j];
        ++count;
      }
    }
    out[i] = sum / count;
  }
  return out;
}

}  // namespace

std::string ToString(HistogramDistance d) {
  switch (d) {
    case HistogramDistance::kJeffrey:
      return "jeffrey";
    case HistogramDistance::kChiSquare:
      return "chi_square";
    case HistogramDistance::kL1:
      return "l1";
    case HistogramDistance::kL2:
      return "l2";
    case HistogramDistance::kIntersection:
      return "intersection";
  }
  return "unknown";
}

HistogramDistance HistogramDistanceFromString(const std::string& s) {
  if (s == "jeffrey") return HistogramDistance::kJeffrey;
  if (s == "chi_square") return HistogramDistance::kChiSquare;
  if (s == "l1") return HistogramDistance::kL1;
  if (s == "l2") return HistogramDistance::kL2;
  if (s == "intersection") return HistogramDistance::kIntersection;
  throw Error(StrCat("unknown histogram distance '", s,
                     "' (expected jeffrey, chi_square, l1, l2 or intersection)"));
}

void ColorHistogramOptions::Validate() const {
  if (bins < 2 || bins > 256)
    throw Error(StrCat("ColorHistogramOptions.bins must be in 2..256, got ", bins));
  if (filter_width < 1 || filter_width > bins || filter_width % 2 == 0) {
    throw Error(StrCat("ColorHistogramOptions.filter_width must be odd and in 1..bins (", bins,
                       "), got ", filter_width));
  }
  if (!(relative_luminance_range_stops > 0 && relative_luminance_range_stops <= 16)) {
    throw Error(
        StrCat("ColorHistogramOptions.relative_luminance_range_stops must be in (0, 16], got ",
               relative_luminance_range_stops));
  }
  switch (distance) {
    case HistogramDistance::kJeffrey:
    case HistogramDistance::kChiSquare:
    case HistogramDistance::kL1:
    case HistogramDistance::kL2:
    case HistogramDistance::kIntersection:
      return;
  }
  throw Error("ColorHistogramOptions.distance is not a known distance");
}

ColorHistogram::ColorHistogram(const ColorHistogramOptions& options) : options_(options) {
  options_.Validate();
}

double EstimateNoiseSigma(const cv::Mat& image) {
  if (image.empty() || image.depth() != CV_8U || image.rows < 3 || image.cols < 3 ||
      (image.channels() != 1 && image.channels() != 3)) {
    throw Error(
        StrCat("EstimateNoiseSigma: expected an 8-bit grey or BGR image of at least 3 x 3 "
               "pixels, got ",
               image.cols, " x ", image.rows, " with ", image.channels(), " channels"));
  }
  const int ch = image.channels();
  // Immerkaer (1996) eq. (3): sigma = sqrt(pi/2) / (6 (W-2)(H-2)) sum |I * N|, per channel,
  // pooled over the channels.
  std::int64_t sum = 0;
  for (int y = 1; y + 1 < image.rows; ++y) {
    const std::uint8_t* a = image.ptr<std::uint8_t>(y - 1);
    const std::uint8_t* b = image.ptr<std::uint8_t>(y);
    const std::uint8_t* c = image.ptr<std::uint8_t>(y + 1);
    for (int x = ch; x + ch < image.cols * ch; ++x) {
      const int v = a[x - ch] - 2 * a[x] + a[x + ch] - 2 * (b[x - ch] - 2 * b[x] + b[x + ch]) +
                    c[x - ch] - 2 * c[x] + c[x + ch];
      sum += v < 0 ? -v : v;
    }
  }
  const double n = 6.0 * (image.cols - 2) * (image.rows - 2) * ch;
  return std::sqrt(std::acos(-1.0) / 2.0) * static_cast<double>(sum) / n;
}

double ColorHistogram::ReliableIntensitySum(double noise_sigma) const {
  // A grey pixel's r = R / (R + G + B) has standard deviation sqrt(2/3) sigma / (R + G + B)
  // under independent channel noise sigma; at most half a bin (1 / (2 bins)) needs this sum.
  return 2.0 * std::sqrt(2.0 / 3.0) * options_.bins * std::max(0.0, noise_sigma);
}

Descriptor ColorHistogram::Compute(const cv::Mat& panorama) const {
  internal::CheckDescriptorInput(panorama, "ColorHistogram", 2, 2);
  const double sigma = options_.reliable_chromaticity && panorama.rows >= 3 && panorama.cols >= 3
                           ? EstimateNoiseSigma(panorama)
                           : 0.0;
  return Compute(panorama, sigma);
}

Descriptor ColorHistogram::Compute(const cv::Mat& panorama, double noise_sigma) const {
  internal::CheckDescriptorInput(panorama, "ColorHistogram", 2, 2);
  cv::Mat bgr;
  if (panorama.channels() == 1) {
    cv::cvtColor(panorama, bgr, cv::COLOR_GRAY2BGR);
  } else {
    bgr = panorama;
  }
  cv::Mat hls;
  cv::cvtColor(bgr, hls, cv::COLOR_BGR2HLS);  // 8-bit: H in [0, 180), L and S in [0, 255]
  const int bins = options_.bins;
  // Reliable pixels (reliable_chromaticity): no clipped channel and R + G + B at least
  // min_sum; when no pixel qualifies, every pixel counts.
  const double min_sum = options_.reliable_chromaticity ? ReliableIntensitySum(noise_sigma) : 0.0;
  const bool masking = options_.reliable_chromaticity;
  auto reliable = [&](int b, int g, int r) {
    return !masking || (b < 255 && g < 255 && r < 255 && b + g + r >= min_sum);
  };
  bool any_reliable = !masking;
  for (int y = 0; y < bgr.rows && !any_reliable; ++y) {
    const std::uint8_t* p = bgr.ptr<std::uint8_t>(y);
    for (int x = 0; x < bgr.cols && !any_reliable; ++x, p += 3)
      any_reliable = reliable(p[0], p[1], p[2]);
  }
  const bool mask = masking && any_reliable;
  // Relative luminance: bin of log2(L / median L) over [-range, range] per L value.
  std::array<int, 256> bin_l{};
  for (int v = 0; v < 256; ++v) bin_l[v] = v * bins / 256;
  if (options_.relative_luminance) {
    std::array<std::int64_t, 256> lhist{};
    for (int y = 0; y < hls.rows; ++y) {
      const std::uint8_t* q = hls.ptr<std::uint8_t>(y);
      for (int x = 0; x < hls.cols; ++x) ++lhist[q[3 * x + 1]];
    }
    const std::int64_t half = (static_cast<std::int64_t>(hls.rows) * hls.cols + 1) / 2;
    int median = 0;
    for (std::int64_t acc = 0; median < 255; ++median) {
      acc += lhist[median];
      if (acc >= half) break;
    }
    const double range = options_.relative_luminance_range_stops;
    for (int v = 0; v < 256; ++v) {
      // +0.5: the centre of the 8-bit quantisation interval (and no log of zero).
      const double stops = std::log2((v + 0.5) / (median + 0.5));
      bin_l[v] = std::clamp(static_cast<int>(std::floor((stops + range) / (2 * range) * bins)), 0,
                            bins - 1);
    }
  }
  // Integer counts in two interleaved copies (even / odd columns), so that runs of equal
  // pixels (sky) do not serialise on one memory location; summed afterwards.
  std::vector<std::int32_t> counts(2 * kBands * static_cast<std::size_t>(bins), 0);
  // Bin of an 8-bit value (0..255) and of an OpenCV hue (0..179).
  std::array<int, 256> bin8{}, bin_hue{};
  for (int v = 0; v < 256; ++v) {
    bin8[v] = v * bins / 256;
    bin_hue[v] = std::min(bins - 1, v * bins / 180);
  }
  const int grey_bin = bins / 3;  // normalised rgb of a black pixel: 1/3 each
  for (int y = 0; y < bgr.rows; ++y) {
    const std::uint8_t* p = bgr.ptr<std::uint8_t>(y);
    const std::uint8_t* q = hls.ptr<std::uint8_t>(y);
    for (int x = 0; x < bgr.cols; ++x, p += 3, q += 3) {
      std::int32_t* c = counts.data() + (x & 1) * kBands * bins;
      const int b = p[0], g = p[1], r = p[2];
      ++c[bins + bin_l[q[1]]];
      if (mask && !reliable(b, g, r)) continue;
      ++c[bin_hue[q[0]]];
      if (options_.hsv_saturation) {
        // HSV saturation (max - min) / max: unchanged when R, G, B are scaled together.
        const int mx = std::max({r, g, b}), mn = std::min({r, g, b});
        ++c[2 * bins + (mx > 0 ? std::min(bins - 1, (mx - mn) * bins / mx) : 0)];
      } else {
        ++c[2 * bins + bin8[q[2]]];
      }
      if (options_.normalized_rgb) {
        // Normalised rgb: chromaticity, invariant to the brightness of a pixel;
        // bin = floor(bins * r / (r + g + b)) in exact integer arithmetic.
        const int sum = r + g + b;
        ++c[3 * bins + (sum > 0 ? std::min(bins - 1, r * bins / sum) : grey_bin)];
        ++c[4 * bins + (sum > 0 ? std::min(bins - 1, g * bins / sum) : grey_bin)];
        ++c[5 * bins + (sum > 0 ? std::min(bins - 1, b * bins / sum) : grey_bin)];
      } else {
        ++c[3 * bins + bin8[r]];
        ++c[4 * bins + bin8[g]];
        ++c[5 * bins + bin8[b]];
      }
    }
  }
  std::array<std::vector<double>, kBands> hist;
  for (int band = 0; band < kBands; ++band) {
    hist[band].resize(static_cast<std::size_t>(bins));
    for (int i = 0; i < bins; ++i) {
      hist[band][i] = static_cast<double>(counts[band * bins + i]) +
                      static_cast<double>(counts[(kBands + band) * bins + i]);
    }
  }
  Descriptor d;
  d.kind = DescriptorKind::kColorHistogram;
  d.panorama_width = panorama.cols;
  d.features.reserve(FeatureSize());
  for (int band = 0; band < kBands; ++band) {
    double pixels = 0;
    for (double v : hist[band]) pixels += v;
    for (double& v : hist[band]) v /= pixels;
    // [UN]: low-pass filter; hue is an angle, so its histogram wraps.
    std::vector<double> smooth = LowPass(hist[band], options_.filter_width, band == 0);
    double total = 0;
    for (double v : smooth) total += v;
    for (double v : smooth) d.features.push_back(static_cast<float>(v / total));
  }
  return d;
}

double ColorHistogram::JeffreyDivergence(const float* a, const float* b, std::size_t n) {
  // [UN] eq. (1): d_J(H, K) = sum_i h_i log(h_i / m_i) + k_i log(k_i / m_i). Terms in
  // float (single-precision logf is several times faster than log), summed in double.
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const float h = a[i], k = b[i];
    if (h == k) continue;  // both terms are exactly 0
    const float m = 0.5f * (h + k);
    float term = 0;
    if (h > 0) term += h * std::log(h / m);
    if (k > 0) term += k * std::log(k / m);
    sum += term;
  }
  return std::max(0.0, sum);
}

double ColorHistogram::ChiSquare(const float* a, const float* b, std::size_t n) {
  // [UN] eq. (2): chi^2(H, K) = sum_i (h_i - m_i)^2 / m_i.
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double h = a[i], k = b[i], m = 0.5 * (h + k);
    if (m > 0) sum += (h - m) * (h - m) / m;
  }
  return sum;
}

double ColorHistogram::L1(const float* a, const float* b, std::size_t n) {
  return internal::SumAbsoluteDifference(a, b, n);
}

double ColorHistogram::L2(const float* a, const float* b, std::size_t n) {
  return std::sqrt(internal::SumSquaredDifference(a, b, n));
}

double ColorHistogram::IntersectionDistance(const float* a, const float* b, std::size_t n) {
  const internal::IntersectionSums s = internal::SumMinimum(a, b, n);
  const float denom = std::max(s.a_sum, s.b_sum);
  if (!(denom > 0)) return 0.0;
  return 1.0 - std::clamp(static_cast<double>(s.min_sum) / denom, 0.0, 1.0);
}

double ColorHistogram::Distance(const float* a, const float* b, std::size_t n) const {
  switch (options_.distance) {
    case HistogramDistance::kJeffrey:
      return JeffreyDivergence(a, b, n);
    case HistogramDistance::kChiSquare:
      return ChiSquare(a, b, n);
    case HistogramDistance::kL1:
      return L1(a, b, n);
    case HistogramDistance::kL2:
      return L2(a, b, n);
    case HistogramDistance::kIntersection:
      return IntersectionDistance(a, b, n);
  }
  return JeffreyDivergence(a, b, n);
}

}  // namespace omnicml
