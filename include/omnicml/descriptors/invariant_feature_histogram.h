// Invariant feature histogram [W] (docs/design.md "Descriptors"): a descriptor invariant to
// image rotation and (cyclic) translation, used by the MCL baseline.
//
// For a kernel f (a monomial: the product of pixel values at a few offsets q_1..q_d from
// the pixel) and the group of rotations g(x0, x1, phi) about pixel (x0, x1):
//   T[f](M)(x0, x1) = 1/P sum_{p=0}^{P-1} f(g(x0, x1, 2 pi p / P) M)        [W] eq. (2)
//                   = 1/P sum_p prod_j M((x0, x1) + s R(2 pi p / P) q_j),
// with pixel values in [0, 1], bilinear interpolation at non-integer positions and the
// kernel offsets scaled by s (the scale variants). The image is treated as a torus
// (columns and rows wrap), so a cyclic translation only permutes the T values and leaves
// their histogram unchanged; with P a multiple of 4 a 90-degree rotation maps the set of
// sample points onto itself, so the histogram is also unchanged by it (up to the
// interpolation's rounding). T values lie in [0, 1] and go into a weighted histogram of
// `bins` bins on [0, 1]: each value's unit weight is split linearly between the two
// nearest bin centres. One histogram per (colour channel, kernel, scale), each
// normalised to sum 1, joined in that order (channel-major, then kernel, then scale)
// and divided by their count, so the whole feature vector sums to 1.
//
// Similarity: the normalised intersection [W] eq. (5)
//   I(a, b) = sum_i min(a_i, b_i) / max(sum_i a_i, sum_i b_i)   (1 for a = b),
// and distance E = 1 - I, in [0, 1], zero only for equal vectors.
//
// Monte-Carlo sampling [W]: with sample_fraction < 1, T is evaluated only at
// round(fraction W H) pixels drawn uniformly (with replacement) by std::mt19937(seed),
// so the same image and seed give the same descriptor.
//
// Thread-safety: immutable after construction; Compute may run on any number of threads.
#ifndef OMNICML_DESCRIPTORS_INVARIANT_FEATURE_HISTOGRAM_H_
#define OMNICML_DESCRIPTORS_INVARIANT_FEATURE_HISTOGRAM_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <vector>

#include "omnicml/descriptors/descriptor.h"

namespace omnicml {

// A monomial kernel: the product of the pixel values at these offsets (x = column
// offset to the right, y = row offset downwards, pixels, before scaling/rotation).
struct IfhKernel {
  std::vector<cv::Point2d> offsets;
};

struct IfhOptions {
  // Kernels; default M(0,0)M(0,1) and M(0,3)M(4,0) as in [W]. Each has 1..4 offsets
  // with |offset| * max(scales) <= 16 pixels.
  std::vector<IfhKernel> kernels = {IfhKernel{{{0, 0}, {0, 1}}}, IfhKernel{{{0, 3}, {4, 0}}}};
  // Rotation angles P sampled over [0, 2 pi). 1..64; a multiple of 4 makes the
  // histogram invariant to 90-degree rotations of the image.
  int angles = 8;
  // Histogram bins per (channel, kernel, scale) on [0, 1]. 2..1024.
  int bins = 16;
  // Scale variants s: kernel offsets multiplied by s. Each in [0.25, 2]; not empty.
  std::vector<double> scales = {1.0};
  // true: three colour channels (B, G, R; grey input is replicated); false: one grey
  // channel (colour input converted to grey).
  bool color = true;
  // Fraction of pixels at which T is evaluated, (0, 1]; 1 evaluates every pixel.
  double sample_fraction = 1.0;
  // Seed of the Monte-Carlo pixel sampling (used only when sample_fraction < 1).
  std::uint32_t seed = 42;
  // Column normalisation before the kernels (not in [W]): every pixel of column c (all
  // channels) is multiplied by 0.5 / (the column's mean value in [0, 1] over its rows and
  // channels, floored at 1e-3) and clipped to [0, 1], so a column's mean maps to
  // mid-grey; computed on the 8-bit values in integers, so a gain common to a column
  // cancels exactly. A light switched or a curtain drawn scales a sector of the panorama
  // by a factor nearly constant along each column (as for FourierOptions::
  // normalize_columns); the division removes it. Invariant to a column roll, so the
  // descriptor keeps its rotation invariance. Used by `omnicml mcl
  // --ifh-normalize-columns` (for worlds whose lights switch between days, e.g. institute).
  bool normalize_columns = false;

  // Throws omnicml::Error naming the field when a value is out of range.
  void Validate() const;
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
// IfhOptions::kernels in YAML: a list of kernels, each a list of [x, y] offsets.
template <class V>
void VisitFields(V& v, IfhOptions& o) {
  using Offsets = std::vector<std::vector<std::array<double, 2>>>;
  v.template Converted<Offsets>(
      "kernels", o.kernels,
      [](const std::vector<IfhKernel>& kernels) {
        Offsets rep;
        for (const IfhKernel& k : kernels) {
          rep.emplace_back();
          for (const cv::Point2d& p : k.offsets) rep.back().push_back({p.x, p.y});
        }
        return rep;
      },
      [](const Offsets& rep) {
        std::vector<IfhKernel> kernels;
        for (const auto& k : rep) {
          kernels.emplace_back();
          for (const auto& p : k) kernels.back().offsets.emplace_back(p[0], p[1]);
        }
        return kernels;
      });
  v("angles", o.angles);
  v("bins", o.bins);
  v("scales", o.scales);
  v("color", o.color);
  v("sample_fraction", o.sample_fraction);
  v("seed", o.seed);
  v("normalize_columns", o.normalize_columns);
}

class InvariantFeatureHistogram final : public DescriptorExtractor {
 public:
  // Throws omnicml::Error if the options are invalid.
  explicit InvariantFeatureHistogram(const IfhOptions& options = {});

  DescriptorKind kind() const override { return DescriptorKind::kInvariantFeatureHistogram; }

  // Image: CV_8UC1 or CV_8UC3, at least 2 x 2 pixels. Throws omnicml::Error otherwise.
  Descriptor Compute(const cv::Mat& panorama) const override;

  // E = 1 - normalised intersection (file comment). n > 0.
  double Distance(const float* a, const float* b, std::size_t n) const override;
  using DescriptorExtractor::Distance;

  // Normalised intersection I(a, b) in [0, 1] ([W] eq. (5)).
  static double Intersection(const float* a, const float* b, std::size_t n);

  // Histograms carry no rotation information.
  bool ProvidesHeading() const override { return false; }
  std::optional<double> RelativeHeading(const Descriptor&, const Descriptor&) const override {
    return std::nullopt;
  }

  std::size_t FeatureSize() const override;

  const IfhOptions& options() const { return options_; }

 private:
  IfhOptions options_;
};

}  // namespace omnicml

#endif  // OMNICML_DESCRIPTORS_INVARIANT_FEATURE_HISTOGRAM_H_
