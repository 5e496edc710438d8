#include "omnicml/descriptors/fourier_signature.h"

#include <fftw3.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <mutex>

#include <opencv2/imgproc.hpp>

#include "descriptors/internal/descriptor_util.h"
#include "omnicml/common/common.h"

namespace omnicml {
namespace {

// Process-wide FFTW plans, one per (direction, size). The FFTW planner is not
// thread-safe, so creation happens under one mutex; execution through the new-array
// interface (fftwf_execute_dft_r2c / _c2r) is thread-safe. Plans live until exit.
class PlanCache {
 public:
  static PlanCache& Get() {
    static PlanCache* cache = new PlanCache;  // never destroyed: no exit-order issues
    return *cache;
  }
  fftwf_plan Forward(int n) { return Find(n, true); }
  fftwf_plan Inverse(int n) { return Find(n, false); }

 private:
  fftwf_plan Find(int n, bool forward) {
    std::lock_guard<std::mutex> lock(mu_);
    auto& plans = forward ? forward_ : inverse_;
    auto it = plans.find(n);
    if (it != plans.end()) return it->second;
    // Plan on fftwf_malloc'd arrays so that every per-call buffer (also fftwf_malloc'd)
    // has the alignment the plan assumes. FFTW_ESTIMATE: deterministic plan choice.
    float* real = fftwf_alloc_real(static_cast<std::size_t>(n));
    fftwf_complex* spectrum = fftwf_alloc_complex(static_cast<std::size_t>(n / 2 + 1));
    fftwf_plan plan = forward ? fftwf_plan_dft_r2c_1d(n, real, spectrum, FFTW_ESTIMATE)
                              : fftwf_plan_dft_c2r_1d(n, spectrum, real, FFTW_ESTIMATE);
    fftwf_free(real);
    fftwf_free(spectrum);
    OMNICML_CHECK(plan != nullptr) << "FFTW could not plan a transform of size " << n;
    plans.emplace(n, plan);
    return plan;
  }

