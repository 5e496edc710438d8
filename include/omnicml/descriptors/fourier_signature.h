// Fourier signature of a cylindrical panorama [M, G] (docs/design.md "Descriptors").
//
// The panorama (converted to grey, values in [0, 1]) is split into `bands` horizontal
// segments of (nearly) equal height (band b holds rows floor(b H / bands) up to
// floor((b + 1) H / bands) - 1); each band is averaged over its rows into a 1-D
// signal s_b[c] over azimuth (c = 0..W-1, W the panorama width). Optionally (on by
// default) each s_b[c] is divided by the mean brightness of column c over the whole
// height: a light zone switched off or a curtain drawn scales a sector of the panorama by
// a factor that is nearly constant along each column, and this division removes it
// (omnicml's addition to [G]; measured on the `institute` world, where lights and curtains
// change every few steps: the Fourier-nearest day-1 view of a day-2 frame lies within 1 m
// for 85 % of frames with it and 40 % without, and the engine's mean error on two days
// fell from 1.76 m to 0.46 m with e_max 0.45). Optionally each signal is then normalised
// to zero mean and unit variance, which removes a global gain and offset of the
// illumination. A real FFT of size W (FFTW3, single precision) gives
//   S_b[m] = (1 / W) sum_c s_b[c] exp(-2 pi i m c / W).
// A column roll multiplies S_b[m] by a phase only, so the magnitudes |S_b[m]| are
// rotation invariant: they are the feature vector. The complex values are kept for the
// rotation estimate.
//
// Which harmonics are stored: K = `coefficients` per band, starting at m0 = 1 when
// `normalize_bands` is on (after normalisation the DC term is 0 by construction, so it
// would waste a slot) and at m0 = 0 otherwise (the DC term then carries the band's mean
// brightness). Descriptor::features[b * K + j] = |S_b[m0 + j]| and
// Descriptor::coefficients[b * K + j] = S_b[m0 + j]. Requires W >= 2 (m0 + K).
//
// Distance: L2 (default) or L1 over the magnitudes. L2 is the default because, by the
// triangle inequality per coefficient and Parseval, the L2 distance of the magnitudes
// is a lower bound of the L2 distance between the two low-passed band signals at their
// best relative rotation: small E means "looks alike after turning", and E is a metric.
//
// Relative heading: the circular cross-correlation over azimuth, summed over bands,
//   r[n] = sum_b sum_c a_b[c] b_b[c + n],  R[m] = sum_b conj(A_b[m]) B_b[m],
// is computed from the stored coefficients alone (harmonics not stored are zero; the
// spectrum is completed conjugate-symmetrically and inverted by a complex-to-real FFT of
// size W), its arg max n* is refined below one column by a parabola through
// r[n*-1], r[n*], r[n*+1], and RelativeHeading(a, b) = WrapAngle(2 pi n* / W). With the
// panorama convention of omni_unwrapper.h, if a[c] = b[(c + k) mod W] (the robot turned
// counter-clockwise by k columns between b and a) the result is +k 2 pi / W.
//
// Thread-safety: FourierSignature is immutable after construction. FFTW plans are made
// once per signal size in a process-wide cache (plan creation serialised by a global
// mutex, since the FFTW planner is not thread-safe) and executed with the new-array
// interface on per-call buffers, so Compute and RelativeHeading may be called from any
// number of threads. Code elsewhere in the process that calls the FFTW planner
// concurrently must not do so outside this module's mutex (no other module does).
// Plans use FFTW_ESTIMATE, so results are bit-identical from run to run.
#ifndef OMNICML_DESCRIPTORS_FOURIER_SIGNATURE_H_
#define OMNICML_DESCRIPTORS_FOURIER_SIGNATURE_H_

#include <cstddef>
#include <optional>
#include <string>

#include "omnicml/descriptors/descriptor.h"

