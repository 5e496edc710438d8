// Private helpers shared by the descriptor extractors: input checks and the tight
// distance loops the environment model runs over thousands of stored descriptors.
#ifndef OMNICML_DESCRIPTORS_INTERNAL_DESCRIPTOR_UTIL_H_
#define OMNICML_DESCRIPTORS_INTERNAL_DESCRIPTOR_UTIL_H_

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include <opencv2/core.hpp>

#include "omnicml/common/common.h"

namespace omnicml::internal {

// Throws omnicml::Error unless valid_mask is CV_8UC1 of the panorama's size with at
// least one non-zero pixel (descriptor.cc).
void CheckValidMask(const cv::Mat& panorama, const cv::Mat& valid_mask);

// Throws omnicml::Error unless `image` is a non-empty CV_8UC1 or CV_8UC3 image of at
// least min_width x min_height pixels. `who` names the caller in the message.
inline void CheckDescriptorInput(const cv::Mat& image, const char* who, int min_width,
                                 int min_height) {
  if (image.empty()) throw Error(StrCat(who, ": empty image"));
  if (image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3)) {
    throw Error(StrCat(who, ": unsupported image type (", image.channels(),
                       " channel(s), depth code ", image.depth(),
                       "); expected 8-bit grey (CV_8UC1) or 8-bit BGR (CV_8UC3)"));
  }
  if (image.cols < min_width || image.rows < min_height) {
    throw Error(StrCat(who, ": image of ", image.cols, "x", image.rows,
                       " pixels is too small; needs at least ", min_width, "x", min_height));
  }
}

// The distance loops below work on 8 floats at a time, as two 4-float GCC/Clang vector
// values (one SSE register each on baseline x86-64, NEON on ARM): SIMD without
// reassociating floating point (no -ffast-math), so the result is the same on every
// call and does not depend on the caller. n need not be a multiple of 8.
using Float4 = float __attribute__((vector_size(16)));
using Int4 = std::int32_t __attribute__((vector_size(16)));

inline Float4 Load4(const float* p) {
  Float4 v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}

// Sum of the 8 lanes of (lo, hi) in a fixed order.
inline float Sum8(const Float4& lo, const Float4& hi) {
  return ((lo[0] + hi[0]) + (lo[1] + hi[1])) + ((lo[2] + hi[2]) + (lo[3] + hi[3]));
}

inline Float4 Abs4(const Float4& v) {
  return reinterpret_cast<Float4>(reinterpret_cast<Int4>(v) & 0x7fffffff);
}

inline float SumSquaredDifference(const float* a, const float* b, std::size_t n) {
  Float4 lo = {}, hi = {};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const Float4 d0 = Load4(a + i) - Load4(b + i);
    const Float4 d1 = Load4(a + i + 4) - Load4(b + i + 4);
    lo += d0 * d0;
    hi += d1 * d1;
  }
  float tail = 0;
  for (; i < n; ++i) tail += (a[i] - b[i]) * (a[i] - b[i]);
  return Sum8(lo, hi) + tail;
}

inline float SumAbsoluteDifference(const float* a, const float* b, std::size_t n) {
  Float4 lo = {}, hi = {};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    lo += Abs4(Load4(a + i) - Load4(b + i));
    hi += Abs4(Load4(a + i + 4) - Load4(b + i + 4));
  }
  float tail = 0;
  for (; i < n; ++i) tail += std::fabs(a[i] - b[i]);
  return Sum8(lo, hi) + tail;
}

// Sum of min(a_i, b_i), and the sums of a and b, in one pass.
struct IntersectionSums {
  float min_sum = 0, a_sum = 0, b_sum = 0;
};
inline IntersectionSums SumMinimum(const float* a, const float* b, std::size_t n) {
  Float4 m0 = {}, m1 = {}, sa0 = {}, sa1 = {}, sb0 = {}, sb1 = {};
  std::size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const Float4 x0 = Load4(a + i), y0 = Load4(b + i);
    const Float4 x1 = Load4(a + i + 4), y1 = Load4(b + i + 4);
    m0 += x0 < y0 ? x0 : y0;
    m1 += x1 < y1 ? x1 : y1;
    sa0 += x0;
    sa1 += x1;
    sb0 += y0;
    sb1 += y1;
  }
  IntersectionSums r{Sum8(m0, m1), Sum8(sa0, sa1), Sum8(sb0, sb1)};
  for (; i < n; ++i) {
    r.min_sum += a[i] < b[i] ? a[i] : b[i];
    r.a_sum += a[i];
    r.b_sum += b[i];
  }
  return r;
}

}  // namespace omnicml::internal

#endif  // OMNICML_DESCRIPTORS_INTERNAL_DESCRIPTOR_UTIL_H_
