// Small builders shared by the map-model tests (environment_model_test, view_index_test,
// ann_index_test): a Fourier descriptor with given magnitudes, an estimate at a point,
// and a model's serialized bytes (what "the same model" compares).
#ifndef OMNICML_TESTS_TESTING_MODEL_HELPERS_H_
#define OMNICML_TESTS_TESTING_MODEL_HELPERS_H_

#include <algorithm>
#include <complex>
#include <cstdint>
#include <random>
#include <vector>

#include "omnicml/common/binary_io.h"
#include "omnicml/descriptors/descriptor.h"
#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/mapping/environment_model.h"

namespace omnicml::testing {

// A Fourier descriptor with the given magnitudes (negative ones clamped to 0) and random
// phases from `rng`, of a 64-column panorama.
inline Descriptor MakeFourier(const std::vector<float>& magnitudes, std::mt19937& rng) {
  std::uniform_real_distribution<float> phase(-3.1f, 3.1f);
  Descriptor d;
  d.kind = DescriptorKind::kFourier;
  d.features = magnitudes;
  for (float& v : d.features) v = std::max(v, 0.0f);
  for (float v : d.features) d.coefficients.push_back(std::polar(v, phase(rng)));
  d.panorama_width = 64;
  return d;
}

// An estimate at (x, y), heading 0, with 0.2 m / 0.2 rad standard deviations.
inline Gaussian Estimate(double x, double y) {
  Gaussian g;
  g.mean = MakePose(x, y, 0.0);
  g.covariance = Eigen::Vector3d(0.04, 0.04, 0.04).asDiagonal();
  return g;
}

// The model's Serialize bytes.
inline std::vector<std::uint8_t> Bytes(const EnvironmentModel& m) {
  BinaryWriter w;
  m.Serialize(w);
  return w.Release();
}

}  // namespace omnicml::testing

#endif  // OMNICML_TESTS_TESTING_MODEL_HELPERS_H_
