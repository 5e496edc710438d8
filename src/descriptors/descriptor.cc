#include "omnicml/descriptors/descriptor.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <random>

#include "descriptors/internal/descriptor_util.h"
#include "omnicml/common/common.h"

namespace omnicml {
namespace {

constexpr std::uint8_t kMagic[4] = {'O', 'M', 'D', 'S'};
constexpr std::uint16_t kVersion = 1;
// magic + version + kind + reserved + width + feature count + coefficient count.
constexpr std::size_t kHeaderBytes = 4 + 2 + 1 + 1 + 4 + 4 + 4;
constexpr std::size_t kChecksumBytes = 4;

// FNV-1a, 32 bit: cheap and good enough to catch corrupted buffers (not an HMAC).
std::uint32_t Fnv1a(const std::uint8_t* data, std::size_t n) {
  std::uint32_t h = 2166136261u;
  for (std::size_t i = 0; i < n; ++i) {
    h ^= data[i];
    h *= 16777619u;
  }
  return h;
}

void PutU32(std::vector<std::uint8_t>& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) out.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}
void PutF32(std::vector<std::uint8_t>& out, float v) {
  PutU32(out, std::bit_cast<std::uint32_t>(v));
}

std::uint32_t GetU32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}
float GetF32(const std::uint8_t* p) { return std::bit_cast<float>(GetU32(p)); }

bool IsKnownKind(std::uint8_t k) {
  return k == static_cast<std::uint8_t>(DescriptorKind::kFourier) ||
         k == static_cast<std::uint8_t>(DescriptorKind::kInvariantFeatureHistogram) ||
         k == static_cast<std::uint8_t>(DescriptorKind::kColorHistogram);
}

}  // namespace

std::string ToString(DescriptorKind kind) {
  switch (kind) {
    case DescriptorKind::kFourier:
      return "fourier";
    case DescriptorKind::kInvariantFeatureHistogram:
      return "ifh";
    case DescriptorKind::kColorHistogram:
      return "color";
  }
  return StrCat("unknown(", static_cast<int>(kind), ")");
}

DescriptorKind DescriptorKindFromString(const std::string& name) {
  if (name == "fourier") return DescriptorKind::kFourier;
  if (name == "ifh") return DescriptorKind::kInvariantFeatureHistogram;
  if (name == "color") return DescriptorKind::kColorHistogram;
  throw Error(StrCat("unknown descriptor kind '", name, "' (expected fourier, ifh or color)"));
}

std::vector<std::uint8_t> Serialize(const Descriptor& d) {
  std::vector<std::uint8_t> out;
  out.reserve(kHeaderBytes + 4 * d.features.size() + 8 * d.coefficients.size() + kChecksumBytes);
  for (std::uint8_t m : kMagic) out.push_back(m);
  out.push_back(static_cast<std::uint8_t>(kVersion & 0xff));
  out.push_back(static_cast<std::uint8_t>(kVersion >> 8));
  out.push_back(static_cast<std::uint8_t>(d.kind));
  out.push_back(0);
  PutU32(out, static_cast<std::uint32_t>(d.panorama_width));
  PutU32(out, static_cast<std::uint32_t>(d.features.size()));
  PutU32(out, static_cast<std::uint32_t>(d.coefficients.size()));
  for (float f : d.features) PutF32(out, f);
  for (const auto& c : d.coefficients) {
    PutF32(out, c.real());
    PutF32(out, c.imag());
  }
  PutU32(out, Fnv1a(out.data(), out.size()));
  return out;
}

void WriteDescriptorRecord(BinaryWriter& out, const Descriptor& d) {
  out.Write(d.kind);
  out.WriteVector(d.features);
  out.Write<std::uint64_t>(d.coefficients.size());
  for (const std::complex<float>& c : d.coefficients) {
    out.Write(c.real());
    out.Write(c.imag());
  }
  out.Write<std::int32_t>(d.panorama_width);
}

Descriptor ReadDescriptorRecord(BinaryReader& in) {
  Descriptor d;
  const auto kind = in.Read<std::uint8_t>("descriptor kind");
  if (!IsKnownKind(kind)) in.Fail("descriptor kind", StrCat("invalid descriptor kind ", int{kind}));
  d.kind = static_cast<DescriptorKind>(kind);
  d.features = in.ReadVector<float>("descriptor features");
  for (const float f : d.features) {
    if (!std::isfinite(f)) in.Fail("descriptor features", "non-finite feature value");
  }
  const std::size_t n = in.ReadCount("descriptor coefficients", 8);
  if (n != 0 && d.kind != DescriptorKind::kFourier) {
    in.Fail("descriptor coefficients",
            StrCat("a ", ToString(d.kind), " descriptor cannot carry coefficients"));
  }
  d.coefficients.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const float re = in.Read<float>("descriptor coefficient");
    const float im = in.Read<float>("descriptor coefficient");
    if (!std::isfinite(re) || !std::isfinite(im)) {
      in.Fail("descriptor coefficient", "non-finite coefficient");
    }
    d.coefficients.emplace_back(re, im);
  }
  d.panorama_width = in.Read<std::int32_t>("descriptor panorama width");
  if (d.panorama_width < 0) {
    in.Fail("descriptor panorama width", StrCat("negative panorama width ", d.panorama_width));
  }
  return d;
}

