#include "omnicml/descriptors/invariant_feature_histogram.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include <opencv2/imgproc.hpp>

#include "descriptors/internal/descriptor_util.h"
#include "omnicml/common/common.h"

namespace omnicml {
namespace {

constexpr double kMaxOffsetPx = 16.0;

// One kernel point at one angle: bilinear interpolation as 4 taps (element offsets from
// the centre pixel in the padded plane, and weights). Integer positions use 1 tap.
struct Point {
  std::array<std::ptrdiff_t, 4> offset{};
  std::array<float, 4> weight{};
  int taps = 4;
};

// Taps of one (kernel, scale). Points at the centre (0, 0) are the same at every angle:
// they are factored out of the angle average as M(0,0)^centre_power.
struct KernelTaps {
  int centre_power = 0;
  std::vector<std::vector<Point>> angles;  // [angle][other kernel point]
};

double SnapToInteger(double v) {
  const double r = std::round(v);
  return std::fabs(v - r) < 1e-9 ? r : v;
}

KernelTaps MakeTaps(const IfhKernel& kernel, double scale, int angles, std::ptrdiff_t stride) {
  KernelTaps taps;
  taps.angles.resize(static_cast<std::size_t>(angles));
  for (const cv::Point2d& q : kernel.offsets) taps.centre_power += (q.x == 0 && q.y == 0) ? 1 : 0;
  for (int p = 0; p < angles; ++p) {
    // [W] eq. (2): rotation g(x0, x1, 2 pi p / P) about the pixel.
    const double phi = kTwoPi * p / angles;
    const double c = std::cos(phi), s = std::sin(phi);
    for (const cv::Point2d& q : kernel.offsets) {
      if (q.x == 0 && q.y == 0) continue;  // factored out
      const double x = SnapToInteger(scale * (c * q.x - s * q.y));
      const double y = SnapToInteger(scale * (s * q.x + c * q.y));
      const double fx0 = std::floor(x), fy0 = std::floor(y);
      const auto ix = static_cast<std::ptrdiff_t>(fx0), iy = static_cast<std::ptrdiff_t>(fy0);
      const double fx = x - fx0, fy = y - fy0;
      Point pt;
      if (fx == 0 && fy == 0) {
        pt.taps = 1;
        pt.offset = {iy * stride + ix, 0, 0, 0};
        pt.weight = {1.0f, 0, 0, 0};
      } else {
        pt.offset = {iy * stride + ix, iy * stride + ix + 1, (iy + 1) * stride + ix,
                     (iy + 1) * stride + ix + 1};
        pt.weight = {static_cast<float>((1 - fx) * (1 - fy)), static_cast<float>(fx * (1 - fy)),
                     static_cast<float>((1 - fx) * fy), static_cast<float>(fx * fy)};
      }
      taps.angles[p].push_back(pt);
    }
  }
  return taps;
}

// Toroidal padding of one channel of an 8-bit image, scaled to [0, 1]:
//   padded(y, x) = image((y - margin) mod H, (x - margin) mod W)[channel] / 255.
void PadCyclic(const cv::Mat& image, int channel, int margin, std::vector<float>& padded) {
  const int h = image.rows, w = image.cols, cn = image.channels();
  const int pw = w + 2 * margin, ph = h + 2 * margin;
  padded.resize(static_cast<std::size_t>(pw) * ph);
  std::vector<int> col(static_cast<std::size_t>(pw));
  for (int x = 0; x < pw; ++x) col[x] = (((x - margin) % w + w) % w) * cn + channel;
  constexpr float kScale = 1.0f / 255.0f;
  for (int y = 0; y < ph; ++y) {
    const std::uint8_t* src = image.ptr<std::uint8_t>(((y - margin) % h + h) % h);
    float* dst = padded.data() + static_cast<std::size_t>(y) * pw;
    for (int x = 0; x < pw; ++x) dst[x] = src[col[x]] * kScale;
  }
}

// The AVX2 clone is chosen by an ifunc resolver that runs during dynamic relocation,
// before a sanitizer runtime is initialised; ThreadSanitizer instruments the resolver and
// the program dies at start-up (gcc and clang alike). Under TSan: one plain version.
#if defined(__SANITIZE_THREAD__)
#define OMNICML_TSAN_BUILD 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define OMNICML_TSAN_BUILD 1
#endif
#endif
#ifdef OMNICML_TSAN_BUILD
#define OMNICML_AVX2_CLONES
#else
#define OMNICML_AVX2_CLONES __attribute__((target_clones("avx2", "default")))
#endif

// T[f](M) for one image row: out[x] = M(0,0)^c * 1/P sum_p prod_j M(x + q_pj) ([W] eq. 2).
// Element-wise loops over x that the compiler vectorises; an AVX2 clone is picked at
// run time where available (no FMA, so the results are bit-identical either way).
OMNICML_AVX2_CLONES void KernelRow(const float* centre, const KernelTaps& kt, int width,
                                   float* __restrict out, float* __restrict tmp) {
  for (int x = 0; x < width; ++x) out[x] = 0.0f;
  for (const auto& angle : kt.angles) {
    for (int x = 0; x < width; ++x) tmp[x] = 1.0f;
    for (const Point& pt : angle) {
      const float* p0 = centre + pt.offset[0];
      if (pt.taps == 1) {
        for (int x = 0; x < width; ++x) tmp[x] *= p0[x];
      } else {
        const float* p1 = centre + pt.offset[1];
        const float* p2 = centre + pt.offset[2];
        const float* p3 = centre + pt.offset[3];
        const float w0 = pt.weight[0], w1 = pt.weight[1], w2 = pt.weight[2], w3 = pt.weight[3];
        for (int x = 0; x < width; ++x) tmp[x] *= w0 * p0[x] + w1 * p1[x] + w2 * p2[x] + w3 * p3[x];
      }
    }
    for (int x = 0; x < width; ++x) out[x] += tmp[x];
  }
  const float inv_angles = 1.0f / static_cast<float>(kt.angles.size());
  for (int x = 0; x < width; ++x) out[x] *= inv_angles;
  for (int c = 0; c < kt.centre_power; ++c) {
    for (int x = 0; x < width; ++x) out[x] *= centre[x];
  }
}

// Adds a value in [0, 1] to a histogram of `bins` bins, its unit weight split linearly
// between the two nearest bin centres (clamped at the ends).
inline void AddWeighted(double* hist, int bins, float value) {
  const float t = value * static_cast<float>(bins) - 0.5f;
  const float f0 = std::floor(t);
  const int i0 = static_cast<int>(f0);
  if (i0 < 0) {
    hist[0] += 1.0;
  } else if (i0 >= bins - 1) {
    hist[bins - 1] += 1.0;
  } else {
    const float f = t - f0;
    hist[i0] += 1.0f - f;
    hist[i0 + 1] += f;
  }
}

// T[f](M) at one pixel: the mean over angles of the product of interpolated values.
inline float EvaluateAt(const float* centre, const KernelTaps& taps) {
  float sum = 0;
  for (const auto& angle : taps.angles) {
    float prod = 1;
    for (const Point& pt : angle) {
      float v = 0;
      for (int t = 0; t < pt.taps; ++t) v += pt.weight[t] * centre[pt.offset[t]];
      prod *= v;
    }
    sum += prod;
  }
  float value = sum * (1.0f / static_cast<float>(taps.angles.size()));
  for (int c = 0; c < taps.centre_power; ++c) value *= centre[0];
  return value;
}

}  // namespace

void IfhOptions::Validate() const {
  if (kernels.empty()) throw Error("IfhOptions.kernels must not be empty");
  if (scales.empty()) throw Error("IfhOptions.scales must not be empty");
  double max_scale = 0;
  for (double s : scales) {
    if (!(s >= 0.25 && s <= 2.0))
      throw Error(StrCat("IfhOptions.scales: ", s, " is not in [0.25, 2]"));
    max_scale = std::max(max_scale, s);
  }
  for (std::size_t i = 0; i < kernels.size(); ++i) {
    const auto& k = kernels[i];
    if (k.offsets.empty() || k.offsets.size() > 4) {
      throw Error(
          StrCat("IfhOptions.kernels[", i, "] must have 1..4 offsets, has ", k.offsets.size()));
    }
    for (const auto& q : k.offsets) {
      if (!std::isfinite(q.x) || !std::isfinite(q.y) ||
          std::hypot(q.x, q.y) * max_scale > kMaxOffsetPx) {
        throw Error(StrCat("IfhOptions.kernels[", i, "]: offset (", q.x, ", ", q.y,
                           ") times the largest scale exceeds ", kMaxOffsetPx, " pixels"));
      }
    }
  }
  if (angles < 1 || angles > 64)
    throw Error(StrCat("IfhOptions.angles must be in 1..64, got ", angles));
  if (bins < 2 || bins > 1024)
    throw Error(StrCat("IfhOptions.bins must be in 2..1024, got ", bins));
  if (!(sample_fraction > 0.0 && sample_fraction <= 1.0)) {
    throw Error(StrCat("IfhOptions.sample_fraction must be in (0, 1], got ", sample_fraction));
  }
}

InvariantFeatureHistogram::InvariantFeatureHistogram(const IfhOptions& options)
    : options_(options) {
  options_.Validate();
}

std::size_t InvariantFeatureHistogram::FeatureSize() const {
  return static_cast<std::size_t>(options_.color ? 3 : 1) * options_.kernels.size() *
         options_.scales.size() * options_.bins;
}

Descriptor InvariantFeatureHistogram::Compute(const cv::Mat& panorama) const {
  internal::CheckDescriptorInput(panorama, "InvariantFeatureHistogram", 2, 2);
  cv::Mat image8;
  if (options_.color && panorama.channels() == 1) {
    cv::cvtColor(panorama, image8, cv::COLOR_GRAY2BGR);
  } else if (!options_.color && panorama.channels() == 3) {
    cv::cvtColor(panorama, image8, cv::COLOR_BGR2GRAY);
  } else {
    image8 = panorama;
  }
  if (options_.normalize_columns) {
    // v -> v * 0.5 / mean(column) on 8-bit values, in integers so that a gain common to a
    // column's pixels cancels exactly: with n the column's pixel values (rows x channels)
    // and S their sum, v' = round(v 255 n / (2 S)) (half up), clipped to 255; S is floored
    // at n / 4 (a mean brightness of 1e-3 of full scale).
    const int w = image8.cols, h = image8.rows, ch = image8.channels();
    const std::int64_t n = static_cast<std::int64_t>(h) * ch;
    cv::Mat column_sums;  // 1 x w, ch channels: exact integer sums over the rows
    cv::reduce(image8, column_sums, 0, cv::REDUCE_SUM, CV_32S);
    std::vector<std::int64_t> sum(static_cast<std::size_t>(w), 0);
    const std::int32_t* cs = column_sums.ptr<std::int32_t>(0);
    for (int c = 0; c < w; ++c) {
      for (int k = 0; k < ch; ++k) sum[c] += cs[c * ch + k];
      sum[c] = std::max<std::int64_t>(sum[c], (n + 3) / 4);
    }
    cv::Mat normalized(h, w, image8.type());
    for (int r = 0; r < h; ++r) {
      const std::uint8_t* in = image8.ptr<std::uint8_t>(r);
      std::uint8_t* out = normalized.ptr<std::uint8_t>(r);
      for (int c = 0; c < w; ++c) {
        const std::int64_t den = 2 * sum[c];
        for (int k = 0; k < ch; ++k) {
          const std::int64_t num = static_cast<std::int64_t>(in[c * ch + k]) * 255 * n;
          out[c * ch + k] =
              static_cast<std::uint8_t>(std::min<std::int64_t>(255, (2 * num + den) / (2 * den)));
        }
      }
    }
    image8 = normalized;
  }

  double max_radius = 0;
  for (const auto& k : options_.kernels) {
    for (const auto& q : k.offsets) max_radius = std::max(max_radius, std::hypot(q.x, q.y));
  }
  max_radius *= *std::max_element(options_.scales.begin(), options_.scales.end());
  const int margin = static_cast<int>(std::ceil(max_radius)) + 2;
  const int width = image8.cols, height = image8.rows, bins = options_.bins;
  const std::ptrdiff_t stride = width + 2 * margin;

  std::vector<KernelTaps> taps;  // [kernel * scales + scale]
  for (const auto& k : options_.kernels) {
    for (double s : options_.scales) taps.push_back(MakeTaps(k, s, options_.angles, stride));
  }

  // Monte-Carlo sample positions, the same for every channel and kernel.
  std::vector<std::pair<int, int>> samples;
  if (options_.sample_fraction < 1.0) {
    const auto n = static_cast<std::size_t>(
        std::max(1.0, std::round(options_.sample_fraction * width * height)));
    std::mt19937 rng(options_.seed);
    std::uniform_int_distribution<int> ux(0, width - 1), uy(0, height - 1);
    samples.reserve(n);
    for (std::size_t i = 0; i < n; ++i) {
      const int x = ux(rng);
      samples.emplace_back(x, uy(rng));
    }
  }

  const std::size_t channels = static_cast<std::size_t>(image8.channels());
  const std::size_t n_hist = channels * taps.size();
  std::vector<double> hist(n_hist * bins, 0.0);
  // Per-thread scratch buffers: Compute stays thread-safe and does not allocate (and
  // page-fault) fresh large buffers on every call.
  thread_local std::vector<float> padded, row, tmp;
  row.resize(static_cast<std::size_t>(width));
  tmp.resize(static_cast<std::size_t>(width));
  for (std::size_t ch = 0; ch < channels; ++ch) {
    if (ch > 0 && panorama.channels() == 1) {
      // Grey input replicated into colour channels: the same histograms again.
      std::copy_n(hist.begin(), taps.size() * bins, hist.begin() + ch * taps.size() * bins);
      continue;
    }
    PadCyclic(image8, static_cast<int>(ch), margin, padded);
    for (std::size_t t = 0; t < taps.size(); ++t) {
      double* h = &hist[(ch * taps.size() + t) * bins];
      const KernelTaps& kt = taps[t];
      if (!samples.empty()) {
        for (const auto& [x, y] : samples) {
          AddWeighted(h, bins, EvaluateAt(padded.data() + (y + margin) * stride + x + margin, kt));
        }
        continue;
      }
      for (int y = 0; y < height; ++y) {
        KernelRow(padded.data() + (y + margin) * stride + margin, kt, width, row.data(),
                  tmp.data());
        for (int x = 0; x < width; ++x) AddWeighted(h, bins, row[x]);
      }
    }
  }

  Descriptor d;
  d.kind = DescriptorKind::kInvariantFeatureHistogram;
  d.panorama_width = width;
  d.features.resize(hist.size());
  for (std::size_t i = 0; i < n_hist; ++i) {
    double total = 0;
    for (int j = 0; j < bins; ++j) total += hist[i * bins + j];
    const double scale = total > 0 ? 1.0 / (total * static_cast<double>(n_hist)) : 0.0;
    for (int j = 0; j < bins; ++j)
      d.features[i * bins + j] = static_cast<float>(hist[i * bins + j] * scale);
  }
  OMNICML_CHECK(d.features.size() == FeatureSize());
  return d;
}

double InvariantFeatureHistogram::Intersection(const float* a, const float* b, std::size_t n) {
  // [W] eq. (5): normalised histogram intersection.
  const internal::IntersectionSums s = internal::SumMinimum(a, b, n);
  const float denom = std::max(s.a_sum, s.b_sum);
  if (!(denom > 0)) return 1.0;  // two empty histograms are equal
  return std::clamp(static_cast<double>(s.min_sum) / denom, 0.0, 1.0);
}

double InvariantFeatureHistogram::Distance(const float* a, const float* b, std::size_t n) const {
  return 1.0 - Intersection(a, b, n);
}

}  // namespace omnicml
