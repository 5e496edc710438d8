// The omnicml._omnicml extension module: exceptions, conversions, and the registration of
// every binding group. The Python package omnicml (python/omnicml/__init__.py) re-exports
// it and adds the pure-Python helpers (options dicts as YAML).
#include <cstring>
#include <vector>

#include "convert.h"
#include "omnicml/common/common.h"

namespace omnicml::python {

cv::Mat ImageFromArray(const py::handle& obj, const char* what) {
  if (!py::isinstance<py::array>(obj)) {
    throw Error(StrCat(what, ": expected a numpy uint8 array of shape (H, W) or (H, W, 3), got ",
                       std::string(py::str(py::type::of(obj).attr("__name__")))));
  }
  auto array = py::reinterpret_borrow<py::array>(obj);
  if (!array.dtype().is(py::dtype::of<std::uint8_t>())) {
    throw Error(StrCat(what, ": dtype ", std::string(py::str(array.dtype())),
                       ", expected uint8 (convert with .astype(numpy.uint8))"));
  }
  const int ndim = static_cast<int>(array.ndim());
  const int channels = ndim == 3 ? static_cast<int>(array.shape(2)) : 1;
  if ((ndim != 2 && ndim != 3) || (channels != 1 && channels != 3)) {
    std::string shape = "(";
    for (int i = 0; i < ndim; ++i) shape += (i ? ", " : "") + std::to_string(array.shape(i));
    throw Error(StrCat(what, ": shape ", shape, "), expected (H, W) or (H, W, 3)"));
  }
  const int rows = static_cast<int>(array.shape(0));
  const int cols = static_cast<int>(array.shape(1));
  const int type = channels == 3 ? CV_8UC3 : CV_8UC1;
  if (rows == 0 || cols == 0) return cv::Mat(rows, cols, type);
  const bool contiguous = (array.flags() & py::array::c_style) != 0 && array.strides(ndim - 1) == 1;
  if (contiguous) {
    return cv::Mat(rows, cols, type, const_cast<void*>(array.data()));
  }
  // Strided view (a slice, a transposed array): copy element by element.
  auto c = py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>::ensure(array);
  cv::Mat copy(rows, cols, type);
  std::memcpy(copy.data, c.data(), static_cast<std::size_t>(rows) * cols * channels);
  return copy;
}

py::array ArrayFromImage(const cv::Mat& image) {
  const cv::Mat m = image.isContinuous() ? image : image.clone();
  std::vector<py::ssize_t> shape = {m.rows, m.cols};
  if (m.channels() > 1) shape.push_back(m.channels());
  const std::size_t bytes = m.total() * m.elemSize();
  if (m.depth() == CV_8U) {
    py::array_t<std::uint8_t> out(shape);
    if (bytes) std::memcpy(out.mutable_data(), m.data, bytes);
    return out;
  }
  if (m.depth() == CV_32F) {
    py::array_t<float> out(shape);
    if (bytes) std::memcpy(out.mutable_data(), m.data, bytes);
    return out;
  }
  throw InternalError(StrCat("ArrayFromImage: unsupported depth ", m.depth()));
}

Pose2 PoseFromObject(const py::handle& obj, const char* what) {
  py::array_t<double, py::array::c_style | py::array::forcecast> a;
  try {
    a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(obj);
  } catch (const py::error_already_set&) {
  }
  if (!a || a.ndim() != 1 || a.shape(0) != 3) {
    throw Error(StrCat(what, ": expected a pose (x_m, y_m, phi_rad) of 3 numbers"));
  }
  return Pose2(a.at(0), a.at(1), a.at(2));
}

py::array_t<double> ArrayFromPose(const Pose2& pose) {
  py::array_t<double> out(3);
  for (int i = 0; i < 3; ++i) out.mutable_at(i) = pose[i];
  return out;
}

Eigen::Matrix3d Matrix3FromObject(const py::handle& obj, const char* what) {
  py::array_t<double, py::array::c_style | py::array::forcecast> a;
  try {
    a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(obj);
  } catch (const py::error_already_set&) {
  }
  if (!a || a.ndim() != 2 || a.shape(0) != 3 || a.shape(1) != 3) {
    throw Error(StrCat(what, ": expected a 3x3 matrix"));
  }
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m(r, c) = a.at(r, c);
  return m;
}

py::array_t<double> ArrayFromMatrix3(const Eigen::Matrix3d& m) {
  py::array_t<double> out({3, 3});
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out.mutable_at(r, c) = m(r, c);
  return out;
}

py::dict DictFromGaussian(const Gaussian& g) {
  py::dict d;
  d["mean"] = ArrayFromPose(g.mean);
  d["covariance"] = ArrayFromMatrix3(g.covariance);
  d["weight"] = g.weight;
  return d;
}

}  // namespace omnicml::python

PYBIND11_MODULE(_omnicml, m) {
  namespace py = pybind11;
  using namespace omnicml::python;
  m.doc() =
      "omnicml: omniview-based concurrent map building and localization (appearance SLAM).\n"
      "Low-level extension module; import the package `omnicml` instead.";
  // omnicml::Error (bad input: file, image, option) keeps its message; InternalError is a
  // broken invariant inside the library (a bug).
  py::register_exception<omnicml::Error>(m, "Error", PyExc_RuntimeError);
  py::register_exception<omnicml::InternalError>(m, "InternalError", PyExc_RuntimeError);
  m.def("wrap_angle", &omnicml::WrapAngle, py::arg("angle_rad"),
        "Wraps an angle in radians to (-pi, pi].");
  BindDescriptors(m);
  BindUnwrap(m);
  BindLogs(m);
  BindEngine(m);
  BindExperiments(m);
}