  std::mutex mu_;
  std::map<int, fftwf_plan> forward_, inverse_;
};

struct FftwFree {
  void operator()(void* p) const { fftwf_free(p); }
};
using RealBuffer = std::unique_ptr<float[], FftwFree>;
using ComplexBuffer = std::unique_ptr<fftwf_complex[], FftwFree>;

RealBuffer AllocReal(int n) { return RealBuffer(fftwf_alloc_real(static_cast<std::size_t>(n))); }
ComplexBuffer AllocComplex(int n) {
  return ComplexBuffer(fftwf_alloc_complex(static_cast<std::size_t>(n)));
}

// Zero mean, unit variance over the valid entries of s (valid[c] != 0); invalid entries
// become 0 (the mean). Without `normalize`, invalid entries become the valid mean.
void NormalizeValid(float* s, const std::vector<char>& valid, bool normalize) {
  const int width = static_cast<int>(valid.size());
  double mean = 0, var = 0;
  int n = 0;
  for (int c = 0; c < width; ++c) {
    if (!valid[c]) continue;
    mean += s[c];
    ++n;
  }
  mean = n > 0 ? mean / n : 0.0;
  if (!normalize) {
    for (int c = 0; c < width; ++c) {
      if (!valid[c]) s[c] = static_cast<float>(mean);
    }
    return;
  }
  for (int c = 0; c < width; ++c) {
    if (valid[c]) var += (s[c] - mean) * (s[c] - mean);
  }
  var = n > 0 ? var / n : 0.0;
  const double inv_std = var > 1e-14 ? 1.0 / std::sqrt(var) : 0.0;
  for (int c = 0; c < width; ++c) {
    s[c] = valid[c] ? static_cast<float>((s[c] - mean) * inv_std) : 0.0f;
  }
}

}  // namespace

cv::Mat FourierSignature::MaskedBandSignals(const cv::Mat& panorama,
                                            const cv::Mat& valid_mask) const {
  cv::Mat grey;
  if (panorama.channels() == 3) {
    cv::cvtColor(panorama, grey, cv::COLOR_BGR2GRAY);
  } else {
    grey = panorama;
  }
  const int width = grey.cols, height = grey.rows, bands = options_.bands;
  const std::size_t w = static_cast<std::size_t>(width);
  std::vector<std::uint32_t> sums(static_cast<std::size_t>(bands) * w, 0u);
  std::vector<std::uint32_t> counts(sums.size(), 0u);
  for (int b = 0; b < bands; ++b) {
    std::uint32_t* band_sums = sums.data() + static_cast<std::size_t>(b) * w;
    std::uint32_t* band_counts = counts.data() + static_cast<std::size_t>(b) * w;
    for (int r = b * height / bands; r < (b + 1) * height / bands; ++r) {
      const std::uint8_t* row = grey.ptr<std::uint8_t>(r);
      const std::uint8_t* m = valid_mask.ptr<std::uint8_t>(r);
      // Branch-free (vectorises): v = 1 for a valid pixel, 0 for an invalid one.
      for (int c = 0; c < width; ++c) {
        const std::uint32_t v = m[c] != 0;
        band_sums[c] += row[c] * v;
        band_counts[c] += v;
      }
    }
  }
  // Column gain from the column's valid pixels (as BandSignals, floored at 1e-3).
  std::vector<double> column_gain(w, 1.0);
  if (options_.normalize_columns) {
    for (std::size_t c = 0; c < w; ++c) {
      std::uint64_t sum = 0, count = 0;
      for (int b = 0; b < bands; ++b) {
        sum += sums[b * w + c];
        count += counts[b * w + c];
      }
      if (count > 0) column_gain[c] = 1.0 / std::max(sum / (255.0 * count), 1e-3);
    }
  }
  cv::Mat signals(bands, width, CV_32FC1);
  std::vector<char> valid(w);
  for (int b = 0; b < bands; ++b) {
    float* s = signals.ptr<float>(b);
    for (std::size_t c = 0; c < w; ++c) {
      const std::uint32_t n = counts[b * w + c];
      valid[c] = n > 0;
      s[c] = n > 0 ? static_cast<float>(sums[b * w + c] / (255.0 * n) * column_gain[c]) : 0.0f;
    }
    NormalizeValid(s, valid, options_.normalize_bands);
  }
  return signals;
}

Descriptor FourierSignature::ComputeMasked(const cv::Mat& panorama,
                                           const cv::Mat& valid_mask) const {
  return Spectrum(BandSignals(panorama, valid_mask));
}

std::string ToString(FourierDistance d) { return d == FourierDistance::kL1 ? "l1" : "l2"; }

FourierDistance FourierDistanceFromString(const std::string& s) {
  if (s == "l1") return FourierDistance::kL1;
  if (s == "l2") return FourierDistance::kL2;
  throw Error(StrCat("unknown Fourier distance '", s, "' (expected l1 or l2)"));
}

void FourierOptions::Validate() const {
  if (bands < 1 || bands > 64)
    throw Error(StrCat("FourierOptions.bands must be in 1..64, got ", bands));
  if (coefficients < 1 || coefficients > 1024) {
    throw Error(StrCat("FourierOptions.coefficients must be in 1..1024, got ", coefficients));
  }
  if (distance != FourierDistance::kL1 && distance != FourierDistance::kL2) {
    throw Error("FourierOptions.distance must be l1 or l2");
  }
}

FourierSignature::FourierSignature(const FourierOptions& options) : options_(options) {
  options_.Validate();
}

cv::Mat FourierSignature::BandSignals(const cv::Mat& panorama, const cv::Mat& valid_mask) const {
  const int min_width = 2 * (options_.first_harmonic() + options_.coefficients);
  internal::CheckDescriptorInput(panorama, "FourierSignature", min_width, options_.bands);
  if (!valid_mask.empty()) {
    internal::CheckValidMask(panorama, valid_mask);
    if (cv::countNonZero(valid_mask) < valid_mask.rows * valid_mask.cols)
      return MaskedBandSignals(panorama, valid_mask);
  }
  cv::Mat grey;
  if (panorama.channels() == 3) {
    cv::cvtColor(panorama, grey, cv::COLOR_BGR2GRAY);
  } else {
    grey = panorama;
  }
  const int width = grey.cols, height = grey.rows, bands = options_.bands;
  cv::Mat signals(bands, width, CV_32FC1);
  // Integer row sums per band (bands partition the rows): exact, so a column roll
  // permutes them exactly.
  const std::size_t w = static_cast<std::size_t>(width);
  std::vector<std::uint32_t> band_sums(static_cast<std::size_t>(bands) * w, 0u);
  for (int b = 0; b < bands; ++b) {
    std::uint32_t* sums = band_sums.data() + static_cast<std::size_t>(b) * w;
    for (int r = b * height / bands; r < (b + 1) * height / bands; ++r) {
      const std::uint8_t* row = grey.ptr<std::uint8_t>(r);
      for (int c = 0; c < width; ++c) sums[c] += row[c];
    }
  }
  // Column normalisation: the gain 1 / (mean brightness of column c over the whole
  // height, the sum of its band sums), the brightness floored at 1e-3 of full scale so a
  // black column does not blow up.
  std::vector<double> column_gain(w, 1.0);
  if (options_.normalize_columns) {
    const double scale = 1.0 / (255.0 * height);
    for (std::size_t c = 0; c < w; ++c) {
      std::uint32_t column_sum = 0;
      for (int b = 0; b < bands; ++b) column_sum += band_sums[static_cast<std::size_t>(b) * w + c];
      column_gain[c] = 1.0 / std::max(column_sum * scale, 1e-3);
    }
  }
  for (int b = 0; b < bands; ++b) {
    const int r0 = b * height / bands, r1 = (b + 1) * height / bands;
    const std::uint32_t* sums = band_sums.data() + static_cast<std::size_t>(b) * w;
    float* s = signals.ptr<float>(b);
    const double scale = 1.0 / (255.0 * (r1 - r0));
    for (int c = 0; c < width; ++c) s[c] = static_cast<float>(sums[c] * scale * column_gain[c]);
    if (options_.normalize_bands) {
      // Zero mean, unit variance: a gain g and offset o of the brightness (s -> g s + o)
      // leave the normalised signal unchanged.
      double mean = 0, var = 0;
      for (int c = 0; c < width; ++c) mean += s[c];
      mean /= width;
      for (int c = 0; c < width; ++c) var += (s[c] - mean) * (s[c] - mean);
      var /= width;
      const double inv_std = var > 1e-14 ? 1.0 / std::sqrt(var) : 0.0;
      for (int c = 0; c < width; ++c) s[c] = static_cast<float>((s[c] - mean) * inv_std);
    }
  }
  return signals;
}

Descriptor FourierSignature::Compute(const cv::Mat& panorama) const {
  return Spectrum(BandSignals(panorama));
}

Descriptor FourierSignature::Spectrum(const cv::Mat& signals) const {
  const int width = signals.cols, bands = options_.bands, k = options_.coefficients;
  const int m0 = options_.first_harmonic();
  fftwf_plan plan = PlanCache::Get().Forward(width);
  RealBuffer in = AllocReal(width);
  ComplexBuffer out = AllocComplex(width / 2 + 1);
  Descriptor d;
  d.kind = DescriptorKind::kFourier;
  d.panorama_width = width;
  d.features.resize(FeatureSize());
  d.coefficients.resize(FeatureSize());
  const float inv_width = 1.0f / static_cast<float>(width);
  for (int b = 0; b < bands; ++b) {
    std::copy_n(signals.ptr<float>(b), width, in.get());
    fftwf_execute_dft_r2c(plan, in.get(), out.get());
    for (int j = 0; j < k; ++j) {
      const int m = m0 + j;
      const std::complex<float> c(out[m][0] * inv_width, out[m][1] * inv_width);
      d.coefficients[b * k + j] = c;
      d.features[b * k + j] = std::abs(c);
    }
  }
  return d;
}

double FourierSignature::Distance(const float* a, const float* b, std::size_t n) const {
  if (options_.distance == FourierDistance::kL1) return internal::SumAbsoluteDifference(a, b, n);
  return std::sqrt(internal::SumSquaredDifference(a, b, n));
}

std::optional<double> FourierSignature::RelativeShiftColumns(const Descriptor& a,
                                                             const Descriptor& b) const {
  const std::size_t expected = FeatureSize();
  for (const Descriptor* d : {&a, &b}) {
    if (d->kind != DescriptorKind::kFourier || d->coefficients.size() != expected) {
      throw Error(StrCat("RelativeHeading: expected a Fourier descriptor with ", expected,
                         " coefficients (", options_.bands, " bands x ", options_.coefficients,
                         "), got a ", ToString(d->kind), " descriptor with ",
                         d->coefficients.size()));
    }
  }
  if (a.panorama_width != b.panorama_width) {
    throw Error(StrCat("RelativeHeading: panorama widths differ (", a.panorama_width, " vs ",
                       b.panorama_width, ")"));
  }
  const int width = a.panorama_width, k = options_.coefficients, m0 = options_.first_harmonic();
  if (width < 2 * (m0 + k)) {
    throw Error(
        StrCat("RelativeHeading: panorama width ", width, " too small for ", k, " coefficients"));
  }
  // Cross-power spectrum summed over bands: R[m] = sum_b conj(A_b[m]) B_b[m]; its
  // inverse transform is r[n] = sum_b sum_c a_b[c] b_b[c + n] (up to a positive scale).
  // Accumulated in double, rounded once.
  ComplexBuffer spectrum = AllocComplex(width / 2 + 1);
  for (int m = 0; m <= width / 2; ++m) spectrum[m][0] = spectrum[m][1] = 0.0f;
  for (int j = 0; j < k; ++j) {
    std::complex<double> sum = 0;
    for (int band = 0; band < options_.bands; ++band) {
      const std::complex<double> ca = a.coefficients[band * k + j];
      const std::complex<double> cb = b.coefficients[band * k + j];
      sum += std::conj(ca) * cb;
    }
    spectrum[m0 + j][0] = static_cast<float>(sum.real());
    spectrum[m0 + j][1] = static_cast<float>(sum.imag());
  }
  RealBuffer corr = AllocReal(width);
  // c2r treats the half spectrum as conjugate-symmetric: the padding to width W.
  fftwf_execute_dft_c2r(PlanCache::Get().Inverse(width), spectrum.get(), corr.get());
  const float* r = corr.get();
  const auto [min_it, max_it] = std::minmax_element(r, r + width);
  const float scale = std::max(std::fabs(*min_it), std::fabs(*max_it));
  if (!(scale > 0) || *max_it - *min_it <= 1e-6f * scale) return std::nullopt;  // flat
  const int n = static_cast<int>(max_it - r);
  const double y0 = r[(n + width - 1) % width], y1 = r[n], y2 = r[(n + 1) % width];
  // Parabola through the peak and its neighbours: vertex offset in (-0.5, 0.5).
  const double curvature = y0 - 2.0 * y1 + y2;
  double delta = curvature < 0 ? 0.5 * (y0 - y2) / curvature : 0.0;
  delta = std::clamp(delta, -0.5, 0.5);
  double shift = n + delta;
  if (shift < 0) shift += width;
  if (shift >= width) shift -= width;
  return shift;
}

std::optional<double> FourierSignature::RelativeHeading(const Descriptor& a,
                                                        const Descriptor& b) const {
  const auto shift = RelativeShiftColumns(a, b);
  if (!shift) return std::nullopt;
  return WrapAngle(kTwoPi * *shift / a.panorama_width);
}

}  // namespace omnicml
