// Bindings of the descriptors module: Descriptor, the three extractors (FourierSignature,
// InvariantFeatureHistogram, ColorHistogram), RollColumns and the synthetic panorama.
#include <complex>
#include <cstring>
#include <memory>
#include <optional>
#include <vector>

#include <pybind11/complex.h>
#include <pybind11/stl.h>

#include "convert.h"
#include "omnicml/common/common.h"
#include "omnicml/descriptors/descriptor_factory.h"

namespace omnicml::python {
namespace {

py::array_t<float> FloatArray(const std::vector<float>& v) {
  py::array_t<float> out(static_cast<py::ssize_t>(v.size()));
  if (!v.empty()) std::memcpy(out.mutable_data(), v.data(), v.size() * sizeof(float));
  return out;
}

py::array_t<std::complex<float>> ComplexArray(const std::vector<std::complex<float>>& v) {
  py::array_t<std::complex<float>> out(static_cast<py::ssize_t>(v.size()));
  if (!v.empty()) std::memcpy(out.mutable_data(), v.data(), v.size() * sizeof(std::complex<float>));
  return out;
}

Descriptor ComputeDescriptor(const DescriptorExtractor& e, const py::object& image) {
  const cv::Mat m = ImageFromArray(image, "image");
  py::gil_scoped_release release;
  return e.Compute(m);
}

}  // namespace

void BindDescriptors(py::module_& m) {
  py::class_<Descriptor>(m, "Descriptor",
                         "A panorama descriptor: the feature vector distances are computed on and, "
                         "for the Fourier signature, the complex coefficients the relative heading "
                         "is computed from. A plain value (copied in and out).")
      .def(py::init([](const std::string& kind, const py::object& features,
                       const py::object& coefficients, int panorama_width) {
             Descriptor d;
             d.kind = DescriptorKindFromString(kind);
             auto f =
                 py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(features);
             if (!f || f.ndim() != 1) throw Error("Descriptor: features must be a 1-D float array");
             d.features.assign(f.data(), f.data() + f.size());
             if (!coefficients.is_none()) {
               auto c =
                   py::array_t<std::complex<float>,
                               py::array::c_style | py::array::forcecast>::ensure(coefficients);
               if (!c || c.ndim() != 1)
                 throw Error("Descriptor: coefficients must be a 1-D complex array");
               d.coefficients.assign(c.data(), c.data() + c.size());
             }
             d.panorama_width = panorama_width;
             return d;
           }),
           py::arg("kind"), py::arg("features"), py::arg("coefficients") = py::none(),
           py::arg("panorama_width") = 0,
           "Builds a descriptor from its parts (kind 'fourier', 'ifh' or 'color').")
      .def_property_readonly(
          "kind", [](const Descriptor& d) { return ToString(d.kind); },
          "'fourier', 'ifh' or 'color'.")
      .def_property_readonly(
          "features", [](const Descriptor& d) { return FloatArray(d.features); },
          "Feature vector (float32 copy): Fourier magnitudes or histogram bins.")
      .def_property_readonly(
          "coefficients", [](const Descriptor& d) { return ComplexArray(d.coefficients); },
          "Fourier only: the stored complex coefficients, band-major (bands x K), complex64 "
          "copy; empty for histograms.")
      .def_readonly("panorama_width", &Descriptor::panorama_width,
                    "Width in columns of the panorama it was computed from.")
      .def(
          "to_bytes",
          [](const Descriptor& d) {
            const std::vector<std::uint8_t> b = Serialize(d);
            return py::bytes(reinterpret_cast<const char*>(b.data()), b.size());
          },
          "Versioned little-endian byte encoding with checksum (descriptor.h).")
      .def_static(
          "from_bytes",
          [](const py::bytes& b) {
            const std::string s = b;
            return Deserialize(std::span<const std::uint8_t>(
                reinterpret_cast<const std::uint8_t*>(s.data()), s.size()));
          },
          py::arg("data"),
          "Parses bytes from to_bytes(); raises omnicml.Error on a malformed buffer.")
      .def("__eq__", [](const Descriptor& a, const Descriptor& b) { return a == b; })
      .def("__repr__", [](const Descriptor& d) {
        return StrCat("<omnicml.Descriptor kind=", ToString(d.kind),
                      " features=", d.features.size(), " coefficients=", d.coefficients.size(),
                      " panorama_width=", d.panorama_width, ">");
      });

  py::class_<DescriptorExtractor, std::shared_ptr<DescriptorExtractor>>(
      m, "DescriptorExtractor",
      "Computes descriptors of panoramas and compares them. Immutable and thread-safe. "
      "Panoramas: numpy uint8 (H, W) grey or (H, W, 3) BGR; column c looks along robot "
      "azimuth 2 pi c / W counter-clockwise, row 0 the highest elevation.")
      .def_property_readonly(
          "kind", [](const DescriptorExtractor& e) { return ToString(e.kind()); },
          "'fourier', 'ifh' or 'color'.")
      .def("compute", &ComputeDescriptor, py::arg("image"),
           "Descriptor of a panorama (numpy uint8 (H, W) or (H, W, 3)). Raises omnicml.Error on "
           "an empty, too small or wrongly typed image.")
      .def(
          "distance",
          [](const DescriptorExtractor& e, const Descriptor& a, const Descriptor& b) {
            return e.Distance(a, b);
          },
          py::arg("a"), py::arg("b"),
          "Distance E >= 0 between two descriptors of this extractor (0 for equal inputs). "
          "Raises omnicml.Error when kinds or lengths differ.")
      .def(
          "relative_heading",
          [](const DescriptorExtractor& e, const Descriptor& a, const Descriptor& b) {
            return e.RelativeHeading(a, b);
          },
          py::arg("a"), py::arg("b"),
          "Robot heading at a minus heading at b, radians in (-pi, pi], from the circular "
          "cross-correlation over azimuth; None when the descriptor carries no rotation "
          "(histograms) or the correlation is flat. If a is b's panorama rolled by k columns "
          "(a[:, c] = b[:, (c + k) % W]) the result is 2 pi k / W.")
      .def_property_readonly("provides_heading", &DescriptorExtractor::ProvidesHeading,
                             "Whether relative_heading can give a rotation.")
      .def_property_readonly("feature_size", &DescriptorExtractor::FeatureSize,
                             "Length of the feature vectors this extractor produces.");

  py::class_<FourierSignature, DescriptorExtractor, std::shared_ptr<FourierSignature>>(
      m, "FourierSignature",
      "Fourier signature of a cylindrical panorama [M, G]: band-wise FFT magnitudes over "
      "azimuth (rotation invariant); the complex coefficients give the relative heading.")
      .def(py::init([](int bands, int coefficients, const std::string& distance,
                       bool normalize_bands, bool normalize_columns) {
             FourierOptions o;
             o.bands = bands;
             o.coefficients = coefficients;
             o.distance = FourierDistanceFromString(distance);
             o.normalize_bands = normalize_bands;
             o.normalize_columns = normalize_columns;
             return std::make_shared<FourierSignature>(o);
           }),
           py::arg("bands") = FourierOptions{}.bands,
           py::arg("coefficients") = FourierOptions{}.coefficients,
           py::arg("distance") = ToString(FourierOptions{}.distance),
           py::arg("normalize_bands") = FourierOptions{}.normalize_bands,
           py::arg("normalize_columns") = FourierOptions{}.normalize_columns,
           "bands: horizontal bands (1..64); coefficients: harmonics per band (1..1024); "
           "distance: 'l2' or 'l1'; normalize_bands: zero mean, unit variance per band; "
           "normalize_columns: divide by each column's mean brightness. Raises omnicml.Error "
           "naming the field when a value is out of range.")
      .def(
          "relative_shift_columns",
          [](const FourierSignature& e, const Descriptor& a, const Descriptor& b) {
            return e.RelativeShiftColumns(a, b);
          },
          py::arg("a"), py::arg("b"),
          "Sub-column arg max of the cross-correlation in columns, in [0, W).")
      .def(
          "band_signals",
          [](const FourierSignature& e, const py::object& image) {
            return ArrayFromImage(e.BandSignals(ImageFromArray(image, "image")));
          },
          py::arg("image"), "The band signals (bands x W, float32) the FFT is taken of.")
      .def_property_readonly(
          "options",
          [](const FourierSignature& e) {
            const FourierOptions& o = e.options();
            py::dict d;
            d["bands"] = o.bands;
            d["coefficients"] = o.coefficients;
            d["distance"] = ToString(o.distance);
            d["normalize_bands"] = o.normalize_bands;
            d["normalize_columns"] = o.normalize_columns;
            return d;
          },
          "The options as a dict.");

  py::class_<InvariantFeatureHistogram, DescriptorExtractor,
             std::shared_ptr<InvariantFeatureHistogram>>(
      m, "InvariantFeatureHistogram",
      "Invariant feature histogram [W]: histograms of kernel products averaged over rotations; "
      "rotation invariant, no heading.")
      .def(py::init([](int angles, int bins, const std::vector<double>& scales, bool color,
                       double sample_fraction, std::uint32_t seed, const py::object& kernels,
                       bool normalize_columns) {
             IfhOptions o;
             o.normalize_columns = normalize_columns;
             o.angles = angles;
             o.bins = bins;
             o.scales = scales;
             o.color = color;
             o.sample_fraction = sample_fraction;
             o.seed = seed;
             if (!kernels.is_none()) {
               o.kernels.clear();
               for (const auto& k : kernels) {
                 IfhKernel kernel;
                 for (const auto& p : k) {
                   auto xy = p.cast<std::vector<double>>();
                   if (xy.size() != 2) throw Error("kernels: each offset is a pair [dx, dy]");
                   kernel.offsets.emplace_back(xy[0], xy[1]);
                 }
                 o.kernels.push_back(kernel);
               }
             }
             return std::make_shared<InvariantFeatureHistogram>(o);
           }),
           py::arg("angles") = IfhOptions{}.angles, py::arg("bins") = IfhOptions{}.bins,
           py::arg("scales") = IfhOptions{}.scales, py::arg("color") = IfhOptions{}.color,
           py::arg("sample_fraction") = IfhOptions{}.sample_fraction,
           py::arg("seed") = IfhOptions{}.seed, py::arg("kernels") = py::none(),
           py::arg("normalize_columns") = IfhOptions{}.normalize_columns,
           "kernels: list of kernels, each a list of 1..4 offsets [dx, dy] (default "
           "[[[0, 0], [0, 1]], [[0, 3], [4, 0]]]); normalize_columns: divide each column by "
           "its mean value first (lights that switch part of the panorama). Raises "
           "omnicml.Error naming the field.");

  py::class_<ColorHistogram, DescriptorExtractor, std::shared_ptr<ColorHistogram>>(
      m, "ColorHistogram",
      "Six-band colour histogram [UN] (H, L, S and R, G, B or normalised rgb), low-pass "
      "filtered; no heading.")
      .def(py::init(
               [](int bins, int filter_width, bool normalized_rgb, const std::string& distance) {
                 ColorHistogramOptions o;
                 o.bins = bins;
                 o.filter_width = filter_width;
                 o.normalized_rgb = normalized_rgb;
                 o.distance = HistogramDistanceFromString(distance);
                 return std::make_shared<ColorHistogram>(o);
               }),
           py::arg("bins") = ColorHistogramOptions{}.bins,
           py::arg("filter_width") = ColorHistogramOptions{}.filter_width,
           py::arg("normalized_rgb") = ColorHistogramOptions{}.normalized_rgb,
           py::arg("distance") = ToString(ColorHistogramOptions{}.distance),
           "distance: 'jeffrey', 'chi_square', 'l1', 'l2' or 'intersection'.");

  m.def("similarity", &DescriptorExtractor::Similarity, py::arg("distance"), py::arg("e_max"),
        "S = max(0, 1 - E / e_max) in [0, 1]; raises omnicml.Error unless e_max > 0.");
  m.def(
      "roll_columns",
      [](const py::object& image, int k) {
        return ArrayFromImage(RollColumns(ImageFromArray(image, "image"), k));
      },
      py::arg("image"), py::arg("k"),
      "out[:, c] = in[:, (c + k) % W]: the view after a counter-clockwise turn by 2 pi k / W.");
  m.def(
      "synthetic_panorama",
      [](int width, int height, std::uint32_t seed) {
        return ArrayFromImage(MakeSyntheticPanorama(width, height, seed));
      },
      py::arg("width") = 360, py::arg("height") = 60, py::arg("seed") = 1,
      "A procedural, seeded colour panorama (H, W, 3) uint8 BGR; same seed, same pixels.");
}

}  // namespace omnicml::python
