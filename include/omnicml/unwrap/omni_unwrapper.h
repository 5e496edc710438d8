// Omniview camera model: raw catadioptric ring image <-> cylindrical panorama.
//
// Panorama convention used by the whole engine (descriptors, simulator, environment
// model): a panorama is W columns by H rows; column c looks along the robot-frame
// azimuth alpha_c = 2 pi c / W, counter-clockwise from the robot's forward axis (x);
// row 0 is the highest elevation. Turning the robot counter-clockwise by k * 2 pi / W
// therefore rolls the panorama by k columns towards lower indices:
//   after[c] = before[(c + k) mod W].
//
// OmniUnwrapper computes its sampling maps once at construction for any camera model of
// camera_model.h (cv::remap, bilinear, fixed-point maps) and is then immutable: Unwrap
// and Render are safe to call from several threads.
#ifndef OMNICML_UNWRAP_OMNI_UNWRAPPER_H_
#define OMNICML_UNWRAP_OMNI_UNWRAPPER_H_

#include <string>

#include <vector>

#include <opencv2/core.hpp>

#include "omnicml/unwrap/auto_calibration.h"
#include "omnicml/unwrap/camera_model.h"

namespace omnicml {

class OmniUnwrapper {
 public:
  // Precomputes the maps for raw images of image_width x image_height pixels of the
  // calibration's camera model (camera_model.h; an OmniCalibration converts to a ring).
  // `user_mask` (optional, CV_8UC1 of the image size): zero marks pixels that never show
  // the scene (the robot's body, mounts, cables); panorama pixels whose bilinear sample
  // reads any of them are invalid in valid_mask(), so masked pixels cannot influence a
  // valid one. Throws omnicml::Error if the calibration is invalid, leaves
  // the image (CameraCalibration::ValidateFor) or the mask has the wrong size or type.
  OmniUnwrapper(const CameraCalibration& calibration, int image_width, int image_height,
                const cv::Mat& user_mask = cv::Mat());

  // Raw ring (CV_8UC1 or CV_8UC3 of the construction size) -> panorama of the same type.
  // Throws omnicml::Error on an empty image, a wrong size or an unsupported type.
  cv::Mat Unwrap(const cv::Mat& raw) const;
  // The same into *panorama, whose buffer is reused when it already has the panorama's
  // size and type (no per-frame allocation in a loop).
  void Unwrap(const cv::Mat& raw, cv::Mat* panorama) const;

  // Inverse mapping: panorama (any size; resampled to the calibration's width/height)
  // -> raw ring image of the construction size and the panorama's type; pixels outside
  // the ring are `background`. A raw pixel belongs to the ring when its centre lies within
  // half a pixel of [inner_radius_px, outer_radius_px] (it touches the ring), so that
  // Unwrap(Render(p)) reproduces p up to interpolation, edge rows included; the visible
  // ring of a rendered image is therefore ~0.5 px wider on each side than the radii.
  // Cost: cv::remap over a few rectangles covering the ring (render_rects_), not the
  // pixels of the bounding box's corners or the hole (under 1 ms for 640x480).
  // Throws omnicml::Error on an empty panorama or more than 4 channels.
  cv::Mat Render(const cv::Mat& panorama, const cv::Scalar& background = cv::Scalar::all(0)) const;

  // The ring calibration (meaningful when camera().model is kRing).
  const OmniCalibration& calibration() const { return camera_.ring; }
  const CameraCalibration& camera() const { return camera_; }

  // Which panorama pixels show the scene (CV_8UC1, panorama size, 255 valid, 0 invalid):
  // invalid where the sample falls outside the image (a clipped ring) or on a zero pixel
  // of the user mask. Descriptors take it to ignore those pixels (descriptor.h).
  const cv::Mat& valid_mask() const { return valid_mask_; }
  // Fraction of valid panorama pixels, in (0, 1].
  double valid_fraction() const { return valid_fraction_; }
  // The validity mask for a panorama of width x height made from Unwrap's output by
  // PreparePanorama (PrepareMask), or an empty Mat when every pixel is valid: what
  // DescriptorExtractor::ComputeMasked takes (descriptor.h; empty = all valid).
  cv::Mat MaskFor(int width, int height) const;

 private:
  CameraCalibration camera_;
  cv::Mat valid_mask_;
  double valid_fraction_ = 1.0;
  int border_mode_ = 0;  // cv::BORDER_REPLICATE, or cv::BORDER_WRAP for equirectangular
  int image_width_;
  int image_height_;
  // Sampling maps in OpenCV's fixed-point form (cv::convertMaps: CV_16SC2 positions in the
  // *_x_ member, CV_16UC1 interpolation indices in the *_y_ member; 1/32 pixel).
  cv::Mat map_x_, map_y_;          // panorama pixel -> raw pixel
  cv::Mat inv_map_x_, inv_map_y_;  // raw pixel -> panorama pixel (padded by one column)
  // Rectangles of the raw image, together holding every pixel Render paints (bands of
  // rows, split around the hole); the pixels outside them keep the background.
  std::vector<cv::Rect> render_rects_;
};

// Panoramic input (already unwrapped): returned as is, or resized (bilinear, INTER_AREA
// when shrinking) to width x height when both are positive. Throws omnicml::Error on
// an empty or 1x1 image or a negative size. Resizing keeps the column convention: output
// column c looks along the azimuth of input column c * W_in / W (columns are centred on
// their azimuth and wrap around; plain cv::resize would shift them by a fraction of a
// column). Render resamples panoramas of another size the same way.
cv::Mat PreparePanorama(const cv::Mat& panorama, int width = 0, int height = 0);

// A validity mask (OmniUnwrapper::valid_mask) resampled to a panorama of width x height as
// PreparePanorama resamples the image: a pixel stays valid when at least half of what it
// averages is valid. Returns the mask itself when the size already matches.
cv::Mat PrepareMask(const cv::Mat& valid_mask, int width, int height);

// Reads an image file as 8-bit grey or BGR: PNG, JPEG, BMP, TIFF, PBM/PGM/PPM/PAM or WebP,
// recognised by their signature before any decoder runs (OpenCV's other decoders, DICOM
// among them, are not offered untrusted bytes). Throws omnicml::Error naming the file when
// it is missing, not a regular file (directory, FIFO, device), larger than
// kMaxImageFileBytes, of another format, declares more than kMaxImagePixels in its
// PNG/JPEG header (checked before decoding), unreadable, empty, 1x1, or has a channel
// count other than 1, 3 or 4 (4 is converted to 3). 16-bit images are scaled to 8 bit
// (v * 255 / 65535); other depths are an error.
cv::Mat ReadImage(const std::string& path);

// Writes an image atomically: encodes it in memory in the format of the extension, then
// WriteFileAtomic (common/file_io.h: temporary file, fsync, rename over `path`); readers
// never see a partial file. Throws omnicml::Error naming the file on an
// empty image, a path without extension or a failed write (missing directory, no
// permission, format unable to store the image); no temporary file is left behind.
void WriteImage(const std::string& path, const cv::Mat& image);

}  // namespace omnicml

#endif  // OMNICML_UNWRAP_OMNI_UNWRAPPER_H_
