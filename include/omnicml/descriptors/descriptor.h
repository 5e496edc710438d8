// One interface for the three panorama descriptors, so the rest of the engine does not
// care which one it has.
//
// A Descriptor is a plain value: the feature vector that distances are computed on
// (Fourier magnitudes or histogram bins, all float, stored contiguously so a map can
// keep thousands of them in one array) plus, for descriptors that can estimate a
// rotation, the complex coefficients the relative heading is computed from.
//
// A DescriptorExtractor computes descriptors from panoramas (see omni_unwrapper.h for
// the panorama convention) and compares them. Extractors are immutable after
// construction and safe to use from several threads at once.
#ifndef OMNICML_DESCRIPTORS_DESCRIPTOR_H_
#define OMNICML_DESCRIPTORS_DESCRIPTOR_H_

#include <complex>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "omnicml/common/binary_io.h"

namespace omnicml {

enum class DescriptorKind : std::uint8_t {
  kFourier = 1,
  kInvariantFeatureHistogram = 2,
  kColorHistogram = 3,
};

// "fourier", "ifh", "color".
std::string ToString(DescriptorKind kind);
// Throws omnicml::Error on an unknown name.
DescriptorKind DescriptorKindFromString(const std::string& name);

struct Descriptor {
  DescriptorKind kind = DescriptorKind::kFourier;
  // The vector distances are computed on (magnitudes / concatenated histogram bins).
  std::vector<float> features;
  // Fourier only: the K stored complex coefficients of each band, band-major (bands x K;
  // which harmonics they are is documented in fourier_signature.h); empty for histograms.
  // Used by RelativeHeading.
  std::vector<std::complex<float>> coefficients;
  // Width in columns of the panorama it was computed from (heading resolution).
  int panorama_width = 0;

  bool operator==(const Descriptor&) const = default;
};

// Versioned little-endian byte encoding, independent of the host's byte order:
//   magic "OMDS" | u16 version (1) | u8 kind | u8 reserved (0) | i32 panorama_width |
//   u32 feature count | u32 coefficient count | f32 features... | (f32 re, f32 im)... |
//   u32 FNV-1a checksum of everything before it.
// Deserialize throws omnicml::Error on a truncated, garbled (checksum, magic, unknown
// kind or version, inconsistent sizes, trailing bytes) or otherwise malformed buffer.
std::vector<std::uint8_t> Serialize(const Descriptor& d);
Descriptor Deserialize(std::span<const std::uint8_t> bytes);

// Record encoding for descriptors inside a larger binary container (the environment
// model's map file), which carries its own magic, version and checksum:
//   u8 kind | u64 feature count | f32 features... | u64 coefficient count |
//   (f32 re, f32 im)... | i32 panorama_width
// (BinaryWriter's little-endian encoding). ReadDescriptor reports a truncated record, an
// unknown kind, non-finite values, coefficients on a histogram or a negative width
// through BinaryReader::Fail (omnicml::Error naming `what` and the offset).
void WriteDescriptorRecord(BinaryWriter& out, const Descriptor& d);
Descriptor ReadDescriptorRecord(BinaryReader& in);

class DescriptorExtractor {
 public:
  virtual ~DescriptorExtractor() = default;

  virtual DescriptorKind kind() const = 0;

  // Computes the descriptor of a panorama (CV_8UC1 or CV_8UC3). Throws omnicml::Error
  // on an empty, too small or wrongly typed image.
  virtual Descriptor Compute(const cv::Mat& panorama) const = 0;

  // The descriptor of a panorama of which only some pixels show the scene: `valid_mask`
  // (CV_8UC1 of the panorama's size; 0 = invalid: outside a clipped ring, the robot's own
  // body) or empty (all valid, same as Compute). Invalid pixels have no influence on the
  // result: changing them leaves the descriptor unchanged. Default (histograms): each
  // invalid pixel is replaced by the mean of the valid pixels of its row (of the whole
  // panorama when the row has none), so masked areas add no structure of their own; the
  // Fourier signature overrides it (fourier_signature.h). Throws omnicml::Error as Compute,
  // or when the mask has the wrong size/type or no valid pixel.
  virtual Descriptor ComputeMasked(const cv::Mat& panorama, const cv::Mat& valid_mask) const;

  // Distance E >= 0 between two feature vectors of equal length (0 for equal inputs).
  // The raw-pointer form serves contiguous storage of many descriptors: it is a tight,
  // vectorisable loop over plain floats (one virtual call per stored descriptor, none
  // per element) and does not check its arguments.
  virtual double Distance(const float* a, const float* b, std::size_t n) const = 0;
  // Checked form: throws omnicml::Error when the kinds differ from kind() or the feature
  // vectors have different lengths.
  double Distance(const Descriptor& a, const Descriptor& b) const;

  // Similarity S in [0, 1]: 1 at E = 0, falling linearly to 0 at E = e_max
  // (docs/design.md "Environment model"): S = max(0, 1 - E / e_max). Throws omnicml::Error
  // unless e_max > 0.
  static double Similarity(double distance, double e_max);

  // Whether RelativeHeading can give a rotation (Fourier: yes; histograms: no).
  virtual bool ProvidesHeading() const = 0;

  // The robot's heading at `a` minus its heading at `b`, radians in (-pi, pi], from the
  // circular cross-correlation of the two panoramas over azimuth. std::nullopt when the
  // descriptor carries no rotation information (histograms) — never a fake 0.
  virtual std::optional<double> RelativeHeading(const Descriptor& a, const Descriptor& b) const = 0;

  // Length of the feature vector this extractor produces.
  virtual std::size_t FeatureSize() const = 0;
};

// The panorama with each invalid pixel (0 in `valid_mask`, CV_8UC1 of the panorama's size)
// replaced by the mean of the valid pixels of its row, or of the whole panorama when the
// row has none: masked areas then carry no structure of their own, and whatever they held
// has no influence on the result. Returns the panorama itself (not a copy) when the mask is
// empty or all valid. Throws omnicml::Error when the mask has the wrong size/type or no
// valid pixel. What DescriptorExtractor::ComputeMasked does by default.
cv::Mat FillInvalidPixels(const cv::Mat& panorama, const cv::Mat& valid_mask);

// Rolls a panorama by k columns (any integer, negative allowed):
//   out[c] = in[(c + k) mod W],
// i.e. the view after a counter-clockwise turn by k * 2 pi / W (omni_unwrapper.h).
// Any type; throws omnicml::Error on an empty image.
cv::Mat RollColumns(const cv::Mat& panorama, int k);

// A procedural, seeded colour panorama (CV_8UC3, width x height) with sky, ground and
// a ring of coloured objects that wraps around in azimuth: a stand-in for a real view in
// tests, benchmarks and `omnicml describe --make-sample`. Same seed, same pixels.
// Throws omnicml::Error unless width >= 8 and height >= 4.
cv::Mat MakeSyntheticPanorama(int width, int height, std::uint32_t seed);

}  // namespace omnicml

#endif  // OMNICML_DESCRIPTORS_DESCRIPTOR_H_