namespace omnicml {

// Norm of the magnitude difference.
enum class FourierDistance { kL1, kL2 };
std::string ToString(FourierDistance d);                          // "l1", "l2"
FourierDistance FourierDistanceFromString(const std::string& s);  // throws omnicml::Error

struct FourierOptions {
  // Horizontal bands the panorama is split into (see the file comment for their rows).
  // 1..64, and the panorama needs H >= bands.
  int bands = 4;
  // Harmonics stored per band (K). 1..1024; the panorama needs W >= 2 (m0 + K).
  int coefficients = 16;
  // Norm of E over the magnitudes (see the file comment for why L2 is the default).
  FourierDistance distance = FourierDistance::kL2;
  // Zero mean, unit variance per band signal before the FFT: invariance to a global
  // gain/offset of brightness. A constant band (variance 0) is left at zero.
  bool normalize_bands = true;
  // Divide each column's band means by the column's mean brightness (floored at 1e-3 of
  // full scale) before the band normalisation: invariance to a brightness gain that
  // varies over azimuth but not along a column (light zones, curtains). A column roll
  // still permutes the band signals exactly.
  bool normalize_columns = true;

  // Throws omnicml::Error naming the field when a value is out of range.
  void Validate() const;
  // First stored harmonic m0 (1 with normalisation, else 0).
  int first_harmonic() const { return normalize_bands ? 1 : 0; }
};

// The options schema (common/options.h): YAML keys, dump, binary codec.
template <class V>
void VisitFields(V& v, FourierOptions& o) {
  v("bands", o.bands);
  v("coefficients", o.coefficients);
  v.Enum("distance", o.distance, {FourierDistance::kL1, FourierDistance::kL2});
  v("normalize_bands", o.normalize_bands);
  v("normalize_columns", o.normalize_columns);
}

class FourierSignature final : public DescriptorExtractor {
 public:
  // Throws omnicml::Error if the options are invalid.
  explicit FourierSignature(const FourierOptions& options = {});

  DescriptorKind kind() const override { return DescriptorKind::kFourier; }

  // Panorama: CV_8UC1 or CV_8UC3 (BGR), H >= bands, W >= 2 (m0 + K). Throws
  // omnicml::Error otherwise (empty, too small, wrong type) saying which.
  Descriptor Compute(const cv::Mat& panorama) const override;

  // L1 or L2 norm of a - b over n floats (options().distance).
  double Distance(const float* a, const float* b, std::size_t n) const override;
  using DescriptorExtractor::Distance;

  bool ProvidesHeading() const override { return true; }

  // Heading at a minus heading at b, radians in (-pi, pi] (see the file comment).
  // Throws omnicml::Error if a or b is not a Fourier descriptor of this configuration
  // or their panorama widths differ. Returns std::nullopt only when the correlation is
  // flat (e.g. both panoramas uniform), where no rotation can be read.
  std::optional<double> RelativeHeading(const Descriptor& a, const Descriptor& b) const override;

  // Sub-column arg max of the cross-correlation in columns, in [0, W) — the quantity
  // RelativeHeading converts to radians. Same preconditions and failures.
  std::optional<double> RelativeShiftColumns(const Descriptor& a, const Descriptor& b) const;

  std::size_t FeatureSize() const override {
    return static_cast<std::size_t>(options_.bands) * options_.coefficients;
  }

  const FourierOptions& options() const { return options_; }

  // Masked panoramas (descriptor.h ComputeMasked): each band signal s_b[c] averages only
  // the valid rows of column c in band b; a column with no valid row in a band is a gap.
  // The column normalisation uses the valid pixels of the column, the band normalisation
  // the band's valid columns, and gaps are set to the band's mean (0 after normalisation,
  // the band mean otherwise), so they add nothing to the spectrum's shape and invalid
  // pixels never change the result. Effect (docs/design.md "Masks"): the magnitudes of a
  // band shrink with its valid fraction (Parseval), and the mask, fixed in the robot
  // frame, does not turn with the robot, so two views of one place differing by a turn
  // are no longer at distance 0; RelativeHeading correlates the gapped signals and still
  // finds the turn while the gaps are a minority of the columns.
  Descriptor ComputeMasked(const cv::Mat& panorama, const cv::Mat& valid_mask) const override;

  // The band signals s_b[c] (bands x W, CV_32FC1, after normalisation when enabled) the
  // FFT is taken of: exposed for tests and plots. `valid_mask` as ComputeMasked.
  cv::Mat BandSignals(const cv::Mat& panorama, const cv::Mat& valid_mask = cv::Mat()) const;

 private:
  cv::Mat MaskedBandSignals(const cv::Mat& panorama, const cv::Mat& valid_mask) const;
  Descriptor Spectrum(const cv::Mat& signals) const;  // FFT of the band signals

  FourierOptions options_;
};

}  // namespace omnicml

#endif  // OMNICML_DESCRIPTORS_FOURIER_SIGNATURE_H_
