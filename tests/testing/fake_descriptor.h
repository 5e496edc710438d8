// A test-only DescriptorExtractor for hand-made reference views with controlled
// distances and headings.
//
// Features are arbitrary float vectors; Distance is their Euclidean (L2) distance, so a
// test chooses E exactly by placing feature points. For a heading-providing fake
// (kind kFourier) each descriptor carries its panorama orientation theta as
// coefficients[0] = exp(i theta), and RelativeHeading(a, b) = wrap(theta_a - theta_b);
// the histogram fake (kind kColorHistogram) has no heading (nullopt). Compute() is not
// supported (tests build descriptors with MakeFakeDescriptor).
#ifndef OMNICML_TESTS_TESTING_FAKE_DESCRIPTOR_H_
#define OMNICML_TESTS_TESTING_FAKE_DESCRIPTOR_H_

#include <cmath>
#include <complex>
#include <memory>
#include <optional>
#include <vector>

#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor.h"

namespace omnicml::testing {

class FakeDescriptorExtractor : public DescriptorExtractor {
 public:
  FakeDescriptorExtractor(std::size_t feature_size, bool provides_heading)
      : feature_size_(feature_size), provides_heading_(provides_heading) {}

  DescriptorKind kind() const override {
    return provides_heading_ ? DescriptorKind::kFourier : DescriptorKind::kColorHistogram;
  }
  Descriptor Compute(const cv::Mat&) const override {
    throw Error("FakeDescriptorExtractor::Compute is not supported");
  }
  double Distance(const float* a, const float* b, std::size_t n) const override {
    double sum = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      const double d = static_cast<double>(a[i]) - static_cast<double>(b[i]);
      sum += d * d;
    }
    return std::sqrt(sum);
  }
  // Descriptor form, defined here so tests need not link the descriptor library.
  double Distance(const Descriptor& a, const Descriptor& b) const {
    OMNICML_CHECK(a.features.size() == b.features.size());
    return Distance(a.features.data(), b.features.data(), a.features.size());
  }
  bool ProvidesHeading() const override { return provides_heading_; }
  std::optional<double> RelativeHeading(const Descriptor& a, const Descriptor& b) const override {
    if (!provides_heading_ || a.coefficients.empty() || b.coefficients.empty()) return std::nullopt;
    return WrapAngle(static_cast<double>(std::arg(a.coefficients[0])) -
                     static_cast<double>(std::arg(b.coefficients[0])));
  }
  std::size_t FeatureSize() const override { return feature_size_; }

  // A descriptor of this extractor's kind with the given features and orientation.
  Descriptor Make(const std::vector<float>& features, double orientation_rad = 0.0) const {
    Descriptor d;
    d.kind = kind();
    d.features = features;
    if (provides_heading_) {
      d.coefficients = {std::polar(1.0f, static_cast<float>(orientation_rad))};
    }
    d.panorama_width = 360;
    return d;
  }

 private:
  std::size_t feature_size_;
  bool provides_heading_;
};

inline std::shared_ptr<FakeDescriptorExtractor> MakeFakeExtractor(std::size_t feature_size,
                                                                  bool provides_heading = true) {
  return std::make_shared<FakeDescriptorExtractor>(feature_size, provides_heading);
}

}  // namespace omnicml::testing

#endif  // OMNICML_TESTS_TESTING_FAKE_DESCRIPTOR_H_
