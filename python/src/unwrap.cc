// Bindings of the unwrap module: OmniCalibration, OmniUnwrapper, auto_calibrate,
// prepare_panorama and image file I/O.
#include <memory>
#include <string>

#include <pybind11/stl.h>

#include "convert.h"
#include "omnicml/common/common.h"
#include "omnicml/unwrap/omni_unwrapper.h"

namespace omnicml::python {
namespace {

std::string ToString(RingDirection d) {
  return d == RingDirection::kClockwise ? "clockwise" : "counter_clockwise";
}
RingDirection RingDirectionFrom(const std::string& s) {
  if (s == "counter_clockwise") return RingDirection::kCounterClockwise;
  if (s == "clockwise") return RingDirection::kClockwise;
  throw Error(StrCat("direction '", s, "': expected counter_clockwise or clockwise"));
}
std::string ToString(ElevationMapping e) {
  return e == ElevationMapping::kLinearInverted ? "linear_inverted" : "linear";
}
ElevationMapping ElevationFrom(const std::string& s) {
  if (s == "linear") return ElevationMapping::kLinear;
  if (s == "linear_inverted") return ElevationMapping::kLinearInverted;
  throw Error(StrCat("elevation '", s, "': expected linear or linear_inverted"));
}

}  // namespace

void BindUnwrap(py::module_& m) {
  const OmniCalibration d;
  py::class_<OmniCalibration>(
      m, "OmniCalibration",
      "Intrinsic calibration of a catadioptric ring image (pixels: x right, y down, origin at "
      "the centre of the top-left pixel).")
      .def(py::init([](double cx, double cy, double r_in, double r_out, double az0,
                       const std::string& direction, const std::string& elevation, int w, int h) {
             OmniCalibration c;
             c.center_x_px = cx;
             c.center_y_px = cy;
             c.inner_radius_px = r_in;
             c.outer_radius_px = r_out;
             c.azimuth0_rad = az0;
             c.direction = RingDirectionFrom(direction);
             c.elevation = ElevationFrom(elevation);
             c.panorama_width = w;
             c.panorama_height = h;
             return c;
           }),
           py::arg("center_x_px") = d.center_x_px, py::arg("center_y_px") = d.center_y_px,
           py::arg("inner_radius_px") = d.inner_radius_px,
           py::arg("outer_radius_px") = d.outer_radius_px, py::arg("azimuth0_rad") = d.azimuth0_rad,
           py::arg("direction") = ToString(d.direction),
           py::arg("elevation") = ToString(d.elevation),
           py::arg("panorama_width") = d.panorama_width,
           py::arg("panorama_height") = d.panorama_height)
      .def_readwrite("center_x_px", &OmniCalibration::center_x_px)
      .def_readwrite("center_y_px", &OmniCalibration::center_y_px)
      .def_readwrite("inner_radius_px", &OmniCalibration::inner_radius_px)
      .def_readwrite("outer_radius_px", &OmniCalibration::outer_radius_px)
      .def_readwrite("azimuth0_rad", &OmniCalibration::azimuth0_rad,
                     "Image-plane angle of panorama column 0 (clockwise on screen), radians.")
      .def_property(
          "direction", [](const OmniCalibration& c) { return ToString(c.direction); },
          [](OmniCalibration& c, const std::string& s) { c.direction = RingDirectionFrom(s); },
          "'counter_clockwise' or 'clockwise'.")
      .def_property(
          "elevation", [](const OmniCalibration& c) { return ToString(c.elevation); },
          [](OmniCalibration& c, const std::string& s) { c.elevation = ElevationFrom(s); },
          "'linear' (row 0 at the outer radius) or 'linear_inverted'.")
      .def_readwrite("panorama_width", &OmniCalibration::panorama_width)
      .def_readwrite("panorama_height", &OmniCalibration::panorama_height)
      .def("validate", &OmniCalibration::Validate,
           "Raises omnicml.Error naming the field when a value is invalid.")
      .def_static("from_yaml", &OmniCalibration::FromYamlFile, py::arg("path"),
                  "Reads a calibration YAML file (keys equal the attribute names).")
      .def("to_yaml", &OmniCalibration::ToYamlFile, py::arg("path"),
           "Writes a calibration YAML file.")
      .def("__repr__", [](const OmniCalibration& c) {
        return StrCat("<omnicml.OmniCalibration center=(", c.center_x_px, ", ", c.center_y_px,
                      ") radii=(", c.inner_radius_px, ", ", c.outer_radius_px,
                      ") panorama=", c.panorama_width, "x", c.panorama_height, ">");
      });

  py::class_<OmniUnwrapper, std::shared_ptr<OmniUnwrapper>>(
      m, "OmniUnwrapper",
      "Raw catadioptric ring image <-> cylindrical panorama (cv::remap, bilinear). Immutable "
      "after construction; thread-safe.")
      .def(py::init<const OmniCalibration&, int, int>(), py::arg("calibration"),
           py::arg("image_width"), py::arg("image_height"),
           "Precomputes the maps for raw images of image_width x image_height pixels. Raises "
           "omnicml.Error if the calibration is invalid or leaves the image.")
      .def(
          "unwrap",
          [](const OmniUnwrapper& u, const py::object& raw) {
            const cv::Mat in = ImageFromArray(raw, "raw");
            cv::Mat out;
            {
              py::gil_scoped_release release;
              out = u.Unwrap(in);
            }
            return ArrayFromImage(out);
          },
          py::arg("raw"),
          "Raw ring image (uint8, construction size) -> panorama (panorama_height, "
          "panorama_width[, 3]).")
      .def(
          "render",
          [](const OmniUnwrapper& u, const py::object& panorama, double background) {
            return ArrayFromImage(
                u.Render(ImageFromArray(panorama, "panorama"), cv::Scalar::all(background)));
          },
          py::arg("panorama"), py::arg("background") = 0.0,
          "Inverse mapping: panorama -> raw ring image of the construction size.")
      .def_property_readonly("calibration", &OmniUnwrapper::calibration);

  m.def(
      "auto_calibrate",
      [](const py::object& raw, const std::optional<OmniCalibration>& initial) {
        const AutoCalibrationResult r =
            AutoCalibrate(ImageFromArray(raw, "raw"), initial.value_or(OmniCalibration{}));
        py::dict d;
        d["calibration"] = r.calibration;
        d["inner_residual_px"] = r.inner_residual_px;
        d["outer_residual_px"] = r.outer_residual_px;
        d["inner_inliers"] = r.inner_inliers;
        d["outer_inliers"] = r.outer_inliers;
        return d;
      },
      py::arg("raw"), py::arg("initial") = py::none(),
      "Estimates the ring's centre and radii from a raw image; returns a dict with "
      "'calibration' (OmniCalibration), residuals and inlier counts. Raises omnicml.Error if "
      "no ring can be found.");
  m.def(
      "prepare_panorama",
      [](const py::object& image, int width, int height) {
        return ArrayFromImage(PreparePanorama(ImageFromArray(image, "image"), width, height));
      },
      py::arg("image"), py::arg("width") = 0, py::arg("height") = 0,
      "A panoramic image as is, or resampled to width x height keeping the column "
      "convention (columns centred on their azimuth, wrapping around).");
  m.def(
      "read_image", [](const std::string& path) { return ArrayFromImage(ReadImage(path)); },
      py::arg("path"),
      "Reads an image file as uint8 (H, W) grey or (H, W, 3) BGR. Raises omnicml.Error "
      "naming the file.");
  m.def(
      "write_image",
      [](const std::string& path, const py::object& image) {
        WriteImage(path, ImageFromArray(image, "image"));
      },
      py::arg("path"), py::arg("image"),
      "Writes an image atomically; the format follows the extension.");
}

}  // namespace omnicml::python
