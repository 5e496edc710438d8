// Tests of the common descriptor interface: serialisation, the factory, the checked
// distance, similarity, RollColumns and the synthetic panorama.
#include "omnicml/descriptors/descriptor.h"

#include <random>

#include <gtest/gtest.h>

#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"

namespace omnicml {
namespace {

std::vector<DescriptorOptions> AllKinds() {
  std::vector<DescriptorOptions> all(3);
  all[0].kind = DescriptorKind::kFourier;
  all[1].kind = DescriptorKind::kInvariantFeatureHistogram;
  all[2].kind = DescriptorKind::kColorHistogram;
  return all;
}

// Serialize then Deserialize returns an equal descriptor, for every kind.
TEST(Descriptor, SerialisationRoundTrip) {
  const cv::Mat pano = MakeSyntheticPanorama(240, 40, 2);
  for (const auto& options : AllKinds()) {
    const auto extractor = MakeDescriptorExtractor(options);
    const Descriptor d = extractor->Compute(pano);
    EXPECT_EQ(d.kind, options.kind);
    EXPECT_EQ(d.features.size(), extractor->FeatureSize());
    EXPECT_EQ(d.panorama_width, 240);
    const auto bytes = Serialize(d);
    EXPECT_EQ(Deserialize(bytes), d) << ToString(options.kind);
  }
  Descriptor empty;  // also the degenerate descriptor
  EXPECT_EQ(Deserialize(Serialize(empty)), empty);
}

// Every truncation and any single flipped bit of a buffer is rejected with omnicml::Error.
TEST(Descriptor, DeserializeRejectsTruncatedAndGarbledBuffers) {
  const FourierSignature fs({2, 4, FourierDistance::kL2, true});
  const auto bytes = Serialize(fs.Compute(MakeSyntheticPanorama(64, 16, 3)));
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    EXPECT_THROW(Deserialize(std::span(bytes.data(), n)), Error) << "length " << n;
  }
  auto longer = bytes;
  longer.push_back(0);
  EXPECT_THROW(Deserialize(longer), Error);
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    for (int bit : {0, 5}) {
      auto garbled = bytes;
      garbled[i] ^= static_cast<std::uint8_t>(1u << bit);
      EXPECT_THROW(Deserialize(garbled), Error) << "byte " << i << " bit " << bit;
    }
  }
}

// The factory builds the requested kind and validates its options with the field name.
TEST(DescriptorFactory, BuildsRequestedKindAndValidates) {
  for (const auto& options : AllKinds()) {
    const auto extractor = MakeDescriptorExtractor(options);
    EXPECT_EQ(extractor->kind(), options.kind);
    EXPECT_EQ(extractor->ProvidesHeading(), options.kind == DescriptorKind::kFourier);
  }
  DescriptorOptions bad;
  bad.fourier.coefficients = 0;
  try {
    MakeDescriptorExtractor(bad);
    FAIL() << "expected omnicml::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("coefficients"), std::string::npos) << e.what();
  }
  // Options of an unselected kind are not validated.
  bad.kind = DescriptorKind::kColorHistogram;
  EXPECT_NO_THROW(MakeDescriptorExtractor(bad));
  bad.color.filter_width = 4;
  EXPECT_THROW(MakeDescriptorExtractor(bad), Error);
}

// Kind names round-trip; an unknown name is an error.
TEST(Descriptor, KindNames) {
  for (const auto& options : AllKinds()) {
    EXPECT_EQ(DescriptorKindFromString(ToString(options.kind)), options.kind);
  }
  EXPECT_THROW(DescriptorKindFromString("sift"), Error);
}

// Histograms say they cannot give a heading and return nullopt rather than 0.
TEST(Descriptor, HistogramsGiveNoHeading) {
  const cv::Mat pano = MakeSyntheticPanorama(240, 40, 4);
  for (const auto& options : AllKinds()) {
    if (options.kind == DescriptorKind::kFourier) continue;
    const auto extractor = MakeDescriptorExtractor(options);
    const Descriptor a = extractor->Compute(pano), b = extractor->Compute(RollColumns(pano, 30));
    EXPECT_FALSE(extractor->ProvidesHeading());
    EXPECT_FALSE(extractor->RelativeHeading(a, b).has_value());
  }
}

// The checked distance rejects mixed kinds and lengths; it is 0 for equal inputs.
TEST(Descriptor, CheckedDistance) {
  const cv::Mat pano = MakeSyntheticPanorama(240, 40, 5);
  const auto fourier = MakeDescriptorExtractor({});
  DescriptorOptions color_options;
  color_options.kind = DescriptorKind::kColorHistogram;
  const auto color = MakeDescriptorExtractor(color_options);
  const Descriptor f = fourier->Compute(pano), c = color->Compute(pano);
  EXPECT_EQ(fourier->Distance(f, f), 0.0);
  EXPECT_EQ(color->Distance(c, c), 0.0);
  EXPECT_THROW(fourier->Distance(f, c), Error);
  Descriptor shorter = f;
  shorter.features.pop_back();
  EXPECT_THROW(fourier->Distance(f, shorter), Error);
}

// S = max(0, 1 - E / E_max): 1 at 0, 0 at and beyond E_max; E_max must be positive.
TEST(Descriptor, Similarity) {
  EXPECT_EQ(DescriptorExtractor::Similarity(0.0, 2.0), 1.0);
  EXPECT_DOUBLE_EQ(DescriptorExtractor::Similarity(0.5, 2.0), 0.75);
  EXPECT_EQ(DescriptorExtractor::Similarity(2.0, 2.0), 0.0);
  EXPECT_EQ(DescriptorExtractor::Similarity(5.0, 2.0), 0.0);
  EXPECT_THROW(DescriptorExtractor::Similarity(1.0, 0.0), Error);
}

// RollColumns follows the panorama convention out[c] = in[(c + k) mod W].
TEST(Descriptor, RollColumnsConvention) {
  cv::Mat in(2, 5, CV_8UC1);
  for (int c = 0; c < 5; ++c)
    in.at<std::uint8_t>(0, c) = in.at<std::uint8_t>(1, c) = static_cast<std::uint8_t>(c);
  for (int k : {-7, -1, 0, 2, 5, 13}) {
    const cv::Mat out = RollColumns(in, k);
    for (int c = 0; c < 5; ++c) {
      EXPECT_EQ(out.at<std::uint8_t>(1, c), in.at<std::uint8_t>(1, ((c + k) % 5 + 5) % 5)) << k;
    }
  }
  EXPECT_THROW(RollColumns(cv::Mat(), 1), Error);
}

// The synthetic panorama is deterministic per seed and differs between seeds.
TEST(Descriptor, SyntheticPanoramaIsSeeded) {
  const cv::Mat a = MakeSyntheticPanorama(720, 120, 1), b = MakeSyntheticPanorama(720, 120, 1);
  const cv::Mat c = MakeSyntheticPanorama(720, 120, 2);
  EXPECT_EQ(a.type(), CV_8UC3);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_L1), 0.0);
  EXPECT_GT(cv::norm(a, c, cv::NORM_L1), 0.0);
  EXPECT_THROW(MakeSyntheticPanorama(4, 4, 1), Error);
}

}  // namespace
}  // namespace omnicml
