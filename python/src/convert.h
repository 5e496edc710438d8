// Conversions between numpy arrays / Python objects and the library's types, shared by
// the binding files of the omnicml Python package (python/src/*.cc).
//
// Images: numpy uint8 arrays of shape (H, W) (grey) or (H, W, 3) (BGR, OpenCV's channel
// order) <-> cv::Mat CV_8UC1 / CV_8UC3. Poses: float arrays of shape (3,) = (x_m, y_m,
// phi_rad) <-> Pose2. Covariances: (3, 3) <-> Eigen::Matrix3d.
//
// Every conversion failure throws omnicml::Error (Python: omnicml.Error) saying which
// argument and what is wrong. Functions here are called with the GIL held.
#ifndef OMNICML_PYTHON_SRC_CONVERT_H_
#define OMNICML_PYTHON_SRC_CONVERT_H_

#include <string>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "omnicml/geometry/gaussian_mixture.h"
#include "omnicml/geometry/pose.h"

namespace omnicml::python {

namespace py = pybind11;

// A cv::Mat header over the array's memory (no copy; valid while `array` lives), or a
// copy when the array is not C-contiguous. `what` names the argument in errors.
// Accepts uint8 (H, W), (H, W, 1) and (H, W, 3).
cv::Mat ImageFromArray(const py::handle& array, const char* what);

// A new numpy array with a copy of the pixels: (H, W) for one channel, (H, W, C) else.
// Supports 8U and 32F matrices.
py::array ArrayFromImage(const cv::Mat& image);

// (3,) array-like of finite or non-finite floats -> pose (finiteness is the library's to check).
Pose2 PoseFromObject(const py::handle& obj, const char* what);
py::array_t<double> ArrayFromPose(const Pose2& pose);

Eigen::Matrix3d Matrix3FromObject(const py::handle& obj, const char* what);
py::array_t<double> ArrayFromMatrix3(const Eigen::Matrix3d& m);

// {"mean": (3,), "covariance": (3, 3), "weight": float}.
py::dict DictFromGaussian(const Gaussian& g);

// Registers the binding groups (each in its own .cc).
void BindDescriptors(py::module_& m);
void BindUnwrap(py::module_& m);
void BindLogs(py::module_& m);
void BindEngine(py::module_& m);
void BindExperiments(py::module_& m);

}  // namespace omnicml::python

#endif  // OMNICML_PYTHON_SRC_CONVERT_H_