Descriptor Deserialize(std::span<const std::uint8_t> bytes) {
  const std::size_t n = bytes.size();
  if (n < kHeaderBytes + kChecksumBytes) {
    throw Error(StrCat("descriptor buffer truncated: ", n, " bytes, the header alone needs ",
                       kHeaderBytes + kChecksumBytes));
  }
  const std::uint8_t* p = bytes.data();
  if (std::memcmp(p, kMagic, 4) != 0) throw Error("descriptor buffer: bad magic (not 'OMDS')");
  const std::uint16_t version = static_cast<std::uint16_t>(p[4] | (p[5] << 8));
  if (version != kVersion) {
    throw Error(StrCat("descriptor buffer: unsupported version ", version, " (this build reads ",
                       kVersion, ")"));
  }
  if (!IsKnownKind(p[6])) throw Error(StrCat("descriptor buffer: unknown kind ", int{p[6]}));
  if (p[7] != 0) throw Error("descriptor buffer: reserved byte is not 0");
  const auto width = static_cast<std::int32_t>(GetU32(p + 8));
  const std::uint64_t n_features = GetU32(p + 12);
  const std::uint64_t n_coefficients = GetU32(p + 16);
  const std::uint64_t expected =
      kHeaderBytes + 4 * n_features + 8 * n_coefficients + kChecksumBytes;
  if (expected != n) {
    throw Error(StrCat("descriptor buffer: ", n, " bytes but the header announces ", n_features,
                       " features and ", n_coefficients, " coefficients (", expected,
                       " bytes); truncated or garbled"));
  }
  if (GetU32(p + n - kChecksumBytes) != Fnv1a(p, n - kChecksumBytes)) {
    throw Error("descriptor buffer: checksum mismatch (garbled data)");
  }
  if (width < 0) throw Error(StrCat("descriptor buffer: negative panorama width ", width));
  Descriptor d;
  d.kind = static_cast<DescriptorKind>(p[6]);
  if (d.kind != DescriptorKind::kFourier && n_coefficients != 0) {
    throw Error(
        StrCat("descriptor buffer: a ", ToString(d.kind), " descriptor cannot carry coefficients"));
  }
  d.panorama_width = width;
  d.features.resize(n_features);
  d.coefficients.resize(n_coefficients);
  const std::uint8_t* q = p + kHeaderBytes;
  for (auto& f : d.features) {
    f = GetF32(q);
    q += 4;
    if (!std::isfinite(f)) throw Error("descriptor buffer: non-finite feature value");
  }
  for (auto& c : d.coefficients) {
    c = {GetF32(q), GetF32(q + 4)};
    q += 8;
    if (!std::isfinite(c.real()) || !std::isfinite(c.imag())) {
      throw Error("descriptor buffer: non-finite coefficient");
    }
  }
  return d;
}

double DescriptorExtractor::Distance(const Descriptor& a, const Descriptor& b) const {
  if (a.kind != kind() || b.kind != kind()) {
    throw Error(StrCat("Distance: a ", ToString(kind()), " extractor was given ", ToString(a.kind),
                       " and ", ToString(b.kind), " descriptors"));
  }
  if (a.features.size() != b.features.size()) {
    throw Error(StrCat("Distance: feature vectors of different lengths (", a.features.size(),
                       " vs ", b.features.size(), ")"));
  }
  if (a.features.empty()) throw Error("Distance: empty feature vectors");
  return Distance(a.features.data(), b.features.data(), a.features.size());
}

namespace internal {
void CheckValidMask(const cv::Mat& panorama, const cv::Mat& valid_mask) {
  if (valid_mask.type() != CV_8UC1 || valid_mask.size() != panorama.size()) {
    throw Error(StrCat("valid mask is ", valid_mask.cols, "x", valid_mask.rows, " with ",
                       valid_mask.channels(), " channel(s), expected 8-bit grey of the panorama's ",
                       panorama.cols, "x", panorama.rows));
  }
  if (cv::countNonZero(valid_mask) == 0) throw Error("valid mask has no valid pixel");
}
}  // namespace internal

cv::Mat FillInvalidPixels(const cv::Mat& panorama, const cv::Mat& valid_mask) {
  if (valid_mask.empty()) return panorama;
  internal::CheckValidMask(panorama, valid_mask);
  if (cv::countNonZero(valid_mask) == valid_mask.rows * valid_mask.cols) return panorama;
  cv::Mat filled = panorama.clone();
  const cv::Scalar global = cv::mean(panorama, valid_mask);
  for (int r = 0; r < filled.rows; ++r) {
    const cv::Mat row_mask = valid_mask.row(r);
    const cv::Scalar mean =
        cv::countNonZero(row_mask) > 0 ? cv::mean(panorama.row(r), row_mask) : global;
    cv::Mat row = filled.row(r);
    cv::Mat invalid = row_mask == 0;
    row.setTo(mean, invalid);
  }
  return filled;
}

Descriptor DescriptorExtractor::ComputeMasked(const cv::Mat& panorama,
                                              const cv::Mat& valid_mask) const {
  if (valid_mask.empty() || panorama.empty()) return Compute(panorama);  // Compute reports
  return Compute(FillInvalidPixels(panorama, valid_mask));
}

double DescriptorExtractor::Similarity(double distance, double e_max) {
  if (!(e_max > 0)) throw Error(StrCat("Similarity: e_max must be > 0, got ", e_max));
  return std::max(0.0, 1.0 - distance / e_max);
}

}  // namespace omnicml

namespace omnicml {

cv::Mat RollColumns(const cv::Mat& panorama, int k) {
  if (panorama.empty()) throw Error("RollColumns: empty image");
  const int w = panorama.cols;
  const int shift = ((k % w) + w) % w;
  if (shift == 0) return panorama.clone();
  cv::Mat out(panorama.size(), panorama.type());
  // out[c] = in[(c + shift) mod W]: columns [shift, W) move to [0, W - shift).
  panorama.colRange(shift, w).copyTo(out.colRange(0, w - shift));
  panorama.colRange(0, shift).copyTo(out.colRange(w - shift, w));
  return out;
}

cv::Mat MakeSyntheticPanorama(int width, int height, std::uint32_t seed) {
  if (width < 8 || height < 4) {
    throw Error(StrCat("MakeSyntheticPanorama: size ", width, "x", height, " is below 8x4"));
  }
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const int horizon = static_cast<int>(0.55 * height);
  cv::Mat img(height, width, CV_32FC3);
  // Sky (brighter towards the top) and ground (darker towards the bottom).
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      cv::Vec3f& px = img.at<cv::Vec3f>(r, c);
      if (r < horizon) {
        const double t = static_cast<double>(r) / horizon;
        px = cv::Vec3f(static_cast<float>(235 - 60 * t), static_cast<float>(200 - 50 * t),
                       static_cast<float>(150 - 40 * t));
      } else {
        const double t = static_cast<double>(r - horizon) / std::max(1, height - horizon);
        px = cv::Vec3f(static_cast<float>(60 - 20 * t), static_cast<float>(90 - 30 * t),
                       static_cast<float>(110 - 30 * t));
      }
    }
  }
  // Objects standing on the ground, wrapping around in azimuth, shaded along their width.
  const int objects = 14;
  for (int i = 0; i < objects; ++i) {
    const double centre = u(rng) * width;
    const double half_width = (0.01 + 0.06 * u(rng)) * width;
    const int top = static_cast<int>((0.08 + 0.4 * u(rng)) * height);
    const int bottom = std::min(height, horizon + static_cast<int>(0.15 * height * u(rng)) + 1);
    const cv::Vec3f colour(static_cast<float>(30 + 200 * u(rng)),
                           static_cast<float>(30 + 200 * u(rng)),
                           static_cast<float>(30 + 200 * u(rng)));
    const double stripes = 1 + std::floor(6 * u(rng));
    for (int dc = -static_cast<int>(half_width); dc <= static_cast<int>(half_width); ++dc) {
      const int c = ((static_cast<int>(centre) + dc) % width + width) % width;
      const double x = dc / half_width;  // -1..1 across the object
      const double shade = 0.75 + 0.25 * std::cos(kPi * x * stripes);
      for (int r = top; r < bottom; ++r)
        img.at<cv::Vec3f>(r, c) = colour * static_cast<float>(shade);
    }
  }
  // Smooth periodic texture over azimuth, then pixel noise.
  std::normal_distribution<float> noise(0.0f, 4.0f);
  const double f1 = 1 + std::floor(5 * u(rng)), f2 = 7 + std::floor(20 * u(rng));
  const double p1 = kTwoPi * u(rng), p2 = kTwoPi * u(rng);
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      const double a = kTwoPi * c / width;
      const float t =
          static_cast<float>(12 * std::sin(f1 * a + p1) + 6 * std::sin(f2 * a + p2 + 0.05 * r));
      cv::Vec3f& px = img.at<cv::Vec3f>(r, c);
      for (int ch = 0; ch < 3; ++ch) px[ch] += t + noise(rng);
    }
  }
  cv::Mat out;
  img.convertTo(out, CV_8UC3);  // saturating
  return out;
}

}  // namespace omnicml
